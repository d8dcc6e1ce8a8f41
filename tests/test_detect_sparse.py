"""xcalib.detect on a high, sparse LiDAR (roadside gantry): the beam step read from the cloud,
rings crossing a vehicle's roof linked into one object, and the refusal of a calibration from
weak LiDAR detections naming what is missing (issue 30)."""

from __future__ import annotations

import numpy as np
import pytest

from xcalib.detect.coverage import COVERAGE_MIN, detection_coverage, explain_refusal
from xcalib.detect.lidar import LidarDetectConfig, beam_step, lidar_boxes
from xcalib.geometry.camera import CameraIntrinsics
from xcalib.types import Frame

H = 8.0          # sensor over the ground, m
STEP = 0.35      # beam spacing, deg
CAR = (35.0, 0.0, 4.5, 1.8, 1.5)  # cx, cy, length (radial, along x), width, height


def _ring_cloud(cars=(CAR,), n_az=4096):
    """Rays of a 64-beam LiDAR ``H`` m up (elevations -30.05 .. -8 deg, every ``STEP``) hitting the
    flat ground or axis-aligned boxes standing on it (first hit); [P, 3] float32."""
    el = np.radians(np.arange(-8.0, -30.4, -STEP))
    az = np.linspace(-np.pi, np.pi, n_az, endpoint=False)
    E, A = np.meshgrid(el, az, indexing="ij")
    d = np.stack([np.cos(E) * np.cos(A), np.cos(E) * np.sin(A), np.sin(E)], -1).reshape(-1, 3)
    t = H / -d[:, 2]  # ground z = -H
    for cx, cy, length, width, height in cars:
        lo = np.array([cx - length / 2, cy - width / 2, -H])
        hi = np.array([cx + length / 2, cy + width / 2, -H + height])
        with np.errstate(divide="ignore", invalid="ignore"):
            t1, t2 = (lo - 0.0) / d, (hi - 0.0) / d
        tn = np.nanmax(np.minimum(t1, t2), axis=1)
        tf = np.nanmin(np.maximum(t1, t2), axis=1)
        hit = (tn <= tf) & (tn > 0)
        t = np.where(hit & (tn < t), tn, t)
    p = d * t[:, None]
    return p[np.hypot(p[:, 0], p[:, 1]) < 80].astype(np.float32)


def test_beam_step_is_read_from_the_cloud():
    cloud = _ring_cloud(cars=())
    assert np.degrees(beam_step(cloud)) == pytest.approx(STEP, abs=0.05)
    rng = np.random.default_rng(0)
    assert beam_step(rng.uniform(-30, 30, (20000, 3))) == 0.0  # no rings: no step


def test_rings_across_a_roof_far_from_a_high_lidar_make_one_vehicle():
    cloud = _ring_cloud()
    # from 8 m up at 35 m, the rings cross the roof ~1.2 m apart: a 0.4 m grid alone cuts the car in stripes
    boxes = lidar_boxes(cloud, LidarDetectConfig(max_link_m=0.4))
    assert len(boxes) != 1 or boxes[0, 3] < 3.0
    boxes = lidar_boxes(cloud)
    assert len(boxes) == 1
    cx, cy, _, length, width, height, yaw = boxes[0]
    assert np.hypot(cx - CAR[0], cy - CAR[1]) < 0.8
    assert 3.0 < length <= CAR[2] + 0.3  # the roof's far end falls between two rings
    assert width == pytest.approx(CAR[3], abs=0.5)
    assert abs(np.sin(yaw)) < 0.2  # length along x, as the car stands


def _frames(n_3d_in_view: int):
    """4 frames of 6 camera boxes each, of which ``n_3d_in_view`` have their 3D box (camera =
    LiDAR frame rotated to look along +x)."""
    K = CameraIntrinsics(fx=1000.0, fy=1000.0, cx=960.0, cy=600.0, width=1920, height=1200)
    T = np.eye(4)
    T[:3, :3] = [[0, -1, 0], [0, 0, -1], [1, 0, 0]]  # x forward -> z forward
    frames = []
    for k in range(4):
        b3, b2 = [], []
        for j in range(6):
            x, y = 15.0 + 5 * j, -6.0 + 2.4 * j
            box = np.array([x, y, -0.75, 4.5, 1.8, 1.5, 0.0])
            c = np.array([[x + sx * 2.25, y + sy * 0.9, -0.75 + sz * 0.75] for sx in (-1, 1) for sy in (-1, 1)
                          for sz in (-1, 1)])
            cam = c @ T[:3, :3].T
            uv = cam[:, :2] / cam[:, 2:] * 1000 + [960, 600]
            b2.append([*uv.min(0), *uv.max(0)])
            if j < n_3d_in_view:
                b3.append(box)
        frames.append(Frame(np.zeros((1200, 1920, 3), np.uint8), np.zeros((0, 3), np.float32),
                            np.asarray(b2, np.float32), np.asarray(b3, np.float32).reshape(-1, 7), intrinsics=K))
    return frames, T, K


def test_refusal_from_weak_lidar_detections_names_them():
    from xcalib.calib.diagnostics import CalibDiagnostics
    from xcalib.calib.result import CalibrationResult

    frames, T, K = _frames(2)
    cov = detection_coverage(frames, T, K)
    assert (cov.boxes_2d, cov.boxes_3d, cov.in_view_3d, cov.covered_2d) == (24, 8, 8, 8)
    assert cov.share == pytest.approx(1 / 3) and cov.too_few()
    res = CalibrationResult(success=False, message="model misfit: principal point moved",
                            diagnostics=CalibDiagnostics(refused_T=T.tolist()))
    out = explain_refusal(res, frames, K)
    assert out.message.startswith("too few LiDAR objects detected: 33 % of the camera's 24 boxes")
    assert "the calibration's verdict: model misfit" in out.message and "own 3D detections" in out.message
    assert out.meta["detection_coverage"]["covered_2d"] == 8 and out.boxes_source == "xcalib detect"
    # enough LiDAR boxes: the calibration's own verdict stands
    frames, T, K = _frames(6)
    assert detection_coverage(frames, T, K).share == 1.0 > COVERAGE_MIN
    assert explain_refusal(res, frames, K).message == res.message
    # no refused pose: the counts alone (8 LiDAR boxes for 24 camera boxes)
    frames, _, K = _frames(2)
    bare = CalibrationResult(success=False, message="too few pairs")
    assert explain_refusal(bare, frames, K).message.startswith("too few LiDAR objects detected: 8 LiDAR boxes")


def test_refusal_when_the_detectors_found_almost_nothing_does_not_tell_to_run_detect():
    """`calibrate --detect` on frames where the camera detector finds nothing (a synthetic render,
    a night image): the calibration's own hint ("`xcalib calibrate --detect` makes them") would
    tell the user to do what they did; the refusal names the detector that found too few."""
    import dataclasses

    from xcalib.calib.result import CalibrationResult

    frames, _, K = _frames(2)
    blind = [dataclasses.replace(f, bboxes_2d=np.zeros((0, 4))) for f in frames]
    res = CalibrationResult(success=False, message="too few detections: 0 valid 2D and 8 3D boxes over 2 frame(s); "
                            "the frames carry no 2D boxes: `xcalib calibrate --detect` (or `xcalib detect`) makes them")
    out = explain_refusal(res, blind, K)
    assert out.message.startswith("too few objects detected to calibrate")
    assert "camera detector" in out.message and "found 0 object(s) in 4 image(s)" in out.message
    assert "LiDAR detector" not in out.message and "--detect`" not in out.message
    assert out.meta["detection_coverage"]["boxes_2d"] == 0
    # the LiDAR side found too few as well: both are named
    none3 = [dataclasses.replace(f, bboxes_2d=np.zeros((0, 4)), bboxes_3d=f.bboxes_3d[:1]) for f in frames]
    both = explain_refusal(res, none3[:1], K).message
    assert "camera detector" in both and "LiDAR detector found 1 object(s) in 1 cloud(s)" in both
