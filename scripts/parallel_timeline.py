"""Where one calibration's wall time goes with ``workers`` = N (issue 29): a timeline of the
calibration's stages (``xcalib.calib.api`` module functions, entered / left on which thread), of
every task its worker pool ran (worker, start, end, CPU) and of the pool's start, then a summary:
CPU of the parent process by thread (the main thread, the threads of the misfit searches, the
pool's own), CPU of the tasks by function (count, total, largest), the wall the parent spent
waiting with no stage of its own running (the misfit searches' tail), and how busy the workers
were. Load-robust figures are the CPU ones; wall figures hold on an idle machine only.

Usage::

    PYTHONPATH=src python scripts/parallel_timeline.py [--workers 2] [--source ../shared/data/a9_sample]
        [--json out.json] [--events]

It wraps module attributes of ``xcalib.calib.api`` and ``xcalib.calib.parallel`` in this process
only (measurement, not a setting of the calibration): the result is the same calibration.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import threading
import time
from collections import defaultdict
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
STAGES = ("prepare_frames", "_search", "_refine_candidates", "_early_searches", "_choose_box_model",
          "decide_selfcal", "match_all", "estimate_uncertainty", "fit_object_outline", "fit_outline", "verdict",
          "_misfit")
T0 = time.perf_counter()


def _timed(job):
    """(worker side) one task run and timed: (result, (pid, function, start, end, CPU s))."""
    fn, args = job
    c0, w0 = time.process_time(), time.perf_counter()
    out = fn(*args)
    return out, (os.getpid(), getattr(fn, "__name__", "?"), w0 - T0, time.perf_counter() - T0, time.process_time() - c0)


class _Timed:
    """A future whose result is a ``_timed`` pair: gives the result, keeps the timing."""

    def __init__(self, fut, sink: list):
        self._f, self._sink = fut, sink

    def result(self, timeout=None):
        out, info = self._f.result(timeout)
        self._sink.append(info)
        return out

    def __getattr__(self, k):
        return getattr(self._f, k)


def instrument(events: list, tasks: list) -> None:
    """Wrap the api stages and the pool of ``xcalib.calib.parallel`` (this process only)."""
    import xcalib.calib.api as api
    import xcalib.calib.parallel as par

    def ev(kind: str, name: str, **kw) -> None:
        events.append(dict(t=time.perf_counter() - T0, thread_cpu=time.thread_time(), cpu=time.process_time(),
                           th=threading.current_thread().name, kind=kind, name=name, **kw))

    for name in STAGES:
        f = getattr(api, name, None)
        if f is None:
            continue

        def wrapped(*a, _f=f, _n=name, **k):
            ev("enter", _n)
            try:
                return _f(*a, **k)
            finally:
                ev("exit", _n)

        setattr(api, name, wrapped)
    pool_of = par.process_pool

    def pool(n):
        ev("pool", "start")
        ex = pool_of(n)
        ev("pool", "started")
        submit = ex.submit

        def timed_submit(fn, *args, **kw):
            if fn is int:  # (the pool's own start-up tasks)
                return submit(fn, *args)
            ev("submit", getattr(fn, "__name__", "?"))
            return _Timed(submit(_timed, (fn, args)), tasks)

        def timed_map(fn, items, *a, **k):
            futs = [timed_submit(fn, x) for x in items]
            return (f.result() for f in futs)

        ex.submit, ex.map = timed_submit, timed_map
        return ex

    par.process_pool = pool
    run_of = par.run_stoppable

    def run_stoppable(stop, fn, *args):  # a Deferred call on a thread of this process: its whole CPU
        c0 = time.thread_time()
        try:
            return run_of(stop, fn, *args)
        finally:
            ev("thread", getattr(fn, "__name__", "?"), thread_total_cpu=time.thread_time() - c0)

    par.run_stoppable = run_stoppable
    wait_of = par.wait
    par.wait = lambda fs, *a, **k: wait_of([getattr(f, "_f", f) for f in fs], *a, **k)


def summarise(events: list, tasks: list, wall: float, parent_cpu: float, children_cpu: float) -> dict:
    by_thread: dict = defaultdict(float)
    last: dict = {}
    for e in events:  # a thread's CPU between its consecutive events, summed per thread kind
        kind = "main" if e["th"] == "MainThread" else "searches" if e["th"].startswith("xcalib-deferred") else e["th"]
        if e["th"] in last:
            by_thread[kind] += e["thread_cpu"] - last[e["th"]]
        last[e["th"]] = e["thread_cpu"]
    main_stages: dict = defaultdict(lambda: [0.0, 0.0])
    depth, opened = 0, {}
    for e in events:
        if e["th"] != "MainThread" or e["kind"] not in ("enter", "exit"):
            continue
        if e["kind"] == "enter":
            if depth == 0:
                opened = e
            depth += 1
        else:
            depth -= 1
            if depth == 0:
                main_stages[opened["name"]][0] += e["t"] - opened["t"]
                main_stages[opened["name"]][1] += e["thread_cpu"] - opened["thread_cpu"]
    fns: dict = defaultdict(lambda: [0, 0.0, 0.0])
    for _, fn, _, _, c in tasks:
        fns[fn][0] += 1
        fns[fn][1] += c
        fns[fn][2] = max(fns[fn][2], c)
    threads = {e["name"]: e["thread_total_cpu"] for e in events if e["kind"] == "thread"}
    pool = [e["t"] for e in events if e["kind"] == "pool"]
    starts = [e for e in events if e["kind"] == "calib"]
    t_start, t_end = starts[0]["t"], starts[-1]["t"]
    misfit = [e for e in events if e["th"] == "MainThread" and e["name"] == "_misfit"]
    span = [(s, e) for _, _, s, e, _ in tasks]
    busy = sum(e - s for s, e in span)
    return {
        "wall_s": wall, "parent_cpu_s": parent_cpu, "children_cpu_s": children_cpu,
        "parent_cpu_by_thread_s": dict(by_thread),
        "search_threads_cpu_s": threads,  # each Deferred call run on a thread: its whole CPU
        "pool_start_wall_s": (pool[1] - pool[0]) if len(pool) >= 2 else None,
        "main_stages": {k: {"wall_s": v[0], "main_thread_cpu_s": v[1]} for k, v in main_stages.items()},
        "misfit_wall_s": (misfit[-1]["t"] - misfit[0]["t"]) if len(misfit) >= 2 else None,
        "tasks": {k: {"n": v[0], "cpu_s": v[1], "largest_cpu_s": v[2]} for k, v in fns.items()},
        "task_cpu_s": sum(v[1] for v in fns.values()),
        "worker_busy_share": busy / max((t_end - t_start) * max(len({p for p, *_ in tasks}), 1), 1e-9),
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--source", default=str(REPO.parent / "shared" / "data" / "a9_sample"))
    ap.add_argument("--json", default=None, help="write the summary, events and tasks here")
    ap.add_argument("--events", action="store_true", help="print every event")
    args = ap.parse_args(argv)
    import resource
    import warnings

    warnings.simplefilter("ignore")
    from xcalib.calib.api import calibrate
    from xcalib.calib.config import CalibConfig
    from xcalib.io.sources import open_source

    frames = list(open_source(Path(args.source)))
    events: list = []
    tasks: list = []
    instrument(events, tasks)
    import xcalib.calib.api as api

    events.append(dict(t=time.perf_counter() - T0, thread_cpu=time.thread_time(), cpu=time.process_time(),
                       th="MainThread", kind="calib", name="start"))
    c0, w0 = time.process_time(), time.perf_counter()
    res = api.calibrate(frames, None, CalibConfig(workers=args.workers))
    wall, parent_cpu = time.perf_counter() - w0, time.process_time() - c0
    events.append(dict(t=time.perf_counter() - T0, thread_cpu=time.thread_time(), cpu=time.process_time(),
                       th="MainThread", kind="calib", name="end"))
    ch = resource.getrusage(resource.RUSAGE_CHILDREN)
    out = summarise(events, tasks, wall, parent_cpu, ch.ru_utime + ch.ru_stime)
    out.update(workers=args.workers, success=bool(res.success), refusal=res.diagnostics.refusal,
               load=os.getloadavg())
    del calibrate
    if args.events:
        for e in events:
            print(f"{e['t']:8.3f}s {e['th'][:16]:16s} {e['kind']:7s} {e['name']}")
        for p, fn, s, e, c in sorted(tasks, key=lambda x: x[2]):
            print(f"  task {fn:18s} worker {p} {s:8.3f}-{e:8.3f} s cpu {c:.3f} s")
    print(json.dumps(out, indent=1, default=float))
    if args.json:
        Path(args.json).write_text(json.dumps({"summary": out, "events": events, "tasks": tasks}, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
