"""Geometric augmentation through the calibration: few frames, whole field of view.

A short recording shows few distinct objects at few places, and a model trained on it learns
to recognise those objects instead of the site's geometry. With the pose known, an object can
be moved (probability ``p_move`` per 3D box): with probability ``p_view`` it is placed on the
ground under a random pixel of the image (within ``max_range_m``; each box keeps its height
above the ground, estimated as the median box bottom of the frame), otherwise shifted on the
ground plane by up to ``shift_m`` metres. A matched pair's 2D box is re-derived by projecting
the moved 3D box through the pose and carrying over the detector's offset from the projection
of the original box (scaled with the projected size). The crops stay (image crops are
size-normalised; LiDAR crops are in the box frame), so only the box geometry changes; with
probability ``p_blank`` a crop is blanked (zeros) so that geometry must carry the match. Moved
2D boxes leaving the image (visible part < 50 % or smaller than ``min_box_px``) are dropped.
The recording's objects outside the view (unmatched 3D boxes: often pedestrians, cyclists, parked
cars that never enter the image during a short recording) would otherwise only ever be
negatives, teaching the model that such objects never match; with probability ``p_virtual`` an
unmatched 3D box placed in view becomes a virtual pair (its projected box, a blank image crop,
weight ``virtual_weight``).
Negatives are recomputed from the new geometry. Optional decoys (``p_decoy``, off by default:
they lowered held-out Top-1 in ``benchmarks/bench_oneshot.py``) leave an unmoved copy of one
side of a moved pair behind (its 3D box or its 2D box, never both) that matches nothing.
Defaults were chosen on held-out sequences 202-204 of synthetic site B in the benchmark
(its JSON also reports sequences not used for that choice).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..data.crops import FrameInputs
from ..geometry.boxes import box7_corners
from ..geometry.camera import CameraIntrinsics
from ..geometry.camera_models import CameraModel, project_outline_rects
from ..geometry.projection import project_points
from .pseudo import PseudoTargets

__all__ = ["GeometricAugment"]


def _rects(box7: np.ndarray, intr, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Unclipped enclosing rectangles [M,4] px of projected boxes (NaN if any point is behind or
    outside the camera's valid region). A pinhole ``CameraIntrinsics``: the 8 corners' rectangle; a
    wide-angle camera model: the outline of the box's edges, densely projected (edges curve,
    :func:`xcalib.geometry.camera_models.project_outline_rects`), so a moved object's 2D box is
    where it appears in the fisheye image."""
    if len(box7) == 0:
        return np.zeros((0, 4))
    if isinstance(intr, CameraModel) and not intr.is_pinhole:
        rect, _ = project_outline_rects(box7_corners(box7), R, t, intr, (1, 1), clip=False, min_distance=0.5)
        return rect
    c = box7_corners(box7).reshape(-1, 3)
    uv, depth = project_points(c, intr, R, t, min_depth=0.5)
    uv = uv.reshape(-1, 8, 2)
    r = np.concatenate([uv.min(1), uv.max(1)], axis=1)
    r[np.isnan(uv).any(axis=(1, 2))] = np.nan
    return r


def _pixel_rays(intr, uv: np.ndarray) -> np.ndarray:
    """Camera-frame rays [...,3] through pixels ``uv`` [...,2]: K^-1 (u, v, 1) for a pinhole, the
    model's own ``unproject`` (unit rays, NaN outside its image) for a wide-angle camera model."""
    if isinstance(intr, CameraModel) and not intr.is_pinhole:
        rays, _ = intr.unproject(uv.reshape(-1, 2))
        return rays.reshape(*uv.shape[:-1], 3)
    uv1 = np.concatenate([uv, np.ones((*uv.shape[:-1], 1))], -1)
    return uv1 @ np.linalg.inv(intr.K).T


def _iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """IoU [K,M] of boxes a [K,4] with b [M,4]; NaN boxes give 0."""
    a = np.nan_to_num(a, nan=0.0)
    b = np.nan_to_num(b, nan=0.0)
    x1 = np.maximum(a[:, None, 0], b[None, :, 0])
    y1 = np.maximum(a[:, None, 1], b[None, :, 1])
    x2 = np.minimum(a[:, None, 2], b[None, :, 2])
    y2 = np.minimum(a[:, None, 3], b[None, :, 3])
    inter = np.clip(x2 - x1, 0, None) * np.clip(y2 - y1, 0, None)
    area = lambda r: np.clip(r[:, 2] - r[:, 0], 0, None) * np.clip(r[:, 3] - r[:, 1], 0, None)  # noqa: E731
    union = area(a)[:, None] + area(b)[None, :] - inter
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(union > 0, inter / union, 0.0)


@dataclass
class GeometricAugment:
    """Moves objects through the pose ``R``, ``t`` (LiDAR -> camera) and ``intrinsics`` (see module;
    a ``CameraIntrinsics`` or any camera model: moved boxes are projected, and placed under pixels,
    through the model's own image)."""

    intrinsics: CameraIntrinsics | CameraModel
    R: np.ndarray
    t: np.ndarray
    shift_m: float = 12.0
    p_move: float = 0.8
    p_decoy: float = 0.0
    neg_iou: float = 0.05
    min_box_px: float = 8.0
    p_blank: float = 0.4
    p_view: float = 1.0
    max_range_m: float = 90.0
    p_virtual: float = 1.0
    virtual_weight: float = 0.5

    def _in_view(self, b3: np.ndarray, W: int, H: int, rng: np.random.Generator, tries: int = 8) -> np.ndarray:
        """New box centres [M,3] on the ground under random pixels of the image (NaN where no
        try lands on the ground within ``max_range_m``); each box keeps its own height above ground."""
        M = len(b3)
        ground = float(np.median(b3[:, 2] - b3[:, 5] / 2))
        zc = ground + b3[:, 5] / 2                                      # [M]
        uv = np.stack([rng.uniform(0, W, (M, tries)), rng.uniform(0, H, (M, tries))], -1)
        rays_c = _pixel_rays(self.intrinsics, uv)                        # [M,T,3] camera frame
        d = rays_c @ self.R                                             # R^T d, LiDAR frame
        o = -self.R.T @ self.t
        with np.errstate(divide="ignore", invalid="ignore"):
            s = (zc[:, None] - o[2]) / d[..., 2]
            p = o + s[..., None] * d
            ok = (s > 0) & (np.linalg.norm(p[..., :2], axis=-1) < self.max_range_m) & np.isfinite(s)
        first = np.argmax(ok, axis=1)
        out = p[np.arange(M), first]
        out[~ok.any(axis=1)] = np.nan
        return out

    def project(self, fi: FrameInputs, tg: PseudoTargets | None = None) -> np.ndarray:
        """Where each 3D box of ``fi`` appears in the image: [M,4] px rectangles (x1, y1, x2, y2).

        A pseudo-matched box gets its 2D box (the detector's own framing); any other box its
        projected corners' rectangle clipped to the image. NaN rows: behind the camera, or less
        than half (or under ``min_box_px``) of the rectangle inside the image.
        """
        W, H = fi.image_size
        r = _rects(fi.boxes_3d.astype(np.float64), self.intrinsics, self.R, self.t)
        c = r.copy()
        c[:, [0, 2]] = np.clip(c[:, [0, 2]], 0, W)
        c[:, [1, 3]] = np.clip(c[:, [1, 3]], 0, H)
        area = lambda q: np.clip(q[:, 2] - q[:, 0], 0, None) * np.clip(q[:, 3] - q[:, 1], 0, None)  # noqa: E731
        with np.errstate(invalid="ignore"):
            ok = np.isfinite(r).all(1) & (area(c) >= 0.5 * area(r)) & ((c[:, 2] - c[:, 0]) >= self.min_box_px) \
                & ((c[:, 3] - c[:, 1]) >= self.min_box_px)
        c[~ok] = np.nan
        if tg is not None and tg.positive.any():
            pi, pj = np.nonzero(tg.positive)
            c[pj] = fi.boxes_2d[pi]
        return c

    def apply(self, fi: FrameInputs, tg: PseudoTargets, rng: np.random.Generator) -> tuple[FrameInputs, PseudoTargets]:
        """A moved copy of one frame's inputs and targets (the inputs are not modified)."""
        N, M = fi.num_2d, fi.num_3d
        if N == 0 or M == 0:
            return fi, tg
        W, H = fi.image_size
        b3 = fi.boxes_3d.astype(np.float64)
        b2 = fi.boxes_2d.astype(np.float64)
        pos = tg.positive
        pi, pj = np.nonzero(pos)
        move = rng.random(M) < self.p_move
        new3 = b3.copy()
        new3[move, :2] += rng.uniform(-self.shift_m, self.shift_m, size=(int(move.sum()), 2))
        placed = np.zeros(M, bool)
        if self.p_view > 0:
            view = move & (rng.random(M) < self.p_view)
            if view.any():
                c = self._in_view(b3[view], W, H, rng)
                good = np.isfinite(c).all(1)
                idx = np.flatnonzero(view)[good]
                new3[idx, :3] = c[good]
                placed[idx] = True
        old_r, new_r = _rects(b3, self.intrinsics, self.R, self.t), _rects(new3, self.intrinsics, self.R, self.t)
        # predicted 2D rectangle of every 3D box after the move (detector offset carried over for matched ones)
        pred = new_r.copy()
        new2 = b2.copy()
        keep2 = np.ones(N, bool)
        if len(pi):
            ow = np.maximum(old_r[pj, 2] - old_r[pj, 0], 1e-3)
            oh = np.maximum(old_r[pj, 3] - old_r[pj, 1], 1e-3)
            sx = (new_r[pj, 2] - new_r[pj, 0]) / ow
            sy = (new_r[pj, 3] - new_r[pj, 1]) / oh
            off = b2[pi] - old_r[pj]
            cand = new_r[pj] + off * np.stack([sx, sy, sx, sy], 1)
            moved = move[pj]
            cand = np.where(moved[:, None], cand, b2[pi])
            clipped = cand.copy()
            clipped[:, [0, 2]] = np.clip(clipped[:, [0, 2]], 0, W)
            clipped[:, [1, 3]] = np.clip(clipped[:, [1, 3]], 0, H)
            area = lambda r: np.clip(r[:, 2] - r[:, 0], 0, None) * np.clip(r[:, 3] - r[:, 1], 0, None)  # noqa: E731
            with np.errstate(invalid="ignore", divide="ignore"):
                ok = np.isfinite(cand).all(1) & (area(clipped) >= 0.5 * area(cand)) & \
                    ((clipped[:, 2] - clipped[:, 0]) >= self.min_box_px) & ((clipped[:, 3] - clipped[:, 1]) >= self.min_box_px)
            ok |= ~moved
            new2[pi[ok]] = clipped[ok]
            keep2[pi[~ok]] = False
            pred[pj] = np.where(moved[:, None], cand, b2[pi])
        # decoys: an unmoved copy of one side of a moved pair
        dec = np.zeros(len(pi), bool) if not len(pi) else (move[pj] & keep2[pi] & (rng.random(len(pi)) < self.p_decoy))
        side3 = rng.random(len(pi)) < 0.5
        d3 = pj[dec & side3]          # 3D boxes copied at their old place
        d2 = pi[dec & ~side3]         # 2D boxes copied at their old place
        # virtual pairs: unmatched 3D boxes placed in view get their projected box and a blank image crop
        vr = np.nan_to_num(new_r, nan=-1.0)
        vc = vr.copy()
        vc[:, [0, 2]] = np.clip(vc[:, [0, 2]], 0, W)
        vc[:, [1, 3]] = np.clip(vc[:, [1, 3]], 0, H)
        varea = lambda r: np.clip(r[:, 2] - r[:, 0], 0, None) * np.clip(r[:, 3] - r[:, 1], 0, None)  # noqa: E731
        virt = np.flatnonzero(placed & ~pos.any(0) & np.isfinite(new_r).all(1) & (varea(vc) >= 0.5 * varea(vr))
                              & ((vc[:, 2] - vc[:, 0]) >= self.min_box_px) & ((vc[:, 3] - vc[:, 1]) >= self.min_box_px)
                              & (rng.random(M) < self.p_virtual))
        rows = np.concatenate([np.flatnonzero(keep2), d2])
        cols = np.concatenate([np.arange(M), d3])
        nk, nr = int(keep2.sum()), len(rows)
        boxes2 = np.concatenate([new2[keep2], b2[d2], vc[virt]]).astype(np.float32)
        boxes3 = np.concatenate([new3, b3[d3]]).astype(np.float32)
        pred3 = np.concatenate([pred, old_r[d3]])
        pred3[virt] = vc[virt]
        P = np.zeros((nr + len(virt), len(cols)), bool)
        P[:nk, :M] = pos[keep2]
        P[nr + np.arange(len(virt)), virt] = True
        w = np.zeros(P.shape, np.float32)
        w[:nk, :M] = tg.weight[keep2]
        w[nr + np.arange(len(virt)), virt] = self.virtual_weight
        neg = (_iou(boxes2.astype(np.float64), pred3) < self.neg_iou) & ~P
        c2 = np.concatenate([fi.crops_2d[rows], np.zeros((len(virt), *fi.crops_2d.shape[1:]), np.float32)])
        c3 = fi.crops_3d[cols]
        rows = np.concatenate([rows, np.full(len(virt), -1)])
        if self.p_blank > 0:
            c2 = np.where((rng.random(len(c2)) < self.p_blank)[:, None, None, None], 0.0, c2).astype(np.float32)
            c3 = np.where((rng.random(len(c3)) < self.p_blank)[:, None, None], 0.0, c3).astype(np.float32)
        out = FrameInputs(c2, c3, boxes2, boxes3, fi.point_counts[cols], fi.image_size,
                          np.where(rows >= 0, fi.kept_2d[rows], -1), fi.kept_3d[cols])
        return out, PseudoTargets(P, w, neg)
