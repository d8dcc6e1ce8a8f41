"""Projected 3D boxes as image rectangles, for many poses at once (vectorised).

A 3D box's predicted 2D box is the enclosing rectangle of its projected corners (pixels,
OpenCV distortion applied), clipped to the image, which is how a detector box of a truncated
object behaves.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry.boxes import take_rows
from ..geometry.camera import CameraIntrinsics
from ..geometry.camera_models import project_outline_rects
from ..geometry.camera_models.outline import finish_rects, no_rects, pose_batch
from ..geometry.projection import distort_normalized

__all__ = ["project_rects", "iou_batched", "MIN_DEPTH_M", "RaggedOutlines", "ragged_outlines", "project_ragged"]

MIN_DEPTH_M = 0.3
# _corner_extremes: below this many rectangles, or with more corners than _MANY_CORNERS each, one
# reduction per edge beats 4 S element-wise calls (speed only: both give the same values)
_FEW_RECTS = 128
_MANY_CORNERS = 16


def project_rects(corners: np.ndarray, R: np.ndarray, t: np.ndarray, intr: CameraIntrinsics,
                  size: tuple[int, int], *, clip: bool = True, corner_uv: bool = False):
    """Project box corners for H poses.

    Args:
        corners: [M,S,3] LiDAR-frame points per box (metres).
        R: [H,3,3] or [3,3]; t: [H,3] or [3] (LiDAR -> camera).
        size: (width, height) px used for clipping.
    Returns:
        rects [H,M,4] (x1,y1,x2,y2 px; NaN where invalid), valid [H,M] bool: every corner in
        front of the camera and a non-empty clipped rectangle. With ``corner_uv`` also the pixel
        coordinates u, v [H,M,S] of every corner (NaN behind the camera; for the Jacobian;
        ``CameraIntrinsics`` only).

    ``intr`` may also be any camera model (:mod:`xcalib.geometry.camera_models`): the outline
    is then projected through it (box edges densely for a wide-angle model).
    """
    if not isinstance(intr, CameraIntrinsics):  # camera-model dispatch (CameraIntrinsics: below, unchanged)
        if corner_uv:
            raise TypeError("project_rects(corner_uv=True) is for CameraIntrinsics; other camera models give rects only")
        return project_outline_rects(corners, R, t, intr, size, clip=clip, min_distance=MIN_DEPTH_M)
    single, R, t, c = pose_batch(R, t, corners)
    H, M = len(R), len(c)
    if M == 0:
        out = no_rects(H, single)
        return out + (np.zeros((0, 0)),) * 2 if corner_uv else out
    u, v, ahead = _corner_pixels(c, R, t, intr)
    front = ahead.all(axis=2)
    rect = _corner_extremes(u, v)
    valid = finish_rects(rect, front, size, clip)
    if corner_uv:
        return (rect[0], valid[0], u[0], v[0]) if single else (rect, valid, u, v)
    return (rect[0], valid[0]) if single else (rect, valid)


@dataclass(frozen=True)
class RaggedOutlines:
    """Outlines [n,S,3] without their padding: ``flat`` [N,3] the vertices of every outline, row by
    row (outline i: ``flat[starts[i]:starts[i] + lengths[i]]``, the first ``lengths[i]`` vertices
    of its padded row). Padding is a trailing run of copies of an outline's first vertex (how
    outlines of different lengths share one array, see ``refine._padded``): dropping it changes no
    rectangle (min and max of the same points)."""

    flat: np.ndarray
    starts: np.ndarray
    lengths: np.ndarray
    padded: np.ndarray  # [n,S] the padded rows as indices into ``flat`` (padding: the row's first vertex)


def ragged_outlines(outlines: np.ndarray) -> RaggedOutlines:
    """The :class:`RaggedOutlines` of ``outlines`` [n,S,3] (n >= 1): each row cut after its last
    vertex that differs from its first one."""
    o = np.asarray(outlines, dtype=np.float64)
    n, S = o.shape[:2]
    same = o[:, :, 0] == o[:, :1, 0]  # [n,S] a vertex equal to its outline's first (per coordinate: no
    same &= o[:, :, 1] == o[:, :1, 1]  # reduction over a short last axis)
    same &= o[:, :, 2] == o[:, :1, 2]
    same[:, 0] = False  # the first vertex is kept
    lengths = S - np.argmin(same[:, ::-1], axis=1)  # the trailing run of copies of the first vertex dropped
    col = np.arange(S)[None, :]
    keep = col < lengths[:, None]
    flat = take_rows(np.ascontiguousarray(o).reshape(-1, 3), np.flatnonzero(keep))  # (row gathers, = o[keep])
    starts = np.cumsum(lengths) - lengths
    padded = starts[:, None] + np.where(keep, col, 0)
    return RaggedOutlines(flat, starts, lengths, padded)


def project_ragged(points: np.ndarray, starts: np.ndarray, R: np.ndarray, t: np.ndarray, intr: CameraIntrinsics,
                   size: tuple[int, int]):
    """``project_rects(outlines, R, t, intr, size, corner_uv=True)`` for one pose and a
    ``CameraIntrinsics`` from the outlines' vertices without padding (``points`` [N,3]: the
    ``RaggedOutlines.flat`` vertices, moved as the outlines are; ``starts`` [n] where each outline
    begins; n >= 1): the same rects [n,4] and valid [n] (each corner's pixels are computed as
    ``project_rects`` computes them, the extremes are exact) and the pixels u, v [N] of every
    vertex (NaN behind the camera)."""
    u, v, ahead = _corner_pixels(points[None], np.asarray(R, dtype=np.float64).reshape(1, 3, 3),
                                 np.asarray(t, dtype=np.float64).reshape(1, 3), intr)
    u, v, ahead = u[0, 0], v[0, 0], ahead[0, 0]
    front = np.logical_and.reduceat(ahead, starts)
    rect = np.empty((len(starts), 4))
    np.minimum.reduceat(u, starts, out=rect[:, 0])
    np.minimum.reduceat(v, starts, out=rect[:, 1])
    np.maximum.reduceat(u, starts, out=rect[:, 2])
    np.maximum.reduceat(v, starts, out=rect[:, 3])
    valid = finish_rects(rect, front, size, True)
    return rect, valid, u, v


def _corner_pixels(c: np.ndarray, R: np.ndarray, t: np.ndarray, intr: CameraIntrinsics):
    """Pixels u, v [H,M,S] of the corners c [M,S,3] at the poses R [H,3,3], t [H,3] (NaN behind the
    camera: depth <= ``MIN_DEPTH_M``) and ahead [H,M,S] (in front of it). Every value is computed
    corner by corner (one batched matrix product, then element-wise), so a corner's pixels do not
    depend on the other corners passed with it (``project_ragged`` relies on this)."""
    H, M, S = len(R), len(c), c.shape[1]
    X = np.matmul(R, c.reshape(-1, 3).T)  # [H,3,M*S] (batched BLAS)
    X += t[:, :, None]  # the arithmetic below runs in place on X (same operations, same values)
    z = X[:, 2].reshape(H, M, S)
    ahead = z > MIN_DEPTH_M
    inv = np.full(z.shape, np.nan)
    np.divide(1.0, z, out=inv, where=ahead)
    x = np.multiply(X[:, 0].reshape(H, M, S), inv, out=X[:, 0].reshape(H, M, S))
    y = np.multiply(X[:, 1].reshape(H, M, S), inv, out=X[:, 1].reshape(H, M, S))
    if intr.distortion is not None:
        # The polynomial model is meaningless far outside the field of view; clamp first.
        flat = np.clip(np.stack([x.ravel(), y.ravel()], 1), -1.5, 1.5)
        d = distort_normalized(flat, intr.distortion)
        x, y = d[:, 0].reshape(H, M, S), d[:, 1].reshape(H, M, S)
    u = np.multiply(x, intr.fx, out=x)  # x, y: views of X or of the fresh distorted array
    u += intr.cx
    v = np.multiply(y, intr.fy, out=y)
    v += intr.cy
    return u, v, ahead


def _corner_extremes(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """[H,M,4] (u.min, v.min, u.max, v.max over the last axis) of u, v [H,M,S]. Very few rectangles,
    or few with many corners each (a point outline): each a reduction over the corners as the outer
    axis (written into the result, no stacking); otherwise corner by corner with np.minimum /
    np.maximum, 4 S calls on the H*M rectangles at once (the reduction runs one short row per pose
    and corner: 200 poses x 18 boxes x 8 corners took 6x as long as the 32 calls). Both take
    the corners in the same order, with the same element-wise np.minimum / np.maximum (exact, NaN
    propagates), so the values are the same to the bit whichever runs."""
    H, M, S = u.shape
    rect = np.empty((H, M, 4))
    if H * M < _FEW_RECTS or (S > _MANY_CORNERS and H * M < 4096):
        ut, vt = u.transpose(0, 2, 1), v.transpose(0, 2, 1)
        np.minimum.reduce(ut, axis=1, out=rect[..., 0])
        np.minimum.reduce(vt, axis=1, out=rect[..., 1])
        np.maximum.reduce(ut, axis=1, out=rect[..., 2])
        np.maximum.reduce(vt, axis=1, out=rect[..., 3])
        return rect
    for k, (a, red) in enumerate(((u, np.minimum), (v, np.minimum), (u, np.maximum), (v, np.maximum))):
        rect[..., k] = a[..., 0]
        for j in range(1, S):
            red(rect[..., k], a[..., j], out=rect[..., k])
    return rect


def iou_batched(rects: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """IoU of observed boxes [K,4] with predicted rects [H,M,4] -> [H,K,M] (NaN rect -> 0).

    The [H,K,M] arithmetic runs in place on three buffers (the large arrays were a dozen fresh
    allocations, each paid again in page faults); the operations, and so the values, are unchanged."""
    r = np.nan_to_num(rects, nan=0.0)
    H, M = r.shape[:2]
    b = np.asarray(boxes, dtype=np.float64)
    rx0, ry0, rx1, ry1 = (np.ascontiguousarray(r[..., k]).reshape(H, 1, M) for k in range(4))
    bx0, by0, bx1, by1 = (b[:, k].reshape(1, -1, 1) for k in range(4))
    return iou_planes((rx0, ry0, rx1, ry1), (bx0, by0, bx1, by1))


def iou_planes(rect_edges: tuple, box_edges: tuple) -> np.ndarray:
    """IoU of rectangles given as broadcastable edge arrays (x0, y0, x1, y1) of predicted rects
    and of observed boxes (no NaN) -> the broadcast shape; 0 where the union is empty. Runs in
    place on three buffers of that shape (shared by :func:`iou_batched` and
    ``refine._match_frames``)."""
    rx0, ry0, rx1, ry1 = rect_edges
    bx0, by0, bx1, by1 = box_edges
    tmp = np.maximum(rx0, bx0)
    inter = np.minimum(rx1, bx1)
    inter -= tmp
    np.clip(inter, 0, None, out=inter)  # width of the overlap
    ih = np.minimum(ry1, by1)
    np.maximum(ry0, by0, out=tmp)
    ih -= tmp
    np.clip(ih, 0, None, out=ih)
    inter *= ih
    union = np.add((rx1 - rx0) * (ry1 - ry0), (bx1 - bx0) * (by1 - by0), out=ih)
    union -= inter
    pos = union > 0
    np.divide(inter, union, out=inter, where=pos)
    np.copyto(inter, 0.0, where=~pos)
    return inter
