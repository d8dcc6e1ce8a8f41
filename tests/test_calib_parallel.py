"""CalibConfig.workers (issue 29): the same result whatever the worker count; the pool helpers
keep the order of the items and fall back to one process where a pool would not help."""

from __future__ import annotations

import multiprocessing as mp

import numpy as np
import pytest
from test_calib_support import INTR, sim_frames

from xcalib.calib.api import calibrate
from xcalib.calib.config import CalibConfig
from xcalib.calib.parallel import Deferred, parallel_map, resolve_workers

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
def test_same_result_for_one_and_two_workers():
    frames, T = sim_frames(seed=1, n_frames=6)
    one = calibrate(frames, INTR, CalibConfig(workers=1))
    two = calibrate(frames, INTR, CalibConfig(workers=2))
    assert one.success and two.success, (one.message, two.message)
    assert np.array_equal(one.extrinsics, two.extrinsics)
    assert np.array_equal(one.rotation_std_deg, two.rotation_std_deg)
    assert one.diagnostics.refusal == two.diagnostics.refusal
    assert [m.statistic for m in one.diagnostics.misfit] == [m.statistic for m in two.diagnostics.misfit]
    assert two.config.workers == 2
