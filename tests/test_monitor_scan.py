"""The change-point scan of the drift monitor (``MonitorConfig.change_point_step``): its threshold from the
scan's simulated null distribution, and its settings."""

from __future__ import annotations

import pytest

from xcalib.monitor import MonitorConfig
from xcalib.monitor import stats


def test_scan_threshold_matches_the_union_bound_for_the_fixed_windows_and_rises_for_a_scan():
    fixed = stats.scan_threshold(1e-4, 5, 4, (20, 40, 80), 600)
    bound = stats.threshold(1e-4, 5, 4)
    # three windows of 20 / 40 / 80 frames barely overlap in information: the bound is nearly exact
    assert bound - 0.6 < fixed <= bound + 0.1
    scan = stats.scan_threshold(1e-4, 5, 4, tuple(range(10, 85, 5)), 600)
    # fifteen overlapping segments: higher than three tests, far lower than a union bound over fifteen
    assert fixed + 1.0 < scan < stats.threshold(1e-4, 5, 16)
    assert stats.scan_threshold(1e-4, 5, 4, tuple(range(10, 85, 5)), 600) == scan  # deterministic
    assert stats.scan_threshold(1e-5, 5, 4, tuple(range(10, 85, 5)), 600) > scan


def test_scan_settings():
    cfg = MonitorConfig(change_point_step=5)
    assert cfg.test_windows == tuple(range(10, 85, 5))
    assert MonitorConfig().test_windows == MonitorConfig().windows == (20, 40, 80)
    assert cfg.threshold > MonitorConfig().threshold
    for bad in (-1, 41):
        with pytest.raises(ValueError, match="change_point_step"):
            MonitorConfig(change_point_step=bad)
    with pytest.raises(ValueError, match="history"):
        stats.scan_threshold(1e-4, 5, 4, (20, 40, 80), 80)
