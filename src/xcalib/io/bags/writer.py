"""Writing frames to a ROS 1 ``.bag``, ROS 2 ``.db3`` or ``.mcap`` (rosbags), atomically.

Topics (``<cam>`` = camera name with characters other than ``[A-Za-z0-9_]`` as ``_``):
``/lidar/points`` (PointCloud2, float32 fields named by ``Frame.point_fields``),
``/lidar/detections`` (vision_msgs Detection3DArray), ``/<cam>/image`` (Image rgb8) or
``/<cam>/image/compressed`` (png/jpeg), ``/<cam>/camera_info``, ``/<cam>/detections``
(Detection2DArray), ``/tf_static`` (ground-truth LiDAR -> ``<cam>_optical_frame`` when frames
carry ``extrinsics``) and ``/xcalib/frames`` (std_msgs/String JSON per frame: frame key, per-camera
match matrix and ground truth, the 3D box layout), so frames read back equal the frames written.
Frame ``i`` is stamped ``lidar_time_s`` / ``camera_time_s`` when the frame has them (a relative
clock, below 1e8 s, shifted by ``start_s``; the exact times travel in the record), else
``start_s + i * period_s`` (LiDAR) and camera ``c`` (0, 1, ...) ``camera_delay_s`` + ``c`` ms
later (a frame read from a bag keeps its exact header stamps, ``meta["lidar_stamp_ns"]`` /
``meta["camera_stamp_ns"]``); track ids go into ``Detection3D.id`` (ROS 2 layout) and the record.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import tempfile
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np

from ...geometry.boxes import detect_box3d_convention
from ...geometry.transforms import invert_transform
from ..files import sweep_stale, tmp_prefix
from ...options import Options, document, resolve
from ...types import Frame
from . import _convert as cv
from ._msgs import CAMERA_INFO, COMPRESSED, DET2D, DET3D, IMAGE, POINTCLOUD2, STRING, TF, typestore
from .reader import BAG_SUFFIXES, META_TOPIC, OWN_DETECTIONS

__all__ = ["write_bag", "BagWriteOptions", "topic_name"]


def topic_name(camera: str) -> str:
    """A camera name as a ROS topic segment."""
    seg = re.sub(r"[^A-Za-z0-9_]", "_", camera or "camera")
    return seg if seg[0].isalpha() else "cam_" + seg


def _cameras(frame: Frame) -> list[str]:
    if frame.images:
        return list(frame.images)
    return [frame.camera_name or "camera"]


def _view(frame: Frame, cam: str):
    """(image, 2D boxes, match rows, intrinsics, extrinsics) of one camera of a frame."""
    from ..sources import camera_view

    if not frame.images:
        return frame.image, frame.bboxes_2d, frame.match_matrix, frame.intrinsics, frame.extrinsics
    v = camera_view(frame, cam)
    return v.image, v.bboxes_2d, v.match_matrix, v.intrinsics, v.extrinsics


def _box7_and_rows(b3) -> tuple[np.ndarray, list[str] | None]:
    b = np.asarray(b3, dtype=np.float64)
    if b.size == 0:  # no box ([0, 7] or [0, 6]: reshape(0, -1) cannot infer the width)
        return np.zeros((0, 7)), None
    b = b.reshape(len(b), -1)
    if b.shape[1] == 7:
        return (b if b.shape[1] == 7 else np.zeros((0, 7))), None
    rows = detect_box3d_convention(b.astype(np.float32)).tolist()
    cs = np.empty((len(b), 6))
    for k, kind in enumerate(rows):
        cs[k] = np.concatenate([(b[k, :3] + b[k, 3:]) / 2, b[k, 3:] - b[k, :3]]) if kind == "extents" else b[k]
    return np.hstack([cs, np.zeros((len(b), 1))]), rows


ABSOLUTE_CLOCK_S = 1e8  # frame times from this on (1973+) are a Unix clock and stamped as they are


def _exact(frame: Frame, key: str, t: float | None) -> int | None:
    """A frame read from a bag keeps its header stamp (ns) in ``meta[key]``: used when it is the
    frame's time (float seconds of a Unix clock lose ~200 ns)."""
    ns = frame.meta.get(key) if isinstance(frame.meta, dict) else None
    if isinstance(ns, int) and not isinstance(ns, bool) and ns > 0 and t is not None and abs(ns / 1e9 - t) < 1e-6:
        return ns
    return None


def _stamp(t: float, start_s: float) -> int:
    """Header stamp (ns) of a frame time: an absolute clock as is, a relative one (simulation
    seconds, may be negative) shifted by ``start_s``."""
    if t >= ABSOLUTE_CLOCK_S:
        return int(round(t * 1e9))
    return int(round(start_s * 1e9)) + int(round(t * 1e9))  # in ns: 1.7e9 s + t in float64 loses ~200 ns


class _Sink:
    """One container behind one ``add(topic, type, stamp, msg)``."""

    def __init__(self, tmp: Path, container: str, store):
        self.container, self.store, self.cons = container, store, {}
        if container == ".bag":
            from rosbags.rosbag1 import Writer

            self.path = tmp / "out.bag"
            self.w = Writer(self.path)
        else:
            from rosbags.rosbag2 import StoragePlugin, Writer

            self.dir = tmp / "out"
            plugin = StoragePlugin.MCAP if container == ".mcap" else StoragePlugin.SQLITE3
            self.w = Writer(self.dir, version=9, storage_plugin=plugin)
            self.path = self.dir / ("out" + container)
        self.w.open()

    def add(self, topic: str, msgtype: str, stamp: int, msg) -> None:
        if topic not in self.cons:
            self.cons[topic] = self.w.add_connection(topic, msgtype, typestore=self.store)
        raw = (self.store.serialize_ros1(msg, msgtype) if self.container == ".bag"
               else self.store.serialize_cdr(msg, msgtype))
        self.w.write(self.cons[topic], stamp, raw)

    def close(self) -> Path:
        self.w.close()
        return self.path


@dataclass(frozen=True)
class BagWriteOptions(Options):
    """How :func:`write_bag` writes (the defaults in one place): image_format ("raw" | "png" |
    "jpeg"), vision_layout (vision_msgs layout "ros1" | "ros2"; None: the container's), start_s
    (stamp of the first frame without its own time, s), period_s (between such frames, s),
    camera_delay_s (image stamp after the cloud's, s), lidar_frame (the clouds' frame_id),
    overwrite (replace an existing file), detections (False: sensor topics only)."""

    image_format: Literal["raw", "png", "jpeg"] = "raw"
    vision_layout: Literal["ros1", "ros2"] | None = None
    start_s: float = 1_700_000_000.0
    period_s: float = 0.1
    camera_delay_s: float = 0.01
    lidar_frame: str = "lidar"
    overwrite: bool = False
    detections: bool = True


@document(BagWriteOptions)
def write_bag(path, frames: Iterable[Frame], *, options: BagWriteOptions | None = None, **overrides: Any) -> Path:
    """Write ``frames`` (single- or multi-camera) to ``path`` (container from the suffix: ``.bag``,
    ``.db3``, ``.mcap``); written to a temporary name beside it and renamed into place.
    ``detections=False``: sensor topics only (images, CameraInfo, clouds, tf_static; no
    detections and no ``/xcalib/frames`` record), as a raw recording. The settings: a
    :class:`BagWriteOptions` (``options=``) and/or its fields as keyword arguments."""
    o = resolve(BagWriteOptions, options, overrides, where="write_bag")
    image_format, vision_layout, start_s, period_s, camera_delay_s = o.image_format, o.vision_layout, o.start_s, \
        o.period_s, o.camera_delay_s
    lidar_frame, overwrite, detections = o.lidar_frame, o.overwrite, o.detections
    path = Path(path)
    container = path.suffix.lower()
    if container not in BAG_SUFFIXES:
        raise ValueError(f"write_bag: {path.name}: expected a {', '.join(BAG_SUFFIXES)} file name")
    if path.suffix != container:  # bag readers (rosbags, ROS tools) recognise lower-case suffixes only
        raise ValueError(f"write_bag: {path.name}: write it as {path.stem}{container} (ROS bag readers recognise "
                         f"the lower-case suffix only; {path.suffix} could not be read back)")
    if path.exists() and not overwrite:
        raise FileExistsError(f"{path} exists; pass overwrite=True (--force) to replace it")
    store = typestore(1 if container == ".bag" else 2, vision_layout)
    path.parent.mkdir(parents=True, exist_ok=True)
    sweep_stale(path.parent, path.name)  # temp folders of writers that were killed
    tmp = Path(tempfile.mkdtemp(prefix=tmp_prefix(path.name), suffix=".tmp", dir=path.parent))
    try:
        sink = _Sink(tmp, container, store)
        _write_frames(sink, store, frames, image_format, (start_s, period_s, camera_delay_s), lidar_frame,
                      detections)
        out = sink.close()
        os.chmod(out, 0o644)
        os.replace(out, path)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return path


def _write_frames(sink: _Sink, store, frames, image_format, clock, lidar_frame, detections=True) -> None:
    start_s, period_s, camera_delay_s = clock
    static: dict[str, np.ndarray] = {}
    t0 = int(round(start_s * 1e9))
    for i, frame in enumerate(frames):
        ls = t0 + int(round(i * period_s * 1e9)) if frame.lidar_time_s is None else \
            (_exact(frame, "lidar_stamp_ns", frame.lidar_time_s) or _stamp(frame.lidar_time_s, start_s))
        pts = np.asarray(frame.point_cloud, dtype=np.float32)
        fields = tuple(frame.point_fields) if len(frame.point_fields) == pts.shape[1] else \
            ("x", "y", "z") + tuple(f"f{k}" for k in range(3, pts.shape[1]))
        sink.add("/lidar/points", POINTCLOUD2, ls, cv.make_pointcloud2(store, pts, fields, ls, lidar_frame))
        box7, rows = _box7_and_rows(frame.bboxes_3d)
        tracks = None if frame.track_ids_3d is None else np.asarray(frame.track_ids_3d, dtype=np.int64).tolist()
        if detections:
            sink.add("/lidar/detections", DET3D, ls, cv.make_detection3d_array(store, box7, ls, lidar_frame, ids=tracks))
        record = {"lidar_stamp_ns": ls, "frame_key": frame.frame_key, "box3d_rows": rows, "cameras": {},
                  "lidar_time_s": frame.lidar_time_s, "track_ids_3d": tracks,
                  "velocities_3d": None if frame.velocities_3d is None else
                  np.asarray(frame.velocities_3d, dtype=np.float64).tolist()}
        made = getattr(frame, "detections", None)
        if made is not None and made.source == OWN_DETECTIONS:  # read back, a refusal can name xcalib's own boxes as the cause
            record["detections_source"] = OWN_DETECTIONS
        for c, cam in enumerate(_cameras(frame)):
            seg = topic_name(cam)
            cs = ls + int(round(camera_delay_s * 1e9)) + c * 1_000_000  # camera c: 1 ms after camera c-1
            cam_time = (frame.meta.get("camera_time_s_by_camera") or {}).get(cam) if frame.images \
                else frame.camera_time_s
            if cam_time is not None:
                cs = (None if frame.images else _exact(frame, "camera_stamp_ns", cam_time)) or _stamp(cam_time, start_s)
            image, b2, mm, intr, extr = _view(frame, cam)
            optical = f"{seg}_optical_frame"
            if image_format == "raw":
                sink.add(f"/{seg}/image", IMAGE, cs, cv.make_image(store, image, cs, optical))
            else:
                sink.add(f"/{seg}/image/compressed", COMPRESSED, cs,
                         cv.make_compressed(store, image, cs, optical, image_format))
            if intr is not None:
                sink.add(f"/{seg}/camera_info", CAMERA_INFO, cs,
                         cv.make_camera_info(store, intr, cs, optical, image.shape[1], image.shape[0]))
            if detections:
                sink.add(f"/{seg}/detections", DET2D, cs, cv.make_detection2d_array(store, b2, cs, optical))
            rec = {"camera_name": cam, "camera_time_s": cam_time}
            key = (frame.meta.get("frame_key_by_camera") or {}).get(cam) if frame.images else None
            if key is not None:  # each camera's own key (a merged frame's is the first camera's)
                rec["frame_key"] = str(key)
            if mm is not None:
                rec["match_matrix"] = np.asarray(mm).astype(int).tolist()
            if extr is not None:
                rec["extrinsics"] = np.asarray(extr, dtype=np.float64).tolist()
                static.setdefault(optical, invert_transform(np.asarray(extr, dtype=np.float64)))
            record["cameras"][seg] = rec
        Str = store.types[STRING]
        if detections:  # a sensors-only bag is a raw recording: no xcalib record either
            sink.add(META_TOPIC, STRING, ls, Str(data=json.dumps(record)))
        if i == 0 and static:
            sink.add("/tf_static", TF, ls, cv.make_tf_message(store, [(lidar_frame, k, v) for k, v in static.items()], ls))
