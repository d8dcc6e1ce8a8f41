"""``scripts/few_frames_audit.py`` (issue 25, session 11): its pose classes, its table and its sparse
recordings (1-2 objects per frame, detector outlines keep their object ids), without calibrating."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def _script():
    spec = importlib.util.spec_from_file_location("few_frames_audit", ROOT / "scripts" / "few_frames_audit.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_pose_classes_and_table(capsys):
    m = _script()
    assert m.pose_class(None) == "no pose"
    assert m.pose_class([0.3, 0.2]) == "right" and m.pose_class([0.31, 0.1]) == "within line"
    assert m.pose_class([0.2, 0.51]) == "WRONG" and m.pose_class([1.01, 0.0]) == "WRONG"
    recs = [{"condition": "c", "frames": 5, "verdict": "few_matches_per_half", "error": [0.1, 0.9],
             "without_guard": "ok", "error_without_guard": [0.1, 0.05]},
            {"condition": "c", "frames": 5, "verdict": "few_matches_per_half", "error": [0.1, 0.05],
             "without_guard": "ok", "error_without_guard": [0.1, 0.05]}]
    m.table(recs)
    assert "| c | 5 | few_matches_per_half | ok | right | 2 |" in capsys.readouterr().out


def test_sparse_recording_keeps_one_or_two_objects_per_frame_with_outlines():
    m = _script()
    frames, site = m.sparse_recording(0, 4, noisy_3d=False, outline=True)
    assert len(frames) == 4 and all(f.match_matrix is None and f.extrinsics is None for f in frames)
    shared = [len(set(np.asarray(f.meta["ids_2d"])[np.asarray(f.meta["ids_2d"]) >= 0])
                  & set(np.asarray(f.meta["ids_3d"]))) for f in frames]
    assert all(1 <= s <= 2 for s in shared if s) and sum(shared) >= 4


def test_coverage_summary_counts_axes_within_two_sigma(capsys):
    m = _script()
    lo, hi = m.clopper_pearson(9, 10)
    assert 0.55 < lo < 0.56 and 0.997 < hi < 0.998  # the exact binomial interval
    assert m.clopper_pearson(0, 5)[0] == 0.0 and m.clopper_pearson(5, 5)[1] == 1.0
    sd = [0.1, 0.1, 0.1, 0.05, 0.05, 0.05]
    recs = [{"condition": "noisy", "frames": 8, "seed": s, "verdict": "ok", "n_pairs": 12, "sigma": sd,
             "delta": [0.1, 0.0, 0.0, 0.0, 0.0, 0.3 if s == 0 else 0.01], "parts": {"jacobian": sd}}
            for s in range(4)]
    recs.append({**recs[0], "parts": {"jacobian": sd, "centre_model": [0.1, 0.1, 0.1, 0.05, 0.05, 0.2]}})
    one = m._dedupe(recs)
    assert len(one) == 4 and one[0]["parts"].get("centre_model") is not None  # the record with the part wins
    m.coverage_summary(one)
    out = capsys.readouterr().out
    assert "2-sigma per-axis coverage 23/24 = 0.958" in out  # seed 0's tz: 0.3 m against 2 x 0.05 m
    assert "0 wrong successes" in out and "max(sigma, centre_model)" not in out  # 0.3 m is within the line;
    # the floor needs the part on every record
