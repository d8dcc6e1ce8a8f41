"""Issue 12 item 3 (verdict): realism cases that the 0.4.0 verdict reported as wrong successes
are refused with the cause named, and the clean site of the same seed is not (seeded,
``xcalib.data.synth.realism``; one calibration each)."""

from __future__ import annotations

import warnings

import pytest

from xcalib.calib.api import calibrate
from xcalib.data.synth.realism import make_realism_case


def _calibrate(condition: str, seed: int):
    case = make_realism_case(condition, seed, 20)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return case, calibrate(list(case.frames), case.intrinsics_given)


@pytest.mark.parametrize("condition, seed, code, cause", [
    # 0.4.0: success 33 deg / 2.0 m off -- the pose latched onto the second camera's boxes
    ("second_camera_all", 7, "misfit_mixed_cameras", "more than one camera"),
    # 0.4.0: success 0.08 deg / 0.56 m off (offset found, but it moved the objects < 0.3 m); since
    # the offset is estimated by default where the check finds one: a success 0.05 deg / 0.015 m off
    ("time_offset_0.05s", 4, "misfit_time_offset", "out of time"),
    # 0.4.0: success 1.6 deg / 0.9 m off (the offset fit started at 0 stayed there)
    ("time_offset_0.05s", 19, "misfit_time_offset", "out of time"),
    # 0.4.0: success 1.9 deg / 0.24 m off -- "auto" fitted the focal x0.975 to a principal-point error
    # (5 distinct places: the focal's 1-sigma is now widened for repeated objects, the given focal kept).
    # Its 5 parked objects cannot check the intrinsics (the clean site fits the same principal-point
    # shift; leaving one object out moves it ~180 px): refused as not verifiable, never a success
    ("principal_point+3%W", 9, "focal_unverifiable", "not verifiable"),
    # 0.4.0: success 2.6 deg / 1.9 m off -- "auto" fitted the focal x0.907 from 67 matches at 5 places
    ("queues", 9, "misfit_focal_length", "distinct places"),
])
def test_wrong_realism_case_is_refused_with_its_cause(condition, seed, code, cause):
    case, res = _calibrate(condition, seed)
    if code == "misfit_time_offset" and res.success:
        # deliver when the data allow: the timestamped frames' offset, estimated, gives the right pose
        assert res.diagnostics.selfcal.time_offset_trigger.startswith(code), res.message
        assert abs(res.time_offset_s - case.time_offset_s) < 0.005 and cause in res.message
        rot, trans = res.pose_error(case.T_cam_lidar)
        assert rot < 0.3 and trans < 0.15, (rot, trans)
        return
    assert not res.success
    assert res.diagnostics.refusal == code, res.message
    assert cause in res.message
    flagged = [c.name for c in res.diagnostics.misfit if c.flagged]
    assert flagged, res.diagnostics.misfit


def test_second_pose_check_passes_the_clean_site():
    case, res = _calibrate("clean", 7)
    assert res.success, res.message
    checks = {c.name: c for c in res.diagnostics.misfit}
    sp = checks["second_pose"]  # searched: a share below 0.1; or not searched (issue 29): its bound below the limit
    assert not sp.flagged and (sp.statistic < 0.1 or (sp.detail.startswith("not searched") and sp.statistic < sp.limit))
    assert not checks["time_offset"].flagged
    rot, trans = res.pose_error(case.T_cam_lidar)
    assert rot < 0.2 and trans < 0.1


@pytest.mark.parametrize("condition", ["principal_point+3%W", "time_offset_0.05s"])
def test_three_object_site_is_refused_as_unverifiable(condition):
    """0.5.0 (before the objects check): success 1.6 deg / 0.55 m (principal point) and 2.3 deg /
    1.8 m (time offset) off at site 20, whose 37 matches come from 3 objects."""
    case, res = _calibrate(condition, 20)
    assert case.objects_seen == 3
    assert not res.success
    assert res.diagnostics.refusal == "few_objects", res.message
    assert "3 distinct object" in res.message and res.rotation is None


def test_principal_point_fit_far_outside_the_image_does_not_raise():
    """0.5.0 raised ValueError from the principal-point check: a trial step of its fit put (cx, cy)
    at (677, -599) on a 1920x1200 image (roadside site 35, 0.5 px, the search retried without the
    baseline). Bad fits must end in a result, never an exception."""

    from xcalib.data.synth import generate_frames, sample_site

    site = sample_site(35, preset="roadside")
    frames = generate_frames(site, 20, seed=35, render_images=False, lidar=False, miss_rate_2d=0.1,
                             false_positive_rate_2d=0.05, box_noise_px=0.5, center_noise_m=0.0,
                             size_noise_frac=0.0, yaw_noise_deg=0.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = calibrate(frames, frames[0].intrinsics)
    assert isinstance(res.success, bool)
    if res.success:
        rot, trans = res.pose_error(frames[0].extrinsics)
        assert rot < 1.0 and trans < 0.5
    else:
        assert res.message and res.rotation is None


def test_principal_point_refusal_at_a_queue_says_the_places_are_few():
    """Queue site 9 (66 matches at 5 places): the exact intrinsics fit a principal point shift of
    80 px, a real 3 % W error 76 px -- refused either way. Since the check counts each object once
    (issue 25: leaving one of the 5 objects out moves the fit by ~180 px) the refusal no longer
    blames the intrinsics: not verifiable, the objects too few, add frames with other objects."""
    case, res = _calibrate("clean", 9)
    assert not res.success and res.rotation is None
    assert res.diagnostics.refusal == "principal_point_unverifiable", res.message
    assert "5 distinct objects" in res.message and "Add frames in which other objects pass" in res.message
    chk = next(c for c in res.diagnostics.misfit if c.name == "principal_point")
    assert "leaving objects out (5 objects)" in chk.detail


def test_focal_length_the_detections_cannot_check_is_refused():
    """0.5.0 with 8 px 2D noise (a real detector's; A9 fits ~8 px): at site 16 (5 objects, ~35 m
    away) focal -5 % was a success 0.7 deg / 1.5 m off with a 1-sigma of 0.58 m -- the detections
    fit the focal x1.053 +- 3.8 %, too wide to flag it. Now refused as not verifiable, naming the
    pose shift a 5 % focal error would cause (a deterministic jackknife spread: no seed decides)."""
    import dataclasses

    from xcalib.data.synth.realism import REALISM_CONDITIONS

    cond = dataclasses.replace(REALISM_CONDITIONS["focal-5%"], box_noise_px=8.0)
    case = make_realism_case(cond, 16, 20)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = calibrate(list(case.frames), case.intrinsics_given)
    assert not res.success and res.rotation is None
    # since the session 14 review the focal length "auto" kept as unconstrained also counts in the sigma
    # (selfcal._unconstrained_choice_sd): the pose is then already too uncertain (95 % bound 4.5 m), and the
    # unverifiable focal length, which refuses only what nothing else did, is recorded in the checks
    assert res.diagnostics.refusal in ("focal_unverifiable", "uncertain"), res.message
    if res.diagnostics.refusal == "focal_unverifiable":
        assert "cannot check the given focal length" in res.message and "m along the view" in res.message
    check = next(c for c in res.diagnostics.misfit if c.name == "focal_checkable")
    assert check.flagged and check.statistic <= check.limit == 2.0
    assert not next(c for c in res.diagnostics.misfit if c.name == "focal_scale").flagged
