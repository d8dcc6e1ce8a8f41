"""Waymo conventions (pure functions) and the dependency-free .tfrecord reader."""

from __future__ import annotations

import struct

import numpy as np
import pytest
from conftest import shared_path
from scipy.spatial.transform import Rotation

from xcalib.errors import FormatError
from xcalib.formats.kitti import format_kitti_calibration, parse_kitti_calibration
from xcalib.formats.waymo import (
    R_OPTICAL_FROM_FLU,
    T_cam_lidar_to_waymo_extrinsic,
    flu_to_optical,
    optical_to_flu,
    read_waymo_tfrecord,
    waymo_calibration,
    waymo_extrinsic_to_T_cam_lidar,
    waymo_intrinsics,
    waymo_T_cam_laser,
    waymo_to_kitti_calibration,
)
from xcalib.geometry import box7_corners, boxes2d_from_points, clip_boxes2d, iou_matrix, project_points, transform_points

SPEC_T_FRONT_CAM_TO_REF = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])


def test_flu_optical_axes():
    np.testing.assert_array_equal(R_OPTICAL_FROM_FLU, SPEC_T_FRONT_CAM_TO_REF)
    # forward, left, up in FLU are +z, -x, -y in optical
    np.testing.assert_allclose(flu_to_optical(np.eye(3)), [[0, 0, 1], [-1, 0, 0], [0, -1, 0]])
    pts = np.random.default_rng(0).normal(size=(10, 3))
    np.testing.assert_allclose(optical_to_flu(flu_to_optical(pts)), pts, atol=1e-15)
    assert np.linalg.det(R_OPTICAL_FROM_FLU) == pytest.approx(1.0)


def test_vehicle_to_camera_direction():
    """A camera 1.5 m ahead / 2 m above the vehicle origin, yawed 90 deg left (FLU extrinsic =
    camera -> vehicle): a point 5 m to the vehicle's left of the camera is 5 m in front of it."""
    T_vehicle_cam = np.eye(4)
    T_vehicle_cam[:3, :3] = Rotation.from_euler("z", 90, degrees=True).as_matrix()
    T_vehicle_cam[:3, 3] = [1.5, 0.0, 2.0]
    T = waymo_extrinsic_to_T_cam_lidar(T_vehicle_cam)
    np.testing.assert_allclose(transform_points(T, np.array([[1.5, 5.0, 2.0]]))[0], [0, 0, 5], atol=1e-12)
    np.testing.assert_allclose(transform_points(T, np.array([[1.5, 5.0, 3.0]]))[0], [0, -1, 5], atol=1e-12)  # up = -y
    np.testing.assert_allclose(T_cam_lidar_to_waymo_extrinsic(T), T_vehicle_cam, atol=1e-12)


def test_waymo_to_kitti_mapping_matches_spec(rng):
    T_vehicle_cam = np.eye(4)
    T_vehicle_cam[:3, :3] = Rotation.from_rotvec(rng.normal(scale=0.05, size=3)).as_matrix()
    T_vehicle_cam[:3, 3] = [1.5, -0.1, 2.1]
    intr = [2055.0, 2055.0, 939.6, 641.1, 0.03, -0.3, 0.001, -0.001, 0.0]
    kc = waymo_to_kitti_calibration(T_vehicle_cam, intr)
    spec_tr = np.eye(4)
    spec_tr[:3, :3] = SPEC_T_FRONT_CAM_TO_REF
    spec_tr = spec_tr @ np.linalg.inv(T_vehicle_cam)
    np.testing.assert_allclose(kc.Tr_velo_to_cam, spec_tr, atol=1e-12)
    np.testing.assert_array_equal(kc.R0_rect, np.eye(3))
    np.testing.assert_allclose(kc.P[2][:, :3], waymo_intrinsics(intr).K)
    np.testing.assert_array_equal(kc.P[2][:, 3], 0.0)
    # the KITTI chain and our vehicle->camera extrinsics agree, also after a text round trip
    again = parse_kitti_calibration(format_kitti_calibration(kc))
    np.testing.assert_allclose(again.T_cam_lidar(2), waymo_extrinsic_to_T_cam_lidar(T_vehicle_cam), atol=1e-12)


def test_intrinsics_order():
    k = waymo_intrinsics([2000, 2001, 960, 640, 0.1, 0.2, 0.003, 0.004, 0.05], 1920, 1280)
    assert (k.fx, k.fy, k.cx, k.cy) == (2000, 2001, 960, 640)
    np.testing.assert_allclose(k.distortion, [0.1, 0.2, 0.003, 0.004, 0.05])  # OpenCV k1 k2 p1 p2 k3
    with pytest.raises(ValueError, match="9 numbers"):
        waymo_intrinsics([1, 2, 3])


def test_truncated_tfrecord(tmp_path):
    p = tmp_path / "bad.tfrecord"
    p.write_bytes(struct.pack("<Q", 1000) + b"\0" * 20)
    with pytest.raises(FormatError, match="runs past the end"):
        read_waymo_tfrecord(p)
    p.write_bytes(struct.pack("<Q", 3) + b"\0" * 4 + b"\xff\xff\xff" + b"\0" * 4)
    with pytest.raises(FormatError, match="malformed protobuf"):
        read_waymo_tfrecord(p)


@pytest.mark.shared_data
def test_sample_tfrecord_calibrations_project_labels():
    """Laser labels (vehicle frame) projected through our FRONT camera extrinsics + intrinsics
    overlap Waymo's own projected_lidar_labels."""
    rec = read_waymo_tfrecord(shared_path("waymo", "mmdet3d_tests", "waymo_format", "validation", "val.tfrecord"))[0]
    assert rec.context_name == "1071392229495085036_1844_790_1864_790"
    assert sorted(rec.cameras) == ["FRONT", "FRONT_LEFT", "FRONT_RIGHT", "SIDE_LEFT", "SIDE_RIGHT"]
    assert len(rec.lasers) == 5 and rec.boxes7.shape == (18, 7)
    front = rec.cameras["FRONT"]
    assert (front.width, front.height) == (1920, 1280)
    # FRONT camera looks along vehicle +x: optical z axis in the vehicle frame is ~ +x
    assert front.T_cam_lidar[2, 0] > 0.99
    ious = []
    for name in ("FRONT", "FRONT_LEFT", "SIDE_LEFT"):
        cam, mm = rec.cameras[name], rec.match_matrix(name)
        i, j = np.nonzero(mm)
        assert len(i) == len(rec.camera_boxes[name])
        T = cam.T_cam_lidar
        uv, _ = project_points(box7_corners(rec.boxes7[j]).reshape(-1, 3), cam.intrinsics, T[:3, :3], T[:3, 3])
        pb = clip_boxes2d(boxes2d_from_points(uv.reshape(-1, 8, 2)), cam.width, cam.height)
        ious += np.diag(iou_matrix(pb, rec.camera_boxes[name][i])).tolist()
    print(f"waymo tfrecord: projected laser labels vs projected_lidar_labels mean IoU {np.mean(ious):.3f} "
          f"over {len(ious)} boxes")
    assert len(ious) == 17 and np.mean(ious) > 0.8
    res = waymo_calibration(rec, "FRONT")
    np.testing.assert_allclose(res.extrinsics, front.T_cam_lidar)
    # the TOP laser origin (vehicle frame ~ (1.43, 0, 2.18) m) maps to the camera like that vehicle point
    top = rec.lasers["TOP"].T_vehicle_laser
    np.testing.assert_allclose(waymo_T_cam_laser(rec, "FRONT", "TOP")[:3, 3],
                               transform_points(front.T_cam_lidar, top[None, :3, 3])[0], atol=1e-12)
