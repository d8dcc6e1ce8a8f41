"""Independent pieces of one calibration on several cores (``CalibConfig.workers``).

:func:`parallel_map` runs a function over items in a process pool (``fork``: the children share
the parent's loaded modules and inputs, nothing is imported again) and returns the results in
the order of the items, so the outcome is the same whatever the worker count: every task gets
its inputs (and any random seed) from the item itself, never from a shared generator.

``workers``: an int (1: in this process) or "auto": the CPUs this process may run on, but 1
inside a worker process of a pool (a batch of calibrations already uses the cores; nested pools
would only oversubscribe them; a daemonic process may not start any), where ``fork`` is
unavailable, and once torch is loaded (forking a process whose torch thread pools have started
can hang the child).

One pool per calibration: ``calibrate`` opens a :class:`WorkerPool` (``with WorkerPool(n):``) and
every :func:`parallel_map` and :class:`Deferred` of its stages runs on that pool's processes,
started at the first parallel stage and stopped when the calibration returns (or raises). The
pool is a resource, not a setting: which pieces run in parallel and their results depend only on
the ``workers`` the stage is given; without an open pool each stage starts (and stops) its own.
Large read-only inputs that several tasks share (the frames) travel as :class:`Shared`: pickled
once in the parent, unpickled once per worker process.
"""

from __future__ import annotations

import gc
import itertools
import multiprocessing as mp
import os
import pickle
import sys
import threading
from collections import OrderedDict, deque
from concurrent.futures import CancelledError, Future, ProcessPoolExecutor, ThreadPoolExecutor, wait
from contextvars import ContextVar, copy_context
from typing import Any, Callable, Iterable, Literal, TypeVar, Union

__all__ = ["Workers", "resolve_workers", "parallel_map", "available_cpus", "Deferred", "WorkerPool", "Shared",
           "shared", "Stream", "chunks", "Cancelled"]

T = TypeVar("T")
R = TypeVar("R")
Workers = Union[int, Literal["auto", "pool"]]


def available_cpus() -> int:
    """CPUs this process may run on (its affinity mask where the platform has one)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def _fork_ok() -> bool:
    return "fork" in mp.get_all_start_methods()


def _nested() -> bool:
    """Whether this process is itself a worker of a pool (multiprocessing's, concurrent.futures',
    a daemonic process, a Ray worker): a pool here would only oversubscribe the cores the outer
    pool already uses (and a daemonic process may not start children)."""
    if mp.parent_process() is not None or mp.current_process().daemon:
        return True
    ray = sys.modules.get("ray")
    if ray is not None:
        try:
            return bool(ray.is_initialized()) and ray.get_runtime_context().worker.mode == ray.WORKER_MODE
        except Exception:  # an old or partial Ray: assume no Ray worker
            return False
    return False


def resolve_workers(workers: Workers) -> int:
    """The number of processes ``workers`` stands for here (>= 1): "auto" is the CPUs this process
    may use; both forms are 1 inside a pool's worker (nested pools fall back to one process),
    without ``fork``, and ("auto") once torch is loaded. "pool": the open :class:`WorkerPool`'s
    processes (1 without one)."""
    if workers == "pool":
        pool = _open_pool()
        return 1 if pool is None else pool.n
    if workers == "auto":
        if _nested() or not _fork_ok() or "torch" in sys.modules:
            return 1
        return available_cpus()
    n = int(workers)
    if n < 1:
        raise ValueError(f"workers: expected 'auto' or an int >= 1, got {workers!r}")
    return n if n == 1 or (_fork_ok() and not _nested()) else 1


# --------------------------------------------------------------------------- shared inputs

_KEYS = itertools.count()
#: worker side: the Shared objects this process unpickled, by key (the most recent few)
_RECEIVED: "OrderedDict[str, Any]" = OrderedDict()
_RECEIVED_MAX = 8


class Shared:
    """A read-only input that several tasks carry (the frames): pickled once here, whatever the
    number of tasks, and unpickled once per worker process (a task receives the object itself).
    A task run in this process gets the object through :func:`parallel_map` / :class:`Deferred`
    (a ``Shared`` item, or one in an item's tuple, is replaced by its object)."""

    __slots__ = ("obj", "key", "_blob")

    def __init__(self, obj):
        self.obj = obj
        self.key = f"{os.getpid()}:{next(_KEYS)}"
        self._blob: bytes | None = None

    def __reduce__(self):
        if self._blob is None:
            self._blob = pickle.dumps(self.obj, protocol=pickle.HIGHEST_PROTOCOL)
        return _received, (self.key, self._blob)


def _received(key: str, blob: bytes):
    """(worker side) the object of a :class:`Shared`, unpickled on its first arrival only."""
    if key in _RECEIVED:
        _RECEIVED.move_to_end(key)
        return _RECEIVED[key]
    # safe: ``blob`` is never read from a file or a user: Shared.__reduce__ pickled it in the parent
    # process a moment ago and it reaches this forked worker only through the pool's own pipe (which
    # multiprocessing already pickles); untrusted inputs are parsed by xcalib.io before any Shared exists
    obj = pickle.loads(blob)
    _RECEIVED[key] = obj
    while len(_RECEIVED) > _RECEIVED_MAX:
        _RECEIVED.popitem(last=False)
    return obj


def shared(obj: T, workers: Workers) -> T:
    """``obj`` as a :class:`Shared` when ``workers`` stands for more than one process, else ``obj``
    itself (typed as ``obj``: tasks receive the object either way)."""
    return Shared(obj) if resolve_workers(workers) > 1 else obj  # type: ignore[return-value]


def _local(x):
    """An item (or the elements of a tuple item) with its :class:`Shared` inputs replaced by their objects."""
    if isinstance(x, Shared):
        return x.obj
    if type(x) is tuple:
        return tuple(v.obj if isinstance(v, Shared) else v for v in x)
    return x


# --------------------------------------------------------------------------- the pool

_ACTIVE: ContextVar["WorkerPool | None"] = ContextVar("xcalib_worker_pool", default=None)
#: set (in the context of a thread of a :class:`Deferred`) when the Deferred is given up
_STOP: ContextVar["threading.Event | None"] = ContextVar("xcalib_deferred_stop", default=None)


class Cancelled(Exception):
    """Raised in a thread of a :class:`Deferred` given up (``cancel``) at its next parallel stage:
    its result would go unused, so it starts no more work on the pool (nothing reads it)."""


def _check_stop() -> None:
    ev = _STOP.get()
    if ev is not None and ev.is_set():
        raise Cancelled("the Deferred this work belongs to was given up")


def run_stoppable(stop: "threading.Event", fn, *args):
    """(Public for ``scripts/parallel_timeline.py``, which wraps it.) ``fn(*args)`` in a thread's own context with ``stop`` as its stop flag (see ``_STOP``)."""
    _STOP.set(stop)
    return fn(*args)


class WorkerPool:
    """The worker processes of one calibration, shared by all its parallel stages (a context
    manager: ``with WorkerPool(config.workers):``). The processes start at the first parallel
    stage (none when ``workers`` stands for one process or nothing runs in parallel) and stop on
    exit, every task waited for; the stages find the open pool themselves (this thread's
    context), so their results and their ``workers`` arguments are the same with or without it.

    Every task goes through :meth:`submit`, which counts the tasks on the processes: a task
    submitted ``later`` (independent work whose result is wanted only at the end, e.g. the misfit
    checks' refits) waits here until fewer tasks than processes are on them, so the tasks of a
    chain that must run one after another (a search, its refinements) never queue behind one that
    has not started (one started while a chain was between two of its stages can still hold a
    process when the chain's next tasks come). Which process runs a task, and when, changes no
    result."""

    def __init__(self, workers: Workers = 1):
        self.n = resolve_workers(workers)
        self._pid = os.getpid()
        self._ex: ProcessPoolExecutor | None = None
        self._token = None
        self._lock = threading.Lock()
        self._closed = False
        self._threads: list[ThreadPoolExecutor] = []  # of the Deferreds on this pool: waited for on close
        self._cond = threading.Condition()
        self._busy = 0  # tasks on the processes (submitted, not done)
        self._later: deque = deque()  # (future, fn, args) of tasks submitted ``later``, not on the processes yet
        self._feeder: threading.Thread | None = None

    @property
    def started(self) -> bool:
        return self._ex is not None

    def executor(self) -> ProcessPoolExecutor:
        with self._lock:  # (stages on several threads: one pool)
            if self._closed:
                raise RuntimeError("WorkerPool: closed")
            if self._ex is None:
                self._ex = process_pool(self.n)
            return self._ex

    def submit(self, fn: Callable, *args, later: bool = False) -> Future:
        """``fn(*args)`` on the pool's processes (a future of its result). ``later``: queued behind
        every task submitted without it, it starts once a process is idle (first in, first out
        among such tasks)."""
        ex = self.executor()
        if later:
            fut: Future = Future()
            with self._cond:
                if self._closed:  # closed since ``executor()``: ``close`` has already given the queue up
                    raise RuntimeError("WorkerPool: closed")
                self._later.append((fut, fn, args))
                if self._feeder is None:
                    self._feeder = threading.Thread(target=self._feed, name="xcalib-pool-feeder", daemon=True)
                    self._feeder.start()
                self._cond.notify_all()
            return fut
        with self._cond:
            self._busy += 1
        try:
            task = ex.submit(fn, *args)
        except BaseException:
            self._task_done(None)
            raise
        task.add_done_callback(self._task_done)
        return task

    def _task_done(self, _task) -> None:
        with self._cond:
            self._busy -= 1
            self._cond.notify_all()

    def _feed(self) -> None:
        """(the feeder thread) The ``later`` tasks onto the processes, one whenever one is idle."""
        while True:
            with self._cond:
                while self._later and not self._closed and self._busy >= self.n:
                    self._cond.wait()
                if not self._later or self._closed:
                    self._feeder = None
                    return
                fut, fn, args = self._later.popleft()
                if not fut.set_running_or_notify_cancel():  # given up before it started
                    continue
                self._busy += 1
            try:
                task = self._ex.submit(fn, *args)
            except BaseException as exc:  # a broken or closed pool: the task's future says so
                fut.set_exception(exc)
                self._task_done(None)
                continue
            task.add_done_callback(lambda _t, fut=fut, task=task: _relay(fut, task))
            task.add_done_callback(self._task_done)

    def close(self) -> None:
        for t in self._threads:  # threads of a Deferred given up (``Deferred.cancel``) end first
            t.shutdown(wait=True)
        self._threads = []
        with self._lock:
            self._closed = True
        with self._cond:  # ``later`` tasks not started never will
            later, self._later = list(self._later), deque()
            feeder = self._feeder
            self._cond.notify_all()
        for fut, _, _ in later:
            if fut.set_running_or_notify_cancel():
                fut.set_exception(CancelledError("the worker pool was closed"))
        if feeder is not None and feeder is not threading.current_thread():
            feeder.join()
        if self._ex is not None:
            self._ex.shutdown(wait=True, cancel_futures=True)
            self._ex = None

    def __enter__(self) -> "WorkerPool":
        self._token = _ACTIVE.set(self)
        return self

    def __exit__(self, *exc) -> None:
        if self._token is not None:
            _ACTIVE.reset(self._token)
            self._token = None
        self.close()


def _relay(fut: Future, task) -> None:
    """``task``'s outcome into ``fut`` (a task submitted ``later``, see :meth:`WorkerPool.submit`)."""
    if task.cancelled():
        fut.set_exception(CancelledError("the task was cancelled"))
        return
    try:
        fut.set_result(task.result())
    except BaseException as exc:  # the task's own error, raised where its result is asked for
        fut.set_exception(exc)


def _pool_map(pool: WorkerPool, fn: Callable, items: list) -> list:
    """``[fn(x) for x in items]`` as tasks of ``pool`` (results in the items' order; on an error
    the tasks not started are cancelled and it is raised)."""
    futs = [pool.submit(fn, x) for x in items]
    try:
        return [f.result() for f in futs]
    except BaseException:
        for f in futs:
            f.cancel()
        raise


def _open_pool() -> WorkerPool | None:
    """The pool open in this thread's context, if any (and not one inherited by a forked child)."""
    pool = _ACTIVE.get()
    return pool if pool is not None and pool.n > 1 and pool._pid == os.getpid() else None


def parallel_map(fn: Callable[[T], R], items: Iterable[T], workers: Workers = 1) -> list[R]:
    """``[fn(x) for x in items]``, on up to ``workers`` processes when there are two or more items
    (on the open :class:`WorkerPool`'s processes, else on a pool started for this call).
    ``workers="pool"``: every item (one too) on the open pool's processes, none started for it: for a
    stage that a thread of this process runs beside others (its work then leaves this process's
    interpreter lock to them); here without an open pool.
    ``fn`` and the items must pickle (module-level functions, arrays, dataclasses); the results
    come back in the order of the items. An exception in a task is raised here."""
    items = list(items)
    _check_stop()
    pool = _open_pool()
    if workers == "pool" and pool is not None and items:  # even one item: off this process's GIL
        return _pool_map(pool, fn, items)
    n = min(resolve_workers(workers), len(items))
    if n <= 1:
        return [fn(_local(x)) for x in items]
    if pool is not None:
        return _pool_map(pool, fn, items)
    with process_pool(n) as ex:
        return list(ex.map(fn, items))


def chunks(n_items: int, workers: Workers, per_worker: int = 2) -> list[tuple[int, int]]:
    """[lo, hi) ranges that cut ``n_items`` items (frames) into ``per_worker`` pieces per process
    ``workers`` stands for (one range with one process; none for no items): a per-item stage split
    for :func:`parallel_map`. The ranges follow the items' order, so results joined range by range
    are those of one loop over the items, whatever the worker count."""
    n = resolve_workers(workers)
    k = 1 if n <= 1 else min(n_items, n * per_worker)
    if n_items <= 0:
        return []
    edges = [n_items * j // k for j in range(k + 1)]
    return [(edges[j], edges[j + 1]) for j in range(k) if edges[j + 1] > edges[j]]


class Stream:
    """``[fn(x) for x in items]`` for items that come one at a time (``put``): with more than one
    worker each item starts on the pool's processes as it is put (without an open pool: on a pool
    started at the second item; a single item runs here), so that the caller's work on the
    next item (drawing it: random numbers, in order) overlaps the earlier items' tasks; with one
    worker the items run here, in order, when :meth:`results` is asked for (the serial order of
    work unchanged). The results, in the order of the items, are the same either way. Use as a
    context manager (on exit the tasks not started are cancelled, the running ones waited for; a
    pool started for it is shut down)."""

    def __init__(self, fn: Callable[[T], R], workers: Workers = 1):
        self._fn = fn
        self._n = resolve_workers(workers)
        pool = _open_pool() if self._n > 1 else None
        self._own: ProcessPoolExecutor | None = None
        self._ex = None if pool is None else pool  # (``submit``: the open pool's, or a pool's started for it)
        self._items: list = []  # futures once on processes, else the items

    @property
    def parallel(self) -> bool:
        return self._ex is not None

    def put(self, item: T) -> None:
        _check_stop()
        if self._ex is None and self._n > 1 and len(self._items) == 1:
            # no open pool: one started at the second item (as ``parallel_map``, none for a single item)
            self._own = self._ex = process_pool(self._n)
            self._items = [self._ex.submit(self._fn, x) for x in self._items]
        self._items.append(self._ex.submit(self._fn, item) if self._ex is not None else item)

    def results(self) -> list[R]:
        if self._ex is None:
            return [self._fn(_local(x)) for x in self._items]
        return [f.result() for f in self._items]

    def close(self) -> None:
        if self._ex is not None:
            for f in self._items:
                f.cancel()
            wait(self._items)
        if self._own is not None:
            self._own.shutdown(wait=True, cancel_futures=True)
            self._own = None

    def __enter__(self) -> "Stream":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def process_pool(n: int) -> ProcessPoolExecutor:
    """(Public for ``scripts/parallel_timeline.py``, which wraps it to time the pool's tasks.) A fork pool of ``n`` processes. The parent's objects are frozen out of the garbage
    collector's reach first (``gc.freeze``): a collection in a child would otherwise touch every
    inherited object and copy the parent's whole heap page by page."""
    gc.freeze()
    try:
        ex = ProcessPoolExecutor(n, mp_context=mp.get_context("fork"))
        for f in [ex.submit(int) for _ in range(n)]:  # the workers start now, while the heap is frozen
            f.result()
        return ex
    finally:
        gc.unfreeze()


class Deferred:
    """Calls ``[(fn, args), ...]`` started now on up to ``workers`` processes, or (one worker) run
    here when their result is first asked for (a None call: none, never run) -- so the serial order of work is
    unchanged and the parallel one overlaps it with whatever the caller does meanwhile. Use as a
    context manager (on exit the calls not started are cancelled, the running ones waited for;
    a pool started for it is shut down).

    ``threads``: the indices of calls that run (with more than one worker) on a thread of this
    process instead of as one task of the pool: a call made of parallel stages of its own (a
    search, then refinements) whose pieces then run on the open pool's processes, several at a
    time, where as one task it would run on one core. Their results are the same either way.

    ``later``: the indices of calls (tasks, not ``threads``) that on an open pool start only once
    one of its processes is idle (:meth:`WorkerPool.submit`): independent work whose result is
    wanted last, kept from delaying the tasks of the ``threads``' chains. Same results."""

    def __init__(self, calls: list[tuple[Callable, tuple] | None], workers: Workers = 1, threads: Iterable[int] = (),
                 later: Iterable[int] = ()):
        self._calls = list(calls)
        self._done: dict[int, object] = {}
        n = min(resolve_workers(workers), sum(c is not None for c in self._calls))
        pool = _open_pool() if n > 1 else None
        here = {k for k in threads if 0 <= k < len(self._calls)} if pool is not None else set()
        self._own = process_pool(n) if n > 1 and pool is None else None
        self._threads = ThreadPoolExecutor(len(here), thread_name_prefix="xcalib-deferred") if here else None
        if self._threads is not None:
            pool._threads.append(self._threads)
        ex = self._own if pool is None else pool.executor()
        self._fut: list[Future] | None = None
        self._stop = threading.Event()
        if n > 1:
            later = set(later) if pool is not None else set()
            self._fut = [None if call is None else
                         self._threads.submit(copy_context().run, run_stoppable, self._stop, call[0],
                                              *_local(tuple(call[1]))) if k in here
                         else pool.submit(call[0], *call[1], later=k in later) if pool is not None
                         else ex.submit(call[0], *call[1]) for k, call in enumerate(self._calls)]

    def __len__(self) -> int:
        return len(self._calls)

    def has(self, k: int) -> bool:
        """Whether call ``k`` exists (a None call stands for one that does not apply: never run)."""
        return 0 <= k < len(self._calls) and self._calls[k] is not None

    def result(self, k: int):
        if self._calls[k] is None:
            raise ValueError(f"Deferred: call {k} is None (not a call)")
        if self._fut is not None:
            return self._fut[k].result()
        if k not in self._done:
            fn, args = self._calls[k]
            self._done[k] = fn(*_local(tuple(args)))
        return self._done[k]

    def close(self) -> None:
        if self._fut is not None:
            live = [f for f in self._fut if f is not None]
            for f in live:
                f.cancel()
            # a cancelled call never runs: not waited for (a ``later`` one is only marked cancelled
            # once the pool's feeder reaches it, i.e. once a process is idle)
            wait([f for f in live if not f.cancelled()])
        if self._threads is not None:
            self._threads.shutdown(wait=True)
            self._threads = None
        if self._own is not None:
            self._own.shutdown(wait=True, cancel_futures=True)
            self._own = None

    def cancel(self) -> None:
        """Give the calls up: those not started never run; the running ones end in the background
        (their results unused; the open pool waits for them when it closes), a thread's call at its
        next parallel stage (``Cancelled``: it starts no more tasks on the pool)."""
        self._stop.set()
        if self._fut is not None:
            for f in self._fut:
                if f is not None:
                    f.cancel()
            self._fut = None
        self._calls = [None] * len(self._calls)
        if self._threads is not None:
            self._threads.shutdown(wait=False)
            self._threads = None
        if self._own is not None:
            self._own.shutdown(wait=True, cancel_futures=True)
            self._own = None

    def __enter__(self) -> "Deferred":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
