"""Censored box edges: which edges of the matched 2D boxes are only a bound.

A camera detector's 2D box (and a label drawn on the visible pixels) covers the *visible* part of
an object. Where a nearer object hides part of it, the box ends at the occluder: that edge is not an
observation of the projected 3D box's edge but a bound -- the true edge lies at it or further out.
Fitting it as exact pulls the pose towards the hidden side (the small pitch bias of scenes whose far
objects stand behind near ones). ``occluded_edges`` decides from the data which edges are such
bounds: an edge of box i is censored when it lies on (or within the edge noise of) the 2D box of a
matched object j of the same frame whose 3D box is nearer to the camera, and j covers at least half
of the edge's length. The cost then counts only its outward residual (``cost.BoxEdgeTerm.shape``).

Edges at the image border need nothing here: the projected rectangle is clipped to the image, so
its edge there never moves and an observed edge on the border that the projection does not reach
still counts (it is outward).
"""

from __future__ import annotations

import numpy as np

__all__ = ["occluded_edges", "censor_evidence", "COVER_SHARE", "TOUCH_SIGMAS", "MIN_INWARD_SHIFT", "MIN_EVIDENCE_SE"]

#: the least share of an edge's length that a nearer box must cover for the edge to be censored
COVER_SHARE = 0.5
#: how close (in 1-sigma of the two boxes' edge noise) an edge must lie to a nearer box to touch it
TOUCH_SIGMAS = 2.0
#: "auto" censors when the candidate edges lie inside the projection by at least this much more
#: than the other edges (mean, in edge sigmas) ...
MIN_INWARD_SHIFT = 0.5
#: ... and by at least this many standard errors of that difference
MIN_EVIDENCE_SE = 3.0


def occluded_edges(outlines: np.ndarray, obs: np.ndarray, frame_of: np.ndarray, centre: np.ndarray,
                   sigma_px: np.ndarray) -> np.ndarray:
    """[n,4] bool: the edges (u_min, v_min, u_max, v_max) of the matched 2D boxes ``obs`` [n,4] (px)
    that a nearer matched box hides.

    ``outlines`` [n,S,3]: the matched 3D outlines (LiDAR frame, m); ``frame_of`` [n]: each pair's
    frame (only boxes of one frame occlude each other); ``centre`` [3]: the camera centre in the
    LiDAR frame (range order is taken from it; any pose near the truth gives the same order);
    ``sigma_px`` [n]: each box's edge 1-sigma (px), the tolerance of "lies on".
    """
    obs = np.asarray(obs, dtype=np.float64)
    n = len(obs)
    out = np.zeros((n, 4), dtype=bool)
    if n < 2:
        return out
    rng = np.linalg.norm(np.asarray(outlines, dtype=np.float64).mean(1) - np.asarray(centre, dtype=np.float64), axis=1)
    frame_of = np.asarray(frame_of)
    sig = np.asarray(sigma_px, dtype=np.float64).reshape(-1)
    x1, y1, x2, y2 = obs.T
    for f in np.unique(frame_of):
        idx = np.flatnonzero(frame_of == f)
        if len(idx) < 2:
            continue
        i, j = idx[:, None], idx[None, :]  # i: the box whose edge is tested, j: a possible occluder
        nearer = rng[j] < rng[i]
        tol = TOUCH_SIGMAS * np.sqrt(sig[i] ** 2 + sig[j] ** 2)
        # share of each edge's length that j's box spans (vertical edges: along v, horizontal: along u)
        h = np.maximum(y2[i] - y1[i], 1e-9)
        w = np.maximum(x2[i] - x1[i], 1e-9)
        cover_v = np.clip(np.minimum(y2[i], y2[j]) - np.maximum(y1[i], y1[j]), 0, None) / h
        cover_u = np.clip(np.minimum(x2[i], x2[j]) - np.maximum(x1[i], x1[j]), 0, None) / w
        in_u = lambda u: (u >= x1[j] - tol) & (u <= x2[j] + tol)  # noqa: E731
        in_v = lambda v: (v >= y1[j] - tol) & (v <= y2[j] + tol)  # noqa: E731
        hit = [in_u(x1[i]) & (cover_v >= COVER_SHARE), in_v(y1[i]) & (cover_u >= COVER_SHARE),
               in_u(x2[i]) & (cover_v >= COVER_SHARE), in_v(y2[i]) & (cover_u >= COVER_SHARE)]
        for e, m in enumerate(hit):
            out[idx, e] = np.any(m & nearer, axis=1)
    return out


def censor_evidence(z: np.ndarray, candidates: np.ndarray, valid: np.ndarray, size: tuple[int, int],
                    rects: np.ndarray) -> bool:
    """Whether this run's boxes are boxes of the visible part: the edges ``occluded_edges`` marks
    (``candidates`` [n,4]) lie further inside the projected outlines than the other edges.

    ``z`` [n,4]: edge residuals (projected - observed) in edge sigmas at the current pose;
    ``valid`` [n]: projectable rows; ``rects`` [n,4]: the projected rectangles (edges on the image
    border are left out). The inward residuals (clipped to +-3 sigma against false matches) of the
    candidates and of the other edges are compared: censoring pays when the candidates' mean lies
    ``MIN_INWARD_SHIFT`` sigma or more further in, beyond ``MIN_EVIDENCE_SE`` standard errors
    (a labelled or amodal box's hidden edge is an exact observation: censoring it only loses
    information; a visible-part box's is not).
    """
    from .cost import INWARD

    W, H = size
    ok = (np.asarray(valid, dtype=bool)[:, None] & np.isfinite(z) & np.isfinite(rects)
          & (np.nan_to_num(rects) > 0.5) & (np.nan_to_num(rects) < np.array([W, H, W, H], dtype=np.float64) - 0.5))
    zi = np.clip(np.nan_to_num(z) * INWARD, -3.0, 3.0)
    a, b = zi[ok & candidates], zi[ok & ~candidates]
    if len(a) < 8 or len(b) < 8:
        return False
    diff = float(a.mean() - b.mean())
    se = float(np.sqrt(a.var(ddof=1) / len(a) + b.var(ddof=1) / len(b)))
    return diff >= MIN_INWARD_SHIFT and diff >= MIN_EVIDENCE_SE * se
