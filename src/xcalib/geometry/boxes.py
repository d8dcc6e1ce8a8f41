"""2D and 3D boxes.

2D boxes are ``[K,4]`` (x1, y1, x2, y2) in pixels, x1 < x2 and y1 < y2.

3D boxes come in three layouts, all in the LiDAR frame (metres):

* protocol ``[M,6]`` **extents** (xmin, ymin, zmin, xmax, ymax, zmax), axis-aligned;
* protocol ``[M,6]`` **center** (cx, cy, cz, dx, dy, dz), axis-aligned;
* ``box7`` ``[M,7]`` (cx, cy, cz, dx, dy, dz, yaw): ``dx`` is the length along the heading,
  ``yaw`` (radians) rotates the box about the LiDAR +z axis, counter-clockwise seen from above.

Protocol rows are told apart per row (protocol v1.0 §1): a row whose last three values are all
>= its first three is read as extents, otherwise as centre+dimensions. Pass
``convention="extents"`` or ``"center"`` to override the guess.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "CONVENTIONS", "detect_box3d_convention", "boxes3d_to_center_size", "boxes3d_to_extents",
    "center_size_to_extents", "extents_to_center_size", "as_box7", "box7_corners", "box7_to_extents", "expand_box7",
    "points_in_boxes", "box2d_centers", "box2d_sizes", "box2d_areas", "iou_matrix", "clip_boxes2d",
    "valid_boxes2d", "xyxy_to_xywh", "xywh_to_xyxy", "xyxy_to_cxcywh", "cxcywh_to_xyxy",
    "boxes2d_from_points", "check_boxes2d", "check_boxes3d",
]

CONVENTIONS = ("auto", "extents", "center")


# ----------------------------------------------------------------------------- checks
def check_boxes2d(b, name: str = "bboxes_2d") -> np.ndarray:
    """Return boxes as float64 [K,4]; raise ValueError naming ``name`` otherwise."""
    a = np.asarray(b, dtype=np.float64)
    if a.size == 0:
        return np.zeros((0, 4))
    if a.ndim != 2 or a.shape[1] != 4:
        raise ValueError(f"{name}: expected shape [K, 4] (x1, y1, x2, y2), got {a.shape}")
    return a


def check_boxes3d(b, name: str = "bboxes_3d", allow7: bool = True) -> np.ndarray:
    """Return boxes as float64 [M,6] or [M,7]; raise ValueError naming ``name`` otherwise."""
    a = np.asarray(b, dtype=np.float64)
    if a.size == 0:
        return np.zeros((0, 6))
    ok = (6, 7) if allow7 else (6,)
    if a.ndim != 2 or a.shape[1] not in ok:
        want = "[M, 6] or [M, 7]" if allow7 else "[M, 6]"
        raise ValueError(f"{name}: expected shape {want}, got {a.shape}")
    return a


# ------------------------------------------------------------------------ 3D layouts
def detect_box3d_convention(bboxes_3d) -> np.ndarray:
    """Per-row guess of the protocol convention: array of ``"extents"`` / ``"center"``."""
    b = check_boxes3d(bboxes_3d, allow7=False)
    is_ext = np.all(b[:, 3:6] >= b[:, 0:3], axis=1)
    return np.where(is_ext, "extents", "center")


def _is_extents(b: np.ndarray, convention: str) -> np.ndarray:
    if convention == "auto":
        return np.all(b[:, 3:6] >= b[:, 0:3], axis=1)
    if convention == "extents":
        return np.ones(len(b), dtype=bool)
    if convention == "center":
        return np.zeros(len(b), dtype=bool)
    raise ValueError(f"convention must be one of {CONVENTIONS}, got {convention!r}")


def extents_to_center_size(ext) -> np.ndarray:
    e = np.asarray(ext, dtype=np.float64).reshape(-1, 6)
    return np.hstack([(e[:, :3] + e[:, 3:]) / 2.0, e[:, 3:] - e[:, :3]])


def center_size_to_extents(cs) -> np.ndarray:
    c = np.asarray(cs, dtype=np.float64).reshape(-1, 6)
    half = np.abs(c[:, 3:]) / 2.0
    return np.hstack([c[:, :3] - half, c[:, :3] + half])


def boxes3d_to_center_size(bboxes_3d, convention: str = "auto") -> np.ndarray:
    """Protocol [M,6] boxes -> (cx, cy, cz, dx, dy, dz) with non-negative dims."""
    b = check_boxes3d(bboxes_3d, allow7=False)
    ext = _is_extents(b, convention)
    out = np.empty_like(b)
    out[ext] = extents_to_center_size(b[ext])
    out[~ext] = np.hstack([b[~ext, :3], np.abs(b[~ext, 3:])])
    return out


def boxes3d_to_extents(bboxes_3d, convention: str = "auto") -> np.ndarray:
    """Protocol [M,6] boxes -> (xmin, ymin, zmin, xmax, ymax, zmax)."""
    return center_size_to_extents(boxes3d_to_center_size(bboxes_3d, convention))


def as_box7(bboxes_3d, convention: str = "auto") -> np.ndarray:
    """Protocol [M,6] (yaw 0) or box7 [M,7] -> box7 [M,7] float64."""
    b = check_boxes3d(bboxes_3d)
    if b.shape[1] == 7:
        return b.copy()
    return np.hstack([boxes3d_to_center_size(b, convention), np.zeros((len(b), 1))])


# Corner order: bottom face (z-) counter-clockwise from (+x,+y) seen from above, then top face.
_CORNER_SIGNS = np.array([
    [1, 1, -1], [-1, 1, -1], [-1, -1, -1], [1, -1, -1],
    [1, 1, 1], [-1, 1, 1], [-1, -1, 1], [1, -1, 1],
], dtype=np.float64) / 2.0


def box7_corners(boxes7) -> np.ndarray:
    """box7 [M,7] -> corners [M,8,3] (bottom face first, then top face)."""
    b = as_box7(boxes7)
    local = _CORNER_SIGNS[None] * b[:, None, 3:6]
    c, s = np.cos(b[:, 6]), np.sin(b[:, 6])
    x = local[..., 0] * c[:, None] - local[..., 1] * s[:, None]
    y = local[..., 0] * s[:, None] + local[..., 1] * c[:, None]
    return np.stack([x, y, local[..., 2]], axis=-1) + b[:, None, :3]


def box7_to_extents(boxes7) -> np.ndarray:
    """box7 [M,7] -> protocol extents [M,6] (xmin, ymin, zmin, xmax, ymax, zmax): the
    axis-aligned box enclosing each yawed box (LiDAR frame, metres)."""
    c = box7_corners(boxes7)
    return np.hstack([c.min(axis=1), c.max(axis=1)]) if len(c) else np.zeros((0, 6))


def expand_box7(boxes7, factor: float = 1.25) -> np.ndarray:
    """Scale every box's dimensions by ``factor`` about its centre."""
    if factor <= 0:
        raise ValueError(f"expansion factor must be positive, got {factor}")
    b = as_box7(boxes7)
    b[:, 3:6] *= factor
    return b


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


# ---------------------------------------------------------------------------- 2D boxes
def box2d_centers(b) -> np.ndarray:
    a = check_boxes2d(b)
    return np.stack([(a[:, 0] + a[:, 2]) / 2.0, (a[:, 1] + a[:, 3]) / 2.0], axis=1)


def box2d_sizes(b) -> np.ndarray:
    a = check_boxes2d(b)
    return np.stack([a[:, 2] - a[:, 0], a[:, 3] - a[:, 1]], axis=1)


def box2d_areas(b) -> np.ndarray:
    wh = np.clip(box2d_sizes(b), 0.0, None)
    return wh[:, 0] * wh[:, 1]


def valid_boxes2d(b) -> np.ndarray:
    a = check_boxes2d(b)
    return (a[:, 2] > a[:, 0]) & (a[:, 3] > a[:, 1]) & np.all(np.isfinite(a), axis=1)


def iou_matrix(a, b) -> np.ndarray:
    """IoU of every box in ``a`` [K,4] with every box in ``b`` [N,4] -> [K,N]."""
    A, B = check_boxes2d(a, "a"), check_boxes2d(b, "b")
    x1 = np.maximum(A[:, None, 0], B[None, :, 0])
    y1 = np.maximum(A[:, None, 1], B[None, :, 1])
    x2 = np.minimum(A[:, None, 2], B[None, :, 2])
    y2 = np.minimum(A[:, None, 3], B[None, :, 3])
    inter = np.clip(x2 - x1, 0, None) * np.clip(y2 - y1, 0, None)
    union = box2d_areas(A)[:, None] + box2d_areas(B)[None, :] - inter
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(union > 0, inter / union, 0.0)


def clip_boxes2d(b, width: int, height: int) -> np.ndarray:
    a = check_boxes2d(b).copy()
    a[:, [0, 2]] = np.clip(a[:, [0, 2]], 0, width)
    a[:, [1, 3]] = np.clip(a[:, [1, 3]], 0, height)
    return a


def boxes2d_from_points(uv) -> np.ndarray:
    """Enclosing rectangles of point sets: uv [M,N,2] (NaN ignored) -> [M,4]; all-NaN -> NaN row."""
    uv = np.asarray(uv, dtype=np.float64)
    with np.errstate(all="ignore"):
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            lo = np.nanmin(uv, axis=1)
            hi = np.nanmax(uv, axis=1)
    return np.hstack([lo, hi])


def xyxy_to_xywh(b) -> np.ndarray:
    a = check_boxes2d(b)
    return np.hstack([a[:, :2], a[:, 2:] - a[:, :2]])


def xywh_to_xyxy(b) -> np.ndarray:
    a = check_boxes2d(b)
    return np.hstack([a[:, :2], a[:, :2] + a[:, 2:]])


def xyxy_to_cxcywh(b) -> np.ndarray:
    a = check_boxes2d(b)
    return np.hstack([(a[:, :2] + a[:, 2:]) / 2.0, a[:, 2:] - a[:, :2]])


def cxcywh_to_xyxy(b) -> np.ndarray:
    a = check_boxes2d(b)
    return np.hstack([a[:, :2] - a[:, 2:] / 2.0, a[:, :2] + a[:, 2:] / 2.0])
