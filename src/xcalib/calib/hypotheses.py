"""Correspondence-free pose hypotheses from box triples (vectorised).

For each candidate pair (2D box i, 3D box j) the object's camera-frame position is guessed on
the bearing of the 2D box centre at a depth from size (focal * 3D size / 2D size). Pairs of
pairs must roughly preserve distances (a rigid motion does); triples of mutually consistent
pairs are solved exactly for their depths (P3P by damped Newton from the size prior) and
aligned with Kabsch, giving a pose ``X_cam = R X_lidar + t`` per triple.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry.boxes import box2d_centers, box2d_sizes
from ..geometry.camera import CameraIntrinsics
from ..geometry.projection import undistort_pixels
from .boxproj import iou_batched, project_rects
from .inputs import CalibFrame

__all__ = ["Hypotheses", "kabsch", "bearings", "frame_hypotheses", "score_poses"]


@dataclass
class Hypotheses:
    """Candidate poses R [H,3,3], t [H,3] (LiDAR -> camera) with a score [H] and source frame [H]."""

    R: np.ndarray
    t: np.ndarray
    score: np.ndarray
    frame: np.ndarray

    def __len__(self) -> int:
        return len(self.R)

    @staticmethod
    def empty() -> "Hypotheses":
        return Hypotheses(np.zeros((0, 3, 3)), np.zeros((0, 3)), np.zeros(0), np.zeros(0, dtype=np.int64))

    @staticmethod
    def concat(items: list["Hypotheses"]) -> "Hypotheses":
        items = [h for h in items if len(h)]
        if not items:
            return Hypotheses.empty()
        return Hypotheses(*(np.concatenate([getattr(h, k) for h in items]) for k in ("R", "t", "score", "frame")))

    def take(self, idx) -> "Hypotheses":
        return Hypotheses(self.R[idx], self.t[idx], self.score[idx], self.frame[idx])


def kabsch(A: np.ndarray, B: np.ndarray, w: np.ndarray | None = None):
    """Batched rigid fit B ~ R A + t for point sets A, B [T,N,3] (weights [T,N]) -> R [T,3,3], t [T,3]."""
    if w is None:
        w = np.ones(A.shape[:2])
    w = w / w.sum(1, keepdims=True)
    ca = np.einsum("tn,tni->ti", w, A)
    cb = np.einsum("tn,tni->ti", w, B)
    Hm = np.einsum("tn,tni,tnj->tij", w, A - ca[:, None], B - cb[:, None])
    U, _, Vt = np.linalg.svd(Hm)
    d = np.sign(np.linalg.det(np.einsum("tji,tkj->tik", Vt, U)))
    D = np.zeros_like(Hm)
    D[:, 0, 0] = 1
    D[:, 1, 1] = 1
    D[:, 2, 2] = np.where(d == 0, 1, d)
    R = np.einsum("tji,tjk,tlk->til", Vt, D, U)
    t = cb - np.einsum("tij,tj->ti", R, ca)
    return R, t


def bearings(intr: CameraIntrinsics, uv: np.ndarray) -> np.ndarray:
    """Unit camera-frame rays [N,3] of pixels [N,2] (distortion removed)."""
    uv = undistort_pixels(uv, intr.K, intr.distortion) if intr.distortion is not None else np.asarray(uv, float)
    x = np.stack([(uv[:, 0] - intr.cx) / intr.fx, (uv[:, 1] - intr.cy) / intr.fy, np.ones(len(uv))], 1)
    return x / np.linalg.norm(x, axis=1, keepdims=True)


def _size3(boxes7: np.ndarray) -> np.ndarray:
    """Typical projected extent (metres) of a box: sqrt of ~its mean bounding-rectangle area."""
    l, w, h = boxes7[:, 3], boxes7[:, 4], boxes7[:, 5]
    return np.sqrt(0.75 * (l * w + l * h + w * h))


def _p3p_newton(lam: np.ndarray, cosang: np.ndarray, d2: np.ndarray, iters: int = 12):
    """Solve |l_a b_a - l_b b_b|^2 = d_ab^2 for (ab) in (01, 02, 12); lam [T,3] start depths."""
    a_idx, b_idx = np.array([0, 0, 1]), np.array([1, 2, 2])
    T = len(lam)
    rows = np.arange(3)
    for _ in range(iters):
        la, lb = lam[:, a_idx], lam[:, b_idx]
        f = la * la + lb * lb - 2 * la * lb * cosang - d2
        J = np.zeros((T, 3, 3))
        J[:, rows, a_idx] = 2 * la - 2 * lb * cosang
        J[:, rows, b_idx] = 2 * lb - 2 * la * cosang
        J += np.eye(3)[None] * 1e-6
        try:
            step = np.linalg.solve(J, f[..., None])[..., 0]
        except np.linalg.LinAlgError:
            break
        # damp: never move a depth by more than half its value per step
        scale = np.minimum(1.0, 0.5 * lam.min(1) / np.maximum(np.abs(step).max(1), 1e-12))
        lam = lam - step * scale[:, None]
        lam = np.maximum(lam, 0.05)
    la, lb = lam[:, a_idx], lam[:, b_idx]
    f = la * la + lb * lb - 2 * la * lb * cosang - d2
    rel = np.abs(f) / np.maximum(d2, 1e-6)
    return lam, rel.max(1)


def frame_hypotheses(fr: CalibFrame, intr: CameraIntrinsics, fi: int, *, prior_sim: np.ndarray | None = None,
                     max_triples: int = 3000, rng: np.random.Generator | None = None,
                     min_altitude_m: float = 0.8, keep: int = 25) -> Hypotheses:
    """Pose hypotheses from one frame's box triples, scored on that frame; keep the best ``keep``."""
    rng = np.random.default_rng(0) if rng is None else rng
    K, M = fr.n2, fr.n3
    if K < 3 or M < 3:
        return Hypotheses.empty()
    c2 = box2d_centers(fr.boxes2d)
    s2 = np.sqrt(np.prod(box2d_sizes(fr.boxes2d), axis=1))
    W, Hh = fr.size
    trunc = ((fr.boxes2d[:, 0] < 2) | (fr.boxes2d[:, 1] < 2) | (fr.boxes2d[:, 2] > W - 2)
             | (fr.boxes2d[:, 3] > Hh - 2))
    b = bearings(intr, c2)
    X = fr.boxes3d[:, :3]
    f = np.sqrt(intr.fx * intr.fy)
    lam0 = f * _size3(fr.boxes3d)[None, :] / s2[:, None]  # [K,M]
    ii, jj = np.meshgrid(np.arange(K), np.arange(M), indexing="ij")
    ii, jj = ii.ravel(), jj.ravel()
    if prior_sim is not None:
        sim = np.nan_to_num(np.asarray(prior_sim, dtype=np.float64), nan=-np.inf)
        top = np.argsort(-sim, axis=1)[:, : min(3, M)]
        allowed = np.zeros((K, M), dtype=bool)
        allowed[np.arange(K)[:, None], top] = True
        allowed &= np.isfinite(sim)
        sel = allowed[ii, jj]
        ii, jj = ii[sel], jj[sel]
        pair_w = sim[ii, jj]
    else:
        pair_w = np.zeros(len(ii))
    lam = lam0[ii, jj]
    Xc = lam[:, None] * b[ii]
    tr = trunc[ii]
    dc = np.linalg.norm(Xc[:, None] - Xc[None], axis=2)
    dl = np.linalg.norm(X[jj][:, None] - X[jj][None], axis=2)
    lmax = np.maximum(lam[:, None], lam[None])
    tol = np.where(tr[:, None] | tr[None], 0.8, 0.45) * lmax + 1.5
    C = (np.abs(dc - dl) <= tol) & (ii[:, None] != ii[None]) & (jj[:, None] != jj[None])
    C = np.triu(C, 1)
    pq = np.argwhere(C)
    if len(pq) == 0:
        return Hypotheses.empty()
    both = C[pq[:, 0]] & C[pq[:, 1]]
    rr = np.argwhere(both)
    if len(rr) == 0:
        return Hypotheses.empty()
    tri = np.column_stack([pq[rr[:, 0], 0], pq[rr[:, 0], 1], rr[:, 1]])
    # all three 2D boxes and all three 3D boxes distinct
    ti, tj = ii[tri], jj[tri]
    ok = (ti[:, 0] != ti[:, 2]) & (ti[:, 1] != ti[:, 2]) & (tj[:, 0] != tj[:, 2]) & (tj[:, 1] != tj[:, 2])
    tri = tri[ok]
    # reject thin 3D triangles (collinear boxes leave the roll about their line free)
    P3 = X[jj[tri]]
    e1, e2, e3 = P3[:, 1] - P3[:, 0], P3[:, 2] - P3[:, 0], P3[:, 2] - P3[:, 1]
    area2 = np.linalg.norm(np.cross(e1, e2), axis=1)
    longest = np.maximum(np.maximum(np.linalg.norm(e1, axis=1), np.linalg.norm(e2, axis=1)), np.linalg.norm(e3, axis=1))
    tri = tri[area2 / np.maximum(longest, 1e-9) >= min_altitude_m]
    if len(tri) == 0:
        return Hypotheses.empty()
    if len(tri) > max_triples:
        if prior_sim is not None:
            tri = tri[np.argsort(-pair_w[tri].sum(1), kind="stable")[:max_triples]]
        else:
            tri = tri[rng.choice(len(tri), max_triples, replace=False)]
    B = b[ii[tri]]  # [T,3,3]
    A = X[jj[tri]]
    a_idx, b_idx = np.array([0, 0, 1]), np.array([1, 2, 2])
    cosang = np.einsum("tki,tki->tk", B[:, a_idx], B[:, b_idx])
    d2 = np.sum((A[:, a_idx] - A[:, b_idx]) ** 2, axis=2)
    lam_t, rel = _p3p_newton(lam[tri].copy(), cosang, d2)
    good = (rel < 0.05) & np.all(lam_t > 1.0, axis=1)
    if not np.any(good):
        return Hypotheses.empty()
    Bc = lam_t[good, :, None] * B[good]
    R, t = kabsch(A[good], Bc)
    sc = score_poses(fr, intr, R, t)
    order = np.argsort(-sc)[:keep]
    return Hypotheses(R[order], t[order], sc[order], np.full(len(order), fi, dtype=np.int64))


def score_poses(fr: CalibFrame, intr: CameraIntrinsics, R: np.ndarray, t: np.ndarray, *,
                chunk: int = 2000) -> np.ndarray:
    """Sum over the frame's 2D boxes of the best IoU with any projected 3D box, per pose [H]."""
    out = np.zeros(len(R))
    if fr.n2 == 0 or fr.n3 == 0:
        return out
    for s in range(0, len(R), chunk):
        rects, _ = project_rects(fr.corners, R[s:s + chunk], t[s:s + chunk], intr, fr.size)
        iou = iou_batched(rects, fr.boxes2d)  # [h,K,M]
        best = iou.max(2)
        # a 2D box explained by a 3D box that another 2D box explains better counts once:
        # approximate one-to-one by also taking the column max.
        col = iou.max(1).sum(1)
        out[s:s + chunk] = np.minimum(best.sum(1), col)
    return out
