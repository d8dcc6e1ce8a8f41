"""3D box models for calibration: yaw re-estimation from the LiDAR points (box7, LiDAR frame).

Some exports (A9 r02_s01) lost the yaw of their 3D boxes: every box has its length along x.
A box's projected outline then misses its vehicle. ``estimate_yaw_from_points`` restores the
heading from the principal axis (in the x-y plane) of the points around the box centre.
"""

from __future__ import annotations

import numpy as np

__all__ = ["estimate_yaw_from_points", "shapes_from_points"]

# fixed, well-spread unit directions (Fibonacci sphere) for picking hull extremes
_n = np.arange(64) + 0.5
_phi = np.arccos(1 - 2 * _n / 64)
_theta = np.pi * (1 + 5 ** 0.5) * _n
_DIRS = np.stack([np.cos(_theta) * np.sin(_phi), np.sin(_theta) * np.sin(_phi), np.cos(_phi)], 1)
del _n, _phi, _theta


def estimate_yaw_from_points(boxes7: np.ndarray, points: np.ndarray, *, min_points: int = 12,
                             min_elongation: float = 1.6, radius_factor: float = 0.6) -> np.ndarray:
    """Return a copy of ``boxes7`` [M,7] with yaw (radians) re-estimated from ``points`` [P,3].

    For each box, the points within ``radius_factor * max(dx, dy)`` (x-y distance, metres) of its
    centre and above the lowest quarter of its height are used; the major axis of their x-y
    scatter becomes the box's length direction (``dx`` >= ``dy`` after the call). Boxes with fewer
    than ``min_points`` points, or a scatter that is not elongated (major/minor std ratio below
    ``min_elongation``), keep their yaw.
    """
    b = np.asarray(boxes7, dtype=np.float64).copy()
    pts = np.asarray(points, dtype=np.float64)[:, :3]
    if len(b) == 0 or len(pts) == 0:
        return b
    # A box's x-y extent cannot tell length from width; make dx the longer side.
    swap = b[:, 4] > b[:, 3]
    b[swap, 3], b[swap, 4] = b[swap, 4].copy(), b[swap, 3].copy()
    b[swap, 6] += np.pi / 2
    r = radius_factor * b[:, 3]
    lo = b[:, 2] - b[:, 5] / 2 + 0.25 * b[:, 5]
    hi = b[:, 2] + b[:, 5] / 2
    # Coarse pre-filter on the union of all boxes' bounds keeps the dense [M,P] step small.
    reach = r.max()
    keep = ((pts[:, 0] > b[:, 0].min() - reach) & (pts[:, 0] < b[:, 0].max() + reach)
            & (pts[:, 1] > b[:, 1].min() - reach) & (pts[:, 1] < b[:, 1].max() + reach)
            & (pts[:, 2] > lo.min()) & (pts[:, 2] < hi.max()))
    p = pts[keep]
    if len(p) == 0:
        return b
    dx = p[None, :, 0] - b[:, None, 0]
    dy = p[None, :, 1] - b[:, None, 1]
    m = ((dx * dx + dy * dy) <= (r * r)[:, None]) & (p[None, :, 2] >= lo[:, None]) & (p[None, :, 2] <= hi[:, None])
    w = m.astype(np.float64)
    n = w.sum(1)
    with np.errstate(invalid="ignore", divide="ignore"):
        mx = (w * dx).sum(1) / n
        my = (w * dy).sum(1) / n
        sxx = (w * dx * dx).sum(1) / n - mx * mx
        syy = (w * dy * dy).sum(1) / n - my * my
        sxy = (w * dx * dy).sum(1) / n - mx * my
    tr, det = sxx + syy, sxx * syy - sxy * sxy
    disc = np.sqrt(np.clip(tr * tr / 4 - det, 0, None))
    l1, l2 = tr / 2 + disc, np.clip(tr / 2 - disc, 1e-9, None)
    yaw = 0.5 * np.arctan2(2 * sxy, sxx - syy)
    ok = (n >= min_points) & np.isfinite(yaw) & (np.sqrt(l1 / l2) >= min_elongation)
    b[ok, 6] = yaw[ok]
    return b


def shapes_from_points(boxes7: np.ndarray, corners: np.ndarray, points: np.ndarray, *, min_points: int = 15,
                       max_vertices: int = 40, ground_clearance_m: float = 0.2,
                       expansion: float = 1.1) -> tuple[np.ndarray, np.ndarray]:
    """Per-box outline points [M,S,3] (LiDAR frame, metres) from the LiDAR points inside each box.

    The enclosing rectangle of a convex set's projection is that of its hull's projected vertices,
    so each box keeps the 3D convex-hull vertices of its points (ground points below
    ``ground_clearance_m`` above the box bottom excluded; the box grown by ``expansion`` in x-y)
    plus their vertical drop onto the box bottom (objects stand on the ground).
    Boxes with fewer than ``min_points`` points keep their 8 corners. Rows are padded by repeating
    their first vertex. Returns (shapes, from_points [M] bool).
    """
    from scipy.spatial import ConvexHull, QhullError

    from ..geometry.boxes import points_in_boxes

    b = np.asarray(boxes7, dtype=np.float64)
    M = len(b)
    if M == 0 or points is None or len(points) == 0:
        return corners, np.zeros(M, dtype=bool)
    grown = b.copy()
    grown[:, 3:5] *= expansion
    grown[:, 2] += ground_clearance_m / 2 + 0.05  # lift the bottom, add 0.1 m at the top
    grown[:, 5] += 0.1 - ground_clearance_m
    mask = points_in_boxes(points, grown)
    rows: list[np.ndarray] = []
    used = np.zeros(M, dtype=bool)
    for j in range(M):  # one hull per box (boxes, not points, are looped over)
        p = points[mask[j], :3].astype(np.float64)
        v = corners[j]
        if len(p) >= min_points:
            try:
                hv = p[ConvexHull(p).vertices]
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
            except (QhullError, ValueError):
                pass
        rows.append(v)
    S = max(len(r) for r in rows)
    out = np.empty((M, S, 3))
    for j, r in enumerate(rows):
        out[j, : len(r)] = r
        out[j, len(r):] = r[0]
    return out, used
