"""A fit that no longer evaluates a Jacobian nobody uses (issue 29): ``poses_refine._fit`` (no
Jacobian for a pose that has just settled, nor after the last step) against the loop it replaces,
written out below: the same poses and residuals, bit for bit. (``solver.trf_fit`` against
``solver.trf``: ``tests/test_calib_solver.py``.)"""

from __future__ import annotations

import numpy as np
import pytest

from xcalib.calib import poses_refine as pr
from xcalib.calib.cost import Occlusion, edge_sigma
from xcalib.calib.inputs import prepare_frames
from xcalib.calib.pose import Pose
from xcalib.calib.refine import DEFAULT_NOISE, pair_scores
from xcalib.data.synth import generate_frames, sample_site
from xcalib.geometry.rotations import so3_exp


def _old_fit(batch, R, t, fs, active, max_iter):
    """``poses_refine._fit`` as it was: the Jacobian at every accepted step of every pose."""
    R, t = R.copy(), t.copy()
    r, raw, proj = batch.residuals(R, t)
    cost, wts = pr._robust(r, fs)
    lam = np.full(len(R), 1e-3)
    live = active.copy()
    J = batch.jacobian(t, raw, proj)
    eye = np.eye(6)
    for _ in range(max_iter):
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
        Rn = pr._exp(dx[:, :3]) @ R[idx]
        tn = t[idx] + dx[:, 3:]
        rn, rawn, projn = sub.residuals(Rn, tn)
        cn, wn = pr._robust(rn, fs[idx])
        better = cn <= cost[idx]
        step = np.linalg.norm(dx[:, :3], axis=1) + np.linalg.norm(dx[:, 3:], axis=1) / 100.0
        settled = better & ((step < pr.STEP_TOL) | (cost[idx] - cn <= pr.COST_TOL * np.maximum(cost[idx], 1e-12)))
        if better.any():
            b = idx[better]
            R[b], t[b] = Rn[better], tn[better]
            r[b], raw[b], wts[b], cost[b] = rn[better], rawn[better], wn[better], cn[better]
            kb = np.flatnonzero(better)
            J[b] = (sub if len(kb) == n else sub.take(kb)).jacobian(tn[kb], rawn[kb], tuple(a[kb] for a in projn))
        lam[idx] = np.where(better, np.maximum(lam[idx] / 3.0, 1e-9), lam[idx] * 4.0)
        live[idx] &= ~settled & (lam[idx] < 1e8)
    return R, t, r


@pytest.fixture(scope="module", params=[1, 5])
def case(request):
    site = sample_site(request.param)
    f = generate_frames(site, 1, seed=5, render_images=False, lidar=False, box_noise_px=1.0)[0]
    cfs, intr, _ = prepare_frames([f], f.intrinsics)
    return cfs[0], intr, site.T_cam_lidar


@pytest.mark.parametrize("max_iter", [1, 2, 4, 15])
@pytest.mark.parametrize("seed", [0, 1])
def test_poses_fit_is_the_old_loop(case, max_iter, seed):
    fr, intr, T = case
    rng = np.random.default_rng(seed)
    H = 5
    R = np.stack([so3_exp(rng.normal(size=3) * np.radians(0.8)) @ T[:3, :3] for _ in range(H)])
    t = T[:3, 3] + rng.normal(size=(H, 3)) * 0.2
    pairs, _ = pr.match_poses(fr, intr, R, t, 0.1, 1.0)
    sig = [edge_sigma(fr.boxes2d[p[:, 0]], fr.corners[p[:, 1]], intr, Pose(R[h], t[h]), DEFAULT_NOISE,
                      np.zeros(len(p)), pair_scores([fr], [p])) for h, p in enumerate(pairs)]
    batch = pr._Batch(fr, pairs, sig, intr, Occlusion())
    fs = np.full(H, 2.0)
    active = np.array([len(p) >= 3 for p in pairs])
    active[1] = False  # a pose not refined stays where it is
    new = pr._fit(batch, R, t, fs, active, max_iter)
    old = _old_fit(batch, R, t, fs, active, max_iter)
    for a, b in zip(new, old):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(new[0][1], R[1])
    assert active.sum() >= 3
    if max_iter == 15:  # (the first steps may all be rejected while the damping grows)
        assert not np.array_equal(new[0][active], R[active])  # the fit moved the poses
