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
    "points_in_boxes", "box_point_pairs", "take_rows", "box2d_centers", "box2d_sizes", "box2d_areas", "iou_matrix", "clip_boxes2d",
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


def _box_affines(b: np.ndarray) -> np.ndarray:
    """[M,3,4] float32 affine maps sending each box7's inside to the cube [-1, 1]^3."""
    c, s = np.cos(b[:, 6]), np.sin(b[:, 6])
    inv_half = 2.0 / np.maximum(b[:, 3:6], 1e-9)
    A = np.zeros((len(b), 3, 4))
    A[:, 0, 0], A[:, 0, 1] = c * inv_half[:, 0], s * inv_half[:, 0]
    A[:, 1, 0], A[:, 1, 1] = -s * inv_half[:, 1], c * inv_half[:, 1]
    A[:, 2, 2] = inv_half[:, 2]
    A[:, :, 3] = -np.einsum("mij,mj->mi", A[:, :, :3], b[:, :3])
    return A.astype(np.float32)


_GRID = 128  # cells per axis of the x-y grid over the boxes' footprints (candidate search)
_FEW_BOXES = 32  # up to this many boxes, occupancy is marked box by box (else a 2D prefix sum)


def _box_footprints(b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned x-y footprint (lo [M,2], hi [M,2], metres, 1 mm margin) of each box7."""
    c, s = np.abs(np.cos(b[:, 6])), np.abs(np.sin(b[:, 6]))
    half = np.stack([c * b[:, 3] + s * b[:, 4], s * b[:, 3] + c * b[:, 4]], 1) / 2 + 1e-3
    return b[:, :2] - half, b[:, :2] + half


def _grid_cells(xy: np.ndarray, lo: np.ndarray, hi: np.ndarray):
    """``xy`` [P,>=2] float32 points. An x-y grid of G x G cells over the footprints (padded), framed by a border of cells
    (index 0 and G+1) that takes every point outside: the cell id of every point [P] int32 and
    each box's inclusive cell rectangle lo_c, hi_c [M,2] int64 (one cell of margin), inside
    1..G. A point inside a box is in a cell of that box's rectangle whatever the float32 rounding."""
    G = _GRID
    pad = 2.0 * (hi.max(0) - lo.min(0)) / G + 0.1  # > one cell: rectangles stay off the border
    org = lo.min(0) - pad
    cell = (hi.max(0) + pad - org) / G
    cells = np.empty((2, len(xy)), dtype=np.int32)
    with np.errstate(invalid="ignore"):  # NaN / huge: some int (INT_MIN or saturated), clipped below
        for a in range(2):  # x, then y: one strided read each, then contiguous float32 passes
            f = xy[:, a] * np.float32(1.0 / cell[a])
            f += np.float32(1.0 - org[a] / cell[a])
            cells[a] = f  # truncation toward zero: every f < 1 gives <= 0, the border after the clip
    np.clip(cells, 0, G + 1, out=cells)  # out-of-grid, NaN and huge coordinates land on the border
    cid = cells[1] * (G + 2) + cells[0]
    lo_c = np.clip(np.floor((lo - org) / cell), 1, G).astype(np.int64)  # + 1 border - 1 margin
    hi_c = np.clip(np.floor((hi - org) / cell) + 2, 1, G).astype(np.int64)
    return cid, lo_c, hi_c


def _occupied(cid: np.ndarray, lo_c: np.ndarray, hi_c: np.ndarray) -> np.ndarray:
    """Indices of the points whose cell lies in some box's cell rectangle (2D prefix sum)."""
    if len(lo_c) <= _FEW_BOXES:  # a few boxes: mark their rectangles directly
        occ = np.zeros((_GRID + 2, _GRID + 2), dtype=bool)
        for (x0, y0), (x1, y1) in zip(lo_c.tolist(), hi_c.tolist()):
            occ[y0:y1 + 1, x0:x1 + 1] = True
        return np.flatnonzero(occ.ravel().take(cid))
    n = _GRID + 3
    d = np.zeros((n, n), dtype=np.int32)
    np.add.at(d, (lo_c[:, 1], lo_c[:, 0]), 1)
    np.add.at(d, (lo_c[:, 1], hi_c[:, 0] + 1), -1)
    np.add.at(d, (hi_c[:, 1] + 1, lo_c[:, 0]), -1)
    np.add.at(d, (hi_c[:, 1] + 1, hi_c[:, 0] + 1), 1)
    occ = d.cumsum(0).cumsum(1)[: n - 1, : n - 1] > 0
    return np.flatnonzero(occ.ravel().take(cid))


def box_point_pairs(points, boxes, *, expansion: float = 1.0, convention: str = "auto"
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Every (box, point) with the point inside the box: (box index [T], point index [T]) int64,
    sorted by box, then point (the row-major order of :func:`points_in_boxes`' mask).

    Candidates come from an x-y grid over the boxes' footprints (a box visits only the cells its
    footprint covers); each candidate is then tested in the box's frame (float32). Cost: a few
    vector passes over the points plus the points near boxes, never M x P.
    """
    pts = np.asarray(points)
    if pts.ndim != 2 or pts.shape[1] < 3:
        raise ValueError(f"points: expected shape [P, >=3], got {pts.shape}")
    b = expand_box7(as_box7(boxes, convention), expansion) if len(np.asarray(boxes).reshape(-1)) else np.zeros((0, 7))
    none = (np.zeros(0, np.int64), np.zeros(0, np.int64))
    if len(b) == 0 or len(pts) == 0:
        return none
    finite = np.all(np.isfinite(b), axis=1)
    if not finite.all():  # a non-finite box holds no point
        idx = np.flatnonzero(finite)
        mi, pi = box_point_pairs(pts, b[idx], convention=convention)
        return idx[mi], pi
    xyz = pts[:, :3] if pts.dtype == np.float32 else pts[:, :3].astype(np.float32)
    lo, hi = _box_footprints(b)
    cid, lo_c, hi_c = _grid_cells(xyz, lo, hi)
    cand = _occupied(cid, lo_c, hi_c)
    n = _GRID + 2
    cc = cid[cand].astype(np.uint16)  # (G+2)^2 < 2^16 cells: numpy's radix sort
    order = np.argsort(cc, kind="stable")
    cc = cc[order]
    nrows = hi_c[:, 1] - lo_c[:, 1] + 1
    seg_box = np.repeat(np.arange(len(b)), nrows)
    seg_row = lo_c[seg_box, 1] + np.arange(len(seg_box)) - np.repeat(np.cumsum(nrows) - nrows, nrows)
    seg_start = np.searchsorted(cc, seg_row * n + lo_c[seg_box, 0], "left")
    lens = np.searchsorted(cc, seg_row * n + hi_c[seg_box, 0], "right") - seg_start
    total = int(lens.sum())
    if total == 0:
        return none
    mi = np.repeat(seg_box, lens)
    pi = cand[order[np.repeat(seg_start, lens) + np.arange(total) - np.repeat(np.cumsum(lens) - lens, lens)]]
    inside = _inside(_box_affines(b), mi, np.ascontiguousarray(take_rows(xyz, pi).T))
    key = np.sort(mi[inside] * len(pts) + pi[inside])
    return key // len(pts), key % len(pts)


def take_rows(a: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """``a[idx]`` for a 2D array: rows of a C-contiguous array are gathered as single opaque
    items (one copy per row instead of one per element); the same values as ``a[idx]``."""
    if a.ndim != 2 or not a.flags.c_contiguous or a.shape[1] == 0:
        return a[idx]
    rows = a.view(np.dtype((np.void, a.shape[1] * a.itemsize)))[:, 0]
    return rows.take(idx).view(a.dtype).reshape(*np.shape(idx), a.shape[1])


def _inside(Af: np.ndarray, mi: np.ndarray, p: np.ndarray) -> np.ndarray:
    """[T] bool: point p[:, t] (float32 [3,T]) inside box mi[t] (affines ``Af`` [M,3,4] float32)."""
    px, py, pz = p
    a = np.ascontiguousarray(Af.reshape(-1, 12).T)  # coefficient rows [12, M]: contiguous gathers
    inside = np.abs(a[10][mi] * pz + a[11][mi]) <= 1.0
    inside &= np.abs(a[0][mi] * px + a[1][mi] * py + a[3][mi]) <= 1.0
    inside &= np.abs(a[4][mi] * px + a[5][mi] * py + a[7][mi]) <= 1.0
    return inside


def points_in_boxes(points, boxes, *, expansion: float = 1.0, convention: str = "auto") -> np.ndarray:
    """Which points lie in which boxes, for many boxes at once.

    Args:
        points: [P, >=3] LiDAR-frame points (metres).
        boxes: protocol [M,6] boxes or box7 [M,7] (yaw honoured).
        expansion: scale factor on the box dimensions (protocol ``bbox_expansion``).
    Returns:
        bool mask [M, P] (the pairs of :func:`box_point_pairs`).
    """
    pts = np.asarray(points)
    mi, pi = box_point_pairs(pts, boxes, expansion=expansion, convention=convention)
    M = len(check_boxes3d(boxes))
    mask = np.zeros((M, len(pts)), dtype=bool)
    mask[mi, pi] = True
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
