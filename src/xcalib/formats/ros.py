"""ROS calibration files: ``camera_info`` YAML (camera_calibration_parsers layout) and a static
transform YAML for tf2.

Directions: the static transform follows tf2 — ``parent_frame`` (``header.frame_id``) is the
LiDAR frame, ``child_frame`` the camera's **optical** frame (REP 103 ``*_optical_frame``: x right,
y down, z forward), and translation + rotation (x, y, z, w) are the child's pose in the parent,
i.e. ``T_lidar_cam = inv(T_cam_lidar)`` mapping camera points into the LiDAR frame (what
``static_transform_publisher --frame-id lidar --child-frame-id camera_optical`` expects).
``write_ros`` writes ``<path>`` (camera_info) and ``<stem>_tf.yaml`` next to it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ..calib.result import CalibrationResult
from ..errors import FormatError
from ..geometry.camera import CameraIntrinsics
from ..geometry.rotations import matrix_to_quaternion
from ..geometry.transforms import invert_transform, make_transform
from ..io._files import MAX_TEXT_BYTES, atomic_write, read_text
from ._checks import as_float, as_matrix, checked_quaternion, require
from ._result import calibration_record, require_intrinsics

__all__ = ["camera_info_dict", "static_transform_dict", "write_ros", "read_ros", "read_camera_info",
           "read_static_transform", "tf_path_for"]


def _yaml():
    import yaml

    return yaml


def _mat(rows: int, cols: int, data) -> dict:
    return {"rows": rows, "cols": cols, "data": [float(v) for v in np.asarray(data).reshape(-1)]}


def camera_info_dict(intr: CameraIntrinsics, camera_name: str = "camera") -> dict[str, Any]:
    """``camera_info`` YAML content (distortion model plumb_bob for <= 5 coefficients, else
    rational_polynomial)."""
    d = np.zeros(5) if intr.distortion is None else np.asarray(intr.distortion, dtype=np.float64)
    if d.size < 5:
        d = np.concatenate([d, np.zeros(5 - d.size)])
    model = "plumb_bob" if d.size == 5 else "rational_polynomial"
    out: dict[str, Any] = {}
    if intr.width is not None and intr.height is not None:
        out.update(image_width=intr.width, image_height=intr.height)
    out.update(camera_name=camera_name, camera_matrix=_mat(3, 3, intr.K), distortion_model=model,
               distortion_coefficients=_mat(1, d.size, d), rectification_matrix=_mat(3, 3, np.eye(3)),
               projection_matrix=_mat(3, 4, np.hstack([intr.K, np.zeros((3, 1))])))
    return out


def static_transform_dict(T_cam_lidar, parent_frame: str = "lidar", child_frame: str = "camera_optical") -> dict:
    """Static transform YAML content: the pose of ``child_frame`` (camera, optical) in
    ``parent_frame`` (LiDAR), ``T_lidar_cam = inv(T_cam_lidar)``, plus the equivalent command."""
    T = invert_transform(T_cam_lidar)
    t, q = T[:3, 3], matrix_to_quaternion(T[:3, :3])
    args = (f"--x {t[0]!r} --y {t[1]!r} --z {t[2]!r} --qx {q[0]!r} --qy {q[1]!r} --qz {q[2]!r} --qw {q[3]!r} "
            f"--frame-id {parent_frame} --child-frame-id {child_frame}")
    return {"header": {"frame_id": parent_frame}, "child_frame_id": child_frame,
            "transform": {"translation": {"x": float(t[0]), "y": float(t[1]), "z": float(t[2])},
                          "rotation": {"x": float(q[0]), "y": float(q[1]), "z": float(q[2]), "w": float(q[3])}},
            "comment": f"pose of {child_frame} in {parent_frame}: maps {child_frame} points into {parent_frame}",
            "command": f"ros2 run tf2_ros static_transform_publisher {args}"}


def tf_path_for(path) -> Path:
    """``<stem>_tf.yaml`` next to a camera_info YAML."""
    p = Path(path)
    return p.with_name(p.stem + "_tf.yaml")


def write_ros(result: CalibrationResult, path, *, parent_frame: str = "lidar",
              child_frame: str | None = None) -> tuple[Path, Path]:
    """Write ``camera_info`` YAML to ``path`` and the static transform to ``<stem>_tf.yaml``."""
    intr = require_intrinsics(result, "ros camera_info")
    name = result.camera_name or "camera"
    child = child_frame or f"{name}_optical"
    yaml = _yaml()
    path = Path(path)
    tf = tf_path_for(path)
    info = yaml.safe_dump(camera_info_dict(intr, name), sort_keys=False).encode()
    tfy = yaml.safe_dump(static_transform_dict(result.extrinsics, parent_frame, child), sort_keys=False).encode()
    atomic_write(tf, [tfy])
    atomic_write(path, [info])
    return path, tf


def _load_yaml(path: Path) -> dict:
    if not path.is_file():
        raise FileNotFoundError(f"ROS YAML file not found: {path}")
    yaml = _yaml()
    try:
        d = yaml.safe_load(read_text(path, max_bytes=MAX_TEXT_BYTES, what="YAML file"))
    except (yaml.YAMLError, RecursionError, ValueError, TypeError) as exc:
        if isinstance(exc, FormatError):
            raise
        raise FormatError(path, f"not valid YAML ({type(exc).__name__}: {str(exc)[:200]})") from None
    if not isinstance(d, dict):
        raise FormatError(path, f"expected a YAML mapping, got {type(d).__name__}")
    return d


def read_camera_info(path) -> CameraIntrinsics:
    """Intrinsics from a ``camera_info`` YAML (camera_matrix; a non-trivial rectification is refused)."""
    path = Path(path)
    d = _load_yaml(path)
    K = as_matrix(require(require(d, "camera_matrix", path), "data", path, "camera_matrix."), (3, 3), path,
                  "camera_matrix.data")
    dist = None
    if "distortion_coefficients" in d:
        raw = require(d["distortion_coefficients"], "data", path, "distortion_coefficients.")
        try:
            dist = np.asarray(raw, dtype=np.float64).reshape(-1)
        except (TypeError, ValueError):
            raise FormatError(path, f"expected a list of numbers, got {raw!r:.60}",
                              "distortion_coefficients.data") from None
        model = str(d.get("distortion_model", "plumb_bob"))
        if model not in ("plumb_bob", "rational_polynomial"):
            raise FormatError(path, f"unsupported distortion_model {model!r} (plumb_bob or rational_polynomial)",
                              "distortion_model")
    if "rectification_matrix" in d:
        Rr = as_matrix(require(d["rectification_matrix"], "data", path, "rectification_matrix."), (3, 3), path,
                       "rectification_matrix.data")
        if np.abs(Rr - np.eye(3)).max() > 1e-9:
            raise FormatError(path, "rectification_matrix is not identity (stereo-rectified camera_info is "
                                    "not a plain LiDAR->camera calibration)", "rectification_matrix")
    try:
        return CameraIntrinsics.from_matrix(K, dist, width=d.get("image_width"), height=d.get("image_height"))
    except (TypeError, ValueError) as exc:
        raise FormatError(path, str(exc), "camera_matrix") from None


def read_static_transform(path) -> tuple[np.ndarray, str, str]:
    """``(T_parent_child [4,4], parent_frame, child_frame)`` from a static transform YAML."""
    path = Path(path)
    d = _load_yaml(path)
    tr = require(d, "transform", path)
    t = require(tr, "translation", path, "transform.")
    r = require(tr, "rotation", path, "transform.")
    tv = [as_float(require(t, k, path, "transform.translation."), path, f"transform.translation.{k}") for k in "xyz"]
    qv = [as_float(require(r, k, path, "transform.rotation."), path, f"transform.rotation.{k}") for k in "xyzw"]
    norm = float(np.linalg.norm(qv))
    if norm > 1e-9 and abs(norm - 1.0) > 1e-3:
        raise FormatError(path, f"rotation quaternion norm is {norm:.6f}, expected 1", "transform.rotation")
    R = checked_quaternion(qv, path, "transform.rotation")
    header = d.get("header") or {}
    if not isinstance(header, dict):
        raise FormatError(path, f"expected a mapping, got {type(header).__name__}", "header")
    parent = str(header.get("frame_id", ""))
    return make_transform(R, tv), parent, str(d.get("child_frame_id", ""))


def read_ros(path, tf_path=None) -> CalibrationResult:
    """camera_info YAML + its ``<stem>_tf.yaml`` -> ``CalibrationResult`` (``T_cam_lidar`` =
    inv(pose of the camera optical frame in the LiDAR frame))."""
    path = Path(path)
    intr = read_camera_info(path)
    tf = Path(tf_path) if tf_path is not None else tf_path_for(path)
    if not tf.is_file():
        raise FormatError(path, f"no static transform file {tf.name} next to the camera_info YAML")
    T_parent_child, parent, child = read_static_transform(tf)
    name = str(_load_yaml(path).get("camera_name", ""))
    return calibration_record(intr, invert_transform(T_parent_child), method="ros", camera_name=name,
                              meta={"format": "ros", "parent_frame": parent, "child_frame": child})
