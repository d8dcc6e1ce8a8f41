"""Reading ROS 1 ``.bag``, ROS 2 ``.db3`` and ``.mcap`` files as frames, without ROS (rosbags).

:func:`bag_info` lists topics, types, counts and rates. :class:`BagFrames` picks one LiDAR and
one camera (image + CameraInfo + 2D detections; the LiDAR's 3D detections), indexes their
messages by header stamp, pairs each LiDAR sweep with the nearest image within
``tolerance_s`` and reports every message it dropped and why (:class:`PairingReport`).
Problems raise :class:`~xcalib.errors.FormatError` naming the bag and the topic.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ...errors import FormatError
from ...geometry.camera import CameraIntrinsics
from ...geometry.transforms import invert_transform
from ...types import Frame
from . import _convert as cv
from ._msgs import CAMERA_INFO, COMPRESSED, DET2D, DET3D, IMAGE, POINTCLOUD2, STRING, SUPPORTED_TYPES, TF_TYPES, typestore

__all__ = ["BAG_SUFFIXES", "is_bag", "BagTopic", "BagInfo", "bag_info", "BagCamera", "Dropped", "PairingReport",
           "BagFrames", "pair_by_time", "META_TOPIC"]

log = logging.getLogger(__name__)
BAG_SUFFIXES = (".bag", ".db3", ".mcap")
META_TOPIC = "/xcalib/frames"  # xcalib's own per-frame record (frame key, ground truth) in bags it writes
_IMAGE_SUFFIXES = {"image_raw", "image", "compressed", "image_color", "image_rect", "image_rect_color", "image_mono"}


def is_bag(path) -> bool:
    """A ``.bag`` / ``.db3`` / ``.mcap`` file, or a ROS 2 bag folder (``metadata.yaml``)."""
    p = Path(path)
    return (p.is_file() and p.suffix.lower() in BAG_SUFFIXES) or (p.is_dir() and (p / "metadata.yaml").is_file())


def _reader(path: Path):
    """An opened rosbags AnyReader; the stock ROS 1/ROS 2 types + vision_msgs fill in what the bag
    does not define. Unreadable input -> FormatError naming the file."""
    from rosbags.highlevel import AnyReader

    default = typestore(1 if path.suffix.lower() == ".bag" else 2)
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
        w = max([len(t.topic) for t in self.topics] + [5])
        out.append(f"  {'topic':<{w}}  {'type':<36} {'count':>6} {'rate Hz':>8}")
        for t in self.topics:
            flag = "" if t.msgtype in SUPPORTED_TYPES else "  (not read by xcalib)"
            out.append(f"  {t.topic:<{w}}  {t.msgtype:<36} {t.count:>6} {t.rate_hz:>8.2f}{flag}")
        return out


def _container(path: Path) -> str:
    return {".bag": "ros1-bag", ".db3": "ros2-sqlite3", ".mcap": "mcap"}.get(path.suffix.lower(), "ros2-folder")


def bag_info(path) -> BagInfo:
    """Topics, types, counts and rates of a bag (reads every message's log time, not its data)."""
    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(f"bag not found: {p}")
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


def _messages(reader, path: Path, connections):
    """rosbags' message iterator with read errors (truncated chunk, bad compression) as FormatError."""
    it = reader.messages(connections=connections)
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


@dataclass
class _Entry:
    lidar: tuple
    image: tuple
    det3d: tuple
    det2d: tuple
    info: tuple | None
    meta: dict = field(default_factory=dict)


class BagFrames(Sequence):
    """Frames of one camera and one LiDAR from a bag (a lazy ``Sequence[Frame]``).

    Args: ``camera`` — camera name (namespace of its image topic, e.g. ``front`` for
    ``/front/image_raw``) or image topic; required when the bag has several. ``lidar`` —
    PointCloud2 topic (default: the only one). ``camera_info`` / ``detections_2d`` /
    ``detections_3d`` — topics (default: found under the camera's / LiDAR's namespace, or the only
    one of the type). ``tolerance_s`` — largest LiDAR/image stamp difference paired.
    ``intrinsics`` — used instead of CameraInfo (required when the bag has none).

    Attributes: ``report`` (:class:`PairingReport`), ``cameras`` (every :class:`BagCamera`),
    ``camera`` (the chosen one's name), ``intrinsics``, ``transforms`` (tf_static / tf edges:
    child -> (parent, T_parent_child)), ``tf_T_cam_lidar`` (the bag's own LiDAR -> camera
    transform through tf, between the cloud's and the image's header frames, or None).
    """

    def __init__(self, path, camera: str | None = None, *, lidar: str | None = None,
                 camera_info: str | None = None, detections_2d: str | None = None,
                 detections_3d: str | None = None, tolerance_s: float = 0.05,
                 intrinsics: CameraIntrinsics | None = None, fisheye: str = "rectify"):
        self.path = Path(path)
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
        self.tf_T_cam_lidar = self._tf_lookup()
        self.intrinsics = intrinsics if intrinsics is not None else (
            self._intrinsics(self._entries[0].info) if self._entries and self._entries[0].info else None)
        self.source_name = "bag"

    # ---------------------------------------------------------------- topic resolution
    def _where(self, topic: str | None) -> tuple[str, str | None]:
        return str(self.path), topic

    def _of_type(self, *types: str) -> list[str]:
        return sorted(t for t, m in self._types.items() if m in types)

    def _listing(self) -> str:
        return "; ".join(f"{t} ({m})" for t, m in sorted(self._types.items()))

    def _find_cameras(self) -> list[BagCamera]:
        found: dict[str, BagCamera] = {}
        for topic in self._of_type(IMAGE) + self._of_type(COMPRESSED):
            name, ns = _namespace(topic)
            if name in found:
                continue  # a raw Image wins over a CompressedImage of the same camera
            info = [t for t in self._of_type(CAMERA_INFO) if _under(t, ns)]
            dets = [t for t in self._of_type(DET2D) if _under(t, ns)]
            found[name] = BagCamera(name, ns, topic, info[0] if len(info) == 1 else None,
                                    dets[0] if len(dets) == 1 else None)
        return list(found.values())

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
            raise FormatError(self.path, f"no {' or '.join(types)} topic for the {what}; topics: {self._listing()}",
                              option)
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
                                        f"2D detections of camera {cam.name}", "--detections-2d", True),
            "detections_3d": self._pick(det3d, (DET3D,), lid_ns, "3D detections", "--detections-3d", True),
        }
        if topics["camera_info"] is None and intrinsics is None:
            raise FormatError(self.path, f"no CameraInfo topic for camera {cam.name} ({cam.image_topic}); pass "
                                         "--intrinsics K.json (intrinsics=)", cam.image_topic)
        return topics

    # ---------------------------------------------------------------- indexing and pairing
    def _index(self, reader) -> dict[str, list[tuple[int, object]]]:
        """Deserialise the chosen topics (+ tf, tf_static, xcalib's frame records): topic ->
        [(header stamp ns (log time when the header has none), message)] sorted by stamp."""
        wanted = {t for t in self.topics.values() if t}
        wanted |= {t for t, m in self._types.items() if m in TF_TYPES or (t == META_TOPIC and m == STRING)}
        cons = [c for c in reader.connections if c.topic in wanted]
        out: dict[str, list[tuple[int, object]]] = {t: [] for t in wanted}
        for con, t_log, raw in _messages(reader, self.path, cons):
            try:
                msg = reader.deserialize(raw, con.msgtype)
            except Exception as exc:  # noqa: BLE001 - rosbags' deserialisation errors
                raise FormatError(self.path, f"message of type {con.msgtype} does not deserialise ({exc})",
                                  con.topic) from None
            header = getattr(msg, "header", None)
            stamp = cv.stamp_ns(header) if header is not None else int(t_log)
            out[con.topic].append((stamp if stamp > 0 else int(t_log), msg))
        for v in out.values():
            v.sort(key=lambda x: x[0])
        return out

    def _pair(self, msgs) -> tuple[list[_Entry], PairingReport]:
        tp = self.topics
        lid, img = msgs[tp["lidar"]], msgs[tp["image"]]
        for key in ("lidar", "image", "detections_2d", "detections_3d"):
            if not msgs[tp[key]]:
                raise FormatError(self.path, "topic has no messages", tp[key])
        tol = int(round(self.tolerance_s * 1e9))
        l_ns, i_ns = [s for s, _ in lid], [s for s, _ in img]
        if l_ns[-1] + tol < i_ns[0] or i_ns[-1] + tol < l_ns[0]:
            raise FormatError(self.path, f"clocks do not overlap: LiDAR {tp['lidar']} stamps "
                                         f"{l_ns[0] / 1e9:.3f}-{l_ns[-1] / 1e9:.3f} s, camera {tp['image']} "
                                         f"{i_ns[0] / 1e9:.3f}-{i_ns[-1] / 1e9:.3f} s", tp["image"])
        pairs, lost_l, lost_i = pair_by_time(l_ns, i_ns, tol)
        dropped = [Dropped(tp["lidar"], l_ns[i] / 1e9, f"no image within {self.tolerance_s * 1e3:g} ms "
                                                       f"(nearest {dt / 1e6:.1f} ms)") for i, dt in lost_l.items()]
        dropped += [Dropped(tp["image"], i_ns[j] / 1e9, f"no LiDAR sweep within {self.tolerance_s * 1e3:g} ms "
                                                        f"(nearest {dt / 1e6:.1f} ms)") for j, dt in lost_i.items()]
        d3 = {s: m for s, m in msgs[tp["detections_3d"]]}
        d2 = {s: m for s, m in msgs[tp["detections_2d"]]}
        infos = msgs[tp["camera_info"]] if tp["camera_info"] else []
        meta = {}
        for _, m in msgs.get(META_TOPIC, []):
            rec = self._record(m.data)
            meta[rec["lidar_stamp_ns"]] = rec
        entries, used3, used2, max_dt = [], set(), set(), 0
        for i, j in pairs:
            (ls, lm), (is_, im) = lid[i], img[j]
            if ls not in d3:
                dropped.append(Dropped(tp["detections_3d"], ls / 1e9, "no 3D detections stamped like the sweep"))
                continue
            if is_ not in d2:
                dropped.append(Dropped(tp["detections_2d"], is_ / 1e9, "no 2D detections stamped like the image"))
                continue
            used3.add(ls)
            used2.add(is_)
            max_dt = max(max_dt, abs(ls - is_))
            info = min(infos, key=lambda x: abs(x[0] - is_)) if infos else None
            entries.append(_Entry((ls, lm), (is_, im), (ls, d3[ls]), (is_, d2[is_]), info, meta.get(ls, {})))
        dropped += [Dropped(tp["detections_3d"], s / 1e9, "no paired LiDAR sweep with this stamp")
                    for s in d3 if s not in used3]
        dropped += [Dropped(tp["detections_2d"], s / 1e9, "no paired image with this stamp")
                    for s in d2 if s not in used2]
        report = PairingReport(str(self.path), tp["lidar"], tp["image"], self.tolerance_s, len(lid), len(img),
                               len(entries), tuple(sorted(dropped, key=lambda d: (d.topic, d.stamp_s))),
                               max_dt / 1e9)
        if not entries:
            raise FormatError(self.path, "no frame could be paired: " + " / ".join(report.lines()), tp["image"])
        return entries, report

    def _record(self, text: str) -> dict:
        """One xcalib frame record (JSON), checked for the keys the frames read from it."""
        try:
            rec = json.loads(text)
        except ValueError as exc:
            raise FormatError(self.path, f"frame record is not valid JSON ({exc})", META_TOPIC) from None
        if not isinstance(rec, dict) or not isinstance(rec.get("lidar_stamp_ns"), int) \
                or not isinstance(rec.get("cameras", {}), dict):
            raise FormatError(self.path, "frame record needs an integer lidar_stamp_ns and a cameras mapping",
                              META_TOPIC)
        return rec

    # ---------------------------------------------------------------- tf
    def _tf_edges(self, msgs) -> dict[str, tuple[str, np.ndarray]]:
        edges: dict[str, tuple[str, np.ndarray]] = {}
        for topic, m in self._types.items():
            if m not in TF_TYPES:
                continue
            for _, msg in msgs.get(topic, []):
                for parent, child, T, _ in cv.transforms_from_msg(msg):
                    edges.setdefault(child, (parent, T))  # the first (static) value of each edge
        return edges

    def _root_path(self, frame: str) -> tuple[str, np.ndarray]:
        T, seen = np.eye(4), set()
        while frame in self.transforms and frame not in seen:
            seen.add(frame)
            parent, T_pc = self.transforms[frame]
            T, frame = T_pc @ T, parent
        return frame, T

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
    def _intrinsics(self, info) -> CameraIntrinsics:
        if self._fisheye_mode == "keep":  # an equidistant camera stays a kannala_brandt camera model
            m = cv.camera_model_from_msg(info[1], self._where(self.topics["camera_info"]))
            return m.camera_model if isinstance(m, cv.Fisheye) else m
        return cv.intrinsics_from_msg(info[1], self._where(self.topics["camera_info"]))

    def _fisheye(self, e: _Entry):
        """The frame's equidistant camera model when its CameraInfo has one (and no --intrinsics)."""
        if self._fixed_intrinsics is not None or e.info is None:
            return None
        m = cv.camera_model_from_msg(e.info[1], self._where(self.topics["camera_info"]))
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
        return [str(e.meta.get("frame_key", e.lidar[0])) for e in self._entries]

    def _frame(self, e: _Entry) -> Frame:
        tp = self.topics
        image = cv.image_from_msg(e.image[1], self._where(tp["image"]))
        points, fields, n_bad = cv.cloud_from_msg(e.lidar[1], self._where(tp["lidar"]))
        b2, ids2 = cv.boxes2d_from_msg(e.det2d[1])
        box7, ids3 = cv.boxes3d_from_msg(e.det3d[1], self._where(tp["detections_3d"]))
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
        with np.errstate(over="ignore"):
            b3 = _boxes3d_as_written(box7, e.meta.get("box3d_rows"))
        if not np.all(np.isfinite(b3)):
            raise FormatError(self.path, "3D boxes out of float32 range", tp["detections_3d"])
        mm = rec.get("match_matrix")
        extr = rec.get("extrinsics")
        if extr is not None:
            extr = np.asarray(extr, dtype=np.float64)
            if extr.shape != (4, 4) or not np.all(np.isfinite(extr)):
                raise FormatError(self.path, f"frame record: extrinsics must be a finite 4x4, got {extr.shape}",
                                  META_TOPIC)
        meta = {"source": "bag", "bag": str(self.path), "lidar_topic": tp["lidar"], "image_topic": tp["image"],
                "lidar_stamp_ns": e.lidar[0], "camera_stamp_ns": e.image[0], "detection_ids_2d": ids2}
        if n_bad:
            meta["points_dropped_nonfinite"] = n_bad
        if fisheye is not None:
            meta["rectified_from"] = "equidistant"
        tracks = e.meta.get("track_ids_3d")
        if tracks is None and ids3 and all(i.lstrip("-").isdigit() for i in ids3):
            tracks = [int(i) for i in ids3]
        vel = e.meta.get("velocities_3d")
        lt, ct = e.meta.get("lidar_time_s"), rec.get("camera_time_s")
        return Frame(image=image, point_cloud=points, bboxes_2d=b2, bboxes_3d=b3,
                     lidar_time_s=e.lidar[0] / 1e9 if lt is None else float(lt),
                     camera_time_s=e.image[0] / 1e9 if ct is None else float(ct),
                     track_ids_3d=None if tracks is None else np.asarray(tracks, dtype=np.int64),
                     velocities_3d=None if vel is None else np.asarray(vel, dtype=np.float64).reshape(-1, 3),
                     camera_name=str(rec.get("camera_name", self.camera)),
                     frame_key=str(e.meta.get("frame_key", e.lidar[0])),
                     match_matrix=None if mm is None else np.asarray(mm, dtype=bool).reshape(len(b2), len(b3)),
                     intrinsics=intr, extrinsics=extr,
                     point_fields=fields, meta=meta)


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
