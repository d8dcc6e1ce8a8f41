"""CalibAnything / OpenCalib calibration files and scene folders."""

from __future__ import annotations

import json

import numpy as np
import pytest
from conftest import shared_path
from scipy.spatial.transform import Rotation

from xcalib.calib.result import CalibrationResult
from xcalib.errors import FormatError
from xcalib.formats.calibanything import (
    T_cam_lidar_to_lucid_pose,
    calib_json_to_lucid,
    lucid_pose_to_T_cam_lidar,
    lucid_to_calib_json,
    read_calib_json,
    read_calib_txt,
    read_lucid_calib,
    read_opencalib,
    write_calib_json,
    write_calib_txt,
    write_lucid_calib,
    write_opencalib,
)
from xcalib.formats.calibanything_scene import calibanything_frames, scene_layout
from xcalib.geometry import CameraIntrinsics, transform_points

LUCID = {
    "intrinsic_params": {"fx": 1000.0, "fy": 1001.0, "cx": 320.0, "cy": 240.0, "k1": -0.05, "k2": 0.01,
                         "p1": 0.001, "p2": -0.002, "k3": 0.003, "k4": 0.0, "k5": 0, "k6": 0,
                         "camera": "c0", "camera_model": "normal"},
    "extrinsic_params": {"roll": -90.0, "pitch": 0.0, "yaw": -90.0, "px": 1.5, "py": 0.2, "pz": -0.3,
                         "quaternion": {"x": -0.5, "y": 0.5, "z": -0.5, "w": 0.5},
                         "camera_coordinate": "OPTICAL"},
}


def _result(rng, dist=True) -> CalibrationResult:
    R = Rotation.from_rotvec(rng.normal(size=3)).as_matrix()
    d = np.array([-0.1, 0.02, 0.001, -0.002, 0.004]) if dist else None
    return CalibrationResult(success=True, intrinsics=CameraIntrinsics(900.5, 901.25, 640.1, 360.2, d, 1280, 720),
                             rotation=R, translation=rng.normal(size=3), camera_name="front")


def _write(tmp_path, obj, name="lucid_calib.json"):
    p = tmp_path / name
    p.write_text(json.dumps(obj))
    return p


def test_lucid_direction_and_convention(tmp_path):
    """roll=-90, yaw=-90 is the standard 'camera looks along LiDAR +x' pose; (px,py,pz) is the
    camera origin in the LiDAR frame, so it maps to the camera origin."""
    r = read_lucid_calib(_write(tmp_path, LUCID))
    T = r.extrinsics  # LiDAR -> camera
    np.testing.assert_allclose(transform_points(T, np.array([[1.5, 0.2, -0.3]]))[0], 0.0, atol=1e-12)
    ahead = transform_points(T, np.array([[11.5, 0.2, -0.3]]))[0]  # 10 m ahead along LiDAR +x
    np.testing.assert_allclose(ahead, [0, 0, 10], atol=1e-12)
    left = transform_points(T, np.array([[11.5, 1.2, -0.3]]))[0]  # LiDAR +y (left) = camera -x
    np.testing.assert_allclose(left, [-1, 0, 10], atol=1e-12)
    assert r.meta["quaternion_disagreement_deg"] < 1e-6
    np.testing.assert_allclose(r.intrinsics.distortion, [-0.05, 0.01, 0.001, -0.002, 0.003])


def test_lucid_euler_matches_scipy_and_roundtrips(rng):
    for _ in range(20):
        ang = rng.uniform([-180, -89, -180], [180, 89, 180])
        p = rng.normal(size=3)
        T = lucid_pose_to_T_cam_lidar(*ang, *p)
        R_lidar_cam = Rotation.from_euler("xyz", ang, degrees=True).as_matrix()
        np.testing.assert_allclose(T[:3, :3], R_lidar_cam.T, atol=1e-12)
        pose = T_cam_lidar_to_lucid_pose(T)
        np.testing.assert_allclose([pose["roll"], pose["pitch"], pose["yaw"]], ang, atol=1e-9)
        np.testing.assert_allclose([pose["px"], pose["py"], pose["pz"]], p, atol=1e-12)
        q = pose["quaternion"]
        np.testing.assert_allclose(Rotation.from_quat([q["x"], q["y"], q["z"], q["w"]]).as_matrix(),
                                   R_lidar_cam, atol=1e-12)


@pytest.mark.parametrize("mutate, field", [
    (lambda d: d["extrinsic_params"].pop("roll"), "extrinsic_params.roll"),
    (lambda d: d.pop("intrinsic_params"), "intrinsic_params"),
    (lambda d: d["extrinsic_params"].update(quaternion={"x": 0, "y": 0, "z": 0, "w": 0}), "extrinsic_params.quaternion"),
    (lambda d: d["extrinsic_params"].update(yaw=-85.0), "extrinsic_params.quaternion"),  # 5 deg conflict
    (lambda d: d["extrinsic_params"].update(camera_coordinate="BODY"), "extrinsic_params.camera_coordinate"),
    (lambda d: d["intrinsic_params"].update(fx="wide"), "intrinsic_params.fx"),
    (lambda d: d["extrinsic_params"]["quaternion"].update(w=0.6), "extrinsic_params.quaternion"),  # norm 1.05
])
def test_lucid_bad_input(tmp_path, mutate, field):
    d = json.loads(json.dumps(LUCID))
    mutate(d)
    with pytest.raises(FormatError) as ei:
        read_lucid_calib(_write(tmp_path, d))
    assert ei.value.field == field and "lucid_calib.json" in str(ei.value)


def test_lucid_quaternion_norm_repair(tmp_path):
    d = json.loads(json.dumps(LUCID))
    d["extrinsic_params"]["quaternion"] = {"x": -0.6, "y": 0.6, "z": -0.6, "w": 0.6}  # scaled, same rotation
    r = read_lucid_calib(_write(tmp_path, d), repair=True)
    assert r.meta["quaternion_disagreement_deg"] < 1e-6


@pytest.mark.parametrize("fmt", ["lucid", "calib_json", "calib_txt", "opencalib"])
def test_roundtrips(tmp_path, rng, fmt):
    res = _result(rng)
    if fmt == "lucid":
        back = read_lucid_calib(write_lucid_calib(res, tmp_path / "lucid_calib.json"))
    elif fmt == "calib_json":
        back = read_calib_json(write_calib_json(res, tmp_path / "calib.json", gt=res.extrinsics))
        np.testing.assert_allclose(back.meta["T_cam_lidar_gt"], res.extrinsics, atol=1e-12)
    elif fmt == "calib_txt":
        back = read_calib_txt(write_calib_txt(res, tmp_path / "calib.txt"))
    else:
        ep, _ = write_opencalib(res, tmp_path, lidar="top")
        back = read_opencalib(ep)
        assert back.intrinsics.width == 1280
    np.testing.assert_allclose(back.rotation, res.rotation, atol=1e-9)
    np.testing.assert_allclose(back.translation, res.translation, atol=1e-6)
    np.testing.assert_allclose(back.K, res.K, atol=1e-9)
    np.testing.assert_allclose(back.intrinsics.dist_coeffs, res.intrinsics.dist_coeffs, atol=1e-12)


def test_calib_json_p_offset_and_bad(tmp_path):
    P = [[700.0, 0, 600, 70.0], [0, 700, 180, 0], [0, 0, 1, 0]]  # 0.1 m offset along camera x
    d = {"cam_K": {"rows": 3, "cols": 4, "data": P}, "cam_dist": {"cols": 5, "data": [0] * 5},
         "T_lidar_to_cam": {"rows": 4, "cols": 4, "data": np.eye(4).tolist()},
         "T_lidar_to_cam_gt": {"available": False, "rows": 0, "cols": 0, "data": []}}
    r = read_calib_json(_write(tmp_path, d, "calib.json"))
    np.testing.assert_allclose(r.translation, [0.1, 0, 0], atol=1e-12)
    assert r.meta["T_cam_lidar_gt"] is None
    with pytest.raises(FormatError, match="ground truth"):
        read_calib_json(tmp_path / "calib.json", use_gt=True)
    d["T_lidar_to_cam"]["data"] = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0]]  # [3,4] accepted
    assert read_calib_json(_write(tmp_path, d, "calib.json")).success
    d["T_lidar_to_cam"]["data"] = [[1, 0, 0], [0, 1, 0]]
    with pytest.raises(FormatError) as ei:
        read_calib_json(_write(tmp_path, d, "calib.json"))
    assert ei.value.field == "T_lidar_to_cam"
    d["T_lidar_to_cam"]["data"] = np.diag([1.1, 1.1, 1.1, 1.0]).tolist()
    with pytest.raises(FormatError, match="not a rotation"):
        read_calib_json(_write(tmp_path, d, "calib.json"))


def _scene(tmp_path, rng, cams, stems, image_names=None):
    from xcalib.io.images import write_image
    from xcalib.io.pointcloud import write_pcd

    for s in stems:
        write_pcd(tmp_path / f"{s}.pcd", rng.normal(size=(50, 4)).astype(np.float32))
    for c in cams:
        (tmp_path / c).mkdir()
        (tmp_path / c / "lucid_calib.json").write_text(json.dumps(LUCID))
        for n in (image_names or stems):
            write_image(tmp_path / c / f"{n}.png", np.zeros((480, 640, 3), np.uint8))


def test_lucid_scene_layouts(tmp_path, rng):
    multi = tmp_path / "scene1"
    multi.mkdir()
    _scene(multi, rng, ["cam02", "cam03", "cam04"], ["000000"], image_names=["sample_image"])
    ts = tmp_path / "daytimetraffic"
    ts.mkdir()
    _scene(ts, rng, ["cam03"], ["000000", "000001", "000002"])
    assert scene_layout(multi) == "lucid" and scene_layout(tmp_path) == "multi"
    fm = calibanything_frames(multi)
    assert [f.camera_name for f in fm] == ["cam02", "cam03", "cam04"]
    f = fm[0]
    assert f.image.shape == (480, 640, 3) and f.point_cloud.shape == (50, 4) and f.intrinsics.width == 640
    assert f.bboxes_2d.shape == (0, 4) and f.bboxes_3d.shape == (0, 6)
    np.testing.assert_allclose(f.extrinsics, read_lucid_calib(multi / "cam02" / "lucid_calib.json").extrinsics)
    ft = calibanything_frames(ts)
    assert [f.frame_key for f in ft] == ["000000/cam03", "000001/cam03", "000002/cam03"]
    assert len(calibanything_frames(tmp_path)) == 6
    assert len(calibanything_frames(multi, camera="cam03")) == 1
    (ts / "cam03" / "000001.png").unlink()
    assert [f.frame_key for f in calibanything_frames(ts)] == ["000000/cam03", "000002/cam03"]
    for p in (ts / "cam03").glob("*.png"):
        p.rename(p.with_name("img_" + p.name))
    (ts / "cam03" / "img_000000.png").unlink()
    with pytest.raises(FormatError, match="cannot pair"):
        calibanything_frames(ts)


# --------------------------------------------------------------------------- real samples
@pytest.mark.shared_data
def test_sample_lucid_convention_proof():
    """The sample's Euler angles reproduce CalibAnything's own converted calib.json exactly with
    R_lidar_cam = Rz(yaw) Ry(pitch) Rx(roll) and (px,py,pz) = camera origin in the LiDAR frame;
    its quaternion is the same convention (pitch identical), 0.64 deg away from the Euler angles."""
    ex = shared_path("calibanything", "format_examples")
    lucid = read_lucid_calib(ex / "lucid_calib.json")
    theirs = read_calib_json(ex / "plextechSC_output_daytimetraffic_cam03_calib.json")
    np.testing.assert_allclose(lucid.extrinsics, theirs.extrinsics, atol=1e-12)
    assert 0.5 < lucid.meta["quaternion_disagreement_deg"] < 0.7
    raw = json.loads((ex / "lucid_calib.json").read_text())["extrinsic_params"]
    q = raw["quaternion"]
    q_euler = Rotation.from_quat([q["x"], q["y"], q["z"], q["w"]]).as_euler("xyz", degrees=True)
    assert q_euler[1] == pytest.approx(raw["pitch"], abs=1e-9)
    np.testing.assert_allclose(q_euler[[0, 2]] - [raw["roll"], raw["yaw"]], [-0.4, -0.5], atol=1e-9)
    # every other Euler sequence / the opposite direction disagrees with the quaternion by > 100 deg
    R_q = Rotation.from_quat([q["x"], q["y"], q["z"], q["w"]])
    for seq in ("XYZ", "zyx", "ZYX", "yxz", "zxy"):
        R = Rotation.from_euler(seq, [raw["roll"], raw["pitch"], raw["yaw"]], degrees=True)
        assert np.degrees((R * R_q.inv()).magnitude()) > 0.9, seq
    # conversions lucid -> calib.json -> lucid keep everything incl. distortion
    assert lucid.intrinsics.distortion is not None and lucid.intrinsics.distortion.size == 8
    # direction: the camera sits 2.46 m ahead of the LiDAR looking along LiDAR +x, so a point 30 m
    # ahead lands 27.5 m in front of it, near the image centre; the inverse direction does not
    uv, depth = lucid.project(np.array([[30.0, 0.0, 0.0]]))
    assert depth[0] == pytest.approx(27.5, abs=0.2) and np.all(np.abs(uv[0] - [1915, 1103]) < 800)
    wrong = np.linalg.inv(lucid.extrinsics)
    assert transform_points(wrong, np.array([[30.0, 0.0, 0.0]]))[0][2] < 5


@pytest.mark.shared_data
def test_sample_conversions(tmp_path):
    ex = shared_path("calibanything", "format_examples")
    out = lucid_to_calib_json(ex / "lucid_calib.json", tmp_path / "calib.json")
    back = calib_json_to_lucid(out, tmp_path / "lucid_calib.json", camera="cam03")
    a, b = read_lucid_calib(ex / "lucid_calib.json"), read_lucid_calib(back)
    np.testing.assert_allclose(a.extrinsics, b.extrinsics, atol=1e-12)
    np.testing.assert_allclose(a.intrinsics.distortion, b.intrinsics.distortion, atol=1e-15)


@pytest.mark.shared_data
def test_every_calibanything_sample_loads():
    root = shared_path("calibanything")
    for f in ("plextechSC_kitti_calib.json", "plextechSC_nuscenes_calib.json",
              "plextechSC_output_daytimetraffic_cam03_calib.json"):
        assert read_calib_json(root / "format_examples" / f).success
    kitti = read_calib_json(root / "format_examples" / "plextechSC_kitti_calib.json", use_gt=True)
    assert kitti.translation[2] == pytest.approx(-0.2922 + 3.779761e-03, abs=1e-3)  # P offset folded in
    lab = read_calib_json(root / "johanna0626_lab_data_0304" / "calib.json")
    assert lab.meta["T_cam_lidar_gt"] is None
    txt = {n: read_calib_txt(root / "sensorscalibration" / "auto_calib_v2.0" / "ours" / n / "calib.txt")
           for n in "123"}
    oc = read_opencalib(root / "sensorscalibration" / "auto_calib" /
                        "top_center_lidar-to-center_camera-extrinsic.json")
    # ours/3 is the auto_calib scene: the v1 calib.txt and the OpenCalib JSON pair agree
    np.testing.assert_allclose(txt["3"].extrinsics, oc.extrinsics, atol=1e-12)
    np.testing.assert_allclose(txt["3"].K, oc.K)
    frames = calibanything_frames(root, load_image=False)
    assert len(frames) == 5
    for f in frames:
        assert f.point_cloud.shape[0] > 60_000 and f.intrinsics is not None
        assert f.bboxes_2d.shape == (0, 4) and f.bboxes_3d.shape == (0, 6)
    assert sum(f.extrinsics is not None for f in frames) == 4  # the lab scene has no ground truth
    # direction LiDAR -> camera: a point 20 m ahead of the LiDAR is ~20 m in front of every camera
    # and projects inside the image; through the inverse transform it would not be in front
    for f in frames:
        if f.extrinsics is None:
            continue
        p = transform_points(f.extrinsics, np.array([[20.0, 0.0, 0.0]]))[0]
        assert 19 < p[2] < 21, f.frame_key
        u, v = (f.intrinsics.K @ (p / p[2]))[:2]
        assert 0 <= u < f.intrinsics.width and 0 <= v < f.intrinsics.height
        assert transform_points(np.linalg.inv(f.extrinsics), np.array([[20.0, 0.0, 0.0]]))[0][2] < 2
