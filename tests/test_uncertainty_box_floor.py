"""The box-model floor is the expected error of the outline choice (issue 26, session 6): a pose found
with the point hulls is off by the whole shift to the corners when the corners are right (probability
w), so the floor is sqrt(w) x |shift| -- not half of it, and w not capped at 1/2."""

from __future__ import annotations

import numpy as np
import pytest

import xcalib.calib.uncertainty as U
from xcalib.calib.context import FitContext
from xcalib.calib.pose import Pose


@pytest.mark.parametrize("cost_alt", [93.0, 100.0, 216.0, 300.0])
def test_floor_is_sqrt_of_the_corners_weight_times_the_shift(monkeypatch, cost_alt):
    shift = np.array([0.08, -0.10, 0.06, 0.036, -0.013, 0.009])
    monkeypatch.setattr(U, "_box_model_fits", lambda *a, **k: (shift, 100.0, cost_alt))
    ctx = FitContext([], [np.zeros((40, 2), np.int64)], None, Pose(np.eye(3), np.zeros(3)))
    floor, info = U.box_model_floor(ctx, n_objects=10)
    w = U.box_model_odds(100.0, cost_alt, 40, 10)
    assert info["weight_corners"] == pytest.approx(w)
    np.testing.assert_allclose(floor, np.sqrt(w) * np.abs(shift), rtol=1e-12)
    if cost_alt < 100.0:  # the corners fit better: more than the old cap of half the shift
        assert np.all(floor > 0.71 * np.abs(shift))


def test_no_floor_when_every_outline_is_its_box(monkeypatch):
    monkeypatch.setattr(U, "_box_model_fits", lambda *a, **k: None)
    ctx = FitContext([], [], None, Pose(np.eye(3), np.zeros(3)))
    assert U.box_model_floor(ctx, n_objects=3) == (None, {})
