"""Issue 25: the misfit checks test the box model before they blame the intrinsics, and never clear
what the objects cannot verify.

* The principal-point check's second look without the 2D boxes cut by the image border may clear a
  misfit (truncated boxes asked for the shift) but not an unflagged shift beyond the wrong-pose
  line that the boxes inside the image still ask for: fewer boxes cannot verify what all of them
  could not (realism principal point +3 % W, 4 px, site 18 was delivered 1.55 deg / 0.49 m off
  because the look without its 4 border boxes put x at 2.7 sigmas).
* The focal-length check fits the detector-outline offsets before it blames the focal length: a
  detector's visible outline makes every box a few per cent smaller, which a shorter focal length
  mimics (realism ``detector_all`` site 8: x0.970, with the outline offsets free x0.984). A real
  focal error scales the boxes' positions too and stays a misfit.
"""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np
from test_calib_misfit_objects import _parked
from test_calib_support import sim_frames
from test_calib_uncertainty import _truth_pairs

import xcalib.calib.misfit as misfit
from xcalib.calib.cost import Occlusion
from xcalib.calib.inputs import prepare_frames
from xcalib.calib.diagnostics import MisfitCheck
from xcalib.calib.misfit import focal_box_model, focal_fit, focal_scale_check, principal_point_check
from xcalib.calib.pose import Pose
from xcalib.calib.refine import FitContext, estimate_noise, lsq
from xcalib.types import Frame


def _with_border_box(ctx: FitContext) -> FitContext:
    f = ctx.frames[0]
    b = f.boxes2d.copy()
    b[ctx.pairs[0][0, 0], 0] = 0.0  # one matched box cut by the left border
    return ctx.with_frames([dataclasses.replace(f, boxes2d=b)] + list(ctx.frames[1:]))


def _looks(first: str, detail: str, inner_shift: float):
    """A stand-in for ``principal_point_check_all``: with every box ``first`` (a message) and
    ``detail``, without the border box nothing flagged and a shift of ``inner_shift`` px."""
    def check(ctx, draws=5, seed=0, places=None):
        n = sum(len(p) for p in ctx.pairs)
        if n == check.n_all:
            return MisfitCheck("principal_point", 60.0, 30.0, True, detail), first
        return MisfitCheck("principal_point", inner_shift, 30.0, False, "inner boxes"), None
    return check


def test_the_border_box_second_look_clears_a_shift_only_the_border_boxes_ask_for(monkeypatch):
    """Realism principal point +3 % W, 4 px, site 18: every box fit (-35, -44) px (1.5 deg, x at 3.3
    sigmas: not verifiable), the boxes inside the image (-41, -56) px at 2.7 sigmas -- unflagged,
    which cleared the verdict and delivered the pose 1.55 deg off. The second look may clear a
    misfit, or a not-verifiable shift that the inner boxes do not ask for, never one they still ask for."""
    ctx, _ = _parked(2, 4)
    ctx = _with_border_box(ctx)
    need = misfit._pp_need(ctx.intr)
    # a cleared check is judged by the pose-free sigma too (session 13); not this test's subject
    monkeypatch.setattr(misfit, "_pp_jacobian_sd", lambda c: None)
    asked = "not verifiable: the boxes fit best with the principal point moved by (-35, -44) px ..."
    objects = "not verifiable: the 40 matches come from 5 distinct objects ..."
    for first, detail, inner_shift, kept in [
            (asked, f"fitted ...; not verifiable: ..., not flagged: {misfit._PP_ASKED}", 1.9 * need, True),
            (asked, f"fitted ...; not verifiable: ..., not flagged: {misfit._PP_ASKED}", 0.5 * need, False),
            # session 13: the objects' verdict too stands when the inner boxes ask for a shift beyond the
            # 1-degree line (unified 150 deg bench site 2, cx 3 % W off: delivered 5.2 deg off before)
            (objects, "leaving objects out ...", 1.9 * need, True),
            (objects, "leaving objects out ...", 0.5 * need, False),
            ("model misfit: the boxes fit best with the principal point moved ...", "all boxes", 1.9 * need, False)]:
        check = _looks(first, detail, inner_shift)
        check.n_all = sum(len(p) for p in ctx.pairs)
        monkeypatch.setattr(misfit, "principal_point_check_all", check)
        chk, msg = principal_point_check(ctx)
        if kept:  # the inner boxes still ask for a shift beyond the wrong-pose line: stays unverifiable
            assert msg == first and chk.flagged and chk.detail == detail
        else:  # a shift the border boxes alone asked for is no misfit
            assert msg is None and not chk.flagged and chk.detail.startswith("without the 1 matched 2D boxes")


def test_realism_site_whose_inner_boxes_cannot_verify_the_principal_point_is_refused():
    """The end-to-end case: realism principal point +3 % W, 4 px, site 18 (delivered 1.55 deg /
    0.49 m off, reported 1-sigma 0.16-0.25 deg, before)."""
    import xcalib
    from xcalib.data.synth.realism import make_realism_case

    case = make_realism_case("principal_point+3%W_4px", 18, 20)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = xcalib.calibrate(list(case.frames), case.intrinsics_given)
    assert not res.success and res.diagnostics.refusal == "principal_point_unverifiable", res.message
    assert Pose.parse(np.asarray(res.diagnostics.refused_T)).error(Pose.parse(case.T_cam_lidar))[0] > 1.0


def _focal_ctx(seed: int, focal: float, shrink=(0.05, 0.06, 0.06), n_frames: int = 8) -> FitContext:
    """Frames whose 2D boxes are moved in by outline shares (sides, top, bottom of the box size: a
    detector's visible outline), given fx, fy x ``focal`` of the truth; the pose fitted from the truth."""
    frames, T = sim_frames(seed=seed, n_frames=n_frames, noise_px=1.0, miss=0.0, false_pos=0.0, extra_3d=0)
    out = []
    for f in frames:
        b = np.asarray(f.bboxes_2d, dtype=np.float64)
        w, h = b[:, 2] - b[:, 0], b[:, 3] - b[:, 1]
        out.append(Frame(**{**f.__dict__, "bboxes_2d": b + np.column_stack([shrink[0] * w, shrink[1] * h,
                                                                            -shrink[0] * w, -shrink[2] * h])}))
    K = out[0].intrinsics
    cframes, intr, _ = prepare_frames(out, dataclasses.replace(K, fx=K.fx * focal, fy=K.fy * focal))
    pairs = _truth_pairs(out, cframes)
    noise = estimate_noise(cframes, pairs, intr, T[:3, :3], T[:3, 3])
    R, t, *_ = lsq(FitContext(cframes, pairs, intr, Pose(T[:3, :3], T[:3, 3]), noise, 2.0), 60)
    return FitContext(cframes, pairs, intr, Pose(R, t), noise, 2.0, Occlusion())


def test_a_real_focal_error_under_detector_outlines_is_not_explained_by_the_box_model():
    """Boxes shrunk as a detector's outline AND the given focal length 5 % long: the focal scale
    still flags and the box model does not explain it (the positions scale too)."""
    ctx = _focal_ctx(5, 1.05)
    fit = focal_fit(ctx.frames, ctx.pairs, ctx.intr, ctx.pose, ctx.noise, ctx.f_scale, ctx.occlusion)
    chk, msg = focal_scale_check(fit, ctx.intr)
    assert msg is not None and fit.scale < 0.97, chk.detail
    alt, note = focal_box_model(ctx)
    assert alt is None and note == ""


def test_a_focal_flag_the_detector_outline_explains_is_no_focal_misfit():
    """Realism ``detector_all`` site 8 (exact intrinsics; the detector's visible outlines): the
    focal scale fitted x0.970 (jackknife 1.2 %) and was refused as ``misfit_focal_length``; with
    the outline offsets free it is within the tolerance and the focal length stays checkable.
    (The pose is still refused, as poorly constrained.)"""
    import xcalib
    from xcalib.data.synth.realism import make_realism_case

    case = make_realism_case("detector_all", 8, 20)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = xcalib.calibrate(list(case.frames), case.intrinsics_given)
    assert res.diagnostics.refusal not in ("misfit_focal_length", "focal_unverifiable"), res.message
    checks = {c.name: c for c in res.diagnostics.misfit}
    focal = checks["focal_scale"]
    assert not focal.flagged and focal.statistic < 0.975 and "the box model explains it" in focal.detail, focal.detail
    assert not checks["focal_checkable"].flagged, checks["focal_checkable"].detail


def test_a_real_focal_error_the_outline_fits_as_well_stays_a_focal_misfit():
    """Realism focal -5 % (the given fx, fy 5 % short; exact boxes), given as it is, site 9: the
    focal scale fits x1.045, and with the outline offsets free x0.982 -- the outline offsets alone
    fit the boxes as well as the focal scale alone (robust cost 30.1 vs 30.2), so the data cannot
    tell the two apart and the focal misfit stands (a first version cleared it, and only the
    checkability test, at 1.97 sigmas against 2, kept the pose 2 deg / 1 m off refused)."""
    from xcalib.calib.config import CalibConfig
    from xcalib.data.synth.realism import make_realism_case

    import xcalib

    case = make_realism_case("focal-5%", 9, 20)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = xcalib.calibrate(list(case.frames), case.intrinsics_given, CalibConfig(refine_intrinsics="none"))
    assert not res.success and res.diagnostics.refusal == "misfit_focal_length", res.message
    focal = next(c for c in res.diagnostics.misfit if c.name == "focal_scale")
    assert focal.flagged and focal.statistic > 1.03 and "box model explains" not in focal.detail, focal.detail
