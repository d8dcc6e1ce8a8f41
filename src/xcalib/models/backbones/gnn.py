"""Structure-aware graph layers (exp4), vectorised: kNN graphs built per frame inside a batch
(symmetrised, no duplicate edges), edge-aware attention with a scatter softmax.

Camera graph edge features: (du/W, dv/H) clamped to +-2 and the log area ratio clamped to
+-5, with W, H each frame's own image size. LiDAR graph edge features: dxyz / frame scale
(clamped +-5), distance / frame scale (clamped [0,10]) and the log volume ratio of the boxes.
"""

from __future__ import annotations

import torch
from torch import nn

__all__ = ["knn_edges", "EdgeAwareGAT", "StructureGNN"]


def knn_edges(pos: torch.Tensor, seg: torch.Tensor, k: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Symmetric kNN edges within each segment (frame). pos [N,D], seg [N] -> (src [E], dst [E])."""
    N = len(pos)
    if N <= 1 or k <= 0:
        e = torch.zeros(0, dtype=torch.long, device=pos.device)
        return e, e
    d = torch.cdist(pos, pos)
    bad = (seg[:, None] != seg[None, :]) | torch.eye(N, dtype=torch.bool, device=pos.device)
    d = d.masked_fill(bad, float("inf"))
    kk = min(k, N - 1)
    vals, nbr = d.topk(kk, dim=1, largest=False)
    adj = torch.zeros(N, N, dtype=torch.bool, device=pos.device)
    rows = torch.arange(N, device=pos.device)[:, None].expand(-1, kk)
    adj[rows[torch.isfinite(vals)], nbr[torch.isfinite(vals)]] = True
    adj = adj | adj.T
    dst, src = adj.nonzero(as_tuple=True)
    return src, dst


class EdgeAwareGAT(nn.Module):
    """m_ij = MLP([h_i, h_j, e_ij]); a_ij = softmax_j(MLP([h_i, m_ij])); h_i <- LN(h_i + sum a m)."""

    def __init__(self, dim: int, edge_dim: int = 8, hidden: int = 128, dropout: float = 0.1):
        super().__init__()
        self.msg = nn.Sequential(nn.Linear(2 * dim + edge_dim, hidden), nn.GELU(), nn.Dropout(dropout),
                                 nn.Linear(hidden, dim))
        self.att = nn.Sequential(nn.Linear(2 * dim, 64), nn.GELU(), nn.Linear(64, 1))
        self.norm = nn.LayerNorm(dim)
        self.drop = nn.Dropout(dropout)
        for m in self.modules():
            if isinstance(m, nn.Linear):
                nn.init.xavier_uniform_(m.weight, gain=0.5)
                nn.init.zeros_(m.bias)

    def forward(self, h: torch.Tensor, src: torch.Tensor, dst: torch.Tensor, e: torch.Tensor) -> torch.Tensor:
        if len(src) == 0:
            return h
        m = self.msg(torch.cat([h[dst], h[src], e], dim=1))
        logit = self.att(torch.cat([h[dst], m], dim=1)).squeeze(1).clamp(-20, 20)
        mx = torch.full((len(h),), -20.0, device=h.device, dtype=h.dtype).scatter_reduce(0, dst, logit, "amax")
        w = torch.exp(logit - mx[dst])
        den = torch.zeros(len(h), device=h.device, dtype=h.dtype).index_add(0, dst, w)
        a = w / (den[dst] + 1e-6)
        agg = torch.zeros_like(h).index_add(0, dst, a[:, None] * m)
        return self.norm(h + self.drop(agg)).clamp(-50, 50)


class StructureGNN(nn.Module):
    """Edge encoder (Linear raw->edge_dim + GELU) and ``num_layers`` EdgeAwareGAT layers."""

    def __init__(self, dim: int, raw_edge_dim: int, edge_dim: int = 8, hidden: int = 128, num_layers: int = 2,
                 k_neighbors: int = 4, dropout: float = 0.1):
        super().__init__()
        self.edge_enc = nn.Sequential(nn.Linear(raw_edge_dim, edge_dim), nn.GELU())
        self.layers = nn.ModuleList(EdgeAwareGAT(dim, edge_dim, hidden, dropout) for _ in range(num_layers))
        self.k = k_neighbors

    def forward(self, h: torch.Tensor, pos: torch.Tensor, seg: torch.Tensor, raw_edge_fn) -> torch.Tensor:
        src, dst = knn_edges(pos, seg, self.k)
        if len(src) == 0:
            return h
        e = self.edge_enc(raw_edge_fn(src, dst))
        for layer in self.layers:
            h = layer(h, src, dst, e)
        return h
