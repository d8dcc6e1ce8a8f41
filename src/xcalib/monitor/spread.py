"""The change test's spread from the objects themselves (``MonitorConfig.difference_quantile``).

The change test compares a recent segment's estimate with the estimate of the frames before it.
The covariance each segment states, ``H^-1 s2``, takes the residual variance factor ``s2`` from the
weighted residuals' mean square, which the occluded and wrongly matched edges dominate, and it
counts the two segments' errors as independent. But a 3D box's error persists while its object is
tracked: an object seen on both sides of the boundary pushes both estimates alike, and that part
of the error cancels in their difference. The spread of the difference itself can be read off the
objects (a sandwich covariance clustered by object): with ``s_k`` an object's score (its share of
``g + H x`` at the segment's own estimate),

    d = x_a - x_b ~ -Ha^-1 sum_k s_k^a + Hb^-1 sum_k s_k^b,  Var(d) ~ sum_k u_k u_k^T,
    u_k = Ha^-1 s_k^a - Hb^-1 s_k^b,

summed over the objects of both segments (an object in one segment only contributes its own part).
Its scores are bounded where the soft-L1 loss bends (an outlying edge adds at most its bent share),
and an object whose error persists across the boundary adds little, one whose error changes adds
in full. ``difference_ratio`` is that spread over the stated one, averaged over the six axes (one
number: the clustered matrix itself, from tens of objects, is too noisy for a 6-dof test).
"""

from __future__ import annotations

import numpy as np

__all__ = ["UNTRACKED_MAX", "SegmentTable", "difference_ratio", "object_scores", "tracked"]

#: the largest share of matched pairs without a track id for which the objects' spread is formed: an
#: untracked pair is its own cluster, so the persistence of its box's error over frames is not seen and
#: the clustered spread understates the difference's (per-pair clusters, measured: 6 / 2 false alarms in
#: 2 x 20,400 frames against 1 / 0); above it the test keeps the stated covariance
UNTRACKED_MAX = 0.1


def tracked(ids: np.ndarray) -> bool:
    """Whether the pairs' object ids (untracked: < 0) are tracked enough to cluster by object."""
    ids = np.asarray(ids)
    return bool(len(ids)) and float(np.mean(ids < 0)) <= UNTRACKED_MAX


def object_scores(ids: np.ndarray, H_k: np.ndarray, g_k: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Per object [K,6]: its score at the estimate ``x``, ``g_k + H_k x`` (its share of the normal
    equations' gradient there)."""
    return np.asarray(g_k, dtype=np.float64) + np.einsum("kij,j->ki", np.asarray(H_k, dtype=np.float64), x)


def difference_ratio(recent: tuple, before: tuple, xa: np.ndarray, xb: np.ndarray, cov_stated: np.ndarray) -> float:
    """The spread of the difference of two segments' estimates clustered by object, over the stated
    covariance ``cov_stated`` of the difference (``trace(cov_stated^-1 V) / 6``; NaN where it cannot
    be formed). ``recent`` / ``before``: (sorted object ids [K], their H shares [K,6,6], g shares [K,6])
    of the two segments (``core._object_sums``); ``xa`` / ``xb``: their estimates. The small-sample
    factor G / (G - 1) (G objects in all) is applied."""
    ids_a, Ha_k, ga_k = recent
    ids_b, Hb_k, gb_k = before
    if not len(ids_a) or not len(ids_b):
        return float("nan")
    try:
        ua = np.linalg.solve(Ha_k.sum(0), object_scores(ids_a, Ha_k, ga_k, xa).T).T
        ub = np.linalg.solve(Hb_k.sum(0), object_scores(ids_b, Hb_k, gb_k, xb).T).T
    except np.linalg.LinAlgError:
        return float("nan")
    ids = np.union1d(ids_a, ids_b)
    U = np.zeros((len(ids), 6))
    np.add.at(U, np.searchsorted(ids, ids_a), ua)
    np.add.at(U, np.searchsorted(ids, ids_b), -ub)
    G = len(ids)
    if G < 2:
        return float("nan")
    V = U.T @ U * (G / (G - 1))
    try:
        r = float(np.trace(np.linalg.solve(cov_stated, V))) / 6.0
    except np.linalg.LinAlgError:
        return float("nan")
    return r if np.isfinite(r) else float("nan")


class SegmentTable:
    """Per-object shares (rows [N, 42]: H flattened, g; ``pos`` the frame of each row, ``ids`` its object)
    summed per object and per run of frames between ``bounds`` (one sort): the sums per object before
    and after any of the boundaries (``split``), objects aligned on both sides (an object absent from
    a side has zero share there)."""

    def __init__(self, pos: np.ndarray, ids: np.ndarray, HG: np.ndarray, bounds) -> None:
        self.bounds = sorted(set(int(b) for b in bounds))
        nb = len(self.bounds) + 1
        if not len(ids):
            self.T = np.zeros((0, nb, 42))
            return
        ids = np.asarray(ids, dtype=np.int64)
        key = (ids - ids.min()) * nb + np.searchsorted(self.bounds, pos, side="right")  # one sort: object, run
        order = np.argsort(key, kind="stable")
        k_sorted = key[order]
        starts = np.flatnonzero(np.r_[True, k_sorted[1:] != k_sorted[:-1]])
        obj = k_sorted[starts] // nb
        first = np.r_[True, obj[1:] != obj[:-1]]
        row = np.cumsum(first) - 1  # the object's row in T
        u = np.flatnonzero(first)
        T = np.zeros((len(u) * nb, 42))
        T[row * nb + k_sorted[starts] % nb] = np.add.reduceat(np.asarray(HG, dtype=np.float64)[order], starts, axis=0)
        self.T = T.reshape(len(u), nb, 42)

    def split(self, a: int) -> tuple[tuple, tuple]:
        """(after, before): per object (ids [K], H [K,6,6], g [K,6]) over the frames from boundary ``a``
        on and before it."""
        j = self.bounds.index(int(a)) + 1
        K = len(self.T)
        ids = np.arange(K)
        aft, bef = self.T[:, j:].sum(1), self.T[:, :j].sum(1)
        return ((ids, aft[:, :36].reshape(K, 6, 6), aft[:, 36:]), (ids, bef[:, :36].reshape(K, 6, 6), bef[:, 36:]))
