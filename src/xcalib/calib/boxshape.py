"""3D box models for calibration: yaw re-estimation from the LiDAR points (box7, LiDAR frame).

Some exports (A9 r02_s01) lost the yaw of their 3D boxes: every box has its length along x.
A box's projected outline then misses its vehicle. ``fit_yaw_to_points`` restores the heading
by turning the box (centre and size kept) until its outline best fits the points around it (a
LiDAR sees an L or one face of a vehicle; the principal axis of such points, used up to 0.4,
is biased: 11.6 deg median error on the synthetic no-yaw sites against 0.2 deg for the fit).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

__all__ = ["YawFit", "YawFitSettings", "fit_yaw_to_points", "estimate_yaw_from_points", "lidar_angular_step", "expand_by_scan_gap",
           "shapes_from_points"]

# fixed, well-spread unit directions (Fibonacci sphere) for picking hull extremes
_n = np.arange(64) + 0.5
_phi = np.arccos(1 - 2 * _n / 64)
_theta = np.pi * (1 + 5 ** 0.5) * _n
_DIRS = np.stack([np.cos(_theta) * np.sin(_phi), np.sin(_theta) * np.sin(_phi), np.cos(_phi)], 1)
del _n, _phi, _theta


@dataclass(frozen=True)
class YawFit:
    """Yaw fitted to the LiDAR points of yaw-less boxes (see :func:`fit_yaw_to_points`).

    boxes7 [M,7]: the boxes with the fitted yaw (radians; unchanged where not fitted).
    fitted [M] bool: yaw taken from the points. n_points [M]: points used.
    contrast [M]: cost of the best yaw more than ``ambiguity_deg`` away divided by the cost of the
    best (large: one clear heading; near 1: the points do not tell). ambiguous [M] bool: a box
    whose heading matters (length/width >= ``min_aspect``) but is not fitted or not clear.
    """

    boxes7: np.ndarray
    fitted: np.ndarray
    n_points: np.ndarray
    contrast: np.ndarray
    ambiguous: np.ndarray


def _rect_cost(dx: np.ndarray, dy: np.ndarray, half_l: float, half_w: float, cos_t: np.ndarray,
               sin_t: np.ndarray, band_m: float) -> np.ndarray:
    """Robust cost [T] of points (dx, dy offsets from the centre, m) lying on the outline of a
    half_l x half_w rectangle turned by each angle: distance to the nearest side, capped at band_m.

    With u, v the point's distances outside the two pairs of sides (negative inside), the distance
    is -max(u, v) inside, the positive one of u, v when only one is (``hypot(u, 0) == |u|``
    exactly) and ``hypot(u, v)`` beyond a corner (both positive): so |max(u, v)| everywhere but
    beyond the corners, where ``hypot`` is taken only for the points nearer than ``band_m`` (it is
    >= max(u, v), so the others are capped anyway). The same values, to the bit, as taking
    ``hypot(max(u, 0), max(v, 0))`` outside and ``min(-u, -v)`` inside for every point."""
    c, s = cos_t[:, None], sin_t[:, None]  # np.outer's own products, without its wrapper
    u = c * dx
    u += s * dy
    np.abs(u, out=u)
    u -= half_l
    v = c * dy
    v -= s * dx  # (-sin) dx + cos dy, the same bits
    np.abs(v, out=v)
    v -= half_w
    m = np.maximum(u, v)
    corner = np.minimum(u, v) > 0
    corner &= m < band_m
    d = np.abs(m, out=m)
    np.minimum(d, band_m, out=d)
    if corner.any():
        d[corner] = np.minimum(np.hypot(u[corner], v[corner]), band_m)
    d *= d
    return d.sum(1)


@dataclass(frozen=True)
class YawFitSettings:
    """The settings of :func:`fit_yaw_to_points` (m, deg; see there): the fewest side points a fit
    needs, which points count as the sides (``ground_clearance_m`` above the bottom up to
    ``side_top`` of the height, within the half diagonal + ``margin_m``), the distance cap
    ``band_m``, the heading grid ``step_deg``, and when a fit is ambiguous (``ambiguity_deg``,
    ``min_contrast``, ``min_aspect``)."""

    min_points: int = 8
    ground_clearance_m: float = 0.3
    side_top: float = 0.7
    band_m: float = 0.3
    margin_m: float = 0.3
    step_deg: float = 1.0
    ambiguity_deg: float = 20.0
    min_contrast: float = 1.5
    min_aspect: float = 1.3


class _NearXY:
    """The points [P,>=2] within a distance of a point in x-y (a disc query): the points bucketed by
    x once (``cell_m`` wide buckets, a stable radix sort of 16-bit bucket numbers instead of a sort
    of the coordinates), each query the buckets its x-window touches, found by bisection, and the
    exact test there (a k-d tree's build cost more than all of one frame's queries). The bucket of
    a point is a monotonic function of its x, so the window's buckets hold every point of the
    window. Returns the rows in ascending order."""

    def __init__(self, pts: np.ndarray, cell_m: float = 0.5):
        self.x, self.y = pts[:, 0], pts[:, 1]
        self.cell = float(cell_m)
        keys = self._bucket(self.x)
        self.order = np.argsort(keys, kind="stable")
        self.keys = keys[self.order]

    def _bucket(self, x: np.ndarray) -> np.ndarray:
        return np.clip(np.floor(x / self.cell), -32000, 32000).astype(np.int16)

    def _bucket_of(self, x: float) -> int:
        """``_bucket`` of one coordinate (Python's float division and floor are the same IEEE ones)."""
        return min(max(math.floor(x / self.cell), -32000), 32000) if math.isfinite(x) else (
            32000 if x > 0 else -32000)

    def within(self, x: float, y: float, r: float) -> np.ndarray:
        """Rows with (px - x)^2 + (py - y)^2 <= r^2, ascending."""
        pad = r + 1e-9 * (1.0 + abs(x) + r)  # the window a little wider: the exact test decides
        lo_key, hi_key = self._bucket_of(x - pad), self._bucket_of(x + pad)
        lo = int(np.searchsorted(self.keys, lo_key, side="left"))
        hi = int(np.searchsorted(self.keys, hi_key, side="right"))
        rows = self.order[lo:hi]
        dx, dy = self.x[rows] - x, self.y[rows] - y
        return np.sort(rows[dx * dx + dy * dy <= r * r])


def fit_yaw_to_points(boxes7: np.ndarray, points: np.ndarray, settings: YawFitSettings | None = None,
                      **changes: Any) -> YawFit:
    """Fit the yaw of each box7 [M,7] (LiDAR frame, m) to the LiDAR points [P,>=3] around it.
    ``settings`` (default: :class:`YawFitSettings`) with ``changes`` (its field names, e.g.
    ``min_points=5``) applied.

    The box keeps its centre and its size (x-y extent ``dx`` becomes the length along the fitted
    heading). A LiDAR sees the faces turned to it (an L or a single face), so the points lie on
    the box outline: every heading in [0, 180) deg (``step_deg`` grid, refined by a parabola) is
    scored by the points' distance to the nearest side of the turned rectangle (capped at
    ``band_m``). Points used: within the box's half diagonal + ``margin_m`` (x-y) of its centre,
    from ``ground_clearance_m`` above its bottom up to ``side_top`` of its height: the sides, not
    the roof (roof returns fill the footprint and pull a side onto them; a car's greenhouse is
    inset from its footprint). Boxes with fewer than ``min_points`` such points keep their yaw.
    """
    st = replace(settings or YawFitSettings(), **changes)
    min_points, ground_clearance_m, side_top, band_m = st.min_points, st.ground_clearance_m, st.side_top, st.band_m
    margin_m, step_deg, ambiguity_deg, min_contrast, min_aspect = st.margin_m, st.step_deg, st.ambiguity_deg, \
        st.min_contrast, st.min_aspect
    b = np.asarray(boxes7, dtype=np.float64).copy()
    M = len(b)
    fitted, n_used = np.zeros(M, dtype=bool), np.zeros(M, dtype=np.int64)
    contrast = np.zeros(M)
    pts = np.zeros((0, 3)) if points is None else np.asarray(points, dtype=np.float64).reshape(-1, np.shape(points)[-1])[:, :3]
    if M and len(pts):
        near = _NearXY(pts)
        theta = np.radians(np.arange(0.0, 180.0, step_deg))
        cos_t, sin_t = np.cos(theta), np.sin(theta)
        away = np.abs((np.degrees(theta)[:, None] - np.degrees(theta)[None, :] + 90) % 180 - 90) > ambiguity_deg
        for j in range(M):  # one small point set per box
            x, y, z, ln, wd, h = b[j, :6]
            p = pts[near.within(x, y, float(np.hypot(ln, wd) / 2 + margin_m))]
            bottom = z - h / 2
            p = p[(p[:, 2] > bottom + ground_clearance_m) & (p[:, 2] < bottom + max(side_top * h, ground_clearance_m + 0.3))]
            n_used[j] = len(p)
            if len(p) < min_points:
                continue
            cost = _rect_cost(p[:, 0] - x, p[:, 1] - y, ln / 2, wd / 2, cos_t, sin_t, band_m)
            k = int(np.argmin(cost))
            cm, c0, cp = cost[k - 1], cost[k], cost[(k + 1) % len(cost)]
            curv = cm - 2 * c0 + cp
            step = float(np.clip(0.5 * (cm - cp) / curv, -1.0, 1.0)) if curv > 0 else 0.0
            b[j, 6] = theta[k] + np.radians(step_deg) * step
            contrast[j] = cost[away[k]].min() / max(c0, 1e-9)
            fitted[j] = True
    aspect = np.maximum(b[:, 3], b[:, 4]) / np.maximum(np.minimum(b[:, 3], b[:, 4]), 1e-6)
    ambiguous = (aspect >= min_aspect) & ~(fitted & (contrast >= min_contrast))
    return YawFit(boxes7=b, fitted=fitted, n_points=n_used, contrast=contrast, ambiguous=ambiguous)


def estimate_yaw_from_points(boxes7: np.ndarray, points: np.ndarray, **kwargs) -> np.ndarray:
    """Return a copy of ``boxes7`` [M,7] with the yaw (radians) fitted to ``points`` [P,3]
    (:func:`fit_yaw_to_points`; boxes with too few points keep their yaw)."""
    return fit_yaw_to_points(boxes7, points, **kwargs).boxes7


def lidar_angular_step(points: np.ndarray, *, n_sample: int = 500, k: int = 48, min_range_m: float = 3.0,
                       seed: int = 0) -> tuple[float, float] | None:
    """(azimuth step, elevation step) in radians of the scan pattern of a LiDAR cloud [P,>=3]
    (sensor at the origin): over a seeded sample of returns, the median angular distance to the
    nearest return in the same ring, and to the nearest return of the next ring in the same azimuth
    column (among the ``k`` nearest in angle). None with < 50 points or no such neighbours."""
    from scipy.spatial import cKDTree

    q = np.asarray(points).reshape(-1, np.shape(points)[-1])
    # one contiguous float64 column per axis: the range is ``np.linalg.norm(p, axis=1)``'s
    # sqrt((x * x + y * y) + z * z), the same bits without the strided [P,3] passes
    x, y, z = (np.asarray(q[:, j], dtype=np.float64) for j in range(3))
    r2 = x * x
    r2 += y * y
    r2 += z * z
    near = np.sqrt(r2, out=r2) > min_range_m
    x, y, z = x[near], y[near], z[near]
    if len(x) < 50:
        return None
    ang = np.empty((len(x), 2))
    ang[:, 0] = np.arctan2(y, x)
    ang[:, 1] = np.arctan2(z, np.hypot(x, y))
    # an unbalanced tree builds in about half the time of a median-balanced one, and one whose
    # nodes keep their split bounds (not shrunk to their points) in about 3/4 of that, with the
    # same k nearest neighbours (a k-d tree's query is exact whatever its split points and bounds)
    tree = cKDTree(ang, balanced_tree=False, compact_nodes=False)
    s = ang[np.random.default_rng(seed).choice(len(ang), size=min(n_sample, len(ang)), replace=False)]
    dist, idx = tree.query(s, k=min(k, len(ang)))
    step = float(np.median(dist[:, 1]))
    if not step > 0:
        return None
    d = np.abs(ang[idx] - s[:, None, :])
    col = (d[..., 0] < 0.6 * step) & (d[..., 1] > 0.5 * step)
    row = (d[..., 1] < 0.3 * step) & (d[..., 0] > 1e-9)
    d_el = np.where(col, d[..., 1], np.inf).min(1)
    d_az = np.where(row, d[..., 0], np.inf).min(1)
    d_el, d_az = d_el[np.isfinite(d_el)], d_az[np.isfinite(d_az)]
    if len(d_el) < 10 or len(d_az) < 10:
        return None
    return float(np.median(d_az)), float(np.median(d_el))


def expand_by_scan_gap(vertices: np.ndarray, step_rad: tuple[float, float]) -> np.ndarray:
    """Points where the surface of an object sampled at ``vertices`` [N,3] (LiDAR frame) is expected
    to end: a LiDAR misses up to one scan step beyond its last return, half a step on average. Each
    vertex is turned about the sensor by half the (azimuth, elevation) step both ways at its own
    range (as a camera beside the LiDAR sees it: half a step further out). The box is not used: a
    detected box's centre and size are noisier than the returns. Returns [4N,3]."""
    v = np.asarray(vertices, dtype=np.float64)
    r = np.linalg.norm(v, axis=1, keepdims=True)
    u = v / np.maximum(r, 1e-9)
    az, el = np.arctan2(u[:, 1], u[:, 0]), np.arcsin(np.clip(u[:, 2], -1, 1))
    e_az = np.column_stack([-np.sin(az), np.cos(az), np.zeros_like(az)])
    e_el = np.column_stack([-np.sin(el) * np.cos(az), -np.sin(el) * np.sin(az), np.cos(el)])
    out = []
    for e, half in ((e_az, step_rad[0] / 2), (-e_az, step_rad[0] / 2), (e_el, step_rad[1] / 2), (-e_el, step_rad[1] / 2)):
        d = u * np.cos(half) + e * np.sin(half)
        out.append(d * r)
    return np.concatenate(out)


def shapes_from_points(boxes7: np.ndarray, corners: np.ndarray, points: np.ndarray, *, min_points: int = 15,
                       max_vertices: int = 40, ground_clearance_m: float = 0.2,
                       expansion: float = 1.1, scan_step_rad: tuple[float, float] | None = None
                       ) -> tuple[np.ndarray, np.ndarray]:
    """Per-box outline points [M,S,3] (LiDAR frame, metres) from the LiDAR points inside each box.

    The enclosing rectangle of a convex set's projection is that of its hull's projected vertices,
    so each box keeps the 3D convex-hull vertices of its points (ground points below
    ``ground_clearance_m`` above the box bottom excluded; the box grown by ``expansion`` in x-y)
    plus their vertical drop onto the box bottom (objects stand on the ground).
    ``scan_step_rad`` (azimuth, elevation steps of the LiDAR, see :func:`lidar_angular_step`): the
    hull is first grown by half a scan step (:func:`expand_by_scan_gap`): the last
    return on an object lies on average half a step inside its silhouette (on the synthetic no-yaw
    sites the bare hull's top edge sat 10 px, 5 % of the box height, below the object's).
    Boxes with fewer than ``min_points`` points keep their 8 corners. Rows are padded by repeating
    their first vertex. Returns (shapes, from_points [M] bool).
    """
    from scipy.spatial import ConvexHull, QhullError

    from ..geometry.boxes import box_point_pairs

    b = np.asarray(boxes7, dtype=np.float64)
    M = len(b)
    if M == 0 or points is None or len(points) == 0:
        return corners, np.zeros(M, dtype=bool)
    grown = b.copy()
    grown[:, 3:5] *= expansion
    grown[:, 2] += ground_clearance_m / 2 + 0.05  # lift the bottom, add 0.1 m at the top
    grown[:, 5] += 0.1 - ground_clearance_m
    # each box's points: ``points_in_boxes``' pairs, sorted by box then point, cut at each box's start
    # (the rows of its mask in ascending order, without the [M,P] mask and one pass over it per box)
    mi, pi = box_point_pairs(points, grown)
    starts = np.searchsorted(mi, np.arange(M + 1))
    used = np.zeros(M, dtype=bool)
    # first the hull of each box's points, then (with a scan step) one growth of all the boxes'
    # hull vertices at once (``expand_by_scan_gap`` works point by point: the same values as box
    # by box), then each box's hull of its vertices and their growth
    hulls: list[np.ndarray | None] = [None] * M
    for j in range(M):  # one hull per box (boxes, not points, are looped over)
        p = points[pi[starts[j]:starts[j + 1]], :3].astype(np.float64)
        if len(p) >= min_points:
            try:
                hulls[j] = p[ConvexHull(p).vertices]
            except (QhullError, ValueError):
                pass
    if scan_step_rad is not None and any(h is not None for h in hulls):
        firsts = [h for h in hulls if h is not None]
        grown_all = expand_by_scan_gap(np.concatenate(firsts), scan_step_rad).reshape(4, -1, 3)
        ends = np.cumsum([len(h) for h in firsts])
        k = 0
        for j in range(M):
            if hulls[j] is None:
                continue
            hv = hulls[j]
            grown_hv = np.concatenate([hv, grown_all[:, ends[k] - len(hv): ends[k]].reshape(-1, 3)])
            k += 1
            try:
                hulls[j] = grown_hv[ConvexHull(grown_hv).vertices]
            except (QhullError, ValueError):
                hulls[j] = None
    rows: list[np.ndarray] = []
    for j in range(M):
        hv, v = hulls[j], corners[j]
        if hv is not None:
            if len(hv) > max_vertices:
                # keep the extremes along many directions
                dirs = _DIRS[: max(max_vertices // 2, 3)]
                proj = hv @ dirs.T
                keep = np.unique(np.concatenate([proj.argmax(0), proj.argmin(0)]))
                hv = hv[keep]
            # the object stands on the ground: add the hull's shadow on the box bottom, which
            # the LiDAR rarely sees (wheels, occluded lower parts) but the camera box includes
            foot = hv.copy()
            foot[:, 2] = b[j, 2] - b[j, 5] / 2
            v = np.concatenate([hv, foot])
            used[j] = True
        rows.append(v)
    S = max(len(r) for r in rows)
    out = np.empty((M, S, 3))
    for j, r in enumerate(rows):
        out[j, : len(r)] = r
        out[j, len(r):] = r[0]
    return out, used
