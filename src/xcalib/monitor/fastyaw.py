"""The monitor's yaw fit for yaw-less 3D boxes: ``calib.boxmodel.fit_yaw_to_points``'s cost (the
points' capped distance to the nearest side of the turned rectangle; the side band above the
ground and below the roof) for all boxes of a frame in a few vectorised passes, so a frame at A9
density costs about a millisecond instead of tens.

Points: the cloud is first cut to the grid cells (``CELL_M``) the boxes touch and, per cell, to the
side bands in z of the boxes touching it (a table look-up), then to each box's half diagonal +
margin in x-y and its own side band in z. Headings: a
``step_deg`` grid over [0, 180) refined by a parabola. Contrast and ambiguity as in
``fit_yaw_to_points``.
"""

from __future__ import annotations

import numpy as np

__all__ = ["fit_yaw_batch", "points_near", "maybe_in_view"]

CELL_M = 4.0
MAX_POINTS = 160  # side points per box the heading cost is evaluated on (evenly thinned beyond)


def points_near(pts: np.ndarray, box7: np.ndarray, margin: float = 0.3, clearance: float = 0.3,
                side_top: float = 0.7) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(box index [K], x [K], y [K]) of every point inside a box's x-y half diagonal + ``margin``
    and its side band (``clearance`` above its bottom up to ``side_top`` of its height)."""
    b = np.asarray(box7, dtype=np.float64)
    p = np.asarray(pts)[:, :3]
    if not len(b) or not len(p):
        return np.zeros(0, np.int64), np.zeros(0), np.zeros(0)
    half = np.hypot(b[:, 3], b[:, 4]) / 2 + margin
    bottom = b[:, 2] - b[:, 5] / 2
    lo_z, hi_z = bottom + clearance, bottom + np.maximum(side_top * b[:, 5], clearance + 0.3)
    lo = np.floor((b[:, :2] - half[:, None]) / CELL_M).astype(np.int64)
    hi = np.floor((b[:, :2] + half[:, None]) / CELL_M).astype(np.int64)
    o = lo.min(0)
    shape = hi.max(0) - o + 1
    x, y, z = (np.ascontiguousarray(p[:, k]) for k in range(3))  # contiguous columns: strided ones are ~5x slower
    if shape[0] * shape[1] > 4_000_000:  # boxes kilometres apart: no table, every point is a candidate
        cand = np.arange(len(p))
    else:
        # per cell, the side band's z range over the boxes touching it (empty: lo > hi): boxes at
        # different heights (a sloped road, a truck beside a car) do not widen each other's band
        zlo = np.full(shape, np.inf)
        zhi = np.full(shape, -np.inf)
        for a, c, zl, zh in zip(lo - o, hi - o, lo_z, hi_z):
            cell = (slice(a[0], c[0] + 1), slice(a[1], c[1] + 1))
            zlo[cell] = np.minimum(zlo[cell], zl)
            zhi[cell] = np.maximum(zhi[cell], zh)
        # in the points' own precision (Python floats: float32 clouds stay float32): the cell
        # edges are multiples of CELL_M (exact); the z band is widened by a millimetre (and by
        # float32's rounding at large heights), as the per-cell bands below and each box's own
        # band decide in float64
        zb0, zb1 = float(lo_z.min()), float(hi_z.max())
        zb0, zb1 = zb0 - 1e-3 - 1e-6 * abs(zb0), zb1 + 1e-3 + 1e-6 * abs(zb1)
        inb = (z > zb0) & (z < zb1)
        inb &= (x >= float(o[0] * CELL_M)) & (x < float((o[0] + shape[0]) * CELL_M))
        inb &= (y >= float(o[1] * CELL_M)) & (y < float((o[1] + shape[1]) * CELL_M))
        cand = np.flatnonzero(inb)
        i = np.floor(x[cand] / CELL_M).astype(np.int64) - o[0]
        j = np.floor(y[cand] / CELL_M).astype(np.int64) - o[1]
        zc = z[cand]
        cand = cand[(zc > zlo[i, j]) & (zc < zhi[i, j])]
    qx, qy, qz = (c[cand].astype(np.float64) for c in (x, y, z))
    dx = qx[None, :] - b[:, None, 0]
    dy = qy[None, :] - b[:, None, 1]
    near = (dx * dx + dy * dy < (half * half)[:, None]) & (qz[None, :] > lo_z[:, None]) & (qz[None, :] < hi_z[:, None])
    bi, pi = np.nonzero(near)
    return bi, qx[pi], qy[pi]


def fit_yaw_batch(box7: np.ndarray, pts: np.ndarray, *, step_deg: float = 4.0, min_points: int = 8,
                  band_m: float = 0.3, ambiguity_deg: float = 20.0, min_contrast: float = 1.5,
                  min_aspect: float = 1.3) -> tuple[np.ndarray, np.ndarray]:
    """(boxes [M,7] with the fitted yaw, ambiguous [M] bool): ``fit_yaw_to_points``'s fit for
    every box at once (boxes with fewer than ``min_points`` side points keep their yaw; a box with
    more than ``MAX_POINTS`` is fitted on every k-th of them, at most ``MAX_POINTS``)."""
    b = np.array(box7, dtype=np.float64).reshape(-1, 7)
    M = len(b)
    fitted, contrast = np.zeros(M, dtype=bool), np.zeros(M)
    bi, qx, qy = points_near(pts, b)
    counts = np.bincount(bi, minlength=M)
    if len(bi) and counts.max() > MAX_POINTS:  # near boxes hold thousands of points: thin them evenly
        first = np.concatenate([[0], np.cumsum(counts)[:-1]])
        stride = np.maximum(1, -(-counts // MAX_POINTS))
        thin = ((np.arange(len(bi)) - first[bi]) % stride[bi]) == 0
        bi, qx, qy = bi[thin], qx[thin], qy[thin]
    use = counts[bi] >= min_points
    bi, qx, qy = bi[use], qx[use], qy[use]
    if len(bi):
        theta = np.radians(np.arange(0.0, 180.0, step_deg))
        # the [T, K] grid in single precision (half the memory traffic; the cost's resolution is a
        # fraction of the band's 0.3 m, far above float32's)
        cos_t, sin_t = np.cos(theta)[:, None].astype(np.float32), np.sin(theta)[:, None].astype(np.float32)
        dx, dy = (qx - b[bi, 0]).astype(np.float32), (qy - b[bi, 1]).astype(np.float32)
        # u, v: the point's distance beyond the long / short side (negative inside); the squared
        # distance to the outline is max(u, v)^2 inside and |(u, v)+|^2 outside, capped at the band
        # (in place: the [T, K] temporaries are the pass's cost)
        u = cos_t * dx
        u += sin_t * dy
        np.abs(u, out=u)
        u -= (b[bi, 3] / 2).astype(np.float32)
        v = cos_t * dy
        v -= sin_t * dx
        np.abs(v, out=v)
        v -= (b[bi, 4] / 2).astype(np.float32)
        m = np.maximum(u, v)
        inside = m <= 0
        np.maximum(u, 0, out=u)
        np.maximum(v, 0, out=v)
        u *= u
        v *= v
        u += v
        m *= m
        np.copyto(u, m, where=inside)
        d = np.minimum(u, np.float32(band_m) ** 2, out=u)  # [T, K]
        boxes, starts = np.unique(bi, return_index=True)  # bi is sorted (np.nonzero is row-major)
        cost = np.add.reduceat(d, starts, axis=1, dtype=np.float64).T  # [B, T]
        T = len(theta)
        k = np.argmin(cost, axis=1)
        rows = np.arange(len(boxes))
        cm, c0, cp = cost[rows, k - 1], cost[rows, k], cost[rows, (k + 1) % T]
        curv = cm - 2 * c0 + cp
        with np.errstate(divide="ignore", invalid="ignore"):
            step = np.where(curv > 0, np.clip(0.5 * (cm - cp) / curv, -1.0, 1.0), 0.0)
        b[boxes, 6] = theta[k] + np.radians(step_deg) * step
        deg = np.degrees(theta)
        away = np.abs((deg[k][:, None] - deg[None, :] + 90) % 180 - 90) > ambiguity_deg
        contrast[boxes] = np.where(away, cost, np.inf).min(1) / np.maximum(c0, 1e-9)
        fitted[boxes] = True
    aspect = np.maximum(b[:, 3], b[:, 4]) / np.maximum(np.minimum(b[:, 3], b[:, 4]), 1e-6)
    return b, (aspect >= min_aspect) & ~(fitted & (contrast >= min_contrast))


def maybe_in_view(box7: np.ndarray, R: np.ndarray, t: np.ndarray, intr, size: tuple[int, int] | None,
                  margin: float = 0.25) -> np.ndarray:
    """[M] bool: boxes the camera (pose ``R``, ``t``: LiDAR -> camera) may see. A box is dropped only
    when the sphere around it (its half space diagonal) lies wholly behind the camera or wholly
    outside the pinhole image widened by ``margin`` of its width / height on every side (a whole
    image width with lens distortion); a camera model other than ``CameraIntrinsics`` or an unknown
    image size keeps every box. The yaw of a box no 2D box can match is never used."""
    from ..geometry.camera import CameraIntrinsics

    b = np.asarray(box7, dtype=np.float64).reshape(-1, 7)
    keep = np.ones(len(b), dtype=bool)
    if not len(b) or size is None or not isinstance(intr, CameraIntrinsics):
        return keep
    X = b[:, :3] @ np.asarray(R, dtype=np.float64).T + np.asarray(t, dtype=np.float64)
    r = 0.5 * np.linalg.norm(b[:, 3:6], axis=1)
    Z = X[:, 2]
    near = Z - r <= 0.3  # touches the camera's plane: kept unless wholly behind it
    zs = np.where(near, 1.0, Z)
    ang = r / np.maximum(Z - r, 0.3)  # the sphere's angular radius (tangent, over-estimated)
    W, H = float(size[0]), float(size[1])
    m = 1.0 if intr.distortion is not None else float(margin)
    x0, x1 = (-intr.cx - m * W) / intr.fx, (W - intr.cx + m * W) / intr.fx
    y0, y1 = (-intr.cy - m * H) / intr.fy, (H - intr.cy + m * H) / intr.fy
    xn, yn = X[:, 0] / zs, X[:, 1] / zs
    inside = (xn + ang > x0) & (xn - ang < x1) & (yn + ang > y0) & (yn - ang < y1)
    keep = (Z > -r) & (near | inside)
    return keep | ~np.all(np.isfinite(X), axis=1)
