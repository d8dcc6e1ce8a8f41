"""Calibration pieces in a camera model's own image: dense outlines, the calib dispatch, the
result round trip, synthetic wide-angle sites (no full calibration here: see
benchmarks/bench_camera_models.py for the measured runs)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from xcalib.calib.boxproj import project_rects
from xcalib.calib.hypotheses import bearings
from xcalib.calib.inputs import as_intrinsics
from xcalib.calib.result import CalibrationResult
from xcalib.data.synth import generate_frames, sample_site
from xcalib.data.synth.site import WIDE_ANGLE_PARAMS
from xcalib.geometry import CameraIntrinsics, box7_corners, project_points
from xcalib.geometry.camera_models import (DoubleSphere, KannalaBrandt, PinholeRadtan, densify_box_edges,
                                           project_outline_rects)

KB = KannalaBrandt(fx=300, fy=300, cx=640, cy=400, width=1280, height=800, k=(0.03, -0.006, 0.001, -0.0002))


def _near_boxes(n=60, seed=0):
    rng = np.random.default_rng(seed)
    ang = rng.uniform(-1.4, 1.4, n)
    d = rng.uniform(3, 9, n)
    b7 = np.column_stack([d * np.sin(ang), rng.uniform(-1, 1.5, n), d * np.cos(ang), rng.uniform(4, 12, n),
                          np.full(n, 2.5), np.full(n, 3.0), rng.uniform(-3, 3, n)])
    return box7_corners(b7)


def test_dense_outline_is_the_box_image_not_the_corner_rectangle():
    c = _near_boxes()
    ref, vr = project_outline_rects(c, np.eye(3), np.zeros(3), KB, (1280, 800), samples=60)
    uvc, okc = KB.project(c.reshape(-1, 3))  # the rectangle of the 8 projected corners alone
    uvc = uvc.reshape(len(c), 8, 2)
    corners_only = np.concatenate([uvc.min(1), uvc.max(1)], axis=1).clip(0, [1280, 800, 1280, 800])
    vc = okc.reshape(len(c), 8).all(1)
    dense, vd = project_outline_rects(c, np.eye(3), np.zeros(3), KB, (1280, 800))
    ok = vr & vc & vd
    assert ok.sum() > 40
    # the curved edges bulge past the 8 corners' rectangle by tens of pixels near the rim ...
    assert np.percentile(np.abs(corners_only - ref)[ok], 95) > 5.0
    # ... and the adaptive dense outline follows them
    assert np.percentile(np.abs(dense - ref)[ok], 95) < 0.01
    # the outline never lies inside the corners' rectangle
    assert np.all(dense[ok][:, :2] <= corners_only[ok][:, :2] + 1e-9)
    assert np.all(dense[ok][:, 2:] >= corners_only[ok][:, 2:] - 1e-9)


def test_densify_uses_the_12_box_edges_or_all_segments():
    c = _near_boxes(3)
    assert densify_box_edges(c, 2).shape == (3, 8 + 12 * 2, 3)
    shuffled = c[:, [3, 0, 6, 1, 7, 2, 5, 4]]  # not box7_corners' order: every segment between points
    assert densify_box_edges(shuffled, 2).shape == (3, 8 + 28 * 2, 3)
    hull = np.zeros((3, 11, 3))
    assert densify_box_edges(hull, 2) is not None and densify_box_edges(hull, 2).shape == (3, 11, 3)


def test_boxproj_dispatches_on_the_camera_model_and_keeps_the_pinhole_path():
    c = _near_boxes(60)
    intr = CameraIntrinsics(500, 500, 640, 400, [-0.1, 0.01, 0, 0, 0], 1280, 800)
    R, t = np.eye(3), np.zeros(3)
    rects, valid = project_rects(c, R, t, intr, (1280, 800))
    again, valid2 = project_rects(c, R, t, intr, (1280, 800))
    np.testing.assert_array_equal(rects, again)
    fish, vf = project_rects(c, R, t, KB, (1280, 800))
    ref, vr = project_outline_rects(c, R, t, KB, (1280, 800))
    np.testing.assert_array_equal(fish, ref)
    np.testing.assert_array_equal(vf, vr)
    # boxes beside and behind the image plane are in a fisheye's view, never in a pinhole's
    side = c[:, :, 2] < 0.3
    assert not valid[side.any(1)].any()
    assert vf[side.any(1)].any()


def test_as_intrinsics_keeps_wide_angle_models_and_pinhole_results_identical():
    assert as_intrinsics(KB) is KB
    ph = PinholeRadtan(fx=500, fy=500, cx=640, cy=400, width=1280, height=800, distortion=(-0.1, 0.01, 0, 0))
    got = as_intrinsics(ph)
    assert isinstance(got, CameraIntrinsics) and got == ph.to_intrinsics()
    assert as_intrinsics(KB.to_dict()) == KB
    assert isinstance(as_intrinsics({"model": "pinhole", "fx": 1, "fy": 1, "cx": 0, "cy": 0}), CameraIntrinsics)
    with pytest.raises(ValueError, match="alpha"):
        as_intrinsics({"model": "double_sphere", "fx": 1, "fy": 1, "cx": 0, "cy": 0, "xi": 0.1, "alpha": 7})


def test_bearings_of_a_model_are_its_rays_past_90_degrees():
    P = np.array([[1.0, 0.2, -0.3], [0.0, 0.0, 1.0], [-2.0, 1.0, 0.1]])
    uv, ok = KB.project(P)
    assert ok.all()
    np.testing.assert_allclose(bearings(KB, uv), P / np.linalg.norm(P, axis=1, keepdims=True), atol=1e-9)


def test_result_round_trip_keeps_the_model(tmp_path):
    T = np.eye(4)
    T[:3, 3] = [0.1, -0.2, 0.3]
    res = CalibrationResult(success=True, intrinsics=KB, rotation=T[:3, :3], translation=T[:3, 3], message="")
    back = CalibrationResult.from_dict(res.to_dict())
    assert back.intrinsics == KB
    P = np.array([[3.0, 0.5, -0.5], [1.0, 1.0, 5.0]])  # one beside-behind the image plane
    uv, _ = back.project(P)
    np.testing.assert_allclose(uv, KB.project(P + T[:3, 3])[0])
    assert np.isfinite(uv).all()
    res.save(tmp_path / "r.npz")
    with np.load(tmp_path / "r.npz") as z:
        assert np.isnan(z["dist_coeffs"]).all() and np.isnan(z["projection"]).all()  # never a pinhole K + D


def test_result_json_has_no_pinhole_projection_for_a_wide_angle_model(tmp_path):
    """calibration.json: a fisheye's ``projection`` is null with a note naming the model (K [R|t] is
    no projection of its image); a pinhole result keeps K [R|t] and gets no new key."""
    import json

    T = np.eye(4)
    T[:3, 3] = [0.1, -0.2, 0.3]
    res = CalibrationResult(success=True, intrinsics=KB, rotation=T[:3, :3], translation=T[:3, 3], message="")
    d = json.loads((res.save(tmp_path / "kb.json")).read_text())
    assert d["projection"] is None and "kannala_brandt" in d["projection_note"] and "intrinsics" in d["projection_note"]
    assert not res.has_projection_matrix
    with pytest.raises(ValueError, match="kannala_brandt"):
        res.projection
    back = CalibrationResult.load(tmp_path / "kb.json")
    assert back.intrinsics == KB and np.allclose(back.extrinsics, T)
    pin = CalibrationResult(success=True, intrinsics=CameraIntrinsics(500, 500, 320, 240, None, 640, 480),
                            rotation=T[:3, :3], translation=T[:3, 3], message="")
    d = pin.to_dict()
    assert "projection_note" not in d and pin.has_projection_matrix
    np.testing.assert_allclose(d["projection"], pin.K @ T[:3], atol=1e-12)


def test_project_points_dispatches_on_a_model():
    P = np.array([[1.0, 0.0, -0.2], [0.0, 0.0, 4.0]])
    uv, depth = project_points(P, KB)
    np.testing.assert_allclose(uv, KB.project(P)[0])
    np.testing.assert_allclose(depth, P[:, 2])
    with pytest.raises(ValueError, match="own distortion"):
        project_points(P, KB, dist=[0.1, 0, 0, 0])


@pytest.mark.parametrize("model", sorted(WIDE_ANGLE_PARAMS))
def test_synthetic_wide_angle_site_spans_the_field_of_view(model):
    site = sample_site(3, camera_model=model, hfov_deg=185.0, width=640, height=400)
    assert site.intrinsics.name == model
    h, _ = site.intrinsics.field_of_view()
    assert h == pytest.approx(185.0, abs=0.5)
    assert site.values["hfov_deg"] == 185.0


def test_synthetic_fisheye_boxes_are_the_dense_outlines_at_the_true_pose():
    site = sample_site(1, camera_model="kannala_brandt", hfov_deg=170.0, width=960, height=600, box_noise_px=0.0)
    frames = generate_frames(site, 3, seed=1, render_images=False, lidar=False)
    T = site.T_cam_lidar
    checked = 0
    for fr in frames:
        m = fr.meta
        full = (m["visibility_2d"] >= 1.0) & (m["truncation_2d"] <= 0.0) & (m["ids_2d"] >= 0)
        for i in np.flatnonzero(full):
            j = np.flatnonzero(m["ids_3d"] == m["ids_2d"][i])
            if len(j) != 1:
                continue
            rect, ok = project_rects(box7_corners(m["box7_gt"][j]), T[:3, :3], T[:3, 3], site.intrinsics,
                                     (960, 600))
            assert ok[0]
            np.testing.assert_allclose(rect[0], m["boxes_2d_clean"][i], atol=0.5)
            checked += 1
    assert checked >= 5


def test_synthetic_site_rejects_bad_lens_settings():
    with pytest.raises(ValueError, match="hfov_deg: a kannala_brandt camera needs"):
        sample_site(0, camera_model="kannala_brandt")
    with pytest.raises(ValueError, match="unknown camera model"):
        sample_site(0, camera_model="scaramuzza", hfov_deg=120)
    with pytest.raises(ValueError, match="expected 10..179"):
        sample_site(0, hfov_deg=185)
    pin = sample_site(0, hfov_deg=90.0, width=1280, height=800)
    assert pin.intrinsics.fx == pytest.approx(640.0)
    assert isinstance(DoubleSphere(fx=1, fy=1, cx=0, cy=0, xi=0.0, alpha=0.5), DoubleSphere)
    assert math.isfinite(pin.intrinsics.fy)


def test_bag_equidistant_camera_can_stay_a_fisheye():
    """io.bags: an equidistant CameraInfo is the kannala_brandt model itself (``fisheye="keep"``)."""
    import cv2

    from xcalib.io.bags import _convert as cv
    from xcalib.io.bags.reader import BagFrames

    K = np.array([[300.0, 0, 320], [0, 301.0, 240], [0, 0, 1]])
    D = np.array([0.08, -0.02, 0.004, -0.001])
    fe = cv.Fisheye(K, D, (640, 480), K)
    cam = fe.camera_model
    assert cam.name == "kannala_brandt" and (cam.width, cam.height) == (640, 480)
    P = np.array([[0.5, -0.2, 1.0], [1.5, 0.7, 1.0]])
    ref, _ = cv2.fisheye.projectPoints(P.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K, D)
    np.testing.assert_allclose(cam.project(P)[0], ref.reshape(-1, 2), atol=1e-8)
    with pytest.raises(ValueError, match="fisheye must be 'rectify' or 'keep'"):
        BagFrames("missing.bag", fisheye="undistort")


def test_bag_of_a_fisheye_site_keeps_the_fisheye(tmp_path):
    """A synthetic Kannala-Brandt site written to a bag gets an ``equidistant`` CameraInfo, and reads
    back (``fisheye="keep"``) as the same camera model with the same 2D boxes (the fisheye image's
    own); a model CameraInfo cannot express is refused by the writer, never written as another."""
    from xcalib.data.synth import generate_frames, sample_site
    from xcalib.geometry import CameraIntrinsics
    from xcalib.io.bags.reader import BagFrames
    from xcalib.io.bags.writer import write_bag

    site = sample_site(3, camera_model="kannala_brandt", hfov_deg=185, width=320, height=200, box_noise_px=1.0)
    frames = generate_frames(site, 2, seed=3, render_images=False)
    path = write_bag(tmp_path / "fe.mcap", frames)
    kept = BagFrames(path, fisheye="keep")
    assert len(kept) == 2
    for f, g in zip(kept, frames):
        assert f.intrinsics == site.intrinsics and f.intrinsics.name == "kannala_brandt"
        np.testing.assert_allclose(np.asarray(f.bboxes_2d, dtype=np.float64), g.bboxes_2d, atol=1e-3)
    assert isinstance(BagFrames(path)[0].intrinsics, CameraIntrinsics)  # the default: rectified to a pinhole
    ds = sample_site(3, camera_model="double_sphere", hfov_deg=185, width=320, height=200)
    with pytest.raises(ValueError, match="CameraInfo cannot express a double_sphere camera"):
        write_bag(tmp_path / "ds.mcap", generate_frames(ds, 1, seed=3, render_images=False))
    assert not (tmp_path / "ds.mcap").exists()
