"""Calibration export registry: every format round-trips, detection, bad input."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from xcalib.calib.result import CalibrationResult
from xcalib.errors import FormatError
from xcalib.formats.export import FORMATS, detect_format, export_calibration, format_names, read_calibration
from xcalib.geometry import CameraIntrinsics, transform_points

# formats that store the distortion / the image size
KEEPS_DIST = {"calib_json", "lucid", "calib_txt", "opencalib", "openlabel", "ros", "json", "npz"}
KEEPS_SIZE = {"lucid", "opencalib", "openlabel", "ros", "json", "npz"}


def _result(seed: int, dist) -> CalibrationResult:
    rng = np.random.default_rng(seed)
    R = Rotation.from_rotvec(rng.normal(size=3)).as_matrix()
    return CalibrationResult(success=True, intrinsics=CameraIntrinsics(1234.5678, 1230.25, 960.3, 540.7, dist,
                                                                       1920, 1080),
                             rotation=R, translation=rng.normal(scale=2.0, size=3), camera_name="cam_front",
                             method="test")


EXTRINSICS_ONLY = {"urdf", "tf_static"}


@pytest.mark.parametrize("fmt", format_names(writable=True))
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_every_format_roundtrips(tmp_path, fmt, seed):
    dist = [-0.11, 0.05, 0.001, -0.0007, 0.012] if seed != 2 else [-0.1, 0.02, 1e-3, 2e-4, 0.01, 0.3, 0.02, 0.001]
    res = _result(seed, np.array(dist))
    written = export_calibration(res, fmt, tmp_path / FORMATS[fmt].filename)
    assert all(p.is_file() for p in written)
    assert detect_format(written[0]) == fmt
    back = read_calibration(written[0])
    np.testing.assert_allclose(back.rotation, res.rotation, atol=1e-9, rtol=0)
    np.testing.assert_allclose(back.translation, res.translation, atol=1e-6, rtol=0)
    if fmt in EXTRINSICS_ONLY:  # tf_static / URDF hold the transform only
        assert back.intrinsics is None
    else:
        np.testing.assert_allclose(back.K, res.K, atol=1e-9, rtol=0)
    # direction: a LiDAR point lands at the same camera point through both
    p = np.array([[12.0, -3.0, 1.0]])
    np.testing.assert_allclose(transform_points(back.extrinsics, p), transform_points(res.extrinsics, p), atol=1e-6)
    if fmt in KEEPS_DIST and fmt not in EXTRINSICS_ONLY:
        n = len(dist)
        np.testing.assert_allclose(back.intrinsics.distortion[:n], dist, atol=1e-12)
    if fmt in KEEPS_SIZE and fmt not in EXTRINSICS_ONLY:
        assert (back.intrinsics.width, back.intrinsics.height) == (1920, 1080)


def test_refuses_failed_and_intrinsics_free(tmp_path):
    with pytest.raises(ValueError, match="failed"):
        export_calibration(CalibrationResult(success=False, message="no pairs"), "kitti", tmp_path / "c.txt")
    with pytest.raises(ValueError, match="intrinsics"):
        export_calibration(CalibrationResult(success=True, rotation=np.eye(3), translation=np.zeros(3)), "lucid",
                           tmp_path / "l.json")
    with pytest.raises(ValueError, match="unknown calibration format"):
        export_calibration(_result(0, None), "pdf", tmp_path / "x")
    with pytest.raises(ValueError, match="read-only"):
        export_calibration(_result(0, None), "waymo", tmp_path / "x")


def test_detect_rejects_unknown_json(tmp_path):
    p = tmp_path / "x.json"
    p.write_text(json.dumps({"hello": 1}))
    with pytest.raises(FormatError, match="unrecognised"):
        detect_format(p)
    p.write_text("{not json")
    with pytest.raises(FormatError, match="not valid JSON"):
        read_calibration(p)


def test_openlabel_chain_and_conflict(tmp_path):
    """Camera and LiDAR both children of a base: T_cam_lidar = inv(T_base_cam) @ T_base_lidar."""
    from xcalib.formats.openlabel import read_openlabel

    rng = np.random.default_rng(3)
    T_base_cam, T_base_lidar = np.eye(4), np.eye(4)
    T_base_cam[:3, :3] = Rotation.from_rotvec(rng.normal(size=3)).as_matrix()
    T_base_cam[:3, 3] = rng.normal(size=3)
    T_base_lidar[:3, :3] = Rotation.from_rotvec(rng.normal(size=3)).as_matrix()
    T_base_lidar[:3, 3] = rng.normal(size=3)
    d = {"openlabel": {
        "coordinate_systems": {
            "base": {"type": "local_cs", "parent": ""},
            "cam": {"type": "sensor_cs", "parent": "base", "pose_wrt_parent": {"matrix4x4": T_base_cam.ravel().tolist()}},
            "lid": {"type": "sensor_cs", "parent": "base",
                    "pose_wrt_parent": {"translation": T_base_lidar[:3, 3].tolist(),
                                        "quaternion": Rotation.from_matrix(T_base_lidar[:3, :3]).as_quat().tolist()}}},
        "streams": {"cam": {"type": "camera", "stream_properties": {"intrinsics_pinhole": {
            "camera_matrix_3x4": [800, 0, 640, 0, 0, 800, 360, 0, 0, 0, 1, 0]}}}, "lid": {"type": "lidar"}}}}
    p = tmp_path / "ol.json"
    p.write_text(json.dumps(d))
    r = read_openlabel(p)
    np.testing.assert_allclose(r.extrinsics, np.linalg.inv(T_base_cam) @ T_base_lidar, atol=1e-12)
    d["openlabel"]["coordinate_systems"]["cam"]["pose_wrt_parent"]["quaternion"] = [0, 0, 0, 1]
    p.write_text(json.dumps(d))
    with pytest.raises(FormatError) as ei:
        read_openlabel(p)
    assert ei.value.field == "coordinate_systems.cam.pose_wrt_parent.quaternion"


def test_ros_static_transform_direction(tmp_path):
    """The tf pose is the camera in the LiDAR frame: its translation is the camera centre."""
    import yaml

    res = _result(4, None)
    cam_info, tf = export_calibration(res, "ros", tmp_path / "camera_info.yaml")
    t = yaml.safe_load(tf.read_text())
    centre = -res.rotation.T @ res.translation  # camera origin in LiDAR coordinates
    tr = t["transform"]["translation"]
    np.testing.assert_allclose([tr["x"], tr["y"], tr["z"]], centre, atol=1e-12)
    assert t["header"]["frame_id"] == "lidar" and t["child_frame_id"] == "cam_front_optical_frame"
    info = yaml.safe_load(cam_info.read_text())
    assert info["distortion_model"] == "plumb_bob" and info["image_width"] == 1920
    good = tf.read_text()
    t["transform"]["rotation"] = {"x": 0.0, "y": 0.0, "z": 0.0, "w": 0.0}
    tf.write_text(yaml.safe_dump(t))
    with pytest.raises(FormatError, match="zero norm") as ei:
        read_calibration(cam_info)
    assert ei.value.field == "transform.rotation"
    t["transform"]["rotation"]["w"] = 2.0
    tf.write_text(yaml.safe_dump(t))
    with pytest.raises(FormatError, match="norm is 2"):
        read_calibration(cam_info)
    tf.write_text(good)
    assert read_calibration(cam_info).success


def test_nuscenes_record_direction():
    from xcalib.formats.nuscenes import T_to_calibrated_sensor, calibrated_sensor_to_T, nuscenes_T_cam_lidar

    # camera 1.5 m ahead of ego, looking forward (optical axes), lidar 2 m above ego origin
    R_ego_cam = np.array([[0.0, 0, 1], [-1, 0, 0], [0, -1, 0]])
    cam = {"translation": [1.5, 0, 1.6], "rotation": Rotation.from_matrix(R_ego_cam).as_quat(scalar_first=True).tolist()}
    lid = {"translation": [0, 0, 2.0], "rotation": [1, 0, 0, 0]}
    T = nuscenes_T_cam_lidar(cam, lid)
    # a point 10 m ahead of the lidar at lidar height is 8.5 m in front of the camera, 0.4 m up (y -0.4)
    np.testing.assert_allclose(transform_points(T, np.array([[10.0, 0, 0]]))[0], [0, -0.4, 8.5], atol=1e-12)
    rec = T_to_calibrated_sensor(calibrated_sensor_to_T(cam))
    np.testing.assert_allclose(calibrated_sensor_to_T(rec), calibrated_sensor_to_T(cam), atol=1e-12)
    with pytest.raises(FormatError, match="zero norm"):
        calibrated_sensor_to_T({"translation": [0, 0, 0], "rotation": [0, 0, 0, 0]}, "cs.json")


def test_euler_quaternion_matrix_conventions_agree_with_scipy():
    """Every quaternion / Euler field each writer emits decodes with scipy to the stated rotation."""
    from xcalib.formats.calibanything import T_cam_lidar_to_lucid_pose
    from xcalib.formats.nuscenes import T_to_calibrated_sensor
    from xcalib.formats.openlabel import openlabel_dict
    from xcalib.formats.ros import static_transform_dict

    rng = np.random.default_rng(7)
    for seed in range(15):
        res = _result(seed, None)
        T_lc = np.linalg.inv(res.extrinsics)  # camera -> LiDAR (camera pose in the LiDAR frame)
        pose = T_cam_lidar_to_lucid_pose(res.extrinsics)
        R_e = Rotation.from_euler("xyz", [pose["roll"], pose["pitch"], pose["yaw"]], degrees=True).as_matrix()
        q = pose["quaternion"]
        np.testing.assert_allclose(R_e, T_lc[:3, :3], atol=1e-9)
        np.testing.assert_allclose(Rotation.from_quat([q["x"], q["y"], q["z"], q["w"]]).as_matrix(), T_lc[:3, :3],
                                   atol=1e-12)
        T_ego = np.eye(4)
        T_ego[:3, :3] = Rotation.from_rotvec(rng.normal(size=3)).as_matrix()
        rec = T_to_calibrated_sensor(T_ego)
        np.testing.assert_allclose(Rotation.from_quat(rec["rotation"], scalar_first=True).as_matrix(), T_ego[:3, :3],
                                   atol=1e-12)
        r = static_transform_dict(res.extrinsics)["transform"]["rotation"]
        np.testing.assert_allclose(Rotation.from_quat([r["x"], r["y"], r["z"], r["w"]]).as_matrix(), T_lc[:3, :3],
                                   atol=1e-12)
        cs = openlabel_dict(res)["openlabel"]["coordinate_systems"]["cam_front"]["pose_wrt_parent"]
        np.testing.assert_allclose(Rotation.from_quat(cs["quaternion"]).as_matrix(), T_lc[:3, :3], atol=1e-12)
        np.testing.assert_allclose(np.reshape(cs["matrix4x4"], (4, 4)), T_lc, atol=1e-12)
