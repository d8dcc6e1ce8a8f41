"""nuScenes-schema calibration (``calibrated_sensor.json``, also used by Lyft Level 5).

A ``calibrated_sensor`` record holds ``translation`` [3] metres and ``rotation`` [4] as a
**(w, x, y, z)** quaternion describing the **sensor -> ego** transform ``T_ego_sensor`` (the
sensor's pose in the ego/vehicle frame). Camera records also carry ``camera_intrinsic`` [3,3]
and use OpenCV optical axes; LiDAR records have an empty ``camera_intrinsic``.

xcalib's extrinsics of a camera against a LiDAR (same ego pose):
``T_cam_lidar = inv(T_ego_cam) @ T_ego_lidar``; with two ego poses (``ego_pose`` records,
ego -> global) ``T_cam_lidar = inv(T_ego_cam) @ inv(T_global_ego_cam) @ T_global_ego_lidar @ T_ego_lidar``.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..calib.result import CalibrationResult
from ..errors import FormatError
from ..geometry.camera import CameraIntrinsics
from ..geometry.rotations import matrix_to_quaternion
from ..geometry.transforms import as_transform, invert_transform, make_transform
from ..io.files import atomic_write
from ._checks import as_matrix, checked_quaternion, require
from ._result import calibration_record, require_intrinsics
from .calibanything import load_json

__all__ = ["calibrated_sensor_to_T", "T_to_calibrated_sensor", "nuscenes_T_cam_lidar",
           "camera_record_from_T_cam_lidar", "NuScenesSensor", "read_nuscenes_sensors",
           "read_calibrated_sensor_json", "write_calibrated_sensor_json", "nuscenes_calibration"]


def calibrated_sensor_to_T(record: dict, path=None, where: str = "calibrated_sensor") -> np.ndarray:
    """``{translation, rotation (w,x,y,z)}`` -> ``T_ego_sensor`` [4,4] (sensor -> ego)."""
    t = as_matrix(require(record, "translation", path, where + "."), (3,), path, where + ".translation")
    q = as_matrix(require(record, "rotation", path, where + "."), (4,), path, where + ".rotation")
    norm = float(np.linalg.norm(q))
    if norm > 1e-9 and abs(norm - 1.0) > 1e-3:
        raise FormatError(path, f"quaternion (w, x, y, z) norm is {norm:.6f}, expected 1", where + ".rotation")
    return make_transform(checked_quaternion(q, path, where + ".rotation", order="wxyz"), t)


def T_to_calibrated_sensor(T_ego_sensor, intrinsics: CameraIntrinsics | None = None, *,
                           sensor_token: str = "", token: str = "") -> dict[str, Any]:
    """``T_ego_sensor`` [4,4] (sensor -> ego) -> a ``calibrated_sensor`` record (w, x, y, z)."""
    T = as_transform(T_ego_sensor, "T_ego_sensor")
    q = matrix_to_quaternion(T[:3, :3], order="wxyz")
    return {"token": token, "sensor_token": sensor_token, "translation": T[:3, 3].tolist(),
            "rotation": q.tolist(), "camera_intrinsic": [] if intrinsics is None else intrinsics.K.tolist()}


def nuscenes_T_cam_lidar(cam_record: dict, lidar_record: dict, ego_pose_cam: dict | None = None,
                         ego_pose_lidar: dict | None = None) -> np.ndarray:
    """``T_cam_lidar`` [4,4] (LiDAR -> camera) from the two ``calibrated_sensor`` records (and, when
    the sensors were captured at different ego poses, their ``ego_pose`` records, ego -> global)."""
    T_ego_cam = calibrated_sensor_to_T(cam_record, where="camera")
    T_ego_lidar = calibrated_sensor_to_T(lidar_record, where="lidar")
    mid = np.eye(4)
    if ego_pose_cam is not None and ego_pose_lidar is not None:
        mid = invert_transform(calibrated_sensor_to_T(ego_pose_cam, where="ego_pose_cam")) @ \
            calibrated_sensor_to_T(ego_pose_lidar, where="ego_pose_lidar")
    return invert_transform(T_ego_cam) @ mid @ T_ego_lidar


def camera_record_from_T_cam_lidar(T_cam_lidar, lidar_record: dict, intrinsics: CameraIntrinsics | None = None,
                                   **kw) -> dict[str, Any]:
    """Camera ``calibrated_sensor`` record with ``T_ego_cam = T_ego_lidar @ inv(T_cam_lidar)``."""
    T_ego_cam = calibrated_sensor_to_T(lidar_record, where="lidar") @ invert_transform(T_cam_lidar)
    return T_to_calibrated_sensor(T_ego_cam, intrinsics, **kw)


@dataclass
class NuScenesSensor:
    """One calibrated sensor: ``channel`` (e.g. CAM_FRONT), ``modality``, ``T_ego_sensor`` [4,4]
    (sensor -> ego) and, for cameras, intrinsics (pixels)."""

    channel: str
    modality: str
    T_ego_sensor: np.ndarray
    intrinsics: CameraIntrinsics | None
    token: str
    record: dict


def _intrinsics(rec: dict, path, where: str) -> CameraIntrinsics | None:
    Kd = rec.get("camera_intrinsic") or []
    if not isinstance(Kd, list):
        raise FormatError(path, f"expected [] or a 3x3 nested list, got {Kd!r:.40}", where + ".camera_intrinsic")
    if len(Kd) == 0:
        return None
    K = as_matrix(Kd, (3, 3), path, where + ".camera_intrinsic")
    try:
        return CameraIntrinsics.from_matrix(K)
    except (TypeError, ValueError) as exc:
        raise FormatError(path, str(exc), where + ".camera_intrinsic") from None


def read_nuscenes_sensors(table_dir) -> dict[str, NuScenesSensor]:
    """``{channel: NuScenesSensor}`` from a nuScenes/Lyft table folder (``calibrated_sensor.json``
    + ``sensor.json``). When a channel has several calibrations the first is kept."""
    table_dir = Path(table_dir)
    cs_path, s_path = table_dir / "calibrated_sensor.json", table_dir / "sensor.json"
    cs, sensors = load_json(cs_path), load_json(s_path)
    if not isinstance(cs, list) or not isinstance(sensors, list):
        raise FormatError(cs_path, "expected JSON lists of records (calibrated_sensor.json, sensor.json)")
    by_token = {s.get("token"): s for s in sensors if isinstance(s, dict) and isinstance(s.get("token"), str)}
    out: dict[str, NuScenesSensor] = {}
    for i, rec in enumerate(cs):
        where = f"[{i}]"
        st = require(rec, "sensor_token", cs_path, where + ".")
        if not isinstance(st, str) or st not in by_token:
            raise FormatError(cs_path, f"sensor_token {st!r} not found in {s_path.name}", where + ".sensor_token")
        s = by_token[st]
        ch = str(s.get("channel", st))
        if ch in out:
            continue
        out[ch] = NuScenesSensor(ch, str(s.get("modality", "")), calibrated_sensor_to_T(rec, cs_path, where),
                                 _intrinsics(rec, cs_path, where), str(rec.get("token", "")), rec)
    return out


def nuscenes_calibration(table_dir, camera: str = "CAM_FRONT", lidar: str | None = None) -> CalibrationResult:
    """``CalibrationResult`` (``T_cam_lidar``: LiDAR -> camera) of one camera against a LiDAR
    (default ``LIDAR_TOP``, else the first lidar channel) from a nuScenes/Lyft table folder."""
    sensors = read_nuscenes_sensors(table_dir)
    if camera not in sensors:
        raise KeyError(f"{table_dir}: no channel {camera!r}; channels: {sorted(sensors)}")
    if lidar is None:
        lidars = [c for c, s in sensors.items() if s.modality == "lidar"]
        lidar = "LIDAR_TOP" if "LIDAR_TOP" in lidars else (lidars[0] if lidars else None)
    if lidar is None or lidar not in sensors:
        raise KeyError(f"{table_dir}: no lidar channel {lidar!r}; channels: {sorted(sensors)}")
    cam, lid = sensors[camera], sensors[lidar]
    T = invert_transform(cam.T_ego_sensor) @ lid.T_ego_sensor
    return calibration_record(cam.intrinsics, T, method="nuscenes", camera_name=camera,
                              meta={"format": "nuscenes", "lidar": lidar, "T_ego_lidar": lid.T_ego_sensor.tolist()})


def write_calibrated_sensor_json(result: CalibrationResult, path, *, T_ego_lidar=None,
                                 lidar_channel: str = "LIDAR_TOP") -> Path:
    """Write ``calibrated_sensor.json`` (two records: LiDAR, then camera) + ``sensor.json`` next
    to it. The ego frame is the LiDAR frame unless ``T_ego_lidar`` [4,4] (LiDAR -> ego) is given
    (default: ``result.meta["T_ego_lidar"]`` when present)."""
    intr = require_intrinsics(result, "calibrated_sensor.json")
    if T_ego_lidar is None:
        T_ego_lidar = result.meta.get("T_ego_lidar", np.eye(4))
    cam_ch = result.camera_name or "CAM_FRONT"
    lidar_rec = T_to_calibrated_sensor(np.asarray(T_ego_lidar, dtype=np.float64), sensor_token="sensor-lidar",
                                       token="calib-lidar")
    cam_rec = camera_record_from_T_cam_lidar(result.extrinsics, lidar_rec, intr, sensor_token="sensor-camera",
                                             token="calib-camera")
    path = Path(path)
    atomic_write(path.parent / "sensor.json", [(json.dumps([
        {"token": "sensor-lidar", "channel": lidar_channel, "modality": "lidar"},
        {"token": "sensor-camera", "channel": cam_ch, "modality": "camera"}], indent=2) + "\n").encode()])
    return atomic_write(path, [(json.dumps([lidar_rec, cam_rec], indent=2) + "\n").encode()])


def read_calibrated_sensor_json(path) -> CalibrationResult:
    """Read a ``calibrated_sensor.json``: with ``sensor.json`` next to it via
    :func:`nuscenes_calibration` (first camera channel, CAM_FRONT preferred); without it the file
    must hold exactly one camera record (non-empty ``camera_intrinsic``) and one LiDAR record."""
    path = Path(path)
    if (path.parent / "sensor.json").is_file() and path.name == "calibrated_sensor.json":
        sensors = read_nuscenes_sensors(path.parent)
        cams = [c for c, s in sensors.items() if s.modality == "camera"]
        if not cams:
            raise FormatError(path, "no camera channel")
        return nuscenes_calibration(path.parent, "CAM_FRONT" if "CAM_FRONT" in cams else cams[0])
    recs = load_json(path)
    if not isinstance(recs, list):
        raise FormatError(path, "expected a JSON list of calibrated_sensor records")
    cams = [r for r in recs if isinstance(r, dict) and r.get("camera_intrinsic")]
    lids = [r for r in recs if isinstance(r, dict) and not r.get("camera_intrinsic")]
    if len(cams) != 1 or len(lids) != 1:
        raise FormatError(path, f"expected one camera and one LiDAR record without sensor.json, got "
                                f"{len(cams)} camera and {len(lids)} other records")
    T_ego_cam = calibrated_sensor_to_T(cams[0], path, "camera")
    T_ego_lidar = calibrated_sensor_to_T(lids[0], path, "lidar")
    return calibration_record(_intrinsics(cams[0], path, "camera"), invert_transform(T_ego_cam) @ T_ego_lidar,
                              method="nuscenes", meta={"format": "nuscenes", "T_ego_lidar": T_ego_lidar.tolist()})
