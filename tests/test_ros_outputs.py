"""ROS outputs: a runnable static-transform line (plain numbers), tf_static YAML, URDF joints with
the body / optical frames, CameraInfo YAML; round trips through ``xcalib convert``."""

from __future__ import annotations

import json
import shlex

import numpy as np
import pytest

from xcalib.calib.result import CalibrationResult
from xcalib.cli import main
from xcalib.formats.ros import R_BODY_OPTICAL, static_transform_command
from xcalib.geometry.camera import CameraIntrinsics
from xcalib.geometry.rotations import euler_to_matrix, quaternion_to_matrix
from xcalib.geometry.transforms import invert_transform, make_transform


def _result() -> CalibrationResult:
    R = euler_to_matrix([-91.0, 1.5, -88.0], degrees=True)
    return CalibrationResult(success=True, intrinsics=CameraIntrinsics(1000.0, 1001.0, 640.0, 360.0,
                                                                       [0.1, -0.2, 0.001, 0.002, 0.05], 1280, 720),
                             rotation=R, translation=np.array([0.12, -0.31, 0.05]), camera_name="front",
                             image_size=(1280, 720))


def test_static_transform_line_tokenises_into_numbers():
    res = _result()
    T = invert_transform(res.extrinsics)
    line = static_transform_command(T, "lidar", "front_optical_frame")
    assert "np." not in line and "float64" not in line
    tok = shlex.split(line)
    assert tok[:4] == ["ros2", "run", "tf2_ros", "static_transform_publisher"]
    args = dict(zip(tok[4::2], tok[5::2]))
    vals = {k: float(args[f"--{k}"]) for k in ("x", "y", "z", "qx", "qy", "qz", "qw")}
    assert args["--frame-id"] == "lidar" and args["--child-frame-id"] == "front_optical_frame"
    back = make_transform(quaternion_to_matrix([vals[k] for k in ("qx", "qy", "qz", "qw")]),
                          [vals["x"], vals["y"], vals["z"]])
    np.testing.assert_allclose(back, T, atol=1e-12)


@pytest.mark.parametrize("fmt,name", [("urdf", "cam.urdf"), ("tf_static", "tf_static.yaml"),
                                      ("ros", "camera_info.yaml")])
def test_convert_round_trip(tmp_path, fmt, name, capsys):
    res = _result()
    src = res.save(tmp_path / "calibration.json")
    assert main(["convert", str(src), "--to", fmt, "--out", str(tmp_path / name)]) == 0
    capsys.readouterr()
    assert main(["convert", str(tmp_path / name), "--to", "json", "--out", str(tmp_path / "back.json"),
                 "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["from"] == fmt
    np.testing.assert_allclose(np.array(out["T_cam_lidar"]), res.extrinsics, atol=1e-9)
    back = CalibrationResult.load(tmp_path / "back.json")
    assert back.camera_name == "front"
    if fmt == "ros":  # CameraInfo carries the intrinsics and distortion
        assert back.intrinsics == res.intrinsics
        np.testing.assert_allclose(back.intrinsics.distortion, res.intrinsics.distortion)


def test_urdf_states_body_and_optical_frames(tmp_path):
    import xml.etree.ElementTree as ET

    from xcalib.formats.ros import write_urdf

    res = _result()
    root = ET.fromstring(write_urdf(res, tmp_path / "c.urdf").read_text())
    links = {link.get("name") for link in root.iter("link")}
    assert links == {"lidar", "front_link", "front_optical_frame"}
    # the body frame's x axis is the optical frame's z axis (looking direction) in LiDAR coordinates
    T_lidar_optical = invert_transform(res.extrinsics)
    look = T_lidar_optical[:3, :3] @ np.array([0.0, 0.0, 1.0])
    np.testing.assert_allclose(R_BODY_OPTICAL @ np.array([0.0, 0.0, 1.0]), [1.0, 0.0, 0.0])
    from xcalib.formats.ros import read_urdf

    again = read_urdf(tmp_path / "c.urdf")
    np.testing.assert_allclose(invert_transform(again.extrinsics)[:3, 2], look, atol=1e-12)
