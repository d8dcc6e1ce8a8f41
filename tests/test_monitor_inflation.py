"""The floor of the adjacent-window inflation (``MonitorConfig.min_inflation``) and the
persistence measurement of the monitor's per-frame evidence (``benchmarks/monitor_persistence.py``)."""

from __future__ import annotations

import sys
from collections import deque
from pathlib import Path

import numpy as np
import pytest

from xcalib.calib.result import CalibrationResult
from xcalib.geometry.camera import CameraIntrinsics
from xcalib.monitor import Monitor, MonitorConfig
from xcalib.monitor.core import CHI2_6_Q75_OVER_6, INFLATION_PRIOR, MIN_DIFFS

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))


def _cal() -> CalibrationResult:
    K = CameraIntrinsics(fx=1200.0, fy=1200.0, cx=960.0, cy=540.0, width=1920, height=1080)
    return CalibrationResult(success=True, intrinsics=K, rotation=np.eye(3), translation=np.zeros(3),
                             rotation_std_deg=np.full(3, 0.05), translation_std_m=np.full(3, 0.02),
                             camera_name="cam", image_size=(1920, 1080))


def _camera(cfg: MonitorConfig):
    return next(iter(Monitor(_cal(), cfg).cameras.values()))


@pytest.mark.parametrize("level", [0.6, 1.4])
def test_inflation_follows_the_windows_disagreement_down_to_its_floor(level):
    rng = np.random.default_rng(3)
    diffs = rng.chisquare(6, 200) / 6 * level  # adjacent windows agreeing `level` times what they state
    low, default = _camera(MonitorConfig(min_inflation=0.5)), _camera(MonitorConfig())
    for cm in (low, default):
        cm._diffs = deque(diffs[:MIN_DIFFS - 1], maxlen=200)
        assert cm.inflation == INFLATION_PRIOR  # too few pairs: the prior
        cm._diffs = deque(diffs, maxlen=200)
    measured = float(np.quantile(diffs, 0.75)) / CHI2_6_Q75_OVER_6
    assert abs(measured - level) < 0.2 * level
    assert low.inflation == pytest.approx(max(0.5, measured))
    assert default.inflation == pytest.approx(max(1.0, measured))  # the default floor: never below what frames state
    if level < 1:
        assert low.inflation < 1.0 == default.inflation
    low._diffs = deque(diffs * 0.1, maxlen=200)
    assert low.inflation == 0.5  # never below the floor


@pytest.mark.parametrize("bad", [0.2, 1.5, float("nan")])
def test_min_inflation_is_validated(bad):
    with pytest.raises(ValueError, match="min_inflation"):
        MonitorConfig(min_inflation=bad)


def test_persistence_measure_sees_errors_that_last_and_not_independent_ones():
    import monitor_persistence as mp

    rng = np.random.default_rng(11)
    n = 800
    H = np.tile(np.eye(6) * 100.0, (n, 1, 1))  # each frame: unit information 100 per axis (sd 0.1)
    e = rng.standard_normal((n, 6)) * 0.1
    slow = np.repeat(rng.standard_normal((n // 40, 6)) * 0.1, 40, axis=0)  # the same error for 40 frames
    for errors, persists in ((e, False), (e + slow, True)):
        g = -np.einsum("nij,nj->ni", H, errors)  # x_k = -H^-1 g = the error
        d = {"H": H, "g": g, "c": np.full(n, 24.0), "n_res": np.full(n, 24), "objects": [(None, None, None)] * n,
             "inflation": [], "alarms": 0, "cpu_ms": 0.0}
        r = mp.block_var_ratio(d)
        grow = np.mean(list(r[80]["ratio"].values())) / np.mean(list(r[5]["ratio"].values()))
        lag1 = np.mean([v[0] for v in mp.acf(d).values()])
        if persists:
            assert grow > 4 and lag1 > 0.5  # the block variance grows with L; neighbouring blocks agree
        else:
            assert 0.5 < grow < 2 and abs(lag1) < 0.2


def test_replay_is_held_to_the_default_threshold_not_the_recorders():
    import monitor_persistence as mp

    rng = np.random.default_rng(5)
    n = 200
    H = np.tile(np.eye(6) * 1e4, (n, 1, 1))
    rows = np.concatenate([H.reshape(n, 36), rng.standard_normal((n, 6)) * 100.0,
                           np.full((n, 1), 24.0), np.full((n, 1), 24.0), np.full((n, 1), 30.0), np.zeros((n, 1))], 1)
    cov_cal = np.eye(6) * 1e-6
    dec = mp.decision_statistics(rows, cov_cal)
    assert len(dec) == (n - 20) // 5 + 1 and all(s >= 0 for _, s, _ in dec)
    h = MonitorConfig().threshold
    rows[120:, 36:42] += 2e4  # a step: x = -g / 1e4 = -2 per axis from frame 120
    first = mp.first_detection(rows, cov_cal, h)
    assert first is not None and 120 <= first < 140
    assert mp.first_detection(rows, cov_cal, MonitorConfig(false_alarm_rate=1e-12).threshold * 1e6) is None
