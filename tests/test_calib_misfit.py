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
