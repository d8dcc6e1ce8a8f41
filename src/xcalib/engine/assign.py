"""``assign``: matches from a similarity matrix (argmax or Hungarian); torch-free, shared by the torch
matcher, the ONNX Runtime matcher (``engine.host``) and the geometry fallback (``engine.domain``)."""

from __future__ import annotations

import numpy as np

__all__ = ["ASSIGNMENTS", "assign"]

ASSIGNMENTS = ("argmax", "hungarian")


def assign(similarity: np.ndarray, *, top_k: int = 1, threshold: float = 0.0, method: str = "argmax",
           fill_value: float | None = None) -> tuple[np.ndarray, list[tuple[int, int, float]]]:
    """Matches from a [K',M'] similarity (kept numbering).

    "argmax": up to ``max(1, top_k)`` best columns per row with score >= threshold;
    top_indices = per-row argmax. "hungarian": one-to-one assignment maximising the total score
    (scipy), pairs with score >= threshold; top_indices = assigned column or -1.
    Entries equal to ``fill_value`` (not scored by the model) never match.
    """
    if method not in ASSIGNMENTS:
        raise ValueError(f"assignment must be one of {ASSIGNMENTS}, got {method!r}")
    K, M = similarity.shape
    if K == 0 or M == 0:
        return np.full(K, -1, dtype=np.int64), []
    valid = np.ones_like(similarity, dtype=bool) if fill_value is None else similarity != fill_value
    if method == "argmax":
        top = similarity.argmax(axis=1).astype(np.int64)
        k = min(max(1, int(top_k)), M)
        order = np.argsort(-similarity, axis=1, kind="stable")[:, :k]
        rows = np.repeat(np.arange(K), k)
        cols = order.reshape(-1)
        s = similarity[rows, cols]
        ok = (s >= threshold) & valid[rows, cols]
        return top, [(int(r), int(c), float(v)) for r, c, v in zip(rows[ok], cols[ok], s[ok])]
    from scipy.optimize import linear_sum_assignment

    cost = np.where(valid, -similarity.astype(np.float64), 1e6)
    r, c = linear_sum_assignment(cost)
    top = np.full(K, -1, dtype=np.int64)
    pairs = []
    for i, j in zip(r, c):
        if valid[i, j] and similarity[i, j] >= threshold:
            top[i] = j
            pairs.append((int(i), int(j), float(similarity[i, j])))
    return top, pairs
