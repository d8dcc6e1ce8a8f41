"""Issue 29, consensus speed: the faster input preparation (yaw-fit cost, disc queries, scan step,
point hulls), the batched distinct-pose pick and the sparse explained-IoU maxima give the same
values, to the bit, as the straightforward formulas they replace (written out here)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import ConvexHull, cKDTree
from scipy.spatial.transform import Rotation

from xcalib.calib import boxshape
from xcalib.calib.boxproj import iou_batched
from xcalib.calib.consensus import _distinct, _distinct_best
from xcalib.calib.match_sparse import explained_iou
from xcalib.geometry.boxes import box7_corners, points_in_boxes


def _rect_cost_ref(dx, dy, half_l, half_w, cos_t, sin_t, band_m):
    u = np.abs(np.outer(cos_t, dx) + np.outer(sin_t, dy)) - half_l
    v = np.abs(np.outer(-sin_t, dx) + np.outer(cos_t, dy)) - half_w
    inside = (u <= 0) & (v <= 0)
    d = np.where(inside, np.minimum(-u, -v), np.hypot(np.maximum(u, 0), np.maximum(v, 0)))
    return (np.minimum(d, band_m) ** 2).sum(1)


def _within_ref(pts, x, y, r):
    dx, dy = pts[:, 0] - x, pts[:, 1] - y
    return np.flatnonzero(dx * dx + dy * dy <= r * r)


def _angular_step_ref(points, n_sample=500, k=48, min_range_m=3.0, seed=0):
    p = np.asarray(points, dtype=np.float64).reshape(-1, np.shape(points)[-1])[:, :3]
    p = p[np.linalg.norm(p, axis=1) > min_range_m]
    if len(p) < 50:
        return None
    ang = np.column_stack([np.arctan2(p[:, 1], p[:, 0]), np.arctan2(p[:, 2], np.hypot(p[:, 0], p[:, 1]))])
    tree = cKDTree(ang)
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


def _shapes_ref(b, corners, points, scan_step_rad, min_points=15, max_vertices=40):
    grown = b.copy()
    grown[:, 3:5] *= 1.1
    grown[:, 2] += 0.2 / 2 + 0.05
    grown[:, 5] += 0.1 - 0.2
    mask = points_in_boxes(points, grown)
    rows, used = [], np.zeros(len(b), dtype=bool)
    for j in range(len(b)):
        p = points[mask[j], :3].astype(np.float64)
        v = corners[j]
        if len(p) >= min_points:
            try:
                hv = p[ConvexHull(p).vertices]
                if scan_step_rad is not None:
                    g = np.concatenate([hv, boxshape.expand_by_scan_gap(hv, scan_step_rad)])
                    hv = g[ConvexHull(g).vertices]
                if len(hv) > max_vertices:
                    proj = hv @ boxshape._DIRS[: max(max_vertices // 2, 3)].T
                    hv = hv[np.unique(np.concatenate([proj.argmax(0), proj.argmin(0)]))]
                foot = hv.copy()
                foot[:, 2] = b[j, 2] - b[j, 5] / 2
                v = np.concatenate([hv, foot])
                used[j] = True
            except Exception:
                pass
        rows.append(v)
    S = max(len(r) for r in rows)
    out = np.empty((len(b), S, 3))
    for j, r in enumerate(rows):
        out[j, : len(r)] = r
        out[j, len(r):] = r[0]
    return out, used


def _scene(rng, M):
    b = np.column_stack([rng.uniform(-30, 30, (M, 2)), rng.uniform(-1, 1, M), rng.uniform(1, 6, M),
                         rng.uniform(1, 3, M), rng.uniform(1, 3, M), rng.uniform(-3, 3, M)])
    pts = np.concatenate([bb[:3] + rng.uniform(-0.6, 0.6, (int(rng.integers(0, 300)), 3)) * bb[3:6] for bb in b]
                         + [rng.normal(0, 30, (500, 3))])
    return b, pts


def test_rect_cost_is_the_formula_to_the_bit():
    rng = np.random.default_rng(0)
    th = np.radians(np.arange(0.0, 180.0, 1.0))
    for t in range(60):
        n = int(rng.integers(1, 300))
        dx, dy = rng.normal(0, rng.uniform(0.1, 5), n), rng.normal(0, rng.uniform(0.1, 5), n)
        if t % 3 == 0:  # points exactly on sides and corners
            dx, dy = np.round(dx, 1), np.round(dy, 1)
        args = (dx, dy, float(np.round(rng.uniform(0.2, 4), 1)), float(np.round(rng.uniform(0.2, 2), 1)),
                np.cos(th), np.sin(th), (0.3, 0.05, 10.0)[t % 3])
        assert np.array_equal(boxshape._rect_cost(*args), _rect_cost_ref(*args))


def test_disc_queries_are_exact_and_ascending():
    rng = np.random.default_rng(1)
    for t in range(8):
        pts = rng.normal(0, 30, (int(rng.integers(10, 5000)), 3))
        if t % 2:
            pts = np.round(pts, 1)  # points on the disc's rim and bucket edges
        near = boxshape._NearXY(pts)
        for q in range(25):
            x, y, r = (pts[q, 0], pts[q, 1], 2.0) if q % 5 == 0 else (rng.normal(0, 30), rng.normal(0, 30),
                                                                        rng.uniform(0, 10))
            assert np.array_equal(near.within(x, y, r), _within_ref(pts, x, y, r))


def test_scan_step_hulls_and_yaw_fits_are_the_reference_to_the_bit():
    rng = np.random.default_rng(2)
    ring = np.radians(np.arange(-15, 15, 2.0))
    az = np.radians(np.arange(-180, 180, 0.2))
    A, E = np.meshgrid(az, ring)
    rr = rng.uniform(4, 60, A.shape)
    lidar = np.stack([rr * np.cos(E) * np.cos(A), rr * np.cos(E) * np.sin(A), rr * np.sin(E)], -1).reshape(-1, 3)
    for pts in (lidar, lidar.astype(np.float32), rng.normal(0, 20, (3000, 3))):
        assert boxshape.lidar_angular_step(pts) == _angular_step_ref(pts)
    for t in range(6):
        b, pts = _scene(rng, int(rng.integers(1, 10)))
        if t % 3 == 0:
            pts[: len(pts) // 3, 2] = 0.0  # flat point sets: qhull fails, the box keeps its corners
        c8 = box7_corners(b)
        for step in (None, (0.003, 0.01)):
            got, ref = boxshape.shapes_from_points(b, c8, pts, scan_step_rad=step), _shapes_ref(b, c8, pts, step)
            assert np.array_equal(got[0], ref[0]) and np.array_equal(got[1], ref[1])


def test_yaw_fit_is_the_grid_search_of_the_reference_cost():
    rng = np.random.default_rng(3)
    b, pts = _scene(rng, 6)
    b[:, 6] = 0.0
    fit = boxshape.fit_yaw_to_points(b, pts, min_points=4)
    th = np.radians(np.arange(0.0, 180.0, 1.0))
    for j in np.flatnonzero(fit.fitted):
        x, y, z, ln, wd, h = b[j, :6]
        p = pts[_within_ref(pts, x, y, float(np.hypot(ln, wd) / 2 + 0.3))]
        p = p[(p[:, 2] > z - h / 2 + 0.3) & (p[:, 2] < z - h / 2 + max(0.7 * h, 0.6))]
        cost = _rect_cost_ref(p[:, 0] - x, p[:, 1] - y, ln / 2, wd / 2, np.cos(th), np.sin(th), 0.3)
        assert fit.n_points[j] == len(p)
        assert abs(fit.boxes7[j, 6] - th[int(np.argmin(cost))]) <= np.radians(1.0) + 1e-12


def test_distinct_pick_is_the_pairwise_loop():
    rng = np.random.default_rng(4)
    for t in range(40):
        H = int(rng.integers(1, 120))
        base = Rotation.random(random_state=t).as_matrix()
        R = np.stack([Rotation.from_rotvec(rng.normal(0, np.radians([0.5, 2, 5, 30][t % 4]), 3)).as_matrix() @ base
                      for _ in range(H)])
        tt = rng.normal(0, [0.3, 1, 3][t % 3], (H, 3))
        if t % 5 == 0 and H > 3:  # duplicates, and a pair exactly 1 m apart with the same rotation
            R[H // 2:], tt[H // 2:] = R[: H - H // 2], tt[: H - H // 2]
            R[1], tt[1] = R[0], tt[0] + np.array([1.0, 0.0, 0.0])
        order = np.argsort(-rng.uniform(size=H), kind="stable")
        n = int(rng.integers(1, 10))
        keep: list[int] = []
        for i in order:
            if all(_distinct(R[i], tt[i], R[k], tt[k], 3.0, 1.0) for k in keep):
                keep.append(int(i))
            if len(keep) >= n:
                break
        assert _distinct_best(R, tt, order, n, (3.0, 1.0)) == keep


@pytest.mark.parametrize("H,K,M", [(200, 9, 14), (3, 1, 1), (5, 0, 4), (4, 3, 0), (0, 3, 3)])
def test_explained_iou_is_the_full_arrays_maxima(H, K, M):
    rng = np.random.default_rng(H + K + M)
    xy = rng.uniform(0, 200, (H, M, 2))
    rects = np.concatenate([xy, xy + rng.uniform(5, 60, (H, M, 2))], -1)[..., [0, 1, 2, 3]]
    rects[rng.uniform(size=(H, M)) < 0.2] = np.nan  # not projected
    bxy = rng.uniform(0, 200, (K, 2))
    boxes = np.concatenate([bxy, bxy + rng.uniform(5, 60, (K, 2))], -1)
    if K and M and H:
        rects[0, 0] = boxes[0]  # an exact fit, IoU 1
    full = np.nan_to_num(iou_batched(rects, boxes), nan=0.0) if H and K and M else np.zeros((H, K, M))
    per_box, per_rect = explained_iou(rects, boxes)
    assert np.array_equal(per_box, full.max(2) if M else np.zeros((H, K)))
    assert np.array_equal(per_rect, full.max(1) if K else np.zeros((H, M)))
