"""Runtime-agnostic matching evaluation (torch-free): Top-1 / Top-3 / MRR of any matcher with
the ``match_frame`` API (torch ``Matcher`` or :class:`~xcalib.deploy.ort_runtime.OnnxMatcher`)
over frames with a ground-truth ``match_matrix`` (e.g. an HDF5 cache).

Each frame is matched with ``validate="off"``; its score matrix is compared with the ground
truth restricted to the kept detections (:mod:`xcalib.engine.metrics` conventions).
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable, Iterable

import numpy as np

from ..engine.metrics import MatchingMetrics, MetricsAccumulator
from ..types import Frame

__all__ = ["evaluate_frames", "evaluate_cache"]


def evaluate_frames(matcher, frames: Iterable[Frame], *, limit: int | None = None,
                    progress: Callable[[int], None] | None = None) -> MatchingMetrics:
    """Metrics of ``matcher`` over ``frames`` (frames without ``match_matrix`` are skipped)."""
    acc = MetricsAccumulator()
    n = 0
    for frame in frames:
        if limit is not None and n >= limit:
            break
        n += 1
        if frame.match_matrix is None:
            continue
        res = matcher.match_frame(frame, validate="off")
        gt = np.asarray(frame.match_matrix, dtype=bool)[np.ix_(res.kept_2d_indices, res.kept_3d_indices)]
        acc.add(res.similarity, gt, res.latency_ms)
        if progress is not None:
            progress(n)
    return acc.result()


def evaluate_cache(matcher, cache: str | Path, *, limit: int | None = None,
                   progress: Callable[[int], None] | None = None, **reader_kwargs) -> MatchingMetrics:
    """:func:`evaluate_frames` over an HDF5 cache (``xcalib.io.hdf5.CacheReader``)."""
    from ..io.hdf5 import CacheReader

    with CacheReader(cache, **reader_kwargs) as reader:
        return evaluate_frames(matcher, iter(reader), limit=limit, progress=progress)
