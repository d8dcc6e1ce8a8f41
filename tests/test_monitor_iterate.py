"""The change test's estimate iterated on the frames' unshaped residual rows
(``xcalib.monitor.iterate``): it recovers a move that the occlusion shaping evaluated at the
calibration distorts, and with no step it is the one-step estimate."""

from __future__ import annotations

import numpy as np
import pytest

from xcalib.monitor import MonitorConfig
from xcalib.monitor.iterate import EdgeRows, iterated_fit, normal_equations, object_shares, stack_rows

TAU, SLOPE = 1.5, 0.2


def _rows(seed: int, x_true: np.ndarray, m: int = 2000) -> tuple:
    """Residual rows whose unshaped residuals are J x_true + unit noise, 4 edges of m/4 pairs
    (sign pattern as ``calib.cost.INWARD``), 10 objects."""
    rng = np.random.default_rng(seed)
    J = rng.standard_normal((m, 6)) * np.array([300.0, 300.0, 300.0, 20.0, 20.0, 20.0])
    sgn = np.tile([-1.0, -1.0, 1.0, 1.0], m // 4)
    J[:, 5] = -sgn * np.abs(J[:, 5])  # a shift along the view axis moves every edge inwards (smaller boxes)
    e0 = -J @ x_true + rng.standard_normal(m)  # pred - obs at the calibration: the move undone by x_true
    parts = [EdgeRows(e0[i::10], J[i::10], sgn[i::10], np.full(len(e0[i::10]), i), 2.0) for i in range(10)]
    return stack_rows(parts)


def test_iterating_recovers_a_move_the_shaping_distorts():
    x_true = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.15])  # ~2.4 sigma inwards on a typical edge: beyond tau
    rows = _rows(1, x_true)
    H, g, _ = normal_equations(rows, np.zeros(6), TAU, SLOPE)
    one = -np.linalg.solve(H, g)
    xl, H3, g3, _ = iterated_fit(rows, 3, TAU, SLOPE)
    it = -np.linalg.solve(H3, g3)
    assert abs(one[5] / x_true[5] - 1.0) > 0.08  # the one-step estimate misreads it (the shaping's slope) ...
    assert abs(it[5] / x_true[5] - 1.0) < 0.05  # ... three steps recover the move
    assert np.allclose(xl, it, atol=0.02)  # the last linearisation is near the answer


def test_no_step_is_the_one_step_estimate_and_shares_add_up():
    rows = _rows(2, np.zeros(6))
    x0, H0, g0, c0 = iterated_fit(rows, 0, TAU, SLOPE)
    H, g, c = normal_equations(rows, np.zeros(6), TAU, SLOPE)
    assert np.array_equal(x0, np.zeros(6)) and np.allclose(H0, H) and np.allclose(g0, g) and c0 == pytest.approx(c)
    xl, H3, g3, _ = iterated_fit(rows, 3, TAU, SLOPE)
    ids, oH, og = object_shares(rows, xl, TAU, SLOPE)
    assert list(ids) == list(range(10))
    assert np.allclose(oH.sum(0), H3) and np.allclose(og.sum(0), g3)
    # drift-free rows: the iterated estimate stays within its noise of the one-step one
    sd = np.sqrt(np.diag(np.linalg.inv(H)))
    assert np.all(np.abs(-np.linalg.solve(H3, g3) + np.linalg.solve(H, g)) < 2 * sd)


def test_iterate_steps_is_validated():
    assert MonitorConfig().iterate_steps >= 0
    with pytest.raises(ValueError, match="iterate_steps"):
        MonitorConfig(iterate_steps=-1)
    with pytest.raises(ValueError, match="iterate_steps"):
        MonitorConfig(iterate_steps=11)
