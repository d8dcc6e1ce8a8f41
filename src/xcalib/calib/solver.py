"""A lean trust-region least-squares solver for the calibration's small dense fits.

:func:`trf` is scipy's ``least_squares(method="trf")`` without bounds, with a dense analytic
Jacobian and the exact (SVD) trust-region solver -- the case of every ``CostModel.fit`` with an
analytic Jacobian -- written out in the same operations and order, so the iterates, the
evaluations asked for and the result are scipy's (``tests/test_calib_solver.py`` compares them
on seeded problems). What it drops is scipy's per-call and per-iteration machinery (argument
checks, the function wrappers and their copies, the generic loss plumbing): a pose fit here is
6-8 parameters and a few hundred residuals, where that machinery took about as long as the
residuals and the Jacobian themselves.

Losses: ``"linear"`` and ``"soft_l1"`` (with ``f_scale``), as scipy defines them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np
from scipy.linalg import get_lapack_funcs, svd

__all__ = ["TrfResult", "trf", "trf_fit", "LOSSES"]

EPS = np.finfo(float).eps
LOSSES = ("linear", "soft_l1")


@dataclass
class TrfResult:
    """``x`` [n]; ``cost``: the (robust) cost 0.5 sum rho(f^2) at x; ``fun``: the residuals at x;
    ``nfev`` / ``njev``: evaluations; ``status``: scipy's (0: max_nfev reached, 1: gtol, 2: ftol,
    3: xtol, 4: ftol and xtol)."""

    x: np.ndarray
    cost: float
    fun: np.ndarray
    nfev: int
    njev: int
    status: int


def _residuals(fun, x: np.ndarray) -> np.ndarray:
    """``fun`` at a copy of ``x``, as an array of our own (the solver scales it in place)."""
    return np.array(fun(x.copy()), ndmin=1, copy=True)


_GESDD: list = []  # (gesdd, gesdd_lwork) for float64, looked up on first use


def _svd_thin(a: np.ndarray):
    """``scipy.linalg.svd(a, full_matrices=False)`` of a float64 [m, n] matrix: the same LAPACK
    routine (gesdd) with the same work size and the same finiteness check, without scipy's
    per-call wrapping (the routine looked up once; ~40 % of the call at a pose fit's size)."""
    a = np.asarray_chkfinite(a)  # scipy's check_finite: ValueError on inf / NaN
    if a.ndim != 2 or a.size == 0 or a.dtype != np.float64:
        return svd(a, full_matrices=False)
    if not _GESDD:
        _GESDD.extend(get_lapack_funcs(("gesdd", "gesdd_lwork"), (a,), ilp64="preferred"))
    gesdd, gesdd_lwork = _GESDD
    work, info = gesdd_lwork(a.shape[0], a.shape[1], compute_uv=1, full_matrices=0)
    if info != 0:
        return svd(a, full_matrices=False)
    u, s, v, info = gesdd(a, compute_uv=1, lwork=int(work.real), full_matrices=0, overwrite_a=0)
    if info != 0:  # scipy's own errors (no convergence, NaN)
        return svd(a, full_matrices=False)
    return u, s, v


def _norm(v: np.ndarray) -> float:
    return math.sqrt(v.dot(v))  # numpy.linalg.norm of a vector: sqrt(v . v), both correctly rounded


class _SoftL1:
    """scipy's soft-L1 loss rho(z) = 2 (sqrt(1 + z) - 1) at scale ``f_scale``, its rows in one [3, m] array."""

    def __init__(self, m: int, f_scale: float):
        self.rho, self.f_scale = np.empty((3, m)), f_scale

    def __call__(self, f: np.ndarray, cost_only: bool = False):
        rho, fs = self.rho, self.f_scale
        z = (f / fs) ** 2
        t = 1 + z
        rho[0] = 2 * (t ** 0.5 - 1)
        if cost_only:
            return 0.5 * fs ** 2 * np.sum(rho[0])
        rho[1] = t ** -0.5
        rho[2] = -0.5 * t ** -1.5
        rho[0] *= fs ** 2
        rho[2] /= fs ** 2
        return rho


def _scale_for_loss(J: np.ndarray, f: np.ndarray, rho: np.ndarray):
    """scipy's ``scale_for_robust_loss_function`` (in place)."""
    J_scale = rho[1] + 2 * rho[2] * f ** 2
    J_scale[J_scale < EPS] = EPS
    J_scale **= 0.5
    f *= rho[1] / J_scale
    J *= J_scale[:, np.newaxis]
    return J, f


def _solve_trust_region(n: int, m: int, uf, s, V, Delta: float, initial_alpha: float | None = None):
    """scipy's ``solve_lsq_trust_region`` (More's method on one SVD; its defaults rtol 0.01, 10
    iterations): (step p, alpha, iterations)."""
    rtol, max_iter = 0.01, 10
    def phi_and_derivative(alpha, suf, s, Delta):
        denom = s ** 2 + alpha
        p_norm = _norm(suf / denom)
        phi = p_norm - Delta
        phi_prime = -np.sum(suf ** 2 / denom ** 3) / p_norm
        return phi, phi_prime

    suf = s * uf
    if m >= n:
        threshold = EPS * m * s[0]
        full_rank = s[-1] > threshold
    else:
        full_rank = False
    if full_rank:
        p = -V.dot(uf / s)
        if _norm(p) <= Delta:
            return p, 0.0, 0
    alpha_upper = _norm(suf) / Delta
    if full_rank:
        phi, phi_prime = phi_and_derivative(0.0, suf, s, Delta)
        alpha_lower = -phi / phi_prime
    else:
        alpha_lower = 0.0
    if initial_alpha is None or not full_rank and initial_alpha == 0:
        alpha = max(0.001 * alpha_upper, (alpha_lower * alpha_upper) ** 0.5)
    else:
        alpha = initial_alpha
    for it in range(max_iter):
        if alpha < alpha_lower or alpha > alpha_upper:
            alpha = max(0.001 * alpha_upper, (alpha_lower * alpha_upper) ** 0.5)
        phi, phi_prime = phi_and_derivative(alpha, suf, s, Delta)
        if phi < 0:
            alpha_upper = alpha
        ratio = phi / phi_prime
        alpha_lower = max(alpha_lower, alpha - ratio)
        alpha -= (phi + Delta) * ratio / Delta
        if np.abs(phi) < rtol * Delta:
            break
    p = -V.dot(suf / (s ** 2 + alpha))
    p *= Delta / _norm(p)
    return p, alpha, it + 1


def _update_radius(Delta: float, actual: float, predicted: float, step_norm: float, bound_hit: bool):
    """scipy's ``update_tr_radius``: (new radius, actual / predicted reduction)."""
    if predicted > 0:
        ratio = actual / predicted
    elif predicted == actual == 0:
        ratio = 1
    else:
        ratio = 0
    if ratio < 0.25:
        Delta = 0.25 * step_norm
    elif ratio > 0.75 and bound_hit:
        Delta *= 2.0
    return Delta, ratio


def _termination(dF, F, dx_norm, x_norm, ratio, ftol, xtol) -> int | None:
    ftol_ok = dF < ftol * F and ratio > 0.25
    xtol_ok = dx_norm < xtol * (xtol + x_norm)
    if ftol_ok and xtol_ok:
        return 4
    if ftol_ok:
        return 2
    if xtol_ok:
        return 3
    return None


def trf(fun: Callable[[np.ndarray], np.ndarray], jac: Callable[[np.ndarray], np.ndarray], x0: np.ndarray,
        x_scale: np.ndarray, *, loss: str = "soft_l1", f_scale: float = 1.0, max_nfev: int | None = None,
        tol: tuple[float, float, float] = (1e-8, 1e-8, 1e-8)) -> TrfResult:
    """Minimise 0.5 sum rho(fun(x)^2) from ``x0`` [n] as scipy's ``least_squares(fun, x0, jac=jac,
    method="trf", loss=loss, f_scale=f_scale, x_scale=x_scale, max_nfev=max_nfev, ftol, xtol,
    gtol = tol)`` does with no bounds (``jac``: the dense [m, n] Jacobian). Raises ValueError
    where scipy does: residuals not finite at ``x0``, a Jacobian of the wrong shape, or (its SVD)
    not finite."""
    return _trf(fun, jac, x0, x_scale, (loss, f_scale, max_nfev, tol, True))


def trf_fit(fun: Callable[[np.ndarray], np.ndarray], jac: Callable[[np.ndarray], np.ndarray], x0: np.ndarray,
            x_scale: np.ndarray, *, loss: str = "soft_l1", f_scale: float = 1.0,
            max_nfev: int | None = None) -> TrfResult:
    """:func:`trf` (default tolerances) without the Jacobian at the accepted point that ends the fit
    (a termination test passed or ``max_nfev`` reached): scipy evaluates it there only for one
    more gradient test, which cannot move the point. ``x``, ``cost``, ``fun`` and ``nfev`` are
    :func:`trf`'s, bit for bit; ``njev`` is one less where the fit ended on an accepted step, and
    ``status`` the test that stopped it (scipy may report 1, gtol, there instead). What a fit
    (``CostModel.fit``) uses of the result is x, cost and fun."""
    return _trf(fun, jac, x0, x_scale, (loss, f_scale, max_nfev, (1e-8, 1e-8, 1e-8), False))


def _trf(fun, jac, x0: np.ndarray, x_scale: np.ndarray, settings: tuple) -> TrfResult:
    """:func:`trf`; ``settings``: (loss, f_scale, max_nfev, tol, final_jacobian)."""
    loss, f_scale, max_nfev, tol, final_jacobian = settings
    if loss not in LOSSES:
        raise ValueError(f"loss must be one of {LOSSES}, got {loss!r}")
    ftol, xtol, gtol = tol
    x0 = np.asarray(x0, dtype=np.float64).copy()
    x_scale = np.asarray(x_scale, dtype=np.float64)
    x = x0.copy()
    f = _residuals(fun, x0)
    if f.ndim != 1:
        raise ValueError(f"`fun` must return at most 1-d array_like. f0.shape: {f.shape}")
    if not np.all(np.isfinite(f)):
        raise ValueError("Residuals are not finite in the initial point.")
    m, n = f.size, x0.size
    J = np.atleast_2d(jac(x0.copy())).astype(np.float64, copy=True)
    if J.shape != (m, n):
        raise ValueError(f"The return value of `jac` has wrong shape: expected {(m, n)}, actual {J.shape}.")
    loss_function = _SoftL1(m, f_scale) if loss == "soft_l1" else None
    f_true = f.copy()
    nfev, njev = 1, 1
    if loss_function is not None:
        rho = loss_function(f)
        cost = 0.5 * np.sum(rho[0])
        J, f = _scale_for_loss(J, f, rho)
    else:
        cost = 0.5 * np.dot(f, f)
    g = J.T.dot(f)
    scale, scale_inv = x_scale, 1 / x_scale
    Delta = _norm(x0 * scale_inv)
    if Delta == 0:
        Delta = 1.0
    if max_nfev is None:
        max_nfev = x0.size * 100
    alpha = 0.0
    status = None
    while True:
        g_norm = np.abs(g).max()
        if g_norm < gtol:
            status = 1
        if status is not None or nfev == max_nfev:
            break
        d = scale
        g_h = d * g
        J_h = J * d
        U, s, V = _svd_thin(J_h)
        V = V.T
        uf = U.T.dot(f)
        actual_reduction = -1
        while actual_reduction <= 0 and nfev < max_nfev:
            step_h, alpha, _ = _solve_trust_region(n, m, uf, s, V, Delta, initial_alpha=alpha)
            Js = J_h.dot(step_h)
            predicted_reduction = -(0.5 * np.dot(Js, Js) + np.dot(step_h, g_h))
            step = d * step_h
            x_new = x + step
            f_new = _residuals(fun, x_new)
            nfev += 1
            step_h_norm = _norm(step_h)
            if not np.all(np.isfinite(f_new)):
                Delta = 0.25 * step_h_norm
                continue
            if loss_function is not None:
                cost_new = loss_function(f_new, cost_only=True)
            else:
                cost_new = 0.5 * np.dot(f_new, f_new)
            actual_reduction = cost - cost_new
            Delta_new, ratio = _update_radius(Delta, actual_reduction, predicted_reduction, step_h_norm,
                                              step_h_norm > 0.95 * Delta)
            step_norm = _norm(step)
            status = _termination(actual_reduction, cost, step_norm, _norm(x), ratio, ftol, xtol)
            if status is not None:
                break
            alpha *= Delta / Delta_new
            Delta = Delta_new
        if actual_reduction > 0:
            x = x_new
            f = f_new
            f_true = f.copy()
            cost = cost_new
            if not final_jacobian and (status is not None or nfev == max_nfev):
                break  # the fit ends here: that Jacobian would feed only scipy's last gtol test
            J = np.atleast_2d(jac(x.copy())).astype(np.float64, copy=True)
            njev += 1
            if loss_function is not None:
                rho = loss_function(f)
                J, f = _scale_for_loss(J, f, rho)
            g = J.T.dot(f)
    return TrfResult(x=x, cost=float(cost), fun=f_true, nfev=nfev, njev=njev, status=0 if status is None else status)
