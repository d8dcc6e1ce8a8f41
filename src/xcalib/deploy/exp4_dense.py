"""An export-friendly dense form of crlite_vit_exp4's structure GNNs (one frame).

The model builds a sparse symmetric kNN graph per frame (``nonzero`` / ``index_add`` with
repeated indices), which the TorchScript ONNX exporter rejects. For one frame with at most a
few dozen detections the same computation is cheap as dense [N,N] tensors: the kNN mask from
per-row distance ranks, edge features for every ordered pair (row = receiving node ``dst``,
column = sending node ``src``), and the attention softmax masked to the graph. The values equal
the sparse model's up to float summation order; the export parity check compares the two.
"""

from __future__ import annotations

import torch
from torch import nn

__all__ = ["dense_knn", "dense_gat", "dense_structure_gnn", "Exp4DenseSide"]


def dense_knn(pos: torch.Tensor, k: int) -> torch.Tensor:
    """Symmetric kNN adjacency [N,N] bool of one frame (no self loops)."""
    idx = torch.arange(pos.shape[0], device=pos.device)
    eye = idx[:, None] == idx[None, :]
    d = torch.cdist(pos, pos).masked_fill(eye, float("inf"))
    rank = (d[:, None, :] < d[:, :, None]).sum(-1)  # [i,j]: neighbours of i closer than j
    adj = (rank < int(k)) & ~eye
    return adj | adj.T


def dense_gat(layer, h: torch.Tensor, adj: torch.Tensor, e: torch.Tensor) -> torch.Tensor:
    """``EdgeAwareGAT`` over a dense graph: h [N,D], adj [N,N] (dst, src), e [N,N,edge_dim]."""
    n = h.shape[0]
    hi = h[:, None].expand(n, n, h.shape[1])
    hj = h[None].expand(n, n, h.shape[1])
    m = layer.msg(torch.cat([hi, hj, e], dim=2))
    logit = layer.att(torch.cat([hi, m], dim=2)).squeeze(2).clamp(-20, 20)
    mx = torch.where(adj, logit, torch.full_like(logit, -20.0)).amax(dim=1)
    w = torch.exp(logit - mx[:, None]) * adj.to(logit.dtype)
    a = w / (w.sum(dim=1, keepdim=True) + 1e-6)
    agg = (a[:, :, None] * m).sum(dim=1)
    return layer.norm(h + layer.drop(agg)).clamp(-50, 50)


def dense_structure_gnn(gnn, h: torch.Tensor, pos: torch.Tensor, raw: torch.Tensor) -> torch.Tensor:
    """``StructureGNN`` on one frame; raw [N,N,raw_edge_dim] edge features (dst, src)."""
    adj = dense_knn(pos, gnn.k)
    e = gnn.edge_enc(raw)
    out = h
    for layer in gnn.layers:
        out = dense_gat(layer, out, adj, e)
    return torch.where(adj.any(), out, h)  # no edge at all: the model returns h unchanged


class Exp4DenseSide(nn.Module):
    """One modality of exp4 (backbone + dense GNN) for one frame; forward like the export
    graphs: (crops, boxes, aux) -> (embedding,)."""

    def __init__(self, model: nn.Module, side: str):
        super().__init__()
        self.model, self.side = model, side

    def forward(self, crops: torch.Tensor, boxes: torch.Tensor, aux: torch.Tensor):
        m = self.model
        if self.side == "image":
            h = m.img_proj(m.img_backbone(crops))
            uv = torch.stack([(boxes[:, 0] + boxes[:, 2]) / 2, (boxes[:, 1] + boxes[:, 3]) / 2], 1) / aux
            area = ((boxes[:, 2] - boxes[:, 0]) * (boxes[:, 3] - boxes[:, 1])).clamp_min(1.0)
            duv = (uv[None, :, :] - uv[:, None, :]).clamp(-2, 2)  # [dst, src] = uv[src] - uv[dst]
            la = torch.log(area[None, :] / area[:, None]).clamp(-5, 5)[:, :, None]
            return (dense_structure_gnn(m.camera_gnn, h, uv, torch.cat([duv, la], 2)),)
        h = m.lid_backbone(crops)
        xyz = boxes[:, :3]
        rel = xyz - xyz.mean(dim=0, keepdim=True)
        scale = rel.norm(dim=1).amax().clamp_min(1.0)
        pos = rel / scale
        vol = boxes[:, 3:6].clamp_min(1e-3).prod(dim=1)
        d = pos[None, :, :] - pos[:, None, :]
        raw = torch.cat([d.clamp(-5, 5), d.norm(dim=2, keepdim=True).clamp(0, 10),
                         torch.log(vol[None, :] / vol[:, None]).clamp(-5, 5)[:, :, None]], 2)
        return (dense_structure_gnn(m.lidar_gnn, h, pos, raw),)
