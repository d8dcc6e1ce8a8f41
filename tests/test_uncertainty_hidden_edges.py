"""The hidden-edge part of the reported sigma (issue 26): the pose shift when the edges that lie on a
nearer matched box are censored, counted beyond its own sampling noise; sigma only, never the pose.

Seeded box-level scenes (``test_calib_support.sim_frames``), matches from the truth, no search.
"""

from __future__ import annotations

import numpy as np
from test_calib_censor import _occluded
from test_calib_support import sim_frames
from test_calib_uncertainty import _truth_pairs

from xcalib.calib.cost import Occlusion
from xcalib.calib.inputs import prepare_frames
from xcalib.calib.pose import Pose
from xcalib.calib.refine import FitContext, estimate_noise, lsq
from xcalib.calib.uncertainty import (SHIFT_NOISE_Z, excess, hidden_edge_shift, object_groups,
                                      with_hidden_edges)


def _fit(frames, T, noise_px_known: bool = True):
    cframes, intr, _ = prepare_frames(frames, frames[0].intrinsics)
    pairs = _truth_pairs(frames, cframes)
    truth = Pose(T[:3, :3], T[:3, 3])
    noise = estimate_noise(cframes, pairs, intr, T[:3, :3], T[:3, 3])
    R, t, *_ = lsq(FitContext(cframes, pairs, intr, truth, noise, 2.0, Occlusion()), 60)
    ctx = FitContext(cframes, pairs, intr, Pose(R, t), noise, 2.0, Occlusion())
    return ctx, truth, object_groups(cframes, pairs)


def test_the_shift_points_back_to_the_truth_where_boxes_cover_the_visible_part():
    frames, T = sim_frames(seed=0, n_frames=8, n_objects=(14, 22), noise_px=0.0, miss=0.0, false_pos=0.0,
                           extra_3d=0)
    occ, cut = _occluded(frames, T)
    assert cut >= 15
    ctx, truth, groups = _fit(occ, T)
    err = ctx.pose.delta(truth)  # the hidden edges, fitted as exact, pull the pose
    assert np.linalg.norm(err[:3]) > 1e-3
    shift, noise = hidden_edge_shift(ctx, groups)
    assert shift is not None and noise is not None and shift.shape == (6,) and noise.shape == (6,)
    # censored, the pose goes back to the truth: the shift is minus the error
    np.testing.assert_allclose(shift, -err, atol=0.1 * np.abs(err).max())
    # added to a sigma that misses the error, it covers it on the axes it moved
    sd = np.full(6, 1e-6)
    r, t = with_hidden_edges(sd[:3], sd[3:], shift, noise)
    big = np.abs(err) > 0.3 * np.abs(err).max()
    assert np.all(np.abs(err[big]) <= 2 * np.concatenate([r, t])[big])


def test_no_hidden_edges_no_part_and_a_censoring_fit_has_none():
    frames, T = sim_frames(seed=0, n_frames=8, n_objects=(14, 22), noise_px=0.0, miss=0.0, false_pos=0.0,
                           extra_3d=0)
    ctx, truth, groups = _fit(frames, T)  # amodal, exact boxes: every edge is exact
    shift, noise = hidden_edge_shift(ctx, groups)
    assert shift is not None and np.abs(shift[:3]).max() < 1e-4 and np.abs(shift[3:]).max() < 1e-5
    import dataclasses
    cens = dataclasses.replace(ctx, occlusion=Occlusion(censor=True))
    assert hidden_edge_shift(cens, groups) == (None, None)
    sd = np.arange(1.0, 7.0)
    r, t = with_hidden_edges(sd[:3], sd[3:], None, None)
    np.testing.assert_array_equal(np.concatenate([r, t]), sd)


def test_a_noisy_amodal_scene_adds_little_beyond_its_noise():
    frames, T = sim_frames(seed=1, n_frames=8, n_objects=(14, 22), noise_px=1.0, miss=0.0, false_pos=0.0, extra_3d=0)
    ctx, truth, groups = _fit(frames, T)
    shift, noise = hidden_edge_shift(ctx, groups)
    assert shift is not None and noise is not None
    ex = excess(shift, noise, SHIFT_NOISE_Z)
    # censoring exact edges only drops information: the shift is its own noise, counted as nothing
    assert np.all(ex <= np.abs(shift)) and np.sum(ex ** 2) <= 0.25 * np.sum(np.asarray(noise) ** 2) + 1e-12
