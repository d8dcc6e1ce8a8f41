"""Pose refinement over all frames: match by projection, then robust least squares on box edges.

The residual of a matched pair (2D box i, 3D box j) is the difference (pixels) between the four
edges of the clipped enclosing rectangle of the projected 3D box corners and the 2D box's
edges. ``refine_pose`` alternates one-to-one matching (Hungarian with a gate) and
``scipy.optimize.least_squares`` (soft-L1) until the robust cost stops improving. The pose is
``X_cam = R X_lidar + t``; updates are ``R <- exp([w]x) R``, ``t <- t + dt`` (camera frame).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares, linear_sum_assignment
from scipy.spatial.transform import Rotation

from ..geometry.boxes import box2d_centers
from ..geometry.camera import CameraIntrinsics
from .boxproj import iou_batched, project_rects
from .inputs import CalibFrame

__all__ = ["RefineResult", "match_frame", "match_all", "refine_pose", "pose_covariance", "pair_metrics",
           "pose_spread", "pose_jackknife", "HALF_MIN_MATCHES"]


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
    noise: tuple = (1.0, 0.03, 0.01)  # fitted (sigma_px, sigma_3d_m, sigma_size), see estimate_noise


def match_frame(fr: CalibFrame, intr: CameraIntrinsics, R, t, *, gate_iou: float = 0.3,
                gate_dist: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One-to-one matches of one frame by projection.

    A pair is allowed when IoU >= ``gate_iou`` or, if ``gate_dist`` > 0, when the centre distance
    is below ``gate_dist`` times the 2D box diagonal (for rough poses). Hungarian on
    cost = (1 - IoU) + normalised centre distance. Returns (pairs [n,2] rows, IoU [n], rects [M,4]).
    """
    rects, valid = project_rects(fr.corners, R, t, intr, fr.size)
    if fr.n2 == 0 or fr.n3 == 0 or not np.any(valid):
        return np.zeros((0, 2), dtype=np.int64), np.zeros(0), rects
    iou = iou_batched(rects[None], fr.boxes2d)[0]
    c_obs = box2d_centers(fr.boxes2d)
    c_pred = np.stack([(rects[:, 0] + rects[:, 2]) / 2, (rects[:, 1] + rects[:, 3]) / 2], 1)
    diag = np.hypot(fr.boxes2d[:, 2] - fr.boxes2d[:, 0], fr.boxes2d[:, 3] - fr.boxes2d[:, 1])
    dist = np.linalg.norm(c_obs[:, None] - c_pred[None], axis=2) / diag[:, None]
    dist = np.where(valid[None], dist, np.inf)
    allowed = (iou >= gate_iou) if gate_dist <= 0 else ((iou >= gate_iou) | (dist <= gate_dist))
    allowed &= valid[None]
    if not np.any(allowed):
        return np.zeros((0, 2), dtype=np.int64), np.zeros(0), rects
    cost = np.where(allowed, (1 - iou) + np.minimum(dist, 10.0), 1e6)
    r, c = linear_sum_assignment(cost)
    keep = allowed[r, c]
    pairs = np.column_stack([r[keep], c[keep]]).astype(np.int64)
    return pairs, iou[r[keep], c[keep]], rects


def match_all(frames, intr, R, t, **kw) -> list[np.ndarray]:
    return [match_frame(fr, intr, R, t, **kw)[0] for fr in frames]


def _stack(frames: list[CalibFrame], pairs: list[np.ndarray]):
    corners = [fr.corners[p[:, 1]] for fr, p in zip(frames, pairs) if len(p)]
    obs = [fr.boxes2d[p[:, 0]] for fr, p in zip(frames, pairs) if len(p)]
    if not corners:
        return np.zeros((0, 8, 3)), np.zeros((0, 4))
    S = max(c.shape[1] for c in corners)
    # outlines may differ in length between frames: pad by repeating each box's first vertex
    corners = [c if c.shape[1] == S else np.concatenate([c, np.repeat(c[:, :1], S - c.shape[1], 1)], 1)
               for c in corners]
    return np.concatenate(corners), np.concatenate(obs)


# Expected per-edge disagreement (1 sigma) of a matched pair, in pixels:
#   sigma^2 = SIGMA_PX^2 + (f * SIGMA_3D_M / Z)^2 + (SIGMA_SIZE * s)^2
# (2D box noise, 3D box position noise seen at depth Z, relative 3D size/shape error of a
# box of size s px). Residuals are divided by sigma, which makes near and far boxes comparable.
SIGMA_PX = 1.0
SIGMA_3D_M = 0.03
SIGMA_SIZE = 0.01
F_SCALE = 2.0


NoiseModel = tuple  # (sigma_px, sigma_3d_m, sigma_size) of the per-edge disagreement, see above
DEFAULT_NOISE: NoiseModel = (SIGMA_PX, SIGMA_3D_M, SIGMA_SIZE)


def _pair_features(obs: np.ndarray, corners: np.ndarray, intr: CameraIntrinsics, R, t):
    """Per pair: 2D box size s (px, sqrt of its area) and f/Z (px per metre at the box centre)."""
    s = np.sqrt(np.clip((obs[:, 2] - obs[:, 0]) * (obs[:, 3] - obs[:, 1]), 0, None))
    ctr = corners.mean(1) @ np.asarray(R).T + np.asarray(t)
    z = np.maximum(ctr[:, 2], 1.0)
    return s, np.sqrt(intr.fx * intr.fy) / z


def _weights(obs: np.ndarray, corners: np.ndarray, intr: CameraIntrinsics, R, t,
             noise: NoiseModel | None = None) -> np.ndarray:
    """Per-pair residual weight 1/sigma (1/px) at the pose (R, t); see SIGMA_* above."""
    sp, s3, ss = DEFAULT_NOISE if noise is None else noise
    s, fz = _pair_features(obs, corners, intr, R, t)
    return 1.0 / np.sqrt(sp ** 2 + (fz * s3) ** 2 + (ss * s) ** 2)


def estimate_noise(frames, pairs, intr: CameraIntrinsics, R, t) -> NoiseModel:
    """Fit the per-edge error model sigma^2 = sp^2 + (f/Z s3)^2 + (ss s)^2 to the residuals.

    Only *outward* edge residuals are used (the 2D box reaching beyond the projected 3D box):
    occlusion and truncation never produce them, so for symmetric detector noise their mean
    square is half the edge variance. Non-negative least squares on those squares, trimmed
    twice at 8x the fitted variance (false matches); each term is floored at DEFAULT_NOISE
    (exact 3D boxes keep the default model; noisy 3D detections widen it).
    """
    from scipy.optimize import nnls

    corners, obs = _stack(frames, pairs)
    if len(obs) < 8:
        return DEFAULT_NOISE
    rects, valid = project_rects(corners, R, t, intr, frames[0].size)
    W, H = frames[0].size
    e = rects - obs
    s, fz = _pair_features(obs, corners, intr, R, t)
    X = np.repeat(np.column_stack([np.ones(len(s)), fz ** 2, s ** 2]), 4, axis=0)
    border = np.column_stack([rects[:, 0] <= 0.5, rects[:, 1] <= 0.5, rects[:, 2] >= W - 0.5, rects[:, 3] >= H - 0.5])
    out = valid[:, None] & ~border & np.isfinite(e) & (np.nan_to_num(e) * _INWARD < 0)
    y = 2.0 * np.nan_to_num(e).ravel() ** 2
    use = out.ravel()
    floor = np.array(DEFAULT_NOISE) ** 2
    coef = floor.copy()
    for _ in range(3):
        if use.sum() < 12:
            return DEFAULT_NOISE
        scale = np.maximum(X[use] @ coef, 1e-6)  # relative (heteroscedastic) least squares
        c, _ = nnls(X[use] / scale[:, None], y[use] / scale)
        coef = np.maximum(c, floor)
        use = out.ravel() & (y <= 8.0 * 2.0 * (X @ coef))
    return tuple(float(v) for v in np.sqrt(coef))


# Occlusion (and a detector's truncation) only ever moves a 2D box edge *into* the projected
# outline. Residuals in that direction beyond OCCL_TAU (weighted units, ~sigma) are compressed
# by OCCL_SLOPE before the robust loss, so partly hidden objects pull the pose less.
OCCL_TAU = 1.5
OCCL_SLOPE = 0.2
_INWARD = np.array([-1.0, -1.0, 1.0, 1.0])  # sign of (pred - obs) when the 2D box is inside


def _residual_fn(corners, obs, intr, size, R0, t0, noise: NoiseModel | None = None):
    w = _weights(obs, corners, intr, R0, t0, noise)[:, None]
    fallback = np.sqrt((obs[:, 2] - obs[:, 0]) * (obs[:, 3] - obs[:, 1]))[:, None]

    def fun(x):
        R = Rotation.from_rotvec(x[:3]).as_matrix() @ R0
        t = t0 + x[3:]
        rects, valid = project_rects(corners, R, t, intr, size)
        r = np.where(valid[:, None], rects - obs, fallback) * w
        s = r * _INWARD
        s = np.where(s > OCCL_TAU, OCCL_TAU + OCCL_SLOPE * (s - OCCL_TAU), s)
        return (s * _INWARD).ravel()

    return fun


def pose_covariance(frames, pairs, intr, R, t, *, eps: float = 1e-6, noise: NoiseModel | None = None):
    """1-sigma (rotation deg about camera x,y,z; translation m along camera x,y,z) from the
    Jacobian at the optimum: the larger (per parameter) of the classic (J^T J)^-1 * sigma^2
    (sigma from the inlier residuals) and the cluster-robust sandwich with one cluster per
    matched pair (its 4 edges share the box-model error)."""
    corners, obs = _stack(frames, pairs)
    nan3 = np.full(3, np.nan)
    if len(obs) < 2:
        return nan3, nan3, np.full((6, 6), np.nan)
    fun = _residual_fn(corners, obs, intr, frames[0].size, R, t, noise)
    r0 = fun(np.zeros(6))
    J = np.zeros((len(r0), 6))
    for k in range(6):
        dx = np.zeros(6)
        dx[k] = eps
        J[:, k] = (fun(dx) - fun(-dx)) / (2 * eps)
    # edges clipped at the image border carry no information (zero derivative) -> drop them
    informative = np.any(J != 0, axis=1)
    sigma = 1.4826 * np.median(np.abs(r0[informative])) if np.any(informative) else np.nan
    inl = informative & (np.abs(r0) <= 3 * max(sigma, 1e-9))
    dof = max(int(inl.sum()) - 6, 1)
    sigma2 = np.sum(r0[inl] ** 2) / dof
    JtJ = J[inl].T @ J[inl]
    try:
        A = np.linalg.inv(JtJ)
    except np.linalg.LinAlgError:
        return nan3, nan3, np.full((6, 6), np.nan)
    cov = A * sigma2
    # sandwich: per-pair score vectors g_c = J_c^T r_c over the inlier edges of pair c
    g = ((J * np.where(inl, r0, 0.0)[:, None]).reshape(-1, 4, 6)).sum(1)  # [n_pairs, 6]
    nc = int(np.sum(inl.reshape(-1, 4).any(1)))
    meat = g.T @ g * (nc / max(nc - 6, 1))
    cov_s = A @ meat @ A
    if np.trace(cov_s) > np.trace(cov):
        cov = cov_s
    sd = np.sqrt(np.clip(np.maximum(np.diag(A * sigma2), np.diag(cov_s)), 0, None))
    return np.degrees(sd[:3]), sd[3:], cov


def _lsq(frames, pairs, intr, R, t, f_scale, max_nfev, noise: NoiseModel | None = None):
    corners, obs = _stack(frames, pairs)
    fun = _residual_fn(corners, obs, intr, frames[0].size, R, t, noise)
    res = least_squares(fun, np.zeros(6), loss="soft_l1", f_scale=f_scale, method="trf",
                        x_scale=np.array([1e-3, 1e-3, 1e-3, 0.05, 0.05, 0.05]), max_nfev=max_nfev)
    R1 = Rotation.from_rotvec(res.x[:3]).as_matrix() @ R
    return R1, t + res.x[3:], res.cost, res.fun


def refine_pose(frames: list[CalibFrame], intr: CameraIntrinsics, R, t, *,
                gates: tuple = ((0.1, 1.0), (0.2, 0.5), (0.3, 0.0), (0.3, 0.0), (0.3, 0.0), (0.3, 0.0)),
                min_pairs: int = 3, max_nfev: int = 60, tol: float = 1e-3, max_outer: int | None = None,
                adapt_noise: bool = True) -> RefineResult:
    """Alternate matching and robust least squares from the pose (R, t) until the cost settles.

    ``gates`` is the schedule of (IoU gate, centre-distance gate) per outer iteration; the last
    entry repeats until the robust cost improves by less than ``tol`` (relative) or the pose stops
    moving (about 2e-6 rad / 0.2 mm), at most ``max_outer`` iterations. With ``adapt_noise`` the
    per-edge error model is re-fitted to the residuals (``estimate_noise``) from the second
    iteration on, so noisy 3D boxes are weighted by their actual error.
    """
    noise = DEFAULT_NOISE
    R, t = np.asarray(R, float), np.asarray(t, float)
    history: list[float] = []
    prev = None
    it = 0
    resid = np.zeros(0)
    for it in range(len(gates) + 4 if max_outer is None else max_outer):
        gi, gd = gates[min(it, len(gates) - 1)]
        pairs = match_all(frames, intr, R, t, gate_iou=gi, gate_dist=gd)
        n = sum(len(p) for p in pairs)
        if n < min_pairs:
            break
        _, obs = _stack(frames, pairs)
        # robust scale from the current (weighted) residual level
        f_scale = F_SCALE if prev is None or not len(resid) else max(0.5, 1.5 * float(np.median(np.abs(resid))))
        R_old, t_old = R, t
        if adapt_noise and it >= 1:
            noise = estimate_noise(frames, pairs, intr, R, t)
        R, t, cost, resid = _lsq(frames, pairs, intr, R, t, f_scale, max_nfev, noise)
        per = cost / max(n, 1)
        history.append(per)
        moved = np.linalg.norm(Rotation.from_matrix(R @ R_old.T).as_rotvec()) + np.linalg.norm(t - t_old) / 100.0
        if it >= len(gates) - 1 and prev is not None and (abs(prev - per) <= tol * max(prev, 1e-9) or moved < 2e-6):
            break
        prev = per
    pairs = match_all(frames, intr, R, t, gate_iou=gates[-1][0], gate_dist=gates[-1][1])
    return RefineResult(R=R, t=t, pairs=pairs, cost=history[-1] if history else np.inf, n_iter=it + 1,
                        residuals=resid, history=history, noise=noise)


def pair_metrics(frames: list[CalibFrame], intr: CameraIntrinsics, R, t, pairs: list[np.ndarray]):
    """Per matched pair: mean absolute edge residual (px) and IoU, concatenated over frames."""
    px, ious = [], []
    for fr, p in zip(frames, pairs):
        if len(p) == 0:
            continue
        rects, _ = project_rects(fr.corners[p[:, 1]], R, t, intr, fr.size)
        obs = fr.boxes2d[p[:, 0]]
        px.append(np.nanmean(np.abs(rects - obs), axis=1))
        ious.append(np.diagonal(iou_batched(rects[None], obs)[0]))
    if not px:
        return np.zeros(0), np.zeros(0)
    return np.concatenate(px), np.concatenate(ious)


def _delta(Ra, ta, Rb, tb) -> np.ndarray:
    """6-vector (rotation vector of Ra Rb^T in degrees, camera axes; ta - tb in metres)."""
    return np.concatenate([np.degrees(Rotation.from_matrix(Ra @ Rb.T).as_rotvec()), ta - tb])


HALF_MIN_MATCHES = 6  # matches each half of the frames (or pairs) needs for the frame-halves check


def pose_spread(frames, pairs, intr, R, t, *, noise: NoiseModel | None = None, f_scale: float = F_SCALE,
                max_nfev: int = 40):
    """Two checks of the pose beyond the Jacobian, both with the matches held fixed.

    * ``halves``: refit on the even and on the odd frames separately (or on alternate pairs when
      there is one frame); returns their difference (6-vector, deg / m). For independent frame
      errors the full-data pose has about a quarter of its variance per component.
    * ``occlusion``: refit without the inward (occlusion) compression; the shift of the pose is
      how much it depends on the occlusion model (a systematic error the Jacobian cannot see).
    Returns (halves_delta [6] or None, occlusion_delta [6]).
    """
    global OCCL_TAU
    R, t = np.asarray(R, float), np.asarray(t, float)
    halves = None
    nz = [k for k, p in enumerate(pairs) if len(p)]
    if len(nz) >= 4:
        ev = [p if (i in nz[0::2]) else p[:0] for i, p in enumerate(pairs)]
        od = [p if (i in nz[1::2]) else p[:0] for i, p in enumerate(pairs)]
    else:
        ev = [p[0::2] for p in pairs]
        od = [p[1::2] for p in pairs]
    if sum(len(p) for p in ev) >= HALF_MIN_MATCHES and sum(len(p) for p in od) >= HALF_MIN_MATCHES:
        Re, te, _, _ = _lsq(frames, ev, intr, R, t, f_scale, max_nfev, noise)
        Ro, to, _, _ = _lsq(frames, od, intr, R, t, f_scale, max_nfev, noise)
        halves = _delta(Re, te, Ro, to)
    tau = OCCL_TAU
    try:
        OCCL_TAU = 1e9
        Rs, ts, _, _ = _lsq(frames, pairs, intr, R, t, f_scale, max_nfev, noise)
    finally:
        OCCL_TAU = tau
    return halves, _delta(Rs, ts, R, t)


def pose_jackknife(frames, pairs, intr, R, t, *, noise: NoiseModel | None = None, f_scale: float = F_SCALE,
                   max_nfev: int = 40, max_groups: int = 24) -> np.ndarray | None:
    """Leave-one-pair-out (jackknife) 1-sigma of the pose, 6-vector (deg about camera x,y,z; m).

    For recordings with too few matches for the frame-halves check: the pose is refitted (matches
    held fixed) without each matched pair in turn, and the spread of those G poses gives
    ``sqrt((G-1)/G * sum (p_i - p_mean)^2)``: the cluster-robust variance with one cluster per
    pair (its four edges share the 3D-box error), which, unlike the Jacobian sandwich and the
    error model fitted to the residuals, stays honest with a handful of pairs. Beyond
    ``max_groups`` pairs, groups of pairs are left out instead. None with fewer than 4 pairs.
    """
    R, t = np.asarray(R, float), np.asarray(t, float)
    where = np.array([(k, i) for k, p in enumerate(pairs) for i in range(len(p))], dtype=np.int64).reshape(-1, 2)
    if len(where) < 4:
        return None
    groups = np.array_split(np.arange(len(where)), min(len(where), max_groups))
    d = []
    for g in groups:
        drop = where[g]
        sub = [np.delete(p, drop[drop[:, 0] == j, 1], axis=0) for j, p in enumerate(pairs)]
        Rj, tj, _, _ = _lsq(frames, sub, intr, R, t, f_scale, max_nfev, noise)
        d.append(_delta(Rj, tj, R, t))
    d = np.asarray(d)
    G = len(d)
    return np.sqrt((G - 1) / G * np.sum((d - d.mean(0)) ** 2, axis=0))
