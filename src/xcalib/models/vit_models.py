"""ViT family: crlite_vit_exp1 (appearance only), crlite_vit_exp3 (+ position encodings, used
in training AND inference), crlite_vit_exp4 (+ structure-aware GNNs over each frame's
detections). All score with the cosine of the embeddings, range [-1,1]."""

from __future__ import annotations

import torch
from torch import nn

from .backbones.gnn import StructureGNN
from .backbones.pointnet import PointNetEmbedding
from .backbones.vit import CropViT
from .base import Embeddings, MatchingModel
from .crlite import PositionFusion
from .inputs import ModelBatch
from .registry import register_model

__all__ = ["ViTExp1", "ViTExp3", "ViTExp4"]


@register_model("crlite_vit_exp1")
class ViTExp1(MatchingModel):
    score_range = (-1.0, 1.0)

    def __init__(self, config):
        super().__init__(config)
        c = self.config
        E = int(c["embed_dim"])
        v = dict(c.get("vit") or {})
        D = int(v.get("embed_dim", E))
        self.img_backbone = CropViT(int(c["crop_size"]), int(v.get("patch_size", 8)), D, int(v.get("depth", 6)),
                                    int(v.get("num_heads", 8)), float(v.get("mlp_ratio", 4.0)),
                                    float(v.get("dropout", 0.0)), v.get("pool", "cls"))
        self.img_proj = (nn.Identity() if D == E else
                         nn.Sequential(nn.Linear(D, E), nn.LayerNorm(E), nn.GELU()))
        self.lid_backbone = PointNetEmbedding(E)

    def backbone(self, batch: ModelBatch) -> tuple[torch.Tensor, torch.Tensor]:
        return self.img_proj(self.img_backbone(batch.crops_2d)), self.lid_backbone(batch.crops_3d)

    def embed(self, batch: ModelBatch) -> Embeddings:
        return Embeddings(*self.backbone(batch))


@register_model("crlite_vit_exp3")
class ViTExp3(ViTExp1):
    def __init__(self, config):
        super().__init__(config)
        c = self.config
        self.position = PositionFusion(int(c["embed_dim"]), int(c["token_len"]), float(c.get("max_depth", 100.0)),
                                       c.get("pe_mode", "full"))

    def embed(self, batch: ModelBatch) -> Embeddings:
        fi, fl = self.backbone(batch)
        return Embeddings(*self.position(fi, fl, batch))


@register_model("crlite_vit_exp4")
class ViTExp4(ViTExp1):
    def __init__(self, config):
        super().__init__(config)
        c = self.config
        g = dict(c.get("gnn") or {})
        kw = dict(edge_dim=int(g.get("edge_dim", 8)), hidden=int(g.get("hidden_dim", 128)),
                  num_layers=int(g.get("num_layers", 2)), k_neighbors=int(g.get("k_neighbors", 4)),
                  dropout=float(g.get("dropout", 0.1)))
        E = int(c["embed_dim"])
        self.camera_gnn = StructureGNN(E, 3, **kw)
        self.lidar_gnn = StructureGNN(E, 5, **kw)

    def embed(self, batch: ModelBatch) -> Embeddings:
        fi, fl = self.backbone(batch)
        b2, wh = batch.boxes_2d, batch.image_wh
        uv = torch.stack([(b2[:, 0] + b2[:, 2]) / 2, (b2[:, 1] + b2[:, 3]) / 2], 1) / wh
        area = ((b2[:, 2] - b2[:, 0]) * (b2[:, 3] - b2[:, 1])).clamp_min(1.0)

        def cam_edges(src, dst):
            duv = (uv[src] - uv[dst]).clamp(-2, 2)
            return torch.cat([duv, torch.log(area[src] / area[dst]).clamp(-5, 5)[:, None]], 1)

        xyz = batch.boxes_3d[:, :3]
        # per-frame normalisation: centre on the frame mean, scale by the largest norm (>= 1 m)
        nf = batch.n_frames
        cnt = torch.zeros(nf, device=xyz.device).index_add(0, batch.seg_3d, torch.ones(len(xyz), device=xyz.device))
        mean = torch.zeros(nf, 3, device=xyz.device).index_add(0, batch.seg_3d, xyz) / cnt.clamp_min(1)[:, None]
        rel = xyz - mean[batch.seg_3d]
        scale = torch.ones(nf, device=xyz.device).scatter_reduce(0, batch.seg_3d, rel.norm(dim=1), "amax")
        pos = rel / scale[batch.seg_3d][:, None]
        vol = batch.boxes_3d[:, 3:6].clamp_min(1e-3).prod(dim=1)

        def lid_edges(src, dst):
            d = (pos[src] - pos[dst])
            return torch.cat([d.clamp(-5, 5), d.norm(dim=1, keepdim=True).clamp(0, 10),
                              torch.log(vol[src] / vol[dst]).clamp(-5, 5)[:, None]], 1)

        fi = self.camera_gnn(fi, uv, batch.seg_2d, cam_edges)
        fl = self.lidar_gnn(fl, pos, batch.seg_3d, lid_edges)
        return Embeddings(fi, fl)
