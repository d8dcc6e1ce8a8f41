"""Position encodings with consistent units, one module per modality.

* Image boxes: centre (u/W, v/H), size (w/W, h/H) and bottom edge v2/H, i.e. **fractions of
  the image size** (resolution independent). The sinusoid periods span ``2`` down to ``1/64``.
* LiDAR boxes: centre (x, y, z) in **metres**, range = horizontal distance sqrt(x^2+y^2) from
  the LiDAR origin (not the height), box dims. Sinusoid periods span ``4*max_depth`` down to
  0.5 m; range and coordinates are divided by ``max_depth`` before the MLP branches.

Each encoder concatenates [sin-cos of the 2D position (T), a "depth" MLP (T/4), a "spatial"
MLP (T/4)] and fuses them (Linear 1.5T -> T + LayerNorm + ReLU). ``pe_mode="2d_only"`` zeroes
the depth and spatial branches (same parameters, so checkpoints stay compatible).
"""

from __future__ import annotations

import math

import torch
from torch import nn

__all__ = ["sincos_2d", "ImagePositionEncoding", "LidarPositionEncoding"]


def sincos_2d(xy: torch.Tensor, dim: int, min_period: float, max_period: float) -> torch.Tensor:
    """[N,2] positions -> [N,dim] sin/cos features over geometric periods (same units as xy)."""
    if dim % 4:
        raise ValueError(f"token_len must be a multiple of 4, got {dim}")
    nf = dim // 4
    periods = torch.exp(torch.linspace(math.log(max_period), math.log(min_period), nf,
                                       device=xy.device, dtype=xy.dtype))
    ang = xy[:, :, None] * (2 * math.pi / periods)  # [N,2,nf]
    return torch.cat([torch.sin(ang), torch.cos(ang)], dim=2).flatten(1)  # [N,dim]; traceable N (ONNX)


class _PEBase(nn.Module):
    def __init__(self, token_len: int, n_depth: int, n_spatial: int, pe_mode: str):
        super().__init__()
        if pe_mode not in ("full", "2d_only"):
            raise ValueError(f"pe_mode must be 'full' or '2d_only', got {pe_mode!r}")
        T, q = token_len, token_len // 4
        self.depth = nn.Sequential(nn.Linear(n_depth, q), nn.ReLU(inplace=True), nn.Linear(q, q))
        self.spatial = nn.Sequential(nn.Linear(n_spatial, q), nn.ReLU(inplace=True), nn.Linear(q, q))
        self.fuse = nn.Sequential(nn.Linear(T + 2 * q, T), nn.LayerNorm(T), nn.ReLU(inplace=True))
        self.token_len, self.pe_mode = T, pe_mode

    def _combine(self, sin: torch.Tensor, depth_in: torch.Tensor, spatial_in: torch.Tensor) -> torch.Tensor:
        d, s = self.depth(depth_in), self.spatial(spatial_in)
        if self.pe_mode == "2d_only":
            d, s = d * 0.0, s * 0.0
        return self.fuse(torch.cat([sin, d, s], dim=1))


class ImagePositionEncoding(_PEBase):
    """2D boxes [N,4] px + image size [N,2] (W,H) px -> [N,T]."""

    def __init__(self, token_len: int = 256, pe_mode: str = "full"):
        super().__init__(token_len, 2, 3, pe_mode)

    def forward(self, boxes: torch.Tensor, wh: torch.Tensor) -> torch.Tensor:
        W, H = wh[:, 0:1], wh[:, 1:2]
        c = torch.cat([(boxes[:, 0:1] + boxes[:, 2:3]) / 2 / W, (boxes[:, 1:2] + boxes[:, 3:4]) / 2 / H], 1)
        size = torch.cat([(boxes[:, 2:3] - boxes[:, 0:1]) / W, (boxes[:, 3:4] - boxes[:, 1:2]) / H], 1)
        sin = sincos_2d(c, self.token_len, 1 / 64, 2.0)
        return self._combine(sin, torch.log(size.clamp_min(1e-4)), torch.cat([c, boxes[:, 3:4] / H], 1))


class LidarPositionEncoding(_PEBase):
    """box7 [M,7] (LiDAR frame, metres) -> [M,T]."""

    def __init__(self, token_len: int = 256, max_depth: float = 100.0, pe_mode: str = "full"):
        super().__init__(token_len, 1, 6, pe_mode)
        self.max_depth = float(max_depth)

    def forward(self, box7: torch.Tensor) -> torch.Tensor:
        xyz = box7[:, :3]
        rng = torch.linalg.norm(xyz[:, :2], dim=1, keepdim=True)
        sin = sincos_2d(xyz[:, :2], self.token_len, 0.5, 4 * self.max_depth)
        depth = (rng / self.max_depth).clamp(0, 1)
        spatial = torch.cat([xyz / self.max_depth, torch.log(box7[:, 3:6].clamp_min(1e-3))], 1)
        return self._combine(sin, depth, spatial)
