"""The change test's spread from the objects (``MonitorConfig.difference_quantile``,
``xcalib.monitor.spread``): the object-clustered spread of two segments' difference against the
stated one, and the monitor and its offline replay using it alike."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
from _monitor_helpers import turned_stream

from xcalib.monitor import MonitorConfig
from xcalib.monitor.spread import difference_ratio

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))


def _segment(rng, J, errors, fresh):
    """Per object (ids, H [K,6,6], g [K,6]) of a linear model whose residuals are the object's
    persistent error plus fresh unit noise per row; the segment's estimate and its stated
    covariance (H^-1 times the residual mean square, as ``_Sums.fit``)."""
    H_k = np.einsum("kri,krj->kij", J, J)
    r = errors[:, None] * np.ones(J.shape[1])[None] + fresh * rng.standard_normal(J.shape[:2])
    g_k = np.einsum("kri,kr->ki", J, r)
    H, g = H_k.sum(0), g_k.sum(0)
    x = -np.linalg.solve(H, g)
    rss = float(np.sum(r * r) + x @ g)
    s2 = max(rss / (J.shape[0] * J.shape[1] - 6), 1.0)
    return (np.arange(len(J)), H_k, g_k), x, np.linalg.inv(H) * s2


def _ratio(seed, persistent, fresh, shared=True):
    rng = np.random.default_rng(seed)
    K, rows = 60, 24
    Ja = rng.normal(size=(K, rows, 6))
    Jb = Ja + 0.1 * rng.normal(size=(K, rows, 6)) if shared else rng.normal(size=(K, rows, 6))  # seen again
    e = persistent * rng.standard_normal(K)
    ea = e if shared else persistent * rng.standard_normal(K)
    sa, xa, ca = _segment(rng, Ja, ea, fresh)
    sb, xb, cb = _segment(rng, Jb, e, fresh)
    return difference_ratio(sa, sb, xa, xb, ca + cb)


def test_the_spread_is_the_stated_one_where_the_errors_are_fresh():
    """Fresh unit noise only (the stated covariance is right, s2 ~ 1): the ratio is about 1, on
    average over seeds (it must not narrow what the frames state truly)."""
    r = [_ratio(s, 0.0, 1.0) for s in range(20)]
    assert all(np.isfinite(r))
    assert 0.8 < float(np.mean(r)) < 1.2


def test_a_persistent_error_shared_by_both_segments_cancels():
    """Each object, seen again from nearly the same place, keeps its error across the boundary (3
    times the fresh noise): the stated covariance (s2 ~ 10) is far wider than the difference's
    spread, which the ratio finds (< 0.3); other objects with errors as large on each side do not
    cancel (ratio well above)."""
    shared = [_ratio(s, 3.0, 1.0, shared=True) for s in range(10)]
    fresh = [_ratio(s, 3.0, 1.0, shared=False) for s in range(10)]
    assert float(np.mean(shared)) < 0.3
    assert float(np.mean(fresh)) > 2.0 * float(np.mean(shared))


def test_degenerate_input_gives_nan():
    empty = (np.zeros(0, dtype=np.int64), np.zeros((0, 6, 6)), np.zeros((0, 6)))
    one = (np.array([1]), np.eye(6)[None], np.zeros((1, 6)))
    assert np.isnan(difference_ratio(empty, one, np.zeros(6), np.zeros(6), np.eye(6)))


def test_settings_are_validated():
    assert MonitorConfig().difference_quantile == 0.0
    with pytest.raises(ValueError, match="difference_quantile"):
        MonitorConfig(difference_quantile=1.0)
    with pytest.raises(ValueError, match="difference_quantile"):
        MonitorConfig(difference_quantile=-0.1)


def test_replay_raises_the_monitors_alarms_with_the_spread(monkeypatch):
    """The monitor and ``monitor_persistence.replay`` with ``difference_quantile`` raise the same
    alarms on a stream with a 0.3 deg turn; the scale is in use (the pool is filled early here) and
    below 1 on this site, so the change test's covariance differs from the default's."""
    import monitor_persistence as mp

    from xcalib.monitor import Monitor
    from xcalib.monitor import core

    monkeypatch.setattr(core, "DIFF_MIN_SAMPLES", 3)
    cal, frames = turned_stream()
    cfg = MonitorConfig(latch=False, difference_quantile=0.9)
    mon = Monitor(cal, cfg)
    for f in frames:
        mon.update(f)
    cm = next(iter(mon.cameras.values()))
    alarms = [int(e.detected_frame) for e in cm.events]
    assert alarms and alarms[0] >= 90
    pools = {L: np.asarray(p) for L, p in cm._dratios.items()}
    assert pools and min(float(np.quantile(p, 0.9)) for p in pools.values()) < 1.0
    rec = mp.collect(cal, frames)
    got = mp.replay(_as_loaded(mp, rec, cfg), config=cfg)
    assert got == alarms


def _as_loaded(mp, rec, cfg):
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "rec.npz"
        mp.save_recording(path, rec)
        return mp.load_recording(path)


def test_untracked_pairs_keep_the_stated_covariance():
    """Pairs without track ids (< 0: each its own cluster, the persistence of a box's error unseen) are not
    clustered: above UNTRACKED_MAX of them the test keeps the stated covariance (no table)."""
    from xcalib.monitor import core
    from xcalib.monitor.spread import UNTRACKED_MAX, tracked

    assert tracked(np.array([1, 2, 3, -1] + [4] * 20)) and not tracked(np.array([-1, -2, -3, 4]))
    assert not tracked(np.zeros(0, dtype=np.int64)) and UNTRACKED_MAX < 0.5

    class _R:  # a frame's matched pairs as the monitor keeps them
        def __init__(self, ids):
            self.obj = np.asarray(ids)
            self.obj_H = np.tile(np.eye(6), (len(ids), 1, 1))
            self.obj_g = np.zeros((len(ids), 6))

    assert core._share_table([_R([-1, -2]), _R([-3, -4])], [1]) is None
    t = core._share_table([_R([1, 2]), _R([2, 3])], [1])
    after, before = t.split(1)
    assert list(after[0]) == [0, 1, 2] and np.allclose(after[1][:, 0, 0], [0, 1, 1])
    assert np.allclose(before[1][:, 0, 0], [1, 1, 0])
