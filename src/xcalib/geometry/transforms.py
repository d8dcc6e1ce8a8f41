"""Rigid transforms as 4x4 homogeneous matrices (metres).

``T_b_a`` maps points from frame a to frame b: ``x_b = T_b_a @ x_a``. The extrinsics that
xcalib estimates are ``T_cam_lidar`` (LiDAR frame -> OpenCV camera frame).
"""

from __future__ import annotations

import numpy as np

from .rotations import rotation_angle

__all__ = ["make_transform", "split_transform", "invert_transform", "compose", "transform_points",
           "pose_error", "as_transform"]


def make_transform(R, t) -> np.ndarray:
    """[3,3] rotation and [3] translation -> [4,4] transform."""
    R = np.asarray(R, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64).reshape(-1)
    if R.shape != (3, 3) or t.shape != (3,):
        raise ValueError(f"make_transform: expected R [3,3] and t [3], got {R.shape} and {t.shape}")
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t
    return T


def as_transform(T, name: str = "transform") -> np.ndarray:
    """Accept a [4,4] or [3,4] matrix and return it as float64 [4,4]."""
    T = np.asarray(T, dtype=np.float64)
    if T.shape == (3, 4):
        T = np.vstack([T, [0.0, 0.0, 0.0, 1.0]])
    if T.shape != (4, 4):
        raise ValueError(f"{name}: expected a 4x4 or 3x4 matrix, got shape {T.shape}")
    if not np.all(np.isfinite(T)):
        raise ValueError(f"{name}: matrix has NaN/Inf entries")
    return T


def split_transform(T):
    """[4,4] -> (R [3,3], t [3])."""
    T = as_transform(T)
    return T[:3, :3].copy(), T[:3, 3].copy()


def invert_transform(T) -> np.ndarray:
    """Inverse of a rigid transform (exact, no general matrix inverse)."""
    R, t = split_transform(T)
    return make_transform(R.T, -R.T @ t)


def compose(*transforms) -> np.ndarray:
    """``compose(A, B, C) = A @ B @ C`` (apply C first)."""
    out = np.eye(4)
    for T in transforms:
        out = out @ as_transform(T)
    return out


def transform_points(T, points) -> np.ndarray:
    """Apply a [4,4] transform to points [N,>=3] (extra columns are kept unchanged)."""
    T = as_transform(T)
    pts = np.asarray(points)
    out = pts.copy() if pts.dtype.kind == "f" else pts.astype(np.float64)
    xyz = pts[:, :3].astype(np.float64) @ T[:3, :3].T + T[:3, 3]
    out[:, :3] = xyz
    return out


def pose_error(T_est, T_gt) -> tuple[float, float]:
    """(geodesic rotation error in degrees, translation error in metres) of ``T_est`` vs ``T_gt``."""
    R_e, t_e = split_transform(T_est)
    R_g, t_g = split_transform(T_gt)
    return rotation_angle(R_e, R_g, degrees=True), float(np.linalg.norm(t_e - t_g))
