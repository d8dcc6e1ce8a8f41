"""WorkerPool.submit(later=True) (issue 29, workers=2): a task queued "later" waits until a process
is idle, so the tasks of a chain submitted after it start first; cancelling it or closing the pool
before it starts means it never runs; results are unchanged (Deferred's ``later`` calls)."""

from __future__ import annotations

import multiprocessing as mp
from concurrent.futures import CancelledError

import pytest

from xcalib.calib.parallel import Deferred, WorkerPool, parallel_map

needs_fork = pytest.mark.skipif("fork" not in mp.get_all_start_methods(), reason="no fork start method")

#: set by the test to release the blocking tasks (inherited by the forked workers: made before the pool)
_GATE = mp.get_context("fork").Event() if "fork" in mp.get_all_start_methods() else None


def _blocked(x):
    assert _GATE.wait(120), "the gate was never opened"
    return x


def _square(x):
    return x * x


@needs_fork
def test_later_task_waits_behind_the_tasks_submitted_after_it():
    _GATE.clear()
    with WorkerPool(2) as pool:
        b = [pool.submit(_blocked, k) for k in range(2)]  # both processes busy until the gate opens
        late = pool.submit(_square, 3, later=True)
        chain = pool.submit(_square, 4)  # submitted after, queued ahead of it
        gone = pool.submit(_square, 5, later=True)
        assert gone.cancel()  # not started: can be given up, and never runs
        assert not late.running() and not late.done() and len(pool._later) == 2
        _GATE.set()
        assert [f.result(timeout=120) for f in b] == [0, 1]
        assert chain.result(timeout=120) == 16 and late.result(timeout=120) == 9
        assert gone.cancelled() and not pool._later
        # a later task on an idle pool starts at once
        assert pool.submit(_square, 6, later=True).result(timeout=120) == 36
    assert mp.active_children() == []


def _fails(_):
    raise ValueError("task error")


@needs_fork
def test_later_task_error_and_pool_closed_before_it_starts():
    import threading
    import time

    with WorkerPool(2) as pool:
        err = pool.submit(_fails, 0, later=True)
        with pytest.raises(ValueError, match="task error"):
            err.result(timeout=120)
    _GATE.clear()
    pool = WorkerPool(2)  # (not entered: closed on another thread below)
    b = [pool.submit(_blocked, k) for k in range(2)]
    late = pool.submit(_square, 3, later=True)
    for _ in range(12000):  # both handed to the processes (running): else the close's shutdown cancels one
        if all(f.running() for f in b):
            break
        time.sleep(0.01)
    closing = threading.Thread(target=pool.close)
    closing.start()  # the close gives the queued task up first, then waits for the running ones
    with pytest.raises(CancelledError):
        late.result(timeout=120)
    _GATE.set()
    closing.join(120)
    assert not closing.is_alive() and [f.result() for f in b] == [0, 1]
    assert mp.active_children() == []


@needs_fork
def test_deferred_later_calls_give_the_same_results():
    calls = [(_square, (2,)), (_square, (3,)), (_square, (4,))]
    with Deferred(calls, 1, later=(1, 2)) as one:
        serial = [one.result(k) for k in range(3)]
    with WorkerPool(2), Deferred(calls, 2, later=(1, 2)) as two:
        assert [two.result(k) for k in range(3)] == serial == [4, 9, 16]
        assert parallel_map(_square, range(5), 2) == [0, 1, 4, 9, 16]
    with Deferred(calls, 2, later=(1, 2)) as own:  # no open pool: its own, ``later`` does not apply
        assert [own.result(k) for k in range(3)] == serial
    assert mp.active_children() == []


@needs_fork
def test_calibration_queues_the_misfit_refits_later(monkeypatch):
    """With two workers the misfit checks' refits (calls 3-5 of ``_misfit_searches``) are ``later``
    tasks and the searches (0-2) threads; the result is that of one worker."""
    import numpy as np
    from test_calib_support import INTR, sim_frames

    from xcalib.calib.api import calibrate
    from xcalib.calib.config import CalibConfig

    seen, init = [], Deferred.__init__

    def recorded(self, calls, workers=1, threads=(), later=()):
        seen.append((len(calls), tuple(threads), tuple(later)))
        init(self, calls, workers, threads, later)

    monkeypatch.setattr(Deferred, "__init__", recorded)
    frames, _ = sim_frames(seed=1, n_frames=6)
    one = calibrate(frames, INTR, CalibConfig(workers=1))
    two = calibrate(frames, INTR, CalibConfig(workers=2))
    assert (6, (0, 1, 2), (3, 4, 5)) in seen
    assert one.success and np.array_equal(one.extrinsics, two.extrinsics)
    assert [(m.name, m.detail) for m in one.diagnostics.misfit] == [(m.name, m.detail) for m in two.diagnostics.misfit]
    assert mp.active_children() == []
