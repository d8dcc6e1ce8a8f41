"""Point backbones written here: the crlite PointNet (attention pooling) and a light PointNet.
Input [M,P,3] (or [M,3,P]) box-frame points in metres."""

from __future__ import annotations

from typing import Sequence

import torch
from torch import nn

from ..layers import SafeBatchNorm1d

__all__ = ["PointNetEmbedding", "TinyPointNet", "to_channels_first"]


def to_channels_first(x: torch.Tensor) -> torch.Tensor:
    """[M,P,3] -> [M,3,P]; [M,3,P] passes through."""
    if x.dim() != 3:
        raise ValueError(f"point crops: expected [M, P, 3] or [M, 3, P], got {tuple(x.shape)}")
    return x if x.shape[1] == 3 and x.shape[2] != 3 else x.transpose(1, 2)


def _pointwise(dims: Sequence[int]) -> nn.Sequential:
    layers: list[nn.Module] = []
    for a, b in zip(dims[:-1], dims[1:]):
        layers += [nn.Conv1d(a, b, 1, bias=False), SafeBatchNorm1d(b), nn.ReLU(inplace=True)]
    return nn.Sequential(*layers)


class PointNetEmbedding(nn.Module):
    """Shared point MLP 3->64->128->256->512 (1x1 conv + BN + ReLU), spatial-attention
    weighted mean, head FC 512->256 + BN + ReLU + Dropout -> FC ->E + BN + ReLU + Dropout."""

    def __init__(self, embed_dim: int = 256, dims: Sequence[int] = (3, 64, 128, 256, 512),
                 dropout: tuple[float, float] = (0.2, 0.1)):
        super().__init__()
        c = dims[-1]
        self.point_mlp = _pointwise(dims)
        self.attention = nn.Sequential(nn.Conv1d(c, c // 2, 1), SafeBatchNorm1d(c // 2), nn.ReLU(inplace=True),
                                       nn.Conv1d(c // 2, 1, 1))
        self.head = nn.Sequential(nn.Linear(c, c // 2), SafeBatchNorm1d(c // 2), nn.ReLU(inplace=True),
                                  nn.Dropout(dropout[0]), nn.Linear(c // 2, embed_dim), SafeBatchNorm1d(embed_dim),
                                  nn.ReLU(inplace=True), nn.Dropout(dropout[1]))
        self.out_dim = embed_dim

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        f = self.point_mlp(to_channels_first(x))
        a = torch.sigmoid(self.attention(f))
        pooled = (f * a).sum(dim=2) / (a.sum(dim=2) + 1e-8)
        return self.head(pooled)


class TinyPointNet(nn.Module):
    """Light PointNet: point MLP 3->32->64->128 (1x1 conv + BN + ReLU), max + mean pool -> [M, 2*C]."""

    def __init__(self, dims: Sequence[int] = (3, 32, 64, 128)):
        super().__init__()
        self.point_mlp = _pointwise(dims)
        self.out_dim = 2 * dims[-1]

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        f = self.point_mlp(to_channels_first(x))
        return torch.cat([f.amax(dim=2), f.mean(dim=2)], dim=1)
