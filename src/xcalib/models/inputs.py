"""``ModelBatch``: one or more frames of :class:`xcalib.data.crops.FrameInputs` as tensors."""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Sequence

import numpy as np
import torch

from ..data.crops import FrameInputs

__all__ = ["ModelBatch"]


@dataclass
class ModelBatch:
    """Detections of ``n_frames`` frames, concatenated.

    crops_2d [N,3,S,S]; crops_3d [M,P,3] box-frame metres; boxes_2d [N,4] px; image_wh [N,2]
    px (each 2D box's image size); boxes_3d [M,7] box7 metres; point_counts [M] float;
    seg_2d [N] / seg_3d [M] frame index of every detection.
    """

    crops_2d: torch.Tensor
    crops_3d: torch.Tensor
    boxes_2d: torch.Tensor
    image_wh: torch.Tensor
    boxes_3d: torch.Tensor
    point_counts: torch.Tensor
    seg_2d: torch.Tensor
    seg_3d: torch.Tensor
    n_frames: int = 1

    @classmethod
    def from_frames(cls, frames: Sequence[FrameInputs], device: str | torch.device = "cpu") -> "ModelBatch":
        if not frames:
            raise ValueError("ModelBatch.from_frames: need at least one frame")

        def cat(name: str, dtype=np.float32) -> torch.Tensor:
            return torch.from_numpy(np.ascontiguousarray(np.concatenate([getattr(f, name) for f in frames]),
                                                         dtype=dtype)).to(device)

        n2 = [f.num_2d for f in frames]
        n3 = [f.num_3d for f in frames]
        wh = np.concatenate([np.tile(np.asarray(f.image_size, np.float32), (f.num_2d, 1)) for f in frames])
        return cls(
            crops_2d=cat("crops_2d"), crops_3d=cat("crops_3d"), boxes_2d=cat("boxes_2d"),
            image_wh=torch.from_numpy(wh.reshape(-1, 2)).to(device), boxes_3d=cat("boxes_3d"),
            point_counts=cat("point_counts"),
            seg_2d=torch.from_numpy(np.repeat(np.arange(len(frames)), n2)).to(device),
            seg_3d=torch.from_numpy(np.repeat(np.arange(len(frames)), n3)).to(device),
            n_frames=len(frames))

    def to(self, device) -> "ModelBatch":
        kw = {f.name: getattr(self, f.name) for f in fields(self)}
        for k, v in kw.items():
            if isinstance(v, torch.Tensor):
                kw[k] = v.to(device)
        return ModelBatch(**kw)

    @property
    def num_2d(self) -> int:
        return int(self.crops_2d.shape[0])

    @property
    def num_3d(self) -> int:
        return int(self.crops_3d.shape[0])

    def same_frame(self) -> torch.Tensor:
        """[N,M] bool: True where the 2D and the 3D detection belong to the same frame."""
        return self.seg_2d[:, None] == self.seg_3d[None, :]
