"""Crowded test frames shared by the dense-scene tests: a synthetic site's frames with random 2D and
3D boxes, prepared as the calibration prepares them."""
from __future__ import annotations

import numpy as np


def random_box_frames(n2: int, n3: int, n_frames: int):
    """CalibFrames of synthetic site 1 with ``n2`` random 2D and ``n3`` random 3D boxes in each of
    ``n_frames`` frames (seeded)."""
    from xcalib.calib.inputs import prepare_frames
    from xcalib.data.synth import generate_frames, sample_site
    from xcalib.types import Frame

    site = sample_site(1)
    frames = generate_frames(site, n_frames, seed=2, render_images=False, lidar=False)
    rng = np.random.default_rng(0)
    out = []
    for f in frames:
        x, y = rng.uniform(0, 1700, n2), rng.uniform(0, 1000, n2)
        w, h = rng.uniform(10, 200, n2), rng.uniform(10, 150, n2)
        b3 = np.column_stack([rng.uniform(-60, 60, (n3, 2)), np.zeros(n3), np.tile([4.5, 1.9, 1.6], (n3, 1)),
                              rng.uniform(-3, 3, n3)])
        out.append(Frame(**{**f.__dict__, "bboxes_2d": np.column_stack([x, y, x + w, y + h]), "bboxes_3d": b3}))
    return prepare_frames(out, site.intrinsics)[0]
