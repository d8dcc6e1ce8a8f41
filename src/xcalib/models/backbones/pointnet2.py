"""PointNet++ (single-scale grouping) written here, batched over crops.

Farthest-point sampling is deterministic (it starts from the point nearest the crop centroid)
and vectorised over the batch; ball query picks the first ``nsample`` points within the radius
(by index), padding with the first hit. Input [M,P,3] box-frame metres; output
(embedding [M,E], class log-probs [M,C]).
"""

from __future__ import annotations

from typing import Sequence

import torch
from torch import nn

from ..layers import SafeBatchNorm1d
from .pointnet import to_channels_first

__all__ = ["farthest_point_sample", "ball_query", "PointNet2SSG"]


def farthest_point_sample(xyz: torch.Tensor, npoint: int) -> torch.Tensor:
    """xyz [B,N,3] -> indices [B,npoint] (deterministic start: the point nearest the centroid)."""
    B, N, _ = xyz.shape
    npoint = min(npoint, N)
    idx = torch.zeros(B, npoint, dtype=torch.long, device=xyz.device)
    dist = torch.full((B, N), float("inf"), device=xyz.device, dtype=xyz.dtype)
    far = ((xyz - xyz.mean(dim=1, keepdim=True)) ** 2).sum(-1).argmin(dim=1)
    ar = torch.arange(B, device=xyz.device)
    for i in range(npoint):  # iterative by definition; vectorised over the batch and points
        idx[:, i] = far
        d = ((xyz - xyz[ar, far][:, None]) ** 2).sum(-1)
        dist = torch.minimum(dist, d)
        far = dist.argmax(dim=1)
    return idx


def ball_query(xyz: torch.Tensor, centres: torch.Tensor, radius: float, nsample: int) -> torch.Tensor:
    """Indices [B,S,nsample] of points within ``radius`` (metres) of each centre."""
    N = xyz.shape[1]
    d2 = torch.cdist(centres, xyz) ** 2
    cand = torch.arange(N, device=xyz.device).expand_as(d2).clone()
    cand[d2 > radius ** 2] = N
    cand = cand.sort(dim=-1).values[..., :nsample]
    first = cand[..., :1].expand_as(cand)
    cand = torch.where(cand == N, first, cand)
    return torch.where(cand == N, torch.zeros_like(cand), cand)  # centre-less rows (cannot happen)


def _gather(x: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
    """x [B,N,C], idx [B,...] -> [B,...,C]."""
    B = x.shape[0]
    flat = idx.reshape(B, -1)
    out = torch.gather(x, 1, flat[..., None].expand(-1, -1, x.shape[-1]))
    return out.reshape(*idx.shape, x.shape[-1])


class _SetAbstraction(nn.Module):
    def __init__(self, npoint: int | None, radius: float, nsample: int, c_in: int, dims: Sequence[int]):
        super().__init__()
        self.npoint, self.radius, self.nsample = npoint, radius, nsample
        layers, c = [], c_in + 3
        for d in dims:
            layers += [nn.Conv2d(c, d, 1, bias=False), nn.BatchNorm2d(d), nn.ReLU(inplace=True)]
            c = d
        self.mlp = nn.Sequential(*layers)

    def forward(self, xyz: torch.Tensor, feats: torch.Tensor | None):
        if self.npoint is None:  # group all
            g = xyz[:, None]
            if feats is not None:
                g = torch.cat([g, feats[:, None]], dim=-1)
            new_xyz = xyz.mean(dim=1, keepdim=True)
        else:
            new_xyz = _gather(xyz, farthest_point_sample(xyz, self.npoint))
            gi = ball_query(xyz, new_xyz, self.radius, self.nsample)
            g = _gather(xyz, gi) - new_xyz[:, :, None]
            if feats is not None:
                g = torch.cat([g, _gather(feats, gi)], dim=-1)
        f = self.mlp(g.permute(0, 3, 2, 1)).amax(dim=2)  # [B,C,S]
        return new_xyz, f.transpose(1, 2)


class PointNet2SSG(nn.Module):
    """SA1 (512 centres, r 0.2 m, 32) -> SA2 (128, r 0.4 m, 64) -> SA3 (group all) ->
    FC 1024->512 BN Drop -> 512 BN Drop (embedding) -> ``num_classes``."""

    def __init__(self, embed_dim: int = 512, num_classes: int = 10,
                 sa: Sequence[dict] | None = None, dropout: float = 0.4):
        super().__init__()
        sa = sa or [dict(npoint=512, radius=0.2, nsample=32, mlp=[64, 64, 128]),
                    dict(npoint=128, radius=0.4, nsample=64, mlp=[128, 128, 256]),
                    dict(npoint=None, radius=0.0, nsample=0, mlp=[256, 512, 1024])]
        mods, c = [], 0
        for s in sa:
            mods.append(_SetAbstraction(s.get("npoint"), float(s.get("radius", 0)), int(s.get("nsample", 0)), c, s["mlp"]))
            c = s["mlp"][-1]
        self.sa = nn.ModuleList(mods)
        self.head = nn.Sequential(nn.Linear(c, embed_dim), SafeBatchNorm1d(embed_dim), nn.ReLU(inplace=True),
                                  nn.Dropout(dropout), nn.Linear(embed_dim, embed_dim), SafeBatchNorm1d(embed_dim),
                                  nn.ReLU(inplace=True), nn.Dropout(dropout))
        self.cls = nn.Linear(embed_dim, num_classes)
        self.out_dim = embed_dim

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        xyz = to_channels_first(x).transpose(1, 2).contiguous()
        feats = None
        for m in self.sa:
            xyz, feats = m(xyz, feats)
        e = self.head(feats[:, 0] if feats.shape[1] == 1 else feats.amax(dim=1))
        return e, torch.log_softmax(self.cls(e), dim=1)
