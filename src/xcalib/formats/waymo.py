"""Waymo Open Dataset conventions and a dependency-free reader for the calibrations and labels of
``.tfrecord`` segment files (no TensorFlow / waymo-open-dataset needed).

Frames (``waymo_open_dataset/dataset.proto``):

* **vehicle** frame: x forward, y left, z up (metres). Waymo's points and 3D labels live here;
  after fusion it *is* the LiDAR frame of the KITTI-format export.
* **Waymo camera** frame: x forward (optical axis), y left, z up ("front-left-up", FLU).
* **OpenCV optical** frame (xcalib's camera frame): x right, y down, z forward.
* ``CameraCalibration.extrinsic`` is ``T_vehicle_cam``: Waymo camera (FLU) -> vehicle.
* ``LaserCalibration.extrinsic`` is ``T_vehicle_laser``: laser -> vehicle.
* ``CameraCalibration.intrinsic`` = ``[f_u, f_v, c_u, c_v, k1, k2, p1, p2, k3]`` (OpenCV model).

xcalib's extrinsics of a Waymo camera are ``T_cam_lidar = R_OPTICAL_FROM_FLU @ inv(T_vehicle_cam)``
(vehicle -> optical camera), which is exactly the spec's KITTI ``Tr_velo_to_cam =
T_front_cam_to_ref @ inv(T_front_cam_to_vehicle)`` (``T_front_cam_to_ref`` = ``R_OPTICAL_FROM_FLU``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..calib.result import CalibrationResult
from ..errors import FormatError
from ..geometry.camera import CameraIntrinsics
from ..geometry.transforms import as_transform, invert_transform, make_transform
from ..types import Frame
from ._checks import checked_rotation
from ._protowire import as_double, as_doubles, as_int, as_messages, as_string, iter_tfrecords, parse_message
from ._result import calibration_record
from .kitti import KittiCalibration

__all__ = [
    "R_OPTICAL_FROM_FLU", "CAMERA_NAMES", "LASER_NAMES", "flu_to_optical", "optical_to_flu",
    "waymo_extrinsic_to_T_cam_lidar", "T_cam_lidar_to_waymo_extrinsic", "waymo_intrinsics",
    "waymo_to_kitti_calibration", "WaymoCamera", "WaymoLaser", "WaymoFrameRecord", "read_waymo_tfrecord",
    "waymo_calibration", "waymo_T_cam_laser",
]

#: Rotation Waymo camera (front-left-up) -> OpenCV optical (right-down-front):
#: ``x_opt = -y_flu, y_opt = -z_flu, z_opt = x_flu``. Equals the spec's ``T_front_cam_to_ref``.
R_OPTICAL_FROM_FLU = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])

CAMERA_NAMES = {1: "FRONT", 2: "FRONT_LEFT", 3: "FRONT_RIGHT", 4: "SIDE_LEFT", 5: "SIDE_RIGHT"}
LASER_NAMES = {1: "TOP", 2: "FRONT", 3: "SIDE_LEFT", 4: "SIDE_RIGHT", 5: "REAR"}
LABEL_TYPES = {0: "UNKNOWN", 1: "VEHICLE", 2: "PEDESTRIAN", 3: "SIGN", 4: "CYCLIST"}


# ---------------------------------------------------------------------------- conventions
def flu_to_optical(points) -> np.ndarray:
    """Points [N,3] in a front-left-up camera frame -> the same points in OpenCV optical axes."""
    return np.asarray(points, dtype=np.float64)[:, :3] @ R_OPTICAL_FROM_FLU.T


def optical_to_flu(points) -> np.ndarray:
    """Points [N,3] in OpenCV optical axes -> front-left-up camera axes (inverse of flu_to_optical)."""
    return np.asarray(points, dtype=np.float64)[:, :3] @ R_OPTICAL_FROM_FLU


def waymo_extrinsic_to_T_cam_lidar(T_vehicle_cam) -> np.ndarray:
    """Waymo ``CameraCalibration.extrinsic`` (FLU camera -> vehicle, [4,4] or 16 numbers) ->
    xcalib ``T_cam_lidar`` (vehicle/LiDAR -> OpenCV camera) = ``R_OPTICAL_FROM_FLU @ inv(T_vehicle_cam)``."""
    T = as_transform(np.asarray(T_vehicle_cam, dtype=np.float64).reshape(4, 4), "waymo extrinsic")
    return make_transform(R_OPTICAL_FROM_FLU, np.zeros(3)) @ invert_transform(T)


def T_cam_lidar_to_waymo_extrinsic(T_cam_lidar) -> np.ndarray:
    """Inverse of :func:`waymo_extrinsic_to_T_cam_lidar`: ``T_cam_lidar`` -> ``T_vehicle_cam`` (FLU)."""
    T_flu_vehicle = make_transform(R_OPTICAL_FROM_FLU.T, np.zeros(3)) @ as_transform(T_cam_lidar)
    return invert_transform(T_flu_vehicle)


def waymo_intrinsics(intrinsic, width: int | None = None, height: int | None = None) -> CameraIntrinsics:
    """``[f_u, f_v, c_u, c_v, k1, k2, p1, p2, k3]`` (pixels) -> ``CameraIntrinsics`` (OpenCV k1 k2 p1 p2 k3)."""
    v = np.asarray(intrinsic, dtype=np.float64).reshape(-1)
    if v.size not in (4, 9):
        raise ValueError(f"waymo intrinsic: expected 9 numbers [f_u, f_v, c_u, c_v, k1, k2, p1, p2, k3], got {v.size}")
    dist = v[4:9] if v.size == 9 else None
    return CameraIntrinsics(v[0], v[1], v[2], v[3], dist, width, height)


def waymo_to_kitti_calibration(T_vehicle_front_cam, intrinsic) -> KittiCalibration:
    """The spec's Waymo -> KITTI mapping of the FRONT camera: ``P2`` = intrinsics (K with a zero
    4th column), ``P0``, ``P1``, ``P3`` = ``[I | 0]`` placeholders, ``R0_rect`` = I and
    ``Tr_velo_to_cam = T_front_cam_to_ref @ inv(T_front_cam_to_vehicle)`` (vehicle -> optical)."""
    K = waymo_intrinsics(intrinsic).K
    dummy = np.hstack([np.eye(3), np.zeros((3, 1))])
    P = {0: dummy.copy(), 1: dummy.copy(), 2: np.hstack([K, np.zeros((3, 1))]), 3: dummy.copy()}
    return KittiCalibration(P=P, R0_rect=np.eye(3), Tr_velo_to_cam=waymo_extrinsic_to_T_cam_lidar(T_vehicle_front_cam))


# ------------------------------------------------------------------------------ tfrecords
@dataclass
class WaymoCamera:
    """One ``CameraCalibration``: ``T_vehicle_cam`` [4,4] (FLU camera -> vehicle), ``intrinsic``
    [9], image size in pixels, rolling-shutter read-out direction (enum value)."""

    name: str
    intrinsic: np.ndarray
    T_vehicle_cam: np.ndarray
    width: int | None
    height: int | None
    rolling_shutter_direction: int | None = None

    @property
    def intrinsics(self) -> CameraIntrinsics:
        return waymo_intrinsics(self.intrinsic, self.width, self.height)

    @property
    def T_cam_lidar(self) -> np.ndarray:
        """[4,4] vehicle (= fused LiDAR) frame -> OpenCV camera."""
        return waymo_extrinsic_to_T_cam_lidar(self.T_vehicle_cam)


@dataclass
class WaymoLaser:
    """One ``LaserCalibration``: ``T_vehicle_laser`` [4,4] (laser -> vehicle)."""

    name: str
    T_vehicle_laser: np.ndarray
    beam_inclination_min: float | None = None
    beam_inclination_max: float | None = None


@dataclass
class WaymoFrameRecord:
    """Calibrations and labels of one Waymo ``Frame`` record.

    ``boxes7`` [M,7] laser labels in the vehicle frame (cx, cy, cz, length, width, height,
    heading rad) with ``box_types`` / ``box_ids``; ``camera_boxes`` {camera: [K,4] x1 y1 x2 y2
    pixels} from ``projected_lidar_labels`` with ``camera_box_ids`` (the laser id + ``_<CAMERA>``).
    """

    context_name: str
    timestamp_micros: int | None
    T_global_vehicle: np.ndarray | None
    cameras: dict[str, WaymoCamera]
    lasers: dict[str, WaymoLaser]
    boxes7: np.ndarray
    box_types: list[str]
    box_ids: list[str]
    camera_boxes: dict[str, np.ndarray] = field(default_factory=dict)
    camera_box_ids: dict[str, list[str]] = field(default_factory=dict)

    def match_matrix(self, camera: str = "FRONT") -> np.ndarray:
        """[K,M] bool: projected 2D label k of ``camera`` comes from laser label m."""
        ids = self.camera_box_ids.get(camera, [])
        col = {bid: j for j, bid in enumerate(self.box_ids)}
        mm = np.zeros((len(ids), len(self.box_ids)), dtype=bool)
        for i, pid in enumerate(ids):
            base = pid[: -len(camera) - 1] if pid.endswith("_" + camera) else pid
            if base in col:
                mm[i, col[base]] = True
        return mm


def _transform(msg, field_no: int, path, what: str) -> np.ndarray | None:
    subs = as_messages(msg, field_no)
    if not subs:
        return None
    vals = as_doubles(subs[0], 1)
    if len(vals) != 16:
        raise FormatError(path, f"expected a 4x4 transform (16 doubles), got {len(vals)}", what)
    T = np.asarray(vals).reshape(4, 4)
    checked_rotation(T[:3, :3], path, what)
    return T


def _box(b: dict) -> list[float]:
    return [as_double(b, k, 0.0) for k in (1, 2, 3, 5, 4, 6, 7)]  # cx cy cz length width height heading


def _parse_frame(buf: bytes, path, index: int) -> WaymoFrameRecord:
    f = parse_message(buf)
    ctxs = as_messages(f, 1)
    if not ctxs:
        raise FormatError(path, f"record {index}: no context (not a waymo Frame?)", "Frame.context")
    ctx = ctxs[0]
    cams: dict[str, WaymoCamera] = {}
    for c in as_messages(ctx, 2):
        n = CAMERA_NAMES.get(as_int(c, 1, 0), f"CAMERA_{as_int(c, 1, 0)}")
        intr = np.asarray(as_doubles(c, 2))
        T = _transform(c, 3, path, f"context.camera_calibrations[{n}].extrinsic")
        if T is None or intr.size < 4:
            raise FormatError(path, f"camera {n}: missing intrinsic or extrinsic", f"context.camera_calibrations[{n}]")
        cams[n] = WaymoCamera(n, intr, T, as_int(c, 4), as_int(c, 5), as_int(c, 6))
    lasers: dict[str, WaymoLaser] = {}
    for c in as_messages(ctx, 3):
        n = LASER_NAMES.get(as_int(c, 1, 0), f"LASER_{as_int(c, 1, 0)}")
        T = _transform(c, 5, path, f"context.laser_calibrations[{n}].extrinsic")
        lasers[n] = WaymoLaser(n, np.eye(4) if T is None else T, as_double(c, 3), as_double(c, 4))
    boxes, types, ids = [], [], []
    for lab in as_messages(f, 6):
        b = as_messages(lab, 1)
        if not b:
            continue
        boxes.append(_box(b[0]))
        types.append(LABEL_TYPES.get(as_int(lab, 3, 0), "UNKNOWN"))
        ids.append(as_string(lab, 4))
    cam_boxes, cam_ids = {}, {}
    for cl in as_messages(f, 9):
        n = CAMERA_NAMES.get(as_int(cl, 1, 0), f"CAMERA_{as_int(cl, 1, 0)}")
        rows, rid = [], []
        for lab in as_messages(cl, 2):
            b = as_messages(lab, 1)
            if not b:
                continue
            cx, cy, _, length, width, _, _ = _box(b[0])  # image boxes: length = x size, width = y size
            rows.append([cx - length / 2, cy - width / 2, cx + length / 2, cy + width / 2])
            rid.append(as_string(lab, 4))
        cam_boxes[n] = np.asarray(rows, dtype=np.float64).reshape(-1, 4)
        cam_ids[n] = rid
    return WaymoFrameRecord(
        context_name=as_string(ctx, 1), timestamp_micros=as_int(f, 2),
        T_global_vehicle=_transform(f, 3, path, "Frame.pose"), cameras=cams, lasers=lasers,
        boxes7=np.asarray(boxes, dtype=np.float64).reshape(-1, 7), box_types=types, box_ids=ids,
        camera_boxes=cam_boxes, camera_box_ids=cam_ids)


def read_waymo_tfrecord(path, max_frames: int | None = None) -> list[WaymoFrameRecord]:
    """Calibrations and labels of every ``Frame`` in a Waymo segment ``.tfrecord`` (images and
    range images are skipped). FormatError naming the file and field on malformed input."""
    out = []
    for i, rec in enumerate(iter_tfrecords(path)):
        if max_frames is not None and i >= max_frames:
            break
        try:
            out.append(_parse_frame(rec, path, i))
        except ValueError as exc:
            if isinstance(exc, FormatError):
                raise
            raise FormatError(path, f"record {i}: malformed protobuf ({exc})") from None
    if not out:
        raise FormatError(path, "no records")
    return out


def waymo_calibration(record: WaymoFrameRecord, camera: str = "FRONT") -> CalibrationResult:
    """``CalibrationResult`` of one camera: ``T_cam_lidar`` = vehicle -> OpenCV camera."""
    if camera not in record.cameras:
        raise KeyError(f"waymo frame has no camera {camera!r}; cameras: {sorted(record.cameras)}")
    cam = record.cameras[camera]
    return calibration_record(cam.intrinsics, cam.T_cam_lidar, method="waymo", camera_name=camera,
                              meta={"format": "waymo", "context_name": record.context_name,
                                    "T_vehicle_cam_flu": cam.T_vehicle_cam.tolist()})


def waymo_T_cam_laser(record: WaymoFrameRecord, camera: str = "FRONT", laser: str = "TOP") -> np.ndarray:
    """[4,4] ``T_cam_laser``: points in one laser's own frame -> OpenCV camera,
    ``T_cam_vehicle @ T_vehicle_laser`` (Waymo's released points are already in the vehicle frame;
    use this only for raw, per-laser points)."""
    if camera not in record.cameras or laser not in record.lasers:
        raise KeyError(f"waymo frame: need camera {camera!r} and laser {laser!r}; have cameras "
                       f"{sorted(record.cameras)}, lasers {sorted(record.lasers)}")
    return record.cameras[camera].T_cam_lidar @ record.lasers[laser].T_vehicle_laser


class WaymoFrames(Sequence):
    """A Waymo segment ``.tfrecord`` as frames of one camera: labels and calibration only (the
    reader skips pixels and range images): an empty image [0,0,3] and cloud [0,3], the camera's
    projected 2D labels, the laser labels (box7, vehicle frame), their match matrix, intrinsics and
    ``extrinsics`` = ``T_cam_lidar`` (vehicle -> camera)."""

    def __init__(self, path, camera: str | None = None, *, max_frames: int | None = None):
        self.path = Path(path)
        self.records = read_waymo_tfrecord(self.path, max_frames=max_frames)
        self.camera = camera or "FRONT"
        self.camera_names = sorted(self.records[0].cameras)
        self._track_int = {u: i for i, u in enumerate(sorted({u for r in self.records for u in r.box_ids}))}
        if self.camera not in self.records[0].cameras:
            raise FormatError(self.path, f"no camera {self.camera!r}; cameras: {self.camera_names}",
                              "context.camera_calibrations")

    def __len__(self) -> int:
        return len(self.records)

    def __getitem__(self, index):
        if isinstance(index, slice):
            return [self[i] for i in range(*index.indices(len(self)))]
        rec = self.records[index]
        cam = rec.cameras[self.camera]
        b2 = rec.camera_boxes.get(self.camera, np.zeros((0, 4)))
        return Frame(image=np.zeros((0, 0, 3), dtype=np.uint8), point_cloud=np.zeros((0, 3), dtype=np.float32),
                     bboxes_2d=np.asarray(b2, dtype=np.float32).reshape(-1, 4),
                     bboxes_3d=np.asarray(rec.boxes7, dtype=np.float32).reshape(-1, 7),
                     camera_name=self.camera, frame_key=f"{rec.context_name}/{rec.timestamp_micros}",
                     match_matrix=rec.match_matrix(self.camera), intrinsics=cam.intrinsics,
                     extrinsics=cam.T_cam_lidar, meta={"source": "waymo", "classes_3d": list(rec.box_types)},
                     lidar_time_s=None if rec.timestamp_micros is None else rec.timestamp_micros * 1e-6,
                     track_ids_3d=np.array([self._track_int[u] for u in rec.box_ids], dtype=np.int64)
                     if len(rec.box_ids) == len(rec.boxes7) else None)


def _register() -> None:
    from ..io.sources import register_source

    register_source("waymo", lambda p: p.is_file() and ".tfrecord" in p.name.lower(), WaymoFrames,
                    description="Waymo segment .tfrecord (labels + calibration; no pixels)", priority=70)


_register()
