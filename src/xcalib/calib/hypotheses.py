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
from ..geometry.camera_models import pixels_per_metre as camera_pixels_per_metre
from ..geometry.projection import undistort_pixels
from ..geometry.camera_models.outline import finish_rects
from .boxproj import MIN_DEPTH_M, project_rects
from .inputs import CalibFrame
from .match_sparse import explained_iou

__all__ = ["Hypotheses", "kabsch", "kabsch_triangles", "informative_view", "bearings", "frame_hypotheses", "TripleSearch",
           "score_poses", "TripleDraw", "draw_triples", "solve_triples", "triple_miss_bound"]


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

    n_searches: int = 1  # searches this set came from (more than 1: split by azimuth, see frame_hypotheses)


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


def kabsch_triangles(A: np.ndarray, B: np.ndarray):
    """:func:`kabsch` (unweighted) of triangles A, B [T,3,3] in closed form, no SVD: the centred
    points of a triangle span its plane, so the best rotation maps A's plane normal onto B's, up to
    sign, and turns in the plane by the 2D Procrustes angle; of the two signs the one with the
    larger fit wins (the SVD's determinant correction). The same R, t as :func:`kabsch` up to
    rounding (1e-12) wherever the triangles are not degenerate. Returns R [T,3,3], t [T,3]."""
    ca, EA = _plane_frames(A)
    cb, EB = _plane_frames(B)
    a, b = A - ca[:, None], B - cb[:, None]
    pa = a @ EA.transpose(0, 2, 1)  # [T,3 points, (x, y, ~0)]
    pb = b @ EB.transpose(0, 2, 1)
    xa, ya, xb, yb = pa[..., 0], pa[..., 1], pb[..., 0], pb[..., 1]
    xx, yy, xy, yx = xa * xb, ya * yb, xa * yb, ya * xb  # each product once ((-x) y = -(x y) exactly)

    def sum3(q):  # np.sum(q, 1) of [T,3], in its order
        return q[:, 0] + q[:, 1] + q[:, 2]

    c1, s1 = sum3(xx + yy), sum3(xy - yx)  # normal onto normal
    c2, s2 = sum3(xx - yy), sum3(np.negative(xy) - yx)  # onto minus normal (y flipped)
    flip = np.hypot(c2, s2) > np.hypot(c1, s1)
    c, s = np.where(flip, c2, c1), np.where(flip, s2, s1)
    h = np.maximum(np.hypot(c, s), 1e-300)
    c, s = c / h, s / h
    EB[flip, 1:] *= -1.0  # the flipped frames' second and third rows negated
    Rz = np.zeros((len(A), 3, 3))
    Rz[:, 0, 0], Rz[:, 0, 1], Rz[:, 1, 0], Rz[:, 1, 1], Rz[:, 2, 2] = c, -s, s, c, 1.0
    R = EB.transpose(0, 2, 1) @ Rz @ EA
    return R, cb - (R @ ca[..., None])[..., 0]


def _cross_cols(a0, a1, a2, b0, b1, b2):
    """``np.cross`` of [T] columns of 3-vectors: its products and differences, in its order."""
    return a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0


def _norm_cols(x0, x1, x2):
    """``np.linalg.norm(x, axis=1)`` for [T] columns: its sum of squares in its order ((x0^2 + x1^2) + x2^2)."""
    return np.sqrt(x0 * x0 + x1 * x1 + x2 * x2)


def _unit_cols(x0, x1, x2):
    """x / max(``np.linalg.norm(x, axis=1)``, 1e-300) for [T] columns."""
    n = _norm_cols(x0, x1, x2)
    np.maximum(n, 1e-300, out=n)
    return x0 / n, x1 / n, x2 / n


def _plane_frames(P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Centroids [T,3] and orthonormal frames [T,3,3] (rows e1, n x e1, n) of triangles P [T,3,3],
    e1 along the first edge, n the plane normal; computed on [T] columns with the operations of
    ``P.mean(1)``, ``np.cross`` and ``np.linalg.norm`` in their order (the same values to the bit,
    without the reductions over short axes and the stacking)."""
    p0, p1, p2 = P[:, 0], P[:, 1], P[:, 2]
    c = p0 + p1
    c += p2
    c /= 3.0
    e, f = p1 - p0, p2 - p0
    e0, e1, e2 = e[:, 0], e[:, 1], e[:, 2]
    n0, n1, n2 = _unit_cols(*_cross_cols(e0, e1, e2, f[:, 0], f[:, 1], f[:, 2]))
    e0, e1, e2 = _unit_cols(e0, e1, e2)
    E = np.empty((len(P), 3, 3))
    E[:, 0, 0], E[:, 0, 1], E[:, 0, 2] = e0, e1, e2
    E[:, 1, 0], E[:, 1, 1], E[:, 1, 2] = _cross_cols(n0, n1, n2, e0, e1, e2)
    E[:, 2, 0], E[:, 2, 1], E[:, 2, 2] = n0, n1, n2
    return c, E


def bearings(intr: CameraIntrinsics, uv: np.ndarray) -> np.ndarray:
    """Unit camera-frame rays [N,3] of pixels [N,2] (distortion removed)."""
    if not isinstance(intr, CameraIntrinsics):  # camera-model dispatch: the model's own rays
        rays, ok = intr.unproject(uv)
        return np.where(ok[:, None], rays, np.array([0.0, 0.0, 1.0]))
    uv = undistort_pixels(uv, intr.K, intr.distortion) if intr.distortion is not None else np.asarray(uv, float)
    x = np.stack([(uv[:, 0] - intr.cx) / intr.fx, (uv[:, 1] - intr.cy) / intr.fy, np.ones(len(uv))], 1)
    return x / np.linalg.norm(x, axis=1, keepdims=True)


def _size3(boxes7: np.ndarray) -> np.ndarray:
    """Typical projected extent (metres) of a box: sqrt of ~its mean bounding-rectangle area."""
    l, w, h = boxes7[:, 3], boxes7[:, 4], boxes7[:, 5]
    return np.sqrt(0.75 * (l * w + l * h + w * h))


def _p3p_newton(lam: np.ndarray, cosang: np.ndarray, d2: np.ndarray, iters: int = 12):
    """Solve |l_a b_a - l_b b_b|^2 = d_ab^2 for (ab) in (01, 02, 12); lam [T,3] start depths.

    Damped Newton on the three depths. Each equation involves two depths, so the 3x3 Jacobian has
    one zero per row ([[P0, Q0, 0], [P1, 0, Q1], [0, P2, Q2]] plus 1e-6 on the diagonal): it is
    solved by the adjugate written out for that pattern, one [T] column at a time: the terms of the
    general 3x3 adjugate that have a zero factor are dropped, which changes no bit of the result,
    and the [T,3,3] arrays and their fancy indexing are gone (4x less time on A9's triples).

    Each product that the residuals and the Jacobian share (l_a^2, 2 l_a) is formed once, and a
    negated factor is a subtraction (-(x) * y = -(x * y) and a + (-b) = a - b hold exactly in IEEE
    arithmetic), every operation writes into a buffer of the loop: the same values to the bit as
    every term written out."""
    L = np.array(np.asarray(lam).T, dtype=np.float64)  # [3,T]: the depths l0, l1, l2 as rows
    l0, l1, l2 = L
    c0, c1, c2 = np.ascontiguousarray(np.asarray(cosang, dtype=np.float64).T)  # contiguous columns
    d0, d1, d2_ = np.ascontiguousarray(np.asarray(d2, dtype=np.float64).T)
    n = L.shape[1]
    Q, W, F, S = (np.empty((3, n)) for _ in range(4))  # l^2, 2 l, residuals, steps (rows per depth / side)
    (q0, q1, q2), (w0, w1, w2), (f0, f1, f2), (s0, s1, s2) = Q, W, F, S
    P0, Q0, P1, Q1, P2, Q2, A00, A22, k00, P1A22, k02, det, t1, t2, big, scale = np.empty((16, n))
    for _ in range(iters):  # every operation in place, each a term of the written-out formulas, in their order
        np.multiply(L, L, out=Q)
        np.multiply(2, L, out=W)
        for f, qa, qb, wa, lb, c, d in ((f0, q0, q1, w0, l1, c0, d0), (f1, q0, q2, w0, l2, c1, d1),
                                        (f2, q1, q2, w1, l2, c2, d2_)):
            np.add(qa, qb, out=f)  # f = la^2 + lb^2 - 2 la lb c - d
            np.multiply(wa, lb, out=t1)
            t1 *= c
            f -= t1
            f -= d
        for out, wa, wb, c in ((P0, w0, w1, c0), (Q0, w1, w0, c0), (P1, w0, w2, c1), (Q1, w2, w0, c1),
                               (P2, w1, w2, c2), (Q2, w2, w1, c2)):
            np.multiply(wb, c, out=out)  # 2 la - 2 lb c
            np.subtract(wa, out, out=out)
        np.add(P0, 1e-6, out=A00)
        np.add(Q2, 1e-6, out=A22)
        np.multiply(1e-6, A22, out=k00)  # k00 = 1e-6 A22 - Q1 P2
        k00 -= np.multiply(Q1, P2, out=t1)
        np.multiply(P1, A22, out=P1A22)  # the adjugate's k01 = -(P1 A22)
        np.multiply(P1, P2, out=k02)
        np.multiply(A00, k00, out=det)  # det = A00 k00 + Q0 k01
        det -= np.multiply(Q0, P1A22, out=t1)
        if not np.all(np.isfinite(det)) or np.any(det == 0):  # a singular system (np.linalg.solve would raise)
            break
        np.multiply(k00, f0, out=s0)  # s0 = k00 f0 - (Q0 A22) f1 + (Q0 Q1) f2
        s0 -= np.multiply(np.multiply(Q0, A22, out=t1), f1, out=t1)
        s0 += np.multiply(np.multiply(Q0, Q1, out=t1), f2, out=t1)
        np.multiply(np.multiply(A00, A22, out=s1), f1, out=s1)  # s1 = (A00 A22) f1 - P1A22 f0 - (A00 Q1) f2
        s1 -= np.multiply(P1A22, f0, out=t1)
        s1 -= np.multiply(np.multiply(A00, Q1, out=t1), f2, out=t1)
        np.multiply(k02, f0, out=s2)  # s2 = k02 f0 - (A00 P2) f1 + (A00 1e-6 - Q0 P1) f2
        s2 -= np.multiply(np.multiply(A00, P2, out=t1), f1, out=t1)
        np.multiply(A00, 1e-6, out=t1)
        t1 -= np.multiply(Q0, P1, out=t2)
        s2 += np.multiply(t1, f2, out=t1)
        S /= det
        # damp: never move a depth by more than half its value per step
        np.maximum(np.maximum(np.abs(s0, out=big), np.abs(s1, out=t1), out=big), np.abs(s2, out=t1), out=big)
        np.minimum(np.minimum(l0, l1, out=scale), l2, out=scale)
        scale *= 0.5
        scale /= np.maximum(big, 1e-12, out=big)
        np.minimum(1.0, scale, out=scale)
        S *= scale
        L -= S
        np.maximum(L, 0.05, out=L)
    lam = np.ascontiguousarray(L.T)
    la, lb = lam[:, [0, 0, 1]], lam[:, [1, 2, 2]]
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
    if not isinstance(intr, CameraIntrinsics):  # camera-model dispatch: the scale along each ray
        f = np.nan_to_num(camera_pixels_per_metre(intr, b), nan=f)[:, None]
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


def _pair_distances(P: np.ndarray) -> np.ndarray:
    """Euclidean distances [n,n] between rows of P [n,3] (Gram form: never an [n,n,3] array)."""
    sq = np.einsum("ij,ij->i", P, P)
    gram = P @ P.T
    gram *= 2.0
    d2 = np.add(sq[:, None], sq[None, :])
    d2 -= gram  # in place: two [n,n] buffers instead of five, the same values
    np.maximum(d2, 0.0, out=d2)
    return np.sqrt(d2, out=d2)


def _azimuth_windows(X: np.ndarray, cap: int, rng: np.random.Generator, weight: np.ndarray | None,
                     width_deg: float = 120.0, step_deg: float = 60.0) -> list[np.ndarray]:
    """Candidate subsets of at most ``cap`` rows for crowded searches.

    A camera sees a sector of a 360-degree LiDAR's surroundings, so the candidate pairs are split
    by the LiDAR-frame azimuth of their 3D box into overlapping windows (``width_deg`` wide every
    ``step_deg``); a window still above ``cap`` keeps its ``cap`` best-weighted (matcher prior)
    or randomly drawn candidates. Returns index arrays into the candidates."""
    if len(X) <= cap:
        return [np.arange(len(X))]
    az = np.degrees(np.arctan2(X[:, 1], X[:, 0]))
    out = []
    for c in np.arange(0.0, 360.0, step_deg):
        idx = np.flatnonzero(np.abs((az - c + 180.0) % 360.0 - 180.0) <= width_deg / 2)
        if len(idx) > cap:
            idx = idx[np.argsort(-weight[idx], kind="stable")[:cap]] if weight is not None \
                else rng.choice(idx, cap, replace=False)
        if len(idx) >= 3:
            out.append(np.sort(idx))
    return out


@dataclass(frozen=True)
class TripleSearch:
    """Settings of :func:`frame_hypotheses`: at most ``max_triples`` box triples per window, triangles
    with an altitude of at least ``min_altitude_m`` (m), the ``keep`` best hypotheses kept, a camera
    within ``max_baseline_m`` of the LiDAR (None: anywhere), at most ``max_candidates`` candidate
    pairs per azimuth window; ``closed_form``: each triple's Kabsch fit by :func:`kabsch_triangles`
    (no SVD; the same poses up to rounding) rather than :func:`kabsch`; ``miss_stats``: also count
    each consistent pair's common partners (``TripleDraw.pair_stats``, for :func:`triple_miss_bound`;
    the same draws)."""

    max_triples: int = 3000
    min_altitude_m: float = 0.8
    keep: int = 25
    max_baseline_m: float | None = None
    max_candidates: int = 1500
    closed_form: bool = False
    miss_stats: bool = False


@dataclass
class TripleDraw:
    """The random part of one search (:func:`draw_triples`): its candidate pairs ``cand`` (None:
    none), per azimuth window the candidate rows and the drawn triples [T,3] of rows of the window
    (None: none that are consistent and well shaped), and whether matcher priors ranked them. What
    remains (:func:`solve_triples`: P3P, Kabsch, scoring) draws no random numbers, so searches drawn
    one after another from one generator can be solved in any order, or in parallel, with the same
    result."""

    cand: "_Candidates | None"
    windows: list
    have_prior: bool = False
    #: per window, (consistent pairs of pairs, how many of them were drawn, the most consistent
    #: partners of one pair) or None (no consistent pair): what :func:`triple_miss_bound` needs
    pair_stats: list | None = None

    @property
    def n_windows(self) -> int:
        return len(self.windows)


def draw_triples(frs: CalibFrame | list[CalibFrame], intr: CameraIntrinsics, *, prior_sims: list | None = None,
                 rng: np.random.Generator | None = None, search: TripleSearch = TripleSearch()) -> TripleDraw:
    """The candidate pairs of ``frs`` and the box triples of :func:`frame_hypotheses`, drawn from
    ``rng`` exactly as it draws them (the same numbers in the same order)."""
    rng = np.random.default_rng(0) if rng is None else rng
    frs = [frs] if isinstance(frs, CalibFrame) else list(frs)
    prior_sims = [None] * len(frs) if prior_sims is None else list(prior_sims)
    parts = [(k,) + _candidate_pairs(fr, intr, ps, max_baseline_m=search.max_baseline_m)
             for k, (fr, ps) in enumerate(zip(frs, prior_sims)) if fr.n2 and fr.n3]
    if not parts:
        return TripleDraw(None, [])
    cand = _Candidates(
        fk=np.concatenate([np.full(len(p[1]), p[0]) for p in parts]),
        ii=np.concatenate([p[1] for p in parts]), jj=np.concatenate([p[2] for p in parts]),
        ray=np.concatenate([p[3] for p in parts]), lam=np.concatenate([p[4] for p in parts]),
        dtol=np.concatenate([p[5] for p in parts]), w=np.concatenate([p[6] for p in parts]),
        X=np.concatenate([frs[p[0]].boxes3d[p[2], :3] for p in parts]))  # LiDAR centre of each pair
    have_prior = any(ps is not None for ps in prior_sims)
    windows = _azimuth_windows(cand.X, search.max_candidates, rng, cand.w if have_prior else None)
    drawn, stats = [], []
    for idx in windows:
        tri, st = _triples(cand.take(idx), rng, search.max_triples, search.min_altitude_m, have_prior,
                           search.miss_stats)
        drawn.append((idx, tri))
        stats.append(st)
    return TripleDraw(cand, drawn, have_prior, stats)


def triple_miss_bound(support: int, stats: tuple | None) -> float:
    """An upper bound on the probability that a drawn search (one azimuth window, no matcher
    priors; ``stats``: its ``TripleDraw.pair_stats`` entry) holds no triple of three pairs of one
    pose that ``support`` = k of its candidate pairs agree with (its inliers). 1.0 where the
    numbers allow no bound.

    Model: the inliers are candidate pairs, mutually consistent (the premise of the search itself).
    The search draws n_drawn of its n_pairs consistent pairs of pairs uniformly, then two third
    members of a drawn pair uniformly among the T pairs consistent with both. An inlier pair of
    pairs has k-2 inlier partners among its T, so its two thirds miss them all with probability
    miss(T) = C(T-k+2,2)/C(T,2), which grows with T: with the C(k,2) inlier pairs of pairs taken as
    those with the largest T (the worst case), one draw finds an inlier triple with probability
    p >= sum(1 - miss(T_i)) / n_pairs, and n_drawn draws (without replacement: no more often
    missed than with) miss with probability <= (1 - p)^n_drawn; with every pair of pairs drawn,
    <= prod(miss(T_i))."""
    k = int(support)
    if stats is None or len(stats) < 3 or stats[2] is None or k < 3:
        return 1.0
    n_pairs, n_drawn, common = int(stats[0]), int(stats[1]), np.asarray(stats[2], dtype=np.float64)
    inl = k * (k - 1) // 2
    if n_pairs <= 0 or n_drawn <= 0 or inl > n_pairs or len(common) < min(inl, n_pairs):
        return 1.0
    T = common[:inl]  # the largest counts first
    with np.errstate(divide="ignore", invalid="ignore"):
        miss = np.where(T >= k, (T - k + 2) * (T - k + 1) / (T * (T - 1)), 0.0)
    if n_drawn >= n_pairs:
        return float(np.prod(miss))
    return float((1.0 - np.sum(1.0 - miss) / n_pairs) ** n_drawn)


#: ``TripleSearch.miss_stats``: windows of at most this many candidates count their pairs' common
#: partners (one [n,n] matrix product), and the largest this many counts are kept
MISS_STATS_MAX_CANDIDATES = 800
MISS_STATS_KEEP = 2000


def solve_triples(frs: CalibFrame | list[CalibFrame], intr: CameraIntrinsics, fi: int, draw: TripleDraw,
                  search: TripleSearch = TripleSearch()) -> Hypotheses:
    """The poses of a drawn search's triples (P3P, Kabsch), pre-scored per window, then IoU-scored
    on ``frs``; the ``search.keep`` best, from frame ``fi``. No random numbers."""
    frs = [frs] if isinstance(frs, CalibFrame) else list(frs)
    keep, cand, windows = search.keep, draw.cand, draw.windows
    if cand is None:
        return Hypotheses.empty()
    Rs, ts = [], []
    for idx, tri in windows:
        f = None if tri is None else _triple_solve(cand.take(idx), tri, search.closed_form)
        if f is None:
            continue
        # cheap pre-score (projected 3D centres inside 2D boxes; split searches: only the 3D boxes
        # of the window, as a camera looking there sees no others), then IoU on the best few hundred
        sub = frs if len(windows) == 1 else [_only_3d(fr, np.unique(cand.jj[idx][cand.fk[idx] == k]))
                                             for k, fr in enumerate(frs)]
        pre = sum(_centre_hits(fr, intr, f[0], f[1]) for fr in sub)
        top = np.argsort(-pre, kind="stable")[: max(8 * keep, 200)]
        Rs.append(f[0][top])
        ts.append(f[1][top])
    if not Rs:
        return Hypotheses.empty()
    R, t = np.concatenate(Rs), np.concatenate(ts)
    sc = sum(score_poses(fr, intr, R, t) for fr in frs)
    order = np.argsort(-sc, kind="stable")[:keep]
    out = Hypotheses(R[order], t[order], sc[order], np.full(len(order), fi, dtype=np.int64))
    out.n_searches = len(windows)
    return out


def frame_hypotheses(frs: CalibFrame | list[CalibFrame], intr: CameraIntrinsics, fi: int, *,
                     prior_sims: list | None = None, rng: np.random.Generator | None = None,
                     search: TripleSearch = TripleSearch()) -> Hypotheses:
    """Pose hypotheses from box triples of one frame (or a group of frames of the same static rig,
    whose pairs are rigidly consistent with each other too), scored on those frames; keep ``keep``.

    The search is quadratic in the candidate pairs; beyond ``max_candidates`` of them it runs on
    azimuth windows of at most that many (see ``_azimuth_windows``), so memory stays bounded.
    (``search``: these settings, :class:`TripleSearch`.) It is :func:`draw_triples` (every random
    number) followed by :func:`solve_triples`."""
    frs = [frs] if isinstance(frs, CalibFrame) else list(frs)
    return solve_triples(frs, intr, fi, draw_triples(frs, intr, prior_sims=prior_sims, rng=rng, search=search), search)


def informative_view(fr: CalibFrame, max_2d: int) -> tuple[CalibFrame, np.ndarray]:
    """The search's gate on a crowded frame: a view of ``fr`` with only ``max_2d`` of its 2D boxes,
    the most informative: the largest (px area: near objects, whose size tells their depth best)
    of those well separated -- inside the image (not truncated) and covered by no other 2D box for
    more than a quarter of their area (not occluded, not occluding: their box is the object's
    whole outline) -- then, if too few are, the largest others; and the rows kept (ascending).
    Every 3D box stays (a 360-degree LiDAR's boxes around the camera's view are sorted out by the
    depth test of the candidate pairs and the azimuth windows). A frame within the count is
    returned as it is. The pose is scored and refined on all boxes later; the search's cost then
    grows only with the 3D boxes, linearly."""
    rows = np.arange(fr.n2)
    if fr.n2 <= max_2d:
        return fr, rows
    from dataclasses import replace

    b = fr.boxes2d
    area = (b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1])
    W, H = fr.size
    inside = (b[:, 0] > 2) & (b[:, 1] > 2) & (b[:, 2] < W - 2) & (b[:, 3] < H - 2)
    covered = np.zeros(len(b))
    for s in range(0, len(b), 256):  # [s:s+256, all] overlaps: memory linear in the boxes
        blk = b[s:s + 256]
        w = np.clip(np.minimum(blk[:, None, 2], b[None, :, 2]) - np.maximum(blk[:, None, 0], b[None, :, 0]), 0, None)
        h = np.clip(np.minimum(blk[:, None, 3], b[None, :, 3]) - np.maximum(blk[:, None, 1], b[None, :, 1]), 0, None)
        ov = w * h
        ov[np.arange(len(blk)), np.arange(s, s + len(blk))] = 0.0
        covered[s:s + len(blk)] = ov.max(1) / np.maximum(area[s:s + len(blk)], 1e-9)
    separated = inside & (covered <= 0.25)
    order = np.lexsort((-area, ~separated))  # separated first, each group largest first
    rows = np.sort(order[:max_2d])
    return replace(fr, boxes2d=fr.boxes2d[rows], idx2d=fr.idx2d[rows]), rows


def _only_3d(fr: CalibFrame, cols: np.ndarray) -> CalibFrame:
    """A view of ``fr`` with only the 3D boxes ``cols`` (for pre-scoring a window's poses)."""
    from dataclasses import replace

    return replace(fr, boxes3d=fr.boxes3d[cols], corners=fr.corners[cols], idx3d=fr.idx3d[cols],
                   box_corners=None if fr.box_corners is None else fr.box_corners[cols])


@dataclass
class _Candidates:
    """Candidate (2D, 3D) pairs of a search: frame, rows, cols, ray, depth guess (m), depth
    tolerance (m), prior weight and the 3D box centre (LiDAR frame, m)."""

    fk: np.ndarray
    ii: np.ndarray
    jj: np.ndarray
    ray: np.ndarray
    lam: np.ndarray
    dtol: np.ndarray
    w: np.ndarray
    X: np.ndarray

    def take(self, idx) -> "_Candidates":
        return _Candidates(*(getattr(self, k)[idx] for k in ("fk", "ii", "jj", "ray", "lam", "dtol", "w", "X")))


def _third_members(Cs: np.ndarray, pq: np.ndarray, rng: np.random.Generator, pair_w: np.ndarray | None,
                   block: int = 1024) -> np.ndarray:
    """Up to 2 third members per pair of pairs, drawn at random among the compatible ones
    (higher prior weight first); rows in blocks. Returns triples [T,3].

    Without priors the keys of the incompatible members are their random numbers less one
    (``keys -= apart``), not -1.0 as with ``np.where``: every compatible key keeps its value
    (x - 0.0 == x) and every incompatible one lies below all of them (in [-1, 0)), so the arg-max
    picks the same compatible members; a pick among the incompatible ones (a row with fewer than
    two compatible members) is dropped either way (``okr``). The same triples, without the
    [rows, candidates] ``np.where`` copy (the second-pose search over every A9 frame: 10,000 rows
    of 506 candidates)."""
    out = []
    apart_of = ~Cs if pair_w is None else None
    for s in range(0, len(pq), block):
        p = pq[s:s + block]
        if apart_of is None:
            both = Cs[p[:, 0]] & Cs[p[:, 1]]
            keys = np.where(both, rng.random(both.shape), -1.0)
            keys = np.where(both, keys + pair_w[None, :], -np.inf)
        else:
            apart = apart_of[p[:, 0]] | apart_of[p[:, 1]]  # not compatible with both (``~both``)
            keys = rng.random(apart.shape)  # (the same numbers: same shape, same order)
            keys -= apart
        k = min(2, keys.shape[1])
        third = _top2(keys) if k == 2 else keys.argmax(1)[:, None]  # the best key first
        okr = np.take_along_axis(both, third, 1) if apart_of is None else ~np.take_along_axis(apart, third, 1)
        if k == 2:  # (a row whose keys are all -inf but one: no second member)
            okr[:, 1] &= third[:, 1] != third[:, 0]
        out.append(np.column_stack([np.repeat(p, k, axis=0), third.ravel()])[okr.ravel()])
    return np.concatenate(out) if out else np.zeros((0, 3), dtype=np.int64)


def _top2(keys: np.ndarray) -> np.ndarray:
    """Columns [n,2] of the largest and the second largest key of each row (``keys`` [n,>=2] is
    overwritten). Two arg-max passes instead of a partition and a sort of the two: the same columns
    wherever the two keys differ from the rest (ties only among incompatible members, which are
    dropped). A row whose other keys are all -inf gives its largest twice."""
    rows = np.arange(len(keys))
    first = keys.argmax(1)
    keys[rows, first] = -np.inf
    return np.column_stack([first, keys.argmax(1)])


def _triples(c: _Candidates, rng: np.random.Generator, max_triples: int, min_altitude_m: float,
             have_prior: bool, miss_stats: bool = False) -> tuple[np.ndarray | None, tuple | None]:
    """The consistent, well-shaped triples [T,3] of candidates c (rows), or None; every random
    number of a window's search is drawn here. Also (consistent pairs of pairs, pairs drawn, with
    ``miss_stats`` the largest ``MISS_STATS_KEEP`` counts of partners consistent with both pairs of
    a consistent pair, descending, else None), or None without a consistent pair
    (``TripleDraw.pair_stats``)."""
    if len(c.ii) < 3:
        return None, None
    X, ray, lam = c.X, c.ray, c.lam
    Xc = lam[:, None] * ray
    dc = _pair_distances(Xc)
    dl = _pair_distances(X)
    dc -= dl
    np.abs(dc, out=dc)  # |dc - dl|, in place
    C = dc <= np.maximum(c.dtol[:, None], c.dtol[None])
    del dc
    if len(np.unique(c.fk)) > 1:
        same = c.fk[:, None] == c.fk[None]
        C &= ~same | ((c.ii[:, None] != c.ii[None]) & (c.jj[:, None] != c.jj[None]))
        del same
    else:  # one frame: two pairs must differ in both boxes
        C &= c.ii[:, None] != c.ii[None]
        C &= c.jj[:, None] != c.jj[None]
    C &= dl > 0.5  # two pairs on (nearly) the same LiDAR point say nothing about rotation
    del dl
    C = np.triu(C, 1)
    pq = np.argwhere(C)
    if len(pq) == 0:
        return None, None
    n_pairs = len(pq)
    max_pq = max(max_triples // 2, 1)
    if len(pq) > max_pq:  # keep the enumeration bounded on crowded frames
        if have_prior:
            pq = pq[np.argsort(-(c.w[pq[:, 0]] + c.w[pq[:, 1]]), kind="stable")[:max_pq]]
        else:
            pq = pq[rng.choice(len(pq), max_pq, replace=False)]
    Cs = C | C.T
    common = None
    if miss_stats and len(Cs) <= MISS_STATS_MAX_CANDIDATES:
        F = Cs.astype(np.float32)  # (integer counts below 2^24: exact in float32)
        common = -np.sort(-(F @ F)[C].astype(np.float64))[:MISS_STATS_KEEP]
    stats = (n_pairs, len(pq), common)
    tri = _third_members(Cs, pq, rng, c.w if have_prior else None)
    if len(tri) == 0:
        return None, stats
    # reject thin 3D triangles (collinear boxes leave the roll about their line free)
    # (on [T] columns: ``np.cross`` and ``np.linalg.norm``'s operations in their order, the same values)
    Xc = [np.ascontiguousarray(X[:, j]) for j in range(3)]
    P0, P1, P2 = ([x[tri[:, k]] for x in Xc] for k in range(3))
    e1, e2, e3 = ([b - a for a, b in zip(Pa, Pb)] for Pa, Pb in ((P0, P1), (P0, P2), (P1, P2)))
    area2 = _norm_cols(*_cross_cols(*e1, *e2))
    longest = np.maximum(np.maximum(_norm_cols(*e1), _norm_cols(*e2)), _norm_cols(*e3))
    tri = tri[area2 / np.maximum(longest, 1e-9) >= min_altitude_m]
    return (tri if len(tri) else None), stats


def _triple_solve(c: _Candidates, tri: np.ndarray, closed_form: bool = False):
    """Poses (R [T,3,3], t [T,3]) of the triples ``tri`` [T,3] of candidates c (P3P, then Kabsch),
    or None when none solves."""
    X, ray, lam = c.X, c.ray, c.lam
    B = ray[tri]  # [T,3,3]
    A = X[tri]
    # per side (01, 02, 12): the cosine of the rays' angle and the squared LiDAR distance, on the
    # [T,3] views of each member (the sums of einsum / np.sum over the last axis of 3, without the
    # gathered [T,3,3] copies of ``B[:, [0, 0, 1]]``)
    cosang, d2 = np.empty((len(tri), 3)), np.empty((len(tri), 3))
    for k, (a, b) in enumerate(((0, 1), (0, 2), (1, 2))):
        cosang[:, k] = np.einsum("ti,ti->t", B[:, a], B[:, b])
        d2[:, k] = np.sum((A[:, a] - A[:, b]) ** 2, axis=1)
    lam_t, rel = _p3p_newton(lam[tri], cosang, d2)
    good = (rel < 0.05) & np.all(lam_t > 1.0, axis=1)
    if not np.any(good):
        return None
    return (kabsch_triangles if closed_form else kabsch)(A[good], lam_t[good, :, None] * B[good])


def _centre_hits(fr: CalibFrame, intr: CameraIntrinsics, R: np.ndarray, t: np.ndarray, *,
                 max_elems: int = 4_000_000) -> np.ndarray:
    """Per pose [H]: number of 2D boxes containing at least one projected 3D box centre (no distortion)."""
    if fr.n2 == 0 or fr.n3 == 0:
        return np.zeros(len(R))
    chunk = max(1, max_elems // (fr.n2 * fr.n3))
    if len(R) > chunk:
        return np.concatenate([_centre_hits(fr, intr, R[s:s + chunk], t[s:s + chunk], max_elems=max_elems)
                               for s in range(0, len(R), chunk)])
    H, M = len(R), fr.n3
    if not isinstance(intr, CameraIntrinsics):  # camera-model dispatch
        Xc = np.matmul(fr.boxes3d[:, :3], np.transpose(R, (0, 2, 1)))  # [H,M,3] (BLAS, not einsum)
        Xc += t[:, None, :]
        uv, ok = intr.project(Xc.reshape(-1, 3))
        ok &= np.linalg.norm(Xc.reshape(-1, 3), axis=1) > 0.5
        u = np.where(ok, uv[:, 0], np.nan).reshape(H, M)
        v = np.where(ok, uv[:, 1], np.nan).reshape(H, M)
    else:
        # camera-frame coordinates as [M,3,H] planes (pose last): one matrix product for all poses,
        # the translation added along H, and every mask below along H too, its any() over the
        # M rows (the same products, sums and comparisons as [H,M,3] rows, whose stacked product,
        # broadcast add over a last axis of 3 and any() over a short last axis cost 2-3x more)
        Xc = (fr.boxes3d[:, :3] @ R.transpose(2, 1, 0).reshape(3, 3 * H)).reshape(M, 3, H)
        Xc += t.T[None]
        x, y, z = Xc[:, 0], Xc[:, 1], Xc[:, 2]
        behind = z <= 0.5
        # u = x / z * fx + cx (u NaN behind the camera), the same operations in place on x and y
        with np.errstate(divide="ignore", invalid="ignore"):
            u = np.divide(x, z, out=x)
            v = np.divide(y, z, out=y)
        u *= intr.fx
        u += intr.cx
        v *= intr.fy
        v += intr.cy
        # behind the camera u is NaN, which fails both of its comparisons below: a box can then
        # not hold the centre whatever v is, so v keeps its value there (the same hits, one pass less)
        np.copyto(u, np.nan, where=behind)
        hits = np.zeros(H, dtype=np.int64)
        inside, tmp = np.empty(u.shape, dtype=bool), np.empty(u.shape, dtype=bool)
        for x0, y0, x1, y1 in np.asarray(fr.boxes2d, dtype=np.float64).tolist():
            np.greater_equal(u, x0, out=inside)  # (u >= x0) & (u <= x1) & (v >= y0) & (v <= y1), in place
            inside &= np.less_equal(u, x1, out=tmp)
            inside &= np.greater_equal(v, y0, out=tmp)
            inside &= np.less_equal(v, y1, out=tmp)
            hits += inside.any(0)
        return hits.astype(np.float64)
    hits = np.zeros(len(R), dtype=np.int64)
    for x0, y0, x1, y1 in np.asarray(fr.boxes2d, dtype=np.float64).tolist():  # box by box: [H,M] masks stay in cache
        hits += ((u >= x0) & (u <= x1) & (v >= y0) & (v <= y1)).any(1)
    return hits.astype(np.float64)


def score_poses(fr: CalibFrame, intr: CameraIntrinsics, R: np.ndarray, t: np.ndarray, *,
                chunk: int = 2000, max_elems: int = 3_000_000) -> np.ndarray:
    """Sum over the frame's 2D boxes of the best IoU with any projected 3D box, per pose [H]
    (poses in chunks of at most ``max_elems`` IoU entries)."""
    out = np.zeros(len(R))
    if fr.n2 == 0 or fr.n3 == 0:
        return out
    chunk = int(max(1, min(chunk, max_elems // (fr.n2 * fr.n3))))
    shape = np.asarray(fr.corners if fr.box_corners is None else fr.box_corners, dtype=np.float64)
    plain = type(intr) is CameraIntrinsics and intr.distortion is None
    by_corner = np.ascontiguousarray(shape.transpose(1, 0, 2)).reshape(-1, 3) if plain else None
    for s in range(0, len(R), chunk):
        if plain:
            rects = _pinhole_rects(by_corner, len(shape), R[s:s + chunk], t[s:s + chunk], intr, fr.size)
        else:
            rects, _ = project_rects(shape, R[s:s + chunk], t[s:s + chunk], intr, fr.size)
        # the maxima of the [h,K,M] IoU over its 3D and its 2D boxes, computed on the overlapping
        # pairs only (the others are 0): the same values as from ``iou_batched``'s full array
        best, col = explained_iou(rects, fr.boxes2d)
        # a 2D box explained by a 3D box that another 2D box explains better counts once:
        # approximate one-to-one by also taking the column max.
        out[s:s + chunk] = np.minimum(best.sum(1), col.sum(1))
    return out


def _pinhole_rects(by_corner: np.ndarray, M: int, R: np.ndarray, t: np.ndarray, intr: CameraIntrinsics,
                   size: tuple[int, int]) -> np.ndarray:
    """``project_rects(shape, R, t, intr, size)[0]`` for a pinhole without distortion, from the
    outline corners ``by_corner`` [S*M,3] ordered corner by corner (``shape.transpose(1, 0, 2)``
    of ``shape`` [M,S,3]): every corner's pixels with ``boxproj``'s operations (one batched matrix
    product per pose, then element-wise), laid out [H,S,M] so that each edge is a running
    minimum / maximum over S contiguous [H,M] planes instead of over the strided corners of each
    box. The rects are the same values: a corner's pixels do not depend on the other corners of
    the product (``boxproj._corner_pixels``' own premise), and min / max are exact whatever their
    order (a pixel is never -0.0: ``x fx + cx``; a NaN corner makes its edge NaN either way).
    Returns rects [H,M,4], a view of [4,H,M] edge planes (invalid rects NaN)."""
    H, S = len(R), len(by_corner) // max(M, 1)
    X = np.matmul(R, by_corner.T)  # [H,3,S*M]
    X += t[:, :, None]
    z = X[:, 2].reshape(H, S, M)
    ahead = z > MIN_DEPTH_M
    inv = np.full(z.shape, np.nan)
    np.divide(1.0, z, out=inv, where=ahead)
    u = np.multiply(X[:, 0].reshape(H, S, M), inv, out=X[:, 0].reshape(H, S, M))
    v = np.multiply(X[:, 1].reshape(H, S, M), inv, out=X[:, 1].reshape(H, S, M))
    u *= intr.fx
    u += intr.cx
    v *= intr.fy
    v += intr.cy
    E = np.empty((4, H, M))
    for k, (a, red) in enumerate(((u, np.minimum), (v, np.minimum), (u, np.maximum), (v, np.maximum))):
        np.copyto(E[k], a[:, 0])
        for j in range(1, S):
            red(E[k], a[:, j], out=E[k])
    rects = E.transpose(1, 2, 0)
    finish_rects(rects, ahead.all(1), size, True)
    return rects
