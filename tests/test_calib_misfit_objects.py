"""Issue 25: the misfit checks count each object once.

* The principal-point check's bootstrap over frames cannot see an object's own error (its outline,
  its occlusion) repeated in every frame that shows it: with a few parked objects it flagged a
  shift of ~80 px on a clean site (realism clean site 9). Its sigma now also comes from leaving
  objects out; a shift the frames flagged but the objects do not support is no misfit, and when
  the objects cannot rule out a shift that would turn the pose by 1 deg the pose is refused as
  ``principal_point_unverifiable`` (never delivered: the same site with cx 3 % W off fits the
  same shift).
* A focal-length / principal-point misfit found together with a flagged time-offset check is
  retried with the offset estimated (``api._deliver_time_offset``).
"""

from __future__ import annotations

import dataclasses

import numpy as np
from test_calib_support import sim_frames
from test_calib_uncertainty import _truth_pairs

from xcalib.calib.cost import Occlusion
from xcalib.calib.inputs import prepare_frames
from xcalib.calib.misfit import _pp_object_sd, principal_point_check
from xcalib.calib.pose import Pose
from xcalib.calib.refine import FitContext, estimate_noise, lsq
from xcalib.types import Frame


def _parked(seed: int, n_frames: int, dx_px: float = 0.0, n_objects=(5, 7)):
    """A few objects seen again in ``n_frames`` frames (1 px fresh noise per frame), each 2D box
    moved in by its object's own outline shares (the same car alike over the frames), and shifted
    right by ``dx_px`` (a principal point off by that much). Returns a FitContext at the pose fitted
    from the truth (matches from the truth) and the truth."""
    base, T = sim_frames(seed=seed, n_frames=1, n_objects=n_objects, noise_px=0.0, miss=0.0, false_pos=0.0, extra_3d=0)
    rng = np.random.default_rng(seed)
    f0 = base[0]
    b = np.asarray(f0.bboxes_2d, dtype=np.float64)
    w, h = b[:, 2] - b[:, 0], b[:, 3] - b[:, 1]
    sh = np.array([0.06, 0.08, 0.08]) * rng.normal(size=(len(b), 3))
    b = b + np.column_stack([sh[:, 0] * w / 2, sh[:, 1] * h, -sh[:, 0] * w / 2, -sh[:, 2] * h])
    b = b + np.array([dx_px, 0.0, dx_px, 0.0])
    frames = [Frame(**{**f0.__dict__, "frame_key": f"{k:04d}", "bboxes_2d": b + rng.normal(0, 1.0, b.shape)})
              for k in range(n_frames)]
    cframes, intr, _ = prepare_frames(frames, frames[0].intrinsics)
    pairs = _truth_pairs(frames, cframes)
    noise = estimate_noise(cframes, pairs, intr, T[:3, :3], T[:3, 3])
    truth = Pose(T[:3, :3], T[:3, 3])
    R, t, *_ = lsq(FitContext(cframes, pairs, intr, truth, noise, 2.0), 60)
    return FitContext(cframes, pairs, intr, Pose(R, t), noise, 2.0, Occlusion()), truth


def test_a_few_parked_objects_give_no_principal_point_misfit_but_cannot_check_it(monkeypatch):
    import xcalib.calib.misfit as misfit

    ctx, _ = _parked(2, 8)  # exact intrinsics, 5 parked objects with their own outlines
    sd_obj, n_obj = _pp_object_sd(ctx)
    assert n_obj == 5 and np.all(sd_obj > 30.0)  # leaving one object out moves the fit a lot
    # over frames alone (the check before): a false misfit
    monkeypatch.setattr(misfit, "_pp_object_sd", lambda c, outline=False: (np.zeros(2), 0))
    chk, msg = principal_point_check(ctx)
    assert chk.flagged and msg.startswith("model misfit"), chk.detail
    monkeypatch.undo()
    chk, msg = principal_point_check(ctx)
    assert msg.startswith("not verifiable") and "5 distinct objects" in msg, msg  # not a misfit, and not checkable
    assert "leaving objects out (5 objects)" in chk.detail
    # fewer than 4 objects: nothing to leave out (the few_objects rule refuses such poses)
    keep = [p[:3] for p in ctx.pairs]
    assert _pp_object_sd(ctx.with_pairs(keep))[1] == 3 and not np.any(_pp_object_sd(ctx.with_pairs(keep))[0])


def test_a_shifted_principal_point_stays_a_misfit_with_objects_at_many_places():
    frames, T = sim_frames(seed=5, n_frames=12, noise_px=1.0, miss=0.0, false_pos=0.0, extra_3d=0)
    W = frames[0].intrinsics.width  # new objects in every frame; cx 3 % of the width off
    shifted = [Frame(**{**f.__dict__, "bboxes_2d": np.asarray(f.bboxes_2d) + np.array([0.03 * W, 0, 0.03 * W, 0])})
               for f in frames]
    cframes, intr, _ = prepare_frames(shifted, shifted[0].intrinsics)
    pairs = _truth_pairs(shifted, cframes)
    noise = estimate_noise(cframes, pairs, intr, T[:3, :3], T[:3, 3])
    R, t, *_ = lsq(FitContext(cframes, pairs, intr, Pose(T[:3, :3], T[:3, 3]), noise, 2.0), 60)
    chk, msg = principal_point_check(FitContext(cframes, pairs, intr, Pose(R, t), noise, 2.0, Occlusion()))
    assert chk.flagged and msg.startswith("model misfit") and "principal point" in msg, chk.detail


def test_boxes_at_the_image_border_do_not_vote_on_the_principal_point():
    from xcalib.calib.misfit import inner_pairs

    ctx, _ = _parked(2, 4)
    f = ctx.frames[0]
    W, H = f.size
    b = f.boxes2d.copy()
    b[ctx.pairs[0][0, 0], 0] = 0.0  # a box cut by the left border
    b[ctx.pairs[0][1, 0], 3] = H - 0.5  # one by the bottom border
    frames = [dataclasses.replace(f, boxes2d=b)] + list(ctx.frames[1:])
    inner = inner_pairs(frames, ctx.pairs)
    assert len(inner[0]) == len(ctx.pairs[0]) - 2 and all(len(a) == len(p) for a, p in zip(inner[1:], ctx.pairs[1:]))


def test_a_focal_misfit_explained_by_a_flagged_time_offset_is_retried_with_the_offset():
    """Realism time_offset_0.1s site 1: refused as misfit_focal_length (x1.12) while the time-offset
    check flagged too; the retry with the offset estimated passes every check and is delivered."""
    import warnings

    from xcalib.calib.api import calibrate
    from xcalib.data.synth.realism import make_realism_case

    case = make_realism_case("time_offset_0.1s", 1, 20)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = calibrate(list(case.frames), case.intrinsics_given)
    assert res.success, res.message
    sc = res.diagnostics.selfcal
    assert sc.time_offset_trigger.startswith("misfit_time_offset (with misfit_focal_length"), sc.time_offset_trigger
    assert abs(res.time_offset_s - case.time_offset_s) < 0.005 and "out of time" in res.message
    rot, trans = res.pose_error(case.T_cam_lidar)
    assert rot < 0.3 and trans < 0.15, (rot, trans)


def test_an_unflagged_principal_point_shift_that_turns_the_pose_beyond_1_deg_is_not_verifiable(monkeypatch):
    """Issue 25, realism principal point +3 % W, 4 px, sites 7 and 18: the boxes asked for shifts of
    89 and 56 px (2.4 and 1.5 deg) below 4 frame sigmas: unflagged, never judged, and the poses were
    delivered 1.6 deg off the truth. A shift beyond ``PP_CHECK_DEG`` whose x part is beyond the
    tolerance and 3 of its sigmas, neither flagged nor explained by the box model, now refuses as not
    verifiable; a small one passes."""
    import xcalib.calib.misfit as misfit

    frames, T = sim_frames(seed=5, n_frames=12, noise_px=1.0, miss=0.0, false_pos=0.0, extra_3d=0)
    W = frames[0].intrinsics.width

    def ctx_for(dx_px: float) -> FitContext:
        shifted = [Frame(**{**f.__dict__, "bboxes_2d": np.asarray(f.bboxes_2d) + np.array([dx_px, 0, dx_px, 0])})
                   for f in frames]
        cframes, intr, _ = prepare_frames(shifted, shifted[0].intrinsics)
        pairs = _truth_pairs(shifted, cframes)
        noise = estimate_noise(cframes, pairs, intr, T[:3, :3], T[:3, 3])
        R, t, *_ = lsq(FitContext(cframes, pairs, intr, Pose(T[:3, :3], T[:3, 3]), noise, 2.0), 60)
        return FitContext(cframes, pairs, intr, Pose(R, t), noise, 2.0, Occlusion())

    fit = misfit._pp_fit

    def wide_boot(ctx, draws, seed, outline, d=None):  # noisy data: x at 3.5 of its sigmas, y unknown
        d = fit(ctx.frames, ctx.pairs, ctx.intr, ctx.pose, ctx.noise, ctx.f_scale, ctx.occlusion, outline) \
            if d is None else d
        return d, np.array([abs(d[0]) / 3.5, 1e3])

    monkeypatch.setattr(misfit, "_pp_boot", wide_boot)
    ctx = ctx_for(0.03 * W)
    need = misfit._pp_need(ctx.intr)
    chk, msg = principal_point_check(ctx)
    assert chk.statistic > need and msg.startswith("not verifiable") and "would turn the camera" in msg, chk.detail
    chk, msg = principal_point_check(ctx_for(0.0))  # exact intrinsics: the fitted shift is small
    assert msg is None and not chk.flagged and chk.statistic < need, chk.detail


def test_realism_site_with_an_unflagged_principal_point_error_is_refused():
    """The end-to-end case: realism principal point +3 % W, 4 px, site 7 (1.6 deg off when delivered)."""
    import warnings

    import xcalib
    from xcalib.data.synth.realism import make_realism_case

    case = make_realism_case("principal_point+3%W_4px", 7, 20)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = xcalib.calibrate(list(case.frames), case.intrinsics_given)
    assert not res.success and res.diagnostics.refusal == "principal_point_unverifiable", res.message
    assert Pose.parse(np.asarray(res.diagnostics.refused_T)).error(Pose.parse(case.T_cam_lidar))[0] > 1.0
