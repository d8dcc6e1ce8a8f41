"""``calib.solver.trf`` is scipy's ``least_squares(method="trf")`` without bounds (dense analytic
Jacobian, exact trust-region solver): on seeded problems it takes the same steps, asks for the same
evaluations and ends at the same minimum as scipy. ``trf_fit`` (what ``CostModel.fit`` runs) is
``trf`` without the Jacobian at the point where the fit ends: the same x, fun, cost, one Jacobian fewer."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import least_squares

from xcalib.calib.solver import trf, trf_fit


def _curve_problem(seed: int):
    """A seeded robust curve fit: y = a exp(-b t) + c sin(d t) + e, 5 % gross outliers."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0, 6, 120)
    p_true = np.array([2.0, 0.7, 0.5, 2.1, 0.3]) * (1 + 0.2 * rng.standard_normal(5))
    y = p_true[0] * np.exp(-p_true[1] * t) + p_true[2] * np.sin(p_true[3] * t) + p_true[4]
    y = y + 0.02 * rng.standard_normal(len(t))
    out = rng.random(len(t)) < 0.05
    y[out] += rng.normal(0, 2, out.sum())

    def fun(p):
        return (p[0] * np.exp(-p[1] * t) + p[2] * np.sin(p[3] * t) + p[4] - y) / 0.02

    def jac(p):
        e = np.exp(-p[1] * t)
        return np.column_stack([e, -p[0] * t * e, np.sin(p[3] * t), p[2] * t * np.cos(p[3] * t),
                                np.ones_like(t)]) / 0.02

    x0 = p_true * (1 + 0.15 * rng.standard_normal(5))
    return fun, jac, x0


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("loss,f_scale,max_nfev", [("soft_l1", 2.0, 60), ("soft_l1", 0.7, 6), ("linear", 1.0, 40)])
def test_trf_is_scipys_trf(seed, loss, f_scale, max_nfev):
    fun, jac, x0 = _curve_problem(seed)
    x_scale = np.array([0.1, 0.05, 0.1, 0.05, 0.1])
    ref = least_squares(fun, x0, jac=jac, method="trf", loss=loss, f_scale=f_scale, x_scale=x_scale,
                        max_nfev=max_nfev)
    got = trf(fun, jac, x0, x_scale, loss=loss, f_scale=f_scale, max_nfev=max_nfev)
    assert (got.nfev, got.njev, got.status) == (ref.nfev, ref.njev, ref.status)
    np.testing.assert_array_equal(got.x, ref.x)  # the same operations: the same bits
    np.testing.assert_allclose(got.fun, ref.fun, rtol=1e-10, atol=1e-10)
    assert got.cost == pytest.approx(ref.cost, rel=1e-12)
    if max_nfev >= 40:  # converged: the minimum (the fit moved the start)
        assert got.status > 0 and got.cost < 0.5 * np.sum(fun(x0) ** 2)


def test_a_pose_fit_is_scipys():
    from xcalib.calib.cost import Occlusion
    from xcalib.calib.inputs import prepare_frames
    from xcalib.calib.pose import Pose
    from xcalib.calib.refine import build_cost, match_all
    from xcalib.data.synth import generate_frames, sample_site

    site = sample_site(0, "roadside")
    frames = generate_frames(site, 3, seed=1, render_images=False, lidar=False, box_noise_px=2.0)
    cframes, intr, _ = prepare_frames(frames, site.intrinsics)
    truth = Pose(site.T_cam_lidar[:3, :3], site.T_cam_lidar[:3, 3])
    start = truth.moved(np.array([0.01, -0.008, 0.005]), np.array([0.2, -0.1, 0.15]))
    pairs = match_all(cframes, intr, truth.R, truth.t)
    model = build_cost(cframes, pairs, intr, start, None, Occlusion())
    assert model.has_analytic_jacobian()
    for max_nfev in (5, 60):
        ref = least_squares(model.residuals, np.zeros(6), jac=model.analytic_jacobian, loss="soft_l1", f_scale=2.0,
                            method="trf", x_scale=model.x_scale(), max_nfev=max_nfev)
        fit = model.fit(f_scale=2.0, max_nfev=max_nfev)
        np.testing.assert_array_equal(fit.x, ref.x)
        assert fit.cost == pytest.approx(float(ref.cost), rel=1e-12)
    assert fit.pose.error(truth)[0] < 0.5 * start.error(truth)[0]  # the fit moved towards the true pose


def test_trf_refuses_what_scipy_refuses():
    fun, jac, x0 = _curve_problem(0)
    with pytest.raises(ValueError, match="not finite"):
        trf(lambda p: fun(p) * np.nan, jac, x0, np.ones(5))
    with pytest.raises(ValueError, match="wrong shape"):
        trf(fun, lambda p: jac(p)[:, :3], x0, np.ones(5))
    with pytest.raises(ValueError, match="loss"):
        trf(fun, jac, x0, np.ones(5), loss="cauchy")


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("loss,f_scale,max_nfev", [("soft_l1", 2.0, 60), ("soft_l1", 0.7, 6), ("linear", 1.0, 40),
                                                   ("soft_l1", 1.0, 3)])
def test_trf_fit_is_trf_without_the_last_jacobian(seed, loss, f_scale, max_nfev):
    fun, jac, x0 = _curve_problem(seed)
    calls = {"full": 0, "lean": 0}

    def counted(kind):
        def j(x):
            calls[kind] += 1
            return jac(x)
        return j

    x_scale = np.array([0.1, 0.05, 0.1, 0.05, 0.1])
    ref = trf(fun, counted("full"), x0, x_scale, loss=loss, f_scale=f_scale, max_nfev=max_nfev)
    got = trf_fit(fun, counted("lean"), x0, x_scale, loss=loss, f_scale=f_scale, max_nfev=max_nfev)
    np.testing.assert_array_equal(got.x, ref.x)
    np.testing.assert_array_equal(got.fun, ref.fun)
    assert got.cost == ref.cost and got.nfev == ref.nfev
    # the one Jacobian left out is the one at the accepted point where the fit ended
    assert calls["lean"] == got.njev and ref.njev - got.njev in (0, 1)
    if got.status in (2, 4):  # ended by ftol: on an accepted step (its ratio > 0.25), whose Jacobian is left out
        assert got.njev == ref.njev - 1
    if max_nfev >= 40:
        assert got.status in (2, 4)  # (these converge by ftol: the saving is exercised)
