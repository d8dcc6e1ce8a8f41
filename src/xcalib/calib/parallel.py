"""Independent pieces of one calibration on several cores (``CalibConfig.workers``).

:func:`parallel_map` runs a function over items in a process pool (``fork``: the children share
the parent's loaded modules and inputs, nothing is imported again) and returns the results in
the order of the items, so the outcome is the same whatever the worker count: every task gets
its inputs (and any random seed) from the item itself, never from a shared generator.

``workers``: an int (1: in this process) or "auto": the CPUs this process may run on, but 1
inside a worker process of a pool (a batch of calibrations already uses the cores; nested pools
would only oversubscribe them), where ``fork`` is unavailable, and once torch is loaded (forking
a process whose torch thread pools have started can hang the child).
"""

from __future__ import annotations

import gc
import multiprocessing as mp
import os
import sys
from concurrent.futures import ProcessPoolExecutor
from typing import Callable, Iterable, Literal, TypeVar, Union

__all__ = ["Workers", "resolve_workers", "parallel_map", "available_cpus", "Deferred"]

T = TypeVar("T")
R = TypeVar("R")
Workers = Union[int, Literal["auto"]]


def available_cpus() -> int:
    """CPUs this process may run on (its affinity mask where the platform has one)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def _fork_ok() -> bool:
    return "fork" in mp.get_all_start_methods()


def resolve_workers(workers: Workers) -> int:
    """The number of processes ``workers`` stands for here (>= 1)."""
    if workers == "auto":
        if mp.parent_process() is not None or mp.current_process().daemon or not _fork_ok() or "torch" in sys.modules:
            return 1
        return available_cpus()
    n = int(workers)
    if n < 1:
        raise ValueError(f"workers: expected 'auto' or an int >= 1, got {workers!r}")
    return n if _fork_ok() else 1


def parallel_map(fn: Callable[[T], R], items: Iterable[T], workers: Workers = 1) -> list[R]:
    """``[fn(x) for x in items]``, on up to ``workers`` processes when there are two or more items.
    ``fn`` and the items must pickle (module-level functions, arrays, dataclasses); the results
    come back in the order of the items. An exception in a task is raised here."""
    items = list(items)
    n = min(resolve_workers(workers), len(items))
    if n <= 1:
        return [fn(x) for x in items]
    with _pool(n) as ex:
        return list(ex.map(fn, items))


def _pool(n: int) -> ProcessPoolExecutor:
    """A fork pool of ``n`` processes. The parent's objects are frozen out of the garbage
    collector's reach first (``gc.freeze``): a collection in a child would otherwise touch every
    inherited object and copy the parent's whole heap page by page."""
    gc.freeze()
    try:
        ex = ProcessPoolExecutor(n, mp_context=mp.get_context("fork"))
        ex.submit(int).result()  # the workers start now, while the heap is frozen
        return ex
    finally:
        gc.unfreeze()


class Deferred:
    """Calls ``[(fn, args), ...]`` started now on up to ``workers`` processes, or (one worker) run
    here in order when their result is first asked for -- so the serial order of work is
    unchanged and the parallel one overlaps it with whatever the caller does meanwhile. Use as a
    context manager (the pool is shut down on exit)."""

    def __init__(self, calls: list[tuple[Callable, tuple]], workers: Workers = 1):
        self._calls = list(calls)
        self._done: dict[int, object] = {}
        n = min(resolve_workers(workers), len(self._calls))
        self._ex = _pool(n) if n > 1 else None
        self._fut = [self._ex.submit(fn, *args) for fn, args in self._calls] if self._ex is not None else None

    def result(self, k: int):
        if self._fut is not None:
            return self._fut[k].result()
        if k not in self._done:
            fn, args = self._calls[k]
            self._done[k] = fn(*args)
        return self._done[k]

    def close(self) -> None:
        if self._ex is not None:
            self._ex.shutdown(wait=True, cancel_futures=True)
            self._ex = None

    def __enter__(self) -> "Deferred":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
