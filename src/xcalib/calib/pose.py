"""``Pose``: one camera<-LiDAR pose (``X_cam = R X_lidar + t``) and its one parser.

Every place that accepts a pose (``calibrate(prior=...)``, ``derive_matches``, reports) calls
:meth:`Pose.parse`, which takes a ``CalibrationResult`` (anything with ``rotation`` and
``translation``), an ``(R, t)`` pair, a [4,4] or [3,4] ``T_cam_lidar`` or a ``Pose``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from ..geometry.rotations import so3_exp

__all__ = ["Pose"]


@dataclass(frozen=True)
class Pose:
    """R [3,3] (LiDAR -> camera rotation), t [3] metres (camera frame)."""

    R: np.ndarray
    t: np.ndarray

    def __post_init__(self) -> None:
        object.__setattr__(self, "R", np.asarray(self.R, dtype=np.float64).reshape(3, 3))
        object.__setattr__(self, "t", np.asarray(self.t, dtype=np.float64).reshape(3))

    @classmethod
    def parse(cls, obj, name: str = "pose") -> "Pose":
        """Pose from a CalibrationResult, (R, t), [4,4]/[3,4] T_cam_lidar or Pose; ValueError otherwise."""
        if isinstance(obj, Pose):
            return obj
        if hasattr(obj, "rotation") and hasattr(obj, "translation"):
            if getattr(obj, "rotation", None) is None:
                raise ValueError(f"{name}: the calibration has no pose ({getattr(obj, 'message', '')})")
            return cls(obj.rotation, obj.translation)
        if isinstance(obj, (tuple, list)) and len(obj) == 2:
            R, t = np.asarray(obj[0], dtype=np.float64), np.asarray(obj[1], dtype=np.float64)
            if R.size != 9 or t.size != 3:
                raise ValueError(f"{name}: expected (R [3,3], t [3]), got shapes {R.shape} and {t.shape}")
            return cls(R, t)
        T = np.asarray(obj, dtype=np.float64)
        if T.shape not in ((4, 4), (3, 4)):
            raise ValueError(f"{name}: expected a CalibrationResult, (R, t) or a 4x4 T_cam_lidar, got shape {T.shape}")
        return cls(T[:3, :3], T[:3, 3])

    @property
    def T(self) -> np.ndarray:
        """[4,4] ``T_cam_lidar``."""
        out = np.eye(4)
        out[:3, :3], out[:3, 3] = self.R, self.t
        return out

    def delta(self, other: "Pose") -> np.ndarray:
        """6-vector: rotation vector of ``self.R other.R^T`` (deg, camera axes), ``self.t - other.t`` (m)."""
        return np.concatenate([np.degrees(Rotation.from_matrix(self.R @ other.R.T).as_rotvec()), self.t - other.t])

    def error(self, other: "Pose") -> tuple[float, float]:
        """(rotation angle in degrees, translation distance in metres) to ``other``."""
        d = self.delta(other)
        return float(np.linalg.norm(d[:3])), float(np.linalg.norm(d[3:]))

    def distinct(self, other: "Pose", rot_deg: float, trans_m: float) -> bool:
        """True when ``other`` is more than ``rot_deg`` or ``trans_m`` away."""
        r, t = self.error(other)
        return r > rot_deg or t > trans_m

    def moved(self, rotvec: np.ndarray, dt: np.ndarray) -> "Pose":
        """``R <- exp([w]x) R``, ``t <- t + dt`` (camera frame; rotvec in radians)."""
        return Pose(so3_exp(rotvec) @ self.R, self.t + np.asarray(dt, float))
