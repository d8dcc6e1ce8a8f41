"""The TensorRT shape envelope (protocol v1.0 §5) and batch-axis chunking (pure numpy).

Every deployed graph has one dynamic batch axis: ``N`` (image detections), ``M`` (LiDAR
detections) or ``B`` (detection pairs). An engine built for the envelope accepts 1..max along
it, so a frame outside the envelope is run in chunks of at most ``max`` rows and the outputs are
concatenated. Per-detection and per-pair graphs have no interaction between rows, so the merged
result equals the unsplit one (up to float rounding of the kernels).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Mapping

import numpy as np

__all__ = ["Profile", "Envelope", "PROTOCOL_ENVELOPE", "chunk_slices", "run_chunked"]


@dataclass(frozen=True)
class Profile:
    """min / opt / max rows along a graph's dynamic axis."""

    min: int
    opt: int
    max: int

    def __post_init__(self) -> None:
        if not 1 <= self.min <= self.opt <= self.max:
            raise ValueError(f"profile must satisfy 1 <= min <= opt <= max, got {self.min}/{self.opt}/{self.max}")


@dataclass(frozen=True)
class Envelope:
    """Profiles per graph role: ``image`` (N), ``lidar`` (M), ``stage2`` (crlite pairs B =
    N*top_k) and ``pairwise`` (all pairs B = N*M, calibrefine / fastmatch)."""

    image: Profile = Profile(1, 8, 32)
    lidar: Profile = Profile(1, 12, 32)
    stage2: Profile = Profile(1, 80, 320)
    pairwise: Profile = Profile(1, 96, 1024)

    def profile(self, role: str) -> Profile:
        if role not in ("image", "lidar", "stage2", "pairwise"):
            raise ValueError(f"envelope role must be image, lidar, stage2 or pairwise, got {role!r}")
        return getattr(self, role)


PROTOCOL_ENVELOPE = Envelope()


def chunk_slices(n: int, max_rows: int | None) -> list[slice]:
    """Consecutive slices of at most ``max_rows`` covering ``range(n)`` (one slice when None)."""
    if max_rows is None or n <= max_rows:
        return [slice(0, n)]
    if max_rows < 1:
        raise ValueError(f"max_rows must be >= 1, got {max_rows}")
    return [slice(s, min(s + max_rows, n)) for s in range(0, n, max_rows)]


def run_chunked(fn: Callable[[dict[str, np.ndarray]], dict[str, np.ndarray]],
                feeds: Mapping[str, np.ndarray], max_rows: int | None) -> dict[str, np.ndarray]:
    """Call ``fn`` on row chunks of ``feeds`` (all sharing axis 0) and concatenate its outputs."""
    sizes = {k: len(v) for k, v in feeds.items()}
    if len(set(sizes.values())) > 1:
        raise ValueError(f"run_chunked: inputs must share their first axis, got {sizes}")
    n = next(iter(sizes.values()))
    if max_rows is None or n <= max_rows:  # one call on the feeds themselves
        return fn(dict(feeds))
    parts = [fn({k: v[s] for k, v in feeds.items()}) for s in chunk_slices(n, max_rows)]
    if len(parts) == 1:
        return parts[0]
    return {k: np.concatenate([p[k] for p in parts], axis=0) for k in parts[0]}
