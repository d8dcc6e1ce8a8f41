"""Projected 3D boxes as image rectangles, for many poses at once (vectorised).

A 3D box's predicted 2D box is the enclosing rectangle of its projected corners (pixels,
OpenCV distortion applied), clipped to the image, which is how a detector box of a truncated
object behaves.
"""

from __future__ import annotations

import numpy as np

from ..geometry.camera import CameraIntrinsics
from ..geometry.projection import distort_normalized

__all__ = ["project_rects", "iou_batched", "MIN_DEPTH_M"]

MIN_DEPTH_M = 0.3


def project_rects(corners: np.ndarray, R: np.ndarray, t: np.ndarray, intr: CameraIntrinsics,
                  size: tuple[int, int], *, clip: bool = True):
    """Project box corners for H poses.

    Args:
        corners: [M,S,3] LiDAR-frame points per box (metres).
        R: [H,3,3] or [3,3]; t: [H,3] or [3] (LiDAR -> camera).
        size: (width, height) px used for clipping.
    Returns:
        rects [H,M,4] (x1,y1,x2,y2 px; NaN where invalid), valid [H,M] bool: every corner in
        front of the camera and a non-empty clipped rectangle.
    """
    single = np.ndim(R) == 2
    R = np.asarray(R, dtype=np.float64).reshape(-1, 3, 3)
    t = np.asarray(t, dtype=np.float64).reshape(-1, 3)
    c = np.asarray(corners, dtype=np.float64)
    H, M = len(R), len(c)
    if M == 0:
        out = np.zeros((H, 0, 4)), np.zeros((H, 0), dtype=bool)
        return (out[0][0], out[1][0]) if single else out
    S = c.shape[1]
    X = np.matmul(R, c.reshape(-1, 3).T) + t[:, :, None]  # [H,3,M*S] (batched BLAS)
    z = X[:, 2].reshape(H, M, S)
    front = np.all(z > MIN_DEPTH_M, axis=2)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = np.where(z > MIN_DEPTH_M, 1.0 / z, np.nan)
    x = X[:, 0].reshape(H, M, S) * inv
    y = X[:, 1].reshape(H, M, S) * inv
    if intr.distortion is not None:
        # The polynomial model is meaningless far outside the field of view; clamp first.
        flat = np.clip(np.stack([x.ravel(), y.ravel()], 1), -1.5, 1.5)
        d = distort_normalized(flat, intr.distortion)
        x, y = d[:, 0].reshape(H, M, S), d[:, 1].reshape(H, M, S)
    u = x * intr.fx + intr.cx
    v = y * intr.fy + intr.cy
    with np.errstate(invalid="ignore"):
        rect = np.stack([u.min(2), v.min(2), u.max(2), v.max(2)], axis=-1)
    if clip:
        W, Hh = size
        rect[..., [0, 2]] = np.clip(rect[..., [0, 2]], 0.0, W)
        rect[..., [1, 3]] = np.clip(rect[..., [1, 3]], 0.0, Hh)
    with np.errstate(invalid="ignore"):
        valid = front & (rect[..., 2] - rect[..., 0] > 1.0) & (rect[..., 3] - rect[..., 1] > 1.0)
    rect[~valid] = np.nan
    return (rect[0], valid[0]) if single else (rect, valid)


def iou_batched(rects: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """IoU of observed boxes [K,4] with predicted rects [H,M,4] -> [H,K,M] (NaN rect -> 0)."""
    r = np.nan_to_num(rects[:, None, :, :], nan=0.0)
    b = boxes[None, :, None, :]
    iw = np.clip(np.minimum(r[..., 2], b[..., 2]) - np.maximum(r[..., 0], b[..., 0]), 0, None)
    ih = np.clip(np.minimum(r[..., 3], b[..., 3]) - np.maximum(r[..., 1], b[..., 1]), 0, None)
    inter = iw * ih
    ar = (r[..., 2] - r[..., 0]) * (r[..., 3] - r[..., 1])
    ab = (b[..., 2] - b[..., 0]) * (b[..., 3] - b[..., 1])
    union = ar + ab - inter
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(union > 0, inter / union, 0.0)
