"""Issue 29: the second-pose and mirror searches are skipped only where no result of theirs could
flag (an exact bound: one-to-one matches, IoU <= 1) -- the verdict is the one the search gives."""

from __future__ import annotations

import numpy as np
import pytest
from _calib_bent import bent_case

from xcalib.calib import api
from xcalib.calib.config import CalibConfig
from xcalib.calib.inputs import prepare_frames
from xcalib.calib.misfit import (MIRROR_GAIN, SECOND_POSE_MIN_PAIRS, SECOND_POSE_SHARE, match_bound, mirror_check,
                                 mirror_screen, second_pose_check, second_pose_screen)
from xcalib.calib.pose import Pose

UPRIGHT = Pose(np.array([[0, -1, 0], [0, 0, -1], [1, 0, 0]], float), np.zeros(3))  # LiDAR z up -> image up
UPSIDE_DOWN = Pose(np.diag([1.0, -1.0, -1.0]) @ UPRIGHT.R, np.zeros(3))


@pytest.fixture(scope="module")
def cf():
    frames, K, _ = bent_case("clean", seed=1, n_frames=6)
    return prepare_frames(frames, K)[0]


def test_match_bound_is_one_to_one_per_frame(cf):
    assert match_bound(cf) == sum(min(f.n2, f.n3) for f in cf) > 0


@pytest.mark.parametrize("best", [1.0, 10.0, 40.0, 80.0, 200.0])
def test_second_pose_screen_never_hides_a_flag(cf, best):
    """Whenever the screen skips the search, every result the search could return (score and
    matches within the bound, any distance, admissible) leaves the check unflagged."""
    bound = match_bound(cf)
    why = second_pose_screen(best, cf)
    if why is None:  # the search must run: some result within the bound can flag
        assert bound >= SECOND_POSE_MIN_PAIRS and bound >= SECOND_POSE_SHARE * best
        assert second_pose_check(best, 50, float(bound), bound, (10.0, 5.0))[0].flagged
        return
    for n in range(bound + 1):
        for score in np.linspace(0.0, n, 5):
            assert not second_pose_check(best, 50, float(score), n, (10.0, 5.0))[0].flagged
    chk, msg = second_pose_check(best, 50, float(bound), bound, None, False, why)
    assert not chk.flagged and msg is None and chk.detail.startswith("not searched")


@pytest.mark.parametrize("best", [10.0, 40.0, 60.0, 100.0, 300.0])
@pytest.mark.parametrize("pose", [UPRIGHT, UPSIDE_DOWN])
def test_mirror_screen_never_hides_a_flag(cf, best, pose):
    bound = match_bound(cf)
    need = 6
    why = mirror_screen(best, cf, pose, need)
    if why is None:
        assert mirror_check(best, float(bound), pose, (bound, need))[0].flagged
        return
    for n in range(bound + 1):
        for score in np.linspace(0.0, n, 5):
            assert not mirror_check(best, float(score), pose, (n, need))[0].flagged
    chk, msg = mirror_check(best, float(bound), pose, (bound, need), why)
    assert not chk.flagged and msg is None and chk.detail.startswith("not searched")
    assert chk.statistic <= MIRROR_GAIN


def test_screened_searches_give_the_verdict_of_the_full_search(monkeypatch):
    """A clean site calibrated with the screens and with them switched off (the searches always
    run): the same pose, sigmas and verdict; the screened checks say they were not searched."""
    frames, K, _ = bent_case("clean", seed=1, n_frames=8)
    screened = api.calibrate(frames, K, CalibConfig(workers=1))
    monkeypatch.setattr(api, "second_pose_screen", lambda best, left: None)
    monkeypatch.setattr(api, "mirror_screen", lambda best, cf, pose, need: None)
    full = api.calibrate(frames, K, CalibConfig(workers=1))
    assert screened.success == full.success and screened.diagnostics.refusal == full.diagnostics.refusal
    np.testing.assert_array_equal(screened.extrinsics, full.extrinsics)
    np.testing.assert_array_equal(screened.rotation_std_deg, full.rotation_std_deg)
    a = {c.name: c for c in screened.diagnostics.misfit}
    b = {c.name: c for c in full.diagnostics.misfit}
    assert a.keys() == b.keys() and all(a[k].flagged == b[k].flagged for k in a)
    skipped = [k for k in ("second_pose", "mirrored") if a[k].detail.startswith("not searched")]
    assert skipped, "the clean site should let at least one search be screened"
    for k in skipped:  # the statistic recorded is the bound's, at or above the searched one
        assert a[k].statistic >= b[k].statistic - 1e-9
