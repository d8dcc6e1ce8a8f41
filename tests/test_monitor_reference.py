"""The change test calibrated per axis and window length from the stream's own drift-free
decisions (``CameraMonitor.axis_factors``) and from a reference stretch (``Monitor.learn``)."""

from __future__ import annotations

from collections import deque
from dataclasses import replace

import numpy as np
import pytest

from xcalib.calib.result import CalibrationResult
from xcalib.data.synth import iter_frames, sample_site
from xcalib.monitor import Monitor, MonitorConfig
from xcalib.monitor.core import MIN_AXIS_FACTOR
from xcalib.monitor.stats import variance_upper


@pytest.fixture(scope="module")
def stream():
    site = sample_site(3, n_objects=(15, 30))
    frames = [replace(f, bboxes_3d=np.asarray(f.meta["box7"], dtype=np.float32))
              for f in iter_frames(site, 150, 0, render_images=False, lidar=False)]
    T = site.T_cam_lidar
    cal = CalibrationResult(success=True, intrinsics=site.intrinsics_given, rotation=T[:3, :3], translation=T[:3, 3],
                            rotation_std_deg=np.full(3, 0.05), translation_std_m=np.full(3, 0.02),
                            camera_name=site.camera_name, image_size=(site.width, site.height))
    return cal, frames


def test_variance_upper_bound_is_wider_with_fewer_samples():
    ups = [float(variance_upper(np.array([m]), m, 0.9)[0]) for m in (12, 30, 100, 1000)]
    assert ups[0] > ups[1] > ups[2] > ups[3] > 1.0  # a mean square of 1 from few samples: a wider factor
    assert ups[0] > 1.5 and ups[3] < 1.1
    assert float(variance_upper(np.array([60.0]), 30, 0.5)[0]) == pytest.approx(2.0, rel=0.03)


def test_axis_factors_follow_each_axis_spread_and_wait_for_enough_samples(stream):
    cal, _ = stream
    cm = next(iter(Monitor(cal, MonitorConfig(reference_samples=20)).cameras.values()))
    rng = np.random.default_rng(7)
    true = np.array([1.0, 0.4, 0.5, 0.45, 1.0, 0.55])  # stated / empirical variance 1 .. 2.5 (one site's axes)
    z2 = rng.standard_normal((400, 6)) ** 2 * true
    cm._zs[20] = deque(z2[:19], maxlen=400)
    assert cm.axis_factors(20) is None  # too few samples: the single inflation holds
    cm._zs[20] = deque(z2, maxlen=400)
    f = cm.axis_factors(20)
    assert f is not None and np.all(f >= true * 0.95) and np.all(f <= true * 1.35)  # an upper bound, close
    assert f[1] < f[0] and f[3] < f[4]  # per axis, not one scale
    cm._zs[20] = deque(z2 * 0.01, maxlen=400)
    assert np.all(cm.axis_factors(20) == MIN_AXIS_FACTOR)  # never below the floor
    for cfg in (MonitorConfig(reference_samples=0), MonitorConfig()):  # off, and off by default
        off = next(iter(Monitor(cal, cfg).cameras.values()))
        off._zs[20] = deque(z2, maxlen=400)
        assert off.axis_factors(20) is None


def test_learn_measures_the_reference_and_starts_afresh(stream):
    cal, frames = stream
    mon = Monitor(cal, MonitorConfig(reference_samples=4))
    summ = mon.learn(frames[:150])
    (name, s), = summ.items()
    assert s["alarms"] == 0 and s["window_20"]["samples"] >= 4
    f = s["window_20"]["variance_factors"]
    assert f is not None and set(f) == {"rx", "ry", "rz", "tx", "ty", "tz"}
    assert all(np.isfinite(v) and v >= MIN_AXIS_FACTOR for v in f.values())
    cm = mon.cameras[name]
    assert mon.n_frames == 0 and cm.n_seen == 0 and len(cm.recs) == 0 and cm.last_time is None
    assert cm.events == [] and sum(cm.statuses_seen.values()) == 0
    assert cm.axis_factors(20) is not None  # kept across the restart
    # the stream goes on from its own start (times before the reference's end are accepted again)
    states = [st.state for st in mon.run(frames[:60])]
    assert states and "drift" not in states


def test_reference_settings_are_validated():
    with pytest.raises(ValueError, match="reference_samples"):
        MonitorConfig(reference_samples=-1)
    with pytest.raises(ValueError, match="reference_confidence"):
        MonitorConfig(reference_confidence=1.0)


def test_cli_reference_calibrates_before_monitoring(tmp_path, stream, capsys):
    import json

    from xcalib.cli import main
    from xcalib.io.frames import write_frame_folder

    cal, frames = stream
    small = [replace(f, image=np.zeros((1, 1, 3), np.uint8)) for f in frames[:100]]
    write_frame_folder(tmp_path / "ref", small[:100], pcd_encoding="binary")
    write_frame_folder(tmp_path / "live", small[:40], pcd_encoding="binary")
    cal.save(tmp_path / "cal.json")
    out = tmp_path / "watch"
    rc = main(["monitor", str(tmp_path / "live"), "--calibration", str(tmp_path / "cal.json"), "--reference",
               str(tmp_path / "ref"), "--out", str(out)])
    assert rc == 0
    ref = json.loads((out / "summary.json").read_text())["reference"]
    (cam, q), = ref["cameras"].items()
    assert ref["source"].endswith("ref") and q["alarms"] == 0 and q["window_20"]["samples"] >= 3
    assert q["window_20"]["variance_factors"] is None  # fewer than reference_samples (12): the prior holds
