"""Safe with untrusted recordings (issue 31, items 3 and 4): bag inputs pass the special-file
checks before the bag library opens them, the decoders validate every field they rely on, and a
seeded sample of the mutation campaign (``tests/_bag_cases.py``; the whole set:
``benchmarks/bench_untrusted.py --part recordings``) gives only clean FormatErrors or valid data."""

from __future__ import annotations

import json
import logging
import math
import os
import pickle
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from xcalib.errors import FormatError
from xcalib.io.bags import BagFrames, bag_cameras
from xcalib.io.bags import _convert as cv
from xcalib.io.bags._msgs import typestore

from _bag_cases import MUTATIONS, Pool, Samples, _message_case, make_bag, plan, read_bag

TESTS = Path(__file__).resolve().parent
REPO = TESTS.parent
ENV = dict(os.environ, PYTHONPATH=str(REPO / "src"), OMP_NUM_THREADS="1")
WHERE = ("x.mcap", "/lidar/points", 3)


# ------------------------------------------------------------------------- item 3: special files
_SPECIAL = r"""
import sys
from xcalib.errors import FormatError
from xcalib.io.bags import BagFrames, bag_info
for p in sys.argv[1:]:
    for fn in (bag_info, BagFrames):
        try:
            fn(p)
            print("read", p)
        except FormatError as exc:
            print("refused", exc.path, "|", exc.problem)
"""


def test_fifo_and_dev_zero_bags_are_refused_at_once(tmp_path):
    """``mkfifo f.mcap`` / ``ln -s /dev/zero z.bag``: refused before any read, naming the file
    (run in a subprocess with a timeout, so a regression fails instead of hanging the suite)."""
    paths = []
    for suffix in (".mcap", ".bag", ".db3"):
        f = tmp_path / f"fifo{suffix}"
        os.mkfifo(f)
        z = tmp_path / f"zero{suffix}"
        z.symlink_to("/dev/zero")
        paths += [f, z]
    folder = tmp_path / "ros2_bag"
    folder.mkdir()
    os.mkfifo(folder / "metadata.yaml")
    paths.append(folder)
    r = subprocess.run([sys.executable, "-c", _SPECIAL, *map(str, paths)], capture_output=True, text=True,
                       timeout=120, env=ENV)
    lines = r.stdout.strip().splitlines()
    assert len(lines) == 2 * len(paths), r.stderr[-2000:]
    for line in lines:
        assert line.startswith("refused"), line
    assert sum("FIFO" in ln for ln in lines) == 8 and sum("device (through a symlink)" in ln for ln in lines) == 6
    for p in paths[:-1]:
        assert any(f"refused {p} |" in ln for ln in lines)
    assert any("metadata.yaml" in ln for ln in lines)


# --------------------------------------------------------------------- item 4: PointCloud2 fields
@pytest.fixture(scope="module")
def store():
    return typestore(2)


def _cloud(store, n=12, **kw):
    pts = np.random.default_rng(0).normal(size=(n, 4)) * 5
    return pts, cv.make_pointcloud2(store, pts, ("x", "y", "z", "intensity"), 5, "lidar", **kw)


def _field(msg, name):
    return next(f for f in msg.fields if f.name == name)


@pytest.mark.parametrize("edit, field", [
    (lambda m: setattr(m, "is_bigendian", True), "is_bigendian|data"),
    (lambda m: setattr(_field(m, "x"), "datatype", 8), "fields\\[1\\].offset"),   # x as float64 overlaps y
    (lambda m: setattr(_field(m, "x"), "offset", 2), "fields\\[1\\].offset"),
    (lambda m: setattr(_field(m, "y"), "offset", 0), "fields\\[1\\].offset"),    # y == x
    (lambda m: setattr(_field(m, "x"), "datatype", 5), "fields\\[0\\].datatype"),  # int32 coordinates
    (lambda m: setattr(_field(m, "intensity"), "count", 10**9), "fields\\[3\\].count"),
    (lambda m: setattr(m, "height", 0), "field data"),
    (lambda m: setattr(m, "point_step", 0), "point_step"),
    (lambda m: setattr(m, "data", np.asarray(m.data)[:-3]), "field data"),
    (lambda m: setattr(m, "row_step", m.row_step - 16), "row_step"),
])
def test_pointcloud2_fields_that_do_not_fit_the_data_are_refused(store, edit, field):
    _, msg = _cloud(store)
    edit(msg)
    with pytest.raises(FormatError, match=f"message 3, (field )?({field})") as ei:
        cv.cloud_from_msg(msg, WHERE)
    assert ei.value.path == "x.mcap" and ei.value.field == "/lidar/points"


def test_pointcloud2_absurd_coordinates_refused_nan_points_counted(store):
    pts, msg = _cloud(store)
    big = pts.copy()
    big[3, 1] = 1e30
    msg_big = cv.make_pointcloud2(store, big, ("x", "y", "z", "intensity"), 5, "lidar")
    with pytest.raises(FormatError, match="1e\\+30 m"):
        cv.cloud_from_msg(msg_big, WHERE)
    nan = pts.copy()
    nan[::3, 0] = np.nan
    got, _, n_bad = cv.cloud_from_msg(cv.make_pointcloud2(store, nan, ("x", "y", "z", "intensity"), 5, "l"), WHERE)
    assert n_bad == 4 and len(got) == 8 and np.isfinite(got).all()
    empty = cv.make_pointcloud2(store, np.zeros((0, 4)), ("x", "y", "z", "intensity"), 5, "l")
    got, _, n_bad = cv.cloud_from_msg(empty, WHERE)
    assert got.shape == (0, 4) and n_bad == 0


# ----------------------------------------------------------------------- item 4: CameraInfo, boxes
def _info(store, **k_edits):
    from xcalib.geometry import CameraIntrinsics

    msg = cv.make_camera_info(store, CameraIntrinsics(600, 600, 320, 240, [-0.1, 0.01, 0, 0, 0]), 1, "cam", 640, 480)
    for key, (i, v) in k_edits.items():
        a = np.array(getattr(msg, key), dtype=np.float64)
        a[i] = v
        setattr(msg, key, a)
    return msg


@pytest.mark.parametrize("edits, match", [
    ({"k": (0, 1e-9)}, "fx"),
    ({"k": (0, 1e9)}, "implausible|fx/fy"),
    ({"k": (1, 5.0)}, "no skew"),
    ({"k": (8, 0.0)}, "K\\[8\\] = 1"),
    ({"k": (2, float("nan"))}, "not a calibrated"),
    ({"d": (0, 1e6)}, "absurd"),
    ({"d": (1, float("nan"))}, "not finite"),
    ({"r": (0, float("nan"))}, "R \\(rectification\\)"),
    ({"r": (1, 0.5)}, "not identity"),
])
def test_camera_info_fields_validated(store, edits, match):
    with pytest.raises(FormatError, match=match) as ei:
        cv.intrinsics_from_msg(_info(store, **edits), ("x.bag", "/cam/camera_info", 0))
    assert "message 0" in ei.value.problem and ei.value.field == "/cam/camera_info"
    assert cv.intrinsics_from_msg(_info(store), ("x.bag", "/cam/camera_info", 0)).fx == 600


def test_box_fields_validated(store):
    where2, where3 = ("x.db3", "/cam/detections", 1), ("x.db3", "/lidar/detections", 1)
    for bad in ([[10, 10, 5, 30]], [[10, np.nan, 40, 30]]):  # negative size (x2 < x1), non-finite
        msg = cv.make_detection2d_array(store, np.array(bad, dtype=np.float64), 1, "cam")
        with pytest.raises(FormatError, match="detection 0"):
            cv.boxes2d_from_msg(msg, where2)
    ok = np.array([[1.0, 2.0, 0.0, 4.0, 2.0, 1.5, 0.3]])
    assert np.allclose(cv.boxes3d_from_msg(cv.make_detection3d_array(store, ok, 1, "l"), where3)[0], ok)
    for col, v, match in [(3, 0.0, "must be > 0"), (4, -1.0, "must be > 0"), (0, np.nan, "non-finite"),
                          (1, 1e12, "beyond")]:
        b = ok.copy()
        b[0, col] = v
        with pytest.raises(FormatError, match=match):
            cv.boxes3d_from_msg(cv.make_detection3d_array(store, b, 1, "l"), where3)
    for q in ({"x": 0.0, "y": 0.0, "z": 0.0, "w": 0.0}, {"w": float("nan")}):
        msg = cv.make_detection3d_array(store, ok, 1, "l")
        for k, v in q.items():
            setattr(msg.detections[0].bbox.center.orientation, k, v)
        with pytest.raises(FormatError, match="not a unit quaternion"):
            cv.boxes3d_from_msg(msg, where3)


# ------------------------------------------------------------ item 4: whole bags (reader-level)
@pytest.fixture(scope="module")
def sample_mcap(tmp_path_factory):
    return make_bag(tmp_path_factory.mktemp("bags"), ".mcap")


def _mutated(sample, tmp_path, name):
    dst = tmp_path / f"{name}.mcap"
    return _message_case(sample, dst, MUTATIONS[name], np.random.default_rng(0))


def test_two_cameras_of_one_name_are_both_kept(sample_mcap, tmp_path, caplog):
    p = _mutated(sample_mcap, tmp_path, "two_cameras_one_name")
    with caplog.at_level(logging.WARNING):
        cams = bag_cameras(p)
    assert sorted(c.name for c in cams) == ["a_cam", "b_cam"] and "same camera name" in caplog.text
    with pytest.raises(FormatError, match="several cameras"):
        BagFrames(p)
    seq = BagFrames(p, "/b/cam/image")
    assert seq.camera == "b_cam" and seq.topics["camera_info"] == "/b/cam/camera_info" and len(seq) == 3


def test_sweeps_sharing_a_stamp_are_dropped_and_reported(sample_mcap, tmp_path, caplog):
    p = _mutated(sample_mcap, tmp_path, "dup_lidar_stamp")
    with caplog.at_level(logging.WARNING):
        seq = BagFrames(p)
    reasons = [d.reason for d in seq.report.dropped if d.topic == "/lidar/points"]
    assert sum("share this stamp" in r for r in reasons) == 2 and len(seq) == 1
    assert "share their header stamp" in caplog.text


@pytest.mark.parametrize("name, match", [
    ("topic_newline", r"topic name '/cam\\ntouch PWNED"),
    ("topic_rtl", r"topic name '/cam\\u202egpj"),
    ("rec_nested", "frame record is not valid JSON \\(RecursionError"),
    ("rec_extr_scaled", "cameras.cam.extrinsics: not a rigid transform"),
    ("rec_time_nan", "lidar_time_s: expected a finite number"),
])
def test_bag_level_refusals_name_bag_topic_message_field(sample_mcap, tmp_path, name, match):
    p = _mutated(sample_mcap, tmp_path, name)
    with pytest.raises(FormatError, match=match) as ei:
        seq = BagFrames(p)
        [seq[i] for i in range(len(seq))]
    assert Path(ei.value.path).name == p.name


def test_nan_points_and_empty_clouds_warn(sample_mcap, tmp_path, caplog):
    for name, text in (("pc_some_nan", "NaN/Inf coordinates dropped"), ("pc_empty", "point cloud is empty")):
        p = _mutated(sample_mcap, tmp_path, name)
        caplog.clear()
        with caplog.at_level(logging.WARNING):
            got = read_bag(p)
        frames = got["cameras"]["cam"][1]
        assert text in caplog.text and "message 0" in caplog.text
        assert name != "pc_some_nan" or frames[0].meta["points_dropped_nonfinite"] == 14


# ----------------------------------------------------------- item 4: intrinsics JSON, camera_info YAML
def test_intrinsics_json_and_camera_info_yaml_refuse_non_numbers(tmp_path):
    from xcalib.formats.ros import read_camera_info
    from xcalib.geometry import CameraIntrinsics

    from _bag_cases import make_camera_info_yaml, make_intrinsics_json

    good = make_intrinsics_json(tmp_path)
    d = json.loads(good.read_text())
    for key, value in (("fx", True), ("fx", "1000"), ("cy", None), ("width", 1280.5), ("fx", 1e-9)):
        bad = tmp_path / "bad.json"
        bad.write_text(json.dumps({**d, key: value}))
        with pytest.raises(FormatError, match="bad.json"):
            CameraIntrinsics.from_json(bad)
    deep = tmp_path / "deep.json"
    deep.write_text("[" * 100000)
    with pytest.raises(FormatError, match="not valid JSON"):
        CameraIntrinsics.from_json(deep)
    import yaml

    y = make_camera_info_yaml(tmp_path)
    info = yaml.safe_load(y.read_text())
    assert read_camera_info(y).fx == 1000.0
    quoted = json.loads(json.dumps(info))
    quoted["camera_matrix"]["data"][0] = "1000.0"
    dropped = json.loads(json.dumps(info))
    del dropped["camera_matrix"]["data"][4]
    flag = json.loads(json.dumps(info))
    flag["distortion_coefficients"]["data"][0] = True
    for variant, match in ((quoted, "expected numbers"), (dropped, "3 x 3 matrix holds 8 numbers"),
                           (flag, "expected numbers, found True")):
        y.write_text(yaml.safe_dump(variant))
        with pytest.raises(FormatError, match=match):
            read_camera_info(y)


def test_mmdet3d_malformed_infos_name_the_file(tmp_path):
    from xcalib.formats.mmdet3d import read_mmdet3d_infos

    from _bag_cases import make_mmdet3d_info

    p = make_mmdet3d_info(tmp_path)
    base = pickle.loads(p.read_bytes())
    assert len(read_mmdet3d_infos(p)) == 2
    edits = [lambda d: d["data_list"].__setitem__(0, 5),
             lambda d: d["data_list"][0].__setitem__("images", [1, 2]),
             lambda d: d["data_list"][0]["images"]["CAM_FRONT"].__setitem__("cam2img", "K"),
             lambda d: d["data_list"][0]["cam_instances"]["CAM_FRONT"][0].pop("bbox"),
             lambda d: d["data_list"][0]["instances"][0].__setitem__("bbox_3d", [1, 2, 3, 0, 1, 1, 0]),
             lambda d: d["data_list"][1]["lidar_points"].__setitem__("num_pts_feats", 10**9),
             lambda d: d.__setitem__("metainfo", 3)]
    for i, edit in enumerate(edits):
        d = pickle.loads(pickle.dumps(base))
        edit(d)
        q = tmp_path / f"m{i}.pkl"
        q.write_bytes(pickle.dumps(d))
        with pytest.raises(FormatError) as ei:
            read_mmdet3d_infos(q)
        assert ei.value.path == str(q), i
    big = tmp_path / "corrupt.pkl"  # a length field claiming 2 GB in a 40-byte file
    big.write_bytes(b"\x80\x04\x95" + (1 << 31).to_bytes(8, "little") + b"B" + (1 << 31).to_bytes(4, "little") + b"x" * 20)
    with pytest.raises(FormatError, match="corrupt.pkl"):
        read_mmdet3d_infos(big)


# ---------------------------------------------------------------------- the campaign, a sample
def test_recording_campaign_sample_gives_format_errors_or_valid_data(tmp_path):
    """A seeded sample of the campaign, each case in a killable worker (a hang or a memory
    blow-up fails the test instead of stalling the suite): 0 garbage, 0 unclear, 0 hangs."""
    cases = []
    for reader in ("bag", "db3", "mcap"):
        cases += [c for c in plan(reader, 400, "suite") if c[1] in ("flip", "truncate")][:1]
    cases += [("mcap", k, 1, 2) for k in ("pc_bigendian", "ci_skew", "d3_quat_zero")]
    cases += [("bag", "rec_nested", 1, 2), ("db3", "dup_lidar_stamp", 1, 2)]
    for reader in ("intrinsics_json", "camera_info_yaml", "mmdet3d_pkl"):
        cases += plan(reader, 12, "suite")
    pool = Pool(tmp_path, TESTS, ENV, timeout=60.0, max_rss_mb=1500.0)
    try:
        results = [(c, *pool.run(c)) for c in cases]
    finally:
        pool.close()
    bad = [f"{c}: {o}: {d}" for c, o, d, _ in results if o not in ("ok", "clear")]
    assert not bad, "\n".join(bad)
    assert sum(o == "clear" for _, o, _, _ in results) >= 8


def test_samples_read_back_valid(tmp_path):
    s = Samples(tmp_path)
    got = read_bag(s.base("db3"))
    frames = got["cameras"]["cam"][1]
    assert len(frames) == 3 and all(math.isfinite(f.lidar_time_s) for f in frames)
    assert not got["warnings"]
