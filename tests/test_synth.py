"""Synthetic site generator: determinism, exact ground truth, LiDAR, presets, tracks, site folders."""

from __future__ import annotations

import json

import numpy as np
import pytest

from xcalib.data.synth import generate_frames, sample_site, write_site, zero_noise
from xcalib.geometry import box7_corners, iou_matrix, points_in_boxes, project_points, rotation_angle
from xcalib.geometry.boxes import boxes3d_to_extents
from xcalib.io.hdf5 import CacheReader

SMALL = dict(width=480, height=300, focal_px=(250.0, 625.0))  # same field of view as 1920x1200, f 1000-2500


def _projected_boxes(frame):
    T = frame.extrinsics
    uv, _ = project_points(box7_corners(frame.meta["box7"]).reshape(-1, 3), frame.intrinsics, T[:3, :3], T[:3, 3])
    uv = uv.reshape(-1, 8, 2)
    return np.hstack([uv.min(axis=1), uv.max(axis=1)])


def test_deterministic_and_independent_of_rendering():
    site = sample_site(3, **SMALL)
    a = generate_frames(site, 3, seed=5)
    b = generate_frames(sample_site(3, **SMALL), 3, seed=5)
    c = generate_frames(site, 2, seed=5, render_images=False, lidar=False)
    for fa, fb in zip(a, b):
        assert np.array_equal(fa.image, fb.image) and np.array_equal(fa.point_cloud, fb.point_cloud)
        assert np.array_equal(fa.bboxes_2d, fb.bboxes_2d) and np.array_equal(fa.match_matrix, fb.match_matrix)
    for fa, fc in zip(a, c):  # labels do not depend on rendering / LiDAR / sequence length
        assert np.array_equal(fa.bboxes_2d, fc.bboxes_2d) and np.array_equal(fa.bboxes_3d, fc.bboxes_3d)
        assert fc.point_cloud.shape == (0, 3)
    d = generate_frames(site, 1, seed=6, render_images=False, lidar=False)
    assert not np.array_equal(d[0].bboxes_3d, a[0].bboxes_3d)


@pytest.mark.parametrize("preset,distortion", [("roadside", False), ("roadside", True), ("vehicle", True)])
def test_ground_truth_is_exact(preset, distortion):
    """Projecting the GT 3D boxes with the written calibration reproduces the noise-free 2D boxes."""
    checked = 0
    for seed in range(3):
        site = sample_site(seed, preset, distortion=distortion, **zero_noise())
        for f in generate_frames(site, 3, seed=seed, render_images=False, lidar=False):
            proj = _projected_boxes(f)
            assert np.allclose(f.extrinsics, site.T_cam_lidar)
            full = (f.meta["visibility_2d"] >= 0.999) & (f.meta["truncation_2d"] == 0) & (f.meta["ids_2d"] >= 0)
            for i in np.flatnonzero(full):
                j = np.flatnonzero(f.match_matrix[i])
                assert len(j) <= 1  # one 3D partner at most (none when out of LiDAR range)
                if not len(j):
                    continue
                assert iou_matrix(f.bboxes_2d[i:i + 1], proj[j])[0, 0] > 0.99
                checked += 1
            # every match pairs the same object
            ii, jj = np.nonzero(f.match_matrix)
            assert np.array_equal(f.meta["ids_2d"][ii], f.meta["ids_3d"][jj])
            assert not f.match_matrix[f.meta["ids_2d"] < 0].any() and not f.match_matrix[:, f.meta["ids_3d"] < 0].any()
    assert checked >= 10


def test_occluded_boxes_shrink_to_visible_part():
    site = sample_site(0, **zero_noise())
    shrunk = 0
    for f in generate_frames(site, 4, seed=0, render_images=False, lidar=False):
        proj = _projected_boxes(f)
        part = (f.meta["visibility_2d"] < 0.9) & (f.meta["truncation_2d"] == 0) & f.match_matrix.any(axis=1)
        for i in np.flatnonzero(part):
            j = np.flatnonzero(f.match_matrix[i])[0]
            b, p = f.bboxes_2d[i], proj[j]
            assert b[0] >= p[0] - 1e-3 and b[1] >= p[1] - 1e-3 and b[2] <= p[2] + 1e-3 and b[3] <= p[3] + 1e-3
            shrunk += iou_matrix(b[None], p[None])[0, 0] < 0.99
    assert shrunk >= 1


def test_lidar_points_inside_boxes_and_dense_enough():
    site = sample_site(2, **zero_noise())
    frames = generate_frames(site, 2, seed=1, render_images=False)
    near_counts = []
    for f in frames:
        assert f.point_cloud.dtype == np.float32 and f.point_cloud.shape[1] == 3 and len(f.point_cloud) > 10000
        gt = f.meta["box7_gt"]
        inside = points_in_boxes(f.point_cloud, gt, expansion=1.01).sum(axis=1)
        true = f.meta["ids_3d"] >= 0
        # every object return lies inside its own box
        assert np.all(inside[true] >= f.meta["n_points_3d"][true])
        d = np.hypot(gt[:, 0], gt[:, 1])
        big = np.isin(np.array(f.meta["classes_3d"]), ["car", "van", "truck", "bus"])
        near_counts += list(f.meta["n_points_3d"][true & big & (d < 40)])
        # ground points: z of the ground plane in the levelled LiDAR frame
        # outside the detected boxes: ground (z = -lidar height) or objects beyond the 3D detection range
        rest = f.point_cloud[~points_in_boxes(f.point_cloud, gt, expansion=1.05).any(axis=0)]
        off = np.abs(rest[:, 2] + site.lidar_position[2]) > 1e-3
        assert off.mean() < 0.01
        assert np.all(np.hypot(rest[off, 0], rest[off, 1]) > site.config.detection_range_3d - 5)
    assert len(near_counts) >= 3 and np.median(near_counts) >= 50


def test_lidar_sees_what_camera_sees():
    site = sample_site(4)
    f = generate_frames(site, 1, seed=0, render_images=False)[0]
    T = f.extrinsics
    uv, depth = project_points(f.point_cloud, f.intrinsics, T[:3, :3], T[:3, 3])
    W, H = site.width, site.height
    ok = np.isfinite(uv[:, 0]) & (uv[:, 0] >= 0) & (uv[:, 0] < W) & (uv[:, 1] >= 0) & (uv[:, 1] < H)
    cells = np.unique((uv[ok] // np.array([W / 8, H / 8])).astype(int), axis=0)
    assert ok.sum() > 2000 and len(cells) >= 30   # points cover most of the (lower) image


@pytest.mark.parametrize("seed", range(6))
def test_preset_geometry_ranges(seed):
    r = sample_site(seed, "roadside")
    assert 5 <= r.camera_position[2] <= 12 and 1000 <= r.intrinsics.fx <= 2500
    assert (r.width, r.height) == (1920, 1200)
    T = r.T_cam_lidar
    assert rotation_angle(T[:3, :3], np.eye(3)) > 10        # not identity: tens of degrees
    off = r.lidar_position - r.camera_position
    assert 0.5 <= np.hypot(off[0], off[1]) <= 4.0 + 1e-9
    dyaw = (np.degrees(r.lidar_yaw) - r.values["camera_yaw_deg"] + 180) % 360 - 180
    assert 15 - 1e-6 <= abs(dyaw) <= 60 + 1e-6
    v = sample_site(seed, "vehicle")
    assert 0.1 <= np.linalg.norm(v.lidar_position - v.camera_position) <= 2.0
    assert 1.2 <= v.camera_position[2] <= 1.8
    # users can pin height, yaw offset and lens per site ("site B")
    b = sample_site(seed, camera_height=10.0, camera_yaw_offset_deg=20.0, focal_px=1200.0)
    assert b.camera_position[2] == 10.0 and b.intrinsics.fx == 1200.0


def test_unknown_override_is_rejected():
    with pytest.raises(TypeError, match="camera_hight"):
        sample_site(0, camera_hight=3.0)
    with pytest.raises(ValueError, match="preset"):
        sample_site(0, "drone")


def test_tracks_across_frames():
    site = sample_site(1, n_objects=20, **zero_noise())
    frames = generate_frames(site, 5, seed=2, render_images=False, lidar=False)
    moves = []
    for f0, f1 in zip(frames, frames[1:]):
        i0 = {int(t): k for k, t in enumerate(f0.meta["ids_3d"]) if t >= 0}
        common = [(i0[int(t)], k) for k, t in enumerate(f1.meta["ids_3d"]) if int(t) in i0]
        assert len(common) >= 0.7 * min(len(i0), f1.num_3d)
        for a, b in common:
            moves.append(np.linalg.norm(f1.meta["box7"][b, :2] - f0.meta["box7"][a, :2]))
    moves = np.array(moves)
    assert moves.max() <= 13.0 * 0.1 + 1e-6          # speeds <= 13 m/s at 10 Hz
    assert (moves > 0.3).sum() >= 3 and (moves < 1e-9).sum() >= 1  # moving traffic and queued vehicles


def test_noise_parameters():
    site = sample_site(0, **zero_noise())
    f = generate_frames(site, 1, seed=0, render_images=False, lidar=False)[0]
    assert np.allclose(f.meta["boxes_2d_clean"], f.bboxes_2d, atol=1e-3)
    assert (f.meta["ids_2d"] >= 0).all() and (f.meta["ids_3d"] >= 0).all()
    g = generate_frames(site, 1, seed=0, render_images=False, lidar=False, miss_rate_2d=1.0,
                        false_positive_rate_3d=1.0, box_noise_px=3.0)[0]
    assert g.num_2d == 0 and (g.meta["ids_3d"] < 0).sum() >= 1 and not g.match_matrix.any()
    h = generate_frames(site, 1, seed=0, render_images=False, lidar=False, box_noise_px=3.0)[0]
    err = h.bboxes_2d - h.meta["boxes_2d_clean"]
    assert 1.0 < np.abs(err).mean() < 6.0


def test_box_conventions():
    for conv in ("extents", "center"):
        site = sample_site(0, box_convention=conv, **zero_noise())
        f = generate_frames(site, 1, seed=0, render_images=False, lidar=False)[0]
        ext = boxes3d_to_extents(f.bboxes_3d, convention=conv)
        c = box7_corners(f.meta["box7"])
        assert np.allclose(ext[:, :3], c.min(axis=1), atol=1e-4) and np.allclose(ext[:, 3:], c.max(axis=1), atol=1e-4)


def test_rendered_image_shows_objects():
    site = sample_site(0, **SMALL, **zero_noise())
    f = generate_frames(site, 1, seed=0)[0]
    assert f.image.shape == (300, 480, 3) and f.image.dtype == np.uint8
    bg = site.background
    changed = np.any(f.image != bg, axis=2)
    for i in np.flatnonzero(f.meta["visibility_2d"] > 0.9):
        x1, y1, x2, y2 = np.round(f.bboxes_2d[i]).astype(int)
        if (x2 - x1) * (y2 - y1) >= 50:
            assert changed[y1:y2, x1:x2].mean() > 0.3   # the object is painted where its box is


def test_write_site_round_trip(tmp_path):
    out = write_site(tmp_path / "site", 3, 2, 2, seed=4, **SMALL)
    info = json.loads((out / "site.json").read_text())
    assert info["splits"]["train"]["frames"] == 3
    for split, n in (("train", 3), ("val", 2), ("test", 2)):
        with CacheReader(out / f"{split}.h5") as r:
            assert len(r) == n
            f = r[0]
            assert np.allclose(f.extrinsics, np.array(info["T_cam_lidar"]))
            assert f.intrinsics.width == 480 and f.image.shape == (300, 480, 3)
            assert f.meta["box7"].shape == (f.num_3d, 7) and len(f.meta["ids_2d"]) == f.num_2d
            assert f.meta["boxes_2d_clean"].shape == (f.num_2d, 4) and len(f.meta["visibility_2d"]) == f.num_2d
            assert f.meta["box7_gt"].shape == (f.num_3d, 7) and f.meta["classes_3d"][0] in (
                "car", "van", "truck", "bus", "pedestrian", "cyclist", "false_positive")
    with CacheReader(out / "train.h5") as a, CacheReader(out / "test.h5") as b:
        assert not np.array_equal(a[0].bboxes_3d, b[0].bboxes_3d)   # splits are different sequences


def test_cli_synth_and_cache_info(tmp_path, capsys):
    from xcalib.cli import main

    out = tmp_path / "site"
    rc = main(["synth", "--out", str(out), "--frames", "4", "--seed", "2", "--set", "width=320", "--set", "height=200",
               "--set", "focal_px=[170, 400]", "--no-lidar", "--json", "--contact-sheet", str(tmp_path / "s.png")])
    assert rc == 0
    res = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert res["splits"]["train"]["frames"] == 2 and res["splits"]["test"]["frames"] == 1
    assert (tmp_path / "s.png").stat().st_size > 1000
    assert main(["cache", "info", str(out / "train.h5"), "--json"]) == 0
    info = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert info["frames"] == 2 and info["calibration"]["camera"]["extrinsics"] == "single"
    assert main(["synth", "--out", str(out), "--preset", "drone"]) == 2
