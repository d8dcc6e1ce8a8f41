"""Reading ROS 1 ``.bag``, ROS 2 ``.db3`` and ``.mcap`` files as frames, without ROS (rosbags).

:func:`bag_info` lists topics, types, counts and rates. :class:`BagFrames` picks one LiDAR and
one camera (image + CameraInfo + 2D detections; the LiDAR's 3D detections), indexes their
messages by header stamp, pairs each LiDAR sweep with the nearest image within
``tolerance_s`` and reports every message it dropped and why (:class:`PairingReport`).
Problems raise :class:`~xcalib.errors.FormatError` naming the bag and the topic.
"""

from __future__ import annotations

import functools
import json
import logging
import math
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ...errors import FormatError
from ...options import Options, document, resolve
from ..files import open_regular
from ..timing import MAX_SPEED_MPS, MAX_TIME_S
from .._validate import check_rigid
from ...geometry.camera import CameraIntrinsics
from ...geometry.transforms import invert_transform
from ...types import OWN_DETECTIONS, Frame, FrameDetections
from . import _convert as cv
from ._msgs import (CAMERA_INFO, COMPRESSED, DET2D, DET3D_TYPES, IMAGE, POINTCLOUD2, STRING, SUPPORTED_TYPES, TF_TYPES,
                    typestore)
from ._objects import MAX_TILT_DEG, boxes3d_any

__all__ = ["BagReadOptions", "BAG_SUFFIXES", "MAX_BAG_BYTES", "OWN_DETECTIONS", "MAX_MESSAGE_BYTES", "check_bag_input", "is_bag", "BagTopic", "BagInfo",
           "bag_info", "BagCamera", "bag_cameras", "Dropped", "PairingReport",
           "BagFrames", "pair_by_time", "META_TOPIC", "recorded_stamp_ns", "rectified_from"]

log = logging.getLogger(__name__)
BAG_SUFFIXES = (".bag", ".db3", ".mcap")
META_TOPIC = "/xcalib/frames"  # xcalib's own per-frame record (frame key, ground truth) in bags it writes
_SAFE_TOPIC = re.compile(r"^[A-Za-z0-9_/~{}.\-]+$")  # ROS name characters (plus . and -)
_IMAGE_SUFFIXES = {"image_raw", "image", "compressed", "image_color", "image_rect", "image_rect_color", "image_mono"}


def is_bag(path) -> bool:
    """A ``.bag`` / ``.db3`` / ``.mcap`` file, or a ROS 2 bag folder (``metadata.yaml``)."""
    p = Path(path)  # any non-folder with a bag suffix: a FIFO / device is refused by the reader, not skipped
    if p.is_dir():
        return (p / "metadata.yaml").exists() or (p / "metadata.yaml").is_symlink()
    return (p.exists() or p.is_symlink()) and p.suffix.lower() in BAG_SUFFIXES


#: Largest bag file read (streamed, never loaded whole): a sanity limit, not a memory one.
MAX_BAG_BYTES = 1 << 40
#: Largest single message decoded (a 2M-point sweep of 8 float32 fields is 64 MB).
MAX_MESSAGE_BYTES = 512 << 20


def check_bag_input(path: Path) -> None:
    """The special-file and size checks every reader applies, before the bag library opens
    anything: a bag file (or a ROS 2 bag folder's ``metadata.yaml`` and storage files) must be a
    regular file (FIFOs, devices, sockets - also behind symlinks - are refused at once, so
    ``mkfifo x.mcap`` cannot hang a read nor ``ln -s /dev/zero x.bag`` fill the memory)."""
    p = Path(path)
    if not p.exists() and not p.is_symlink():
        raise FileNotFoundError(f"bag not found: {p}")
    if p.is_dir():
        files = [p / "metadata.yaml"] + sorted(q for q in p.iterdir() if q.name != "metadata.yaml"
                                               and q.suffix.lower() in BAG_SUFFIXES)
        for f in files:
            open_regular(f, max_bytes=MAX_BAG_BYTES, what="bag file").close()
        return
    open_regular(p, max_bytes=MAX_BAG_BYTES, what="bag file").close()


@functools.lru_cache(maxsize=2)
def _default_store(ros: int):
    """The stock types + vision_msgs, built once per process (only read: AnyReader copies the
    definitions it needs into a store of its own)."""
    return typestore(ros)


def _reader(path: Path):
    """An opened rosbags AnyReader; the stock ROS 1/ROS 2 types + vision_msgs fill in what the bag
    does not define. Unreadable input -> FormatError naming the file."""
    from rosbags.highlevel import AnyReader

    check_bag_input(path)
    if path.suffix.lower() == ".mcap" and path.is_file():  # either ROS profile, schema names with or without /msg/
        from ._mcap import open_mcap

        return open_mcap(path, typestore)
    default = _default_store(1 if path.suffix.lower() == ".bag" else 2)
    try:
        reader = AnyReader([path], default_typestore=default)
        reader.open()
    except FileNotFoundError:
        raise
    except Exception as exc:  # noqa: BLE001 - rosbags raises several types for truncated/corrupt files
        raise FormatError(path, f"not a readable bag ({type(exc).__name__}: {exc})") from None
    missing = {k: v for k, v in default.fielddefs.items() if k not in reader.typestore.fielddefs}
    if missing:
        reader.typestore.register(missing)
    return reader


@dataclass(frozen=True)
class BagTopic:
    """One topic: message type, count and the log-time span (seconds)."""

    topic: str
    msgtype: str
    count: int
    first_ns: int
    last_ns: int

    @property
    def first_s(self) -> float:
        return self.first_ns / 1e9

    @property
    def last_s(self) -> float:
        return self.last_ns / 1e9

    @property
    def rate_hz(self) -> float:
        span = self.last_ns - self.first_ns
        return (self.count - 1) * 1e9 / span if self.count > 1 and span > 0 else 0.0


@dataclass(frozen=True)
class BagInfo:
    path: str
    container: str
    topics: tuple[BagTopic, ...]
    start_s: float
    end_s: float

    def to_dict(self) -> dict:
        return {"path": self.path, "container": self.container, "start_s": self.start_s, "end_s": self.end_s,
                "topics": [{"topic": t.topic, "type": t.msgtype, "count": t.count, "rate_hz": round(t.rate_hz, 3),
                            "first_s": t.first_s, "last_s": t.last_s} for t in self.topics]}

    def lines(self) -> list[str]:
        out = [f"{self.path} ({self.container}): {sum(t.count for t in self.topics)} messages, "
               f"{self.end_s - self.start_s:.3f} s"]
        w = max([len(_shown(t.topic)) for t in self.topics] + [5])
        out.append(f"  {'topic':<{w}}  {'type':<36} {'count':>6} {'rate Hz':>8}")
        for t in self.topics:
            flag = "" if t.msgtype in SUPPORTED_TYPES else "  (not read by xcalib)"
            if not _SAFE_TOPIC.match(t.topic):
                flag += "  (name holds characters outside ROS names: refused by bag frames)"
            rate = f"{t.rate_hz:>8.2f}" if t.rate_hz > 0 else f"{'-':>8}"  # one message (or one stamp): no rate
            out.append(f"  {_shown(t.topic):<{w}}  {_shown(t.msgtype):<36} {t.count:>6} {rate}{flag}")
        return out


def _shown(topic: str) -> str:
    """A topic name as printed: names with characters outside ROS names (newlines, controls,
    unicode) escaped."""
    return topic if _SAFE_TOPIC.match(topic) else ascii(topic)


def _container(path: Path) -> str:
    return {".bag": "ros1-bag", ".db3": "ros2-sqlite3", ".mcap": "mcap"}.get(path.suffix.lower(), "ros2-folder")


def bag_info(path) -> BagInfo:
    """Topics, types, counts and rates of a bag (reads every message's log time, not its data)."""
    p = Path(path)
    reader = _reader(p)
    try:
        spans: dict[str, list[int]] = {}
        for con, t, _ in _messages(reader, p, reader.connections):
            s = spans.setdefault(con.topic, [t, t, 0])
            s[0], s[1], s[2] = min(s[0], t), max(s[1], t), s[2] + 1
        types = {c.topic: c.msgtype for c in reader.connections}
        topics = tuple(BagTopic(k, types[k], v[2], v[0], v[1]) for k, v in sorted(spans.items()))
        topics += tuple(BagTopic(k, v, 0, 0, 0) for k, v in sorted(types.items()) if k not in spans)
        start = min((t.first_s for t in topics if t.count), default=0.0)
        end = max((t.last_s for t in topics if t.count), default=0.0)
        return BagInfo(str(p), _container(p), topics, start, end)
    finally:
        reader.close()


def _messages(reader, path: Path, connections, start: int | None = None, stop: int | None = None):
    """rosbags' message iterator with read errors (truncated chunk, bad compression) as FormatError."""
    it = reader.messages(connections=connections, start=start, stop=stop)
    while True:
        try:
            item = next(it)
        except StopIteration:
            return
        except Exception as exc:  # noqa: BLE001
            raise FormatError(path, f"bag data is truncated or corrupt ({type(exc).__name__}: {exc})") from None
        yield item


@dataclass(frozen=True)
class BagCamera:
    """A camera found in a bag: its name (last part of the image topic's namespace) and topics."""

    name: str
    namespace: str
    image_topic: str
    info_topic: str | None
    detections_topic: str | None


@dataclass(frozen=True)
class Dropped:
    topic: str
    stamp_s: float
    reason: str


@dataclass(frozen=True)
class PairingReport:
    """What pairing kept and dropped: ``frames`` paired, every dropped message with its reason."""

    path: str
    lidar_topic: str
    image_topic: str
    tolerance_s: float
    num_lidar: int
    num_images: int
    frames: int
    dropped: tuple[Dropped, ...] = ()
    max_dt_s: float = 0.0

    def by_reason(self) -> dict[str, int]:
        out: dict[str, int] = {}
        for d in self.dropped:
            key = f"{d.topic}: {d.reason.split(' (')[0]}"
            out[key] = out.get(key, 0) + 1
        return out

    def lines(self) -> list[str]:
        out = [f"{self.frames} frame(s) paired from {self.num_lidar} LiDAR sweep(s) on {self.lidar_topic} and "
               f"{self.num_images} image(s) on {self.image_topic} (tolerance {self.tolerance_s * 1e3:g} ms, "
               f"largest offset {self.max_dt_s * 1e3:.1f} ms)"]
        for reason, n in self.by_reason().items():
            out.append(f"  dropped {n}: {reason}")
        return out

    def to_dict(self) -> dict:
        return {"path": self.path, "lidar_topic": self.lidar_topic, "image_topic": self.image_topic,
                "tolerance_s": self.tolerance_s, "num_lidar": self.num_lidar, "num_images": self.num_images,
                "frames": self.frames, "max_dt_s": self.max_dt_s, "dropped_by_reason": self.by_reason(),
                "dropped": [{"topic": d.topic, "stamp_s": d.stamp_s, "reason": d.reason} for d in self.dropped]}


def pair_by_time(lidar_ns, image_ns, tolerance_ns: int) -> tuple[list[tuple[int, int]], dict[int, int], dict[int, int]]:
    """Pair each LiDAR stamp with the nearest image stamp within ``tolerance_ns`` (each image used
    once; closer pairs win). Returns ``(pairs [(i_lidar, j_image)], unpaired lidar {i: nearest
    |dt| ns}, unpaired images {j: nearest |dt| ns})``; -1 as dt when the other list is empty."""
    lid = np.asarray(lidar_ns, dtype=np.int64)
    img = np.asarray(image_ns, dtype=np.int64)
    if len(img) == 0 or len(lid) == 0:
        return [], {i: -1 for i in range(len(lid))}, {j: -1 for j in range(len(img))}
    order = np.argsort(img, kind="stable")
    s = img[order]

    def nearest(t):
        k = np.searchsorted(s, t)
        cand = [c for c in (k - 1, k) if 0 <= c < len(s)]
        best = min(cand, key=lambda c: abs(int(s[c]) - int(t)))
        return int(order[best]), abs(int(s[best]) - int(t))

    cands = sorted(((dt, i, j) for i, (j, dt) in enumerate(nearest(t) for t in lid)), key=lambda x: x[0])
    used, pairs, lost = set(), [], {}
    for dt, i, j in cands:
        if dt <= tolerance_ns and j not in used:
            used.add(j)
            pairs.append((i, j))
        else:
            lost[i] = dt
    sl = np.sort(lid)
    img_lost = {}
    for j in range(len(img)):
        if j not in used:
            k = np.searchsorted(sl, img[j])
            img_lost[j] = min(abs(int(sl[c]) - int(img[j])) for c in (k - 1, k) if 0 <= c < len(sl))
    return sorted(pairs), lost, img_lost


def _namespace(topic: str) -> tuple[str, str]:
    parts = [p for p in topic.split("/") if p]
    while len(parts) > 1 and parts[-1] in _IMAGE_SUFFIXES:
        parts.pop()
    if len(parts) == 1 and parts[0] in _IMAGE_SUFFIXES:
        return "camera", ""
    return parts[-1], "/" + "/".join(parts)


def _under(topic: str, ns: str) -> bool:
    return bool(ns) and topic.startswith(ns + "/")


def _cameras_of(types: dict[str, str], path) -> list[BagCamera]:
    """One camera per image namespace (a raw Image wins over a CompressedImage of the same
    namespace). Cameras whose namespaces end alike (``/a/camera/image``, ``/b/camera/image``)
    are all kept, named after their whole namespace (``a_camera``, ``b_camera``)."""
    def of_type(*ts):
        return sorted(t for t, m in types.items() if m in ts)

    by_ns: dict[str, tuple[str, str]] = {}
    for topic in of_type(IMAGE) + of_type(COMPRESSED):
        name, ns = _namespace(topic)
        by_ns.setdefault(ns, (name, topic))
    counts: dict[str, int] = {}
    for name, _ in by_ns.values():
        counts[name] = counts.get(name, 0) + 1
    found: list[BagCamera] = []
    for ns, (name, topic) in by_ns.items():
        if counts[name] > 1:
            name = ns.strip("/").replace("/", "_") or name
            log.warning("%s: several image namespaces end in the same camera name; camera %s is %s", path, name, topic)
        info = [t for t in of_type(CAMERA_INFO) if _under(t, ns)]
        dets = [t for t in of_type(DET2D) if _under(t, ns)]
        found.append(BagCamera(name, ns, topic, info[0] if len(info) == 1 else None,
                               dets[0] if len(dets) == 1 else None))
    return found


def bag_cameras(path) -> list[BagCamera]:
    """The cameras of a bag (image topics by namespace; see :class:`BagFrames`), read from its
    topic list only. Topic names outside ROS names are a FormatError."""
    p = Path(path)
    reader = _reader(p)
    try:
        types = {c.topic: c.msgtype for c in reader.connections}
    finally:
        reader.close()
    _check_topic_names(types, p)
    return _cameras_of(types, p)


def _check_topic_names(types, path) -> None:
    """Topic names become camera names, file names and script text downstream: a name with
    characters outside ROS names (newline, quote, space, control or unicode characters) is
    refused, naming it escaped."""
    for t in sorted(types):
        if not _SAFE_TOPIC.match(t) or len(t) > 512:
            raise FormatError(path, f"topic name {ascii(t)[:200]} holds characters outside ROS names "
                                    "(letters, digits, _ / ~ { } . -); refusing the bag", "topic")


@dataclass(frozen=True)
class _Lazy:
    """A LiDAR sweep or image not kept in memory: where to read it again (its log time, its rank
    among the topic's messages of that log time) and its header (stamp, frame id)."""

    t_log: int
    rank: int
    header: Any


@dataclass
class _Entry:
    lidar: tuple
    image: tuple
    det3d: tuple
    det2d: tuple
    info: tuple | None
    meta: dict = field(default_factory=dict)


@dataclass(frozen=True)
class BagReadOptions(Options):
    """How :class:`BagFrames` reads a bag besides the camera (the defaults in one place; the class
    docstring documents each): lidar, camera_info, detections_2d, detections_3d (topics; None:
    found), tolerance_s, intrinsics, detections, fisheye ("rectify" | "keep")."""

    lidar: str | None = None
    camera_info: str | None = None
    detections_2d: str | None = None
    detections_3d: str | None = None
    tolerance_s: float = 0.05
    intrinsics: CameraIntrinsics | None = None
    detections: bool = True
    fisheye: str = "rectify"


class BagFrames(Sequence):
    """Frames of one camera and one LiDAR from a bag (a lazy ``Sequence[Frame]``).

    Args: ``camera`` — camera name (namespace of its image topic, e.g. ``front`` for
    ``/front/image_raw``) or image topic; required when the bag has several. ``lidar`` —
    PointCloud2 topic (default: the only one). ``camera_info`` / ``detections_2d`` /
    ``detections_3d`` — topics (default: found under the camera's / LiDAR's namespace, or the only
    one of the type). ``tolerance_s`` — largest LiDAR/image stamp difference paired.
    ``intrinsics`` — used instead of CameraInfo (required when the bag has none).
    ``detections`` — False: read the sensors only (no detection topics needed; frames carry no
    boxes, for :mod:`xcalib.detect` to fill). ``fisheye`` — an equidistant CameraInfo: "rectify"
    to pinhole or "keep" the fisheye. These settings (all but ``camera``) are the fields of
    :class:`BagReadOptions`: pass one as ``options=`` and/or them as keyword arguments.

    Attributes: ``report`` (:class:`PairingReport`), ``cameras`` (every :class:`BagCamera`),
    ``camera`` (the chosen one's name), ``intrinsics``, ``transforms`` (tf_static / tf edges:
    child -> (parent, T_parent_child)), ``tf_T_cam_lidar`` (the bag's own LiDAR -> camera
    transform through tf, between the cloud's and the image's header frames, or None).
    """

    @document(BagReadOptions)
    def __init__(self, path, camera: str | None = None, *, options: BagReadOptions | None = None, **overrides: Any):
        o = resolve(BagReadOptions, options, overrides, where="BagFrames")
        lidar, camera_info, detections_2d, detections_3d = o.lidar, o.camera_info, o.detections_2d, o.detections_3d
        tolerance_s, intrinsics, detections, fisheye = o.tolerance_s, o.intrinsics, o.detections, o.fisheye
        self.path = Path(path)
        self.with_detections = bool(detections)
        if fisheye not in ("rectify", "keep"):
            raise ValueError(f"fisheye must be 'rectify' or 'keep', got {fisheye!r}")
        self._fisheye_mode = fisheye  # an equidistant CameraInfo: rectify to pinhole, or keep the fisheye
        if not self.path.exists():
            raise FileNotFoundError(f"bag not found: {self.path}")
        if not tolerance_s > 0:
            raise ValueError(f"tolerance_s must be > 0, got {tolerance_s}")
        reader = _reader(self.path)
        try:
            self._types = {c.topic: c.msgtype for c in reader.connections}
            _check_topic_names(self._types, self.path)
            self.cameras = self._find_cameras()
            cam = self._choose_camera(camera)
            self.camera = cam.name
            self.camera_names = [c.name for c in self.cameras]
            self.topics = self._resolve(cam, lidar, camera_info, detections_2d, detections_3d, intrinsics)
            msgs = self._index(reader)
        finally:
            reader.close()
        self._fixed_intrinsics = intrinsics
        self.tolerance_s = float(tolerance_s)
        self._entries, self.report = self._pair(msgs)
        self.transforms = self._tf_edges(msgs)
        self._static = self._tf_edges(msgs, static_only=True)
        self.lidar_frame_id = str(self._entries[0].lidar[1].header.frame_id).lstrip("/") if self._entries else ""
        self.camera_frame_id = str(self._entries[0].image[1].header.frame_id).lstrip("/") if self._entries else ""
        self.tf_T_cam_lidar = self._tf_lookup()
        self._det_frames: dict[str, np.ndarray | None] = {}
        self.intrinsics = intrinsics if intrinsics is not None else (
            self._intrinsics(self._entries[0].info) if self._entries and self._entries[0].info else None)
        self.source_name = "bag"

    # ---------------------------------------------------------------- topic resolution
    def _where(self, topic: str | None, index: int | None = None) -> tuple[str, str | None, int | None]:
        return str(self.path), topic, index

    def _of_type(self, *types: str) -> list[str]:
        return sorted(t for t, m in self._types.items() if m in types)

    def _listing(self) -> str:
        return "; ".join(f"{t} ({m})" for t, m in sorted(self._types.items()))

    def _find_cameras(self) -> list[BagCamera]:
        return _cameras_of(self._types, self.path)

    def _choose_camera(self, camera: str | None) -> BagCamera:
        if not self.cameras:
            raise FormatError(self.path, "no Image or CompressedImage topic; topics: " + self._listing(), "camera")
        if camera is None:
            if len(self.cameras) > 1:
                raise FormatError(self.path, "several cameras; choose one with camera= (--camera): "
                                  + ", ".join(f"{c.name} ({c.image_topic})" for c in self.cameras), "camera")
            return self.cameras[0]
        for c in self.cameras:
            if camera in (c.name, c.namespace, c.image_topic):
                return c
        raise FormatError(self.path, f"no camera {camera!r}; cameras: "
                          + ", ".join(f"{c.name} ({c.image_topic})" for c in self.cameras), camera)

    def _pick(self, wanted: str | None, types: tuple[str, ...], ns: str, what: str, option: str,
              required: bool) -> str | None:
        if wanted is not None:
            if wanted not in self._types:
                raise FormatError(self.path, f"no topic {wanted!r} for the {what}; topics: {self._listing()}", wanted)
            if self._types[wanted] not in types:
                raise FormatError(self.path, f"topic has type {self._types[wanted]}, expected "
                                  f"{' or '.join(types)} for the {what}", wanted)
            return wanted
        cands = self._of_type(*types)
        near = [t for t in cands if _under(t, ns)]
        if len(near) == 1:
            return near[0]
        if len(cands) == 1 and not near:
            return cands[0]
        if not required:
            return None
        if not cands:
            hint = " (xcalib detect BAG --out OUT.mcap, or calibrate --detect, makes them)" \
                if types[0] in (DET2D, *DET3D_TYPES) else ""
            raise FormatError(self.path, f"no {' or '.join(types)} topic for the {what}{hint}; topics: "
                                         f"{self._listing()}", option)
        raise FormatError(self.path, f"several {types[0]} topics for the {what}: {', '.join(near or cands)}; "
                                     f"choose one with {option}", option)

    def _resolve(self, cam: BagCamera, lidar, info, det2d, det3d, intrinsics) -> dict[str, str | None]:
        lid = self._pick(lidar, (POINTCLOUD2,), "", "LiDAR", "--lidar", True)
        lid_ns = lid.rsplit("/", 1)[0]
        topics = {
            "lidar": lid,
            "image": cam.image_topic,
            "camera_info": self._pick(info or cam.info_topic, (CAMERA_INFO,), cam.namespace, "camera info",
                                      "--camera-info", False),
            "detections_2d": self._pick(det2d or cam.detections_topic, (DET2D,), cam.namespace,
                                        f"2D detections of camera {cam.name}", "--detections-2d", True)
            if self.with_detections else None,
            "detections_3d": self._pick(det3d, DET3D_TYPES, lid_ns, "3D detections", "--detections-3d", True)
            if self.with_detections else None,
        }
        if topics["camera_info"] is None and intrinsics is None:
            raise FormatError(self.path, f"no CameraInfo topic for camera {cam.name} ({cam.image_topic}); pass "
                                         "--intrinsics K.json (Python: intrinsics=)", cam.image_topic)
        return topics

    # ---------------------------------------------------------------- indexing and pairing
    def _index(self, reader) -> dict[str, list[tuple[int, object, int]]]:
        """Deserialise the chosen topics (+ tf, tf_static, xcalib's frame records): topic ->
        [(header stamp ns (log time when the header has none), message, index on the topic in
        log order)] sorted by stamp. LiDAR sweeps and images are not kept: each is read once for
        its header and stands as a :class:`_Lazy` (read again when its frame is asked for), so
        memory holds one sweep at a time whatever the recording's length."""
        lazy = {self.topics["lidar"], self.topics["image"]}
        seen_log: dict[tuple[str, int], int] = {}
        wanted = {t for t in self.topics.values() if t}
        wanted |= {t for t, m in self._types.items() if m in TF_TYPES or (t == META_TOPIC and m == STRING)}
        cons = [c for c in reader.connections if c.topic in wanted]
        out: dict[str, list[tuple[int, object, int]]] = {t: [] for t in wanted}
        for con, t_log, raw in _messages(reader, self.path, cons):
            k = len(out[con.topic])
            if len(raw) > MAX_MESSAGE_BYTES:
                raise FormatError(self.path, f"message {k} is {len(raw)} bytes; the limit is {MAX_MESSAGE_BYTES} "
                                             "bytes per message", con.topic)
            try:
                msg = reader.deserialize(raw, con.msgtype)
            except Exception as exc:  # noqa: BLE001 - rosbags' deserialisation errors
                raise FormatError(self.path, f"message {k} of type {con.msgtype} does not deserialise ({exc})",
                                  con.topic) from None
            header = getattr(msg, "header", None)
            stamp = cv.stamp_ns(header, self._where(con.topic, k)) if header is not None else int(t_log)
            if con.topic in lazy:
                rank = seen_log.get((con.topic, int(t_log)), 0)
                seen_log[(con.topic, int(t_log))] = rank + 1
                msg = _Lazy(int(t_log), rank, header)
            out[con.topic].append((stamp if stamp > 0 else int(t_log), msg, k))
        for v in out.values():
            v.sort(key=lambda x: x[0])
        return out

    def _pair(self, msgs) -> tuple[list[_Entry], PairingReport]:
        tp = self.topics
        lid, img = msgs[tp["lidar"]], msgs[tp["image"]]
        for key in ("lidar", "image", "detections_2d", "detections_3d"):
            if tp[key] is not None and not msgs[tp[key]]:
                raise FormatError(self.path, "topic has no messages", tp[key])
        tol = int(round(self.tolerance_s * 1e9))
        dropped: list[Dropped] = []
        lid, img = self._unique(lid, tp["lidar"], dropped), self._unique(img, tp["image"], dropped)
        d3u = self._unique(msgs[tp["detections_3d"]], tp["detections_3d"], dropped) if tp["detections_3d"] else None
        d2u = self._unique(msgs[tp["detections_2d"]], tp["detections_2d"], dropped) if tp["detections_2d"] else None
        if not lid or not img:
            raise FormatError(self.path, "every message shares its stamp with another", tp["lidar" if not lid
                                                                                                  else "image"])
        l_ns, i_ns = [s for s, _, _ in lid], [s for s, _, _ in img]
        if l_ns[-1] + tol < i_ns[0] or i_ns[-1] + tol < l_ns[0]:
            raise FormatError(self.path, f"clocks do not overlap: LiDAR {tp['lidar']} stamps "
                                         f"{l_ns[0] / 1e9:.3f}-{l_ns[-1] / 1e9:.3f} s, camera {tp['image']} "
                                         f"{i_ns[0] / 1e9:.3f}-{i_ns[-1] / 1e9:.3f} s", tp["image"])
        pairs, lost_l, lost_i = pair_by_time(l_ns, i_ns, tol)
        dropped += [Dropped(tp["lidar"], l_ns[i] / 1e9, f"no image within {self.tolerance_s * 1e3:g} ms "
                                                       f"(nearest {dt / 1e6:.1f} ms)") for i, dt in lost_l.items()]
        dropped += [Dropped(tp["image"], i_ns[j] / 1e9, f"no LiDAR sweep within {self.tolerance_s * 1e3:g} ms "
                                                        f"(nearest {dt / 1e6:.1f} ms)") for j, dt in lost_i.items()]
        # sweep / image stamp -> (stamp, message, index) of the nearest detections within the tolerance
        d3 = _nearest_within(l_ns, d3u, tol) if d3u is not None else None
        d2 = _nearest_within(i_ns, d2u, tol) if d2u is not None else None
        infos = msgs[tp["camera_info"]] if tp["camera_info"] else []
        meta = {}
        for _, m, k in msgs.get(META_TOPIC, []):
            rec = self._record(m.data, k)
            if rec["lidar_stamp_ns"] in meta:
                raise FormatError(self.path, f"message {k}: a second frame record for LiDAR stamp "
                                             f"{rec['lidar_stamp_ns']}", META_TOPIC)
            meta[rec["lidar_stamp_ns"]] = rec
        entries, used3, used2, max_dt = [], set(), set(), 0
        for i, j in pairs:
            (ls, lm, lk), (is_, im, ik) = lid[i], img[j]
            if d3 is None or d2 is None:  # sensors only (detections=False)
                max_dt = max(max_dt, abs(ls - is_))
                info = min(infos, key=lambda x: abs(x[0] - is_)) if infos else None
                entries.append(_Entry((ls, lm, lk), (is_, im, ik), None, None, info, meta.get(ls, {})))
                continue
            if ls not in d3:
                dropped.append(Dropped(tp["detections_3d"], ls / 1e9, f"no 3D detections within "
                                       f"{self.tolerance_s * 1e3:g} ms of the sweep"))
                continue
            if is_ not in d2:
                dropped.append(Dropped(tp["detections_2d"], is_ / 1e9, f"no 2D detections within "
                                       f"{self.tolerance_s * 1e3:g} ms of the image"))
                continue
            used3.add(d3[ls][0])
            used2.add(d2[is_][0])
            max_dt = max(max_dt, abs(ls - is_))
            info = min(infos, key=lambda x: abs(x[0] - is_)) if infos else None
            entries.append(_Entry((ls, lm, lk), (is_, im, ik), d3[ls], d2[is_], info, meta.get(ls, {})))
        if d3 is not None and d2 is not None:
            dropped += [Dropped(tp["detections_3d"], s / 1e9, "no paired LiDAR sweep near this stamp")
                        for s, _, _ in d3u if s not in used3]
            dropped += [Dropped(tp["detections_2d"], s / 1e9, "no paired image near this stamp")
                        for s, _, _ in d2u if s not in used2]
        report = PairingReport(str(self.path), tp["lidar"], tp["image"], self.tolerance_s, len(lid), len(img),
                               len(entries), tuple(sorted(dropped, key=lambda d: (d.topic, d.stamp_s))),
                               max_dt / 1e9)
        if not entries:
            raise FormatError(self.path, "no frame could be paired: " + " / ".join(report.lines()), tp["image"])
        return entries, report

    def _unique(self, items, topic: str, dropped: list[Dropped]):
        """``items`` without the messages that share their header stamp with another on the same
        topic (which of them goes with which is unknowable): each is reported as dropped."""
        counts: dict[int, int] = {}
        for s, _, _ in items:
            counts[s] = counts.get(s, 0) + 1
        if all(c == 1 for c in counts.values()):
            return items
        for s, _, k in items:
            if counts[s] > 1:
                dropped.append(Dropped(topic, s / 1e9, f"{counts[s]} messages share this stamp (message {k})"))
        log.warning("%s: %s: %d message(s) share their header stamp with another; dropped", self.path, topic,
                    sum(c for c in counts.values() if c > 1))
        return [it for it in items if counts[it[0]] == 1]

    def _record(self, text: str, index: int = 0) -> dict:
        """One xcalib frame record (JSON), every key the frames read from it checked."""
        def bad(problem: str, key: str):
            return FormatError(self.path, f"message {index}, frame record {key}: {problem}", META_TOPIC)

        try:
            rec = json.loads(text)
        except (ValueError, RecursionError) as exc:
            raise FormatError(self.path, f"message {index}: frame record is not valid JSON "
                                         f"({type(exc).__name__}: {str(exc)[:120]})", META_TOPIC) from None
        if not isinstance(rec, dict) or type(rec.get("lidar_stamp_ns")) is not int \
                or not isinstance(rec.get("cameras", {}), dict):
            raise FormatError(self.path, f"message {index}: frame record needs an integer lidar_stamp_ns and a "
                                         "cameras mapping", META_TOPIC)
        _time(rec.get("lidar_time_s"), bad, "lidar_time_s")
        if rec.get("detections_source") not in (None, OWN_DETECTIONS):
            raise bad(f"expected {OWN_DETECTIONS!r} or nothing, got {rec['detections_source']!r:.40}",
                      "detections_source")
        if not isinstance(rec.get("frame_key", ""), (str, int)) or isinstance(rec.get("frame_key"), bool):
            raise bad("expected a string", "frame_key")
        rows = rec.get("box3d_rows")
        if rows is not None and (not isinstance(rows, list) or any(r not in ("extents", "center") for r in rows)):
            raise bad("expected a list of 'extents' / 'center'", "box3d_rows")
        tracks = rec.get("track_ids_3d")
        if tracks is not None and (not isinstance(tracks, list)
                                   or any(type(t) is not int or abs(t) >= 1 << 63 for t in tracks)):
            raise bad("expected a list of integers", "track_ids_3d")
        vel = rec.get("velocities_3d")
        if vel is not None:
            v = _numbers(vel, bad, "velocities_3d")
            if v.ndim != 2 or v.shape[1:] != (3,) or (tracks is not None and len(v) != len(tracks)):
                raise bad(f"expected [M, 3] finite numbers, got shape {list(v.shape)}", "velocities_3d")
            if v.size and np.abs(v).max() > MAX_SPEED_MPS:
                raise bad(f"a velocity of {float(np.abs(v).max()):.3g} m/s, beyond {MAX_SPEED_MPS:g} m/s: not m/s "
                          "(mm/s?) or corrupt", "velocities_3d")
        for cam, c in rec["cameras"].items():
            if not isinstance(c, dict):
                raise bad("expected a mapping", f"cameras.{cam}")
            _time(c.get("camera_time_s"), bad, f"cameras.{cam}.camera_time_s")
            if not isinstance(c.get("camera_name", ""), str):
                raise bad("expected a string", f"cameras.{cam}.camera_name")
            if c.get("extrinsics") is not None:
                T = _numbers(c["extrinsics"], bad, f"cameras.{cam}.extrinsics")
                try:
                    check_rigid(self.path, f"{META_TOPIC} message {index} cameras.{cam}.extrinsics", T)
                except FormatError as exc:
                    raise bad(exc.problem, f"cameras.{cam}.extrinsics") from None
            if c.get("match_matrix") is not None:
                mm = _numbers(c["match_matrix"], bad, f"cameras.{cam}.match_matrix")
                if mm.ndim != 2 or not np.isin(mm, (0, 1)).all():
                    raise bad("expected a 0/1 matrix", f"cameras.{cam}.match_matrix")
        return rec

    # ---------------------------------------------------------------- tf
    def _tf_edges(self, msgs, static_only: bool = False) -> dict[str, tuple[str, np.ndarray]]:
        edges: dict[str, tuple[str, np.ndarray]] = {}
        for topic, m in self._types.items():
            if m not in TF_TYPES or (static_only and not topic.endswith("tf_static")):
                continue
            for _, msg, k in msgs.get(topic, []):
                for parent, child, T, _ in cv.transforms_from_msg(msg, self._where(topic, k)):
                    edges.setdefault(child, (parent, T))  # the first (static) value of each edge
        return edges

    def _root_path(self, frame: str, edges=None) -> tuple[str, np.ndarray]:
        edges = self.transforms if edges is None else edges
        T, seen = np.eye(4), set()
        while frame in edges and frame not in seen:
            seen.add(frame)
            parent, T_pc = edges[frame]
            T, frame = T_pc @ T, parent
        return frame, T

    def _lidar_from(self, frame: str) -> np.ndarray | None:
        """``T_lidar_frame`` through the static tf for detections stamped in ``frame`` (None: the
        cloud's own frame, or no frame named); FormatError when the static tf does not connect them."""
        frame = frame.lstrip("/")
        if not frame or frame == self.lidar_frame_id or not self.lidar_frame_id:
            return None
        if frame not in self._det_frames:
            root_d, T_root_det = self._root_path(frame, self._static)
            root_l, T_root_lidar = self._root_path(self.lidar_frame_id, self._static)
            if root_d != root_l:
                raise FormatError(self.path, f"3D detections are in frame {frame!r} and the cloud in "
                                             f"{self.lidar_frame_id!r}, and the recording's /tf_static does not "
                                             "connect them (a moving frame such as map needs the detections in "
                                             "the sensor's frame)", self.topics["detections_3d"])
            self._det_frames[frame] = invert_transform(T_root_lidar) @ T_root_det
        return self._det_frames[frame]

    def _tf_lookup(self) -> np.ndarray | None:
        if not self._entries or not self.transforms:
            return None
        lid_frame = str(self._entries[0].lidar[1].header.frame_id).lstrip("/")
        cam_frame = str(self._entries[0].image[1].header.frame_id).lstrip("/")
        root_l, T_root_lidar = self._root_path(lid_frame)
        root_c, T_root_cam = self._root_path(cam_frame)
        if root_l != root_c:
            return None
        if not cam_frame.endswith(("optical_frame", "optical")):
            log.warning("%s: image frame_id %r is not an *_optical_frame; the tf transform is taken as the "
                        "OpenCV optical frame", self.path, cam_frame)
        return invert_transform(T_root_cam) @ T_root_lidar

    # ---------------------------------------------------------------- frames
    def _load(self, topic: str, item):
        """The message of an index entry, read again from the bag when it was not kept."""
        msg = item[1]
        if not isinstance(msg, _Lazy):
            return msg
        import os

        if getattr(self, "_open", None) is None or self._open[0] != os.getpid():
            self._open = (os.getpid(), _reader(self.path))
        reader = self._open[1]
        cons = [c for c in reader.connections if c.topic == topic]
        rank = 0
        for con, t, raw in _messages(reader, self.path, cons, msg.t_log, msg.t_log + 1):
            if t != msg.t_log:
                continue
            if rank == msg.rank:
                try:
                    return reader.deserialize(raw, con.msgtype)
                except Exception as exc:  # noqa: BLE001
                    raise FormatError(self.path, f"message {item[2]} of type {con.msgtype} does not deserialise "
                                                 f"({exc})", topic) from None
            rank += 1
        raise FormatError(self.path, f"message {item[2]} is no longer in the bag (changed while read?)", topic)

    def close(self) -> None:
        """Close the bag opened to read frames (reopened when another frame is asked for)."""
        opened, self._open = getattr(self, "_open", None), None
        if opened is not None:
            opened[1].close()

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __del__(self):
        try:
            self.close()
        except Exception:  # noqa: BLE001 - interpreter shutdown
            pass

    def _intrinsics(self, info) -> CameraIntrinsics:
        if self._fisheye_mode == "keep":  # an equidistant camera stays a kannala_brandt camera model
            m = cv.camera_model_from_msg(info[1], self._where(self.topics["camera_info"], info[2]))
            return m.camera_model if isinstance(m, cv.Fisheye) else m
        return cv.intrinsics_from_msg(info[1], self._where(self.topics["camera_info"], info[2]))

    def _fisheye(self, e: _Entry):
        """The frame's equidistant camera model when its CameraInfo has one (and no --intrinsics)."""
        if self._fixed_intrinsics is not None or e.info is None:
            return None
        m = cv.camera_model_from_msg(e.info[1], self._where(self.topics["camera_info"], e.info[2]))
        return m if isinstance(m, cv.Fisheye) else None

    def __len__(self) -> int:
        return len(self._entries)

    def __getitem__(self, index):
        if isinstance(index, slice):
            return [self[i] for i in range(*index.indices(len(self)))]
        e = self._entries[index]
        try:
            return self._frame(e)
        except FormatError:
            raise
        except (ValueError, TypeError, KeyError, IndexError, AttributeError) as exc:  # malformed message fields
            raise FormatError(self.path, f"frame at LiDAR stamp {e.lidar[0] / 1e9:.6f} s: malformed message "
                                         f"({type(exc).__name__}: {exc})", self.topics["lidar"]) from None

    @property
    def frame_keys(self) -> list[str]:
        return [str(e.meta.get("cameras", {}).get(self.camera, {}).get("frame_key", e.meta.get("frame_key", e.lidar[0])))
                for e in self._entries]

    def _frame(self, e: _Entry) -> Frame:
        tp = self.topics
        image = cv.image_from_msg(self._load(tp["image"], e.image), self._where(tp["image"], e.image[2]))
        points, fields, n_bad = cv.cloud_from_msg(self._load(tp["lidar"], e.lidar),
                                                  self._where(tp["lidar"], e.lidar[2]))
        if n_bad:
            log.warning("%s: %s message %d: %d of %d point(s) with NaN/Inf coordinates dropped", self.path,
                        tp["lidar"], e.lidar[2], n_bad, n_bad + len(points))
        if len(points) == 0:
            log.warning("%s: %s message %d: the point cloud is empty", self.path, tp["lidar"], e.lidar[2])
        flattened, yawless = 0, False
        if e.det2d is None:  # sensors only
            b2, ids2, box7, ids3 = np.zeros((0, 4), np.float32), [], np.zeros((0, 7), np.float32), []
        else:
            b2, ids2 = cv.boxes2d_from_msg(e.det2d[1], self._where(tp["detections_2d"], e.det2d[2]))
            det = boxes3d_any(e.det3d[1], self._where(tp["detections_3d"], e.det3d[2]),
                              self._lidar_from(str(e.det3d[1].header.frame_id)), MAX_TILT_DEG)
            box7, ids3, flattened, yawless = det.box7, det.ids, det.flattened, det.yawless
            if det.flattened:
                log.warning("%s [%s] frame at %.3f s: %d 3D box(es) turned about x/y (up to %.1f deg) flattened "
                            "to their heading (refused beyond %g deg)", self.path, tp["detections_3d"],
                            e.lidar[0] / 1e9, det.flattened, det.max_tilt_deg, MAX_TILT_DEG)
        intr = self._fixed_intrinsics or self._intrinsics(e.info)
        fisheye = self._fisheye(e) if self._fisheye_mode == "rectify" else None
        if fisheye is not None:  # equidistant: image and 2D boxes rectified to the pinhole ``intr``
            if image.shape[1::-1] != fisheye.size:
                raise FormatError(self.path, f"CameraInfo is for {fisheye.size[0]}x{fisheye.size[1]} but the image "
                                             f"is {image.shape[1]}x{image.shape[0]}", tp["camera_info"])
            image, b2 = fisheye.rectify_image(image), fisheye.rectify_boxes(b2)
        h, w = image.shape[:2]
        if intr.width is not None and (intr.width, intr.height) != (w, h):
            raise FormatError(self.path, f"CameraInfo is for {intr.width}x{intr.height} but the image is {w}x{h}",
                              tp["camera_info"] or tp["image"])
        intr = intr.with_image_size(w, h)
        rec = e.meta.get("cameras", {}).get(self.camera, {})
        if not (np.all(np.isfinite(b2)) and np.all(np.isfinite(box7))):
            raise FormatError(self.path, "detections hold non-finite box values",
                              tp["detections_2d"] if not np.all(np.isfinite(b2)) else tp["detections_3d"])
        rows = e.meta.get("box3d_rows")
        if rows is None and not e.meta and yawless:  # no orientation given: yaw re-estimated from the points
            rows = ["extents"] * len(box7)
        with np.errstate(over="ignore"):
            b3 = _boxes3d_as_written(box7, rows)
        if not np.all(np.isfinite(b3)):
            raise FormatError(self.path, "3D boxes out of float32 range", tp["detections_3d"])
        mm = rec.get("match_matrix") if e.det2d is not None else None
        extr = rec.get("extrinsics")
        if extr is not None:
            extr = np.asarray(extr, dtype=np.float64)
        meta = {"source": "bag", "bag": str(self.path), "lidar_topic": tp["lidar"], "image_topic": tp["image"],
                "lidar_stamp_ns": e.lidar[0], "camera_stamp_ns": e.image[0], "detection_ids_2d": ids2}
        made = None  # the boxes of a bag `xcalib detect` wrote say so
        if e.meta.get("detections_source") == OWN_DETECTIONS and e.det2d is not None:
            made = FrameDetections(OWN_DETECTIONS)
        if n_bad:
            meta["points_dropped_nonfinite"] = n_bad
        if flattened:
            meta["boxes3d_flattened"] = flattened
        if fisheye is not None:
            meta["rectified_from"] = "equidistant"
        tracks = e.meta.get("track_ids_3d")
        if tracks is None and ids3 and all(i.lstrip("-").isdigit() for i in ids3):
            tracks = [int(i) for i in ids3]
        elif tracks is None and ids3 and all(len(i) == 32 and set(i) <= set("0123456789abcdef") for i in ids3):
            tracks = [int(i[:15], 16) for i in ids3]  # Autoware TrackedObjects' UUIDs
        vel = e.meta.get("velocities_3d")
        lt, ct = e.meta.get("lidar_time_s"), rec.get("camera_time_s")
        return Frame(image=image, point_cloud=points, bboxes_2d=b2, bboxes_3d=b3,
                     lidar_time_s=e.lidar[0] / 1e9 if lt is None else float(lt),
                     camera_time_s=e.image[0] / 1e9 if ct is None else float(ct),
                     track_ids_3d=None if tracks is None else np.asarray(tracks, dtype=np.int64),
                     velocities_3d=None if vel is None else np.asarray(vel, dtype=np.float64).reshape(-1, 3),
                     camera_name=str(rec.get("camera_name", self.camera)),
                     frame_key=str(rec.get("frame_key", e.meta.get("frame_key", e.lidar[0]))),
                     match_matrix=None if mm is None else _match(mm, len(b2), len(b3), self.path),
                     intrinsics=intr, extrinsics=extr,
                     point_fields=fields, meta=meta, detections=made)


def recorded_stamp_ns(frame, sensor: str) -> int | None:
    """The recording's header stamp (ns) of a frame's ``sensor`` (``"lidar"`` or ``"camera"``) as a
    bag reader keeps it (exact, where ``lidar_time_s`` as float seconds loses ~200 ns); None for a
    frame without one. The one reader of that ``meta`` key outside the bag code."""
    if sensor not in ("lidar", "camera"):
        raise ValueError(f"sensor: expected 'lidar' or 'camera', got {sensor!r}")
    meta = getattr(frame, "meta", None)
    return meta.get(f"{sensor}_stamp_ns") if isinstance(meta, dict) else None


def rectified_from(frame) -> str | None:
    """``"equidistant"`` when the bag reader rectified the frame's fisheye image and 2D boxes to a
    pinhole camera (``fisheye="rectify"``), else None."""
    meta = getattr(frame, "meta", None)
    return meta.get("rectified_from") if isinstance(meta, dict) else None


def _nearest_within(stamps, items, tol: int) -> dict[int, tuple]:
    """Each of ``stamps`` -> the item of ``items`` ([(stamp, message, index)] sorted) nearest to it
    within ``tol`` ns (each message used once, the closest pairs first): detections stamped a few
    ms off their sensor message, as detector nodes stamp them."""
    pairs, _, _ = pair_by_time(stamps, [it[0] for it in items], tol)
    return {int(stamps[i]): items[j] for i, j in pairs}


def _time(value, bad, key: str) -> None:
    """A frame record's time: absent/null or a finite number (not a bool, not ``NaN``)."""
    if value is None:
        return
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise bad(f"expected a finite number of seconds, got {value!r:.40}", key)
    if abs(value) > MAX_TIME_S:
        raise bad(f"time {value:.6g} s is beyond {MAX_TIME_S:g} s in magnitude: not a clock in seconds (a stamp "
                  "in milliseconds, microseconds or nanoseconds?) or corrupt", key)


def _numbers(value, bad, key: str) -> np.ndarray:
    """Nested lists of finite numbers (no bools, strings, nulls) as a float64 array."""
    def walk(v):
        if isinstance(v, list):
            return all(walk(x) for x in v)
        return not isinstance(v, bool) and isinstance(v, (int, float)) and math.isfinite(v)

    if not isinstance(value, list) or not walk(value):
        raise bad("expected nested lists of finite numbers", key)
    try:
        return np.asarray(value, dtype=np.float64)
    except ValueError:
        raise bad("rows of unequal length", key) from None


def _match(mm, n2: int, n3: int, path) -> np.ndarray:
    a = np.asarray(mm, dtype=bool)
    if a.shape != (n2, n3):
        raise FormatError(path, f"frame record: match_matrix is {list(a.shape)} for {n2} 2D and {n3} 3D boxes",
                          META_TOPIC)
    return a


def _boxes3d_as_written(box7: np.ndarray, rows) -> np.ndarray:
    """box7 -> the layout xcalib wrote (``rows``: per-row ``extents`` / ``center`` for protocol
    [M, 6] boxes, None for box7) — exact for float32 inputs."""
    if rows is None or len(rows) != len(box7):
        return box7.astype(np.float32)
    out = np.empty((len(box7), 6), dtype=np.float64)
    for k, kind in enumerate(rows):
        c, s = box7[k, :3], box7[k, 3:6]
        out[k] = np.concatenate([c - s / 2, c + s / 2]) if kind == "extents" else np.concatenate([c, s])
    return out.astype(np.float32)
