"""The information a window of boxes holds about a step (``benchmarks/monitor_information.py``:
the Cramer-Rao bound and the power of efficient tests at the false-alarm rate, a site's geometry)."""

from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from scipy.stats import chi2, norm

from xcalib.calib.result import CalibrationResult
from xcalib.data.synth import iter_frames, sample_site
from xcalib.monitor import Monitor

BENCH = Path(__file__).resolve().parents[1] / "benchmarks"


@pytest.fixture(scope="module")
def info_mod():
    if str(BENCH) not in sys.path:
        sys.path.insert(0, str(BENCH))
    import monitor_information

    return monitor_information


@pytest.fixture(scope="module")
def stream():
    site = sample_site(5, n_objects=(15, 30))
    frames = [replace(f, bboxes_3d=np.asarray(f.meta["box7"], dtype=np.float32))
              for f in iter_frames(site, 120, 0, render_images=False, lidar=False)]
    T = site.T_cam_lidar
    cal = CalibrationResult(success=True, intrinsics=site.intrinsics_given, rotation=T[:3, :3], translation=T[:3, 3],
                            rotation_std_deg=np.full(3, 0.05), translation_std_m=np.full(3, 0.02),
                            camera_name=site.camera_name, image_size=(site.width, site.height))
    return site, cal, frames


def test_efficient_rows_match_the_closed_form(info_mod):
    a = np.array([4e4, 4e4, 4e4, 900.0, 900.0, 40.0])  # per-frame information (independent axes)
    infos = np.tile(np.diag(a), (400, 1, 1))
    rate, stride = 1e-4, 5
    rows = info_mod.efficient_rows(infos, rate, stride, ref=250, targets=((5, 0.10, 50),))
    q = rows["tz_0.1_within_50"]
    assert q["crb_sigma_median"] == pytest.approx(1 / np.sqrt(40.0 * 50), rel=1e-9)
    var = 1 / (40.0 * 50) + 1 / (40.0 * 250)
    assert q["two_sample_sigma_median"] == pytest.approx(np.sqrt(var), rel=1e-9)
    z = 0.10 / np.sqrt(var)
    h1 = chi2.isf(rate * stride, 1)
    assert q["power_oracle_1dof"] == pytest.approx(norm.sf(np.sqrt(h1) - z) + norm.cdf(-np.sqrt(h1) - z), rel=1e-9)
    # the test that knows the direction beats the one over six axes, which beats six 1-dof tests here
    assert 1.0 > q["power_oracle_1dof"] > q["power_6dof"] > 0.0
    assert q["thresholds"]["6dof"] > q["thresholds"]["axes_1dof"] > q["thresholds"]["oracle_1dof"]
    weak = info_mod.efficient_rows(infos * 0.25, rate, stride, ref=250, targets=((5, 0.10, 50),))["tz_0.1_within_50"]
    assert weak["power_oracle_1dof"] < q["power_oracle_1dof"] and weak["share_oracle_ge_95"] <= q["share_oracle_ge_95"]


def test_site_geometry_finds_the_camera_height_and_pitch_from_the_boxes(info_mod, stream):
    site, cal, frames = stream
    cm = next(iter(Monitor(cal).cameras.values()))
    truth = info_mod.site_geometry(cm, frames[:20], site.T_world_cam)
    est = info_mod.site_geometry(cm, frames[:20])  # the ground from the boxes' lowest corners
    assert est["camera_height_m"] == pytest.approx(truth["camera_height_m"], abs=0.3)
    assert est["camera_pitch_down_deg"] == pytest.approx(truth["camera_pitch_down_deg"], abs=1.0)
    assert est["pairs_per_frame"] > 3 and 5 < est["depth_m_median"] < 120
    lo, hi = est["depth_m_p10_p90"]
    assert lo < est["depth_m_median"] < hi
