"""The consensus search's trims (issue 29, session 12) give the same bits as the code before them:
``_p3p_newton`` (shared products, in-place buffers), ``kabsch_triangles`` (plane frames on columns),
``_triple_solve``'s side cosines / distances (views, not gathered copies) and ``score_poses``'
corner-major pinhole rects, each against the previous formulation written out here."""

from __future__ import annotations

import numpy as np
import pytest

from xcalib.calib import hypotheses as hy
from xcalib.calib.boxproj import project_rects
from xcalib.calib.match_sparse import explained_iou
from xcalib.geometry.camera import CameraIntrinsics
from xcalib.geometry.rotations import rotvec_to_matrix


def _p3p_newton_before(lam, cosang, d2, iters=12):  # hypotheses._p3p_newton of fc83fa0, verbatim
    l0, l1, l2 = (np.array(lam[:, k], dtype=np.float64) for k in range(3))
    c0, c1, c2 = cosang[:, 0], cosang[:, 1], cosang[:, 2]
    d0, d1, d2_ = d2[:, 0], d2[:, 1], d2[:, 2]
    for _ in range(iters):
        f0 = l0 * l0 + l1 * l1 - 2 * l0 * l1 * c0 - d0
        f1 = l0 * l0 + l2 * l2 - 2 * l0 * l2 * c1 - d1
        f2 = l1 * l1 + l2 * l2 - 2 * l1 * l2 * c2 - d2_
        P0, Q0 = 2 * l0 - 2 * l1 * c0, 2 * l1 - 2 * l0 * c0
        P1, Q1 = 2 * l0 - 2 * l2 * c1, 2 * l2 - 2 * l0 * c1
        P2, Q2 = 2 * l1 - 2 * l2 * c2, 2 * l2 - 2 * l1 * c2
        A00, A22 = P0 + 1e-6, Q2 + 1e-6
        k00 = 1e-6 * A22 - Q1 * P2
        k01 = -(P1 * A22)
        k02 = P1 * P2
        det = A00 * k00 + Q0 * k01
        if not np.all(np.isfinite(det)) or np.any(det == 0):
            break
        s0 = (k00 * f0 + -(Q0 * A22) * f1 + (Q0 * Q1) * f2) / det
        s1 = (k01 * f0 + (A00 * A22) * f1 + -(A00 * Q1) * f2) / det
        s2 = (k02 * f0 + -(A00 * P2) * f1 + (A00 * 1e-6 - Q0 * P1) * f2) / det
        big = np.maximum(np.maximum(np.abs(s0), np.abs(s1)), np.abs(s2))
        scale = np.minimum(1.0, 0.5 * np.minimum(np.minimum(l0, l1), l2) / np.maximum(big, 1e-12))
        l0 = np.maximum(l0 - s0 * scale, 0.05)
        l1 = np.maximum(l1 - s1 * scale, 0.05)
        l2 = np.maximum(l2 - s2 * scale, 0.05)
    lam = np.column_stack([l0, l1, l2])
    la, lb = lam[:, [0, 0, 1]], lam[:, [1, 2, 2]]
    f = la * la + lb * lb - 2 * la * lb * cosang - d2
    rel = np.abs(f) / np.maximum(d2, 1e-6)
    return lam, rel.max(1)


def _kabsch_triangles_before(A, B):  # hypotheses.kabsch_triangles of fc83fa0, verbatim
    ca, cb = A.mean(1), B.mean(1)
    a, b = A - ca[:, None], B - cb[:, None]

    def frame(p):
        e1 = p[:, 1] - p[:, 0]
        n = np.cross(e1, p[:, 2] - p[:, 0])
        e1 = e1 / np.maximum(np.linalg.norm(e1, axis=1, keepdims=True), 1e-300)
        n = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
        return np.stack([e1, np.cross(n, e1), n], 1)

    EA, EB = frame(A), frame(B)
    pa = a @ EA.transpose(0, 2, 1)
    pb = b @ EB.transpose(0, 2, 1)
    xa, ya, xb, yb = pa[..., 0], pa[..., 1], pb[..., 0], pb[..., 1]
    c1, s1 = np.sum(xa * xb + ya * yb, 1), np.sum(xa * yb - ya * xb, 1)
    c2, s2 = np.sum(xa * xb - ya * yb, 1), np.sum(-xa * yb - ya * xb, 1)
    flip = np.hypot(c2, s2) > np.hypot(c1, s1)
    c, s = np.where(flip, c2, c1), np.where(flip, s2, s1)
    h = np.maximum(np.hypot(c, s), 1e-300)
    c, s = c / h, s / h
    EB = np.where(flip[:, None, None], EB * np.array([1.0, -1.0, -1.0])[None, :, None], EB)
    Rz = np.zeros((len(A), 3, 3))
    Rz[:, 0, 0], Rz[:, 0, 1], Rz[:, 1, 0], Rz[:, 1, 1], Rz[:, 2, 2] = c, -s, s, c, 1.0
    R = EB.transpose(0, 2, 1) @ Rz @ EA
    return R, cb - (R @ ca[..., None])[..., 0]


def _triangles(seed: int, n: int):
    """Random camera-frame depth problems and triangles, with degenerate ones (a repeated vertex,
    collinear vertices) among them."""
    r = np.random.default_rng(seed)
    A = r.normal(scale=15.0, size=(n, 3, 3))
    A[: n // 10, 1] = A[: n // 10, 0]
    A[n // 10: n // 5, 2] = 2.0 * A[n // 10: n // 5, 1] - A[n // 10: n // 5, 0]
    rot = np.stack([rotvec_to_matrix(v) for v in r.normal(scale=1.0, size=(n, 3))])
    B = A @ rot.transpose(0, 2, 1) + r.normal(scale=10.0, size=(n, 1, 3)) + r.normal(scale=0.2, size=(n, 3, 3))
    return A, B


@pytest.mark.parametrize("seed", range(4))
def test_p3p_newton_same_depths_as_before(seed):
    r = np.random.default_rng(seed)
    A, B = _triangles(seed, 3000)
    ray = B / np.linalg.norm(B, axis=2, keepdims=True)
    pairs = ((0, 1), (0, 2), (1, 2))
    cosang = np.stack([np.einsum("ti,ti->t", ray[:, a], ray[:, b]) for a, b in pairs], 1)
    d2 = np.stack([np.sum((A[:, a] - A[:, b]) ** 2, axis=1) for a, b in pairs], 1)
    lam = np.linalg.norm(B, axis=2) * r.uniform(0.5, 2.0, size=(len(A), 3))
    got, want = hy._p3p_newton(lam.copy(), cosang, d2), _p3p_newton_before(lam.copy(), cosang, d2)
    assert got[0].tobytes() == want[0].tobytes() and got[1].tobytes() == want[1].tobytes()
    assert np.mean(got[1] < 0.05) > 0.5  # most solve (the test compares converged depths too)
    if seed == 0:  # a singular system stops every triple at that iteration, as before
        cos1 = cosang.copy()
        cos1[5] = 1.0
        lam1 = lam.copy()
        lam1[5] = 7.0
        g, w = hy._p3p_newton(lam1.copy(), cos1, d2, iters=3), _p3p_newton_before(lam1.copy(), cos1, d2, iters=3)
        assert g[0].tobytes() == w[0].tobytes()


@pytest.mark.parametrize("seed", range(4))
def test_kabsch_triangles_same_poses_as_before(seed):
    A, B = _triangles(seed, 2000)
    R, t = hy.kabsch_triangles(A, B)
    R0, t0 = _kabsch_triangles_before(A, B)
    assert np.array_equal(R, R0, equal_nan=True) and np.array_equal(t, t0, equal_nan=True)
    ok = slice(len(A) // 5, None)  # the well-shaped ones: proper rotations
    assert np.allclose(np.linalg.det(R[ok]), 1.0)


def test_triple_solve_same_poses_as_the_gathered_form():
    """``_triple_solve``'s per-side cosines and distances from [T,3] views are those of the gathered
    [T,3,3] form (``einsum("tki,tki->tk")`` and ``np.sum(axis=2)``): the same poses."""
    r = np.random.default_rng(3)
    A, B = _triangles(3, 1200)
    n = 60
    X = r.normal(scale=15.0, size=(n, 3))
    Xc = X @ rotvec_to_matrix(np.array([0.1, -1.2, 0.3])).T + np.array([0.5, 1.0, 25.0])
    ray = Xc / np.linalg.norm(Xc, axis=1, keepdims=True)
    c = hy._Candidates(fk=np.zeros(n, np.int64), ii=np.arange(n), jj=np.arange(n), ray=ray,
                       lam=np.linalg.norm(Xc, axis=1) * r.uniform(0.7, 1.4, n), dtol=np.ones(n), w=np.zeros(n), X=X)
    tri = np.stack([r.choice(n, 3, replace=False) for _ in range(2000)])
    Bg, Ag = ray[tri], X[tri]
    a_idx, b_idx = np.array([0, 0, 1]), np.array([1, 2, 2])
    cos_w = np.einsum("tki,tki->tk", Bg[:, a_idx], Bg[:, b_idx])
    d2_w = np.sum((Ag[:, a_idx] - Ag[:, b_idx]) ** 2, axis=2)
    lam_t, rel = _p3p_newton_before(c.lam[tri].copy(), cos_w, d2_w)
    good = (rel < 0.05) & np.all(lam_t > 1.0, axis=1)
    want = hy.kabsch_triangles(Ag[good], lam_t[good, :, None] * Bg[good])
    got = hy._triple_solve(c, tri, closed_form=True)
    assert good.sum() > 1000
    assert got[0].tobytes() == want[0].tobytes() and got[1].tobytes() == want[1].tobytes()


@pytest.mark.parametrize("case", ["corners", "outlines", "few_poses"])
def test_score_poses_pinhole_rects_are_project_rects(case):
    """``score_poses``' corner-major rects (pinhole, no distortion) are ``project_rects``', bit for bit,
    with poses that put boxes behind the camera and partly out of the image, and the scores those of
    ``explained_iou`` on ``project_rects``' rects."""
    r = np.random.default_rng({"corners": 0, "outlines": 1, "few_poses": 2}[case])
    intr = CameraIntrinsics(fx=1100.0, fy=1090.0, cx=960.0, cy=600.0, width=1920, height=1200)
    size = (1920, 1200)
    M, S = 14, (8 if case != "outlines" else 30)
    centre = np.column_stack([r.uniform(5, 60, M), r.uniform(-20, 20, M), r.uniform(-1, 2, M)])
    shape = centre[:, None, :] + r.normal(scale=1.5, size=(M, S, 3))
    if case == "outlines":  # padded outlines: trailing copies of the first vertex
        shape[:5, 20:] = shape[:5, :1]
    H = 5 if case == "few_poses" else 700
    base = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])  # LiDAR x forward -> camera z
    R = np.stack([rotvec_to_matrix(v) @ base for v in r.normal(scale=0.15, size=(H, 3))])
    t = r.normal(scale=2.0, size=(H, 3))
    t[: H // 5, 2] -= 40.0  # every box behind the camera, or some
    by_corner = np.ascontiguousarray(shape.transpose(1, 0, 2)).reshape(-1, 3)
    got = hy._pinhole_rects(by_corner, M, R, t, intr, size)
    want, _ = project_rects(shape, R, t, intr, size)
    assert got.shape == want.shape and np.array_equal(got, want, equal_nan=True)
    assert np.isnan(want).any() and np.isfinite(want).any()

    seen = want[-1][np.isfinite(want[-1, :, 0])]  # 2D boxes near the last pose's rects
    assert len(seen) >= 3

    class _Fr:  # the fields score_poses reads
        n2, n3 = len(seen), M
        corners, box_corners, size = shape, None, (1920, 1200)
        boxes2d = seen + r.normal(scale=10.0, size=seen.shape)

    best, col = explained_iou(want, _Fr.boxes2d)
    sc = hy.score_poses(_Fr, intr, R, t, chunk=97)
    assert sc.tobytes() == np.minimum(best.sum(1), col.sum(1)).tobytes()
    assert sc.max() > 0.0
