"""A long synthetic recording made on demand (issue 31, item 5): the boxes of a synthetic roadside
site (``xcalib.data.synth``) with, per frame, a LiDAR cloud of ``n_points`` (64 scan rings over
the ground and a far wall, plus returns on the 3D boxes' sides and tops) and a camera-sized image,
both made when the frame is asked for (seeded by the frame index), so nothing but the boxes is
held and nothing is on disk. Used by tests/test_stream.py and benchmarks/bench_calibration_memory.py.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import numpy as np


def _rings(n: int) -> int:
    """Scan rings of a cloud of ``n`` returns: an azimuth step about a tenth of the ring spacing
    (as a spinning LiDAR's), so the scan-step estimate finds both."""
    return int(np.clip(np.sqrt(n / 90.0), 16, 256))


class LongRecording(Sequence):
    """``n_frames`` frames of one camera; ``yawless``: 3D boxes as protocol [M,6] boxes with no
    yaw (the calibration re-estimates it from the points and outlines them by point hulls)."""

    def __init__(self, n_frames: int, n_points: int, seed: int = 0, *, yawless: bool = False, image: bool = True):
        from xcalib.data.synth import sample_site
        from xcalib.data.synth.generate import iter_frames

        self.site = sample_site(seed, preset="roadside")
        self.intrinsics = self.site.intrinsics
        self.n_points, self.seed, self.with_image = int(n_points), int(seed), image
        self._frames, self._box7 = [], []
        empty = np.zeros((0, 0, 3), np.uint8)
        for f in iter_frames(self.site, n_frames, seed, render_images=False, lidar=False):
            b7 = np.asarray(f.meta["box7"], dtype=np.float64)
            meta = {k: v for k, v in f.meta.items() if not (yawless and k.startswith("box7"))}
            self._box7.append(b7)
            self._frames.append(replace(f, image=empty, point_cloud=np.zeros((0, 3), np.float32), meta=meta))
        b = np.concatenate(self._box7) if self._box7 else np.zeros((0, 7))
        self.ground_z = float(np.median(b[:, 2] - b[:, 5] / 2)) if len(b) else -5.0

    def __len__(self) -> int:
        return len(self._frames)

    def __getitem__(self, index):
        if isinstance(index, slice):
            return [self[i] for i in range(*index.indices(len(self)))]
        i = range(len(self))[index]
        f = self._frames[i]
        W, H = self.intrinsics.width, self.intrinsics.height
        img = np.zeros((H, W, 3), np.uint8) if self.with_image else f.image
        if self.with_image:
            img[:, :, 1] = (i * 7) % 255  # touched, so the pages are really there
        return replace(f, image=img, point_cloud=self.cloud(i))

    def cloud(self, i: int) -> np.ndarray:
        """[n_points, 4] float32 (x, y, z, intensity), LiDAR frame."""
        rng = np.random.default_rng([self.seed, int(i), 31])
        obj = _box_returns(self._box7[i], rng)[: self.n_points // 2]
        bg = self._background()
        out = np.empty((self.n_points, 4), np.float32)
        n_bg = self.n_points - len(obj)
        out[:n_bg] = bg[:n_bg]  # the static scene (one scan pattern) ...
        out[n_bg:, :3] = obj  # ... and the objects of this frame
        out[n_bg:, 3] = 0.5
        return out

    def _background(self) -> np.ndarray:
        """[n_points, 4] float32: the scan rings over the ground (and a wall 120 m away), made once."""
        if getattr(self, "_bg", None) is None:
            rng = np.random.default_rng([self.seed, 29])
            n, rings = self.n_points, _rings(self.n_points)
            n_az = -(-n // rings)
            el = np.repeat(np.radians(np.linspace(-25.0, 15.0, rings)), n_az)[:n]
            az = np.tile(np.linspace(-np.pi, np.pi, n_az, endpoint=False), rings)[:n]
            down = el < -1e-3
            r = np.where(down, -self.ground_z / np.tan(-np.where(down, el, -1.0)), 120.0)
            r = np.minimum(r, 120.0) + rng.normal(0, 0.02, n)
            bg = np.empty((n, 4), np.float32)
            bg[:, 0], bg[:, 1], bg[:, 2] = r * np.cos(el) * np.cos(az), r * np.cos(el) * np.sin(az), r * np.sin(el)
            bg[:, 3] = rng.uniform(0, 1, n)
            self._bg = bg
        return self._bg


def _box_returns(b7: np.ndarray, rng) -> np.ndarray:
    """Returns on each box's four sides and top, more for near boxes."""
    out = []
    for x, y, z, ln, wd, h, yaw in b7:
        d = max(np.hypot(x, y), 3.0)
        k = int(np.clip(4e4 / d ** 2, 30, 2000))
        u, v, face = rng.uniform(-0.5, 0.5, k), rng.uniform(-0.5, 0.5, k), rng.integers(0, 5, k)
        lx = np.where(face == 0, 0.5, np.where(face == 1, -0.5, u)) * ln
        ly = np.where(face == 2, 0.5, np.where(face == 3, -0.5, np.where(face < 2, u, v))) * wd
        lz = np.where(face == 4, 0.5, v) * h
        c, s = np.cos(yaw), np.sin(yaw)
        out.append(np.column_stack([x + c * lx - s * ly, y + s * lx + c * ly, z + lz]))
    return np.concatenate(out) if out else np.zeros((0, 3))
