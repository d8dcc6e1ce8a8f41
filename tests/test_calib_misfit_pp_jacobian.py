"""Issue 26: the principal-point check on a shift the pose can absorb.

On a wide-angle lens a shift of cx trades off against the camera's rotation (on the horizon line
of an equidistant image a turn of the camera moves every point by the same pixels): the fitted shift
is poorly determined and the frame bootstrap of one draw understates its spread (double sphere 150
deg, site 4 of the camera-model bench, right intrinsics: +31 px at 6 frame-bootstrap sigmas, a
"model misfit"). A flagged shift is now also judged by its sigma from the cost's Jacobian with the
pose free (``misfit._pp_jacobian_sd``); one within ``PP_SIGMAS`` of it is refused as not verifiable
(never delivered: a wrong cx there fits the same), one beyond it stays a misfit.
"""

from __future__ import annotations

import numpy as np
from test_calib_support import sim_frames
from test_calib_uncertainty import _truth_pairs

from xcalib.calib.cost import Occlusion
from xcalib.calib.inputs import prepare_frames
from xcalib.calib.pose import Pose
from xcalib.calib.refine import FitContext, estimate_noise, lsq
from xcalib.types import Frame


def _shifted(dx_frac: float) -> FitContext:
    """12 frames of new objects (1 px noise), every 2D box moved right by ``dx_frac`` of the width (cx
    that far off); the context at the pose fitted from the truth, matches from the truth."""
    frames, T = sim_frames(seed=5, n_frames=12, noise_px=1.0, miss=0.0, false_pos=0.0, extra_3d=0)
    W = frames[0].intrinsics.width
    shifted = [Frame(**{**f.__dict__, "bboxes_2d": np.asarray(f.bboxes_2d) + np.array([dx_frac * W, 0, dx_frac * W, 0])})
               for f in frames]
    cframes, intr, _ = prepare_frames(shifted, shifted[0].intrinsics)
    pairs = _truth_pairs(shifted, cframes)
    noise = estimate_noise(cframes, pairs, intr, T[:3, :3], T[:3, 3])
    R, t, *_ = lsq(FitContext(cframes, pairs, intr, Pose(T[:3, :3], T[:3, 3]), noise, 2.0), 60)
    return FitContext(cframes, pairs, intr, Pose(R, t), noise, 2.0, Occlusion())


def test_the_jacobian_sigma_of_the_principal_point_shrinks_with_more_boxes():
    from xcalib.calib.misfit import _pp_jacobian_sd

    ctx = _shifted(0.0)
    sd = _pp_jacobian_sd(ctx)
    assert sd is not None and np.all(np.isfinite(sd)) and np.all(sd > 0.05) and np.all(sd < 20.0), sd
    half = _pp_jacobian_sd(ctx.with_pairs([p if k % 2 == 0 else p[:0] for k, p in enumerate(ctx.pairs)]))
    assert half is not None and np.all(half > 1.2 * sd), (sd, half)  # half the frames: ~sqrt(2) wider


def test_a_flag_the_jacobian_does_not_support_is_not_verifiable_never_delivered(monkeypatch):
    import xcalib.calib.misfit as misfit

    ctx = _shifted(0.03)  # cx 3 % of the width off: a misfit
    chk, msg = misfit.principal_point_check(ctx)
    assert chk.flagged and msg.startswith("model misfit"), chk.detail
    # the same flag where the Jacobian (pose free) gives the shift a sigma it lies within: the boxes
    # cannot tell -> refused as not verifiable, never passed
    monkeypatch.setattr(misfit, "_pp_jacobian_sd", lambda c: np.array([200.0, 200.0]))
    chk, msg = misfit.principal_point_check(ctx)
    assert chk.flagged and msg.startswith("not verifiable") and "trades off against the camera's rotation" in msg, msg
    assert "cost's Jacobian" in chk.detail and misfit._PP_ASKED in chk.detail, chk.detail
    # a Jacobian sigma below the resamplings' leaves the check as it was
    monkeypatch.setattr(misfit, "_pp_jacobian_sd", lambda c: np.array([0.01, 0.01]))
    chk, msg = misfit.principal_point_check(ctx)
    assert chk.flagged and msg.startswith("model misfit") and "Jacobian" not in chk.detail, chk.detail


def test_a_principal_point_the_boxes_cannot_fix_is_not_verifiable_even_unflagged(monkeypatch):
    """Session 13 (issue 26's wrong success): an unflagged check is judged by what the boxes can
    see. With the rotation free they fix the principal point here to well within the shift that
    turns the camera by ``PP_CHECK_DEG`` (passed, the sigma noted); where they fix it only beyond
    that shift (a wide-angle lens: double sphere 150 deg site 4, cx 3 % off, delivered 4.4 deg off
    with a refitted shift of (-7, +15) px) the same unflagged check refuses as not verifiable."""
    import xcalib.calib.misfit as misfit

    ctx = _shifted(0.0)  # right intrinsics, a pinhole 12-frame scene: passes
    assert not misfit.pp_resolution_applies(ctx.intr)  # a pinhole is not judged by it (session 13 review)
    from xcalib.geometry.camera_models import DoubleSphere, Pinhole
    assert misfit.pp_resolution_applies(DoubleSphere(500.0, 500.0, 320.0, 240.0, 640, 480, xi=-0.2, alpha=0.6))
    assert not misfit.pp_resolution_applies(Pinhole(500.0, 500.0, 320.0, 240.0, 640, 480))
    assert misfit.principal_point_resolution(ctx, misfit.principal_point_check_all(ctx)[0])[1] is None
    monkeypatch.setattr(misfit, "pp_resolution_applies", lambda intr: True)  # the rule as on a wide-angle model
    chk, msg = misfit.principal_point_check(ctx)  # passes, the pose-free sigma noted
    need = misfit._pp_need(ctx.intr)
    assert msg is None and not chk.flagged and "with the camera's rotation free" in chk.detail, chk.detail
    sd = misfit._pp_jacobian_sd(ctx)
    assert float(sd[0]) < misfit.PP_RESOLUTION_SIGMAS * need, (sd, need)
    # the same boxes where the pose-free sigma of cx is beyond the 1-degree shift: not verifiable
    monkeypatch.setattr(misfit, "_pp_jacobian_sd", lambda c: np.array([1.5 * need, 0.2 * need]))
    chk, msg = misfit.principal_point_check(ctx)
    assert chk.flagged and msg.startswith("not verifiable") and "fix cx only" in msg, msg
    assert misfit._PP_ASKED in chk.detail and "1.50 x" in chk.detail, chk.detail
    # just within it (and no Jacobian at all): passed
    monkeypatch.setattr(misfit, "_pp_jacobian_sd", lambda c: np.array([0.2 * need, 0.99 * need]))
    assert misfit.principal_point_check(ctx)[1] is None
    # cy's sigma alone is not judged (box-shape biases widen it on any lens; the wide-angle degeneracy is cx's)
    monkeypatch.setattr(misfit, "_pp_jacobian_sd", lambda c: np.array([0.5 * need, 3.0 * need]))
    assert misfit.principal_point_check(ctx)[1] is None
    monkeypatch.setattr(misfit, "_pp_jacobian_sd", lambda c: None)
    assert misfit.principal_point_check(ctx)[1] is None


def test_the_border_look_clears_a_not_verifiable_principal_point_only_below_the_one_degree_shift(monkeypatch):
    """Session 13: unified 150 deg bench site 2, cx 3 % of the width off: all boxes' shift was not
    verifiable (the objects' scatter), the boxes inside the image fitted (-18, +2) px, below the
    tolerance but beyond the 16 px that turn the camera 1 deg, which cleared it: delivered 5.2 deg
    off. Fewer boxes cannot verify what all of them could not: such a verdict now stands unless the
    inner boxes ask for less than the 1-degree shift (then cleared, and judged by the pose-free sigma)."""
    import xcalib.calib.misfit as misfit
    from xcalib.calib.diagnostics import MisfitCheck

    ctx = _shifted(0.0)
    monkeypatch.setattr(misfit, "pp_resolution_applies", lambda intr: True)  # judged as on a wide-angle model
    need = misfit._pp_need(ctx.intr)
    W = ctx.frames[0].size[0]
    all_boxes = (MisfitCheck("principal_point", 19.0, misfit.PP_TOL_FRAC * W, True, "objects scatter"),
                 "not verifiable: the 138 matches come from 12 distinct objects")
    inner = {"stat": 1.1 * need, "detail": "inner"}

    def fake_all(c, **kw):
        if sum(len(p) for p in c.pairs) == sum(len(p) for p in ctx.pairs):
            return all_boxes
        return MisfitCheck("principal_point", inner["stat"], misfit.PP_TOL_FRAC * W, False, inner["detail"]), None

    monkeypatch.setattr(misfit, "principal_point_check_all", fake_all)
    monkeypatch.setattr(misfit, "inner_pairs", lambda frames, pairs: [p[1:] for p in pairs])  # some border boxes
    chk, msg = misfit.principal_point_check(ctx)
    assert chk.flagged and msg == all_boxes[1], (chk.detail, msg)
    inner["detail"] = "inner; " + misfit._PP_BOX_EXPLAINS  # a shift the outline offsets explain: cleared as before
    chk, msg = misfit.principal_point_check(ctx)
    assert msg is None and not chk.flagged, chk.detail
    inner["detail"] = "inner"
    inner["stat"] = 0.5 * need  # the inner boxes ask for less than the 1-degree shift: cleared
    chk, msg = misfit.principal_point_check(ctx)
    assert msg is None and not chk.flagged and chk.detail.startswith("without the"), chk.detail
    assert "with the camera's rotation free" in chk.detail, chk.detail  # judged by the pose-free sigma too
    monkeypatch.setattr(misfit, "_pp_jacobian_sd", lambda c: np.array([2.0 * need, 0.1]))
    chk, msg = misfit.principal_point_check(ctx)
    assert chk.flagged and msg.startswith("not verifiable: these detections cannot check"), msg


def test_an_estimated_focal_length_is_refitted_with_the_principal_point_before_the_check(monkeypatch):
    """Session 14 (issue 26's last wrong success): unified 150 deg bench site 3, cx given 3 % of the
    width off: "auto" estimated the focal length with the wrong cx (905.7 px, true 921.6), which took
    up part of the error with the pose (4.8 deg off); the check, holding that focal length, fitted
    (-16.6, +5.7) px, below the tolerance, and the pose was delivered. When the focal length was
    estimated (``focal_free``) the check is judged at the focal length fitted jointly with the
    principal point (``pp_focal_centred``): there (-41, +1) px, a misfit. Here a pinhole scene, its
    focal length fitted with the pose at the given cx (the way "auto" estimates it). The check at the
    estimated focal length still runs first (its flag stands: each refit starts from the calibration's
    pose and the robust cost is not convex, realism principal point +3 % W site 19)."""
    from dataclasses import replace

    import xcalib.calib.misfit as misfit
    from xcalib.calib.cost import FocalScaleTerm

    def absorbed(frac):  # the focal length (and pose) fitted at the given cx, as self-calibration does
        ctx = _shifted(frac)
        *_, fit = lsq(ctx, 100, extra=(FocalScaleTerm(),))
        s = float(np.exp(fit.params[FocalScaleTerm.name][0]))
        return ctx.intr.fx, replace(ctx, intr=replace(ctx.intr, fx=ctx.intr.fx * s, fy=ctx.intr.fy * s), pose=fit.pose)

    fx_true, ctx = absorbed(0.03)  # cx 3 % off: the focal length took up part of it
    assert abs(ctx.intr.fx / fx_true - 1) > 0.003, ctx.intr.fx
    centred, note = misfit.pp_focal_centred(ctx)
    assert abs(centred.intr.fx / fx_true - 1) < 0.001 and "judged at the focal length fitted" in note, (centred.intr, note)
    chk, msg = misfit.principal_point_check(ctx, focal_free=True)  # flagged at the estimated focal already
    assert chk.flagged and msg.startswith("model misfit"), chk.detail
    real = misfit.principal_point_check_looks

    def passes_at_the_absorbed_focal(c, **kw):  # as on unified 150 site 3: the held focal hid the shift
        if c.intr.fx == ctx.intr.fx:
            return replace(real(c, **kw)[0], flagged=False, detail="held: within the tolerance"), None
        return real(c, **kw)

    monkeypatch.setattr(misfit, "principal_point_check_looks", passes_at_the_absorbed_focal)
    assert misfit.principal_point_check(ctx)[1] is None  # without focal_free: judged as before
    chk, msg = misfit.principal_point_check(ctx, focal_free=True)  # the centred focal's flag stands
    assert chk.flagged and msg.startswith("model misfit") and note in chk.detail and "held:" in chk.detail, chk.detail
    # only the second look's decisive verdict adds a refusal: a "not verifiable" there does not (realism
    # detector_outline 0, 3, 11: right pinhole poses, the objects' scatter at the refitted focal length)
    monkeypatch.setattr(misfit, "principal_point_check_looks", lambda c, **kw: (
        passes_at_the_absorbed_focal(c, **kw) if c.intr.fx == ctx.intr.fx else
        (replace(real(c, **kw)[0], flagged=True, detail="scatter"), "not verifiable: the 9 matches come from 3 objects")))
    chk, msg = misfit.principal_point_check(ctx, focal_free=True)
    assert msg is None and not chk.flagged and "not verifiable there (scatter)" in chk.detail, chk.detail
    monkeypatch.undo()
    fx_true, ctx = absorbed(0.0)  # right intrinsics: the focal length hardly moves, the check passes
    centred, _ = misfit.pp_focal_centred(ctx)
    assert abs(centred.intr.fx / fx_true - 1) < 0.003, centred.intr
    chk, msg = misfit.principal_point_check(ctx, focal_free=True)
    assert msg is None and not chk.flagged and "judged at the focal length fitted" in chk.detail, chk.detail
