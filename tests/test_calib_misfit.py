"""The verdict refuses a pose whose model does not fit the detections, naming the cause: wrong
focal length, mirrored image, frames of a second camera mixed in (quick bent synthetic sites,
tests/_calib_bent.py) -- and does not refuse the clean site."""

from __future__ import annotations

import pytest
from _calib_bent import bent_case

from xcalib.calib.api import calibrate


@pytest.mark.parametrize("variant, cause", [("focal x1.2", "focal length about 0.83x"), ("mirrored", "mirrored")])
def test_model_misfit_is_refused_with_its_cause(variant, cause):
    frames, K, T = bent_case(variant, seed=1, n_frames=10)
    res = calibrate(frames, K)
    assert not res.success and res.diagnostics.refusal.startswith("misfit")
    assert cause in res.message
    assert any(c.flagged for c in res.diagnostics.misfit)


def test_clean_site_passes_every_misfit_check():
    frames, K, T = bent_case("clean", seed=1, n_frames=10)
    res = calibrate(frames, K)
    assert res.success, res.message
    assert {c.name for c in res.diagnostics.misfit} >= {"focal_scale", "mirrored", "unexplained_frames"}
    assert not any(c.flagged for c in res.diagnostics.misfit)
    assert abs(res.diagnostics.misfit[1].statistic - 1.0) < 0.01  # the fitted focal scale
    rot, trans = res.pose_error(T)
    assert rot < 0.2 and trans < 0.1
