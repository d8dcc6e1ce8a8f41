"""The wall time one calibration would take on idle cores, estimated from CPU times (issue 29).

A wall-clock speed-up needs an idle second core; on a shared, loaded machine the wall time says
nothing. This runs one case of ``benchmarks/bench_calibration_speed.py`` with ``workers`` processes
and records every parent thread's CPU timeline (``time.thread_time``) cut at its sync points (tasks
submitted to the pool, tasks or a thread waited for, a thread started), and each pool task's CPU
(measured in the worker; the workers' other CPU -- unpickling, start-up -- is spread over their
tasks, the parent's other threads' over its main thread). A discrete-event simulation then runs the
parent's threads (one interpreter lock: together at most one core) and the ``workers`` FIFO
processes on ``cores`` cores shared evenly. Printed: the measured wall and CPU (parent, children),
the simulated wall, the speed-up estimate (the run's own parent + task CPU over the simulated wall)
and, with ``-v``, the CPU by task and the idle core-seconds by the main thread's segment (what runs
alone). Not modelled: process start-up latency, memory bandwidth, the cores' clocks.

    OMP_NUM_THREADS=1 PYTHONPATH=src python scripts/two_core_estimate.py a9 2 [--cores 2] [-v]
"""
import argparse
import hashlib
import resource
import sys
import threading
import time
from concurrent.futures import wait as fwait
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import bench_calibration_speed as b  # noqa: E402

import xcalib.calib.parallel as par  # noqa: E402

ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
ap.add_argument("case", help="a case of bench_calibration_speed.py (a9, synth20, synth1000, dense20, ...)")
ap.add_argument("workers", type=int)
ap.add_argument("--cores", type=int, default=2)
ap.add_argument("--frames-long", type=int, default=1000)
ap.add_argument("-v", action="store_true")
args = ap.parse_args()
case, W, C = args.case, args.workers, args.cores
frames, intr, T = b._case_frames(case, args.frames_long)
EV = {}; TASKS = {}; _n = iter(range(10**9)); TL = threading.local(); LOCK = threading.Lock()
def key(): return getattr(TL, 'key', 'main')
def _where():
    f, out = sys._getframe(2), []
    while f is not None and len(out) < 4:
        if 'xcalib' in f.f_code.co_filename and 'parallel.py' not in f.f_code.co_filename: out.append(f.f_code.co_name)
        f = f.f_back
    return '<'.join(out)
def rec(kind, payload):
    w = _where()
    with LOCK: EV.setdefault(key(), []).append((time.thread_time(), kind, payload, w))
def _run(tid, fn, *a):
    c = time.process_time(); r = fn(*a)
    return r, (tid, time.process_time() - c, getattr(fn, '__name__', '?'))
def _take(res):
    r, (tid, cpu, name) = res; TASKS[tid] = (cpu, name); return r
def _thr(tkey, fn, *a):
    TL.key = tkey; rec('start', None)
    try: return fn(*a)
    finally: rec('end', None)
def parallel_map(fn, items, workers=1):
    items = list(items)
    n = min(par.resolve_workers(workers), len(items))
    if workers == 'pool' and par._open_pool() is not None and items: n = 2
    if n <= 1: return [fn(par._local(x)) for x in items]
    ex = par._open_pool().executor()
    ids = [next(_n) for _ in items]
    rec('submit', ids)
    futs = [ex.submit(_run, i, fn, x) for i, x in zip(ids, items)]
    out = [_take(f.result()) for f in futs]
    rec('wait', ids)
    return out
class Deferred(par.Deferred):
    def __init__(self, calls, workers=1, threads=(), later=()):  # ``later``: run as plain tasks here (not modelled)
        n = min(par.resolve_workers(workers), len(calls))
        self._par = n > 1
        self._ids = [next(_n) for _ in calls]
        self._isthr = [k in set(threads) for k in range(len(calls))] if n > 1 else [False] * len(calls)
        if n > 1:
            rec('submit', [i for i, t in zip(self._ids, self._isthr) if not t])
            for i, t in zip(self._ids, self._isthr):
                if t: rec('spawn', 'T%d' % i)
            calls = [((_thr, ('T%d' % i, fn, *args)) if t else (_run, (i, fn, *args)))
                     for i, t, (fn, args) in zip(self._ids, self._isthr, calls)]
        super().__init__(calls, workers, threads)
        self._seen = {}
    def result(self, k):
        if not self._par: return super().result(k)
        if k not in self._seen:
            r = super().result(k)
            if self._isthr[k]: rec('join', 'T%d' % self._ids[k]); self._seen[k] = r
            else: rec('wait', [self._ids[k]]); self._seen[k] = _take(r)
        return self._seen[k]
    def close(self):
        if self._par and self._fut is not None:
            for f in self._fut: f.cancel()
            fwait(self._fut)
            for k, f in enumerate(self._fut):
                if k not in self._seen and not f.cancelled():
                    if self._isthr[k]: rec('join', 'T%d' % self._ids[k])
                    else: self._seen[k] = _take(f.result()); rec('wait', [self._ids[k]])
                    self._seen.setdefault(k, None)
        super().close()
class Stream(par.Stream):
    def put(self, item):
        if not self.parallel: return super().put(item)
        i = next(_n); rec('submit', [i])
        self._items.append(self._ex.submit(_run, i, self._fn, item))
    def results(self):
        if not self.parallel: return super().results()
        out = [f.result() for f in self._items]
        rec('wait', [r[1][0] for r in out])
        return [_take(r) for r in out]
import xcalib.calib.api as api, xcalib.calib.bringup as bu, xcalib.calib.inputs as inp, xcalib.calib.misfit as mf
for m in (api, bu, inp, mf):
    if hasattr(m, 'parallel_map'): m.parallel_map = parallel_map
api.Deferred = Deferred
bu.Stream = Stream
from xcalib.calib.config import CalibConfig
t0 = time.perf_counter(); c0 = time.process_time(); tm0 = time.thread_time()
res = api.calibrate(frames, intr, CalibConfig(workers=W))
rec('end', None)
wall, pcpu = time.perf_counter() - t0, time.process_time() - c0
ch = resource.getrusage(resource.RUSAGE_CHILDREN); ccpu = ch.ru_utime + ch.ru_stime
tcpu = sum(c for c, _ in TASKS.values())
k = 1 + max(0.0, ccpu - tcpu) / max(tcpu, 1e-9)
# segments per parent thread
SEG = {}
for tk, evs in EV.items():
    last = tm0 if tk == 'main' else evs[0][0]
    segs = []
    for c, kind, p, w in (evs if tk == 'main' else evs[1:]):
        segs.append([c - last, kind, p, w]); last = c
    SEG[tk] = segs
thr_cpu = sum(sum(s[0] for s in v) for v in SEG.values())
other = max(0.0, pcpu - thr_cpu)  # executor/feeder threads: spread over the main thread's segments
km = 1 + other / max(sum(s[0] for s in SEG['main']), 1e-9)
for s in SEG['main']: s[0] *= km
tcost = {i: c * k for i, (c, _) in TASKS.items()}
state = {'main': 0}; rem = {'main': SEG['main'][0][0]}; blocked = {}; ended = set()
queue, running, done, now = [], {}, set(), 0.0
IDLE = {}
def advance_thread(tk):
    """the thread finished its current segment: act on its event."""
    i = state[tk]; _, kind, p, _w = SEG[tk][i]
    if kind == 'submit': queue.extend(x for x in p if x in tcost)
    elif kind == 'spawn': state[p] = 0; rem[p] = SEG[p][0][0]
    elif kind == 'wait': blocked[tk] = ('tasks', [x for x in p if x in tcost]); return
    elif kind == 'join': blocked[tk] = ('thread', p); return
    elif kind == 'end': ended.add(tk); del state[tk]; return
    next_seg(tk)
def next_seg(tk):
    state[tk] += 1; rem[tk] = SEG[tk][state[tk]][0]
while True:
    for tk, (what, p) in list(blocked.items()):
        if (what == 'tasks' and all(x in done for x in p)) or (what == 'thread' and p in ended):
            del blocked[tk]; next_seg(tk)
    while queue and len(running) < W:
        t = queue.pop(0); running[t] = tcost[t]
    act = [tk for tk in state if tk not in blocked]
    if not act and not running:
        break
    nproc = len(running) + (1 if act else 0)
    r = min(1.0, C / nproc); rp = r / max(len(act), 1)
    cand = [(v / r, ('w', t)) for t, v in running.items()] + [(rem[tk] / rp, ('p', tk)) for tk in act]
    dt, _ = min(cand, key=lambda x: x[0])
    used = min(C, nproc)
    if used < C and 'main' in state:
        lab = SEG['main'][state['main']][3] + ':' + SEG['main'][state['main']][1] + ('(blocked)' if 'main' in blocked else '')
        IDLE[lab] = IDLE.get(lab, 0) + (C - used) * dt
    now += dt
    for t in list(running):
        running[t] -= dt * r
        if running[t] <= 1e-12: done.add(t); del running[t]
    for tk in act:
        rem[tk] -= dt * rp
        if rem[tk] <= 1e-12: advance_thread(tk)
print(f"{case} workers={W} measured wall {wall:.2f} parent cpu {pcpu:.2f} children {ccpu:.2f} (tasks {tcpu:.2f}) "
      f"total {pcpu+ccpu:.2f}; simulated wall on {C} idle cores: {now:.2f} s (speed-up estimate "
      f"x{(pcpu + tcpu) / max(now, 1e-9):.2f}); ok={res.success} "
      f"T={hashlib.md5(str(None if res.rotation is None else res.extrinsics.tolist()).encode()).hexdigest()[:8]}", flush=True)
if args.v:
    by = {}
    for i, (c, nme) in TASKS.items(): by[nme] = by.get(nme, 0) + c
    print('tasks', {n: round(v, 3) for n, v in by.items()})
    print('parent threads cpu', {tk: round(sum(s[0] for s in v), 3) for tk, v in SEG.items()}, 'other', round(other, 3))
    print('idle core-seconds by main-thread segment (ends at):')
    for lab, v in sorted(IDLE.items(), key=lambda x: -x[1])[:12]: print(f'  {v:.3f} {lab}')
