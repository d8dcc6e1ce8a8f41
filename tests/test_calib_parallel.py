"""CalibConfig.workers (issue 29): the same result whatever the worker count; the pool helpers
keep the order of the items and fall back to one process where a pool would not help."""

from __future__ import annotations

import multiprocessing as mp

import numpy as np
import pytest
from test_calib_support import INTR, sim_frames

from xcalib.calib.api import calibrate
from xcalib.calib.config import CalibConfig
from xcalib.calib.parallel import Deferred, Shared, WorkerPool, parallel_map, resolve_workers

needs_fork = pytest.mark.skipif("fork" not in mp.get_all_start_methods(), reason="no fork start method")


def _square(x):
    return x * x


@needs_fork
def test_parallel_map_keeps_the_order():
    items = list(range(7))
    assert parallel_map(_square, items, 2) == [x * x for x in items] == parallel_map(_square, items, 1)
    with Deferred([(_square, (3,)), (_square, (4,))], 2) as d:
        assert (d.result(1), d.result(0)) == (16, 9)
    with Deferred([(_square, (5,))], 1) as d:  # one worker: run here, once, when asked
        assert d.result(0) == d.result(0) == 25


def test_workers_validated_and_resolved():
    assert CalibConfig().workers == "auto"
    assert CalibConfig.from_dict(CalibConfig(workers=2).to_dict()).workers == 2
    for bad in (0, -1, "two", 1.5, True):
        with pytest.raises(ValueError, match="workers"):
            CalibConfig(workers=bad)
    assert resolve_workers(1) == 1 and resolve_workers("auto") >= 1


@needs_fork
def test_same_result_for_one_and_two_workers(monkeypatch):
    import xcalib.calib.api as api

    seen, kept = [], api._kept

    def counted(early, state, refits):
        out = kept(early, state, refits)
        seen.append((early is not None, out is not None))  # (started early, kept)
        return out

    monkeypatch.setattr(api, "_kept", counted)
    frames, T = sim_frames(seed=1, n_frames=6)
    one = calibrate(frames, INTR, CalibConfig(workers=1))
    two = calibrate(frames, INTR, CalibConfig(workers=2))
    # two workers: the misfit searches started before the box-model choice and were kept (it changed
    # nothing on boxes with a yaw and no cloud); one worker starts nothing early
    assert seen == [(False, False), (True, True)]
    assert one.success and two.success, (one.message, two.message)
    assert np.array_equal(one.extrinsics, two.extrinsics)
    assert np.array_equal(one.rotation_std_deg, two.rotation_std_deg)
    assert one.diagnostics.refusal == two.diagnostics.refusal
    # every misfit check (the searches and refits that ran on the pool or its threads): the same figures
    assert [(m.name, m.statistic, m.flagged, m.detail) for m in one.diagnostics.misfit] == \
        [(m.name, m.statistic, m.flagged, m.detail) for m in two.diagnostics.misfit]
    assert two.config.workers == 2
    assert mp.active_children() == []  # the calibration's pool is stopped when it returns


def _pid_of(_):
    import os

    return os.getpid()


@needs_fork
def test_one_pool_serves_every_stage_and_stops():
    with WorkerPool(2) as pool:
        assert not pool.started  # started by the first parallel stage, not before
        first = set(parallel_map(_pid_of, range(8), 2))
        # the pool's processes (which of them ran the first stage's items is the scheduler's choice)
        procs = set(pool.executor()._processes)
        assert pool.started and first <= procs and len(procs) <= 2
        with Deferred([(_pid_of, (0,)), (_pid_of, (1,))], 2) as d:
            later = {d.result(0), d.result(1)}
        again = set(parallel_map(_pid_of, range(8), 2))
        assert later | again <= procs and set(pool.executor()._processes) == procs  # none started anew
        assert set(parallel_map(_pid_of, [0], "pool")) <= procs  # "pool": even one item on the pool
    assert not pool.started and mp.active_children() == []
    assert parallel_map(_pid_of, [0], "pool") == [_pid_of(0)]  # no pool open: here


def _nested_workers(_):
    return resolve_workers("auto"), resolve_workers(2), resolve_workers("pool")


@needs_fork
def test_nested_pools_fall_back_to_one_process():
    from concurrent.futures import ProcessPoolExecutor

    with ProcessPoolExecutor(1, mp_context=mp.get_context("fork")) as ex:  # e.g. calibrate-many's pool
        assert ex.submit(_nested_workers, 0).result() == (1, 1, 1)
    with WorkerPool(2):  # a pool's own workers see no pool to nest into
        assert parallel_map(_nested_workers, range(2), 2) == [(1, 1, 1)] * 2


class _Counted:
    """A payload that counts how often it is pickled (in this process)."""

    pickled = 0

    def __init__(self, value):
        self.value = value

    def __reduce__(self):
        type(self).pickled += 1
        return _Counted, (self.value,)


def _received_value(item):
    import os

    payload, k = item
    return os.getpid(), id(payload), payload.value + k


@needs_fork
def test_shared_inputs_are_pickled_once_and_unpickled_once_per_worker():
    _Counted.pickled = 0
    shared = Shared(_Counted(10))
    with WorkerPool(2):
        out = parallel_map(_received_value, [(shared, k) for k in range(12)], 2)
    assert [v for _, _, v in out] == [10 + k for k in range(12)]
    assert _Counted.pickled == 1
    per_worker = {}
    for pid, ident, _ in out:
        per_worker.setdefault(pid, set()).add(ident)
    assert all(len(ids) == 1 for ids in per_worker.values())  # one object per worker, not one per task
    # run here (one worker, or one item): the task gets the object itself
    assert parallel_map(_received_value, [(shared, 1)], 2)[0][1:] == (id(shared.obj), 11)


def _twice(x):
    return 2 * x


def _thread_stage(xs, workers):
    return parallel_map(_twice, xs, workers)


@needs_fork
def test_deferred_threads_use_the_open_pool_and_give_the_same_results():
    calls = [(_thread_stage, ([1, 2, 3], 2)), (_twice, (5,)), None, (_twice, (Shared(7),))]
    with Deferred(calls, 1, threads=(0,)) as one:
        serial = [one.result(k) for k in (0, 1, 3)]
        assert not one.has(2) and one.has(3) and len(one) == 4
    with WorkerPool(2), Deferred(calls, 2, threads=(0,)) as two:
        assert [two.result(k) for k in (0, 1, 3)] == serial == [[2, 4, 6], 10, 14]
        with pytest.raises(ValueError, match="None"):
            two.result(2)
    assert mp.active_children() == []


# a Ray worker runs one process (nested pools fall back): tests/test_batch.py::test_ray_cluster_gives_the_same_table


@needs_fork
def test_searches_started_before_the_self_calibration_are_dropped_when_it_moves_the_intrinsics(monkeypatch):
    """With several workers the misfit checks' searches start before the self-calibration; a focal
    length given 15 % off is estimated there, so they are given up and started again: the same
    result as one worker (which starts nothing early)."""
    from dataclasses import replace

    import xcalib.calib.api as api

    seen, kept = [], api._kept

    def counted(early, state, refits):
        out = kept(early, state, refits)
        if early is not None:
            seen.append(out is not None)  # True: the early searches were used
        return out

    monkeypatch.setattr(api, "_kept", counted)
    frames, _ = sim_frames(seed=1, n_frames=6)
    given = replace(INTR, fx=INTR.fx * 1.15, fy=INTR.fy * 1.15)
    one = calibrate(frames, given, CalibConfig(workers=1))
    two = calibrate(frames, given, CalibConfig(workers=2))
    assert seen == [False]  # started early (two workers only), then given up
    assert one.diagnostics.selfcal.focal_estimated and two.diagnostics.selfcal.focal_estimated
    assert (one.success, one.diagnostics.refusal, one.message) == (two.success, two.diagnostics.refusal, two.message)
    assert one.success and np.array_equal(one.extrinsics, two.extrinsics)
    assert [(m.name, m.statistic, m.detail) for m in one.diagnostics.misfit] == \
        [(m.name, m.statistic, m.detail) for m in two.diagnostics.misfit]
    assert mp.active_children() == []


def test_chunks_cover_the_items_in_order():
    from xcalib.calib.parallel import chunks

    assert chunks(0, 2) == [] and chunks(5, 1) == [(0, 5)]
    for n in (1, 3, 7, 200):
        spans = chunks(n, 2)
        assert spans[0][0] == 0 and spans[-1][1] == n and len(spans) <= 4
        assert all(a[1] == b[0] for a, b in zip(spans, spans[1:])) and all(hi > lo for lo, hi in spans)


@needs_fork
def test_stream_gives_the_results_in_order_and_stops():
    from xcalib.calib.parallel import Stream

    for w in (1, 2):
        with Stream(_square, w) as s:
            for x in range(6):
                s.put(x)
            assert s.results() == [x * x for x in range(6)] and s.parallel == (w > 1)
        assert mp.active_children() == []  # a pool started for the stream stops with it
    with Stream(_square, 2) as s:  # no open pool, one item: run here, no pool started for it
        s.put(3)
        assert not s.parallel and s.results() == [9] and mp.active_children() == []
    with WorkerPool(2) as pool, Stream(_pid_of, 2) as s:  # on the open pool: none started for it
        for x in range(4):
            s.put(x)
        assert set(s.results()) <= set(pool.executor()._processes)
    assert mp.active_children() == []


@needs_fork
def test_hypotheses_solved_and_scored_on_the_pool_are_those_of_one_process():
    """The bring-up's searches (solved as they are drawn) and the scoring of their hypotheses on
    every frame (frames in ranges on the pool): bit-identical to one process."""
    from xcalib.calib.bringup import frame_scores, pose_hypotheses
    from xcalib.calib.inputs import prepare_frames

    frames, _ = sim_frames(seed=2, n_frames=8)
    cframes, intr, _ = prepare_frames(frames, INTR)
    one = pose_hypotheses(cframes, intr, CalibConfig(workers=1), rng=np.random.default_rng(0))
    with WorkerPool(2):
        two = pose_hypotheses(cframes, intr, CalibConfig(workers=2), rng=np.random.default_rng(0))
        assert len(one.hyps) > 0
        per_frame = frame_scores(cframes, intr, one.hyps.R, one.hyps.t, 2)
    for a, b in zip((one.hyps.R, one.hyps.t, one.hyps.score, one.hyps.frame), (two.hyps.R, two.hyps.t, two.hyps.score,
                                                                                two.hyps.frame)):
        assert np.array_equal(a, b)
    assert len(per_frame) == len(cframes)
    assert all(np.array_equal(a, b) for a, b in zip(per_frame, frame_scores(cframes, intr, one.hyps.R, one.hyps.t, 1)))
    assert mp.active_children() == []


def _slow(x):
    import time

    time.sleep(0.2)
    return x


def _stages(log, n):
    """A thread's call of ``n`` parallel stages, logging each one it starts."""
    for k in range(n):
        log.append(k)
        parallel_map(_slow, [k, k], 2)
    return "done"


@needs_fork
def test_a_deferred_given_up_starts_no_more_stages():
    """``Deferred.cancel``: a call running on a thread ends at its next parallel stage (``Cancelled``),
    so the work of searches whose result is unused stops occupying the pool; one not given up ends."""
    import time

    log_kept, log_given_up = [], []
    with WorkerPool(2):
        with Deferred([(_stages, (log_kept, 3)), (_square, (2,))], 2, threads=(0,)) as kept:
            assert kept.result(0) == "done"
        d = Deferred([(_stages, (log_given_up, 50)), (_square, (2,))], 2, threads=(0,))
        time.sleep(0.3)
        d.cancel()
    # the pool's close waited for the thread: it stopped after the stage it was in (without the stop
    # flag it would have run all 50; each stage takes >= 0.2 s, so at most 2 began before the cancel)
    assert log_kept == [0, 1, 2] and len(log_given_up) <= 4
    assert mp.active_children() == []
