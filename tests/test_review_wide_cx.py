"""Session 15 review (R): wide-angle cameras given cx 1-1.5 % of the width off were delivered beyond the
wrong-pose line with sigmas that did not cover it (at the session's base ``4d64948`` and at the first
version of route b alike: the principal-point check passed them).

* Kannala-Brandt 150 deg, bench site 9 (``bench_camera_models.calibrate_case``'s site), cx +1.5 % W
  (+19 px): the check fitted (-13.1, -0.9) px, a 1.6 deg turn (8.2 px turn this camera 1 deg), below
  its pixel tolerance (1.5 % of the width: 2.3 deg on this lens); delivered 2.21 deg off with a
  1-sigma of 0.16 deg. Route b (session 15, P) now puts such a shift in the bound.
* Unified 150 deg, site 9, cx +1 % W: the check fitted -11.3 px, within the 16.1 px that fx tan 1 deg
  gives, but the unified model's own focal length at the centre is fx / (1 + xi): 7.7 px turn this
  camera 1 deg; delivered 1.35 deg off. ``misfit._pp_need`` now takes the model's 1-degree shift.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from xcalib.calib import misfit
from xcalib.calib.misfit import _pp_need
from xcalib.geometry import CameraIntrinsics


def _site(model: str, seed: int):
    from xcalib.data.synth import sample_site

    return sample_site(seed, camera_model=model, hfov_deg=150, width=1280, height=800, box_noise_px=1.0)


def test_the_one_degree_shift_is_the_model_s_own_at_the_centre():
    uni = _site("unified", 9).intrinsics
    t = np.tan(np.radians(1.0))
    uv, _ = uni.project(np.array([[t, 0.0, 1.0]]))
    assert _pp_need(uni) == pytest.approx(float(uv[0, 0] - uni.cx), rel=1e-6)
    assert _pp_need(uni) < 0.6 * min(uni.fx, uni.fy) * t  # fx / (1 + xi), xi 1.1: not fx tan 1 deg
    kb = _site("kannala_brandt", 9).intrinsics  # equidistant: fx tan 1 deg is its own already
    assert _pp_need(kb) == pytest.approx(min(kb.fx, kb.fy) * t, rel=1e-3)
    ds = _site("double_sphere", 9).intrinsics  # a centre stretched (xi < 0): never above fx tan 1 deg
    assert _pp_need(ds) == pytest.approx(min(ds.fx, ds.fy) * t)
    pin = CameraIntrinsics(1000.0, 990.0, 640.0, 400.0, None, 1280, 800)  # a pinhole: unchanged
    assert _pp_need(pin) == pytest.approx(990.0 * t)


def _delivered(model: str, seed: int, frac: float):
    import xcalib
    from xcalib.calib.config import CalibConfig
    from xcalib.calib.cost import shift_principal_point
    from xcalib.data.synth import generate_frames

    site = _site(model, seed)
    frames = generate_frames(site, 20, seed=seed, render_images=False)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = xcalib.calibrate(frames, shift_principal_point(site.intrinsics, frac * 1280, 0.0), CalibConfig(workers=1))
    return res, (res.pose_error(site.T_cam_lidar) if res.success else None)


@pytest.mark.slow
@pytest.mark.xfail(not hasattr(misfit, "_PP_X_BEYOND"), strict=True,
                   reason="needs route b for an unflagged shift beyond the 1-degree shift (session 15, P)")
def test_a_unified_camera_given_cx_off_by_1_percent_is_delivered_only_within_its_bound():
    """With the model's 1-degree shift the check's -11.3 px go to route b's part of the bound (session 15, P):
    delivered 1.35 deg off with a 95 % bound of about 2 deg (inside it) instead of a 0.3 deg bound."""
    res, err = _delivered("unified", 9, 0.01)
    if err is not None:
        rot_b, tr_b = res.bound95
        assert err[0] <= rot_b and err[1] <= tr_b, f"delivered {err[0]:.2f} deg / {err[1]:.2f} m off, bound {rot_b:.2f} / {tr_b:.2f}"
        assert res.diagnostics.uncertainty.principal_point is not None  # the part is what covers it


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="open (session 15 review): route b delivers a pose whose 95 % bound (up to the "
                   "2 deg limit) covers its error but lies beyond the wrong-pose line (1 deg): unified 150 site 9, cx "
                   "+1 % W, 1.35 deg off")
def test_a_unified_camera_given_cx_off_by_1_percent_is_not_delivered_beyond_the_wrong_pose_line():
    res, err = _delivered("unified", 9, 0.01)
    assert err is None or (err[0] <= 1.0 and err[1] <= 0.5), f"delivered {err[0]:.2f} deg / {err[1]:.2f} m off"


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="open (session 15 review): Kannala-Brandt 150 deg, site 9, cx +1 % W (12.8 px): the "
                   "boxes ask for -6.8 px only, within the 8.2 px 1-degree shift, at a pose-free 1-sigma of 5.7 px "
                   "(ratio 0.70: 'resolved'): the check passes and the pose is delivered 1.50 deg off with a 1-sigma "
                   "of 0.14 deg (a 1-sigma of 0.7 x the 1-degree shift sees that shift at 1.4 sigmas only)")
def test_a_kannala_brandt_camera_given_cx_off_by_1_percent_is_not_delivered_wrong():
    res, err = _delivered("kannala_brandt", 9, 0.01)
    assert err is None or (err[0] <= 1.0 and err[1] <= 0.5), f"delivered {err[0]:.2f} deg / {err[1]:.2f} m off"
