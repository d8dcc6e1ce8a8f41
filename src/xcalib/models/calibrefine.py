"""calibrefine: pairwise baseline (bottleneck ResNet + PointNet++ + pair MLP).

Backbones run once per detection (not once per pair), then every one of the N*M pairs is
scored in one batched call. Score: sigmoid pair probability in [0,1] for every pair.
Positions: image box centre as fractions of the image size, LiDAR box centre (x, y) in metres.
"""

from __future__ import annotations

import torch
from torch import nn

from .backbones.pointnet2 import PointNet2SSG
from .backbones.resnet import BottleneckResNet
from .base import Embeddings, MatchingModel, TrainLogits
from .inputs import ModelBatch
from .position_encoding import sincos_2d
from .registry import register_model

__all__ = ["CalibRefine"]


def _lin(d_in: int, d_out: int, dropout: float, ln: bool = True) -> nn.Sequential:
    layers: list[nn.Module] = [nn.Linear(d_in, d_out)]
    if ln:
        layers.append(nn.LayerNorm(d_out))
    layers.append(nn.ReLU(inplace=True))
    if dropout > 0:
        layers.append(nn.Dropout(dropout))
    return nn.Sequential(*layers)


@register_model("calibrefine")
class CalibRefine(MatchingModel):
    score_range = (0.0, 1.0)

    def __init__(self, config):
        super().__init__(config)
        c = self.config
        C, T = int(c.get("num_classes", 10)), int(c.get("token_len", 256))
        d = dict(c.get("dense") or {})
        dims = {k: int(d.get(k, v)) for k, v in (("embed_dim", 512), ("fusion_dim", 512), ("hidden_dim", 256))}
        for k, v in dims.items():
            if v <= 0:
                raise ValueError(f"calibrefine: dense.{k} must be > 0, got {v}")
        E = int(c.get("embed_dim", 512))
        self.img_backbone = BottleneckResNet(tuple(c.get("num_blocks", (2, 2, 2, 2))), int(c.get("base_width", 64)),
                                             E, C)
        self.lid_backbone = PointNet2SSG(E, C, c.get("pointnet2"))
        self.token_len = T
        self.fc1 = _lin(2 * E, dims["embed_dim"], float(d.get("dropout_embed", 0.1)))
        self.fc2 = _lin(2 * C, 2 * C, 0.0, ln=False)
        self.fc3 = _lin(2 * T, 512, 0.0, ln=False)
        self.fc4 = _lin(dims["embed_dim"] + 2 * C + 512, dims["fusion_dim"], float(d.get("dropout_fusion", 0.3)), ln=False)
        self.fc5 = _lin(dims["fusion_dim"], dims["hidden_dim"], float(d.get("dropout_hidden", 0.4)), ln=False)
        self.fc6 = nn.Linear(dims["hidden_dim"], 1)

    def embed(self, batch: ModelBatch) -> Embeddings:
        ei, ci = self.img_backbone(batch.crops_2d)
        el, cl = self.lid_backbone(batch.crops_3d)
        b2 = batch.boxes_2d
        uv = torch.stack([(b2[:, 0] + b2[:, 2]) / 2, (b2[:, 1] + b2[:, 3]) / 2], 1) / batch.image_wh
        pi = sincos_2d(uv, self.token_len, 1 / 64, 2.0)
        pl = sincos_2d(batch.boxes_3d[:, :2], self.token_len, 0.5, 400.0)
        return Embeddings(ei, el, {"cls_img": ci, "cls_lid": cl, "pos_img": pi, "pos_lid": pl})

    def score_pairs(self, ei: torch.Tensor, ci: torch.Tensor, pi: torch.Tensor,
                    el: torch.Tensor, cl: torch.Tensor, pl: torch.Tensor) -> torch.Tensor:
        """Pair logits [B] from the per-pair embedding, class and position tensors [B, ...]
        of the image side (ei, ci, pi) and the LiDAR side (el, cl, pl)."""
        x = torch.cat([self.fc1(torch.cat([ei, el], 1)), self.fc2(torch.cat([ci, cl], 1)),
                       self.fc3(torch.cat([pi, pl], 1))], 1)
        return self.fc6(self.fc5(self.fc4(x))).squeeze(-1)

    def pair_logits(self, emb: Embeddings) -> torch.Tensor:
        N, M = len(emb.img), len(emb.lid)
        x = emb.extra
        img = [t[:, None].expand(N, M, -1).reshape(N * M, -1) for t in (emb.img, x["cls_img"], x["pos_img"])]
        lid = [t[None].expand(N, M, -1).reshape(N * M, -1) for t in (emb.lid, x["cls_lid"], x["pos_lid"])]
        return self.score_pairs(*img, *lid).reshape(N, M)

    def score(self, emb: Embeddings, batch: ModelBatch) -> torch.Tensor:
        return torch.sigmoid(self.pair_logits(emb))

    def train_logits(self, emb: Embeddings, batch: ModelBatch) -> list[TrainLogits]:
        return [TrainLogits(self.pair_logits(emb), "logit", 1.0)]
