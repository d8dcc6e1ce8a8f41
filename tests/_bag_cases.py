"""The untrusted-recording campaign (issue 31): seeded mutations of bags in all three containers
(ROS 1 ``.bag``, ROS 2 ``.db3``, ``.mcap``), of CameraInfo YAML / intrinsics JSON files and of
mmdetection3d info pickles, and the classification of what a reader did with each.

Shared by ``tests/test_untrusted_bags.py`` (a small seeded sample, each case in a killable
worker) and ``benchmarks/bench_untrusted.py --part recordings`` (the whole set).

A case is ``(reader, kind, a, b)``: ``kind`` a byte-level mutation (flip, truncate, append,
zero_block) or a named message-level mutation (``MUTATIONS``: a field of one message set to what
an attacker or a broken driver writes), ``a`` / ``b`` seeds. Outcomes:

* ``ok`` — read, the data pass the validity check and what the mutation demands (a warning for
  dropped NaN points or an empty cloud, both cameras kept, duplicated stamps reported);
* ``clear`` — a FormatError naming the file (or FileNotFoundError naming the path);
* ``refused_valid`` — a FormatError for an input that is valid (counted apart: the second worst);
* ``unclear`` — any other exception;
* ``garbage`` — read without an error but the data are invalid, or the mutation made them
  invalid and nothing said so;
* ``hang`` / ``memory`` — set by the worker pool (no answer in time / peak RSS over the limit).
"""

from __future__ import annotations

import functools
import json
import logging
import math
import pickle
import random
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np

from xcalib.errors import FormatError

CONTAINERS = (".bag", ".db3", ".mcap")
BYTE_KINDS = ("flip", "truncate", "append", "zero_block")
OUTCOMES = ("ok", "clear", "refused_valid", "unclear", "garbage", "hang", "memory")


# ----------------------------------------------------------------------------- the sample bag
def sample_frames(n: int = 3):
    """``n`` small, valid single-camera frames (boxes matched, ground-truth extrinsics)."""
    from xcalib.geometry import CameraIntrinsics
    from xcalib.types import Frame

    out = []
    for k in range(n):
        rng = np.random.default_rng(k)
        b2 = np.array([[10, 10, 40, 30], [50, 20, 70, 60]], np.float32)
        b3 = np.array([[1, 1, 0, 2, 2, 1], [4, -1, 0, 5, 0, 2]], np.float32)
        T = np.eye(4)
        T[:3, 3] = [0.1, 0.2, 0.3]
        out.append(Frame(image=rng.integers(0, 255, (48, 64, 3), dtype=np.uint8),
                         point_cloud=(rng.normal(size=(40, 4)) * 5).astype(np.float32), bboxes_2d=b2, bboxes_3d=b3,
                         camera_name="cam", frame_key=f"{k:04d}", match_matrix=np.eye(2, dtype=bool), extrinsics=T,
                         intrinsics=CameraIntrinsics(60.0, 60.0, 32.0, 24.0, [-0.1, 0.01, 0, 0, 0], 64, 48),
                         point_fields=("x", "y", "z", "intensity")))
    return out


def make_bag(d: Path, suffix: str) -> Path:
    from xcalib.io.bags import write_bag

    return write_bag(Path(d) / f"sample{suffix}", sample_frames(), overwrite=True)


@functools.lru_cache(maxsize=2)
def _store(suffix: str):
    from xcalib.io.bags._msgs import typestore

    return typestore(1 if suffix == ".bag" else 2)


def rewrite_bag(src: Path, dst: Path, edit: Callable) -> Path:
    """Copy bag ``src`` to ``dst`` (same container) message by message through
    ``edit(topic, msgtype, index_on_topic, msg) -> [(topic, msg), ...]`` (an empty list drops it)."""
    from rosbags.highlevel import AnyReader

    suffix = src.suffix.lower()
    store = _store(suffix)
    items = []
    with AnyReader([src], default_typestore=store) as r:
        counts: dict[str, int] = {}
        for con, t, raw in r.messages():
            k = counts.get(con.topic, 0)
            counts[con.topic] = k + 1
            msg = r.deserialize(raw, con.msgtype)
            for topic, m in edit(con.topic, con.msgtype, k, msg):
                items.append((topic, con.msgtype, t, m))
    tmp = dst.parent / (dst.name + ".d")
    if suffix == ".bag":
        from rosbags.rosbag1 import Writer

        w = Writer(dst)
    else:
        from rosbags.rosbag2 import StoragePlugin, Writer

        w = Writer(tmp, version=9, storage_plugin=StoragePlugin.MCAP if suffix == ".mcap" else StoragePlugin.SQLITE3)
    w.open()
    cons = {}
    for topic, msgtype, t, m in items:
        if topic not in cons:
            cons[topic] = w.add_connection(topic, msgtype, typestore=store)
        raw = store.serialize_ros1(m, msgtype) if suffix == ".bag" else store.serialize_cdr(m, msgtype)
        w.write(cons[topic], t, raw)
    w.close()
    if suffix != ".bag":
        shutil.move(str(tmp / f"{tmp.name}{suffix}"), dst)
        shutil.rmtree(tmp, ignore_errors=True)
    return dst


# ----------------------------------------------------------------------- message-level mutations
@dataclass(frozen=True)
class Mutation:
    """``topic`` (suffix of the topic edited), ``fn(msg, rng, store)`` edits one message (index
    ``which``: 0, or -1 for every message); ``expect``: ``refuse`` (the data are invalid: a read
    is garbage), ``warn`` (read, with a warning), ``both_cameras`` / ``dup_reported`` (read, with
    that property), ``any`` (valid data either way)."""

    name: str
    topic: str
    fn: Callable
    expect: str = "refuse"
    which: int = 0


def _pc_field(msg, name):
    return next(f for f in msg.fields if f.name == name)


def _set_xyz(msg, fn):
    """Apply ``fn(xyz float32 [N,3]) -> xyz`` to a little-endian float32 x/y/z cloud in place."""
    pts = np.frombuffer(np.asarray(msg.data, np.uint8).tobytes(), dtype=np.uint8).reshape(-1, msg.point_step)
    xyz = pts[:, :12].copy().view("<f4").reshape(-1, 3)
    new = fn(xyz.astype(np.float64)).astype("<f4")
    out = pts.copy()
    out[:, :12] = new.view(np.uint8).reshape(-1, 12)
    msg.data = out.reshape(-1)


def _pc(**kw):
    def fn(msg, rng, store):
        for k, v in kw.items():
            setattr(msg, k, v(msg, rng) if callable(v) else v)
    return fn


def _field_attr(name, attr, value):
    def fn(msg, rng, store):
        f = _pc_field(msg, name)
        setattr(f, attr, value(msg, rng) if callable(value) else value)
    return fn


def _cam_info(key, value):
    def fn(msg, rng, store):
        low = hasattr(msg, "k")
        attr = key.lower() if low else key.upper()
        if key.lower() in ("width", "height", "distortion_model"):
            setattr(msg, key.lower(), value)
            return
        a = np.array(getattr(msg, attr), dtype=np.float64)
        v = value(a.copy(), rng) if callable(value) else value
        setattr(msg, attr, np.asarray(v, dtype=np.float64))
    return fn


def _idx(i, v):
    def f(a, rng):
        a[i] = v
        return a
    return f


def _det2d(attr, value):
    def fn(msg, rng, store):
        det = msg.detections[int(rng.integers(len(msg.detections)))]
        if attr in ("size_x", "size_y"):
            setattr(det.bbox, attr, value)
        else:
            c = det.bbox.center
            tgt = c.position if hasattr(c, "position") else c
            setattr(tgt, attr, value)
    return fn


def _det3d(part, attr, value):
    def fn(msg, rng, store):
        det = msg.detections[int(rng.integers(len(msg.detections)))]
        obj = {"size": det.bbox.size, "position": det.bbox.center.position,
               "orientation": det.bbox.center.orientation}[part]
        vals = value if isinstance(value, dict) else {attr: value}
        for k, v in vals.items():
            setattr(obj, k, v)
    return fn


def _record(edit):
    def fn(msg, rng, store):
        if isinstance(edit, str):
            msg.data = edit
            return
        rec = json.loads(msg.data)
        edit(rec, rng)
        msg.data = json.dumps(rec, allow_nan=True)
    return fn


def _rec_cam(key, value):
    def f(rec, rng):
        cam = next(iter(rec["cameras"].values()))
        cam[key] = value(cam.get(key)) if callable(value) else value
    return f


def _scale_extr(s):
    return lambda T: (np.asarray(T) * np.array([[s, 1, 1, 1], [1, 1, 1, 1], [1, 1, 1, 1], [1, 1, 1, 1]])).tolist()


def _tf(attr, values):
    def fn(msg, rng, store):
        obj = getattr(msg.transforms[0].transform, attr)
        for k, v in values.items():
            setattr(obj, k, v)
    return fn


def _nested(depth):
    return "[" * depth + "]" * depth


def _image(**kw):
    def fn(msg, rng, store):
        for k, v in kw.items():
            setattr(msg, k, v(msg) if callable(v) else v)
    return fn


NAN, INF = float("nan"), float("inf")
MUTATIONS: dict[str, Mutation] = {m.name: m for m in [
    # PointCloud2: layout fields that do not describe the data
    Mutation("pc_bigendian", "/lidar/points", _pc(is_bigendian=True)),
    Mutation("pc_x_float64", "/lidar/points", _field_attr("x", "datatype", 8)),
    Mutation("pc_x_offset2", "/lidar/points", _field_attr("x", "offset", 2)),
    Mutation("pc_y_overlaps_x", "/lidar/points", _field_attr("y", "offset", 0)),
    Mutation("pc_z_past_step", "/lidar/points", _field_attr("z", "offset", 14)),
    Mutation("pc_x_int8", "/lidar/points", _field_attr("x", "datatype", 1)),
    Mutation("pc_datatype_0", "/lidar/points", _field_attr("y", "datatype", 0)),
    Mutation("pc_datatype_99", "/lidar/points", _field_attr("z", "datatype", 99)),
    Mutation("pc_count_huge", "/lidar/points", _field_attr("intensity", "count", 1_000_000_000)),
    Mutation("pc_count_3", "/lidar/points", _field_attr("x", "count", 3)),
    Mutation("pc_x_renamed", "/lidar/points", _field_attr("x", "name", "q")),
    Mutation("pc_y_named_x", "/lidar/points", _field_attr("y", "name", "x")),
    Mutation("pc_point_step_small", "/lidar/points", _pc(point_step=lambda m, r: m.point_step - 4)),
    Mutation("pc_point_step_big", "/lidar/points", _pc(point_step=lambda m, r: m.point_step + 4)),
    Mutation("pc_point_step_0", "/lidar/points", _pc(point_step=0)),
    Mutation("pc_row_step_small", "/lidar/points", _pc(row_step=lambda m, r: m.row_step - m.point_step)),
    Mutation("pc_row_step_big", "/lidar/points", _pc(row_step=lambda m, r: m.row_step + m.point_step)),
    Mutation("pc_width_big", "/lidar/points", _pc(width=lambda m, r: m.width + 1)),
    Mutation("pc_width_small", "/lidar/points", _pc(width=lambda m, r: m.width - 1), expect="any"),  # row padding
    Mutation("pc_width_huge", "/lidar/points", _pc(width=2**31 - 1)),
    Mutation("pc_height_0", "/lidar/points", _pc(height=0)),
    Mutation("pc_height_2", "/lidar/points", _pc(height=2)),
    Mutation("pc_data_short", "/lidar/points", _pc(data=lambda m, r: np.asarray(m.data)[:-int(r.integers(1, 9))])),
    Mutation("pc_data_long", "/lidar/points", _pc(data=lambda m, r: np.concatenate(
        [np.asarray(m.data), np.zeros(m.point_step, np.uint8)]))),
    Mutation("pc_coords_1e30", "/lidar/points", lambda m, r, s: _set_xyz(m, lambda x: x * 1e30)),
    Mutation("pc_coord_1e6", "/lidar/points", lambda m, r, s: _set_xyz(m, lambda x: np.vstack([x[:-1], [[1e6, 0, 0]]]))),
    Mutation("pc_all_nan", "/lidar/points", lambda m, r, s: _set_xyz(m, lambda x: x * np.nan), expect="warn"),
    Mutation("pc_some_nan", "/lidar/points", lambda m, r, s: _set_xyz(m, lambda x: np.where(
        np.arange(len(x))[:, None] % 3 == 0, np.nan, x)), expect="warn"),
    Mutation("pc_some_inf", "/lidar/points", lambda m, r, s: _set_xyz(m, lambda x: np.where(
        np.arange(len(x))[:, None] % 5 == 0, np.inf, x)), expect="warn"),
    Mutation("pc_empty", "/lidar/points", _pc(width=0, row_step=0, data=np.zeros(0, np.uint8)), expect="warn"),
    Mutation("pc_no_fields", "/lidar/points", _pc(fields=[])),
    # CameraInfo
    Mutation("ci_fx_tiny", "/cam/camera_info", _cam_info("k", _idx(0, 1e-9)), which=-1),
    Mutation("ci_fx_negative", "/cam/camera_info", _cam_info("k", _idx(0, -60.0)), which=-1),
    Mutation("ci_fx_nan", "/cam/camera_info", _cam_info("k", _idx(0, NAN)), which=-1),
    Mutation("ci_fx_huge", "/cam/camera_info", _cam_info("k", _idx(0, 1e12)), which=-1),
    Mutation("ci_fy_ratio", "/cam/camera_info", _cam_info("k", _idx(4, 600.0)), which=-1),
    Mutation("ci_cx_nan", "/cam/camera_info", _cam_info("k", _idx(2, NAN)), which=-1),
    Mutation("ci_cx_far", "/cam/camera_info", _cam_info("k", _idx(2, 1e5)), which=-1),
    Mutation("ci_skew", "/cam/camera_info", _cam_info("k", _idx(1, 5.0)), which=-1),
    Mutation("ci_k8_zero", "/cam/camera_info", _cam_info("k", _idx(8, 0.0)), which=-1),
    Mutation("ci_k3_nonzero", "/cam/camera_info", _cam_info("k", _idx(3, 2.0)), which=-1),
    Mutation("ci_k1_huge", "/cam/camera_info", _cam_info("d", _idx(0, 1e6)), which=-1),
    Mutation("ci_k2_huge", "/cam/camera_info", _cam_info("d", _idx(1, -5e3)), which=-1),
    Mutation("ci_d_nan", "/cam/camera_info", _cam_info("d", _idx(2, NAN)), which=-1),
    Mutation("ci_d_len3", "/cam/camera_info", _cam_info("d", lambda a, r: a[:3] + 0.01), which=-1),
    Mutation("ci_r_nan", "/cam/camera_info", _cam_info("r", _idx(0, NAN)), which=-1),
    Mutation("ci_r_not_rotation", "/cam/camera_info", _cam_info("r", lambda a, r: a * 2), which=-1),
    Mutation("ci_width_other", "/cam/camera_info", _cam_info("width", 640), which=-1),
    Mutation("ci_width_only", "/cam/camera_info", _cam_info("height", 0), which=-1),
    Mutation("ci_model_unknown", "/cam/camera_info", _cam_info("distortion_model", "kannala"), which=-1),
    # 2D detections
    Mutation("d2_negative_size", "/cam/detections", _det2d("size_x", -20.0)),
    Mutation("d2_nan_size", "/cam/detections", _det2d("size_y", NAN)),
    Mutation("d2_inf_center", "/cam/detections", _det2d("x", INF)),
    Mutation("d2_nan_center", "/cam/detections", _det2d("y", NAN)),
    Mutation("d2_huge_center", "/cam/detections", _det2d("x", 1e30)),
    # 3D detections
    Mutation("d3_size_zero", "/lidar/detections", _det3d("size", "x", 0.0)),
    Mutation("d3_size_negative", "/lidar/detections", _det3d("size", "y", -1.5)),
    Mutation("d3_size_nan", "/lidar/detections", _det3d("size", "z", NAN)),
    Mutation("d3_center_nan", "/lidar/detections", _det3d("position", "x", NAN)),
    Mutation("d3_center_far", "/lidar/detections", _det3d("position", "y", 1e12)),
    Mutation("d3_center_inf", "/lidar/detections", _det3d("position", "z", -INF)),
    Mutation("d3_quat_nan", "/lidar/detections", _det3d("orientation", "w", NAN)),
    Mutation("d3_quat_zero", "/lidar/detections", _det3d("orientation", None, {"x": 0.0, "y": 0.0, "z": 0.0, "w": 0.0})),
    Mutation("d3_quat_norm2", "/lidar/detections", _det3d("orientation", None, {"x": 0.0, "y": 0.0, "z": 0.0, "w": 2.0})),
    Mutation("d3_quat_tilted", "/lidar/detections", _det3d("orientation", None, {"x": 0.5, "y": 0.0, "z": 0.0,
                                                                                  "w": math.sqrt(0.75)})),
    # xcalib's frame records
    Mutation("rec_extr_scaled", "/xcalib/frames", _record(_rec_cam("extrinsics", _scale_extr(2.0)))),
    Mutation("rec_extr_nan", "/xcalib/frames", _record(_rec_cam("extrinsics", lambda T: [[NAN] * 4] * 4))),
    Mutation("rec_extr_shape", "/xcalib/frames", _record(_rec_cam("extrinsics", lambda T: T[:3]))),
    Mutation("rec_extr_string", "/xcalib/frames", _record(_rec_cam("extrinsics", "eye"))),
    Mutation("rec_time_nan", "/xcalib/frames", _record(lambda rec, r: rec.update(lidar_time_s=NAN))),
    Mutation("rec_time_string", "/xcalib/frames", _record(lambda rec, r: rec.update(lidar_time_s="NaN"))),
    Mutation("rec_cam_time_inf", "/xcalib/frames", _record(_rec_cam("camera_time_s", INF))),
    Mutation("rec_match_shape", "/xcalib/frames", _record(_rec_cam("match_matrix", [[1, 0, 0]]))),
    Mutation("rec_match_values", "/xcalib/frames", _record(_rec_cam("match_matrix", [[7, 0], [0, 1]]))),
    Mutation("rec_tracks_strings", "/xcalib/frames", _record(lambda rec, r: rec.update(track_ids_3d=["a", "b"]))),
    Mutation("rec_velocities_nan", "/xcalib/frames", _record(lambda rec, r: rec.update(velocities_3d=[[NAN] * 3] * 2))),
    Mutation("rec_rows_bad", "/xcalib/frames", _record(lambda rec, r: rec.update(box3d_rows=["up", "down"]))),
    Mutation("rec_stamp_float", "/xcalib/frames", _record(lambda rec, r: rec.update(lidar_stamp_ns=1.5))),
    Mutation("rec_not_json", "/xcalib/frames", _record("{not json")),
    Mutation("rec_nested", "/xcalib/frames", _record(_nested(100_000))),
    Mutation("rec_frame_key_list", "/xcalib/frames", _record(lambda rec, r: rec.update(frame_key=[1, 2]))),
    # tf
    Mutation("tf_quat_zero", "/tf_static", _tf("rotation", {"x": 0.0, "y": 0.0, "z": 0.0, "w": 0.0})),
    Mutation("tf_quat_nan", "/tf_static", _tf("rotation", {"w": NAN})),
    Mutation("tf_trans_inf", "/tf_static", _tf("translation", {"x": INF})),
    # images
    Mutation("img_encoding", "/cam/image", _image(encoding="yuv422_weird")),
    Mutation("img_step_small", "/cam/image", _image(step=lambda m: m.step - 3)),
    Mutation("img_height_big", "/cam/image", _image(height=lambda m: m.height + 1)),
    Mutation("img_width_huge", "/cam/image", _image(width=2**31 - 1)),
    Mutation("img_data_short", "/cam/image", _image(data=lambda m: np.asarray(m.data)[:-10])),
    # headers, topics, stamps (handled by name in ``_message_case``)
    Mutation("hdr_nanosec", "/lidar/points", lambda m, r, s: setattr(m.header.stamp, "nanosec", 2_000_000_000)),
    Mutation("dup_lidar_stamp", "/lidar/points", None, expect="dup_reported"),
    Mutation("dup_all_stamps", "/lidar/points", None),  # nothing left to pair: refused
    Mutation("two_cameras_one_name", "/cam/image", None, expect="both_cameras"),
    Mutation("topic_newline", "/cam/image", None),
    Mutation("topic_rtl", "/cam/image", None),
    Mutation("topic_quote", "/lidar/points", None),
]}
MESSAGE_KINDS = tuple(MUTATIONS)


def _message_case(src: Path, dst: Path, mut: Mutation, rng) -> Path:
    store = _store(src.suffix.lower())
    stamps: dict[str, Any] = {}

    def edit(topic, msgtype, k, msg):
        name = mut.name
        if name == "two_cameras_one_name":  # /cam/... -> /a/cam/... plus a copy as /b/cam/...
            if topic.startswith("/cam/"):
                return [("/a" + topic, msg), ("/b" + topic, msg)]
            return [(topic, msg)]
        if name in ("topic_newline", "topic_rtl", "topic_quote"):
            bad = {"topic_newline": "/cam\ntouch PWNED\n#", "topic_rtl": "/cam\u202egpj", "topic_quote": "/li'$(id)'dar"}
            seg = "/cam" if name != "topic_quote" else "/lidar"
            if topic.startswith(seg + "/"):
                return [(bad[name] + topic[len(seg):], msg)]
            return [(topic, msg)]
        if name.startswith("dup_") and topic in ("/lidar/points", "/lidar/detections", "/xcalib/frames"):
            # sweep 1 (its detections and record too) carries sweep 0's stamp
            if topic == "/xcalib/frames":
                rec = json.loads(msg.data)
                if k == 0:
                    stamps["rec"] = rec["lidar_stamp_ns"]
                elif k == 1 or name == "dup_all_stamps":
                    return []  # the writer's record of the sweep is dropped with it
                return [(topic, msg)]
            if k == 0:
                stamps[topic] = (msg.header.stamp.sec, msg.header.stamp.nanosec)
            elif k == 1 or name == "dup_all_stamps":
                msg.header.stamp.sec, msg.header.stamp.nanosec = stamps[topic]
            return [(topic, msg)]
        if topic == mut.topic and (mut.which == -1 or k == mut.which):
            mut.fn(msg, rng, store)
        return [(topic, msg)]

    return rewrite_bag(src, dst, edit)


# ---------------------------------------------------------------------------------- reading
class _Capture(logging.Handler):
    def __init__(self):
        super().__init__(logging.WARNING)
        self.records: list[str] = []

    def emit(self, record):
        self.records.append(record.getMessage())


def read_bag(path: Path) -> dict:
    """Every camera of the bag read as frames: ``{"cameras": {camera: (BagFrames, frames)},
    "warnings": [logged warnings]}``."""
    from xcalib.io.bags import BagFrames

    cap = _Capture()
    lg = logging.getLogger("xcalib")
    lg.addHandler(cap)
    old = lg.level
    lg.setLevel(logging.WARNING)
    try:
        out = {}
        try:
            seqs = [BagFrames(path, tolerance_s=0.05)]
        except FormatError as exc:
            if "several cameras" not in exc.problem:
                raise
            topics = [part.split(" (", 1)[1].rstrip(")") for part in exc.problem.split(": ", 1)[1].split(", ")]
            seqs = [BagFrames(path, t, tolerance_s=0.05) for t in topics]
        for seq in seqs:
            out[seq.camera] = (seq, [seq[i] for i in range(len(seq))])
        return {"cameras": out, "warnings": cap.records}
    finally:
        lg.removeHandler(cap)
        lg.setLevel(old)


def frame_problem(fr, intr_check: bool = True) -> str | None:
    """Why a frame read without an error is invalid, or None."""
    from xcalib.geometry.rotations import orthonormality_error

    def finite(a):
        return bool(np.all(np.isfinite(np.asarray(a, dtype=np.float64))))

    pts = np.asarray(fr.point_cloud)
    if pts.ndim != 2 or not finite(pts[:, :3]):
        return "non-finite points"
    if pts.size and np.abs(pts[:, :3]).max() > 1e5:
        return f"points up to {np.abs(pts[:, :3]).max():.3g} m"
    b2 = np.asarray(fr.bboxes_2d, dtype=np.float64)
    if not finite(b2) or (len(b2) and np.any(b2[:, 2:] < b2[:, :2])):
        return "invalid 2D boxes"
    b3 = np.asarray(fr.bboxes_3d, dtype=np.float64)
    if not finite(b3) or (len(b3) and np.abs(b3).max() > 1e4):
        return "invalid 3D boxes"
    if len(b3) and b3.shape[1] == 7 and np.any(b3[:, 3:6] <= 0):
        return "3D box size <= 0"
    if len(b3) and b3.shape[1] == 6 and np.any(b3[:, 3:6] <= b3[:, :3]):
        return "inverted/flat 3D box"
    for t in (fr.lidar_time_s, fr.camera_time_s):
        if t is not None and not math.isfinite(t):
            return "non-finite time"
    T = fr.extrinsics
    if T is not None and (not finite(T) or orthonormality_error(np.asarray(T)[:3, :3]) > 1e-3
                          or np.abs(np.asarray(T)[3] - [0, 0, 0, 1]).max() > 1e-9):
        return "non-rigid extrinsics"
    if fr.match_matrix is not None and np.asarray(fr.match_matrix).shape != (len(b2), len(b3)):
        return "match matrix shape"
    if fr.velocities_3d is not None and not finite(fr.velocities_3d):
        return "non-finite velocities"
    intr = fr.intrinsics
    if intr_check and intr is not None:
        why = implausible(intr, fr.image.shape[1], fr.image.shape[0])
        if why:
            return f"implausible intrinsics: {why}"
    if fr.image.dtype != np.uint8 or fr.image.ndim != 3:
        return "image"
    return None


def implausible(intr, w=None, h=None) -> str | None:
    """The campaign's own judgement of intrinsics (independent of the code under test): focal
    lengths >= 1 px, within 1/50..100x the image's larger side, fx/fy within 1/4..4, distortion
    coefficients within 1e3 and a radial factor within 0.1..10 across the image."""
    w, h = w or intr.width, h or intr.height
    fx, fy = intr.fx, intr.fy
    if not (math.isfinite(fx) and math.isfinite(fy) and fx >= 1 and fy >= 1 and 0.25 <= fx / fy <= 4):
        return f"fx={fx:g} fy={fy:g}"
    if w and h and not all(max(w, h) / 50 <= v <= 100 * max(w, h) for v in (fx, fy)):
        return f"fx={fx:g} fy={fy:g} for {w}x{h}"
    if intr.distortion is None:
        return None
    d = np.asarray(intr.distortion, dtype=np.float64)
    if not np.all(np.isfinite(d)) or np.abs(d).max() > 1e3:
        return f"distortion {d.tolist()}"
    if w and h:
        k = np.zeros(8)
        k[:min(d.size, 8)] = d[:8]
        r2 = np.linspace(0, max(max(intr.cx, w - intr.cx) / fx, max(intr.cy, h - intr.cy) / fy), 33) ** 2
        with np.errstate(all="ignore"):
            f = (1 + k[0] * r2 + k[1] * r2 ** 2 + k[4] * r2 ** 3) / (1 + k[5] * r2 + k[6] * r2 ** 2 + k[7] * r2 ** 3)
        if not np.all(np.isfinite(f)) or f.min() < 0.1 or f.max() > 10:
            return f"distortion {d.tolist()} scales radii {np.nanmin(f):.3g}..{np.nanmax(f):.3g}"
    return None


def classify_bag(path: Path, mut: Mutation | None) -> tuple[str, str]:
    """(outcome, detail) of reading the (mutated) bag ``path``."""
    expect = "any" if mut is None else mut.expect
    try:
        got = read_bag(path)
    except FormatError as exc:
        named = exc.path is not None and Path(exc.path).name == path.name
        if not named:
            return "unclear", f"FormatError not naming the bag: {str(exc)[:160]}"
        if expect in ("both_cameras", "dup_reported"):
            return "refused_valid", f"FormatError: {str(exc)[:160]}"
        return "clear", f"FormatError: {str(exc)[:160]}"
    except FileNotFoundError as exc:
        return ("clear" if "/" in str(exc) else "unclear"), f"FileNotFoundError: {str(exc)[:160]}"
    except RecursionError as exc:
        return "unclear", f"RecursionError: {str(exc)[:120]}"
    except MemoryError:
        return "memory", "MemoryError"
    except Exception as exc:  # noqa: BLE001 - that is what we count
        return "unclear", f"{type(exc).__name__}: {str(exc)[:160]}"
    frames = [f for _, fs in got["cameras"].values() for f in fs]
    for fr in frames:
        why = frame_problem(fr)
        if why:
            return "garbage", why
    warned = any(("dropped" in w or "empty" in w) for w in got["warnings"])
    if expect == "refuse":
        return "garbage", f"read {len(frames)} frame(s) without an error"
    if expect == "warn":
        counted = any(f.meta.get("points_dropped_nonfinite") for f in frames) or any(
            len(f.point_cloud) == 0 for f in frames)
        return ("ok", "") if warned and counted else ("garbage", "points dropped / empty cloud without a warning")
    if expect == "both_cameras":
        return ("ok", "") if len(got["cameras"]) == 2 else ("garbage", f"cameras {sorted(got['cameras'])}")
    if expect == "dup_reported":
        reps = [seq.report for seq, _ in got["cameras"].values()]
        reported = any("share this stamp" in d.reason for r in reps for d in r.dropped)
        return ("ok", "") if reported else ("garbage", "sweeps sharing a stamp paired silently")
    return "ok", ""


# ------------------------------------------------------------------- CameraInfo / intrinsics files
_TEXT_KINDS = ("number", "quote", "drop", "bool", "token", "nest", "truncate", "flip", "dup_line")
_EDITS = (b"NaN", b"Infinity", b"-1", b"1e308", b"1e-9", b"0", b"null", b'"x"', b"[]", b"{}", b"true",
          b"1000000.0", b"-500.0", b"3.7")


def mutate_text(data: bytes, kind: str, a: int, b: int) -> bytes:
    import re

    nums = list(re.finditer(rb"-?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?", data))
    n = max(len(data), 1)
    if kind in ("number", "quote", "drop", "bool") and nums:
        m = nums[a % len(nums)]
        if kind == "number":
            rep = _EDITS[b % len(_EDITS)]
        elif kind == "quote":
            rep = b'"' + m.group() + b'"'
        elif kind == "bool":
            rep = (b"true", b"false", b"null", b"yes", b"on")[b % 5]
        else:  # drop the number and a comma beside it
            end = m.end() + (1 if data[m.end():m.end() + 1] == b"," else 0)
            return data[:m.start()] + data[end:]
        return data[:m.start()] + rep + data[m.end():]
    if kind == "token":
        s = a % n
        return data[:s] + _EDITS[b % len(_EDITS)] + data[s:]
    if kind == "nest":
        s = a % n
        return data[:s] + b"[" * (100 + 1000 * (b % 60)) + data[s:]
    if kind == "truncate":
        return data[:a % n]
    if kind == "dup_line":
        lines = data.split(b"\n")
        i = a % len(lines)
        return b"\n".join(lines[:i + 1] + [lines[i]] * (1 + b % 3) + lines[i + 1:])
    out = bytearray(data)  # flip
    for k in range(1 + b % 4):
        out[(a + 7919 * k) % n] ^= 1 << ((b + k) % 8)
    return bytes(out)


def _intrinsics_sample():
    from xcalib.geometry import CameraIntrinsics

    return CameraIntrinsics(1000.0, 1002.0, 640.0, 360.0, [-0.1, 0.01, 0.001, -0.002, 0.001], 1280, 720)


def make_intrinsics_json(d: Path) -> Path:
    p = Path(d) / "K.json"
    p.write_text(json.dumps(_intrinsics_sample().to_dict(), indent=1))
    return p


def make_camera_info_yaml(d: Path) -> Path:
    from xcalib.formats.ros import camera_info_dict

    import yaml

    p = Path(d) / "camera_info.yaml"
    p.write_text(yaml.safe_dump(camera_info_dict(_intrinsics_sample(), "cam"), sort_keys=False))
    return p


def read_intrinsics_json(p: Path):
    from xcalib.geometry import CameraIntrinsics

    return CameraIntrinsics.from_json(p)


def read_camera_info_yaml(p: Path):
    from xcalib.formats.ros import read_camera_info

    return read_camera_info(p)


def intrinsics_ok(intr, original_bytes: bytes, mutated: bytes) -> str | None:
    """A read intrinsics is garbage when implausible, or when the file changed in a number the
    intrinsics hold but the result equals what a silent coercion gives (``true`` -> 1.0,
    ``"500"`` -> 500)."""
    why = implausible(intr)
    if why:
        return f"implausible: {why}"
    vals = [intr.fx, intr.fy, intr.cx, intr.cy, *([] if intr.distortion is None else list(intr.distortion))]
    if not all(math.isfinite(v) for v in vals):
        return "non-finite"
    ref = _intrinsics_sample()
    d_got, d_ref = np.zeros(14), np.zeros(14)
    d_got[:intr.dist_coeffs.size] = intr.dist_coeffs
    d_ref[:ref.dist_coeffs.size] = ref.dist_coeffs
    changed = not (np.allclose(intr.K, ref.K) and np.allclose(d_got, d_ref)
                   and intr.width == ref.width and intr.height == ref.height)
    if changed and any(tok in mutated for tok in (b"true", b"false", b"yes", b"on", b'"')) and \
            mutated.count(b'"') != original_bytes.count(b'"'):
        return "a non-number read as a number"
    if changed and any(tok in mutated for tok in (b"true", b"yes", b": on")) and b"true" not in original_bytes:
        return "a boolean read as a number"
    return None


# ------------------------------------------------------------------------- mmdet3d info pickles
def make_mmdet3d_info(d: Path) -> Path:
    """A small nuScenes-style v1.x info (2 samples, 2 cameras, 3 boxes; files are not needed to
    read the infos)."""
    info = {"metainfo": {"dataset": "nuscenes", "categories": {"car": 0, "pedestrian": 1}}, "data_list": []}
    K = [[1000.0, 0.0, 800.0], [0.0, 1000.0, 450.0], [0.0, 0.0, 1.0]]
    L = [[0.0, -1.0, 0.0, 0.0], [0.0, 0.0, -1.0, 0.3], [1.0, 0.0, 0.0, -0.4], [0.0, 0.0, 0.0, 1.0]]
    for s in range(2):
        boxes = [[10.0 + s, 1.0, 0.0, 4.0, 1.8, 1.5, 0.1], [15.0, -2.0, 0.2, 0.8, 0.6, 1.7, 1.0],
                 [25.0, 3.0, 0.1, 4.5, 2.0, 1.6, -0.3]]
        insts = [{"bbox_3d": b, "bbox_label_3d": i % 2, "velocity": [0.5, 0.0]} for i, b in enumerate(boxes)]
        cams, cam_insts = {}, {}
        for c, name in enumerate(("CAM_FRONT", "CAM_BACK")):
            cams[name] = {"img_path": f"{name}_{s}.jpg", "cam2img": K, "lidar2cam": L, "timestamp": 1.5e9 + s * 0.5,
                          "width": 1600, "height": 900}
            cam_insts[name] = [{"bbox": [700.0, 400.0, 760.0, 450.0], "bbox_label": 0,
                                "bbox_3d": [1.0, 0.5, 10.0, 4.0, 1.5, 1.8, 0.1]}] if c == 0 else []
        info["data_list"].append({"token": f"tok{s}", "timestamp": 1.5e9 + s * 0.5, "instances": insts,
                                  "images": cams, "cam_instances": cam_insts,
                                  "lidar_points": {"lidar_path": f"lidar_{s}.bin", "num_pts_feats": 5}})
    p = Path(d) / "infos.pkl"
    p.write_bytes(pickle.dumps(info, protocol=4))
    return p


_JUNK = (None, "x", [], {}, float("nan"), float("inf"), 1e300, -1, True, 0, [[1, 2], [3]], {"a": 1}, "1.5",
         [1.0] * 3, -1e9)


def mutate_info(obj, rng: random.Random):
    """Replace a random leaf / container of the info by junk, or delete a random key."""
    path, node = [], obj
    while True:
        if isinstance(node, dict) and node:
            key = rng.choice(list(node))
        elif isinstance(node, list) and node:
            key = rng.randrange(len(node))
        else:
            break
        path.append((node, key))
        node = node[key]
        if rng.random() < 0.25:
            break
    if not path:
        return obj
    parent, key = path[-1]
    if isinstance(parent, dict) and rng.random() < 0.2:
        del parent[key]
    else:
        parent[key] = rng.choice(_JUNK)
    return obj


def read_mmdet3d(p: Path):
    from xcalib.formats.mmdet3d import read_mmdet3d_infos

    return read_mmdet3d_infos(p)


def mmdet3d_problem(samples) -> str | None:
    from xcalib.geometry.rotations import orthonormality_error

    for s in samples:
        b = np.asarray(s.boxes7, dtype=np.float64)
        if not np.all(np.isfinite(b)) or (len(b) and np.any(b[:, 3:6] <= 0)):
            return "invalid 3D boxes"
        for cam in s.cameras.values():
            why = implausible(cam.intrinsics)
            if why:
                return f"implausible intrinsics {why}"
            T = cam.T_cam_lidar
            if not np.all(np.isfinite(T)) or orthonormality_error(T[:3, :3]) > 1e-3:
                return "non-rigid extrinsics"
            b2 = np.asarray(cam.boxes_2d, dtype=np.float64)
            if not np.all(np.isfinite(b2)) or (len(b2) and np.any(b2[:, 2:] < b2[:, :2])):
                return "invalid 2D boxes"
        for key in ("lidar_time_s",):
            v = s.meta.get(key)
            if v is not None and not math.isfinite(v):
                return "non-finite time"
    return None


# ------------------------------------------------------------------------------- the case runner
READERS = ("bag", "db3", "mcap", "intrinsics_json", "camera_info_yaml", "mmdet3d_pkl")


class Samples:
    """Valid samples made once in ``root``; cases are written to fresh files beside them."""

    def __init__(self, root):
        self.root = Path(root)
        self.root.mkdir(parents=True, exist_ok=True)
        self._made: dict[str, Path] = {}
        self._n = 0

    def base(self, reader: str) -> Path:
        if reader not in self._made:
            d = self.root / f"sample_{reader}"
            d.mkdir(exist_ok=True)
            if reader in ("bag", "db3", "mcap"):
                self._made[reader] = make_bag(d, "." + reader)
            elif reader == "intrinsics_json":
                self._made[reader] = make_intrinsics_json(d)
            elif reader == "camera_info_yaml":
                self._made[reader] = make_camera_info_yaml(d)
            else:
                self._made[reader] = make_mmdet3d_info(d)
        return self._made[reader]

    def case_path(self, reader: str) -> Path:
        self._n += 1
        d = self.root / f"case_{self._n}"
        d.mkdir()
        return d / self.base(reader).name


def kinds_for(reader: str) -> tuple[str, ...]:
    if reader in ("bag", "db3", "mcap"):  # a third byte-level, two thirds message-level
        return BYTE_KINDS * (len(MESSAGE_KINDS) // 8) + MESSAGE_KINDS
    if reader == "mmdet3d_pkl":
        return ("structure",) * 3 + BYTE_KINDS
    return _TEXT_KINDS


def _byte_mutation(data: bytes, kind: str, a: int, b: int) -> bytes:
    n = max(len(data), 1)
    if kind == "flip":
        out = bytearray(data)
        for k in range(1 + b % 4):
            out[(a + 7919 * k) % n] ^= 1 << ((b + k) % 8)
        return bytes(out)
    if kind == "truncate":
        return data[:a % n]
    if kind == "append":
        return data + bytes((a + i * b) % 256 for i in range(1 + b % 64))
    s = a % n  # zero_block
    return data[:s] + b"\x00" * (1 + b % 256) + data[s + 1 + b % 256:]


def run_case(samples: Samples, reader: str, kind: str, a: int, b: int) -> tuple[str, str]:
    """Build one mutated input and classify what the reader made of it."""
    base = samples.base(reader)
    path = samples.case_path(reader)
    try:
        if reader in ("bag", "db3", "mcap"):
            if kind in BYTE_KINDS:
                path.write_bytes(_byte_mutation(base.read_bytes(), kind, a, b))
                return classify_bag(path, None)
            mut = MUTATIONS[kind]
            _message_case(base, path, mut, np.random.default_rng(a))
            return classify_bag(path, mut)
        if reader == "mmdet3d_pkl":
            if kind == "structure":
                obj = pickle.loads(base.read_bytes())
                rng = random.Random(a)
                for _ in range(1 + b % 3):
                    mutate_info(obj, rng)
                path.write_bytes(pickle.dumps(obj, protocol=4))
            else:
                path.write_bytes(_byte_mutation(base.read_bytes(), kind, a, b))
            return _classify_file(path, read_mmdet3d, mmdet3d_problem)
        original = base.read_bytes()
        data = mutate_text(original, kind, a, b)
        path.write_bytes(data)
        read = read_intrinsics_json if reader == "intrinsics_json" else read_camera_info_yaml
        return _classify_file(path, read, lambda intr: intrinsics_ok(intr, original, data))
    finally:
        shutil.rmtree(path.parent, ignore_errors=True)


def _classify_file(path: Path, read, problem) -> tuple[str, str]:
    try:
        data = read(path)
    except FormatError as exc:
        named = exc.path is not None and Path(exc.path).name == path.name
        return ("clear" if named else "unclear"), f"FormatError: {str(exc)[:160]}"
    except FileNotFoundError as exc:
        return ("clear" if "/" in str(exc) else "unclear"), f"FileNotFoundError: {str(exc)[:160]}"
    except MemoryError:
        return "memory", "MemoryError"
    except Exception as exc:  # noqa: BLE001
        return "unclear", f"{type(exc).__name__}: {str(exc)[:160]}"
    why = problem(data)
    return ("garbage", why) if why else ("ok", "")


def plan(reader: str, n: int, seed: str) -> list[tuple[str, str, int, int]]:
    """``n`` seeded cases for ``reader``: every kind in turn, seeds from ``random.Random(seed)``."""
    rnd = random.Random(f"{seed}-{reader}")
    kinds = kinds_for(reader)
    return [(reader, kinds[i % len(kinds)], rnd.randrange(1 << 30), rnd.randrange(1 << 30)) for i in range(n)]


# ----------------------------------------------------------------------------------- worker pool
WORKER = r'''
import logging, os, sys, warnings
sys.path.insert(0, sys.argv[2])
warnings.simplefilter("ignore")
out = os.fdopen(os.dup(1), "w")
os.dup2(os.open(os.devnull, os.O_WRONLY), 1)
os.dup2(os.open(os.devnull, os.O_WRONLY), 2)
from _bag_cases import Samples, run_case


def hwm_kb():
    for line in open("/proc/self/status"):
        if line.startswith("VmHWM:"):
            return int(line.split()[1])
    return 0


samples = Samples(sys.argv[1])
for line in sys.stdin:
    reader, kind, a, b = line.split()
    outcome, detail = run_case(samples, reader, kind, int(a), int(b))
    out.write(outcome + "\t" + str(hwm_kb()) + "\t" + detail.replace("\n", " ").replace("\t", " ") + "\n")
    out.flush()
'''


class Pool:
    """One worker process fed over stdin. A case without an answer within ``timeout`` s is a
    ``hang`` (the worker is killed and restarted); a worker whose peak RSS passes ``max_rss_mb``
    after a case makes that case a ``memory`` blow-up (and is restarted, resetting the peak)."""

    def __init__(self, root, tests_dir, env, timeout: float = 30.0, max_rss_mb: float = 1500.0):
        self.root, self.tests_dir, self.env = str(root), str(tests_dir), env
        self.timeout, self.max_rss_kb = timeout, max_rss_mb * 1024
        self._start()

    def _start(self) -> None:
        import subprocess
        import sys

        self.proc = subprocess.Popen([sys.executable, "-c", WORKER, self.root, self.tests_dir], stdin=subprocess.PIPE,
                                     stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, env=self.env,
                                     bufsize=1)

    def _restart(self) -> None:
        self.proc.kill()
        self.proc.wait()
        self._start()

    def run(self, case) -> tuple[str, str, float]:
        """(outcome, detail, peak RSS MB of the worker so far)."""
        import select

        try:
            self.proc.stdin.write(" ".join(map(str, case)) + "\n")
            self.proc.stdin.flush()
            ready, _, _ = select.select([self.proc.stdout], [], [], self.timeout)
            line = self.proc.stdout.readline() if ready else ""
        except (BrokenPipeError, OSError):
            line = ""
        if not line:
            self._restart()
            return "hang", f"no answer within {self.timeout:.0f} s (hang or crash)", 0.0
        outcome, hwm, detail = line.rstrip("\n").split("\t", 2)
        if int(hwm) > self.max_rss_kb:
            self._restart()
            return "memory", f"peak RSS {int(hwm) / 1024:.0f} MB ({outcome}: {detail[:100]})", int(hwm) / 1024
        return outcome, detail, int(hwm) / 1024

    def close(self) -> None:
        self.proc.stdin.close()
        self.proc.wait(timeout=30)
