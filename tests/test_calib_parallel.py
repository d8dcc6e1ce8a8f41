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


@needs_fork
def test_the_bring_up_search_is_the_same_on_two_workers():
    from xcalib.calib.bringup import pose_hypotheses
    from xcalib.calib.inputs import prepare_frames

    frames, _ = sim_frames(seed=1, n_frames=6)
    cf, intr, _ = prepare_frames(frames, INTR)
    one = pose_hypotheses(cf, intr, CalibConfig(workers=1))
    two = pose_hypotheses(cf, intr, CalibConfig(workers=2))
    assert len(one.hyps) > 10
    for k in ("R", "t", "score", "frame"):
        assert np.array_equal(getattr(one.hyps, k), getattr(two.hyps, k)), k
    assert (one.split_searches, one.pooled_search) == (two.split_searches, two.pooled_search)


def test_drawn_searches_solved_later_are_the_frame_search():
    """``frame_hypotheses`` = ``draw_triples`` then ``solve_triples``: two searches drawn one after
    the other from one generator, solved afterwards in reverse order, give what two searches in a
    row give (the draws take every random number)."""
    from xcalib.calib.hypotheses import draw_triples, frame_hypotheses, solve_triples
    from xcalib.calib.inputs import prepare_frames

    frames, _ = sim_frames(seed=2, n_frames=2)
    cf, intr, _ = prepare_frames(frames, INTR)
    rng = np.random.default_rng(3)
    direct = [frame_hypotheses([f], intr, k, rng=rng) for k, f in enumerate(cf)]
    rng = np.random.default_rng(3)
    draws = [draw_triples([f], intr, rng=rng) for f in cf]
    later = [solve_triples([cf[k]], intr, k, draws[k]) for k in (1, 0)][::-1]
    assert all(len(h) for h in direct)
    for a, b in zip(direct, later):
        assert np.array_equal(a.R, b.R) and np.array_equal(a.t, b.t) and np.array_equal(a.score, b.score)
