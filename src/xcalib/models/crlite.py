"""crlite / crlite_2dpe: ResNet + PointNet embeddings fused with position encodings, hybrid
two-stage scoring (cosine -> top-k -> pair MLP).

Score semantics (``score``): [N,M] with the Stage-2 pair **probability** sigmoid(logit) in
[0,1] for each row's top-k Stage-1 candidates and ``fill_value`` -1 elsewhere. The
probability is absolute (trained with binary cross-entropy beside the row/column
cross-entropy), so ``match_threshold`` is meaningful; it is not min-max normalised per row.
"""

from __future__ import annotations

import torch
from torch import nn

from .backbones.pointnet import PointNetEmbedding
from .backbones.resnet import ResNetEmbeddingDeep
from .base import Embeddings, MatchingModel, TrainLogits, cosine_matrix
from .inputs import ModelBatch
from .layers import linear_ln_relu, mlp
from .position_encoding import ImagePositionEncoding, LidarPositionEncoding
from .registry import register_model

__all__ = ["CRLite", "CRLite2DPE", "PositionFusion", "dense_pairs"]


class PositionFusion(nn.Module):
    """Per-modality position encoders, projections T->E and fusions [feat ; pos] 2E->E."""

    def __init__(self, embed_dim: int, token_len: int, max_depth: float, pe_mode: str):
        super().__init__()
        E, T = embed_dim, token_len
        self.img_pe = ImagePositionEncoding(T, pe_mode)
        self.lid_pe = LidarPositionEncoding(T, max_depth, pe_mode)
        self.img_position_proj = linear_ln_relu(T, E)
        self.lid_position_proj = linear_ln_relu(T, E)
        self.img_fusion = linear_ln_relu(2 * E, E)
        self.lid_fusion = linear_ln_relu(2 * E, E)

    def forward(self, fi: torch.Tensor, fl: torch.Tensor, batch: ModelBatch) -> tuple[torch.Tensor, torch.Tensor]:
        pi = self.img_position_proj(self.img_pe(batch.boxes_2d, batch.image_wh))
        pl = self.lid_position_proj(self.lid_pe(batch.boxes_3d))
        return self.img_fusion(torch.cat([fi, pi], 1)), self.lid_fusion(torch.cat([fl, pl], 1))


def dense_pairs(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """[N,E], [M,E] -> [N,M,2E] (every pair, image half first)."""
    N, M = len(a), len(b)
    return torch.cat([a[:, None].expand(N, M, -1), b[None].expand(N, M, -1)], dim=2)


@register_model("crlite")
class CRLite(MatchingModel):
    score_range = (0.0, 1.0)
    fill_value = -1.0
    force_pe_mode: str | None = None

    def __init__(self, config):
        super().__init__(config)
        c = self.config
        E, T = int(c["embed_dim"]), int(c["token_len"])
        if self.force_pe_mode:
            c["pe_mode"] = self.force_pe_mode
        self.top_k = int(c.get("top_k", 10))
        self.img_backbone = ResNetEmbeddingDeep(E, dropout=float(c.get("dropout", 0.1)))
        self.lid_backbone = PointNetEmbedding(E)
        self.position = PositionFusion(E, T, float(c.get("max_depth", 100.0)), c.get("pe_mode", "full"))
        sh = c.get("similarity_head") or {}
        hidden = list(sh.get("hidden_dims") or [E // 2, E // 4, E // 8])
        self.embed_fusion = linear_ln_relu(2 * E, E, float((c.get("embed_fusion") or {}).get("dropout", 0.1)))
        self.similarity_head = mlp([E, *hidden, 1], dropout=float(sh.get("dropout", 0.1)))
        self.stage1_weight = float(c.get("stage1_weight", 1.0))
        self.stage2_weight = float(c.get("stage2_weight", 1.0))

    def embed(self, batch: ModelBatch) -> Embeddings:
        fi, fl = self.img_backbone(batch.crops_2d), self.lid_backbone(batch.crops_3d)
        fi, fl = self.position(fi, fl, batch)
        return Embeddings(fi, fl)

    def stage2(self, pairs: torch.Tensor) -> torch.Tensor:
        """[..., 2E] pair features -> [...] logits."""
        return self.similarity_head(self.embed_fusion(pairs)).squeeze(-1)

    def score_pairs(self, img: torch.Tensor, lid: torch.Tensor) -> torch.Tensor:
        """img [..., E], lid [..., E] of the same pairs -> stage-2 logits [...]."""
        return self.stage2(torch.cat([img, lid], dim=-1))

    def score(self, emb: Embeddings, batch: ModelBatch) -> torch.Tensor:
        N, M = len(emb.img), len(emb.lid)
        out = torch.full((N, M), float(self.fill_value), device=emb.img.device)
        if N == 0 or M == 0:
            return out
        cos = cosine_matrix(emb.img, emb.lid)
        k = min(self.top_k, M) if self.top_k > 0 else M
        idx = cos.topk(k, dim=1).indices  # [N,k]
        return out.scatter(1, idx, torch.sigmoid(self.score_pairs(emb.img[:, None].expand(N, k, -1), emb.lid[idx])))

    def train_logits(self, emb: Embeddings, batch: ModelBatch) -> list[TrainLogits]:
        cos = cosine_matrix(emb.img, emb.lid) / self.temperature
        out = [TrainLogits(cos, "cosine", self.stage1_weight)]
        if self.stage2_weight > 0:
            out.append(TrainLogits(self.stage2(dense_pairs(emb.img, emb.lid)), "logit", self.stage2_weight))
        return out


@register_model("crlite_2dpe")
class CRLite2DPE(CRLite):
    """crlite with the depth and spatial PE branches switched off (``pe_mode`` forced to 2d_only)."""

    force_pe_mode = "2d_only"
