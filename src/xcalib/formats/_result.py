"""Building the ``CalibrationResult`` every calibration reader returns, and reading it back."""

from __future__ import annotations

from typing import Any

import numpy as np

from ..calib.result import CalibrationResult
from ..geometry.camera import CameraIntrinsics
from ..geometry.transforms import as_transform

__all__ = ["calibration_record", "require_intrinsics", "opencv_distortion", "split_opencv_distortion"]

_DIST_NAMES = ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6")


def calibration_record(intrinsics: CameraIntrinsics | None, T_cam_lidar, *, method: str, camera_name: str = "",
                       message: str = "", meta: dict[str, Any] | None = None) -> CalibrationResult:
    """A successful ``CalibrationResult`` holding ``T_cam_lidar`` [4,4] (LiDAR -> OpenCV camera)."""
    T = as_transform(T_cam_lidar, "T_cam_lidar")
    size = None
    if intrinsics is not None and intrinsics.width is not None and intrinsics.height is not None:
        size = (intrinsics.width, intrinsics.height)
    return CalibrationResult(success=True, intrinsics=intrinsics, rotation=T[:3, :3], translation=T[:3, 3],
                             camera_name=camera_name, image_size=size, method=method, message=message,
                             meta=dict(meta or {}))


def require_intrinsics(result: CalibrationResult, fmt: str) -> CameraIntrinsics:
    """The result's intrinsics, or a ValueError saying the format needs them."""
    if result.intrinsics is None:
        raise ValueError(f"{fmt}: the calibration has no camera intrinsics; this format stores K "
                         "(give the intrinsics, e.g. CalibrationResult(intrinsics=...))")
    return result.intrinsics


def opencv_distortion(named: dict[str, float]) -> np.ndarray | None:
    """{k1,k2,p1,p2,k3,k4,k5,k6} (missing = 0) -> OpenCV vector of 4, 5 or 8 (None if all zero)."""
    d = np.array([float(named.get(k, 0.0)) for k in _DIST_NAMES])
    if not np.any(d):
        return None
    if np.any(d[5:]):
        return d
    return d[:5] if d[4] else d[:4]


def split_opencv_distortion(intr: CameraIntrinsics | None) -> dict[str, float]:
    """OpenCV distortion of ``intr`` -> {k1,k2,p1,p2,k3,k4,k5,k6} (zeros where absent)."""
    out = dict.fromkeys(_DIST_NAMES, 0.0)
    if intr is not None and intr.distortion is not None:
        d = np.asarray(intr.distortion, dtype=np.float64).reshape(-1)
        if d.size > 8 and np.any(d[8:]):
            raise ValueError(f"distortion has {d.size} coefficients with thin-prism/tilt terms; "
                             "this format stores k1-k6, p1, p2 only")
        for name, v in zip(_DIST_NAMES, d[:8]):
            out[name] = float(v)
    return out
