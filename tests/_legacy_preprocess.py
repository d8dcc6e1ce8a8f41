"""The 0.3.1 preprocessing, frozen: the reference that the vectorised crops and the grid
points-in-boxes of 0.4 must reproduce bit for bit (tests/test_crops_equivalence.py) and the
"before" of benchmarks/bench_matching_speed.py. Copied verbatim from xcalib 0.3.1
(``xcalib.data.crops`` / ``xcalib.geometry.boxes`` at commit 619cb2d); do not edit."""

from __future__ import annotations

import cv2
import numpy as np

from xcalib.data.crops import IMAGENET_MEAN, IMAGENET_STD
from xcalib.geometry.boxes import as_box7, expand_box7

__all__ = ["points_in_boxes", "crop_images", "gather_box_points", "resample_points", "crop_points"]


def _image_float_scale(image: np.ndarray) -> float:
    return 1.0 if image.dtype.kind == "f" else 1.0 / 255.0


def points_in_boxes(points, boxes, *, expansion: float = 1.0, convention: str = "auto") -> np.ndarray:
    """Which points lie in which boxes, for many boxes at once.

    Args:
        points: [P, >=3] LiDAR-frame points (metres).
        boxes: protocol [M,6] boxes or box7 [M,7] (yaw honoured).
        expansion: scale factor on the box dimensions (protocol ``bbox_expansion``).
    Returns:
        bool mask [M, P].
    """
    pts = np.asarray(points)
    if pts.ndim != 2 or pts.shape[1] < 3:
        raise ValueError(f"points: expected shape [P, >=3], got {pts.shape}")
    b = expand_box7(as_box7(boxes, convention), expansion) if len(np.asarray(boxes).reshape(-1)) else np.zeros((0, 7))
    M, P = len(b), len(pts)
    if M == 0 or P == 0:
        return np.zeros((M, P), dtype=bool)
    # One affine map per box sends its inside to the cube [-1, 1]^3; all boxes in one matmul.
    c, s = np.cos(b[:, 6]), np.sin(b[:, 6])
    inv_half = 2.0 / np.maximum(b[:, 3:6], 1e-9)
    A = np.zeros((M, 3, 4))
    A[:, 0, 0], A[:, 0, 1] = c * inv_half[:, 0], s * inv_half[:, 0]
    A[:, 1, 0], A[:, 1, 1] = -s * inv_half[:, 1], c * inv_half[:, 1]
    A[:, 2, 2] = inv_half[:, 2]
    A[:, :, 3] = -np.einsum("mij,mj->mi", A[:, :, :3], b[:, :3])
    xyz = np.ascontiguousarray(pts[:, :3], dtype=np.float32)
    Af = A.astype(np.float32)
    # Candidate pairs without a dense [M,P] test: bucket the points on a G x G grid in x, y
    # (radix sort on uint16 cell ids); each box visits only the cell rows its footprint covers.
    G = 256
    x, y = xyz[:, 0], xyz[:, 1]
    lo = np.array([x.min(), y.min()], dtype=np.float64)
    cell = np.maximum((np.array([x.max(), y.max()], dtype=np.float64) - lo) / G, 1e-6)
    ix = ((x - np.float32(lo[0])) * np.float32(1.0 / cell[0])).astype(np.int32)
    iy = ((y - np.float32(lo[1])) * np.float32(1.0 / cell[1])).astype(np.int32)
    np.clip(ix, 0, G - 1, out=ix)
    np.clip(iy, 0, G - 1, out=iy)
    cid = (iy * G + ix).astype(np.uint16)
    order = np.argsort(cid, kind="stable")
    starts = np.zeros(G * G + 1, dtype=np.int64)
    np.cumsum(np.bincount(cid, minlength=G * G), out=starts[1:])
    half = np.stack([np.abs(c) * b[:, 3] + np.abs(s) * b[:, 4],
                     np.abs(s) * b[:, 3] + np.abs(c) * b[:, 4]], 1) / 2 + 1e-3
    lo_c = np.floor((b[:, :2] - half - lo) / cell) - 1
    hi_c = np.floor((b[:, :2] + half - lo) / cell) + 1
    valid = (hi_c[:, 0] >= 0) & (hi_c[:, 1] >= 0) & (lo_c[:, 0] <= G - 1) & (lo_c[:, 1] <= G - 1)
    lo_c = np.clip(lo_c, 0, G - 1).astype(np.int64)
    hi_c = np.clip(hi_c, 0, G - 1).astype(np.int64)
    nrows = np.where(valid, hi_c[:, 1] - lo_c[:, 1] + 1, 0)
    seg_box = np.repeat(np.arange(M), nrows)
    seg_row = lo_c[seg_box, 1] + np.arange(len(seg_box)) - np.repeat(np.cumsum(nrows) - nrows, nrows)
    seg_start = starts[seg_row * G + lo_c[seg_box, 0]]
    lens = starts[seg_row * G + hi_c[seg_box, 0] + 1] - seg_start
    mask = np.zeros((M, P), dtype=bool)
    total = int(lens.sum())
    if total == 0:
        return mask
    mi = np.repeat(seg_box, lens)
    offs = np.arange(total) - np.repeat(np.cumsum(lens) - lens, lens)
    pi = order[np.repeat(seg_start, lens) + offs]
    px, py, pz = xyz[pi, 0], xyz[pi, 1], xyz[pi, 2]
    lz = Af[mi, 2, 2] * pz + Af[mi, 2, 3]
    inside = np.abs(lz) <= 1.0
    lx = Af[mi, 0, 0] * px + Af[mi, 0, 1] * py + Af[mi, 0, 3]
    inside &= np.abs(lx) <= 1.0
    ly = Af[mi, 1, 0] * px + Af[mi, 1, 1] * py + Af[mi, 1, 3]
    inside &= np.abs(ly) <= 1.0
    mask[mi[inside], pi[inside]] = True
    return mask


def crop_images(image: np.ndarray, bboxes_2d, crop_size: int = 32, *, keep_aspect: bool = True,
                normalize: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Crop + resize every 2D box. Returns (crops [N,3,S,S] float32, kept indices [N] int64)."""
    if image.ndim != 3 or image.shape[2] != 3:
        raise ValueError(f"image: expected shape [H, W, 3], got {image.shape}")
    S = int(crop_size)
    b = np.asarray(bboxes_2d, dtype=np.float64).reshape(-1, 4) if np.size(bboxes_2d) else np.zeros((0, 4))
    H, W = image.shape[:2]
    ok = np.all(np.isfinite(b), axis=1) & (b[:, 2] > b[:, 0]) & (b[:, 3] > b[:, 1])
    ok &= (b[:, 2] > 0) & (b[:, 0] < W) & (b[:, 3] > 0) & (b[:, 1] < H)
    src = np.where(ok[:, None], b, 0.0)
    if keep_aspect and len(src):
        c = (src[:, :2] + src[:, 2:]) / 2.0
        half = np.maximum(src[:, 2] - src[:, 0], src[:, 3] - src[:, 1])[:, None] / 2.0
        src = np.hstack([c - half, c + half])
    ix0 = np.floor(np.clip(src[:, 0], 0, W)).astype(np.int64)
    iy0 = np.floor(np.clip(src[:, 1], 0, H)).astype(np.int64)
    ix1 = np.ceil(np.clip(src[:, 2], 0, W)).astype(np.int64)
    iy1 = np.ceil(np.clip(src[:, 3], 0, H)).astype(np.int64)
    ok &= (ix1 > ix0) & (iy1 > iy0)
    kept = np.nonzero(ok)[0].astype(np.int64)
    scale = _image_float_scale(image)
    fill = IMAGENET_MEAN / scale if normalize else np.zeros(3, np.float32)
    out = np.empty((len(kept), S, S, 3), dtype=np.float32)
    out[:] = fill
    for n, k in enumerate(kept):  # loop over detections (one OpenCV resize each), not points
        w, h = src[k, 2] - src[k, 0], src[k, 3] - src[k, 1]
        ox0 = int(np.clip(round((ix0[k] - src[k, 0]) * S / w), 0, S - 1))
        oy0 = int(np.clip(round((iy0[k] - src[k, 1]) * S / h), 0, S - 1))
        ox1 = int(np.clip(round((ix1[k] - src[k, 0]) * S / w), ox0 + 1, S))
        oy1 = int(np.clip(round((iy1[k] - src[k, 1]) * S / h), oy0 + 1, S))
        patch = image[iy0[k]:iy1[k], ix0[k]:ix1[k]]
        step = int(min(patch.shape[0] / (oy1 - oy0), patch.shape[1] / (ox1 - ox0)) // 2)
        if step > 1:  # big box: subsample to ~2x the output size first, then area-average
            patch = patch[::step, ::step]
        shrink = patch.shape[0] > (oy1 - oy0) or patch.shape[1] > (ox1 - ox0)
        patch = cv2.resize(patch, (ox1 - ox0, oy1 - oy0),
                           interpolation=cv2.INTER_AREA if shrink else cv2.INTER_LINEAR)
        out[n, oy0:oy1, ox0:ox1] = patch.reshape(oy1 - oy0, ox1 - ox0, 3)
    out *= scale
    if normalize:
        out -= IMAGENET_MEAN
        out /= IMAGENET_STD
    return np.ascontiguousarray(out.transpose(0, 3, 1, 2)), kept


def gather_box_points(points: np.ndarray, boxes7: np.ndarray, expansion: float = 1.25
                      ) -> tuple[np.ndarray, np.ndarray]:
    """Points inside each expanded box7, in that box's frame (metres).

    Returns (points [T,3] float32 grouped box by box, counts [M] int64) with T = counts.sum().
    """
    b = np.asarray(boxes7, dtype=np.float64).reshape(-1, 7)
    xyz = np.asarray(points)[:, :3]
    mask = points_in_boxes(xyz, b, expansion=expansion)
    flat = np.flatnonzero(mask)  # row-major: grouped box by box (much faster than 2D nonzero)
    mi, pi = flat // mask.shape[1], flat % mask.shape[1]
    counts = np.bincount(mi, minlength=len(b)).astype(np.int64)
    d = xyz[pi].astype(np.float64) - b[mi, :3]
    c, s = np.cos(b[mi, 6]), np.sin(b[mi, 6])
    local = np.stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1], d[:, 2]], axis=1)
    return local.astype(np.float32), counts


def resample_points(points: np.ndarray, counts: np.ndarray, n: int,
                    rng: np.random.Generator) -> np.ndarray:
    """Resample grouped points (see :func:`gather_box_points`) to ``n`` per group -> [M,n,3].

    Groups with >= n points: a random subset without replacement; smaller groups: all their
    points plus random repeats. Every count must be >= 1.
    """
    counts = np.asarray(counts, dtype=np.int64)
    M = len(counts)
    if M == 0:
        return np.zeros((0, n, 3), dtype=np.float32)
    if np.any(counts < 1):
        raise ValueError(f"resample_points: every group needs >= 1 point, got counts {counts.tolist()}")
    starts = np.cumsum(counts) - counts
    seg = np.repeat(np.arange(M), counts)
    order = np.lexsort((rng.random(len(seg)), seg))
    j = np.arange(n)[None, :]
    fill = np.minimum((rng.random((M, n)) * counts[:, None]).astype(np.int64), counts[:, None] - 1)
    src = np.where(j < counts[:, None], j, fill)
    return np.asarray(points, dtype=np.float32)[order[starts[:, None] + src]]


def crop_points(point_cloud: np.ndarray, bboxes_3d, point_cloud_size: int = 1024, *,
                expansion: float = 1.25, rng: np.random.Generator | None = None,
                min_points: int = 1) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """LiDAR crops. Returns (crops [M,P,3] float32, box7 [M,7] float32, counts [M], kept [M])."""
    rng = np.random.default_rng(0) if rng is None else rng
    b = np.asarray(bboxes_3d, dtype=np.float64)
    if b.size == 0:
        return (np.zeros((0, point_cloud_size, 3), np.float32), np.zeros((0, 7), np.float32),
                np.zeros(0, np.int64), np.zeros(0, np.int64))
    box7 = as_box7(b)
    ok = np.all(np.isfinite(box7), axis=1) & np.all(box7[:, 3:6] > 0, axis=1)
    idx = np.nonzero(ok)[0]
    pc = np.asarray(point_cloud)
    if len(idx) and len(pc):
        pts, counts = gather_box_points(pc, box7[idx], expansion)
    else:
        pts, counts = np.zeros((0, 3), np.float32), np.zeros(len(idx), np.int64)
    keep = counts >= min_points
    if not keep.all():  # drop the groups of boxes that are too sparse
        pts = pts[np.repeat(keep, counts)]
        counts = counts[keep]
    kept = idx[keep].astype(np.int64)
    crops = resample_points(pts, counts, int(point_cloud_size), rng)
    return crops, box7[kept].astype(np.float32), counts, kept
