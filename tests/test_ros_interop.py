"""Issue 30: raw ROS recordings written by tools that are not xcalib's (the ``rosbags`` writers,
``mcap_ros2``, ROS 1-profile MCAP as ``mcap convert`` makes it), detections as stacks emit them
(stamped a few ms off, Autoware objects, tilted and yaw-less boxes, another frame), the user's
frame names and clock, and outputs loaded as ROS tools load them (URDF tree, tf lookup, CameraInfo
YAML as camera_calibration_parsers reads it, shell lines for ROS 1 and 2, launch files)."""

from __future__ import annotations

import ast
import logging
import re
import shlex
import subprocess
import sys
import types
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
import yaml

from xcalib.calib.result import CalibrationResult
from xcalib.errors import FormatError
from xcalib.geometry.camera import CameraIntrinsics
from xcalib.geometry.rotations import euler_to_matrix, matrix_to_quaternion, quaternion_to_matrix
from xcalib.geometry.transforms import invert_transform, make_transform
from xcalib.io.bags import BagFrames
from xcalib.io.bags import _convert as cv
from xcalib.io.bags._msgs import typestore

LIDAR, CAMERA = "velodyne", "camera_optical_frame"
T_BASE_VELODYNE = make_transform(euler_to_matrix([0.0, 0.0, 30.0], degrees=True), [1.2, 0.0, 1.8])
DET_DELAY_NS = 3_000_000  # detections stamped 3 ms after their sensor message


@pytest.fixture(scope="module")
def frames():
    from xcalib.data.synth import generate_frames, sample_site

    site = sample_site(3, width=160, height=100, focal_px=150)
    out = generate_frames(site, 3, seed=0)
    for f in out:
        f.point_cloud = np.ascontiguousarray(f.point_cloud[::40, :3])
    return out


def _box7(f) -> np.ndarray:
    from xcalib.geometry.boxes import as_box7

    return as_box7(np.asarray(f.bboxes_3d, dtype=np.float64))


def _messages(store, frames, *, det3d=None, det_frame=LIDAR, quats=None, det_delay=DET_DELAY_NS):
    """(topic, msgtype, stamp, message) of a sensor-only recording + detections stamped 3 ms off,
    frame ids velodyne / camera_optical_frame, tf_static base_link -> velodyne -> camera."""
    out = []
    t0 = 1_700_000_000_000_000_000
    for i, f in enumerate(frames):
        ls = t0 + i * 100_000_000
        cs = ls + 7_000_000
        out.append(("/velodyne_points", "sensor_msgs/msg/PointCloud2", ls,
                    cv.make_pointcloud2(store, f.point_cloud, ("x", "y", "z"), ls, LIDAR)))
        out.append(("/camera/image_raw", "sensor_msgs/msg/Image", cs, cv.make_image(store, f.image, cs, CAMERA)))
        out.append(("/camera/camera_info", "sensor_msgs/msg/CameraInfo", cs,
                    cv.make_camera_info(store, f.intrinsics, cs, CAMERA, f.image.shape[1], f.image.shape[0])))
        out.append(("/camera/detections", "vision_msgs/msg/Detection2DArray", cs + det_delay,
                    cv.make_detection2d_array(store, f.bboxes_2d, cs + det_delay, CAMERA)))
        if det3d is None:
            msg = cv.make_detection3d_array(store, _box7(f), ls + det_delay, det_frame)
            if quats is not None:
                for det, q in zip(msg.detections, quats):
                    o = det.bbox.center.orientation
                    o.x, o.y, o.z, o.w = (float(v) for v in q)
            out.append(("/velodyne/detections", "vision_msgs/msg/Detection3DArray", ls + det_delay, msg))
        else:
            out.append(det3d(store, f, ls + det_delay))
        if i == 0:
            T_lc = invert_transform(np.asarray(f.extrinsics, dtype=np.float64))
            out.append(("/tf_static", "tf2_msgs/msg/TFMessage", ls,
                        cv.make_tf_message(store, [("base_link", LIDAR, T_BASE_VELODYNE), (LIDAR, CAMERA, T_lc)], ls)))
    return out


def _write_rosbags(path: Path, frames, **kw) -> Path:
    """The rosbags writers (ROS 1 .bag or rosbag2 .mcap / .db3), not xcalib's."""
    ros1 = path.suffix == ".bag"
    store = typestore(1 if ros1 else 2)
    msgs = _messages(store, frames, **kw)
    if ros1:
        from rosbags.rosbag1 import Writer

        w = Writer(path)
    else:
        from rosbags.rosbag2 import StoragePlugin, Writer

        w = Writer(path.with_suffix(""), version=9,
                   storage_plugin=StoragePlugin.MCAP if path.suffix == ".mcap" else StoragePlugin.SQLITE3)
    cons = {}
    with w:
        for topic, typ, stamp, msg in msgs:
            if topic not in cons:
                cons[topic] = w.add_connection(topic, typ, typestore=store)
            raw = store.serialize_ros1(msg, typ) if ros1 else store.serialize_cdr(msg, typ)
            w.write(cons[topic], stamp, raw)
    if ros1:
        return path
    folder = path.with_suffix("")
    return next(folder.glob("*" + (path.suffix or ".db3")))


def _write_mcap_ros2(path: Path, frames, **kw) -> Path:
    """The official mcap ROS 2 writer with schema names as its examples give them (no ``/msg/``)."""
    mcap_ros2_writer = pytest.importorskip("mcap_ros2.writer")
    store = typestore(2)
    schemas = {}
    with open(path, "wb") as f:
        w = mcap_ros2_writer.Writer(f)
        for topic, typ, stamp, msg in _messages(store, frames, **kw):
            if typ not in schemas:
                text, _ = store.generate_msgdef(typ, ros_version=2)
                schemas[typ] = w.register_msgdef(typ.replace("/msg/", "/"), text)
            w.write_message(topic, schemas[typ], _plain(msg), log_time=stamp, publish_time=stamp)
        w.finish()
    return path


def _plain(msg):
    """A rosbags message as the plain dict mcap_ros2 serialises (uint8[] as bytes)."""
    if isinstance(msg, np.ndarray):
        return msg.tobytes() if msg.dtype == np.uint8 else msg.tolist()
    if isinstance(msg, (list, tuple)):
        return [_plain(m) for m in msg]
    if hasattr(msg, "__dataclass_fields__"):
        return {k: _plain(getattr(msg, k)) for k in msg.__dataclass_fields__}
    return msg


def _write_mcap_ros1(path: Path, frames, **kw) -> Path:
    """An MCAP of the ros1 profile (ros1msg schemas, ros1 encoding), as ``mcap convert`` writes a ROS 1 bag."""
    from mcap.writer import Writer

    store = typestore(1)
    with open(path, "wb") as f:
        w = Writer(f)
        w.start(profile="ros1", library="test")
        schemas, chans = {}, {}
        for topic, typ, stamp, msg in _messages(store, frames, **kw):
            if typ not in schemas:
                text, _ = store.generate_msgdef(typ, ros_version=1)
                schemas[typ] = w.register_schema(typ.replace("/msg/", "/"), "ros1msg", text.encode())
            if topic not in chans:
                chans[topic] = w.register_channel(topic, "ros1", schemas[typ])
            w.add_message(chans[topic], stamp, bytes(store.serialize_ros1(msg, typ)), stamp)
        w.finish()
    return path


WRITERS = {"rosbags-ros1.bag": (_write_rosbags, ".bag"), "rosbags-rosbag2.mcap": (_write_rosbags, ".mcap"),
           "rosbags-rosbag2.db3": (_write_rosbags, ".db3"), "mcap_ros2-no-msg.mcap": (_write_mcap_ros2, ".mcap"),
           "ros1-profile.mcap": (_write_mcap_ros1, ".mcap")}


def _bag(tmp_path, frames, writer="rosbags-rosbag2.mcap", **kw) -> Path:
    fn, suffix = WRITERS[writer]
    return fn(tmp_path / f"rec{suffix}", frames, **kw)


@pytest.mark.parametrize("writer", list(WRITERS))
def test_foreign_bags_pair_detections_within_tolerance_and_keep_frames(tmp_path, frames, writer):
    path = _bag(tmp_path, frames, writer)
    seq = BagFrames(path)
    assert len(seq) == len(frames) and seq.report.frames == len(frames)
    assert (seq.lidar_frame_id, seq.camera_frame_id) == (LIDAR, CAMERA)
    np.testing.assert_allclose(seq.tf_T_cam_lidar, frames[0].extrinsics, atol=1e-6)
    for src, got in zip(frames, seq):
        np.testing.assert_allclose(_box7(got), _box7(src), atol=1e-4)
        np.testing.assert_allclose(got.bboxes_2d, src.bboxes_2d, atol=1e-3)
        assert got.meta["lidar_stamp_ns"] % 100_000_000 == 0  # the sweep's own stamp, not the detections'


def test_detections_beyond_the_tolerance_are_dropped_with_the_reason(tmp_path, frames):
    path = _bag(tmp_path, frames, det_delay=20_000_000)  # sensors 7 ms apart, detections 20 ms after them
    with pytest.raises(FormatError, match="no 3D detections within 10 ms"):
        BagFrames(path, tolerance_s=0.01)
    assert len(BagFrames(path, tolerance_s=0.03)) == len(frames)


def test_tilted_boxes_are_flattened_and_counted_refused_beyond_the_limit(tmp_path, frames, caplog):
    m = len(_box7(frames[0]))
    pitched = [matrix_to_quaternion(euler_to_matrix([0.0, 2.0, 20.0], degrees=True))] + \
        [[0.0, 0.0, 0.0, 1.0]] * (m - 1)
    seq = BagFrames(_bag(tmp_path, frames[:1], quats=pitched))
    with caplog.at_level(logging.WARNING):
        f = seq[0]
    assert f.meta["boxes3d_flattened"] == 1 and "1 3D box(es) turned about x/y (up to 2.0 deg)" in caplog.text
    assert f.bboxes_3d[0, 6] == pytest.approx(np.radians(20.0), abs=1e-6)
    steep = [matrix_to_quaternion(euler_to_matrix([15.0, 0.0, 0.0], degrees=True))] * m
    (tmp_path / "b").mkdir()
    with pytest.raises(FormatError, match=r"turned 15.0 deg about x/y .* up to 10 deg are flattened"):
        BagFrames(_bag(tmp_path / "b", frames[:1], quats=steep))[0]


def test_yawless_boxes_from_a_bag_get_their_yaw_reestimated(tmp_path, frames):
    m = len(_box7(frames[0]))
    f = BagFrames(_bag(tmp_path, frames[:1], quats=[[0.0, 0.0, 0.0, 1.0]] * m))[0]
    assert f.bboxes_3d.shape == (m, 6)  # [M, 6]: calibrate's "auto" re-estimates the yaw from the points
    from xcalib.calib.inputs import prepare_frames

    cf, _, _ = prepare_frames([f], f.intrinsics)
    assert cf[0].boxes3d.shape[1] == 7 and np.any(cf[0].boxes3d[:, 6] != 0.0)


def _autoware(pkg: str, tracked: bool):
    def make(store, f, stamp):
        T = store.types
        b7 = _box7(f)
        objs = []
        for k, (x, y, z, l, w, h, yaw) in enumerate(b7):
            pose = T["geometry_msgs/msg/Pose"](
                position=T["geometry_msgs/msg/Point"](x=x, y=y, z=z),
                orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=float(np.sin(yaw / 2)),
                                                              w=float(np.cos(yaw / 2))))
            pwc = T["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=np.zeros(36))
            twist = T["geometry_msgs/msg/TwistWithCovariance"](
                twist=T["geometry_msgs/msg/Twist"](linear=T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0),
                                                   angular=T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)),
                covariance=np.zeros(36))
            shape = T[f"{pkg}/msg/Shape"](type=0, footprint=T["geometry_msgs/msg/Polygon"](points=[]),
                                          dimensions=T["geometry_msgs/msg/Vector3"](x=l, y=w, z=h))
            cls = [T[f"{pkg}/msg/ObjectClassification"](label=1, probability=0.9)]
            if tracked:
                accel = T["geometry_msgs/msg/AccelWithCovariance"](
                    accel=T["geometry_msgs/msg/Accel"](linear=T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0),
                                                       angular=T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)),
                    covariance=np.zeros(36))
                kin = T[f"{pkg}/msg/TrackedObjectKinematics"](pose_with_covariance=pwc, orientation_availability=2,
                                                              twist_with_covariance=twist,
                                                              acceleration_with_covariance=accel, is_stationary=False)
                uid = T["unique_identifier_msgs/msg/UUID"](uuid=np.frombuffer(bytes([k + 1] * 16), np.uint8).copy())
                objs.append(T[f"{pkg}/msg/TrackedObject"](object_id=uid, existence_probability=0.9,
                                                          classification=cls, kinematics=kin, shape=shape))
            else:
                kin = T[f"{pkg}/msg/DetectedObjectKinematics"](pose_with_covariance=pwc, has_position_covariance=False,
                                                               orientation_availability=2, twist_with_covariance=twist,
                                                               has_twist=False, has_twist_covariance=False)
                objs.append(T[f"{pkg}/msg/DetectedObject"](existence_probability=0.9, classification=cls,
                                                           kinematics=kin, shape=shape))
        name = "TrackedObjects" if tracked else "DetectedObjects"
        msg = T[f"{pkg}/msg/{name}"](header=cv.make_header(store, stamp, LIDAR), objects=objs)
        return ("/perception/objects", f"{pkg}/msg/{name}", stamp, msg)
    return make


@pytest.mark.parametrize("pkg", ["autoware_perception_msgs", "autoware_auto_perception_msgs"])
@pytest.mark.parametrize("tracked", [False, True])
def test_autoware_objects_read_as_3d_boxes(tmp_path, frames, pkg, tracked):
    seq = BagFrames(_bag(tmp_path, frames[:2], det3d=_autoware(pkg, tracked)))
    assert seq.topics["detections_3d"] == "/perception/objects"
    for src, got in zip(frames, seq):
        np.testing.assert_allclose(_box7(got), _box7(src), atol=1e-4)
        assert (got.track_ids_3d is not None) == tracked


def test_detections_in_another_frame_are_moved_through_tf_static(tmp_path, frames):
    def in_base(store, f, stamp):
        b7 = _box7(f).copy()
        b7[:, :3] = (T_BASE_VELODYNE[:3, :3] @ b7[:, :3].T).T + T_BASE_VELODYNE[:3, 3]
        b7[:, 6] += np.radians(30.0)
        return ("/velodyne/detections", "vision_msgs/msg/Detection3DArray", stamp,
                cv.make_detection3d_array(store, b7, stamp, "base_link"))

    got = BagFrames(_bag(tmp_path, frames[:1], det3d=in_base))[0]
    ref = _box7(frames[0])
    np.testing.assert_allclose(got.bboxes_3d[:, :6], ref[:, :6], atol=1e-4)
    np.testing.assert_allclose(np.cos(got.bboxes_3d[:, 6] - ref[:, 6]), 1.0, atol=1e-6)
    (tmp_path / "b").mkdir()
    bad = BagFrames(_bag(tmp_path / "b", frames[:1], det_frame="map"))
    with pytest.raises(FormatError, match="'map' and the cloud in 'velodyne'.*does not connect"):
        bad[0]


# ----------------------------------------------------------------------------- outputs
def _site(tmp_path, frames, **kw):
    """calibrate_site on a foreign bag, the 'calibration' being the truth (the writers are under test)."""
    from xcalib.site import calibrate_site

    seq = BagFrames(_bag(tmp_path, frames))
    truth = np.asarray(frames[0].extrinsics, dtype=np.float64)
    off = make_transform(euler_to_matrix([0.0, 0.5, 0.0], degrees=True), [0.1, 0.0, 0.0]) @ truth

    def fake(fr, intr, stage, prior=None):  # intrinsics without the image size: the images give it
        k = CameraIntrinsics(intr.fx, intr.fy, intr.cx, intr.cy, intr.distortion)
        return CalibrationResult(success=True, rotation=off[:3, :3], translation=off[:3, 3], intrinsics=k)

    site, _ = calibrate_site({"camera": seq}, calibrate=fake, **kw)
    return site, off, truth


def _tree(edges):
    """child -> (parent, T_parent_child) of (parent, child, T) edges; lookup(target, source) = T_target_source."""
    par = {c: (p, T) for p, c, T in edges}

    def to_root(frame):
        T = np.eye(4)
        while frame in par:
            p, T_pc = par[frame]
            T, frame = T_pc @ T, p
        return frame, T

    def lookup(target, source):
        rt, T_rt = to_root(target)
        rs, T_rs = to_root(source)
        assert rt == rs, f"{target} and {source} are not connected ({rt} vs {rs})"
        return invert_transform(T_rt) @ T_rs

    return lookup


def test_outputs_connect_to_the_recordings_tree(tmp_path, frames):
    from xcalib.site import write_site_ros

    site, T_cam_lidar, truth = _site(tmp_path, frames)
    assert site.lidar_frame == LIDAR and site.cameras[0].child_frame == CAMERA
    rot, tr = site.cameras[0].vs_recorded  # the recording's tf (the truth) against the calibration
    assert (rot, tr) == pytest.approx(site.cameras[0].result.pose_error(truth)) and rot == pytest.approx(0.5)
    assert site.transforms()[0]["recorded_tf_vs_calibration"]["rotation_deg"] == pytest.approx(0.5)
    files = {p.name: p for p in write_site_ros(site, tmp_path / "ros")}
    # the recording's tree (tf_static: base_link -> velodyne) + xcalib's tf_static YAML
    tf = yaml.safe_load(files["tf_static.yaml"].read_text())["transforms"]
    edges = [("base_link", LIDAR, T_BASE_VELODYNE)]
    for t in tf:
        tr_, q = t["transform"]["translation"], t["transform"]["rotation"]
        edges.append((t["header"]["frame_id"], t["child_frame_id"],
                      make_transform(quaternion_to_matrix([q[k] for k in "xyzw"]), [tr_[k] for k in "xyz"])))
    lookup = _tree(edges)
    np.testing.assert_allclose(lookup(LIDAR, CAMERA), invert_transform(T_cam_lidar), atol=1e-12)
    np.testing.assert_allclose(lookup("base_link", CAMERA), T_BASE_VELODYNE @ invert_transform(T_cam_lidar),
                               atol=1e-12)
    # the URDF as a URDF library loads it
    yourdfpy = pytest.importorskip("yourdfpy")
    robot = yourdfpy.URDF.load(str(files["site.urdf"]), load_meshes=False, build_collision_scene_graph=False)
    assert robot.base_link == LIDAR and CAMERA in robot.link_map and "camera_link" in robot.link_map
    np.testing.assert_allclose(robot.get_transform(CAMERA, LIDAR), invert_transform(T_cam_lidar), atol=1e-9)


def test_frame_overrides(tmp_path, frames):
    site, _, _ = _site(tmp_path, frames, lidar_frame="os_sensor", camera_frames={"camera": "cam0_optical_frame"})
    assert site.lidar_frame == "os_sensor" and site.transforms()[0]["child"] == "cam0_optical_frame"
    from xcalib.io.sources import open_source

    sub = open_source(next(tmp_path.glob("rec*/*.mcap")), frames="0:2")  # --frames / --limit keep them too
    assert (len(sub), sub.lidar_frame_id, sub.camera_frame_id) == (2, LIDAR, CAMERA)
    assert sub.tf_T_cam_lidar is not None


def _parse_camera_info(path: Path) -> dict:
    """What camera_calibration_parsers' YAML reader requires: every key, of its type and shape."""
    d = yaml.safe_load(path.read_text())
    assert isinstance(d["image_width"], int) and isinstance(d["image_height"], int)
    assert d["image_width"] > 0 and d["image_height"] > 0
    assert isinstance(d["camera_name"], str) and isinstance(d["distortion_model"], str)
    for key, (r, c) in {"camera_matrix": (3, 3), "distortion_coefficients": (1, None),
                        "rectification_matrix": (3, 3), "projection_matrix": (3, 4)}.items():
        m = d[key]
        assert isinstance(m["rows"], int) and isinstance(m["cols"], int), key
        assert m["rows"] == r and (c is None or m["cols"] == c), key
        assert len(m["data"]) == m["rows"] * m["cols"] and all(isinstance(v, float) for v in m["data"]), key
    return d


def test_camera_info_yaml_loads_as_camera_calibration_parsers_reads_it(tmp_path, frames, capsys):
    from xcalib.cli import main
    from xcalib.site import write_site_ros

    site, _, _ = _site(tmp_path, frames)
    assert site.cameras[0].result.intrinsics.width is None  # the size comes from the images
    info = next(p for p in write_site_ros(site, tmp_path / "ros") if p.name.endswith("_camera_info.yaml"))
    d = _parse_camera_info(info)
    assert (d["image_width"], d["image_height"]) == frames[0].image.shape[1::-1]
    # xcalib convert --to ros: from the calibration's image size, from --image-size, refused without either
    k = CameraIntrinsics(150.0, 150.0, 80.0, 50.0)
    res = CalibrationResult(success=True, rotation=np.eye(3), translation=np.zeros(3), intrinsics=k,
                            camera_name="cam", image_size=(160, 100))
    src = res.save(tmp_path / "c.json")
    assert main(["convert", str(src), "--to", "ros", "--out", str(tmp_path / "a.yaml")]) == 0
    assert _parse_camera_info(tmp_path / "a.yaml")["image_width"] == 160
    res.image_size = None
    src = res.save(tmp_path / "d.json")
    assert main(["convert", str(src), "--to", "ros", "--out", str(tmp_path / "b.yaml")]) == 1
    assert "--image-size" in capsys.readouterr().err and not (tmp_path / "b.yaml").exists()
    assert main(["convert", str(src), "--to", "ros", "--out", str(tmp_path / "b.yaml"), "--image-size", "640x480"]) == 0
    assert _parse_camera_info(tmp_path / "b.yaml")["image_height"] == 480


def _fake_ros_bin(tmp_path: Path) -> Path:
    bin_ = tmp_path / "bin"
    bin_.mkdir()
    for name in ("rosrun", "ros2"):
        exe = bin_ / name
        exe.write_text(f'#!/bin/sh\nprintf "%s\\n" {name} "$@" >> "{tmp_path}/calls.txt"\n')
        exe.chmod(0o755)
    return bin_


def test_static_transforms_script_runs_ros1_and_ros2_lines(tmp_path, frames):
    from xcalib.site import write_site_ros

    site, T_cam_lidar, _ = _site(tmp_path, frames)
    sh = next(p for p in write_site_ros(site, tmp_path / "ros") if p.name == "static_transforms.sh")
    subprocess.run(["sh", "-n", str(sh)], check=True)
    env = {"PATH": f"{_fake_ros_bin(tmp_path)}:/usr/bin:/bin"}
    T = invert_transform(T_cam_lidar)
    for version in ("1", "2"):
        (tmp_path / "calls.txt").unlink(missing_ok=True)
        subprocess.run(["sh", str(sh), version], check=True, env=env, timeout=30)
        tok = (tmp_path / "calls.txt").read_text().split("\n")[:-1]
        if version == "1":
            assert tok[:3] == ["rosrun", "tf2_ros", "static_transform_publisher"]
            vals, frames_ = [float(v) for v in tok[3:10]], tok[10:12]
        else:
            assert tok[:4] == ["ros2", "run", "tf2_ros", "static_transform_publisher"]
            args = dict(zip(tok[4::2], tok[5::2]))
            vals = [float(args[f"--{k}"]) for k in ("x", "y", "z", "qx", "qy", "qz", "qw")]
            frames_ = [args["--frame-id"], args["--child-frame-id"]]
        assert frames_ == [LIDAR, CAMERA]
        np.testing.assert_allclose(make_transform(quaternion_to_matrix(vals[3:]), vals[:3]), T, atol=1e-12)


def test_launch_files_for_ros1_and_ros2(tmp_path, frames, monkeypatch):
    from xcalib.site import write_site_ros

    site, T_cam_lidar, _ = _site(tmp_path, frames)
    files = {p.name: p for p in write_site_ros(site, tmp_path / "ros")}
    T = invert_transform(T_cam_lidar)
    node = ET.parse(files["static_transforms.launch"]).getroot().find("node")
    assert (node.get("pkg"), node.get("type")) == ("tf2_ros", "static_transform_publisher")
    assert re.fullmatch(r"[A-Za-z][A-Za-z0-9_]*", node.get("name"))
    a = shlex.split(node.get("args"))
    assert a[7:] == [LIDAR, CAMERA]
    np.testing.assert_allclose(make_transform(quaternion_to_matrix([float(v) for v in a[3:7]]),
                                              [float(v) for v in a[:3]]), T, atol=1e-12)
    # ROS 2: the Python launch file run against stand-ins of launch / launch_ros
    text = files["static_transforms.launch.py"].read_text()
    ast.parse(text)
    launch, launch_ros, actions = (types.ModuleType(n) for n in ("launch", "launch_ros", "launch_ros.actions"))
    launch.LaunchDescription = list
    actions.Node = lambda **kw: kw
    for name, mod in (("launch", launch), ("launch_ros", launch_ros), ("launch_ros.actions", actions)):
        monkeypatch.setitem(sys.modules, name, mod)
    ns: dict = {}
    exec(compile(text, str(files["static_transforms.launch.py"]), "exec"), ns)  # noqa: S102 - our own output
    (n,) = ns["generate_launch_description"]()
    args = dict(zip(n["arguments"][::2], n["arguments"][1::2]))
    assert (n["package"], n["executable"]) == ("tf2_ros", "static_transform_publisher")
    assert (args["--frame-id"], args["--child-frame-id"]) == (LIDAR, CAMERA)
    assert float(args["--x"]) == pytest.approx(T[0, 3], abs=1e-12)


def test_review_keeps_the_recordings_stamps_and_whole_cloud(tmp_path, frames):
    from mcap.reader import make_reader

    from xcalib.viz.review import write_review_mcap

    site, _, _ = _site(tmp_path, frames)
    bag = BagFrames(next(tmp_path.glob("rec*/*.mcap")))
    loaded = {"camera": [bag[i] for i in range(len(bag))]}
    path = write_review_mcap(tmp_path / "review.mcap", site, loaded)
    with open(path, "rb") as f:
        msgs = [(c.topic, m.log_time, m.data) for _, c, m in make_reader(f).iter_messages()]
    import base64
    import json

    clouds = [(t, json.loads(d)) for topic, t, d in msgs if topic == "/lidar/points"]
    assert [t for t, _ in clouds] == [fr.meta["lidar_stamp_ns"] for fr in loaded["camera"]]
    sizes = [len(base64.b64decode(c["data"])) // 12 for _, c in clouds]
    assert sizes == [len(fr.point_cloud) for fr in loaded["camera"]]  # the whole cloud
    assert all(c["frame_id"] == LIDAR for _, c in clouds)
    images = [(t, json.loads(d)) for topic, t, d in msgs if topic == "/camera/image"]
    assert [t for t, _ in images] == [fr.meta["camera_stamp_ns"] for fr in loaded["camera"]]
    assert images[0][1]["frame_id"] == CAMERA
    # decimated only when asked
    path = write_review_mcap(tmp_path / "small.mcap", site, loaded, max_points=50)
    with open(path, "rb") as f:
        n = [len(base64.b64decode(json.loads(m.data)["data"])) // 12
             for _, c, m in make_reader(f).iter_messages(topics=["/lidar/points"])]
    assert all(0 < k <= 50 for k in n)


# ----------------------------------------------------------------------------- smaller
def test_version_is_the_changelogs():
    from xcalib import __version__

    root = Path(__file__).resolve().parents[1]
    head = re.search(r"^## (\S+)", (root / "CHANGELOG.md").read_text(), re.M).group(1)
    assert head == __version__
    assert f"xcalib {__version__} (input protocol" in (root / "docs" / "cli.md").read_text()


def test_calibrate_help_paragraphs_are_one_line_each():
    from xcalib.cli.calibrate_cmd import _HELP

    assert all("\n" not in p for p in _HELP.split("\n\n"))


def test_bag_frames_counts_frames_that_decode(tmp_path, frames, capsys):
    from xcalib.cli import main

    store = typestore(2)
    good = _bag(tmp_path, frames)
    # the same recording with the 2nd image's bytes cut short
    from mcap.reader import make_reader
    from mcap.writer import Writer

    bad = tmp_path / "bad.mcap"
    with open(good, "rb") as f, open(bad, "wb") as g:
        w = Writer(g)
        w.start(profile="ros2", library="test")
        sch, ch, n_img = {}, {}, 0
        for schema, channel, message in make_reader(f).iter_messages(log_time_order=True):
            if schema.id not in sch:
                sch[schema.id] = w.register_schema(schema.name, schema.encoding, schema.data)
            if channel.id not in ch:
                ch[channel.id] = w.register_channel(channel.topic, channel.message_encoding, sch[schema.id])
            data = message.data
            if channel.topic == "/camera/image_raw":
                n_img += 1
                if n_img == 2:
                    msg = store.deserialize_cdr(data, "sensor_msgs/msg/Image")
                    msg.data = msg.data[:10]
                    data = bytes(store.serialize_cdr(msg, "sensor_msgs/msg/Image"))
            w.add_message(ch[channel.id], message.log_time, data, message.publish_time)
        w.finish()
    assert main(["bag", "frames", str(bad)]) == 0
    out = capsys.readouterr().out
    assert "3 frame(s) paired" in out and "2 of 3 paired frame(s) decode" in out


def test_bag_round_trip_keeps_each_cameras_frame_key(tmp_path, frames):
    import dataclasses

    from xcalib.io.bags import write_bag
    from xcalib.io.sources import merge_cameras

    views = {c: [dataclasses.replace(f, camera_name=c, frame_key=f"s{i}/{c}") for i, f in enumerate(frames[:2])]
             for c in ("front", "rear")}
    path = write_bag(tmp_path / "two.mcap", merge_cameras(views))
    rear = BagFrames(path, "rear")
    assert [f.frame_key for f in rear] == ["s0/rear", "s1/rear"] == rear.frame_keys


def test_tf_prior_starts_from_the_recordings_tf(tmp_path, frames):
    from xcalib.cli.calibrate_cmd import _tf_priors
    from xcalib.site import calibrate_site

    seq = BagFrames(_bag(tmp_path, frames))
    priors = _tf_priors({"camera": seq}, "rec.mcap")
    np.testing.assert_allclose(priors["camera"], frames[0].extrinsics, atol=1e-6)
    seen = {}

    def fake(fr, intr, stage, prior=None):
        seen["prior"] = prior
        return CalibrationResult(success=True, rotation=np.asarray(prior)[:3, :3], translation=np.asarray(prior)[:3, 3],
                                 intrinsics=intr)

    site, _ = calibrate_site({"camera": seq}, calibrate=fake, priors=priors)
    assert seen["prior"] is priors["camera"] and site.cameras[0].vs_recorded == pytest.approx((0.0, 0.0), abs=1e-6)
    # a recording without a tf between the two frames: --tf-prior is refused, naming both frames
    import typer

    seq.tf_T_cam_lidar = None
    with pytest.raises(typer.BadParameter, match="no tf between the cloud's frame 'velodyne' and the image's "
                                                 "'camera_optical_frame'"):
        _tf_priors({"camera": seq}, "rec.mcap")


def test_mcap_without_a_summary_is_read(tmp_path, frames):
    """A recording that was not closed (no summary section): schemas and channels from the records."""
    from mcap.reader import make_reader
    from mcap.writer import Writer

    good = _bag(tmp_path, frames, "mcap_ros2-no-msg.mcap")
    cut = tmp_path / "cut.mcap"
    with open(good, "rb") as f, open(cut, "wb") as g:
        w = Writer(g, use_chunking=False)
        w.start(profile="ros2", library="test")
        sch, ch = {}, {}
        for schema, channel, message in make_reader(f).iter_messages(log_time_order=True):
            if schema.id not in sch:
                sch[schema.id] = w.register_schema(schema.name, schema.encoding, schema.data)
            if channel.id not in ch:
                ch[channel.id] = w.register_channel(channel.topic, channel.message_encoding, sch[schema.id])
            w.add_message(ch[channel.id], message.log_time, message.data, message.publish_time)
        g.flush()  # no finish(): no summary, no footer
    with open(cut, "rb") as f:
        try:
            summary = make_reader(f).get_summary()
        except Exception:  # noqa: BLE001 - the mcap library's error for a missing footer
            summary = None
    assert summary is None
    seq = BagFrames(cut)
    assert len(seq) == len(frames)


def test_frame_ids_that_are_not_plain_names_are_not_written(frames, caplog):
    from xcalib.site import calibrate_site

    class View(list):
        lidar_frame_id, camera_frame_id = "velodyne", 'cam"\n touch x #'

    def fake(fr, intr, stage, prior=None):
        return CalibrationResult(success=True, rotation=np.eye(3), translation=np.zeros(3), intrinsics=intr)

    with caplog.at_level(logging.WARNING):
        site, _ = calibrate_site({"front": View(frames[:1])}, calibrate=fake)
    assert site.lidar_frame == "velodyne" and site.cameras[0].child_frame == "front_optical_frame"
    assert "not a plain tf frame name" in caplog.text
    from xcalib.cli import main

    assert main(["calibrate", "missing.mcap", "--lidar-frame", "a b"]) == 2  # a usage error, before reading


def test_autoware_shapes_cylinder_polygon_and_unknown_orientation():
    from xcalib.io.bags._objects import boxes3d_any

    store = typestore(2)
    T = store.types
    pkg = "autoware_perception_msgs"

    def obj(shape_type, dims, footprint=(), yaw=0.3, availability=2, pos=(10.0, 2.0, 0.5)):
        pose = T["geometry_msgs/msg/Pose"](
            position=T["geometry_msgs/msg/Point"](x=pos[0], y=pos[1], z=pos[2]),
            orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=float(np.sin(yaw / 2)), w=float(np.cos(yaw / 2))))
        zero = T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
        kin = T[f"{pkg}/msg/DetectedObjectKinematics"](
            pose_with_covariance=T["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=np.zeros(36)),
            has_position_covariance=False, orientation_availability=availability,
            twist_with_covariance=T["geometry_msgs/msg/TwistWithCovariance"](
                twist=T["geometry_msgs/msg/Twist"](linear=zero, angular=zero), covariance=np.zeros(36)),
            has_twist=False, has_twist_covariance=False)
        pts = [T["geometry_msgs/msg/Point32"](x=float(x), y=float(y), z=0.0) for x, y in footprint]
        shape = T[f"{pkg}/msg/Shape"](type=shape_type, footprint=T["geometry_msgs/msg/Polygon"](points=pts),
                                      dimensions=T["geometry_msgs/msg/Vector3"](x=dims[0], y=dims[1], z=dims[2]))
        return T[f"{pkg}/msg/DetectedObject"](existence_probability=1.0, classification=[], kinematics=kin, shape=shape)

    def msg(*objs):
        return T[f"{pkg}/msg/DetectedObjects"](header=cv.make_header(store, 1, LIDAR), objects=list(objs))

    where = ("rec.mcap", "/objects")
    b = boxes3d_any(msg(obj(1, (0.6, 0.0, 1.7)), obj(2, (0.0, 0.0, 1.5), footprint=[(0, -1), (4, -1), (4, 1), (0, 1)])),
                    where)
    np.testing.assert_allclose(b.box7[0], [10.0, 2.0, 0.5, 0.6, 0.6, 1.7, 0.3], atol=1e-12)  # cylinder: diameter
    c, s = np.cos(0.3), np.sin(0.3)  # the polygon's centre (2, 0) in the object frame, turned by the yaw
    np.testing.assert_allclose(b.box7[1], [10.0 + 2 * c, 2.0 + 2 * s, 0.5, 4.0, 2.0, 1.5, 0.3], atol=1e-12)
    assert not b.yawless
    assert boxes3d_any(msg(obj(0, (4.0, 2.0, 1.5), availability=0)), where).yawless  # UNAVAILABLE
    with pytest.raises(FormatError, match="unknown shape type 7"):
        boxes3d_any(msg(obj(7, (1.0, 1.0, 1.0))), where)
    with pytest.raises(FormatError, match=r"box size \[4.0, -2.0, 1.5\] is not positive"):
        boxes3d_any(msg(obj(0, (4.0, -2.0, 1.5))), where)
