"""The fit context and the option records of ``xcalib.calib`` (issue 28): frozen, the defaults the
long signatures had, and a refit through them equal to the one built by hand."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from xcalib.calib.context import F_SCALE, FitContext, RefineOptions
from xcalib.calib.cost import Occlusion
from xcalib.calib.hypotheses import TripleSearch
from xcalib.calib.pose import Pose
from xcalib.calib.single import one_frame


def test_fit_context_is_frozen_and_replaces_one_field():
    pose = Pose(np.eye(3), np.zeros(3))
    ctx = FitContext(["f"], [np.zeros((0, 2), np.int64)], "K", pose)
    assert ctx.noise is None and ctx.f_scale == F_SCALE == 2.0 and ctx.occlusion == Occlusion()
    with pytest.raises(dataclasses.FrozenInstanceError):
        ctx.pairs = []
    sub = ctx.with_pairs([])
    assert sub.pairs == [] and sub.frames is ctx.frames and sub.pose is pose and ctx.pairs != []
    assert ctx.with_frames(["g"]).frames == ["g"] and ctx.with_pose(Pose(np.eye(3), np.ones(3))).pose.t[0] == 1.0


def test_option_records_keep_the_old_defaults():
    r = RefineOptions()
    assert r.gates == ((0.1, 1.0), (0.2, 0.5), (0.3, 0.0), (0.3, 0.0), (0.3, 0.0), (0.3, 0.0))
    assert (r.min_pairs, r.max_nfev, r.tol, r.max_outer, r.adapt_noise) == (3, 60, 1e-3, None, True)
    s = TripleSearch()
    assert (s.max_triples, s.min_altitude_m, s.keep, s.max_baseline_m, s.max_candidates) == (3000, 0.8, 25, None, 1500)


def test_one_frame_binds_the_reference_call():
    inputs, intr, options = one_frame("img", "pc", bboxes_3d="b3", bboxes_2d="b2", intrinsics="K", validate="off")
    assert inputs == ("img", "pc", "b2", "b3") and intr == "K" and options == {"validate": "off"}
    with pytest.raises(TypeError):
        one_frame("img", "pc", "b2", "b3")  # no intrinsics


def test_lsq_through_the_context_is_the_hand_built_fit():
    from test_calib_support import sim_frames

    from xcalib.calib.inputs import prepare_frames
    from xcalib.calib.refine import build_cost, lsq, match_all

    frames, T = sim_frames(seed=3, n_frames=3, noise_px=1.0, miss=0.0, false_pos=0.0, extra_3d=0)
    cframes, intr, _ = prepare_frames(frames, frames[0].intrinsics)
    pose = Pose(T[:3, :3], T[:3, 3])
    pairs = match_all(cframes, intr, pose.R, pose.t, gate_iou=0.3)
    R, t, cost, _, _ = lsq(FitContext(cframes, pairs, intr, pose), 40)
    fit = build_cost(cframes, pairs, intr, pose, None, Occlusion()).fit(f_scale=2.0, max_nfev=40)
    assert np.array_equal(R, fit.pose.R) and np.array_equal(t, fit.pose.t) and cost == fit.cost
