"""Realism suite (xcalib.data.synth.realism): each condition produces what it claims."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from xcalib.data.synth import sample_site
from xcalib.data.synth.realism import (REALISM_CONDITIONS, RealismCondition, make_realism_case,
                                       register_condition, second_camera_site)
from xcalib.geometry import box7_corners, iou_matrix, project_points

EXACT = dict(box_noise_px=0.0, miss_rate_2d=0.0, false_positive_rate_2d=0.0, miss_rate_3d=0.0)
SEED = 0  # an identifiable roadside site


def _project(box7, intr, T):
    uv, _ = project_points(box7_corners(box7).reshape(-1, 3), intr, T[:3, :3], T[:3, 3])
    uv = uv.reshape(-1, 8, 2)
    return np.hstack([uv.min(axis=1), uv.max(axis=1)])


def _full_pairs(frame):
    """(2D row, 3D row) of fully visible, untruncated true objects seen by both sensors."""
    m = frame.meta
    full = (m["visibility_2d"] >= 0.999) & (m["truncation_2d"] == 0) & (m["ids_2d"] >= 0)
    col = {int(t): j for j, t in enumerate(m["ids_3d"]) if t >= 0}
    return [(i, col[int(m["ids_2d"][i])]) for i in np.flatnonzero(full) if int(m["ids_2d"][i]) in col]


def test_registry_and_given_intrinsics():
    names = set(REALISM_CONDITIONS)
    for want in ("clean", "focal+20%", "focal-5%", "principal_point+3%W", "time_offset_0.05s", "no_yaw",
                 "blind_ring", "queues", "second_camera_30%", "second_camera_all", "second_camera_half_frames",
                 "mirrored", "box3d_noise", "dropout"):
        assert want in names
    with pytest.raises(ValueError):
        register_condition(REALISM_CONDITIONS["clean"])
    with pytest.raises(ValueError, match="second_camera"):
        RealismCondition("bad", "", second_camera="some")
    clean = make_realism_case("clean", SEED, 2)
    for name, scale in (("focal+20%", 1.2), ("focal-10%", 0.9)):
        c = make_realism_case(name, SEED, 2)
        assert c.intrinsics_given.fx == pytest.approx(scale * c.intrinsics_true.fx)
        assert c.intrinsics_given.fy == pytest.approx(scale * c.intrinsics_true.fy)
        assert c.intrinsics_true == clean.intrinsics_true and np.allclose(c.T_cam_lidar, clean.T_cam_lidar)
        assert all(f.intrinsics == c.intrinsics_given and f.extrinsics is None for f in c.frames)
        assert np.array_equal(c.frames[1].bboxes_2d, clean.frames[1].bboxes_2d)  # only the given K differs
    pp = make_realism_case("principal_point+3%W", SEED, 1)
    assert pp.intrinsics_given.cx - pp.intrinsics_true.cx == pytest.approx(0.03 * 1920)
    assert pp.intrinsics_given.fx == pp.intrinsics_true.fx


def test_time_offset_2d_boxes_see_the_scene_at_camera_time():
    cond = RealismCondition("t-0.2", "", time_offset_s=-0.2, vehicle_speed_mps=(10.0, 10.0), **EXACT)
    case = make_realism_case(cond, SEED, 3)
    assert case.time_offset_s == -0.2
    moved = 0
    for f in case.frames:
        assert f.camera_time_s - f.lidar_time_s == pytest.approx(-0.2)
        assert np.array_equal(f.track_ids_3d, f.meta["ids_3d"]) and f.velocities_3d.shape == (f.num_3d, 3)
        for i, j in _full_pairs(f):
            b7 = f.meta["box7_gt"][j].copy()
            v = f.velocities_3d[j]
            b7[:3] += v * case.time_offset_s  # where the object was at the camera time
            iou_moved = iou_matrix(f.bboxes_2d[i:i + 1], _project(b7[None], case.intrinsics_true, case.T_cam_lidar))
            assert iou_moved[0, 0] > 0.99
            if np.linalg.norm(v) > 5:
                iou_lidar = iou_matrix(f.bboxes_2d[i:i + 1],
                                       _project(f.meta["box7_gt"][j][None], case.intrinsics_true, case.T_cam_lidar))
                moved += iou_lidar[0, 0] < 0.97
    assert moved >= 2


def test_mirrored_flips_u_and_second_camera_comes_from_another_pose():
    clean = make_realism_case(RealismCondition("c", "", **EXACT), SEED, 2)
    mir = make_realism_case(RealismCondition("m", "", mirrored=True, **EXACT), SEED, 2)
    for a, b in zip(clean.frames, mir.frames):
        assert np.allclose(b.bboxes_2d[:, [0, 2]], 1920 - a.bboxes_2d[:, [2, 0]])
        assert np.array_equal(a.bboxes_2d[:, [1, 3]], b.bboxes_2d[:, [1, 3]])
    site = sample_site(SEED)
    site2 = second_camera_site(site)
    T2 = site2.T_cam_lidar
    assert np.allclose(site2.T_world_lidar, site.T_world_lidar) and not np.allclose(T2, site.T_cam_lidar)
    case = make_realism_case(RealismCondition("s", "", second_camera="all_boxes", **EXACT), SEED, 2)
    iou2, iou1 = [], []
    for f in case.frames:
        cam2 = np.array([c == site2.camera_name for c in f.meta["camera_2d"]])
        assert 0 < cam2.sum() < f.num_2d
        col = {int(t): j for j, t in enumerate(f.meta["ids_3d"]) if t >= 0}
        for i in np.flatnonzero(cam2 & (f.meta["ids_2d"] >= 0)):
            j = col.get(int(f.meta["ids_2d"][i]))
            if j is not None:
                b7 = f.meta["box7_gt"][j][None]
                iou2.append(iou_matrix(f.bboxes_2d[i:i + 1], _project(b7, site.intrinsics, T2))[0, 0])
                iou1.append(iou_matrix(f.bboxes_2d[i:i + 1], _project(b7, site.intrinsics, site.T_cam_lidar))[0, 0])
    assert len(iou2) >= 3 and np.median(iou2) > 0.9 and np.median(iou1) < 0.3
    half = make_realism_case("second_camera_half_frames", SEED, 2)
    assert set(half.frames[1].meta["camera_2d"]) == {site2.camera_name}
    assert set(half.frames[0].meta["camera_2d"]) == {site.camera_name}


def test_lidar_side_conditions():
    ny = make_realism_case(dataclasses.replace(REALISM_CONDITIONS["no_yaw"], lidar_points=False), SEED, 1)
    f = ny.frames[0]
    assert f.bboxes_3d.shape[1] == 6 and "box7" not in f.meta
    true = f.meta["ids_3d"] >= 0
    assert np.allclose((f.bboxes_3d[:, 3] - f.bboxes_3d[:, 0])[true], f.meta["box7_gt"][true, 3], atol=1e-4)
    br = make_realism_case("blind_ring", SEED, 3)
    for f in br.frames:
        true = f.meta["ids_3d"] >= 0
        assert np.all(np.hypot(*f.meta["box7_gt"][true, :2].T) > 15.0)
    q, c = make_realism_case("queues", SEED, 20), make_realism_case("clean", SEED, 20)
    speed = lambda case: np.concatenate([np.linalg.norm(f.velocities_3d, axis=1) for f in case.frames])  # noqa: E731
    assert np.mean(speed(q) == 0) > np.mean(speed(c) == 0)
    noisy = make_realism_case("box3d_noise", SEED, 1).frames[0]
    true = noisy.meta["ids_3d"] >= 0
    d = noisy.meta["box7"][true, :3] - noisy.meta["box7_gt"][true, :3]
    assert 0.03 < np.std(d) < 0.3
