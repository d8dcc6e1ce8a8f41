"""HTML calibration report: numbers, relative overlay PNGs, failure and 'before' variants."""

from __future__ import annotations

import re

import numpy as np
import pytest

from xcalib.calib.result import CalibrationResult
from xcalib.data.synth import generate_frames, sample_site
from xcalib.geometry.rotations import euler_to_matrix
from xcalib.viz.report import result_numbers, write_calibration_report


@pytest.fixture(scope="module")
def scene():
    site = sample_site(3, "roadside", width=640, height=400, focal_px=600.0)
    frames = generate_frames(site, 2, seed=3)
    T = site.T_cam_lidar
    pairs = [np.argwhere(f.match_matrix) for f in frames]
    res = CalibrationResult(success=True, intrinsics=site.intrinsics, rotation=T[:3, :3], translation=T[:3, 3],
                            pairs=pairs, frame_keys=[f.frame_key for f in frames], n_correspondences=5,
                            residual_px_median=1.5, iou_median=0.9, method="test")
    return site, frames, res


def _imgs(html_path):
    return re.findall(r'<img src="([^"]+)"', html_path.read_text())


def test_report_has_numbers_and_existing_relative_images(scene, tmp_path):
    site, frames, res = scene
    rep = write_calibration_report(tmp_path / "r", res, frames, ground_truth=site.T_cam_lidar,
                                   extra={"matcher Top-1": 0.875})
    html = rep.html.read_text()
    srcs = _imgs(rep.html)
    assert len(srcs) == 4 and all(not s.startswith("/") for s in srcs)  # 2 frames x (calibration, matching)
    assert all((rep.html.parent / s).stat().st_size > 1000 for s in srcs)
    assert "calibrated" in html and "0.875" in html and "matcher Top-1" in html
    assert rep.numbers["rotation error vs ground truth (deg)"] == pytest.approx(0.0, abs=1e-6)
    assert {f.kind for f in rep.figures} == {"calibration", "matching"}


def test_before_pose_adds_before_overlays(scene, tmp_path):
    site, frames, res = scene
    T = site.T_cam_lidar.copy()
    R0 = euler_to_matrix([2.0, -1.0, 3.0], degrees=True) @ T[:3, :3]
    rep = write_calibration_report(tmp_path / "r", res, frames, before=(R0, T[:3, 3]), max_frames=1)
    kinds = [f.kind for f in rep.figures]
    assert kinds.count("calibration_before") == 1 and kinds.count("calibration") == 1


def test_failed_result_renders_without_overlays(scene, tmp_path):
    site, frames, _ = scene
    bad = CalibrationResult(success=False, intrinsics=site.intrinsics, message="ambiguous: two poses")
    rep = write_calibration_report(tmp_path / "r", bad, frames)
    html = rep.html.read_text()
    assert "not calibrated" in html and "ambiguous: two poses" in html
    assert not any(f.kind.startswith("calibration") for f in rep.figures)
    assert "rotation error vs ground truth (deg)" not in result_numbers(bad, site.T_cam_lidar)


def test_bad_before_pose_is_refused(scene, tmp_path):
    site, frames, res = scene
    with pytest.raises(ValueError, match="before"):
        write_calibration_report(tmp_path / "r", res, frames, before=np.eye(5))
