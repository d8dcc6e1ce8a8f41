"""Evaluate a ``Matcher`` on labelled frames (Top-1 / Top-3 / MRR, latency) -> report dicts.

Dropped detections count: a camera detection with a ground-truth match that the matcher had to
drop (degenerate box, empty crop) is scored as a miss, not skipped.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Callable, Iterable

import numpy as np

from .metrics import MatchingMetrics, MetricsAccumulator

__all__ = ["evaluate_matcher", "report_entry", "REPORT_SCHEMA"]

REPORT_SCHEMA = "xcalib_validation/v1"


def evaluate_matcher(matcher, frames: Iterable, *, limit: int | None = None, validate: str = "off",
                     progress: Callable[[int], None] | None = None) -> tuple[MatchingMetrics, float]:
    """(metrics, wall seconds) over frames that carry a ``match_matrix``; latency = ``match`` time."""
    acc = MetricsAccumulator()
    t0 = time.perf_counter()
    for i, f in enumerate(frames):
        if limit is not None and i >= limit:
            break
        if f.match_matrix is None:
            continue
        r = matcher.match_frame(f, validate=validate, geometry="off")  # the model's own scores
        full = r.full_similarity(f.num_2d, f.num_3d, fill=-np.inf)
        fill = getattr(getattr(matcher, "model", None), "fill_value", getattr(matcher, "fill_value", None))
        if fill is not None:
            full[full == fill] = -np.inf
        acc.add(full, np.asarray(f.match_matrix, dtype=bool), r.latency_ms)
        if progress is not None:
            progress(i + 1)
    return acc.result(), time.perf_counter() - t0


def report_entry(metrics: MatchingMetrics, wall_s: float) -> dict:
    """One model's entry of the validation report (the reference's keys plus per-frame values)."""
    d = metrics.to_dict()
    d["wall_seconds"] = float(wall_s)
    return d


def portable_path(p) -> str:
    try:
        return str(Path(p).resolve().relative_to(Path.cwd()))
    except ValueError:
        return str(p)
