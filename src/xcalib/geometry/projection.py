"""Projection of LiDAR-frame points to pixels through ``P = K [R|t]`` with OpenCV distortion."""

from __future__ import annotations

import numpy as np

__all__ = ["projection_matrix", "project_points", "distort_normalized", "undistort_pixels",
           "points_to_camera"]


def projection_matrix(K, R, t) -> np.ndarray:
    """``P = K [R|t]`` ([3,4]) from K [3,3], R [3,3] (LiDAR->camera) and t [3] (metres)."""
    K = np.asarray(K, dtype=np.float64)
    Rt = np.hstack([np.asarray(R, dtype=np.float64), np.asarray(t, dtype=np.float64).reshape(3, 1)])
    return K @ Rt


def points_to_camera(points, R, t) -> np.ndarray:
    """LiDAR-frame points [N,>=3] -> camera-frame XYZ [N,3] (float64)."""
    pts = np.asarray(points)[:, :3].astype(np.float64, copy=False)
    return pts @ np.asarray(R, dtype=np.float64).T + np.asarray(t, dtype=np.float64).reshape(1, 3)


def distort_normalized(xy, dist) -> np.ndarray:
    """Apply the OpenCV distortion model to normalised image coordinates [N,2]."""
    d = np.zeros(14)
    if dist is not None:
        dist = np.asarray(dist, dtype=np.float64).reshape(-1)
        d[: dist.size] = dist
    if not np.any(d):
        return xy
    if np.any(d[12:14]):
        raise NotImplementedError("tilted-sensor distortion (tauX, tauY) is not supported")
    k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4 = d[:12]
    x, y = xy[:, 0], xy[:, 1]
    r2 = x * x + y * y
    r4 = r2 * r2
    r6 = r4 * r2
    radial = (1 + k1 * r2 + k2 * r4 + k3 * r6) / (1 + k4 * r2 + k5 * r4 + k6 * r6)
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x) + s1 * r2 + s2 * r4
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y + s3 * r2 + s4 * r4
    return np.stack([xd, yd], axis=1)


def project_points(points, K, R=None, t=None, dist=None, *, min_depth: float = 1e-6):
    """Project LiDAR-frame points to pixels.

    Args:
        points: [N, >=3] metres, in the frame of the 3D boxes (LiDAR frame).
        K: [3,3] camera matrix (or a ``CameraIntrinsics``; then its distortion is used
           unless ``dist`` is given; or any ``CameraModel``: its projection, NaN outside its
           valid region, which for a wide-angle model includes points with Z <= 0).
        R, t: LiDAR->camera rotation [3,3] and translation [3] (identity/zero if omitted).
        dist: OpenCV distortion coefficients or None.
    Returns:
        ``(uv [N,2] float64 pixels, depth [N] camera-frame Z in metres)``. Points with
        depth <= ``min_depth`` get uv = NaN.
    """
    from .camera_models.base import CameraModel

    if isinstance(K, CameraModel):  # any camera model: its own projection and valid region
        if dist is not None:
            raise ValueError(f"project_points: a {K.name} camera model carries its own distortion; got dist too")
        pc = points_to_camera(points, np.eye(3) if R is None else R, np.zeros(3) if t is None else t)
        uv, valid = K.project(pc)
        if K.is_pinhole:
            uv[~(pc[:, 2] > min_depth)] = np.nan
        return uv, pc[:, 2]
    if hasattr(K, "K"):
        if dist is None:
            dist = K.distortion
        K = K.K
    K = np.asarray(K, dtype=np.float64)
    R = np.eye(3) if R is None else R
    t = np.zeros(3) if t is None else t
    pc = points_to_camera(points, R, t)
    depth = pc[:, 2]
    front = depth > min_depth
    with np.errstate(divide="ignore", invalid="ignore"):
        xy = pc[:, :2] / np.where(front, depth, np.nan)[:, None]
    xy = distort_normalized(xy, dist)
    uv = xy @ K[:2, :2].T + K[:2, 2]
    uv[~front] = np.nan
    return uv, depth


def undistort_pixels(uv, K, dist) -> np.ndarray:
    """Remove OpenCV distortion from pixel coordinates [N,2] (returns pixels of the ideal pinhole)."""
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    if dist is None or not np.any(dist):
        return uv.copy()
    import cv2

    K = np.asarray(K, dtype=np.float64)
    out = cv2.undistortPoints(uv.reshape(-1, 1, 2), K, np.asarray(dist, dtype=np.float64), P=K)
    return out.reshape(-1, 2)
