"""The drift monitor's change test replayed offline with its leave-objects-out guard
(``benchmarks/monitor_persistence.py``: ``replay``, ``save_recording`` / ``load_recording``): it
raises the alarms the monitor raises, on the same frames, under the settings it is given."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
from _monitor_helpers import turned_stream

from xcalib.monitor import Monitor, MonitorConfig

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """A site's stream with a 0.3 deg turn about x from frame 90, its calibration and its recording
    (the monitor that cannot alarm), saved and read back."""
    import monitor_persistence as mp

    cal, frames = turned_stream()
    path = tmp_path_factory.mktemp("rec") / "rec.npz"
    mp.save_recording(path, mp.collect(cal, frames))
    return cal, frames, mp.load_recording(path)


@pytest.mark.parametrize("settings", [{}, {"min_inflation": 0.5, "leave_out_objects": 4},
                                      {"min_inflation": 0.25, "leave_out_objects": 0}, {"iterate_steps": 3},
                                      {"change_point_step": 5}])
def test_replay_raises_the_monitors_alarms(recorded, settings):
    import monitor_persistence as mp

    cal, frames, rec = recorded
    mon = Monitor(cal, MonitorConfig(latch=False, **settings))
    for f in frames:
        mon.update(f)
    alarms = [int(e.detected_frame) for e in next(iter(mon.cameras.values())).events]
    assert alarms and alarms[0] >= 90  # the turn is found, after it happened
    got = mp.replay(rec, floor=settings.get("min_inflation", 1.0), leave_out=settings.get("leave_out_objects"),
                    iterate=settings.get("iterate_steps", -1), config=MonitorConfig(latch=False, **settings))
    assert got == alarms
    if not settings:
        assert mp.replay(rec, first_only=True) == alarms[:1]


def test_the_guard_holds_a_change_one_object_carries():
    import monitor_persistence as mp

    n, k = 200, 8  # frames; objects per frame, each seen in every frame
    rng = np.random.default_rng(7)
    Hk = np.eye(6) * 1e4 / k
    obj_H = np.tile(Hk, (n * k, 1, 1))
    obj_g = rng.standard_normal((n * k, 6)) * np.sqrt(1e4 / k)  # x noise 1e-2 per frame and axis
    obj_id = np.tile(np.arange(k), n)
    obj_frame = np.repeat(np.arange(n), k)
    obj_g[(obj_frame >= 120) & (obj_id == 0)] -= Hk @ np.full(6, 0.25)  # object 0 alone moves from frame 120
    g = obj_g.reshape(n, k, 6).sum(1)
    rows = np.concatenate([np.tile((np.eye(6) * 1e4).ravel(), (n, 1)), g, np.full((n, 1), 24.0 * k),
                           np.full((n, 1), 24.0 * k), np.full((n, 1), float(k)), np.full((n, 1), float(k))], 1)
    rec = {"rows": rows, "cov_cal": np.eye(6) * 1e-8, "obj_frame": obj_frame, "obj_id": obj_id,
           "obj_H": obj_H, "obj_g": obj_g}
    unguarded = mp.replay(rec, leave_out=0, first_only=True)
    assert unguarded and 120 <= unguarded[0] < 160  # one object's move passes for the camera's ...
    assert mp.replay(rec, leave_out=1) == []  # ... but not without that object
    assert mp.replay(rec, leave_out=0, threshold=1e9) == []  # held to the threshold it is given
