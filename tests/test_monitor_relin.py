"""The re-linearised window test (``MonitorConfig.relinearise_band``) and the benchmark's
accounting of it (``bench_monitor._alarm_frames``, ``bound_verdict``)."""

from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from xcalib.calib.result import CalibrationResult
from xcalib.data.synth import iter_frames, sample_site
from xcalib.monitor import Monitor, MonitorConfig
from xcalib.monitor.inject import inject_change

BENCH = Path(__file__).resolve().parents[1] / "benchmarks"
K0 = 250


@pytest.fixture(scope="module")
def bench():
    if str(BENCH) not in sys.path:
        sys.path.insert(0, str(BENCH))
    import bench_monitor

    return bench_monitor


@pytest.fixture(scope="module")
def z_step():
    """Site 11, 330 frames, a 10 cm shift along the camera's z axis from frame 250."""
    site = sample_site(11, n_objects=(15, 30))
    frames = [replace(f, bboxes_3d=np.asarray(f.meta["box7"], dtype=np.float32))
              for f in iter_frames(site, 137 + 330, 0, render_images=False, lidar=False)][137:]
    T = site.T_cam_lidar
    cal = CalibrationResult(success=True, intrinsics=site.intrinsics_given, rotation=T[:3, :3], translation=T[:3, 3],
                            rotation_std_deg=np.full(3, 0.05), translation_std_m=np.full(3, 0.02),
                            camera_name=site.camera_name, image_size=(site.width, site.height))
    moved = [inject_change(f, cal, np.zeros(3), np.array([0.0, 0.0, 0.10])) if i >= K0 else f
             for i, f in enumerate(frames)]
    return cal, moved


def _monitor(cal, frames, **cfg):
    mon = Monitor(cal, MonitorConfig(**cfg))
    states = [(st.frame, st.state, round(st.statistic, 9)) for f in frames for st in mon.update(f)]
    return mon, next(iter(mon.cameras.values())), states


@pytest.mark.parametrize("kw", [{"relinearise_band": 1.0}, {"relinearise_band": -0.1},
                                {"relinearise_factor": 0.9}, {"relinearise_windows": 0}])
def test_config_rejects_bad_settings(kw):
    with pytest.raises(ValueError, match="relinearise"):
        MonitorConfig(**kw)


def test_recording_only_leaves_the_decisions_alone_and_off_records_nothing(z_step):
    cal, frames = z_step
    _, cm_off, off = _monitor(cal, frames)
    _, cm_rec, rec = _monitor(cal, frames, relinearise_band=0.4, relinearise_factor=1e6)
    assert len(cm_off.relin_trace) == 0
    # re-linearising copies of the window changes nothing the monitor keeps
    assert rec == off
    after = [t for t in cm_rec.relin_trace if t[0] - 1 >= K0]
    assert after, "the step's windows reach the band"
    # the shaping's pull towards the calibration removed: the step's statistic grows
    assert np.median([t[3] / t[2] for t in after]) > 1.2
    assert all(t[2] >= 0.4 * cm_rec.h for t in cm_rec.relin_trace)


def test_relinearised_test_alarms_earlier_at_the_plain_threshold(z_step):
    cal, frames = z_step
    _, cm_off, _ = _monitor(cal, frames)
    _, cm_on, _ = _monitor(cal, frames, relinearise_band=0.4, relinearise_factor=1.0)
    assert cm_on.events, "detected"
    ev = cm_on.events[0]
    assert ev.detected_frame >= K0  # no alarm before the change
    assert not cm_off.events or ev.detected_frame < cm_off.events[0].detected_frame
    assert ev.statistic > cm_on.h
    assert ev.step[5] > 0.05  # the shift along z, estimated at the detection


def test_alarm_frames_merge_and_threshold(bench):
    q = {"alarm_frames": [500], "threshold": 10.0,
         "relin": [(101, 20, 8.0, 15.0), (151, 20, 9.0, 25.0), (400, 40, 9.0, 19.0), (520, 40, 9.0, 30.0)]}
    assert bench._alarm_frames(q, None) == [500]
    assert bench._alarm_frames(q, 2.0) == [150, 500]  # 520 is the alarm at 500; 25 > 20 at 150
    assert bench._alarm_frames(q, 1.0) == [100, 399, 500]  # 150 within RELIN_GAP of 100


def test_bound_verdict(bench):
    row = {"efficient": {"tz_0.1_within_50": {"power_6dof": 0.89, "power_oracle_1dof": 0.98, "crb_sigma_median": 0.02}},
           "sequential": {"tz_0.1_within_50": {"fixed": 0.64}}}
    assert bench.bound_verdict(row, 0.12, "tz_0.1_within_50", 8)["verdict"] == "impossible"
    row["efficient"]["tz_0.1_within_50"]["power_6dof"] = 0.999
    v = bench.bound_verdict(row, 0.38, "tz_0.1_within_50", 8)
    assert v["verdict"] == "possible" and v["bound_fixed_windows_time_unknown"] == 0.64
    assert bench.bound_verdict(row, 1.0, "tz_0.1_within_50", 8)["verdict"] == "detected"
    assert bench.bound_verdict({}, 1.0, "tz_0.1_within_50", 8)["verdict"] == "unknown"


def test_verdicts_table_counts_each_site(bench):
    eff = {"tz_0.1_within_50": {"power_6dof": 0.999, "power_oracle_1dof": 1.0, "crb_sigma_median": 0.01}}
    seq = {"tz_0.1_within_50": {"fixed": 0.99}}
    step = {"size": 0.1, "within": 50, "runs": 8}
    prev = {"bound_s8": {"site_3": {"efficient": eff, "sequential": seq, "monitor_steps": [{**step, "detected_within": 0.375}]},
                         "site_5": {"efficient": {"tz_0.1_within_50": {**eff["tz_0.1_within_50"], "power_6dof": 0.5}},
                                    "sequential": seq, "monitor_steps": [{**step, "detected_within": 0.125}]},
                         "a9": {}},
            "relin_s9": {"steps": {"site_3_tz_0.1_within_50": {"bound": bench.bound_verdict(
                {"efficient": eff, "sequential": seq}, 1.0, "tz_0.1_within_50", 8)}}}}
    out = bench._verdicts(prev, lambda *a, **k: None)
    assert out["cells"]["site_3_tz_0.1_within_50"]["verdict"] == "detected"  # the later run wins
    assert out["cells"]["site_5_tz_0.1_within_50"]["verdict"] == "impossible"
    assert out["counts"]["tz_0.1_within_50"] == {"detected": 1, "possible": 0, "impossible": 1, "unknown": 0}
