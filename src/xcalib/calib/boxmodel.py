"""3D box models for calibration: yaw re-estimation from the LiDAR points (box7, LiDAR frame).

Some exports (A9 r02_s01) lost the yaw of their 3D boxes: every box has its length along x.
A box's projected outline then misses its vehicle. ``estimate_yaw_from_points`` restores the
heading from the principal axis (in the x-y plane) of the points around the box centre.
"""

from __future__ import annotations

import numpy as np

__all__ = ["estimate_yaw_from_points"]


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
