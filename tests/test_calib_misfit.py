"""The verdict refuses a pose whose model does not fit the detections, naming the cause: wrong
focal length, mirrored image, frames of a second camera mixed in (quick bent synthetic sites,
tests/_calib_bent.py) -- and does not refuse the clean site."""

from __future__ import annotations

import pytest
from _calib_bent import bent_case

from xcalib.calib.api import calibrate
from xcalib.calib.config import CalibConfig


@pytest.mark.parametrize("variant, cause", [("focal x1.2", "focal length about 0.83x"), ("mirrored", "mirrored")])
def test_model_misfit_is_refused_with_its_cause(variant, cause):
    frames, K, T = bent_case(variant, seed=1, n_frames=10)
    # the given intrinsics as they are (the default "auto" would estimate this focal length: issue 13)
    res = calibrate(frames, K, CalibConfig(refine_intrinsics="none"))
    assert not res.success and res.diagnostics.refusal.startswith("misfit")
    assert cause in res.message
    assert any(c.flagged for c in res.diagnostics.misfit)


def test_clean_site_passes_every_misfit_check():
    frames, K, T = bent_case("clean", seed=1, n_frames=10)
    res = calibrate(frames, K)
    assert res.success, res.message
    checks = {c.name: c for c in res.diagnostics.misfit}
    assert {"mirrored", "unexplained_frames", "principal_point"} <= set(checks)
    assert not any(c.flagged for c in res.diagnostics.misfit)
    if "focal_scale" in checks:  # (not run when the focal length was estimated with the pose)
        assert abs(checks["focal_scale"].statistic - 1.0) < 0.01
    rot, trans = res.pose_error(T)
    assert rot < 0.2 and trans < 0.1


def test_crowded_frames_are_refused_without_a_guess():
    import numpy as np

    from xcalib.calib import CalibConfig
    from xcalib.calib.decision import crowded_check
    from xcalib.calib.inputs import prepare_frames
    from xcalib.types import Frame

    frames, K, _ = bent_case("clean", seed=1, n_frames=3)
    cf, _, _ = prepare_frames(frames, K)
    assert crowded_check(cf, CalibConfig()) is None
    rng = np.random.default_rng(0)
    b3 = np.column_stack([rng.uniform(-60, 60, (270, 2)), np.zeros(270), np.tile([4.5, 1.9, 1.6], (270, 1)),
                          np.zeros(270)])
    busy = [Frame(**{**f.__dict__, "bboxes_2d": np.tile(f.bboxes_2d, (4, 1))[:32], "bboxes_3d": b3}) for f in frames]
    cf, _, _ = prepare_frames(busy, K)
    why = crowded_check(cf, CalibConfig())
    assert why is not None and why.code == "crowded" and "prior" in why.message


def test_boxes_given_in_the_camera_frame_are_refused_before_the_search():
    """3D boxes (and points) in the camera frame (y down, z forward) spread over a plane far from
    z-up: refused naming the frame, before any search; the same site in the LiDAR frame passes."""
    import numpy as np

    from xcalib.calib.inputs import prepare_frames
    from xcalib.calib.misfit import BOX_FRAME_MAX_TILT_DEG, box_frame_check
    from xcalib.data.synth.realism import make_realism_case

    lidar = make_realism_case("clean", 0, n_frames=6)
    cf, _, _ = prepare_frames(list(lidar.frames), lidar.intrinsics_given)
    chk, msg = box_frame_check(cf)
    assert msg is None and chk.statistic < 5.0
    cam = make_realism_case("boxes_in_camera_frame", 0, n_frames=6)
    np.testing.assert_allclose(cam.T_cam_lidar, np.eye(4))
    res = calibrate(list(cam.frames), cam.intrinsics_given)
    assert not res.success and res.diagnostics.refusal == "misfit_box_frame"
    assert "camera frame" in res.message and "z up" in res.message
    (chk,) = res.diagnostics.misfit
    assert chk.name == "box_frame" and chk.flagged and chk.statistic > BOX_FRAME_MAX_TILT_DEG
    # the check is part of misfit_check: switched off, the search runs (and refuses for other reasons)
    res = calibrate(list(cam.frames), cam.intrinsics_given, CalibConfig(misfit_check=False))
    assert res.diagnostics.refusal != "misfit_box_frame"


def test_box_frame_check_judges_a_line_of_boxes_by_its_elevation():
    """Boxes along one road (one wide direction): the elevation of that line is the statistic."""
    import numpy as np

    from xcalib.calib.misfit import box_frame_check

    s = np.linspace(5.0, 60.0, 12)
    for tilt_deg, flagged in ((3.0, False), (50.0, True)):
        a = np.radians(tilt_deg)
        centres = np.column_stack([s * np.cos(a), 0.3 * np.sin(s), s * np.sin(a)])

        class F:  # the two fields the check reads
            n3 = len(centres)
            boxes3d = np.column_stack([centres, np.tile([4.5, 1.9, 1.6, 0.0], (len(centres), 1))])

        chk, msg = box_frame_check([F()])
        assert chk.flagged is flagged and (msg is not None) is flagged
        assert abs(chk.statistic - tilt_deg) < 1.0


def test_a_horizontal_principal_point_error_under_noisy_boxes_is_refused():
    """Realism site 4, cx + 3 % W, 4 px 2D noise: the shift's norm is within 4 bootstrap sigmas
    (its y part wanders), but its x part alone is far outside its own spread -> refused. Before
    the x test this pose was a success 2.3 deg / 0.77 m off. Since the sigma counts each object once
    (issue 25: 18 objects, leaving them out spreads the x shift wider than the frames do) the shift
    is no longer significant, but neither can the objects rule out one that turns the pose by 1 deg:
    refused as not verifiable, still never a success."""
    from xcalib.data.synth.realism import make_realism_case

    case = make_realism_case("principal_point+3%W_4px", 4)
    res = calibrate(list(case.frames), case.intrinsics_given)
    assert not res.success and res.rotation is None
    assert res.diagnostics.refusal in ("misfit_principal_point", "principal_point_unverifiable"), res.message
    chk = next(c for c in res.diagnostics.misfit if c.name == "principal_point")
    assert chk.flagged and "x alone" in chk.detail
    assert "principal point" in res.message and "moved by (-" in res.message  # the given cx is too large


def test_a_five_percent_focal_error_under_noisy_boxes_is_refused():
    """Realism site 15, fx, fy x1.05, 4 px 2D noise: the fitted scale (0.95) is beyond the 3 %
    tolerance at about 3 bootstrap sigmas -- refused naming the focal length (with 4 sigmas this
    was a success 0.9 deg / 0.6 m off)."""
    import dataclasses

    from xcalib.data.synth.realism import REALISM_CONDITIONS, make_realism_case

    case = make_realism_case(dataclasses.replace(REALISM_CONDITIONS["focal+5%"], box_noise_px=4.0), 15)
    res = calibrate(list(case.frames), case.intrinsics_given)
    assert not res.success and res.diagnostics.refusal == "misfit_focal_length"
    assert "focal length about 0.95x" in res.message


def test_mirror_is_named_only_when_the_flipped_boxes_are_explained():
    """Issue 31: among many unmatched boxes (random 2D distractors, hundreds of 3D boxes) the
    flipped boxes' chance alignment can score above the given boxes' and the chance pose be upside
    down; that is no mirror: the flipped boxes' pose explains no more boxes than the given one."""
    import numpy as np

    from xcalib.calib.misfit import mirror_check
    from xcalib.calib.pose import Pose

    upside_down = Pose(np.diag([1.0, -1.0, -1.0]) @ np.array([[0, -1, 0], [0, 0, -1], [1, 0, 0]], float), np.zeros(3))
    assert upside_down.R[1, 2] > 0.5
    chk, msg = mirror_check(127.1, 130.3, upside_down)  # as before: flagged on the scores alone
    assert chk.flagged and "mirrored" in msg
    chk, msg = mirror_check(127.1, 130.3, upside_down, explained=(190, 600))  # 190 of the 600 needed
    assert not chk.flagged and msg is None and "not explained" in chk.detail
    chk, msg = mirror_check(20.0, 90.0, upside_down, explained=(140, 60))  # a mirrored image: explained
    assert chk.flagged and "mirrored" in msg


def test_an_unflagged_x_shift_beyond_the_one_degree_line_its_sigma_cannot_resolve_is_not_verifiable():
    """Session 14 (issue 25): an unflagged shift whose x part is beyond the 1-degree shift and the
    tolerance, while twice its x sigma exceeds the 1-degree shift, is not verifiable (review: cx 3 % W
    off, detector outline, site 0: (-57, +24) px at x sigma 25.5 px against a 41 px 1-degree shift)."""
    import numpy as np

    from xcalib.calib.misfit import PP_CHECK_SIGMAS, PP_TOL_FRAC, _pp_x_unresolved

    W, need = 1920, 41.0
    assert _pp_x_unresolved(np.array([-57.0, 24.0]), np.array([25.5, 30.0]), W, need)
    # its sigma resolves the 1-degree shift: the other rules judge it (flag / gray zone)
    assert not _pp_x_unresolved(np.array([-57.0, 24.0]), np.array([0.99 * need / PP_CHECK_SIGMAS, 30.0]), W, need)
    # the x part within the 1-degree shift, or within the tolerance where that is wider: nothing to see
    assert not _pp_x_unresolved(np.array([-40.0, 200.0]), np.array([25.5, 30.0]), W, need)
    assert not _pp_x_unresolved(np.array([20.0, 0.0]), np.array([25.5, 30.0]), W, 10.0)
    assert _pp_x_unresolved(np.array([1.01 * PP_TOL_FRAC * W, 0.0]), np.array([25.5, 30.0]), W, 10.0)
