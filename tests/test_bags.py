"""Bags without ROS: frames -> .bag / .db3 / .mcap -> frames (exactly equal), message layouts,
pairing, bad input."""

from __future__ import annotations

import numpy as np
import pytest

from xcalib.errors import FormatError
from xcalib.io.bags import BagFrames, bag_info, pair_by_time, write_bag
from xcalib.io.bags import _convert as cv
from xcalib.io.bags._msgs import typestore
from xcalib.io.sources import camera_view, open_source

CONTAINERS = (".bag", ".db3", ".mcap")


@pytest.fixture(scope="module")
def site_frames():
    from xcalib.data.synth import generate_frames, sample_site

    site = sample_site(3, width=160, height=100, focal_px=150)
    frames = generate_frames(site, 3, seed=0)
    rng = np.random.default_rng(5)
    for i, f in enumerate(frames):
        f.point_cloud = np.ascontiguousarray(f.point_cloud[::40])
        f.lidar_time_s = 1_650_000_000.123456789 + 0.1 * i   # not a whole number of ns
        f.camera_time_s = f.lidar_time_s - 0.0123
        f.track_ids_3d = np.arange(f.num_3d, dtype=np.int64) * 7 + i
        f.velocities_3d = rng.normal(size=(f.num_3d, 3))
    return frames


def assert_frames_equal(a, b):
    for k in ("image", "point_cloud", "bboxes_2d", "bboxes_3d", "match_matrix", "extrinsics"):
        x, y = getattr(a, k), getattr(b, k)
        assert (x is None) == (y is None), k
        if x is not None:
            assert x.dtype == y.dtype and x.shape == y.shape and np.array_equal(x, y), k
    for k in ("track_ids_3d", "velocities_3d"):
        x, y = getattr(a, k), getattr(b, k)
        assert (x is None) == (y is None), k
        if x is not None:
            assert x.dtype == y.dtype and np.array_equal(x, y), k
    for k in ("lidar_time_s", "camera_time_s"):
        if getattr(a, k) is not None:
            assert getattr(b, k) == getattr(a, k), k
    assert a.intrinsics == b.intrinsics
    assert (a.frame_key, a.camera_name, tuple(a.point_fields)) == (b.frame_key, b.camera_name, tuple(b.point_fields))


@pytest.mark.parametrize("suffix", CONTAINERS)
def test_frames_round_trip_exactly(tmp_path, site_frames, suffix):
    path = write_bag(tmp_path / f"site{suffix}", site_frames)
    back = open_source(path)
    assert back.source_name == "bag" and len(back) == len(site_frames)
    for a, b in zip(site_frames, back):
        assert_frames_equal(a, b)
    assert np.allclose(back.tf_T_cam_lidar, site_frames[0].extrinsics, atol=1e-9)
    assert back.report.frames == 3 and not back.report.dropped
    info = bag_info(path)
    counts = {t.topic: t.count for t in info.topics}
    assert counts["/lidar/points"] == 3 and counts["/camera/image"] == 3
    assert abs({t.topic: t for t in info.topics}["/lidar/points"].rate_hz - 10.0) < 1e-6
    with pytest.raises(FileExistsError):
        write_bag(path, site_frames)


def test_png_images_box7_and_frame_selection(tmp_path, site_frames):
    from xcalib.formats.kitti import box7_to_protocol  # noqa: F401 - box7 boxes straight through

    frames = [f for f in site_frames]
    for f in frames:
        f.meta = dict(f.meta)
    box7 = [np.asarray(f.meta["box7"], dtype=np.float32) for f in frames]
    import dataclasses

    frames7 = [dataclasses.replace(f, bboxes_3d=b) for f, b in zip(frames, box7)]
    path = write_bag(tmp_path / "s.mcap", frames7, image_format="png")
    back = open_source(path, frames="1:3")
    assert len(back) == 2
    for a, b in zip(frames7[1:], back):
        assert_frames_equal(a, b)


def _two_camera_frames(frames):
    out = []
    for f in frames:
        g = camera_view(f, f.camera_name)
        flipped = np.ascontiguousarray(f.image[:, ::-1])
        w = f.image.shape[1]
        b2r = f.bboxes_2d.copy()
        b2r[:, [0, 2]] = w - f.bboxes_2d[:, [2, 0]]
        T_right = f.extrinsics.copy()
        T_right[0, 3] += 0.5
        out.append(type(f)(image=f.image, point_cloud=f.point_cloud, bboxes_2d=np.vstack([f.bboxes_2d, b2r]),
                           bboxes_3d=f.bboxes_3d, camera_name="left", frame_key=f.frame_key,
                           match_matrix=np.vstack([f.match_matrix, f.match_matrix]), intrinsics=f.intrinsics,
                           images={"left": f.image, "right flipped": flipped},
                           camera_per_det=["left"] * g.num_2d + ["right flipped"] * g.num_2d,
                           point_fields=f.point_fields,
                           meta={"intrinsics_by_camera": {"left": f.intrinsics, "right flipped": f.intrinsics},
                                 "extrinsics_by_camera": {"left": f.extrinsics, "right flipped": T_right}}))
    return out


def test_multi_camera_bag_reads_each_camera(tmp_path, site_frames):
    frames = _two_camera_frames(site_frames)
    path = write_bag(tmp_path / "two.db3", frames)
    with pytest.raises(FormatError, match="several cameras"):
        BagFrames(path)
    for cam, seg in (("left", "left"), ("right flipped", "right_flipped")):
        back = open_source(path, camera=seg)
        assert back.camera == seg and back.report.max_dt_s > 0
        for a, b in zip(frames, back):
            want = camera_view(a, cam)
            assert_frames_equal(want, b)
    with pytest.raises(FormatError, match="no camera 'middle'.*left"):
        open_source(path, camera="middle")


def test_pointcloud2_layouts():
    store = typestore(2)
    rng = np.random.default_rng(1)
    pts = np.hstack([rng.normal(size=(6, 3)) * 10, rng.integers(0, 1000, (6, 1))]).astype(np.float64)
    pts[2, 0] = np.nan  # organised clouds mark missing returns with NaN
    where = ("x.bag", "/points")
    for big in (False, True):
        msg = cv.make_pointcloud2(store, pts, ("x", "y", "z", "intensity"), 5, "lidar",
                                  datatypes=["f8", "f4", "f4", "u2"], big_endian=big, height=2, point_padding=3,
                                  row_padding=5)
        got, fields, bad = cv.cloud_from_msg(msg, where)
        keep = np.isfinite(pts[:, 0])
        assert fields == ("x", "y", "z", "intensity") and bad == 1 and got.dtype == np.float32
        assert np.array_equal(got, pts[keep].astype(np.float32))
    msg = cv.make_pointcloud2(store, pts[:, [3, 0, 1, 2]], ("intensity", "x", "y", "z"), 5, "lidar")
    got, fields, _ = cv.cloud_from_msg(msg, where)
    assert fields[:3] == ("x", "y", "z") and np.allclose(got[:, 3], pts[np.isfinite(pts[:, 0]), 3])
    msg.row_step = 1
    with pytest.raises(FormatError, match="does not fit"):
        cv.cloud_from_msg(msg, where)


def _image_msg(store, data, enc, h, w, step, big=0):
    return store.types["sensor_msgs/msg/Image"](header=cv.make_header(store, 1, "cam"), height=h, width=w,
                                                encoding=enc, is_bigendian=big, step=step,
                                                data=np.frombuffer(data, np.uint8))


def test_image_encodings():
    store = typestore(1)
    rng = np.random.default_rng(2)
    rgb = rng.integers(0, 256, (4, 5, 3), dtype=np.uint8)
    where = ("x.bag", "/img")
    pad = lambda a, n: np.hstack([a.reshape(a.shape[0], -1), np.zeros((a.shape[0], n), np.uint8)]).tobytes()  # noqa: E731
    assert np.array_equal(cv.image_from_msg(_image_msg(store, pad(rgb, 0), "rgb8", 4, 5, 15), where), rgb)
    assert np.array_equal(cv.image_from_msg(_image_msg(store, pad(rgb[:, :, ::-1].copy(), 2), "bgr8", 4, 5, 17),
                                            where), rgb)
    mono = rgb[:, :, 0].copy()
    got = cv.image_from_msg(_image_msg(store, pad(mono, 1), "mono8", 4, 5, 6), where)
    assert np.array_equal(got, np.repeat(mono[:, :, None], 3, axis=2))
    m16 = (mono.astype(np.uint16) * 257)
    got = cv.image_from_msg(_image_msg(store, m16.astype(">u2").tobytes(), "mono16", 4, 5, 10, big=1), where)
    assert np.array_equal(got[:, :, 0], mono)
    comp = cv.make_compressed(store, rgb, 1, "cam", "png")
    assert np.array_equal(cv.image_from_msg(comp, where), rgb)
    jpg = cv.make_compressed(store, np.full((16, 16, 3), 128, np.uint8), 1, "cam", "jpeg")
    assert np.abs(cv.image_from_msg(jpg, where).astype(int) - 128).max() <= 2
    with pytest.raises(FormatError, match="unsupported image encoding 'yuv422'"):
        cv.image_from_msg(_image_msg(store, pad(rgb, 0), "yuv422", 4, 5, 15), where)


@pytest.mark.parametrize("ros", [1, 2])
def test_camera_info_models(ros):
    from xcalib.geometry.camera import CameraIntrinsics

    store = typestore(ros)
    where = ("x.bag", "/cam/camera_info")
    for d in ([0.1, -0.05, 0.001, 0.002, 0.01], [0.1, -0.05, 0.001, 0.002, 0.01, 0.2, 0.03, 0.004]):
        intr = CameraIntrinsics(500.0, 510.0, 320.0, 240.0, d, 640, 480)
        msg = cv.make_camera_info(store, intr, 1, "cam", 640, 480)
        assert msg.distortion_model == ("plumb_bob" if len(d) == 5 else "rational_polynomial")
        got = cv.intrinsics_from_msg(msg, where)
        assert got == intr and np.array_equal(got.distortion, intr.distortion)
    msg.distortion_model = "equidistant"
    with pytest.raises(FormatError, match="equidistant needs 4"):
        cv.intrinsics_from_msg(msg, where)
    msg.distortion_model = "double_sphere"
    with pytest.raises(FormatError, match="unsupported distortion_model 'double_sphere'"):
        cv.intrinsics_from_msg(msg, where)


def test_equidistant_camera_info_is_rectified_to_pinhole():
    import cv2

    from xcalib.geometry.camera import CameraIntrinsics

    store = typestore(2)
    msg = cv.make_camera_info(store, CameraIntrinsics(300.0, 300.0, 320.0, 240.0, None, 640, 480), 1, "cam", 640, 480)
    msg.distortion_model, msg.d = "equidistant", np.array([0.08, -0.02, 0.004, -0.001])
    fe = cv.camera_model_from_msg(msg, ("x.bag", "/cam/camera_info"))
    assert isinstance(fe, cv.Fisheye)
    intr = cv.intrinsics_from_msg(msg, ("x.bag", "/cam/camera_info"))
    assert intr.distortion is None and (intr.width, intr.height) == (640, 480)
    X = np.array([[1.5, -0.8, 3.0], [-2.0, 1.0, 2.5]])
    uv_d, _ = cv2.fisheye.projectPoints(X.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), fe.K, fe.D)
    uv_d = uv_d.reshape(-1, 2)
    uv_p = (fe.K_new @ (X / X[:, 2:]).T).T[:, :2]  # the same points through the rectified pinhole camera
    boxes = np.hstack([uv_d - 0.25, uv_d + 0.25])
    got = fe.rectify_boxes(boxes)
    np.testing.assert_allclose((got[:, :2] + got[:, 2:]) / 2, uv_p, atol=0.05)
    img = np.zeros((480, 640, 3), np.uint8)
    u, v = np.round(uv_d[0]).astype(int)
    img[v - 2:v + 3, u - 2:u + 3] = 255
    ys, xs = np.nonzero(fe.rectify_image(img)[:, :, 0] > 100)
    assert abs(xs.mean() - uv_p[0, 0]) < 1.0 and abs(ys.mean() - uv_p[0, 1]) < 1.0


@pytest.mark.parametrize("suffix,layout", [(".db3", "ros1"), (".bag", "ros2")])
def test_other_vision_msgs_layout(tmp_path, site_frames, suffix, layout):
    path = write_bag(tmp_path / f"l{suffix}", site_frames[:1], vision_layout=layout)
    back = open_source(path)
    assert_frames_equal(site_frames[0], back[0])


def test_bag_without_message_definitions(tmp_path, site_frames):
    """A ROS 2 bag whose connections carry no message definitions (older rosbag2): the stock
    humble types + vision_msgs fill in."""
    import sqlite3

    p = write_bag(tmp_path / "nodefs.db3", site_frames[:2])
    with sqlite3.connect(p) as db:
        db.execute("DELETE FROM message_definitions")
    back = open_source(p)
    for a, b in zip(site_frames, back):
        assert_frames_equal(a, b)


def test_pair_by_time_reports_what_it_drops():
    pairs, lost_l, lost_i = pair_by_time([0, 100, 200, 300], [5, 104, 108, 260, 900], 10)
    assert pairs == [(0, 0), (1, 1)]
    assert set(lost_l) == {2, 3} and lost_l[3] == 40
    assert set(lost_i) == {2, 3, 4} and lost_i[2] == 8  # a closer image won sweep 1
    assert pair_by_time([], [1], 5) == ([], {}, {0: -1})


def test_bad_input(tmp_path, site_frames):
    good = write_bag(tmp_path / "g.mcap", site_frames)
    for suffix in CONTAINERS:
        p = write_bag(tmp_path / f"t{suffix}", site_frames)
        cut = tmp_path / f"cut{suffix}"
        cut.write_bytes(p.read_bytes()[: p.stat().st_size // 2])
        with pytest.raises(FormatError, match=str(cut.name)):
            BagFrames(cut)
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"\x00" * 64)
    with pytest.raises(FormatError, match="junk.mcap"):
        bag_info(junk)
    with pytest.raises(FormatError, match=r"no topic '/velodyne'.*/lidar/points \(sensor_msgs/msg/PointCloud2\)"):
        BagFrames(good, lidar="/velodyne")
    with pytest.raises(FormatError, match="expected sensor_msgs/msg/PointCloud2"):
        BagFrames(good, lidar="/camera/image")
    with pytest.raises(FormatError, match="--intrinsics"):
        BagFrames(write_bag(tmp_path / "noinfo.bag", [_no_intrinsics(f) for f in site_frames]))
    with pytest.raises(FormatError, match="clocks do not overlap"):
        BagFrames(write_bag(tmp_path / "late.db3", [_untimed(f) for f in site_frames], camera_delay_s=30.0))
    with pytest.raises(FormatError, match="no frame could be paired.*no image within 5 ms"):
        BagFrames(good, tolerance_s=0.005)
    back = BagFrames(good, tolerance_s=0.015)
    assert len(back) == 3
    assert not (tmp_path / "late.db3.tmp").exists() and len(list(tmp_path.glob(".*"))) == 0


@pytest.mark.parametrize("suffix", CONTAINERS)
def test_corrupted_bytes_give_format_errors_only(tmp_path, site_frames, suffix):
    """Random byte flips: every outcome is a frame list or a FormatError, never another exception."""
    raw = bytearray(write_bag(tmp_path / f"g{suffix}", site_frames[:2]).read_bytes())
    rng = np.random.default_rng(7)
    outcomes = set()
    for trial in range(6):
        b = bytearray(raw)
        for _ in range(3):
            b[int(rng.integers(0, len(b)))] = int(rng.integers(0, 256))
        q = tmp_path / f"f{trial}{suffix}"
        q.write_bytes(bytes(b))
        try:
            seq = BagFrames(q, tolerance_s=1.0)
            [seq[i] for i in range(len(seq))]
            outcomes.add("ok")
        except FormatError as exc:
            assert q.name in str(exc)
            outcomes.add("error")
    assert outcomes  # ran; any exception other than FormatError fails the test


def _untimed(f):
    import dataclasses

    return dataclasses.replace(f, lidar_time_s=None, camera_time_s=None)


def _no_intrinsics(f):
    import dataclasses

    return dataclasses.replace(f, intrinsics=None)


def test_intrinsics_option_replaces_camera_info(tmp_path, site_frames):
    p = write_bag(tmp_path / "noinfo.mcap", [_no_intrinsics(f) for f in site_frames])
    back = BagFrames(p, intrinsics=site_frames[0].intrinsics)
    assert back[0].intrinsics == site_frames[0].intrinsics and back.intrinsics is not None


def test_bag_cli(tmp_path, site_frames, capsys):
    import json

    from xcalib.cli import main
    from xcalib.io.frames import write_frame_folder

    write_frame_folder(tmp_path / "site", site_frames, image_ext=".png")
    out = tmp_path / "site.mcap"
    assert main(["bag", "write", str(tmp_path / "site"), str(out), "--frames", "0:2"]) == 0
    assert main(["bag", "write", str(tmp_path / "site"), str(out)]) == 2  # exists, no --force
    capsys.readouterr()
    assert main(["bag", "info", str(out), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert {t["topic"]: t["count"] for t in info["topics"]}["/lidar/points"] == 2
    assert main(["bag", "frames", str(out), "--json", "--tolerance", "0.02"]) == 0
    rep = json.loads(capsys.readouterr().out)
    assert rep["frames"] == 2 and rep["topics"]["camera_info"] == "/camera/camera_info"
    assert main(["bag", "frames", str(out), "--lidar", "/velodyne_points"]) == 1
    assert "/lidar/points (sensor_msgs/msg/PointCloud2)" in capsys.readouterr().err
    seq = open_source(out)
    for a, b in zip(site_frames, seq):
        assert_frames_equal(a, b)
