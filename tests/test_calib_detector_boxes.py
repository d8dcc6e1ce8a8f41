"""The box observation model for real detectors (issue 25 item 1-2).

Seeded box-level scenes (``test_calib_support``), matches from the truth, no search:

* the detector-outline offsets (``boxmodel.outline_edge_term``) recover a detector's tight boxes
  (2D boxes shrunk by a share of their size) and keep the pose;
* the box-model floor counts the corner outline by its posterior weight (``box_model_odds``);
* the principal-point check tests the box model before it blames the intrinsics: 2D boxes whose
  tops sit inside the projected outline are no principal-point misfit, a shifted cx still is;
* yawed 3D boxes with a cloud get point-hull outlines for the boxes in view (``with_point_outlines``).
"""

from __future__ import annotations

import dataclasses

import numpy as np
from test_calib_support import sim_frames
from test_calib_uncertainty import _truth_pairs

from xcalib.calib.boxmodel import fit_outline
from xcalib.calib.cost import Occlusion
from xcalib.calib.inputs import prepare_frames, with_point_outlines
from xcalib.calib.misfit import principal_point_check
from xcalib.calib.pose import Pose
from xcalib.calib.refine import FitContext, estimate_noise, lsq
from xcalib.calib.uncertainty import box_model_odds


def _shrunk(frames, sides: float, top: float, bottom: float, dx_px: float = 0.0):
    """The frames with each 2D box moved in by shares of its size (a detector's visible outline)
    and shifted right by ``dx_px`` (a principal point off by that much)."""
    out = []
    for f in frames:
        b = np.asarray(f.bboxes_2d, dtype=np.float64).copy()
        w, h = b[:, 2] - b[:, 0], b[:, 3] - b[:, 1]
        b += np.column_stack([sides * w, top * h, -sides * w, -bottom * h]) + np.array([dx_px, 0, dx_px, 0])
        out.append(dataclasses.replace(f, bboxes_2d=b.astype(np.float32)))
    return out


def _setup(frames, T):
    cframes, intr, _ = prepare_frames(frames, frames[0].intrinsics)
    pairs = _truth_pairs(frames, cframes)
    noise = estimate_noise(cframes, pairs, intr, T[:3, :3], T[:3, 3])
    return cframes, pairs, intr, noise


def test_outline_offsets_recover_a_detectors_tight_boxes_and_keep_the_pose():
    frames, T = sim_frames(seed=3, n_frames=6, noise_px=1.0, miss=0.0, false_pos=0.0, extra_3d=0)
    det = _shrunk(frames, 0.06, 0.08, 0.02)
    cframes, pairs, intr, noise = _setup(det, T)
    truth = Pose(T[:3, :3], T[:3, 3])
    fit = fit_outline(cframes, pairs, intr, truth, noise, 2.0, Occlusion())
    assert abs(fit["sides"] - 0.06) < 0.02 and abs(fit["top"] - 0.08) < 0.03 and abs(fit["bottom"] - 0.02) < 0.03
    assert fit["pose_shift"][0] < 0.2 and fit["pose_shift"][1] < 0.2
    assert all(s > 0 for s in fit["sd"])
    clean = fit_outline(*_setup(frames, T)[:3], truth, noise, 2.0, Occlusion())
    assert max(abs(clean[k]) for k in ("sides", "top", "bottom")) < 0.02  # exact boxes: nothing to fit


def test_outline_fit_is_shared_by_the_uncertainty_and_the_diagnostics_bit_for_bit():
    # issue 29: the calibration reads ``uncertainty.outline_fit``'s refit (cached on the context) instead of
    # refitting the same offsets in ``fit_outline``: the same dict, the fit made once per context
    import pickle

    from xcalib.calib.uncertainty import outline_fit

    frames, T = sim_frames(seed=3, n_frames=6, noise_px=1.0, miss=0.0, false_pos=0.0, extra_3d=0)
    cframes, pairs, intr, noise = _setup(_shrunk(frames, 0.06, 0.08, 0.02), T)
    truth = Pose(T[:3, :3], T[:3, 3])
    ctx = FitContext(cframes, pairs, intr, truth, noise, 2.0, Occlusion())
    shared = outline_fit(ctx)
    assert outline_fit(ctx) is shared  # once per context
    assert fit_outline(cframes, pairs, intr, truth, noise, 2.0, Occlusion(), shared) == \
        fit_outline(cframes, pairs, intr, truth, noise, 2.0, Occlusion())
    moved = ctx.with_pose(truth.moved(np.array([1e-3, 0, 0]), np.zeros(3)))
    assert outline_fit(moved) is not shared and not np.array_equal(outline_fit(moved)[1].x, shared[1].x)
    again = pickle.loads(pickle.dumps(ctx))  # a worker's copy: the fields, not the cached fit
    assert not again._results and again.f_scale == ctx.f_scale and again.pose.error(ctx.pose) == (0.0, 0.0)


def test_outline_offsets_jacobian_is_analytic_and_matches_central_differences():
    # issue 29: the outline-offset fits (common and per kind) ran scipy with "2-point" Jacobians; their
    # term now gives its derivative (pose, offsets, occlusion shaping, prior rows)
    from xcalib.calib.boxmodel import kind_outline_edge_term, outline_edge_term
    from xcalib.calib.cost import FocalScaleTerm, PrincipalPointTerm
    from xcalib.calib.refine import build_cost

    frames, T = sim_frames(seed=3, n_frames=6, noise_px=1.0, miss=0.0, false_pos=0.0, extra_3d=0)
    cframes, pairs, intr, noise = _setup(_shrunk(frames, 0.06, 0.08, 0.02), T)
    truth = Pose(T[:3, :3], T[:3, 3])
    rng = np.random.default_rng(0)
    for edge, extra in ((outline_edge_term, ()), (kind_outline_edge_term(), ()), (outline_edge_term, (FocalScaleTerm(),)),
                        (outline_edge_term, (PrincipalPointTerm(),))):  # the misfit checks' refits too
        for occl in (Occlusion(), None):
            model = build_cost(cframes, pairs, intr, truth, noise, occl, extra, edge=edge)
            assert model.has_analytic_jacobian()
            x = np.concatenate([rng.normal(0, 2e-3, 6), rng.normal(0, 0.05, model.n_params - 6)])
            J = model.analytic_jacobian(x)
            num = np.column_stack([(model.residuals(x + d) - model.residuals(x - d)) / 2e-7
                                   for d in np.eye(model.n_params) * 1e-7])
            assert J.shape == num.shape and np.abs(J[:, 6:]).max() > 1.0  # the offsets' columns are filled
            assert np.allclose(J, num, rtol=1e-5, atol=1e-4)


def test_box_model_odds_weigh_the_corner_outline_by_the_evidence_per_object():
    assert box_model_odds(100.0, 100.0, 120, 30) == 0.5  # equally good: half the shift counts, as before
    assert box_model_odds(100.0, 300.0, 120, 30) < 1e-6  # corners far worse: the floor vanishes
    # the same cost difference spread over few objects is weaker evidence
    assert box_model_odds(100.0, 110.0, 120, 30) < box_model_odds(100.0, 110.0, 120, 4) < 0.5
    assert box_model_odds(110.0, 100.0, 120, 30) > 0.5


def test_principal_point_check_tests_the_box_model_before_blaming_the_intrinsics():
    frames, T = sim_frames(seed=5, n_frames=6, noise_px=1.0, miss=0.0, false_pos=0.0, extra_3d=0)
    truth = Pose(T[:3, :3], T[:3, 3])
    W = frames[0].intrinsics.width
    tops = _shrunk(frames, 0.05, 0.15, 0.0)  # roofs inset: a vertical bias a principal point can mimic
    cframes, pairs, intr, noise = _setup(tops, T)
    R, t, *_ = lsq(FitContext(cframes, pairs, intr, truth, noise, 2.0), 60)
    chk, msg = principal_point_check(FitContext(cframes, pairs, intr, Pose(R, t), noise, 2.0, Occlusion()))
    assert msg is None and not chk.flagged, chk.detail
    cropped = _shrunk(frames, 0.0, 0.0, 0.0, dx_px=0.08 * W)  # a principal point 8 % W off stays a misfit
    cframes, pairs, intr, noise = _setup(cropped, T)
    R, t, *_ = lsq(FitContext(cframes, pairs, intr, truth, noise, 2.0), 60)
    chk, msg = principal_point_check(FitContext(cframes, pairs, intr, Pose(R, t), noise, 2.0, Occlusion()))
    assert chk.flagged and "principal point" in msg


def test_yawed_boxes_with_a_cloud_get_point_hulls_for_the_boxes_in_view():
    frames, T = sim_frames(seed=2, n_frames=1, noise_px=0.0, miss=0.0, false_pos=0.0, extra_3d=0)
    f = frames[0]
    from xcalib.geometry.boxes import as_box7

    b7 = as_box7(f.bboxes_3d)
    rng = np.random.default_rng(0)
    # points on each box's sides (a LiDAR sees the outline), inset 10 % from the corners
    pts = np.concatenate([b[:3] + (rng.uniform(-0.45, 0.45, (200, 3)) * b[3:6]) @ np.array(
        [[np.cos(b[6]), np.sin(b[6]), 0], [-np.sin(b[6]), np.cos(b[6]), 0], [0, 0, 1]]) for b in b7])
    cframes, intr, _ = prepare_frames([dataclasses.replace(f, point_cloud=pts.astype(np.float32))], f.intrinsics)
    assert not cframes[0].from_points.any()  # boxes with a yaw: corners first
    view = np.zeros(cframes[0].n3, dtype=bool)
    view[:3] = True
    alt = with_point_outlines(cframes, [view])
    assert alt is not None and alt[0].from_points[:3].all() and not alt[0].from_points[3:].any()
    # a hull of points inside the box lies within its corners' extent
    j = 0
    c = alt[0].corners[j] - cframes[0].boxes3d[j, :3]
    assert np.abs(c[:, :2]).max() < np.abs(cframes[0].box_corners[j] - cframes[0].boxes3d[j, :3])[:, :2].max() + 1e-6
    assert with_point_outlines([dataclasses.replace(cframes[0], points=None)], [view]) is None


def test_box_fit_and_floor_weights_survive_the_diagnostics_round_trip():
    from xcalib.calib.diagnostics import CalibDiagnostics, UncertaintyParts

    d = CalibDiagnostics(box_fit={"outline": "corners+points", "sides": 0.05, "top": 0.09, "bottom": 0.0,
                                  "sd": [0.01, 0.01, 0.01], "pose_shift": [0.1, 0.05], "n_pairs": 40},
                         uncertainty=UncertaintyParts(box_model={"weight_corners": 0.07, "shift": [0.0] * 6}))
    back = CalibDiagnostics.from_dict(d.to_dict())
    assert back.box_fit["top"] == 0.09 and back.uncertainty.box_model["weight_corners"] == 0.07
    assert CalibDiagnostics.from_dict({}).box_fit == {}  # results written before: no box fit


def _advice(message: str) -> dict:
    import re

    return dict(re.findall(r"(refine_intrinsics|time_offset)='([a-z+]+)'", message or ""))


def _follow(frames, intr, steps: int = 3):
    """Calibrate, then follow each refusal's advice (the options it names) up to ``steps`` times;
    the chain of (options, success, refusal code)."""
    from xcalib.calib.api import calibrate
    from xcalib.calib.config import CalibConfig

    opts, chain = {}, []
    res = calibrate(frames, intr)
    chain.append(({}, res.success, res.diagnostics.refusal))
    while not res.success and len(chain) <= steps:
        new = {k: v for k, v in _advice(res.message).items() if opts.get(k) != v}
        if not new:
            break
        opts = {**opts, **new}
        res = calibrate(frames, intr, CalibConfig(**opts))
        chain.append((dict(opts), res.success, res.diagnostics.refusal))
    return chain


def test_following_a_refusals_advice_never_leads_back_to_the_same_refusal():
    """Issue 25 item 2, on the realism conditions whose refusals advise an option (a cropped image:
    principal point; unsynchronised sensors: time offset)."""
    from xcalib.data.synth.realism import make_realism_case

    for cond, seed in (("principal_point+3%W", 2), ("time_offset_0.1s", 2)):
        case = make_realism_case(cond, seed, n_frames=12)
        chain = _follow(list(case.frames), case.intrinsics_given)
        codes = [c for _, ok, c in chain if not ok]
        assert len(codes) == len(set(codes)), (cond, chain)  # no refusal comes back
        if cond.startswith("principal"):
            assert not chain[0][1], (cond, chain)  # the bent site is refused first
        else:  # timestamped frames out of time: the default run estimates the offset and delivers
            assert chain == [({}, True, "")], (cond, chain)


def test_a_significant_time_offset_is_estimated_and_delivered_by_default():
    """Deliver when the data allow (issue 25): timestamped frames whose time-offset misfit check finds
    the sensors out of time are calibrated with the offset estimated, and the result says so."""
    from xcalib.calib.api import calibrate
    from xcalib.calib.diagnostics import CalibDiagnostics
    from xcalib.data.synth.realism import make_realism_case

    case = make_realism_case("time_offset_0.05s", 0, n_frames=12)
    res = calibrate(list(case.frames), case.intrinsics_given)
    assert res.success, res.message
    sc = res.diagnostics.selfcal
    assert sc.time_offset_source == "estimated" and sc.time_offset_mode == "auto"
    assert abs(res.time_offset_s - case.time_offset_s) < 3 * res.time_offset_std_s + 1e-3
    assert sc.time_offset_trigger.startswith("misfit_time_offset")
    deg, m = res.pose_error(case.T_cam_lidar)
    assert deg < 0.3 and m < 0.15
    text = res.summary()
    assert "time offset" in text and "out of time" in text  # the offset and why: in the summary
    back = CalibDiagnostics.from_dict(res.diagnostics.to_dict())
    assert back.selfcal.time_offset_trigger == sc.time_offset_trigger
    # without timestamps (frame indices only) the offset is not estimated on its own
    bare = [dataclasses.replace(f, lidar_time_s=None, camera_time_s=None) for f in case.frames]
    res = calibrate(bare, case.intrinsics_given)
    assert res.diagnostics.selfcal.time_offset_trigger == ""



def _objects_with_own_outlines(seed: int, n_frames: int, mean, sd):
    """One frame's objects seen again in ``n_frames`` frames (fresh 1 px box noise per frame), each
    2D box moved in by its object's own shares (width, top, bottom) drawn around ``mean`` with
    1-sigma ``sd``: a detector's visible outline, the same car alike over the frames, car to car different."""
    from xcalib.types import Frame

    base, T = sim_frames(seed=seed, n_frames=1, n_objects=(14, 20), noise_px=0.0, miss=0.0, false_pos=0.0,
                         extra_3d=0)
    rng = np.random.default_rng(seed)
    f0 = base[0]
    b = np.asarray(f0.bboxes_2d, dtype=np.float64)
    w, h = b[:, 2] - b[:, 0], b[:, 3] - b[:, 1]
    sh = np.asarray(mean) + np.asarray(sd) * rng.normal(size=(len(b), 3))
    b = b + np.column_stack([sh[:, 0] * w / 2, sh[:, 1] * h, -sh[:, 0] * w / 2, -sh[:, 2] * h])
    frames = [Frame(**{**f0.__dict__, "frame_key": f"{k:04d}", "bboxes_2d": (b + rng.normal(0, 1.0, b.shape))})
              for k in range(n_frames)]
    return frames, T



def _plain_and_object_outline_fit(seed: int, shared: tuple):
    """A seeded scene whose objects each have their own outline error (and ``shared`` common
    offsets): the pose fitted without per-object offsets from the truth, and the random-effects fit."""
    from xcalib.calib.boxmodel import fit_object_outline
    from xcalib.calib.uncertainty import object_groups

    frames, T = _objects_with_own_outlines(seed, 8, shared, (0.06, 0.06, 0.03))
    truth = Pose(T[:3, :3], T[:3, 3])
    cframes, pairs, intr, noise = _setup(frames, T)
    R, t, *_ = lsq(FitContext(cframes, pairs, intr, truth, noise, 2.0), 60)
    plain = Pose(R, t)
    fit = fit_object_outline(cframes, pairs, intr, plain, noise, 2.0, Occlusion(), object_groups(cframes, pairs))
    return cframes, pairs, intr, noise, truth, plain, fit


def test_each_objects_own_outline_is_a_random_effect_fitted_only_where_objects_differ():
    from xcalib.calib.boxmodel import fit_object_outline
    from xcalib.calib.uncertainty import object_groups

    errs = []
    for seed in (1, 2, 3):
        _, pairs, _, _, truth, plain, fit = _plain_and_object_outline_fit(seed, (0.08, 0.08, 0.02))
        assert fit is not None and fit.p_value < 1e-3 and fit.n_objects >= len(pairs[0]) - 2  # neighbours within 1.5 m: one
        assert fit.tau.max() > 0.02 and np.all(fit.sd > 0) and fit.offsets.shape == (fit.n_objects, 4)
        errs.append((plain.error(truth)[1], fit.pose.error(truth)[1]))
        rec = fit.summary(plain)
        assert set(rec["tau"]) == {"left", "top", "right", "bottom"} and len(rec["pose_shift"]) == 2
    plain_m, re_m = np.mean(errs, axis=0)
    assert re_m < plain_m, errs  # the objects' own outlines no longer pull the camera along its view
    # exact boxes: the objects do not differ beyond the noise, nothing is fitted (the pose stays)
    frames, T = _objects_with_own_outlines(1, 8, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    cframes, pairs, intr, noise = _setup(frames, T)
    truth = Pose(T[:3, :3], T[:3, 3])
    assert fit_object_outline(cframes, pairs, intr, truth, noise, 2.0, Occlusion(), object_groups(cframes, pairs)) is None


def test_object_outline_sigma_taken_per_axis_as_the_larger_and_kept_in_the_parts():
    from xcalib.calib.diagnostics import CalibDiagnostics, UncertaintyParts
    from xcalib.calib.uncertainty import Uncertainty, with_object_outline

    unc = Uncertainty(np.array([0.1, 0.2, 0.3]), np.array([0.05, 0.05, 0.4]), UncertaintyParts(), True,
                      np.array([0.1, 0.1, 0.1]), np.array([0.02, 0.02, 0.02]))
    out = with_object_outline(unc, [0.2, 0.1, 0.1, 0.1, 0.01, 0.1])
    assert np.allclose(out.rot_sd, [0.2, 0.2, 0.3]) and np.allclose(out.tr_sd, [0.1, 0.05, 0.4])
    assert np.allclose(out.rot_sd_data, [0.1, 0.1, 0.1]) and np.allclose(out.tr_sd_data, [0.02] * 3)  # verdict's: kept
    assert out.parts.object_outline == [0.2, 0.1, 0.1, 0.1, 0.01, 0.1]
    back = CalibDiagnostics.from_dict(CalibDiagnostics(uncertainty=out.parts).to_dict())
    assert back.uncertainty.object_outline == out.parts.object_outline
    assert CalibDiagnostics.from_dict({}).uncertainty.object_outline is None  # results written before


def test_summary_names_the_objects_own_outlines_when_fitted():
    from xcalib.calib.diagnostics import CalibDiagnostics
    from xcalib.calib.result import CalibrationResult

    bf = {"outline": "corners", "sides": 0.05, "top": 0.09, "bottom": 0.0,
          "objects": {"tau": {"left": 0.03, "top": 0.07, "right": 0.03, "bottom": 0.02}, "p_value": 1e-20,
                      "n_objects": 13, "sd": [0.1] * 6, "pose_shift": [0.35, 0.42]}}
    res = CalibrationResult(success=True, rotation=np.eye(3), translation=np.zeros(3),
                            diagnostics=CalibDiagnostics(box_fit=bf))
    text = res.summary()
    assert "own outlines" in text and "13 objects" in text and "0.42 m" in text
    bf.pop("objects")
    assert "own outlines" not in CalibrationResult(success=True, rotation=np.eye(3), translation=np.zeros(3),
                                                   diagnostics=CalibDiagnostics(box_fit=bf)).summary()


def test_hausman_test_uses_the_scatter_of_the_difference_not_of_one_fit():
    """Site-14-like (realism detector_all, site 14: the plain pose 0.37 deg / 0.63 m off, d^2 15.3 against
    the random-effects fit's own covariance, under the 16.8 line): the two fits' difference scatters
    with ``cov_plain - cov`` (Hausman), much less than either fit, so the same move is significant."""
    from xcalib.calib.boxmodel import ObjectOutlineFit

    pose0 = Pose(np.eye(3), np.zeros(3))
    cov = np.diag([1e-6] * 3 + [1e-2] * 3)  # rad^2, m^2
    d = np.array([0.0, 0.0, 0.0, 0.1, 0.2, 0.3])  # 1.4 sigma per metre axis of this fit: d^2 14 < 16.8
    moved = pose0.moved(d[:3], d[3:])
    old = ObjectOutlineFit(moved, np.zeros(6), np.zeros(4), 0.0, 8, np.zeros((8, 4)), cov)
    assert old.shift_d2(pose0)[1] == 6 and abs(old.shift_d2(pose0)[0] - 14.0) < 1e-6
    assert not old.shift_significant(pose0)  # without cov_plain: the one-fit stand-in
    new = dataclasses.replace(old, cov_plain=1.5 * cov)  # the plain fit scatters 1.5x: the difference 0.5x
    d2, dof = new.shift_d2(pose0)
    assert dof == 6 and abs(d2 - 28.0) < 1e-6 and new.shift_significant(pose0)
    # where the two fits agree by construction (no difference in scatter), that direction is dropped
    same_z = dataclasses.replace(old, cov_plain=cov + np.diag([1e-6] * 3 + [1e-2, 1e-2, 0.0]))
    assert same_z.shift_d2(pose0)[1] == 5
    assert new.summary(pose0)["shift_dof"] == 6 and new.summary(pose0)["applied"]
    # a move in 2 directions only, d^2 12 (beyond chi-square(2) 99 %, 9.2): judged against the 6-dof point
    # (16.8) whatever the rank -- A9 detector 12-frame subsets moved so ended > 0.5 m from the labelled pose
    low = dataclasses.replace(old, pose=pose0.moved(np.zeros(3), np.array([0.2, 0.2 * np.sqrt(2), 0.0])),
                              cov_plain=cov + np.diag([0.0] * 3 + [1e-2, 1e-2, 0.0]))
    d2, dof = low.shift_d2(pose0)
    assert dof == 2 and abs(d2 - 12.0) < 1e-6 and not low.shift_significant(pose0)


def test_the_plain_poses_sigma_counts_the_objects_own_outlines():
    """The pose fitted without per-object outline offsets takes each object's outline error as noise
    of independent edges; under the random effects the objects' edges share it (``sd_plain``): its
    error then lies within 2 ``sd_plain`` per axis, where the Jacobian sigma is 2-3x too small."""
    from xcalib.calib.uncertainty import pose_covariance

    z_plain, z_jac = [], []
    for seed in (0, 4, 7):
        cframes, pairs, intr, noise, truth, plain, fit = _plain_and_object_outline_fit(seed, (0.0, 0.0, 0.0))
        assert fit is not None and fit.cov_plain is not None and np.all(fit.sd_plain > 0)
        rs, ts, _ = pose_covariance(cframes, pairs, intr, plain.R, plain.t, noise=noise)
        err = np.abs(plain.delta(truth))
        z_plain.append(err / fit.sd_plain)
        z_jac.append(err / np.concatenate([rs, ts]))
    z_plain, z_jac = np.array(z_plain), np.array(z_jac)
    assert np.mean(z_plain <= 2) >= 0.9, z_plain
    assert np.sqrt(np.mean(z_jac ** 2)) > 1.5 * np.sqrt(np.mean(z_plain ** 2)), (z_jac, z_plain)
