"""Refinement over all frames: match by projection, then a robust fit of the cost model.

``refine_pose`` alternates one-to-one matching (Hungarian with a gate) and a soft-L1 fit of the
box-edge term (``cost.BoxEdgeTerm``: projected 3D outline edges vs 2D box edges, px, divided by
the per-pair sigma of the fitted ``NoiseModel``) until the robust cost stops improving. The pose
is ``X_cam = R X_lidar + t``; updates are ``R <- exp([w]x) R``, ``t <- t + dt`` (camera frame).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.spatial.transform import Rotation

from ..geometry.boxes import box2d_centers
from ..geometry.camera import CameraIntrinsics
from .boxproj import iou_batched, iou_planes, project_ragged, project_rects
from .censor import censor_evidence, occluded_edges
from .context import F_SCALE, FitContext, RefineOptions
from .cost import INWARD, BoxEdgeTerm, CostModel, Occlusion, _pair_features, edge_sigma
from .diagnostics import NoiseModel
from .inputs import CalibFrame, box_scores
from .match_sparse import match_candidates
from .pose import Pose
from .terms import CostSpec, TermContext, occlusion_of

__all__ = ["build_cost", "box_edges", "RefineResult", "match_frame", "match_all", "project_frames", "refine_pose", "pair_metrics", "estimate_noise", "lsq",
           "edge_term", "pair_scores", "DEFAULT_NOISE", "F_SCALE", "FitContext", "RefineOptions", "RefineRun",
           "refine_start", "refine_step", "refine_finish"]


#: padded [frames, 2D, 3D] entries from which ``match_all`` works on the candidate pairs only
#: (below, the full arrays cost less than the candidates' bookkeeping; both give the same pairs)
SPARSE_ABOVE = 20_000


@dataclass
class RefineResult:
    """Refined pose, the matches (per frame, rows of CalibFrame arrays) and fit statistics."""

    R: np.ndarray
    t: np.ndarray
    pairs: list[np.ndarray]
    cost: float
    n_iter: int
    residuals: np.ndarray = field(default_factory=lambda: np.zeros(0))
    history: list[float] = field(default_factory=list)
    noise: NoiseModel = NoiseModel()  # fitted per-edge error model, see estimate_noise


def match_frame(fr: CalibFrame, intr: CameraIntrinsics, R, t, *, gate_iou: float = 0.3,
                gate_dist: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One-to-one matches of one frame by projection.

    A pair is allowed when IoU >= ``gate_iou`` or, if ``gate_dist`` > 0, when the centre distance
    is below ``gate_dist`` times the 2D box diagonal (for rough poses). Hungarian on
    cost = (1 - IoU) + normalised centre distance. Returns (pairs [n,2] rows, IoU [n], rects [M,4]).
    """
    rects, valid = project_rects(fr.corners, R, t, intr, fr.size)
    return _match_projected(fr, rects, valid, gate_iou, gate_dist)


def _match_projected(fr: CalibFrame, rects: np.ndarray, valid: np.ndarray, gate_iou: float, gate_dist: float):
    """``match_frame`` given the frame's projected rectangles [M,4] and their validity [M]."""
    if fr.n2 == 0 or fr.n3 == 0 or not np.any(valid):
        return np.zeros((0, 2), dtype=np.int64), np.zeros(0), rects
    iou = iou_batched(rects[None], fr.boxes2d)[0]
    c_obs = box2d_centers(fr.boxes2d)
    c_pred = np.stack([(rects[:, 0] + rects[:, 2]) / 2, (rects[:, 1] + rects[:, 3]) / 2], 1)
    diag = np.hypot(fr.boxes2d[:, 2] - fr.boxes2d[:, 0], fr.boxes2d[:, 3] - fr.boxes2d[:, 1])
    dist = np.linalg.norm(c_obs[:, None] - c_pred[None], axis=2) / diag[:, None]
    pairs, ious = _assign(iou, dist, valid, gate_iou, gate_dist)
    return pairs, ious, rects


def _assign(iou: np.ndarray, dist: np.ndarray, valid: np.ndarray, gate_iou: float, gate_dist: float):
    """Hungarian matching of one frame from its IoU [K,M] and centre distance [K,M] (diagonals).

    The assignment runs on the rows and columns that have an allowed pair only: a box with none
    can only take a forbidden (1e6) entry, and any set of allowed pairs extends to a full
    assignment of the complete matrix with forbidden entries, so both problems choose the most
    allowed pairs at the least summed cost: the same matches (only alternatives of exactly equal
    summed cost could be ordered differently by the solver; tested against the full matrix in
    ``tests/test_match_pruning.py``)."""
    dist = np.where(valid[None], dist, np.inf)
    allowed = (iou >= gate_iou) if gate_dist <= 0 else ((iou >= gate_iou) | (dist <= gate_dist))
    allowed &= valid[None]
    rows = np.flatnonzero(allowed.any(axis=1))
    if not len(rows):
        return np.zeros((0, 2), dtype=np.int64), np.zeros(0)
    if allowed.sum(0).max() <= 1 and allowed.sum(1).max() <= 1:
        # the allowed pairs share no box: the assignment takes every one of them (each left out
        # would cost 1e6 more) and the rest of it is disallowed and dropped -- the same pairs, in
        # row order, without the assignment's search
        pairs = np.argwhere(allowed).astype(np.int64)
        return pairs, iou[pairs[:, 0], pairs[:, 1]]
    return _assign_allowed(allowed, iou, dist, rows, np.flatnonzero(allowed.any(axis=0)))


def _assign_allowed(allowed: np.ndarray, iou: np.ndarray, dist: np.ndarray, rows: np.ndarray, cols: np.ndarray):
    """``_assign``'s assignment given its allowed mask [K,M] (valid columns applied), IoU, centre
    distance (invalid columns at inf) and the rows / columns [int64] with an allowed pair: (pairs, IoUs)."""
    if len(rows) == len(iou) and len(cols) == iou.shape[1]:  # nothing to drop (small frames)
        sub, iou_s, dist_s = allowed, iou, dist
    else:  # (``np.ix_``'s block, indexed directly: the same entries without its per-call checks)
        ix = (rows[:, None], cols)
        sub, iou_s, dist_s = allowed[ix], iou[ix], dist[ix]
    cost = np.where(sub, (1 - iou_s) + np.minimum(dist_s, 10.0), 1e6)
    r, c = linear_sum_assignment(cost)
    keep = sub[r, c]
    r, c = r[keep], c[keep]
    pairs = np.empty((len(r), 2), dtype=np.int64)  # (rows, cols: int64, so the pairs are)
    pairs[:, 0], pairs[:, 1] = rows[r], cols[c]
    return pairs, iou_s[r, c]


def _match_frames(frames: list[CalibFrame], proj: list, gate_iou: float, gate_dist: float,
                  sparse_above: int = SPARSE_ABOVE) -> list[np.ndarray]:
    """The pairs of every frame, the IoU and centre distances of all frames in one padded
    [F,K,M] computation (the same element-wise operations as ``iou_batched`` / ``_match_projected``,
    so the same values); the assignment frame by frame. Only the 3D boxes that project into the
    image (``valid``) enter the arrays: the others can match no box (``_assign`` forbids them), so
    dropping them first changes no match (a 360-degree LiDAR's boxes behind the camera). From
    ``sparse_above`` padded IoU entries on, on the candidate pairs only
    (:func:`~.match_sparse.match_candidates`: the same pairs)."""
    out = [np.zeros((0, 2), dtype=np.int64) for _ in frames]
    live = [k for k, fr in enumerate(frames) if fr.n2 and fr.n3 and np.any(proj[k][1])]
    if not live:
        return out
    cols = [np.flatnonzero(proj[k][1]) for k in live]
    L, K, M = len(live), max(frames[k].n2 for k in live), max(len(c) for c in cols)
    rects = np.zeros((L, M, 4))
    boxes = np.tile(np.array([0.0, 0.0, 1.0, 1.0]), (L, K, 1))  # padding: a unit box (no zero diagonal)
    for i, k in enumerate(live):
        rects[i, :len(cols[i])] = proj[k][0][cols[i]]
        boxes[i, :frames[k].n2] = frames[k].boxes2d
    sparse = (match_candidates(rects, [len(c) for c in cols], boxes, [frames[k].n2 for k in live], gate_iou, gate_dist)
              if L * K * M >= sparse_above else None)
    if sparse is not None:  # the candidate pairs only (dense frames): the same pairs
        for i, k in enumerate(live):
            p = sparse[i]
            p[:, 1] = cols[i][p[:, 1]]
            out[k] = p
        return out
    r = np.nan_to_num(rects, nan=0.0)
    rx0, ry0, rx1, ry1 = (np.ascontiguousarray(r[..., j])[:, None, :] for j in range(4))
    bx0, by0, bx1, by1 = (boxes[..., j][:, :, None] for j in range(4))
    iou = iou_planes((rx0, ry0, rx1, ry1), (bx0, by0, bx1, by1))  # [L,K,M]
    c_obs = np.stack([(boxes[..., 0] + boxes[..., 2]) / 2, (boxes[..., 1] + boxes[..., 3]) / 2], -1)
    c_pred = np.stack([(rects[..., 0] + rects[..., 2]) / 2, (rects[..., 1] + rects[..., 3]) / 2], -1)
    diag = np.hypot(boxes[..., 2] - boxes[..., 0], boxes[..., 3] - boxes[..., 1])
    dist = np.linalg.norm(c_obs[:, :, None] - c_pred[:, None], axis=3) / diag[..., None]
    simple, allowed = _conflict_free(iou, dist, [frames[k].n2 for k in live], [len(c) for c in cols], gate_iou,
                                     gate_dist)
    for i, k in enumerate(live):
        n2, c = frames[k].n2, cols[i]
        if i in simple:  # ``_assign``'s own shortcut, decided for all frames at once (the same pairs)
            p = simple[i]
        else:  # ``_assign``'s assignment on the frame's block of the mask computed for all frames
            a = allowed[i, :n2, :len(c)]
            p = _assign_allowed(a, iou[i, :n2, :len(c)], dist[i, :n2, :len(c)], a.any(axis=1).nonzero()[0],
                                a.any(axis=0).nonzero()[0])[0]
        p[:, 1] = c[p[:, 1]]
        out[k] = p
    return out


def _conflict_free(iou: np.ndarray, dist: np.ndarray, n2: list[int], n3: list[int], gate_iou: float,
                   gate_dist: float) -> tuple[dict[int, np.ndarray], np.ndarray]:
    """The frames of the padded [L,K,M] ``iou`` / ``dist`` (frame i's real block: ``n2[i]`` rows,
    ``n3[i]`` columns) whose allowed pairs share no box, each with its pairs [n,2] (rows of its block,
    in row order) -- what ``_assign`` returns for such a frame (no allowed pair: no pairs; else every
    allowed pair, ``np.argwhere`` order), found for all frames in one array computation instead of a
    dozen small ones per frame. The allowed mask is ``_assign``'s (the same comparisons of the same
    values, every column valid); the padding is masked out. Frames missing from the result have
    allowed pairs that compete for a box and go through ``_assign``'s assignment. Also returned: the
    allowed mask [L,K,M] (False on the padding)."""
    L, K, M = iou.shape
    allowed = (iou >= gate_iou) if gate_dist <= 0 else ((iou >= gate_iou) | (dist <= gate_dist))
    allowed &= np.arange(K)[None, :, None] < np.asarray(n2)[:, None, None]
    allowed &= np.arange(M)[None, None, :] < np.asarray(n3)[:, None, None]
    ok = (allowed.sum(1).max(1) <= 1) & (allowed.sum(2).max(1) <= 1)
    if not ok.any():
        return {}, allowed
    idx = np.argwhere(allowed[ok])  # (frame among ok, row, column), frame by frame in row order
    starts = np.searchsorted(idx[:, 0], np.arange(int(ok.sum()) + 1))
    return {int(i): idx[starts[j]:starts[j + 1], 1:].astype(np.int64) for j, i in enumerate(np.flatnonzero(ok))}, allowed


def project_frames(frames: list[CalibFrame], intr: CameraIntrinsics, R, t) -> list[tuple[np.ndarray, np.ndarray]]:
    """(rects [M,4], valid [M]) of every frame's 3D outlines at one pose: the frames of one image
    size projected in one call (outlines of different lengths padded with their first vertex,
    which changes no rectangle)."""
    out: list = [None] * len(frames)
    by_size: dict = {}
    for k, fr in enumerate(frames):
        by_size.setdefault(tuple(fr.size), []).append(k)
    for size, ks in by_size.items():
        corners = [frames[k].corners for k in ks]
        rects, valid = _project_outlines(corners, R, t, intr, size)
        offs = np.cumsum([0] + [len(c) for c in corners])
        for i, k in enumerate(ks):
            out[k] = (rects[offs[i]:offs[i + 1]], valid[offs[i]:offs[i + 1]])
    return out


def _project_outlines(corners: list[np.ndarray], R, t, intr: CameraIntrinsics, size: tuple[int, int]):
    """``project_rects(_padded(corners), R, t, intr, size)`` (rects [M,4], valid [M]): for one pose
    and a ``CameraIntrinsics``, ``boxproj.project_ragged`` of the outlines' own vertices, without
    the padding (A9's point outlines were padded from ~19 to 80 vertices, 4x the pixels computed at
    every matching). Each vertex's pixels are computed vertex by vertex either way, a rectangle's
    extremes are the exact min / max of the same values and the padding repeats a vertex of its
    outline: the same rects and valid."""
    lengths = [np.full(len(c), np.shape(c)[1]) for c in corners]
    n = sum(len(c) for c in corners)
    if not isinstance(intr, CameraIntrinsics) or np.ndim(R) != 2 or n == 0 or min(np.shape(c)[1] for c in corners) == 0:
        return project_rects(_padded(corners), R, t, intr, size)
    lengths = np.concatenate(lengths)
    flat = np.concatenate([np.asarray(c, dtype=np.float64).reshape(-1, 3) for c in corners])
    rect, valid = project_ragged(flat, np.cumsum(lengths) - lengths, R, t, intr, size)[:2]
    return rect, valid


def _padded(corners: list[np.ndarray]) -> np.ndarray:
    """Outlines [m_i,S_i,3] of several frames as one [sum m_i, max S_i, 3] array, each outline padded
    by repeating its first vertex (which changes no rectangle): written into one array, the values
    of concatenating the padded pieces."""
    S = max(c.shape[1] for c in corners)
    if all(c.shape[1] == S for c in corners):
        return np.concatenate(corners)
    out = np.empty((sum(len(c) for c in corners), S, 3))
    o = 0
    for c in corners:
        m, s = c.shape[:2]
        out[o:o + m, :s] = c
        out[o:o + m, s:] = c[:, :1]
        o += m
    return out


def match_all(frames, intr, R, t, *, gate_iou: float = 0.3, gate_dist: float = 0.0) -> list[np.ndarray]:
    """``match_frame`` of every frame (pairs only), the projection of all frames in one call."""
    frames = list(frames)
    return _match_frames(frames, project_frames(frames, intr, R, t), gate_iou, gate_dist)


def _stack(frames: list[CalibFrame], pairs: list[np.ndarray]):
    corners = [fr.corners[p[:, 1]] for fr, p in zip(frames, pairs) if len(p)]
    obs = [fr.boxes2d[p[:, 0]] for fr, p in zip(frames, pairs) if len(p)]
    if not corners:
        return np.zeros((0, 8, 3)), np.zeros((0, 4))
    # outlines may differ in length between frames: pad by repeating each box's first vertex
    return _padded(corners), np.concatenate(obs)


DEFAULT_NOISE = NoiseModel()


def edge_term(frames: list[CalibFrame], pairs: list[np.ndarray], intr: CameraIntrinsics, pose: Pose,
              noise: NoiseModel | None = None, occlusion: "Occlusion | CostSpec | None" = Occlusion()) -> BoxEdgeTerm:
    """The box-edge term of the matched ``pairs``, weighted by ``noise`` at ``pose`` (``occlusion``:
    its shaping, or a ``terms.CostSpec`` whose shaping it takes)."""
    occlusion = occlusion_of(occlusion)
    outlines, obs = _stack(frames, pairs)
    sigma = edge_sigma(obs, outlines, intr, pose, DEFAULT_NOISE if noise is None else noise,
                       _outline_sigma(frames, pairs), pair_scores(frames, pairs))
    censored = None
    if occlusion is not None and occlusion.censor:  # edges hidden behind a nearer box: bounds only
        frame_of = np.concatenate([np.full(len(p), k) for k, p in enumerate(pairs) if len(p)] or [np.zeros(0)])
        censored = occluded_edges(outlines, obs, frame_of, -pose.R.T @ pose.t, sigma)
        if occlusion.censor == "auto" and censored.any():
            rects, valid = project_rects(outlines, pose.R, pose.t, intr, frames[0].size)
            if not censor_evidence((rects - obs) / sigma[:, None], censored, valid, frames[0].size, rects):
                censored = None
    return BoxEdgeTerm(outlines, obs, frames[0].size, sigma, occlusion, censored)


def pair_scores(frames: list[CalibFrame], pairs: list[np.ndarray]) -> np.ndarray | None:
    """The detector score of each matched pair's 2D box, in ``_stack`` order; None unless every
    frame with matches carries scores (``CalibFrame.scores2d_input``)."""
    parts = []
    for fr, p in zip(frames, pairs):
        if not len(p):
            continue
        q = box_scores(fr)
        if q is None:
            return None
        parts.append(q[p[:, 0]])
    return np.concatenate(parts) if parts else None


def _outline_sigma(frames: list[CalibFrame], pairs: list[np.ndarray]) -> np.ndarray:
    """Each matched outline's own 1-sigma (m, ``CalibFrame.outline_sigma_m``; 0 where none), in ``_stack`` order."""
    parts = [fr.outline_sigma_m[p[:, 1]] if fr.outline_sigma_m is not None else np.zeros(len(p))
             for fr, p in zip(frames, pairs) if len(p)]
    return np.concatenate(parts) if parts else np.zeros(0)


def estimate_noise(frames, pairs, intr: CameraIntrinsics, R, t) -> NoiseModel:
    """Fit the per-edge error model sigma^2 = sp^2 + (f/Z s3)^2 + (ss s)^2 to the residuals.

    Only *outward* edge residuals are used (the 2D box reaching beyond the projected 3D box):
    occlusion and truncation never produce them, so for symmetric detector noise their mean
    square is half the edge variance. Non-negative least squares on those squares, trimmed
    twice at 8x the fitted variance (false matches); each term is floored at DEFAULT_NOISE
    (exact 3D boxes keep the default model; noisy 3D detections widen it).

    When every matched 2D box carries a detector score, a second fit adds one more term
    ``(sigma_score s (q_ref - q))^2`` (floor 0; ``q_ref``: the highest score among the kept
    pairs): how much noisier, relative to its size, a box is per unit of score below the most
    confident one, measured on this run's own residuals (a detector whose low scores are not
    noisier gets 0). It is fitted on the edges the 3-term fit kept (its trimming may drop more,
    never re-admit one): false matches stay outliers for the robust loss instead of making the
    score term, which describes the noise of right matches. Without scores, or when the kept
    pairs' scores are all equal, the model is the 3-term one.
    """
    from scipy.optimize import nnls

    corners, obs = _stack(frames, pairs)
    if len(obs) < 8:
        return DEFAULT_NOISE
    pose = Pose(R, t)
    rects, valid = project_rects(corners, pose.R, pose.t, intr, frames[0].size)
    W, H = frames[0].size
    e = rects - obs
    s, fz = _pair_features(obs, corners, intr, pose)
    X = np.repeat(np.column_stack([np.ones(len(s)), fz ** 2, s ** 2]), 4, axis=0)
    border = np.column_stack([rects[:, 0] <= 0.5, rects[:, 1] <= 0.5, rects[:, 2] >= W - 0.5, rects[:, 3] >= H - 0.5])
    out = valid[:, None] & ~border & np.isfinite(e) & (np.nan_to_num(e) * INWARD < 0)
    out &= (_outline_sigma(frames, pairs) == 0)[:, None]  # outlines with their own error (open yaw) say nothing of it
    y = 2.0 * np.nan_to_num(e).ravel() ** 2
    use = out.ravel()
    floor = np.array(DEFAULT_NOISE[:3]) ** 2
    coef = floor.copy()
    for _ in range(3):
        if use.sum() < 12:
            return DEFAULT_NOISE
        scale = np.maximum(X[use] @ coef, 1e-6)  # relative (heteroscedastic) least squares
        c, _ = nnls(X[use] / scale[:, None], y[use] / scale)
        coef = np.maximum(c, floor)
        use = out.ravel() & (y <= 8.0 * 2.0 * (X @ coef))
    plain = NoiseModel(*(float(v) for v in np.sqrt(coef)))
    q = pair_scores(frames, pairs)
    return plain if q is None else _score_noise(plain, X, y, use, s, q)


def _score_noise(plain: NoiseModel, X: np.ndarray, y: np.ndarray, use: np.ndarray, s: np.ndarray,
                 q: np.ndarray) -> NoiseModel:
    """``plain`` (the 3-term model fitted on the edges ``use``) with the score term fitted on those
    edges (see ``estimate_noise``): X [4n,3] its regressors, y [4n] twice the squared edge residuals,
    s [n] the boxes' sizes (px), q [n] their scores."""
    from scipy.optimize import nnls

    kept = use.reshape(-1, 4).any(axis=1)
    if not kept.any() or float(np.ptp(q[kept])) <= 0:
        return plain
    q_ref = float(q[kept].max())
    X4 = np.column_stack([X, np.repeat((s * np.clip(q_ref - q, 0.0, None)) ** 2, 4)])
    floor = np.append(np.array(DEFAULT_NOISE[:3]) ** 2, 0.0)
    coef = np.append(np.array(plain[:3]) ** 2, 0.0)
    keep = use.copy()
    for _ in range(3):
        if keep.sum() < 12:
            return plain
        scale = np.maximum(X4[keep] @ coef, 1e-6)
        c, _ = nnls(X4[keep] / scale[:, None], y[keep] / scale)
        coef = np.maximum(c, floor)
        keep = use & (y <= 8.0 * 2.0 * (X4 @ coef))
    sp, s3, ss, sq = (float(v) for v in np.sqrt(coef))
    return NoiseModel(sp, s3, ss, sq, q_ref) if sq > 0 else plain


def box_edges(ctx: TermContext, *, occlusion_tau: float = 1.5, occlusion_slope: float = 0.2) -> BoxEdgeTerm:
    """The ``xcalib.cost_terms`` factory of the box-edge term of the matched pairs (``cost.BoxEdgeTerm``)."""
    return edge_term(ctx.frames, ctx.pairs, ctx.intr, ctx.pose, ctx.noise, Occlusion(occlusion_tau, occlusion_slope))


def build_cost(frames: list[CalibFrame], pairs: list[np.ndarray], intr: CameraIntrinsics, pose: Pose,
               noise: NoiseModel | None = None, cost: "CostSpec | Occlusion | None" = Occlusion(), extra: tuple = (),
               edge=None) -> CostModel:
    """The one place a fit's ``CostModel`` is assembled: the box-edge term of the matched ``pairs``
    (weighted by ``noise`` at ``pose``, shaped by the spec's occlusion; ``edge``: a function that
    replaces it by a variant of it, e.g. ``boxmodel.outline_edge_term``), then the terms the stage
    adds (``extra``: self-calibration, misfit refits), then the terms the config names
    (``cost``: a ``terms.CostSpec``; an ``Occlusion`` or None: none), built by their factories."""
    spec = CostSpec.of(cost)
    base = edge_term(frames, pairs, intr, pose, noise, spec.occlusion)
    named = spec.extra_terms(TermContext(frames, pairs, intr, pose, noise)) if spec.terms else []
    return CostModel([base if edge is None else edge(base), *extra, *named], pose, intr)


def lsq(ctx: FitContext, max_nfev: int, extra: tuple = ()):
    """Robust (soft-L1) fit of the box-edge term (plus ``extra`` terms and those ``occlusion``, a
    ``terms.CostSpec``, names) from (R, t), matches fixed. Returns (R, t, cost, residuals, CostFit)."""
    frames, pairs, intr, R, t, f_scale, noise, occlusion = (ctx.frames, ctx.pairs, ctx.intr, ctx.pose.R, ctx.pose.t,
                                                            ctx.f_scale, ctx.noise, ctx.occlusion)
    pose = Pose(R, t)
    model = build_cost(frames, pairs, intr, pose, noise, occlusion, extra)
    fit = model.fit(f_scale=f_scale, max_nfev=max_nfev)
    return fit.pose.R, fit.pose.t, fit.cost, fit.residuals, fit


def refine_pose(frames: list[CalibFrame], intr: CameraIntrinsics, R, t, *, options: RefineOptions = RefineOptions(),
                occlusion: "Occlusion | CostSpec | None" = Occlusion()) -> RefineResult:
    """Alternate matching and robust least squares from the pose (R, t) until the cost settles.

    ``gates`` is the schedule of (IoU gate, centre-distance gate) per outer iteration; the last
    entry repeats until the robust cost improves by less than ``tol`` (relative) or the pose stops
    moving (about 2e-6 rad / 0.2 mm), at most ``max_outer`` iterations. With ``adapt_noise`` the
    per-edge error model is re-fitted to the residuals (``estimate_noise``) from the second
    iteration on, so noisy 3D boxes are weighted by their actual error. (``options``: these settings.)
    It is :func:`refine_start`, :func:`refine_step` until the run is done, then :func:`refine_finish`.
    """
    run = refine_start(frames, intr, R, t, options)
    while not run.done:
        refine_step(frames, intr, run, options, occlusion)
    return refine_finish(frames, intr, run, options)


@dataclass
class RefineRun:
    """A :func:`refine_pose` in progress, between two outer iterations: the pose (R, t), the matches
    ``pairs`` the next fit (iteration ``it``) uses, the last fit's per-match cost ``prev`` (None
    before the second fit), residuals and error model, the cost history; ``done`` when no fit is
    left (converged, too few matches or the iterations spent), ``n_iter`` then the iterations run."""

    R: np.ndarray
    t: np.ndarray
    pairs: list[np.ndarray]
    it: int = 0
    prev: float | None = None
    resid: np.ndarray = field(default_factory=lambda: np.zeros(0))
    noise: NoiseModel = DEFAULT_NOISE
    history: list[float] = field(default_factory=list)
    done: bool = False
    n_iter: int = 0


def _max_outer(options: RefineOptions) -> int:
    return len(options.gates) + 4 if options.max_outer is None else options.max_outer


def _match_next(frames: list[CalibFrame], intr: CameraIntrinsics, run: RefineRun, options: RefineOptions) -> RefineRun:
    """The matches of iteration ``run.it`` at the run's pose; done when the iterations are spent or
    the matches are fewer than ``options.min_pairs``."""
    if run.it >= _max_outer(options):
        run.done, run.n_iter = True, max(run.it, 1)
        return run
    gi, gd = options.gates[min(run.it, len(options.gates) - 1)]
    run.pairs = match_all(frames, intr, run.R, run.t, gate_iou=gi, gate_dist=gd)
    if sum(len(p) for p in run.pairs) < options.min_pairs:
        run.done, run.n_iter = True, run.it + 1
    return run


def refine_start(frames: list[CalibFrame], intr: CameraIntrinsics, R, t, options: RefineOptions = RefineOptions()) -> RefineRun:
    """A :func:`refine_pose` from (R, t), up to its first fit (the first iteration's matches)."""
    run = RefineRun(np.asarray(R, float), np.asarray(t, float), [])
    return _match_next(frames, intr, run, options)


def refine_step(frames: list[CalibFrame], intr: CameraIntrinsics, run: RefineRun, options: RefineOptions = RefineOptions(),
                occlusion: "Occlusion | CostSpec | None" = Occlusion()) -> RefineRun:
    """One outer iteration of a run that is not done (in place): the fit on its matches, the stop
    test, then the next iteration's matches."""
    n = sum(len(p) for p in run.pairs)
    # robust scale from the current (weighted) residual level
    f_scale = F_SCALE if run.prev is None or not len(run.resid) else max(0.5, 1.5 * float(np.median(np.abs(run.resid))))
    R_old, t_old = run.R, run.t
    if options.adapt_noise and run.it >= 1:
        run.noise = estimate_noise(frames, run.pairs, intr, run.R, run.t)
    run.R, run.t, cost, run.resid, _ = lsq(FitContext(frames, run.pairs, intr, Pose(run.R, run.t), run.noise, f_scale,
                                                      occlusion), options.max_nfev)
    per = cost / max(n, 1)
    run.history.append(per)
    prev, tol = run.prev, options.tol
    if run.it >= len(options.gates) - 1 and prev is not None and (abs(prev - per) <= tol * max(prev, 1e-9)
                                                                  or _moved(run.R, R_old, run.t, t_old) < 2e-6):
        run.done, run.n_iter = True, run.it + 1  # (how far the pose moved is computed only where the test needs it)
        return run
    run.prev = per
    run.it += 1
    return _match_next(frames, intr, run, options)


def refine_finish(frames: list[CalibFrame], intr: CameraIntrinsics, run: RefineRun,
                  options: RefineOptions = RefineOptions()) -> RefineResult:
    """The :class:`RefineResult` of a run that is done: its pose matched at the last gate."""
    gates = options.gates
    pairs = match_all(frames, intr, run.R, run.t, gate_iou=gates[-1][0], gate_dist=gates[-1][1])
    return RefineResult(R=run.R, t=run.t, pairs=pairs, cost=run.history[-1] if run.history else np.inf,
                        n_iter=run.n_iter, residuals=run.resid, history=run.history, noise=run.noise)


def _moved(R, R_old, t, t_old) -> float:
    """How far a refinement step moved the pose: rotation angle (rad) + translation (m) / 100."""
    return np.linalg.norm(Rotation.from_matrix(R @ R_old.T).as_rotvec()) + np.linalg.norm(t - t_old) / 100.0


def pair_metrics(frames: list[CalibFrame], intr: CameraIntrinsics, R, t, pairs: list[np.ndarray]):
    """Per matched pair: mean absolute edge residual (px) and IoU, concatenated over frames (the
    matched outlines of frames of one image size projected in one call)."""
    sizes = {tuple(fr.size) for fr, p in zip(frames, pairs) if len(p)}
    if not sizes:
        return np.zeros(0), np.zeros(0)
    if len(sizes) > 1:  # frames of several image sizes: frame by frame
        parts = [pair_metrics([fr], intr, R, t, [p]) for fr, p in zip(frames, pairs) if len(p)]
        return np.concatenate([a for a, _ in parts]), np.concatenate([b for _, b in parts])
    corners, obs = _stack(frames, pairs)
    rects, _ = project_rects(corners, R, t, intr, next(iter(sizes)))
    return np.nanmean(np.abs(rects - obs), axis=1), _paired_iou(rects, obs)


def _paired_iou(rects: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """IoU of rects[i] with boxes[i] [n] (NaN rect -> 0): ``iou_batched``'s diagonal, the same operations."""
    r = np.nan_to_num(rects, nan=0.0)
    b = np.asarray(boxes, dtype=np.float64)
    w = np.minimum(r[:, 2], b[:, 2]) - np.maximum(r[:, 0], b[:, 0])
    np.clip(w, 0, None, out=w)
    h = np.minimum(r[:, 3], b[:, 3]) - np.maximum(r[:, 1], b[:, 1])
    np.clip(h, 0, None, out=h)
    inter = w * h
    union = (r[:, 2] - r[:, 0]) * (r[:, 3] - r[:, 1]) + (b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1])
    union -= inter
    pos = union > 0
    out = np.zeros(len(r))
    np.divide(inter, union, out=out, where=pos)
    return out
