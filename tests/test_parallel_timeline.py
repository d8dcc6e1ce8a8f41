"""``scripts/parallel_timeline.py`` (issue 29, session 11): the summary of a calibration's timeline
with several workers, on crafted events and tasks (no calibration: the script's instrumentation
wraps module attributes, which a test process must not do)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _mod():
    spec = importlib.util.spec_from_file_location("parallel_timeline", ROOT / "scripts" / "parallel_timeline.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _ev(t, th, kind, name, thread_cpu, **kw):
    return dict(t=t, th=th, kind=kind, name=name, thread_cpu=thread_cpu, cpu=0.0, **kw)


def test_summary_of_a_crafted_timeline():
    m = _mod()
    events = [
        _ev(0.0, "MainThread", "calib", "start", 0.0),
        _ev(0.1, "MainThread", "enter", "prepare_frames", 0.05),
        _ev(0.2, "MainThread", "pool", "start", 0.06),
        _ev(0.3, "MainThread", "pool", "started", 0.07),
        _ev(0.6, "MainThread", "exit", "prepare_frames", 0.10),
        _ev(0.7, "MainThread", "enter", "_misfit", 0.11),
        _ev(0.75, "xcalib-deferred_0", "submit", "_solve_job", 0.02),
        _ev(0.95, "xcalib-deferred_0", "submit", "_solve_job", 0.12),
        _ev(0.96, "xcalib-deferred_0", "thread", "_second_pose", 0.13, thread_total_cpu=0.13),
        _ev(1.2, "MainThread", "enter", "match_all", 0.13),  # nested in _misfit: not a stage of its own
        _ev(1.3, "MainThread", "exit", "match_all", 0.14),
        _ev(1.5, "MainThread", "exit", "_misfit", 0.15),
        _ev(1.6, "MainThread", "calib", "end", 0.16),
    ]
    tasks = [(11, "_solve_job", 0.8, 1.0, 0.15), (12, "_solve_job", 0.8, 0.9, 0.05), (11, "_quick_refine", 1.0, 1.4, 0.3)]
    s = m.summarise(events, tasks, wall=1.6, parent_cpu=0.4, children_cpu=0.6)
    assert s["parent_cpu_by_thread_s"]["main"] == pytest.approx(0.16)
    assert s["parent_cpu_by_thread_s"]["searches"] == pytest.approx(0.11)  # between its first and last event
    assert s["search_threads_cpu_s"] == {"_second_pose": 0.13}
    assert s["pool_start_wall_s"] == pytest.approx(0.1)
    assert set(s["main_stages"]) == {"prepare_frames", "_misfit"}
    assert s["main_stages"]["_misfit"]["wall_s"] == pytest.approx(0.8)
    assert s["main_stages"]["_misfit"]["main_thread_cpu_s"] == pytest.approx(0.04)
    assert s["misfit_wall_s"] == pytest.approx(0.8)
    assert s["tasks"]["_solve_job"] == {"n": 2, "cpu_s": pytest.approx(0.2), "largest_cpu_s": 0.15}
    assert s["task_cpu_s"] == pytest.approx(0.5)
    assert s["worker_busy_share"] == pytest.approx((0.2 + 0.1 + 0.4) / (1.6 * 2))
