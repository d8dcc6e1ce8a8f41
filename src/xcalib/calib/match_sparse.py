"""Matching by projection on the candidate pairs only: dense scenes (issue 29).

``refine.match_all`` matches every frame's 2D boxes to its projected 3D outlines (Hungarian on
cost = (1 - IoU) + normalised centre distance, a pair allowed when IoU >= ``gate_iou`` or, with
``gate_dist`` > 0, when the centre distance is within ``gate_dist`` 2D box diagonals). On a busy
junction (200 boxes per side, 20 frames) the IoU and distance arrays of every 2D box with every
3D box, and the masks and sums over them, were a third of a calibration. Here a pair is a
*candidate* when its projected rectangle and its 2D box grown by ``gate_dist`` diagonals (plus a
relative 1e-9) overlap in x and in y (closed intervals): every allowed pair is one (IoU > 0 needs
an overlap; a centre within d of the box centre lies in the grown box, and the rectangle holds
its own centre), so the IoU and distances are computed for the candidates only, with the same
element-wise operations (the same values), and the assignment is built from the allowed
candidates exactly as ``refine._assign`` builds it from the full arrays (the same cost matrix of
the rows and columns with an allowed pair: the same matches, in the same order). The candidate
test is still one comparison per (2D box, 3D box), but of booleans: some 10 cheap operations
instead of some 40. Frames whose allowed pairs share no box (most of them at a good pose) take
their pairs without an assignment, all frames at once.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment

from .boxproj import iou_planes

__all__ = ["match_candidates", "explained_iou"]

#: relative slack of the candidate test (the exact gates decide on the candidates)
SLACK = 1e-9


def match_candidates(rects: np.ndarray, n_cols: np.ndarray, boxes: np.ndarray, n_rows: np.ndarray,
                     gate_iou: float, gate_dist: float) -> list[np.ndarray] | None:
    """The pairs [n,2] (row of ``boxes``, column of ``rects``) of L frames given padded arrays:
    rects [L,M,4] (valid projected rectangles; the first ``n_cols[l]`` of frame l) and 2D boxes
    [L,K,4] (the first ``n_rows[l]``); ``refine._assign`` on each frame's full IoU and distance
    matrices gives the same pairs. None when ``gate_iou`` <= 0 (every pair allowed: no pruning)."""
    if not gate_iou > 0.0:
        return None
    L, M = rects.shape[:2]
    K = boxes.shape[1]
    cmask = np.arange(M)[None, :] < np.asarray(n_cols)[:, None]  # [L,M]
    rmask = np.arange(K)[None, :] < np.asarray(n_rows)[:, None]  # [L,K]
    diag = np.hypot(boxes[..., 2] - boxes[..., 0], boxes[..., 3] - boxes[..., 1])  # [L,K]
    grow = (gate_dist * diag * (1.0 + SLACK) + SLACK * (1.0 + diag)) if gate_dist > 0 else SLACK * (1.0 + diag)
    gx0, gy0 = boxes[..., 0] - grow, boxes[..., 1] - grow
    gx1, gy1 = boxes[..., 2] + grow, boxes[..., 3] + grow
    rx0, ry0, rx1, ry1 = (np.where(cmask, rects[..., j], np.nan)[:, None, :] for j in range(4))  # [L,1,M]
    cand = rx0 <= gx1[..., None]
    cand &= rx1 >= gx0[..., None]
    cand &= ry0 <= gy1[..., None]
    cand &= ry1 >= gy0[..., None]
    cand &= rmask[..., None]
    ll, ii, jj = np.nonzero(cand)  # row-major: frame, then 2D row, then column
    out = [np.zeros((0, 2), dtype=np.int64) for _ in range(L)]
    if not len(ll):
        return out
    r = rects[ll, jj]
    b = boxes[ll, ii]
    iou = iou_planes(tuple(r[:, j] for j in range(4)), tuple(b[:, j] for j in range(4)))
    c_obs = np.stack([(b[:, 0] + b[:, 2]) / 2, (b[:, 1] + b[:, 3]) / 2], -1)
    c_pred = np.stack([(r[:, 0] + r[:, 2]) / 2, (r[:, 1] + r[:, 3]) / 2], -1)
    dist = np.linalg.norm(c_obs - c_pred, axis=1) / diag[ll, ii]
    allowed = (iou >= gate_iou) if gate_dist <= 0 else ((iou >= gate_iou) | (dist <= gate_dist))
    ll, ii, jj, iou, dist = ll[allowed], ii[allowed], jj[allowed], iou[allowed], dist[allowed]
    if not len(ll):
        return out
    # frames whose allowed pairs share no box: every allowed pair, in row order (as ``_assign``)
    shared = np.zeros(L, dtype=bool)
    for key, size in ((ll * K + ii, L * K), (ll * M + jj, L * M)):
        cnt = np.bincount(key, minlength=size)
        shared[(np.flatnonzero(cnt > 1) // (size // L))] = True
    bounds = np.searchsorted(ll, np.arange(L + 1))
    for f in np.flatnonzero(bounds[1:] > bounds[:-1]):
        s, e = bounds[f], bounds[f + 1]
        if not shared[f]:
            out[f] = np.column_stack([ii[s:e], jj[s:e]]).astype(np.int64)
            continue
        out[f] = _assign_allowed(ii[s:e], jj[s:e], iou[s:e], dist[s:e], (K, M))
    return out


def _assign_allowed(ii: np.ndarray, jj: np.ndarray, iou: np.ndarray, dist: np.ndarray, shape: tuple[int, int]
                    ) -> np.ndarray:
    """``refine._assign``'s assignment given one frame's allowed pairs (rows ii < shape[0], columns
    jj < shape[1], their IoU and distance): the cost matrix of the rows and columns with an
    allowed pair, ascending (1e6 at the others), the Hungarian solution, its allowed entries."""
    rows, ri = _ranks(ii, shape[0])
    cols, ci = _ranks(jj, shape[1])
    cost = np.full((len(rows), len(cols)), 1e6)
    cost[ri, ci] = (1 - iou) + np.minimum(dist, 10.0)
    sub = np.zeros(cost.shape, dtype=bool)
    sub[ri, ci] = True
    r, c = linear_sum_assignment(cost)
    keep = sub[r, c]
    return np.column_stack([rows[r[keep]], cols[c[keep]]]).astype(np.int64)


def _ranks(a: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """``np.unique(a, return_inverse=True)`` for integers 0 <= a < n (a count, not a sort)."""
    seen = np.zeros(n, dtype=bool)
    seen[a] = True
    vals = np.flatnonzero(seen)
    rank = np.cumsum(seen) - 1
    return vals, rank[a]


def explained_iou(rects: np.ndarray, boxes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per pose: the best IoU of every 2D box [H,K] with any projected rectangle, and of every
    rectangle [H,M] with any 2D box (``iou_batched(rects, boxes)`` [H,K,M] maxed over its last
    and its middle axis) for rects [H,M,4] (NaN: not projected) and boxes [K,4]. A pair whose
    rectangles do not overlap in both x and y (open intervals) has IoU exactly 0, as a NaN
    rectangle has: the IoU is computed, with the same operations, only for the overlapping pairs,
    and the maxima are those of the full array, to the bit."""
    H, M = rects.shape[:2]
    b = np.asarray(boxes, dtype=np.float64)
    K = len(b)
    edges = [np.ascontiguousarray(rects[..., j]) for j in range(4)]  # [H,M] each
    cols = [np.ascontiguousarray(b[:, j]) for j in range(4)]  # [K] each
    # overlap tests box by box on whole [H,M] planes ([K,H,M]: no broadcast inner loop over the few
    # M of each (h, k)), then read in (h, k, m) order: the same mask as the [H,K,M] broadcast
    cand = np.empty((K, H, M), dtype=bool)
    tmp = np.empty((H, M), dtype=bool)
    rx0, ry0, rx1, ry1 = edges
    for k in range(K):
        ck = cand[k]
        np.less(rx0, cols[2][k], out=ck)
        ck &= np.greater(rx1, cols[0][k], out=tmp)
        ck &= np.less(ry0, cols[3][k], out=tmp)
        ck &= np.greater(ry1, cols[1][k], out=tmp)
    flat = np.flatnonzero(cand.transpose(1, 0, 2))  # (h, k, m) row-major
    if not len(flat):
        return np.zeros((H, K)), np.zeros((H, M))
    hk, mm = np.divmod(flat, M)
    h, k = np.divmod(hk, K)
    hm = h * M + mm
    iou = iou_planes(tuple(e.reshape(-1)[hm] for e in edges), tuple(c[k] for c in cols))
    # the maxima of the full array (zeros but at the overlapping pairs; IoU >= 0): over m, one
    # ``maximum.reduceat`` over the runs of equal (h, k) (``flat`` is sorted); over k, an
    # unbuffered ``maximum.at`` into zeros. max is exact: the same values as the full array's
    per_box = np.zeros(H * K)
    starts = np.flatnonzero(np.r_[True, hk[1:] != hk[:-1]])
    per_box[hk[starts]] = np.maximum.reduceat(iou, starts)
    per_rect = np.zeros(H * M)
    np.maximum.at(per_rect, hm, iou)
    return per_box.reshape(H, K), per_rect.reshape(H, M)
