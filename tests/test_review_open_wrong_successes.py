"""Open wrong successes found by the session 14 review (R): a synthetic roadside site whose given
intrinsics are slightly wrong and whose 2D boxes are a detector's visible outline is delivered as a
success off by more than the wrong-pose line (1 deg / 0.5 m) and outside its own 95 % bound. Both were
delivered already at the session's base (``a704cf0``) and at every engineer branch of session 14; they
are kept here as strict expected failures (a fix makes them pass, and the marker must then go); the
third (the focal length) is fixed in the review and its test passes; the first is fixed in session 14 (G:
the principal-point check's unresolved x shift, ``misfit._pp_x_unresolved``) and its test passes; the
second stays open.

* cx given 3 % of the width off (58 px, which turns the camera 1.4 deg) with the detector outline,
  site 0: the principal-point check fits (-57, +24) px, the right shift, but at 2.2 sigmas of x
  (25.5 px) it neither flags it (4 sigmas) nor calls it unverifiable (3 sigmas), although twice
  that sigma exceeds the shift that turns the camera by 1 deg (41 px): delivered 1.15 deg / 0.81 m
  off, 95 % bound 0.71 deg / 1.14 m.
* cx given 3 % of the width short with the detector outline, site 0: the check, refitting cx, cy
  with the pose free from the calibration's pose and matches, fits (+9, -45) px (x sigma 4.7 px)
  where the truth is +58 px; no local minimum (refits started at -60 ... +60 px all end at +9..+15 px,
  the cost at the true shift is higher): with these outline boxes the pose takes up the shift and
  the boxes prefer the given cx. Delivered 1.40 deg / 0.36 m off, 95 % bound 0.61 deg / 0.38 m.
* fx given 3 % long with the detector outline, site 1: "auto" keeps the given focal length (its
  estimate's 1-sigma 1.08 % is above ``focal_max_std``) without counting the pose's move to the
  fitted one in the sigma; the focal-length check fits x0.973 (jackknife 1-sigma 0.5 %, 5 sigmas)
  but its tolerance is 3 %; delivered 0.26 deg / 1.41 m off (the depth), 95 % bound 0.60 m.
  Fixed in the review: that choice now counts in the reported sigma (``selfcal._unconstrained_choice_sd``).
* fx given 3 % long with every detector habit, site 2 (an over-confident delivery, not a wrong pose):
  "auto" fitted x0.9872 (1-sigma 0.79 %, z 1.6, the truth x0.971) and kept the given focal length as
  "consistent with the given one" without that choice in the sigma: delivered 0.36 deg / 0.40 m off with
  a 95 % bound of 0.26 m. Fixed in session 15 (K): the consistent keep counts sqrt(1 - w) x the focal
  length's own move (0.23 m) as the unconstrained keep does; bound 0.47 m.
* cx given 3 % of the width off with every detector habit (found in session 15 by K, older: delivered at
  ``4d64948``), site 2: the principal-point check fits (-2.3, -30.7) px (x sigma 7.1 px) where the truth is
  58 px: the boxes prefer the given cx as in the -3 % outline case above; delivered 2.26 deg / 0.29 m off
  (ry 2.25 deg against a 1-sigma of 0.075 deg), 95 % bound 0.41 deg / 0.16 m. Site 0 alike (1.53 deg / 0.36 m,
  the fitted focal length x0.979 used). A strict expected failure.
"""

from __future__ import annotations

import warnings

import pytest

from xcalib.data.synth.detector import DetectorStyle
from xcalib.data.synth.realism import RealismCondition, make_realism_case

OUTLINE = DetectorStyle(outline=True, merge_prob=0.0, class_misses=False, part_boxes=False, score_noise=False)


def _delivered_wrong(cond: RealismCondition, seed: int):
    """(delivered beyond 1 deg / 0.5 m, what happened, the result)."""
    import xcalib

    case = make_realism_case(cond, seed, 20)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = xcalib.calibrate(list(case.frames), case.intrinsics_given)
    if not res.success:
        return False, f"refused: {res.diagnostics.refusal}", res
    rot, tr = res.pose_error(case.T_cam_lidar)
    return rot > 1.0 or tr > 0.5, f"delivered {rot:.2f} deg / {tr:.2f} m off", res


@pytest.mark.slow
def test_a_wrong_cx_with_detector_outlines_is_not_delivered():
    cond = RealismCondition("pp+3_outline", "cx +3 % W, detector outline", principal_offset_frac=0.03,
                            detector=OUTLINE, miss_rate_2d=0.0)
    wrong, what, _ = _delivered_wrong(cond, 0)
    assert not wrong, what


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="open (session 14 review): with detector outlines the boxes prefer the "
                   "given cx, 3 % W short, and the pose takes up the shift")
def test_a_short_cx_with_detector_outlines_is_not_delivered():
    cond = RealismCondition("pp-3_outline", "cx -3 % W, detector outline", principal_offset_frac=-0.03,
                            detector=OUTLINE, miss_rate_2d=0.0)
    wrong, what, _ = _delivered_wrong(cond, 0)
    assert not wrong, what


@pytest.mark.slow
def test_a_focal_length_3pct_long_with_detector_outlines_is_not_delivered():
    """Fixed in the review (``selfcal._unconstrained_choice_sd``): the given focal length kept as
    unconstrained counts its choice in the sigma (the move to the fitted x0.970: 1.57 m), so the pose's
    95 % bound is 3.07 m and it is refused as too uncertain instead of delivered 1.41 m off."""
    cond = RealismCondition("f+3_outline", "fx x1.03, detector outline", focal_scale=1.03, detector=OUTLINE,
                            miss_rate_2d=0.0)
    wrong, what, res = _delivered_wrong(cond, 1)
    assert not wrong, what
    assert any("not constrained enough to use" in n for n in res.diagnostics.selfcal.notes)
    assert res.diagnostics.uncertainty.focal_box_model is not None


@pytest.mark.slow
def test_a_focal_length_kept_as_consistent_is_within_its_bound():
    """Session 15 (K): the given focal length kept because the fitted one is within 2 of its sigmas is a
    model choice too; its part in the sigma covers the pose's error (at the base: 0.40 m, bound 0.26 m)."""
    from xcalib.calib.diagnostics import bound95

    cond = RealismCondition("f+3_all", "fx x1.03, every detector habit", focal_scale=1.03, detector=DetectorStyle(),
                            max_truncation=0.9, miss_rate_2d=0.0)
    wrong, what, res = _delivered_wrong(cond, 2)
    assert not wrong, what
    assert any("is consistent with the given one) with a posterior weight" in n for n in res.diagnostics.selfcal.notes)
    if res.success:
        case = make_realism_case(cond, 2, 20)
        rot, tr = res.pose_error(case.T_cam_lidar)
        assert rot <= bound95(res.rotation_std_deg) and tr <= bound95(res.translation_std_m), \
            f"{what}, 95 % bound {bound95(res.rotation_std_deg):.2f} deg / {bound95(res.translation_std_m):.2f} m"


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="open (session 15, K): with every detector habit the boxes prefer the given cx, "
                   "3 % W off, and the pose takes up the shift (older than session 15)")
def test_a_wrong_cx_with_every_detector_habit_is_not_delivered():
    cond = RealismCondition("pp+3_all", "cx +3 % W, every detector habit", principal_offset_frac=0.03,
                            detector=DetectorStyle(), max_truncation=0.9, miss_rate_2d=0.0)
    wrong, what, _ = _delivered_wrong(cond, 2)
    assert not wrong, what
