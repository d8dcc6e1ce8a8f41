"""Matching metrics: Top-1 / Top-3 / MRR per detection and per frame, latency statistics.

Only camera detections (rows) with at least one positive in the ground truth count. A row's
rank is 1 + the number of negatives scoring >= its best positive (ties count against the
model, so a constant scorer gets no credit). Per-detection values are micro-averaged over all
counted rows; per-frame values average each frame's mean over frames with a counted row.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

__all__ = ["row_ranks", "latency_stats", "MatchingMetrics", "MetricsAccumulator"]


def row_ranks(scores: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """Rank (1-based) of the best positive of every row that has one; [R] int64."""
    s = np.asarray(scores, dtype=np.float64)
    g = np.asarray(gt, dtype=bool)
    if s.shape != g.shape:
        raise ValueError(f"scores {s.shape} and ground truth {g.shape} must have the same [N, M] shape")
    rows = g.any(axis=1)
    if not rows.any():
        return np.zeros(0, dtype=np.int64)
    s, g = s[rows], g[rows]
    best = np.where(g, s, -np.inf).max(axis=1)
    return 1 + ((s >= best[:, None]) & ~g).sum(axis=1).astype(np.int64)


def latency_stats(ms) -> dict[str, float]:
    a = np.asarray(list(ms), dtype=np.float64)
    if a.size == 0:
        return {}
    mean = float(a.mean())
    return {"latency_ms_mean": mean, "latency_ms_p50": float(np.percentile(a, 50)),
            "latency_ms_p95": float(np.percentile(a, 95)), "latency_ms_p99": float(np.percentile(a, 99)),
            "latency_ms_std": float(a.std()), "latency_ms_min": float(a.min()), "latency_ms_max": float(a.max()),
            "throughput_fps_mean": 1000.0 / mean if mean > 0 else float("inf"), "n_iters": int(a.size)}


@dataclass
class MatchingMetrics:
    top1: float = 0.0
    top3: float = 0.0
    mrr: float = 0.0
    frame_top1: float = 0.0
    frame_top3: float = 0.0
    frame_mrr: float = 0.0
    n_frames: int = 0
    n_cameras_with_match: int = 0
    latency: dict[str, float] = field(default_factory=dict)

    def to_dict(self) -> dict:
        d = asdict(self)
        lat = d.pop("latency")
        d.update(lat)
        return d


class MetricsAccumulator:
    """Add frames one by one (``add(scores, gt, latency_ms)``); ``result()`` -> MatchingMetrics.
    ``sums()`` / ``from_sums`` let distributed ranks reduce their counts."""

    def __init__(self) -> None:
        self.ranks: list[np.ndarray] = []
        self.latencies: list[float] = []
        self.n_frames = 0

    def add(self, scores: np.ndarray, gt: np.ndarray, latency_ms: float | None = None) -> None:
        r = row_ranks(scores, gt)
        self.n_frames += 1
        if len(r):
            self.ranks.append(r)
        if latency_ms is not None and np.size(scores):
            self.latencies.append(float(latency_ms))

    def sums(self) -> np.ndarray:
        """[n_rows, hit1, hit3, rr, n_frames_counted, f_hit1, f_hit3, f_rr, n_frames]."""
        out = np.zeros(9, dtype=np.float64)
        for r in self.ranks:
            out[:4] += [len(r), (r == 1).sum(), (r <= 3).sum(), (1.0 / r).sum()]
            out[4:8] += [1, (r == 1).mean(), (r <= 3).mean(), (1.0 / r).mean()]
        out[8] = self.n_frames
        return out

    @staticmethod
    def from_sums(s: np.ndarray, latencies=()) -> MatchingMetrics:
        s = [float(v) for v in s]
        n, nf = max(s[0], 1.0), max(s[4], 1.0)
        return MatchingMetrics(top1=s[1] / n, top3=s[2] / n, mrr=s[3] / n, frame_top1=s[5] / nf,
                               frame_top3=s[6] / nf, frame_mrr=s[7] / nf, n_frames=int(s[8]),
                               n_cameras_with_match=int(s[0]), latency=latency_stats(latencies))

    def result(self) -> MatchingMetrics:
        return self.from_sums(self.sums(), self.latencies)
