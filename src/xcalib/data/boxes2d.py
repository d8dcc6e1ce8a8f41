"""Synthetic 2D detections for real frames that have 3D boxes and a ground-truth calibration but no
2D boxes (PandaSet, SUSTech): each 3D box is projected with the frame's own ``T_cam_lidar`` and
intrinsics **at the camera time** (moved by its velocity x (camera time - LiDAR time) when the
frame carries both times and ``velocities_3d``), occlusion is resolved with a far-to-near mask of
the projected box hulls, and the visible extents get pixel noise, misses and false boxes.

These 2D boxes are *synthetic* (made from the annotation and the ground-truth calibration):
say so wherever they are used. Seeded: the same frame, seed and config give the same boxes.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from ..geometry.boxes import as_box7, box7_corners, points_in_boxes
from ..geometry.projection import project_points
from ..types import Frame

__all__ = ["Synth2DConfig", "synthetic_2d_boxes", "box_corners_lidar"]

_NEAR = 0.3  # metres: boxes with a corner nearer the camera plane are not imaged


@dataclass(frozen=True)
class Synth2DConfig:
    """How the 2D detector behaves. noise_px: std of each box coordinate; miss_rate: probability a
    visible object has no box; false_rate: expected false boxes per true box (Poisson);
    min_visible: visible share of the box's projected hull below which it is not detected;
    max_truncation: share of the projected box outside the image above which it is not detected;
    min_box_px: smallest detected width/height; min_points: 3D boxes holding fewer LiDAR points are
    treated as invisible (0: no check; needs the frame's point cloud); max_depth_m: farther boxes are
    not detected; at_camera_time: move each box by its velocity to the camera time; mask_scale:
    resolution of the occlusion mask relative to the image."""

    noise_px: float = 1.0
    miss_rate: float = 0.1
    false_rate: float = 0.05
    min_visible: float = 0.2
    max_truncation: float = 0.6
    min_box_px: float = 8.0
    min_points: int = 5
    max_depth_m: float = 120.0
    at_camera_time: bool = True
    mask_scale: float = 0.5


def box_corners_lidar(frame: Frame) -> np.ndarray:
    """[M,8,3] corners of the frame's 3D boxes (LiDAR frame), using ``meta["R_lidar_box"]``
    (exact rotation, e.g. PandaSet's tilt) when present, else the box7 yaw."""
    b7 = as_box7(frame.bboxes_3d) if frame.num_3d else np.zeros((0, 7))
    R = frame.meta.get("R_lidar_box")
    if R is None or np.shape(R) != (len(b7), 3, 3):
        return box7_corners(b7) if len(b7) else np.zeros((0, 8, 3))
    flat = b7.copy()
    flat[:, 6] = 0.0
    local = box7_corners(flat) - b7[:, None, :3]  # axis-aligned corners about the centre
    return np.einsum("mij,mkj->mki", np.asarray(R, dtype=np.float64), local) + b7[:, None, :3]


def _time_shift(frame: Frame, cfg: Synth2DConfig) -> np.ndarray:
    """[M,3] LiDAR-frame displacement of each box from the LiDAR time to the camera time."""
    if (not cfg.at_camera_time or frame.velocities_3d is None or frame.lidar_time_s is None
            or frame.camera_time_s is None):
        return np.zeros((frame.num_3d, 3))
    return np.asarray(frame.velocities_3d, dtype=np.float64) * (frame.camera_time_s - frame.lidar_time_s)


def _visible_boxes(uv: np.ndarray, depth: np.ndarray, W: int, H: int, cfg: Synth2DConfig):
    """Visible 2D boxes [M,4] (NaN: not detected) of projected corners uv [M,8,2] (far to near mask)."""
    import cv2

    M = len(uv)
    out = np.full((M, 4), np.nan)
    in_view = np.all(depth > _NEAR, axis=1) & (depth.mean(axis=1) <= cfg.max_depth_m)
    if not M or not in_view.any():
        return out
    s = float(cfg.mask_scale)
    w, h = max(int(round(W * s)), 1), max(int(round(H * s)), 1)
    mask = np.zeros((h, w), dtype=np.int32)
    solo = np.zeros(M)
    idx = np.flatnonzero(in_view)
    hulls = {}
    for i in idx[np.argsort(-depth[idx].mean(axis=1), kind="stable")]:
        hull = cv2.convexHull(np.round(uv[i] * s * 16).astype(np.int32))
        one = np.zeros((h, w), dtype=np.uint8)
        cv2.fillConvexPoly(one, hull, 1, lineType=cv2.LINE_8, shift=4)
        solo[i] = np.count_nonzero(one)
        hulls[i] = one
        mask[one > 0] = i + 1
    for i in idx:
        lo, hi = uv[i].min(axis=0), uv[i].max(axis=0)
        full = max((hi[0] - lo[0]) * (hi[1] - lo[1]), 1e-9)
        a = np.array([max(lo[0], 0.0), max(lo[1], 0.0), min(hi[0], W), min(hi[1], H)])
        if a[2] <= a[0] or a[3] <= a[1]:
            continue
        trunc = 1.0 - (a[2] - a[0]) * (a[3] - a[1]) / full
        own = mask == i + 1
        n_vis = int(np.count_nonzero(own))
        if n_vis == 0 or n_vis / solo[i] < cfg.min_visible or trunc > cfg.max_truncation:
            continue
        if n_vis < solo[i]:  # partly occluded: the extent of its own visible pixels
            ys, xs = np.nonzero(own)
            m = np.array([xs.min(), ys.min(), xs.max() + 1.0, ys.max() + 1.0]) / s
            a = np.array([max(a[0], m[0]), max(a[1], m[1]), min(a[2], m[2]), min(a[3], m[3])])
        if min(a[2] - a[0], a[3] - a[1]) >= cfg.min_box_px:
            out[i] = a
    return out


def synthetic_2d_boxes(frame: Frame, seed: int, config: Synth2DConfig | None = None) -> Frame:
    """``frame`` with synthetic 2D boxes made from its 3D boxes and ground-truth calibration.

    Needs ``frame.intrinsics`` (with width/height, or an image) and ``frame.extrinsics``. Returns
    a copy with ``bboxes_2d`` [K,4] px, ``match_matrix`` [K,M] (the truth), and ``meta``:
    ``ids_2d`` [K] (the 3D box index, -1 = false box), ``boxes_2d_clean`` [K,4] (noise-free),
    ``boxes_2d_synthetic`` (a description of how they were made, with the config and seed).
    """
    cfg = config or Synth2DConfig()
    if frame.intrinsics is None or frame.extrinsics is None:
        raise ValueError(f"frame {frame.frame_key!r}: synthetic 2D boxes need intrinsics and the ground-truth extrinsics")
    intr = frame.intrinsics
    W = intr.width or (frame.image.shape[1] if frame.image.size else int(round(2 * intr.cx)))
    H = intr.height or (frame.image.shape[0] if frame.image.size else int(round(2 * intr.cy)))
    rng = np.random.default_rng([int(seed), 2024])
    corners = box_corners_lidar(frame) + _time_shift(frame, cfg)[:, None, :]
    M = len(corners)
    T = np.asarray(frame.extrinsics, dtype=np.float64)
    uv, depth = project_points(corners.reshape(-1, 3), intr, T[:3, :3], T[:3, 3])
    clean = _visible_boxes(uv.reshape(M, 8, 2), depth.reshape(M, 8), W, H, cfg)
    ok = np.isfinite(clean[:, 0])
    if cfg.min_points > 0 and len(frame.point_cloud) and M:
        n_pts = points_in_boxes(np.asarray(frame.point_cloud)[:, :3], as_box7(frame.bboxes_3d)).sum(axis=1)
        ok &= n_pts >= cfg.min_points
    idx = np.flatnonzero(ok & (rng.uniform(size=M) >= cfg.miss_rate))
    boxes = clean[idx] + rng.normal(0.0, cfg.noise_px, (len(idx), 4))
    n_fp = int(rng.poisson(cfg.false_rate * max(len(idx), 1))) if cfg.false_rate > 0 else 0
    wh = rng.uniform(15, 200, (n_fp, 2))
    xy = np.column_stack([rng.uniform(0, W - wh[:, 0]), rng.uniform(0.3 * H, H - wh[:, 1])])
    fp = np.hstack([xy, xy + wh])
    b2 = np.vstack([boxes, fp])
    b2[:, [0, 2]] = np.clip(b2[:, [0, 2]], 0, W)
    b2[:, [1, 3]] = np.clip(b2[:, [1, 3]], 0, H)
    ids = np.concatenate([idx, -np.ones(n_fp, dtype=np.int64)])
    order = rng.permutation(len(ids))
    b2, ids = b2[order], ids[order]
    mm = np.zeros((len(ids), M), dtype=bool)
    mm[np.flatnonzero(ids >= 0), ids[ids >= 0]] = True
    meta = {**frame.meta, "ids_2d": ids, "boxes_2d_clean": np.vstack([clean[idx], fp])[order],
            "boxes_2d_synthetic": {"how": "3D boxes projected with the frame's ground-truth T_cam_lidar and "
                                          "intrinsics at the camera time, occlusion by a far-to-near hull mask, "
                                          "pixel noise, misses and false boxes",
                                   "seed": int(seed), "config": dataclasses.asdict(cfg)}}
    return dataclasses.replace(frame, bboxes_2d=b2.astype(np.float32), match_matrix=mm, meta=meta)
