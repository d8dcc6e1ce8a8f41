"""refine_intrinsics="auto"'s model choice in the pose sigma (issue 26): a fitted focal length used
because it disagrees with the given one beyond 2 sigma widens the pose's sigma by sqrt(w) x the
pose's move to it, w the given focal length's posterior weight."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from xcalib.calib.diagnostics import SelfCalDiagnostics
from xcalib.calib.pose import Pose
from xcalib.calib.selfcal import SelfCalFit, _with_focal_choice, focal_choice_weight
from xcalib.geometry import CameraIntrinsics


def _fit(scale: float, pose: Pose, inflation) -> SelfCalFit:
    return SelfCalFit(pose=pose, intr=CameraIntrinsics(500 * scale, 500 * scale, 320, 240, None, 640, 480), dt_s=0.0,
                      focal_scale=scale, focal_log_sd=0.004, principal_shift_px=None, principal_sd_px=None,
                      dt_sd_s=None, pose_inflation=np.asarray(inflation, dtype=float), n_moving_pairs=0, n_pairs=60)


def test_weight_is_the_likelihood_ratio_of_the_two_focal_lengths():
    assert focal_choice_weight(0.0) == pytest.approx(0.5)
    assert focal_choice_weight(2.0) == pytest.approx(1 / (1 + np.exp(2.0)))
    assert focal_choice_weight(3.0) < 0.012 and focal_choice_weight(5.0) < 1e-5
    assert 0.0 <= focal_choice_weight(1e6) < 1e-300  # no overflow


def test_a_two_sigma_switch_widens_the_sigma_a_clear_focal_error_does_not():
    given = Pose(np.eye(3), np.zeros(3))
    moved = Pose(Rotation.from_rotvec(np.radians([0.14, 0.0, 0.0])).as_matrix(), np.array([0.0, 0.0, 0.14]))
    infl = [0.01, 0.01, 0.01, 0.01, 0.01, 0.01]
    diag = SelfCalDiagnostics()
    near = _with_focal_choice(np.asarray(infl), _fit(np.exp(2.02 * 0.004), moved, infl), given, 0.004, diag)
    w = focal_choice_weight(2.02)
    assert near[0] == pytest.approx(np.hypot(0.01, np.sqrt(w) * 0.14), rel=1e-6)
    assert near[5] == pytest.approx(np.hypot(0.01, np.sqrt(w) * 0.14), rel=1e-6)
    assert near[1] == pytest.approx(0.01, rel=1e-6)  # no move about y: nothing added
    assert any("posterior weight" in n for n in diag.notes)
    far = _with_focal_choice(np.asarray(infl), _fit(np.exp(8 * 0.004), moved, infl), given, 0.004, SelfCalDiagnostics())
    np.testing.assert_allclose(far, infl, rtol=1e-6)  # a clear focal error (8 sigma): the estimate stands alone
    unknown = _with_focal_choice(np.asarray(infl), _fit(1.01, moved, infl), given, None, SelfCalDiagnostics())
    np.testing.assert_allclose(unknown, infl)
