"""Several poses of one frame refined at once: the consensus matcher's short refinement.

The same schedule and objective as :func:`xcalib.calib.refine.refine_pose` run on one frame
(match by projection with the gate of the outer iteration, then a robust soft-L1 fit of the
box-edge residuals of ``cost.BoxEdgeTerm``: projected outline edges minus 2D box edges, divided
by the per-pair sigma of the error model, inward residuals shaped by the occlusion model), but
for H starting poses in one set of array operations: every projection, residual and analytic
Jacobian is one [H, pairs, ...] computation, and the 6x6 normal equations of all poses are
solved together (Levenberg-Marquardt with iteratively reweighted soft-L1 weights, each pose
stopping when its step or its cost change is negligible). A frame's consensus refines ~6 poses
of ~10-20 pairs each, where the per-call overhead of ``scipy.optimize.least_squares`` (and the
~100 small numpy calls of one residual + Jacobian) was the whole cost.

Pinhole ``CameraIntrinsics`` (OpenCV distortion included) only; :func:`refine_poses` falls back
to ``refine_pose`` pose by pose for other camera models. The pose is ``X_cam = R X_lidar + t``;
steps are ``R <- exp([w]x) R``, ``t <- t + dt`` (camera frame), as in ``refine``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry.boxes import box2d_centers
from ..geometry.camera import CameraIntrinsics
from .boxproj import MIN_DEPTH_M, iou_batched, project_rects
from .context import F_SCALE, RefineOptions
from .cost import INWARD, Occlusion, _distort_with_jacobian, _distortion, edge_sigma
from .inputs import CalibFrame
from .pose import Pose
from .refine import DEFAULT_NOISE, _assign, estimate_noise, pair_scores, refine_pose

__all__ = ["PosesFit", "refine_poses", "match_poses"]

STEP_TOL = 1e-8  # a step below this (rad, and m / 100) is settled
COST_TOL = 1e-9  # as is a relative decrease of the robust cost below this


@dataclass
class PosesFit:
    """The refined poses R [H,3,3], t [H,3]; per pose the matches at the last gate (rows of the
    frame's arrays) and their summed IoU ``score`` [H]; ``iou`` [H,K,M] the IoU of every 2D box
    with every projected outline at the refined poses (``match_poses``'; None: not kept)."""

    R: np.ndarray
    t: np.ndarray
    pairs: list[np.ndarray]
    score: np.ndarray
    iou: np.ndarray | None = None


def match_poses(fr: CalibFrame, intr: CameraIntrinsics, R: np.ndarray, t: np.ndarray, gate_iou: float,
                gate_dist: float) -> tuple[list[np.ndarray], np.ndarray]:
    """``refine.match_frame`` at each of H poses (R [H,3,3], t [H,3]): the pairs of each and the
    IoU [H,K,M] of every 2D box with every projected 3D box, all poses projected in one call."""
    H = len(R)
    if fr.n2 == 0 or fr.n3 == 0:
        return [np.zeros((0, 2), np.int64) for _ in range(H)], np.zeros((H, fr.n2, fr.n3))
    rects, valid = project_rects(fr.corners, R, t, intr, fr.size)
    iou = iou_batched(rects, fr.boxes2d)
    c_obs = box2d_centers(fr.boxes2d)
    c_pred = np.stack([(rects[..., 0] + rects[..., 2]) / 2, (rects[..., 1] + rects[..., 3]) / 2], -1)  # [H,M,2]
    diag = np.hypot(fr.boxes2d[:, 2] - fr.boxes2d[:, 0], fr.boxes2d[:, 3] - fr.boxes2d[:, 1])
    dist = np.linalg.norm(c_obs[None, :, None] - c_pred[:, None], axis=3) / diag[None, :, None]
    out = []
    for h in range(H):
        if not np.any(valid[h]):
            out.append(np.zeros((0, 2), np.int64))
            continue
        out.append(_assign(iou[h], dist[h], valid[h], gate_iou, gate_dist)[0])
    return out, iou


class _Batch:
    """The matched pairs of H poses, padded to P pairs: outlines [H,P,S,3], 2D boxes [H,P,4],
    weights 1/sigma [H,P], mask [H,P]; residuals and Jacobians at poses (R [H,3,3], t [H,3])."""

    def __init__(self, fr: CalibFrame, pairs: list[np.ndarray], sigma: list[np.ndarray], intr: CameraIntrinsics,
                 occlusion: Occlusion | None):
        H, P = len(pairs), max(max((len(p) for p in pairs), default=0), 1)
        S = fr.corners.shape[1]
        self.C = np.zeros((H, P, S, 3))
        self.obs = np.tile(np.array([0.0, 0.0, 1.0, 1.0]), (H, P, 1))
        self.w = np.zeros((H, P))
        self.mask = np.zeros((H, P), bool)
        for h, (p, s) in enumerate(zip(pairs, sigma)):
            n = len(p)
            if n:
                self.C[h, :n], self.obs[h, :n] = fr.corners[p[:, 1]], fr.boxes2d[p[:, 0]]
                self.w[h, :n], self.mask[h, :n] = 1.0 / s, True
        self.C[~self.mask] = np.array([0.0, 0.0, 10.0])  # padding: any point ahead (weight 0)
        o = self.obs
        self.fallback = np.sqrt((o[..., 2] - o[..., 0]) * (o[..., 3] - o[..., 1]))[..., None]
        self.intr, self.size, self.occlusion, self.dist = intr, fr.size, occlusion, _distortion(intr)

    def take(self, idx: np.ndarray) -> "_Batch":
        """The batch of the poses ``idx`` only (the same arrays, rows ``idx``): a fit evaluates
        only the poses still moving, with the same operations per pose, so the same values."""
        out = object.__new__(_Batch)
        out.__dict__.update(self.__dict__)
        for k in ("C", "obs", "w", "mask", "fallback"):
            setattr(out, k, getattr(self, k)[idx])
        return out

    def _project(self, R, t):
        """The operations of ``boxproj.project_rects`` on the pairs' outlines: rects [H,P,4]
        (clipped), valid [H,P], and for :meth:`jacobian` the unclipped edges ext [H,P,4] (u min,
        v min, u max, v max) and the camera-frame corner Y = R c (without t) that defines each of
        them, Ys [H,P,4,3] (a box that cannot be projected: its first corner, 4 times)."""
        H, P, S = self.C.shape[:3]
        # one (P*S, 3) x (3, 3) product per pose instead of one per pair: the same BLAS products
        Y = (self.C.reshape(H, P * S, 3) @ R.transpose(0, 2, 1)).reshape(H, P, S, 3)
        z = Y[..., 2] + t[:, None, None, 2]
        ahead = z > MIN_DEPTH_M
        inv = 1.0 / np.where(ahead, z, np.nan)
        x = (Y[..., 0] + t[:, None, None, 0]) * inv
        y = (Y[..., 1] + t[:, None, None, 1]) * inv
        if self.dist is not None:
            x, y = _distort_with_jacobian(x, y, self.dist)[:2]
        intr = self.intr
        u, v = x * intr.fx + intr.cx, y * intr.fy + intr.cy
        # each edge is the coordinate of its defining corner (the first extreme; min / max are
        # exact, and a row with a NaN gives NaN either way: arg-min / -max point at its first NaN)
        at = np.stack([u.argmin(-1), v.argmin(-1), u.argmax(-1), v.argmax(-1)], -1)
        first = (np.arange(H * P) * S).reshape(H, P, 1)  # flat index of each row's first corner
        at += first
        ext = np.empty((H, P, 4))
        ext[..., 0::2] = u.reshape(-1)[at[..., 0::2]]
        ext[..., 1::2] = v.reshape(-1)[at[..., 1::2]]
        W, Hh = self.size
        rect = np.clip(ext, 0.0, np.array([W, Hh, W, Hh], dtype=np.float64))
        with np.errstate(invalid="ignore"):
            valid = ahead.all(-1) & (rect[..., 2] - rect[..., 0] > 1.0) & (rect[..., 3] - rect[..., 1] > 1.0)
        at[~valid] = first[~valid]  # (no Jacobian there: any finite corner, the first)
        return Y.reshape(-1, 3)[at], ext, rect, valid

    def residuals(self, R, t):
        """Weighted, shaped edge residuals [H,P,4] (0 on padding), the unshaped weighted ones, and
        the projection (for :meth:`jacobian`)."""
        proj = self._project(R, t)
        rect, valid = proj[2], proj[3]
        raw = np.where(valid[..., None], rect - self.obs, self.fallback) * self.w[..., None]
        r = raw
        if self.occlusion is not None:
            s = raw * INWARD
            r = np.where(s > self.occlusion.tau, self.occlusion.tau + self.occlusion.slope * (s - self.occlusion.tau),
                         s) * INWARD
        return r * self.mask[..., None], raw, proj

    def jacobian(self, t, raw, proj) -> np.ndarray:
        """d residuals / d (rotvec, dt) [H,P,4,6] at the projected poses (``BoxEdgeTerm.jacobian``
        at rotvec 0, batched): the derivative of each edge is that of the corner defining it, zero
        where the edge is clipped to the image or the box cannot be projected."""
        Ys, ext, _, valid = proj
        W, Hh = self.size
        inside = (ext > 0.0) & (ext < np.array([W, Hh, W, Hh], dtype=np.float64))
        izs = 1.0 / np.where(valid[..., None], Ys[..., 2] + t[:, None, None, 2], 1.0)
        xs, ys = (Ys[..., 0] + t[:, None, None, 0]) * izs, (Ys[..., 1] + t[:, None, None, 1]) * izs
        if self.dist is None:
            a11, a12, a21, a22 = 1.0, 0.0, 0.0, 1.0
        else:
            a11, a12, a21, a22 = _distort_with_jacobian(xs, ys, self.dist)[2:]
        is_u = np.array([True, False, True, False])
        f = np.where(is_u, self.intr.fx, self.intr.fy)
        c1 = f * np.where(is_u, a11, a21)
        c2 = f * np.where(is_u, a12, a22)
        a = np.stack([c1 * izs, c2 * izs, -(c1 * xs + c2 * ys) * izs], -1)  # d edge / d X_cam [H,P,4,3]
        D = np.empty(a.shape[:-1] + (6,))
        D[..., 0] = Ys[..., 1] * a[..., 2] - Ys[..., 2] * a[..., 1]  # (R c) x a
        D[..., 1] = Ys[..., 2] * a[..., 0] - Ys[..., 0] * a[..., 2]
        D[..., 2] = Ys[..., 0] * a[..., 1] - Ys[..., 1] * a[..., 0]
        D[..., 3:] = a
        scale = (inside & valid[..., None]) * (self.w * self.mask)[..., None]
        if self.occlusion is not None:
            scale = np.where(raw * INWARD > self.occlusion.tau, self.occlusion.slope * scale, scale)
        return D * scale[..., None]


def _robust(r: np.ndarray, fs: np.ndarray):
    """soft-L1 cost per pose (``least_squares``' convention: 0.5 f^2 sum 2(sqrt(1 + (r/f)^2) - 1))
    and s = sqrt(1 + (r/f)^2) of each residual, for residuals r [H,...] and scales fs [H]: the
    gradient weights residuals by rho' = 1/s, the Gauss-Newton Hessian by rho' + 2 rho'' r^2 = 1/s^3
    (``least_squares``' second-order correction for a robust loss)."""
    f = fs.reshape((-1,) + (1,) * (r.ndim - 1))
    s = np.sqrt(1.0 + (r / f) ** 2)
    cost = (f.reshape(-1) ** 2) * np.sum((s - 1.0).reshape(len(r), -1), axis=1)
    return cost, s


def _fit(batch: _Batch, R: np.ndarray, t: np.ndarray, fs: np.ndarray, active: np.ndarray, max_iter: int):
    """Robust Levenberg-Marquardt fit of the poses flagged ``active`` [H], at most ``max_iter``
    evaluations; returns (R, t, residuals [H,P,4]). Each step solves, projects and
    differentiates only the poses still live (settled ones keep their state), pose by pose the
    same operations as on the whole batch."""
    R, t = R.copy(), t.copy()
    r, raw, proj = batch.residuals(R, t)
    cost, wts = _robust(r, fs)
    lam = np.full(len(R), 1e-3)
    live = active.copy()
    J = batch.jacobian(t, raw, proj)
    eye = np.eye(6)
    for it in range(max_iter):
        idx = np.flatnonzero(live)
        if not len(idx):
            break
        sub = batch if len(idx) == len(R) else batch.take(idx)
        n = len(idx)
        Jf = J[idx].reshape(n, -1, 6)
        sf = wts[idx].reshape(n, -1)
        Jt = Jf.transpose(0, 2, 1)
        A = (Jt * sf[:, None, :] ** -3) @ Jf
        g = (Jt @ (r[idx].reshape(n, -1) / sf)[..., None])[..., 0]
        dA = np.maximum(np.diagonal(A, axis1=1, axis2=2), 1e-12)
        M = A + lam[idx, None, None] * (eye * dA[:, None, :])
        dx = -np.linalg.solve(M, g[..., None])[..., 0]
        Rn = _exp(dx[:, :3]) @ R[idx]
        tn = t[idx] + dx[:, 3:]
        rn, rawn, projn = sub.residuals(Rn, tn)
        cn, wn = _robust(rn, fs[idx])
        better = cn <= cost[idx]
        dx2 = dx * dx  # (np.linalg.norm's own sums of squares, without its wrapper)
        step = np.sqrt(np.add.reduce(dx2[:, :3], axis=1)) + np.sqrt(np.add.reduce(dx2[:, 3:], axis=1)) / 100.0
        settled = better & ((step < STEP_TOL) | (cost[idx] - cn <= COST_TOL * np.maximum(cost[idx], 1e-12)))
        if better.any():
            b = idx[better]
            R[b], t[b] = Rn[better], tn[better]
            r[b], raw[b], wts[b], cost[b] = rn[better], rawn[better], wn[better], cn[better]
        lam[idx] = np.where(better, np.maximum(lam[idx] / 3.0, 1e-9), lam[idx] * 4.0)
        live[idx] &= ~settled & (lam[idx] < 1e8)
        # the Jacobian at the new pose only where another step will use it: not for a pose that has
        # just settled, nor after the last step (the returned poses and residuals are the same)
        kb = np.flatnonzero(better & live[idx]) if it + 1 < max_iter else np.zeros(0, np.int64)
        if len(kb):
            J[idx[kb]] = (sub if len(kb) == n else sub.take(kb)).jacobian(tn[kb], rawn[kb], tuple(a[kb] for a in projn))
    return R, t, r


def refine_poses(fr: CalibFrame, intr: CameraIntrinsics, R0, t0, options: RefineOptions = RefineOptions(),
                 occlusion: Occlusion | None = Occlusion()) -> PosesFit:
    """Refine H starting poses (R0 [H,3,3], t0 [H,3]) of one frame with ``refine_pose``'s schedule
    (``options``: gates, min_pairs, tol, max_outer, adapt_noise; ``max_nfev``: residual
    evaluations per fit, each pose stopping earlier when its step or cost change is negligible) and objective; the matches and summed IoU at the last gate."""
    R, t = np.asarray(R0, dtype=np.float64).reshape(-1, 3, 3).copy(), np.asarray(t0, dtype=np.float64).reshape(-1, 3).copy()
    H = len(R)
    if not isinstance(intr, CameraIntrinsics) or H == 0:  # other camera models: pose by pose
        out = [refine_pose([fr], intr, R[h], t[h], options=options, occlusion=occlusion) for h in range(H)]
        R = np.stack([o.R for o in out]) if out else R
        t = np.stack([o.t for o in out]) if out else t
        pairs, iou = match_poses(fr, intr, R, t, options.gates[-1][0], options.gates[-1][1])
        return PosesFit(R, t, pairs, np.array([float(iou[h][p[:, 0], p[:, 1]].sum()) for h, p in enumerate(pairs)]),
                        iou)
    gates = options.gates
    live = np.ones(H, bool)
    prev = np.full(H, np.nan)
    resid: list = [None] * H
    noise = [DEFAULT_NOISE] * H
    n_outer = len(gates) + 4 if options.max_outer is None else options.max_outer
    for it in range(n_outer):
        if not live.any():
            break
        gi, gd = gates[min(it, len(gates) - 1)]
        pairs, _ = match_poses(fr, intr, R, t, gi, gd)
        n = np.array([len(p) for p in pairs])
        live &= n >= options.min_pairs
        if not live.any():
            break
        fs = np.array([F_SCALE if np.isnan(prev[h]) or resid[h] is None or not len(resid[h])
                       else max(0.5, 1.5 * float(np.median(np.abs(resid[h])))) for h in range(H)])
        sig = []
        for h in range(H):
            if not live[h]:
                pairs[h] = np.zeros((0, 2), np.int64)
                sig.append(np.zeros(0))
                continue
            if options.adapt_noise and it >= 1:
                noise[h] = estimate_noise([fr], [pairs[h]], intr, R[h], t[h])
            p = pairs[h]
            own = fr.outline_sigma_m[p[:, 1]] if fr.outline_sigma_m is not None else np.zeros(len(p))
            sig.append(edge_sigma(fr.boxes2d[p[:, 0]], fr.corners[p[:, 1]], intr, Pose(R[h], t[h]), noise[h], own,
                                  pair_scores([fr], [p])))
        batch = _Batch(fr, pairs, sig, intr, occlusion)
        R_old, t_old = R.copy(), t.copy()
        R, t, r = _fit(batch, R, t, fs, live, options.max_nfev)
        cost, _ = _robust(r, fs)
        per = cost / np.maximum(n, 1)
        for h in np.flatnonzero(live):
            resid[h] = r[h][batch.mask[h]].ravel()
        moved = (np.linalg.norm(_rotvecs(np.einsum("hij,hkj->hik", R, R_old)), axis=1)
                 + np.linalg.norm(t - t_old, axis=1) / 100.0)
        if it >= len(gates) - 1:
            done = ~np.isnan(prev) & ((np.abs(prev - per) <= options.tol * np.maximum(prev, 1e-9)) | (moved < 2e-6))
            live &= ~done
        prev = np.where(live, per, prev)
    pairs, iou = match_poses(fr, intr, R, t, gates[-1][0], gates[-1][1])
    return PosesFit(R, t, pairs, np.array([float(iou[h][p[:, 0], p[:, 1]].sum()) for h, p in enumerate(pairs)]), iou)


_SKEW_AT, _SKEW_OF = np.array([1, 2, 5, 3, 6, 7]), np.array([2, 1, 0, 2, 1, 0])
_SKEW_SIGN = np.array([-1.0, 1.0, -1.0, 1.0, -1.0, 1.0])


def _exp(w: np.ndarray) -> np.ndarray:
    """Rotation matrices [H,3,3] of rotation vectors w [H,3] (Rodrigues; series below 1e-6 rad)."""
    th2 = np.sum(w * w, axis=1)
    th = np.sqrt(th2)
    small = th2 < 1e-12
    a = np.where(small, 1.0 - th2 / 6.0, np.sin(th) / np.where(small, 1.0, th))
    b = np.where(small, 0.5 - th2 / 24.0, (1.0 - np.cos(th)) / np.where(small, 1.0, th2))
    K = np.zeros((len(w), 9))  # [w]x: (0,1) -w2, (0,2) w1, (1,2) -w0, (1,0) w2, (2,0) -w1, (2,1) w0
    K[:, _SKEW_AT] = w[:, _SKEW_OF] * _SKEW_SIGN
    K = K.reshape(-1, 3, 3)
    return np.eye(3) + a[:, None, None] * K + b[:, None, None] * (K @ K)


def _rotvecs(R: np.ndarray) -> np.ndarray:
    """Rotation vectors [H,3] of rotation matrices [H,3,3] (angle from the trace; small angles exact enough)."""
    c = np.clip((np.trace(R, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
    ang = np.arccos(c)
    v = np.stack([R[:, 2, 1] - R[:, 1, 2], R[:, 0, 2] - R[:, 2, 0], R[:, 1, 0] - R[:, 0, 1]], 1)
    s = np.sin(ang)
    k = np.where(s > 1e-12, ang / (2.0 * np.where(s > 1e-12, s, 1.0)), 0.5)
    return v * k[:, None]
