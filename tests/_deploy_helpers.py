"""Helpers of the deployment tests: seeded "loaded" matchers and a crowded frame."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def loaded_matcher(model: str, tmp: Path, seed: int = 0, **config):
    """A matcher with seeded random weights written and loaded back (so it counts as loaded)."""
    import torch

    from xcalib.engine.matcher import Matcher

    torch.manual_seed(seed)
    m = Matcher(model, config or None, device="cpu", allow_random=True)
    m.save_pretrained(tmp)
    return Matcher.from_pretrained(model, weights=tmp, device="cpu")


def crowded_frame(n: int = 80, seed: int = 0):
    """(image [1080,1920,3] uint8, points [P,3], bboxes_2d [n,4], bboxes_3d [n,6] extents): n
    detections per side with distinct centres and points inside every 3D box."""
    rng = np.random.default_rng(seed)
    image = rng.integers(0, 255, (1080, 1920, 3), dtype=np.uint8)
    xy = np.stack([rng.uniform(0, 1800, n), rng.uniform(0, 1000, n)], 1)
    b2 = np.hstack([xy, xy + rng.uniform(20, 120, (n, 2))]).astype(np.float32)
    ctr = np.stack([rng.uniform(5, 80, n), rng.uniform(-30, 30, n), rng.uniform(-1, 1, n)], 1)
    dims = np.stack([rng.uniform(1.5, 5, n), rng.uniform(1.5, 2.5, n), rng.uniform(1.4, 2.0, n)], 1)
    b3 = np.hstack([ctr - dims / 2, ctr + dims / 2]).astype(np.float32)
    k = 40
    pts = (ctr[:, None] + rng.uniform(-0.45, 0.45, (n, k, 3)) * dims[:, None]).reshape(-1, 3).astype(np.float32)
    return image, pts, b2, b3
