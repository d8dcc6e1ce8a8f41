"""OpenLABEL-style calibration JSON (ASAM OpenLABEL ``coordinate_systems`` + ``streams``).

Directions: ``coordinate_systems.<cs>.pose_wrt_parent`` is the **pose of the child in its
parent** — it maps child-frame points into the parent frame (``T_parent_child``). xcalib writes
the LiDAR as the root and the camera (OpenCV optical axes) as its child, so the camera's
``pose_wrt_parent.matrix4x4`` (row-major, 16 numbers) is ``T_lidar_cam = inv(T_cam_lidar)``.
The reader walks any parent chain (e.g. LiDAR and camera both children of a ``base``) and
returns ``T_cam_lidar = inv(T_root_cam) @ T_root_lidar``. Poses may be ``matrix4x4`` or
``translation`` + ``quaternion`` (x, y, z, w). Intrinsics: ``streams.<camera>.stream_properties.
intrinsics_pinhole`` with ``camera_matrix_3x4`` (or ``camera_matrix`` 3x3/3x4, a non-zero 4th
column is folded into the translation as ``K^-1 P[:,3]``), ``distortion_coeffs_1xN`` (OpenCV order),
``width_px`` / ``height_px``.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from ..calib.result import CalibrationResult
from ..errors import FormatError
from ..geometry.camera import CameraIntrinsics
from ..geometry.rotations import matrix_to_quaternion
from ..geometry.transforms import invert_transform, make_transform
from ..io.files import atomic_write
from ._checks import as_matrix, checked_quaternion, checked_rotation, require
from ._result import calibration_record, require_intrinsics
from .calibanything import load_json

__all__ = ["openlabel_dict", "write_openlabel", "read_openlabel"]


def openlabel_dict(result: CalibrationResult, *, camera: str | None = None, lidar: str = "lidar") -> dict:
    """OpenLABEL JSON of ``result``: LiDAR root cs, camera child with ``pose_wrt_parent`` =
    ``T_lidar_cam`` (camera -> LiDAR) as ``matrix4x4`` plus the same pose as translation/quaternion."""
    intr = require_intrinsics(result, "openlabel")
    camera = camera or result.camera_name or "camera"
    T_lc = invert_transform(result.extrinsics)
    q = matrix_to_quaternion(T_lc[:3, :3])
    pinhole: dict[str, Any] = {"camera_matrix_3x4": np.hstack([intr.K, np.zeros((3, 1))]).reshape(-1).tolist(),
                               "distortion_coeffs_1xN": [] if intr.distortion is None else intr.distortion.tolist()}
    if intr.width is not None and intr.height is not None:
        pinhole = {"width_px": intr.width, "height_px": intr.height, **pinhole}
    return {"openlabel": {
        "metadata": {"schema_version": "1.0.0", "annotator": "xcalib",
                     "comment": f"pose_wrt_parent maps {camera} (OpenCV optical) points into the {lidar} frame"},
        "coordinate_systems": {
            lidar: {"type": "sensor_cs", "parent": "", "children": [camera]},
            camera: {"type": "sensor_cs", "parent": lidar, "children": [],
                     "pose_wrt_parent": {"matrix4x4": T_lc.reshape(-1).tolist(),
                                         "translation": T_lc[:3, 3].tolist(), "quaternion": q.tolist()}},
        },
        "streams": {
            camera: {"type": "camera", "uri": "", "description": "camera, OpenCV optical frame",
                     "stream_properties": {"intrinsics_pinhole": pinhole}},
            lidar: {"type": "lidar", "uri": "", "description": "LiDAR"},
        },
    }}


def write_openlabel(result: CalibrationResult, path, **kw) -> Path:
    """Write :func:`openlabel_dict` to ``path``."""
    return atomic_write(path, [(json.dumps(openlabel_dict(result, **kw), indent=2) + "\n").encode()])


def _pose(cs: dict, path, where: str, repair: bool) -> np.ndarray:
    p = cs.get("pose_wrt_parent")
    if p is None:
        return np.eye(4)
    if not isinstance(p, dict):
        raise FormatError(path, f"expected a JSON object, got {type(p).__name__}", where)
    if "matrix4x4" in p:
        M = as_matrix(p["matrix4x4"], (4, 4), path, where + ".matrix4x4")
        R = checked_rotation(M[:3, :3], path, where + ".matrix4x4", repair=repair)
        T = make_transform(R, M[:3, 3])
        if "quaternion" in p:
            Rq = checked_quaternion(p["quaternion"], path, where + ".quaternion")
            if np.abs(Rq - R).max() > 1e-6:
                raise FormatError(path, "matrix4x4 and quaternion disagree; which one is right is ambiguous",
                                  where + ".quaternion")
        return T
    if "quaternion" in p and "translation" in p:
        R = checked_quaternion(p["quaternion"], path, where + ".quaternion")
        return make_transform(R, as_matrix(p["translation"], (3,), path, where + ".translation"))
    raise FormatError(path, f"unsupported pose (keys {sorted(p)}); expected matrix4x4 or translation + quaternion",
                      where)


def _root_pose(name: str, css: dict, path, repair: bool) -> np.ndarray:
    T, seen = np.eye(4), set()
    while name:
        if name in seen:
            raise FormatError(path, f"coordinate-system parent loop through {name!r}", "coordinate_systems")
        seen.add(name)
        if name not in css:
            raise FormatError(path, f"unknown coordinate system {name!r}", "coordinate_systems")
        cs = require(css, name, path, "coordinate_systems.", kind=dict)
        T = _pose(cs, path, f"coordinate_systems.{name}.pose_wrt_parent", repair) @ T
        name = cs.get("parent", "") or ""
        if not isinstance(name, str):
            raise FormatError(path, f"parent must be a name, got {name!r:.40}", "coordinate_systems.parent")
    return T


def read_openlabel(path, *, camera: str | None = None, lidar: str | None = None,
                   repair: bool = False) -> CalibrationResult:
    """Read an OpenLABEL JSON -> ``CalibrationResult`` (``T_cam_lidar``: LiDAR -> camera). Picks the
    first camera stream with ``intrinsics_pinhole`` and the first lidar stream unless named."""
    path = Path(path)
    ol = require(load_json(path), "openlabel", path, kind=dict)
    css = require(ol, "coordinate_systems", path, "openlabel.", kind=dict)
    streams = require(ol, "streams", path, "openlabel.", kind=dict)
    for n, s in streams.items():
        require(streams, n, path, "openlabel.streams.", kind=dict)
        if not isinstance(s.get("stream_properties") or {}, dict):
            raise FormatError(path, "expected a JSON object", f"openlabel.streams.{n}.stream_properties")
    if camera is None:
        cams = [n for n, s in streams.items() if s.get("type") == "camera"
                and "intrinsics_pinhole" in (s.get("stream_properties") or {})]
        if not cams:
            raise FormatError(path, "no camera stream with stream_properties.intrinsics_pinhole", "openlabel.streams")
        camera = cams[0]
    if lidar is None:
        lids = [n for n, s in streams.items() if s.get("type") == "lidar"]
        if not lids:
            raise FormatError(path, "no stream of type 'lidar'", "openlabel.streams")
        lidar = lids[0]
    where = f"openlabel.streams.{camera}.stream_properties.intrinsics_pinhole"
    pin = (((streams.get(camera) or {}).get("stream_properties")) or {}).get("intrinsics_pinhole")
    if not isinstance(pin, dict):
        raise FormatError(path, f"expected a JSON object, got {type(pin).__name__}", where)
    raw = pin.get("camera_matrix_3x4", pin.get("camera_matrix"))
    if raw is None:
        raise FormatError(path, "missing key camera_matrix_3x4", where)
    try:
        n = np.asarray(raw, dtype=np.float64).size
    except (TypeError, ValueError):
        n = -1
    if n == 9:
        M = np.hstack([as_matrix(raw, (3, 3), path, where + ".camera_matrix"), np.zeros((3, 1))])
    else:
        M = as_matrix(raw, (3, 4), path, where + ".camera_matrix_3x4")
    K = M[:, :3]
    if abs(np.linalg.det(K)) < 1e-12:
        raise FormatError(path, f"camera matrix is singular: {K.tolist()}", where)
    off = np.linalg.solve(K, M[:, 3])
    dist = pin.get("distortion_coeffs_1xN") or None
    try:
        intr = CameraIntrinsics.from_matrix(K, dist, width=pin.get("width_px"), height=pin.get("height_px"))
    except (TypeError, ValueError) as exc:
        raise FormatError(path, str(exc), where) from None
    T_root_cam = _root_pose(camera, css, path, repair)
    T_root_lidar = _root_pose(lidar, css, path, repair)
    T = make_transform(np.eye(3), off) @ invert_transform(T_root_cam) @ T_root_lidar
    return calibration_record(intr, T, method="openlabel", camera_name=camera,
                              meta={"format": "openlabel", "lidar": lidar})
