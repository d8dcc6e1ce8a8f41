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


def _candidate_pairs(fr: CalibFrame, intr: CameraIntrinsics, prior_sim, top_k: int = 3,
                     max_baseline_m: float | None = None):
    """Candidate (2D, 3D) pairs of one frame: rows i, cols j, ray [n,3], depth guess [n] (m),
    depth tolerance [n] (m), weight [n].

    Depth guess: focal * 3D size / 2D size (occlusion and truncation make it an overestimate).
    With ``max_baseline_m`` (camera and LiDAR within that distance of each other, LiDAR-frame
    origin at the sensor), the camera distance of box j is within the baseline of its LiDAR range
    ``|X_j|``: pairs whose size depth disagrees grossly are dropped and the guess is clipped.
    """
    K, M = fr.n2, fr.n3
    c2 = box2d_centers(fr.boxes2d)
    s2 = np.sqrt(np.prod(box2d_sizes(fr.boxes2d), axis=1))
    W, Hh = fr.size
    trunc = ((fr.boxes2d[:, 0] < 2) | (fr.boxes2d[:, 1] < 2) | (fr.boxes2d[:, 2] > W - 2)
             | (fr.boxes2d[:, 3] > Hh - 2))
    b = bearings(intr, c2)
    f = np.sqrt(intr.fx * intr.fy)
    lam0 = f * _size3(fr.boxes3d)[None, :] / s2[:, None]  # [K,M] metres along the ray
    ii, jj = np.meshgrid(np.arange(K), np.arange(M), indexing="ij")
    ii, jj = ii.ravel(), jj.ravel()
    lam = lam0[ii, jj]
    tr = trunc[ii]
    tol = np.where(tr, 0.8, 0.45) * lam + 1.5  # half-width of the depth interval (metres)
    if max_baseline_m is not None:
        rng3 = np.linalg.norm(fr.boxes3d[jj, :3], axis=1)
        B = float(max_baseline_m)
        ok = (rng3 <= 2.0 * lam + B) & ((rng3 >= lam / 2.5 - B) | tr)
        ii, jj, lam, tr, tol, rng3 = ii[ok], jj[ok], lam[ok], tr[ok], tol[ok], rng3[ok]
        lam = np.clip(lam, np.maximum(rng3 - B, 0.5), rng3 + B)
        tol = np.minimum(tol, B + 0.05 * lam + 0.5)
    w = np.zeros(len(ii))
    if prior_sim is not None:
        sim = np.nan_to_num(np.asarray(prior_sim, dtype=np.float64), nan=-np.inf)
        top = np.argsort(-sim, axis=1)[:, : min(top_k, M)]
        allowed = np.zeros((K, M), dtype=bool)
        allowed[np.arange(K)[:, None], top] = True
        allowed &= np.isfinite(sim)
        sel = allowed[ii, jj]
        ii, jj, lam, tol = ii[sel], jj[sel], lam[sel], tol[sel]
        w = sim[ii, jj]
    return ii, jj, b[ii], lam, tol, w


def frame_hypotheses(frs: CalibFrame | list[CalibFrame], intr: CameraIntrinsics, fi: int, *,
                     prior_sims: list | None = None, max_triples: int = 3000,
                     rng: np.random.Generator | None = None, min_altitude_m: float = 0.8,
                     keep: int = 25, max_baseline_m: float | None = None) -> Hypotheses:
    """Pose hypotheses from box triples of one frame (or a group of frames of the same static rig,
    whose pairs are rigidly consistent with each other too), scored on those frames; keep ``keep``."""
    rng = np.random.default_rng(0) if rng is None else rng
    frs = [frs] if isinstance(frs, CalibFrame) else list(frs)
    prior_sims = [None] * len(frs) if prior_sims is None else list(prior_sims)
    parts = [(k,) + _candidate_pairs(fr, intr, ps, max_baseline_m=max_baseline_m)
             for k, (fr, ps) in enumerate(zip(frs, prior_sims)) if fr.n2 and fr.n3]
    if not parts:
        return Hypotheses.empty()
    fk = np.concatenate([np.full(len(p[1]), p[0]) for p in parts])
    ii = np.concatenate([p[1] for p in parts])
    jj = np.concatenate([p[2] for p in parts])
    ray = np.concatenate([p[3] for p in parts])
    lam = np.concatenate([p[4] for p in parts])
    dtol = np.concatenate([p[5] for p in parts])
    pair_w = np.concatenate([p[6] for p in parts])
    X = np.concatenate([frs[p[0]].boxes3d[p[2], :3] for p in parts])  # LiDAR centre of each pair
    if len(ii) < 3:
        return Hypotheses.empty()
    have_prior = any(ps is not None for ps in prior_sims)
    Xc = lam[:, None] * ray
    dc = np.linalg.norm(Xc[:, None] - Xc[None], axis=2)
    dl = np.linalg.norm(X[:, None] - X[None], axis=2)
    tol = np.maximum(dtol[:, None], dtol[None])
    same = fk[:, None] == fk[None]
    C = (np.abs(dc - dl) <= tol) & (~same | ((ii[:, None] != ii[None]) & (jj[:, None] != jj[None])))
    C &= dl > 0.5  # two pairs on (nearly) the same LiDAR point say nothing about rotation
    C = np.triu(C, 1)
    pq = np.argwhere(C)
    if len(pq) == 0:
        return Hypotheses.empty()
    max_pq = max(max_triples // 2, 1)
    if len(pq) > max_pq:  # keep the enumeration bounded on crowded frames
        if have_prior:
            pq = pq[np.argsort(-(pair_w[pq[:, 0]] + pair_w[pq[:, 1]]), kind="stable")[:max_pq]]
        else:
            pq = pq[rng.choice(len(pq), max_pq, replace=False)]
    Cs = C | C.T
    both = Cs[pq[:, 0]] & Cs[pq[:, 1]]
    # up to 2 third members per pair of pairs, drawn at random among the compatible ones
    keys = np.where(both, rng.random(both.shape), -1.0)
    if have_prior:
        keys = np.where(both, keys + pair_w[None, :], -np.inf)
    third = np.argsort(-keys, axis=1)[:, :2]
    okr = np.take_along_axis(both, third, 1)
    tri = np.column_stack([np.repeat(pq, 2, axis=0), third.ravel()])[okr.ravel()]
    if len(tri) == 0:
        return Hypotheses.empty()
    # reject thin 3D triangles (collinear boxes leave the roll about their line free)
    P3 = X[tri]
    e1, e2, e3 = P3[:, 1] - P3[:, 0], P3[:, 2] - P3[:, 0], P3[:, 2] - P3[:, 1]
    area2 = np.linalg.norm(np.cross(e1, e2), axis=1)
    longest = np.maximum(np.maximum(np.linalg.norm(e1, axis=1), np.linalg.norm(e2, axis=1)), np.linalg.norm(e3, axis=1))
    tri = tri[area2 / np.maximum(longest, 1e-9) >= min_altitude_m]
    if len(tri) == 0:
        return Hypotheses.empty()
    B = ray[tri]  # [T,3,3]
    A = X[tri]
    a_idx, b_idx = np.array([0, 0, 1]), np.array([1, 2, 2])
    cosang = np.einsum("tki,tki->tk", B[:, a_idx], B[:, b_idx])
    d2 = np.sum((A[:, a_idx] - A[:, b_idx]) ** 2, axis=2)
    lam_t, rel = _p3p_newton(lam[tri].copy(), cosang, d2)
    good = (rel < 0.05) & np.all(lam_t > 1.0, axis=1)
    if not np.any(good):
        return Hypotheses.empty()
    Bc = lam_t[good, :, None] * B[good]
    R, t = kabsch(A[good], Bc)
    # cheap pre-score (projected 3D centres inside 2D boxes), then IoU on the best few hundred
    pre = sum(_centre_hits(fr, intr, R, t) for fr in frs)
    top = np.argsort(-pre, kind="stable")[: max(8 * keep, 200)]
    R, t = R[top], t[top]
    sc = sum(score_poses(fr, intr, R, t) for fr in frs)
    order = np.argsort(-sc, kind="stable")[:keep]
    return Hypotheses(R[order], t[order], sc[order], np.full(len(order), fi, dtype=np.int64))


def _centre_hits(fr: CalibFrame, intr: CameraIntrinsics, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Per pose [H]: number of 2D boxes containing at least one projected 3D box centre (no distortion)."""
    if fr.n2 == 0 or fr.n3 == 0:
        return np.zeros(len(R))
    Xc = np.einsum("hij,mj->hmi", R, fr.boxes3d[:, :3]) + t[:, None, :]
    z = Xc[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = np.where(z > 0.5, Xc[..., 0] / z * intr.fx + intr.cx, np.nan)
        v = np.where(z > 0.5, Xc[..., 1] / z * intr.fy + intr.cy, np.nan)
    b = fr.boxes2d
    inside = ((u[:, None, :] >= b[None, :, 0, None]) & (u[:, None, :] <= b[None, :, 2, None])
              & (v[:, None, :] >= b[None, :, 1, None]) & (v[:, None, :] <= b[None, :, 3, None]))
    return inside.any(2).sum(1).astype(np.float64)


def score_poses(fr: CalibFrame, intr: CameraIntrinsics, R: np.ndarray, t: np.ndarray, *,
                chunk: int = 2000) -> np.ndarray:
    """Sum over the frame's 2D boxes of the best IoU with any projected 3D box, per pose [H]."""
    out = np.zeros(len(R))
    if fr.n2 == 0 or fr.n3 == 0:
        return out
    for s in range(0, len(R), chunk):
        shape = fr.corners if fr.box_corners is None else fr.box_corners
        rects, _ = project_rects(shape, R[s:s + chunk], t[s:s + chunk], intr, fr.size)
        iou = iou_batched(rects, fr.boxes2d)  # [h,K,M]
        best = iou.max(2)
        # a 2D box explained by a 3D box that another 2D box explains better counts once:
        # approximate one-to-one by also taking the column max.
        col = iou.max(1).sum(1)
        out[s:s + chunk] = np.minimum(best.sum(1), col)
    return out
