"""Calibration overlays (viz.calibration) and the report folder / CLI command."""

from __future__ import annotations

import json

import numpy as np
import pytest
from test_calib_support import INTR, sim_frames

from xcalib.calib.result import CalibrationResult
from xcalib.geometry import CameraIntrinsics, projection_matrix
from xcalib.viz.calibration import draw_calibration_overlay


def _scene():
    frames, T = sim_frames(seed=2, n_frames=1, noise_px=0.0, miss=0.0, false_pos=0.0)
    f = frames[0]
    # a point cloud: the 3D box centres plus a ground grid in front of the camera
    rng = np.random.default_rng(0)
    pts = np.vstack([f.bboxes_3d[:, :3], rng.normal(0, 20, (2000, 3))])
    return f, T, pts


def test_overlay_draws_points_boxes_and_matches():
    f, T, pts = _scene()
    image = np.full((1200, 1920, 3), 128, np.uint8)
    calib = CalibrationResult(success=True, intrinsics=INTR, rotation=T[:3, :3], translation=T[:3, 3])
    pairs = np.argwhere(f.match_matrix)
    out = draw_calibration_overlay(image, pts, calibration=calib, bboxes_3d=f.bboxes_3d, bboxes_2d=f.bboxes_2d,
                                   pairs=pairs, title="test")
    assert out.shape == image.shape and out.dtype == np.uint8
    changed = np.any(out != image, axis=2)
    assert changed.mean() > 0.005
    # the 2D boxes are drawn in green at their corners
    x1, y1 = f.bboxes_2d[pairs[0, 0], :2].astype(int)
    assert out[y1, x1, 1] > 200 and image[y1, x1, 1] == 128
    assert np.array_equal(image, np.full_like(image, 128))  # input untouched


def test_overlay_from_projection_matrix_matches_pose_form():
    f, T, pts = _scene()
    image = np.zeros((1200, 1920, 3), np.uint8)
    a = draw_calibration_overlay(image, pts, intrinsics=INTR, rotation=T[:3, :3], translation=T[:3, 3],
                                 bboxes_3d=f.bboxes_3d)
    b = draw_calibration_overlay(image, pts, projection=projection_matrix(INTR.K, T[:3, :3], T[:3, 3]),
                                 bboxes_3d=f.bboxes_3d)
    assert np.mean(np.any(a != b, axis=2)) < 1e-3


def test_overlay_honours_distortion():
    f, T, pts = _scene()
    image = np.zeros((1200, 1920, 3), np.uint8)
    dist = CameraIntrinsics(INTR.fx, INTR.fy, INTR.cx, INTR.cy, distortion=[-0.3, 0.1, 0, 0, 0])
    a = draw_calibration_overlay(image, pts, intrinsics=INTR, rotation=T[:3, :3], translation=T[:3, 3])
    b = draw_calibration_overlay(image, pts, intrinsics=dist, rotation=T[:3, :3], translation=T[:3, 3])
    assert np.mean(np.any(a != b, axis=2)) > 1e-3


def test_overlay_needs_a_pose():
    with pytest.raises(ValueError, match="calibration="):
        draw_calibration_overlay(np.zeros((10, 10, 3), np.uint8), None)


def test_cli_writes_report(tmp_path):
    from typer.testing import CliRunner

    from xcalib.cli import app
    from xcalib.io.frames import write_frame_folder

    frames, T = sim_frames(seed=1, n_frames=4)
    for f in frames:
        f.image = np.full((1200, 1920, 3), 90, np.uint8)
        f.point_cloud = np.asarray(f.bboxes_3d[:, :3], np.float32)
    src = write_frame_folder(tmp_path / "frames", frames, intrinsics=INTR)
    out = tmp_path / "report"
    res = CliRunner().invoke(app, ["calibrate", str(src), "--out", str(out), "--max-overlays", "1", "--json"])
    assert res.exit_code == 0, res.output
    d = json.loads(res.output[res.output.index("{"):])
    assert d["success"] is True
    calib = CalibrationResult.load(out / "calibration.npz")
    assert calib.pose_error(T)[0] < 0.2
    assert (out / "summary.txt").read_text().startswith("calibration OK")
    assert len(list((out / "overlays").glob("*.png"))) == 2  # refined + bring-up
