"""Observed frames of a one-shot session: cropped once, kept for calibration and training.

An :class:`Observation` holds the model inputs of one frame (image crops and the grouped
box-frame LiDAR points, cut exactly once; the same crops are used to match the frame now and to
train on it later) plus a light copy of the frame for calibration (boxes, point cloud, no
image pixels). The :class:`EvidenceBuffer` is a bounded FIFO of observations (O(1) per frame).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from typing import Any, Iterator

import numpy as np

from ..data.crops import CropConfig, FrameInputs, KeptCounts, crop_images, crop_points, gather_box_points, resample_points
from ..types import Frame

__all__ = ["Observation", "EvidenceBuffer", "observe_frame_inputs", "light_frame"]


@dataclass
class Observation(KeptCounts):
    """One observed frame.

    crops_2d [N,3,S,S] normalised image crops of the kept 2D boxes; points [T,3] box-frame
    points (metres) grouped per kept 3D box with ``counts`` [M]; boxes_2d [N,4] px; boxes_3d
    [M,7] box7 (LiDAR frame, metres); kept_2d / kept_3d map rows/columns to the caller's
    numbering. ``frame`` is a light :class:`Frame` (blank image view, full point cloud, boxes,
    ``meta``) for the calibrator; ``index`` counts observations from 0.
    """

    key: str
    index: int
    crops_2d: np.ndarray
    points: np.ndarray
    counts: np.ndarray
    boxes_2d: np.ndarray
    boxes_3d: np.ndarray
    kept_2d: np.ndarray
    kept_3d: np.ndarray
    image_size: tuple[int, int]
    frame: Frame
    meta: dict[str, Any] = field(default_factory=dict)

    def inputs(self, n_points: int, rng: np.random.Generator) -> FrameInputs:
        """Model inputs with every 3D crop resampled to ``n_points`` points by ``rng``."""
        crops = resample_points(self.points, self.counts, n_points, rng) if self.num_3d else \
            np.zeros((0, n_points, 3), np.float32)
        return FrameInputs(self.crops_2d, crops, self.boxes_2d, self.boxes_3d, self.counts, self.image_size,
                           self.kept_2d, self.kept_3d)


def light_frame(image: np.ndarray, point_cloud, bboxes_2d, bboxes_3d, key: str, meta: dict | None) -> Frame:
    """A Frame for the calibrator: a zero-cost blank image of the same size (no pixels kept)."""
    h, w = image.shape[:2]
    blank = np.broadcast_to(np.zeros(3, dtype=np.uint8), (h, w, 3))
    return Frame(image=blank, point_cloud=np.asarray(point_cloud)[:, :3].astype(np.float32, copy=False),
                 bboxes_2d=np.asarray(bboxes_2d, dtype=np.float32).reshape(-1, 4),
                 bboxes_3d=np.asarray(bboxes_3d, dtype=np.float32), frame_key=key, meta=dict(meta or {}))


def observe_frame_inputs(image: np.ndarray, point_cloud, bboxes_2d, bboxes_3d, cfg: CropConfig, *, key: str,
                         index: int, meta: dict | None = None) -> Observation:
    """Crop one frame once (image crops, grouped box points) into an :class:`Observation`."""
    crops2, k2 = crop_images(image, bboxes_2d, cfg.crop_size, keep_aspect=cfg.keep_aspect, normalize=cfg.normalize)
    b3 = np.asarray(bboxes_3d, dtype=np.float64)
    pc = np.asarray(point_cloud)
    _, box7, _, k3 = crop_points(pc, b3, 1, expansion=cfg.bbox_expansion, min_points=cfg.min_points)
    if len(box7):
        pts, counts = gather_box_points(pc, box7, cfg.bbox_expansion)
    else:
        pts, counts = np.zeros((0, 3), np.float32), np.zeros(0, np.int64)
    b2 = np.asarray(bboxes_2d, dtype=np.float32).reshape(-1, 4)[k2]
    h, w = image.shape[:2]
    return Observation(key=key, index=index, crops_2d=crops2, points=pts, counts=counts, boxes_2d=b2,
                       boxes_3d=np.asarray(box7, np.float32), kept_2d=np.asarray(k2, np.int64),
                       kept_3d=np.asarray(k3, np.int64), image_size=(int(w), int(h)),
                       frame=light_frame(image, pc, bboxes_2d, bboxes_3d, key, meta))


class EvidenceBuffer:
    """Bounded FIFO of observations (``capacity`` frames; the oldest is dropped first)."""

    def __init__(self, capacity: int = 64):
        if int(capacity) < 1:
            raise ValueError(f"EvidenceBuffer: capacity must be >= 1 frame, got {capacity}")
        self.capacity = int(capacity)
        self._items: deque[Observation] = deque(maxlen=self.capacity)
        self.total_seen = 0

    def add(self, obs: Observation) -> None:
        self._items.append(obs)
        self.total_seen += 1

    def __len__(self) -> int:
        return len(self._items)

    def __iter__(self) -> Iterator[Observation]:
        return iter(self._items)

    def __getitem__(self, i: int) -> Observation:
        return self._items[i]

    def frames(self) -> list[Frame]:
        return [o.frame for o in self._items]

    @property
    def n_2d(self) -> int:
        return int(sum(o.num_2d for o in self._items))

    @property
    def n_3d(self) -> int:
        return int(sum(o.num_3d for o in self._items))
