"""The 95 % bound with estimated variances (issue 25, session 10): ``bound95``'s F form, the CR2
cross-axis degrees-of-freedom matrix and ``bound_dof``."""

import numpy as np
import pytest

from xcalib.calib.diagnostics import bound95
from xcalib.calib.uncertainty import bound_dof, cr2_covariance


def _clusters(seed: int, G: int = 6):
    rng = np.random.default_rng(seed)
    n = rng.integers(2, 7, G)
    Xs = [rng.normal(size=6) * np.exp(rng.normal()) + 0.5 * rng.normal(size=(k, 6)) for k in n]
    X = np.concatenate(Xs)
    A = np.linalg.inv(X.T @ X)
    y = rng.normal(size=len(X))
    r = y - X @ (A @ X.T @ y)
    off = np.cumsum([0] + list(n))
    g = np.stack([Xs[c].T @ r[off[c]:off[c + 1]] for c in range(G)])
    M = np.stack([x.T @ x for x in Xs])
    return Xs, X, A, g, M


def test_bound95_f_form_reduces_to_t_and_chi_square():
    from scipy.special import fdtri, stdtrit  # t / F quantiles without importing scipy.stats (seconds)

    assert bound95([1.0, 0.0, 0.0], dof=3) == pytest.approx(stdtrit(3, 0.975))
    assert bound95([1.0, 1.0, 1.0], dof=np.inf) == pytest.approx(bound95([1.0, 1.0, 1.0]))
    assert bound95([1.0, 1.0, 1.0], dof=1e9) == pytest.approx(2.7955, abs=1e-3)
    # three equal axes sharing one variance estimate with 3 dof: |e|^2 / s^2 = 3 F(3, 3)
    assert bound95([1.0, 1.0, 1.0], dof=3) == pytest.approx(np.sqrt(3 * fdtri(3, 3, 0.95)))
    # fully correlated axes are one axis of variance 3: 1.96 sqrt(3), not the independent 2.80
    assert bound95(None, cov=np.ones((3, 3))) == pytest.approx(1.959964 * np.sqrt(3))
    assert bound95([1.0, 1.0, 1.0], dof=np.nan) == np.inf
    assert bound95(None, cov=np.diag([1.0, np.inf, 0.0])) == np.inf


def test_bound95_with_dof_covers_95_percent_of_a_shared_variance_estimate():
    rng = np.random.default_rng(3)
    nu = 4
    e = rng.normal(size=(20000, 3))
    s2 = rng.chisquare(nu, 20000) / nu  # one variance estimate shared by the three axes
    r = np.array([bound95(np.sqrt([v, v, v]), dof=nu) for v in s2[:4000]])
    assert np.mean(np.linalg.norm(e[:4000], axis=1) <= r) == pytest.approx(0.95, abs=0.012)


def test_cr2_cross_dof_matrix_is_the_explicit_one():
    """``cross_out`` (computed in O(G)) against the explicit ``|G_k^T G_l|_F^2 / (tr tr)`` with
    ``G_k``'s column c = ``(I - H)_{., c} (I - H_cc)^-1/2 X_c A e_k``; its diagonal is 1 / dof."""
    Xs, X, A, g, M = _clusters(5)
    S = np.zeros((6, 6))
    cov, nu = cr2_covariance(A, g, M, cross_out=S)
    n = len(X)
    IH = np.eye(n) - X @ A @ X.T
    off = np.cumsum([0] + [len(x) for x in Xs])
    Gk = []
    for k in range(6):
        cols = []
        for c, x in enumerate(Xs):
            sl = slice(off[c], off[c + 1])
            w, V = np.linalg.eigh(IH[sl, sl])
            inv_sqrt = (V / np.sqrt(w)) @ V.T
            cols.append(IH[:, sl] @ inv_sqrt @ x @ A[:, k])
        Gk.append(np.stack(cols, axis=1))  # [n, G]
    B = [[Gk[k].T @ Gk[l] for l in range(6)] for k in range(6)]
    ref = np.array([[np.sum(B[k][l] ** 2) / (np.trace(B[k][k]) * np.trace(B[l][l])) for l in range(6)] for k in range(6)])
    np.testing.assert_allclose(S, ref, rtol=1e-6)
    np.testing.assert_allclose(np.diag(S), 1.0 / nu, rtol=1e-6)
    assert np.all(S[~np.eye(6, dtype=bool)] < np.sqrt(np.outer(np.diag(S), np.diag(S)))[~np.eye(6, dtype=bool)])


def test_bound_dof():
    S = np.array([[0.5, 0.1, 0.0], [0.1, 0.25, 0.0], [0.0, 0.0, 0.2]])
    assert bound_dof([1.0, 2.0, 3.0], [0.0, 0.0, 0.0], S) == np.inf  # nothing estimated
    assert bound_dof([1.0, 0.0, 0.0], [1.0, 0.0, 0.0], S) == pytest.approx(2.0)  # one axis: its own dof
    # a known part beside the estimate raises the dof by (total / estimated)^2
    assert bound_dof([2.0, 0.0, 0.0], [1.0, 0.0, 0.0], S) == pytest.approx(8.0)
    v = np.array([1.0, 1.0, 1.0])
    assert bound_dof(v, v, S) == pytest.approx(9.0 / float(v @ S @ v))


def test_sigma_parts_bounds_on_the_stored_s10_run():
    """``scripts/sigma_parts.py bound`` on ``s10_bound`` (its records keep the CR2 correlation and
    cross-axis dofs): the old bound is the one the run reported (``within_95``), the new one is
    finite wherever the old one is, and the CR2 part unstretched is never above the stretched one."""
    import importlib.util
    from pathlib import Path

    from xcalib.calib.uncertainty import SHIFT_NOISE_Z

    root = Path(__file__).resolve().parents[1]
    spec = importlib.util.spec_from_file_location("sigma_parts", root / "scripts" / "sigma_parts.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    run = mod.load_results()["runs"].get("s10_bound")
    if run is None:
        pytest.skip("no s10_bound run in calibration_realism.json")
    checked = 0
    for cond in run["conditions"]:
        for rec in (r for r in cond["per_site"] if r["success"]):
            assert rec["sigma_parts"]["clusters_dof_cross"] is not None
            err = np.asarray(rec["z_axes"]) * np.asarray(rec["sigma_axes"])
            old = mod.bounds(rec, SHIFT_NOISE_Z, "old", cr2="full")  # the run's own combination (session 10)
            new = mod.bounds(rec, SHIFT_NOISE_Z, "new")
            inside = bool(np.linalg.norm(err[:3]) <= old[0] and np.linalg.norm(err[3:]) <= old[1])
            assert inside == rec["within_95"], (cond["condition"], rec["seed"])
            assert np.all(np.isfinite(new)) == np.all(np.isfinite(old))
            var, rand, _ = mod.bound_inputs(rec, SHIFT_NOISE_Z)
            assert np.all(rand <= var + 1e-15) and np.all(var <= np.asarray(rec["sigma_axes"]) ** 2 * (1 + 1e-9))
            checked += 1
    assert checked >= 30


def test_frames_mode_calibrates_without_the_cr2_parts():
    """``CalibConfig(uncertainty="frames")`` (the 0.4 sigma) computes no object-clustered sandwich,
    so it has no CR2 correlation to keep: the calibration still completes (it raised
    UnboundLocalError once the correlation was stored) and stores none."""
    from xcalib.calib import CalibConfig, calibrate
    from xcalib.data.synth import generate_frames, sample_site

    frames = generate_frames(sample_site(3), 6, seed=1, render_images=False, lidar=False, box_noise_px=1.0)
    r = calibrate(frames, frames[0].intrinsics, config=CalibConfig(uncertainty="frames"))
    parts = r.diagnostics.uncertainty
    assert r.success and parts is not None
    assert parts.clusters is None and parts.clusters_corr is None and parts.clusters_dof_cross is None
