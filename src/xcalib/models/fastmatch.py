"""fastmatch: our CPU-first matcher.

Image side: a 3-stage strided CNN on small crops + 2D box geometry (centre, size, aspect,
bottom edge as fractions of the image size). LiDAR side: a light PointNet on few points + 3D
box geometry (centre and range in units of ``geo_scale_m`` metres, bearing, log dims, log
point count, point spread in the box frame). A small MLP also maps the 3D geometry to
a predicted 2D box (centre, size as image fractions; it learns the site's projection). Scored
by a tiny pair head over [e_i * e_j, |e_i - e_j|, cos, (box_gain x (2D box - predicted 2D box))^2];
score = sigmoid pair probability in [0,1] for every pair. ``box_gain`` (config, default 1) only
changes how the pair head's box weights are parametrised (:meth:`FastMatch.set_box_gain` keeps
the function): one-shot adaptation raises it so that training can resolve box differences of a
few pixels (small, far objects) at ordinary learning rates.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from .backbones.pointnet import TinyPointNet
from .backbones.resnet import SmallCNN
from .base import Embeddings, MatchingModel, TrainLogits
from .inputs import ModelBatch
from .layers import mlp
from .registry import register_model

__all__ = ["FastMatch", "geometry_2d", "geometry_3d", "box_features"]

N_GEO_2D, N_GEO_3D = 9, 14


def geometry_2d(boxes: torch.Tensor, wh: torch.Tensor) -> torch.Tensor:
    """[N,4] px boxes + [N,2] image size -> [N,9] unit-free features."""
    x1, y1, x2, y2 = (boxes[:, i] / wh[:, i % 2] for i in range(4))
    w, h = (x2 - x1).clamp_min(1e-4), (y2 - y1).clamp_min(1e-4)
    return torch.stack([(x1 + x2) / 2, (y1 + y2) / 2, w, h, torch.log(w / h), torch.log(w * h), y2, x1, x2], 1)


def _box_part(g2: torch.Tensor) -> torch.Tensor:
    """[N,9] ``geometry_2d`` features -> [N,4] (centre x, y, log width, log height; image fractions)."""
    return torch.cat([g2[:, :2], torch.log(g2[:, 2:4])], 1)


def box_features(boxes: torch.Tensor, wh: torch.Tensor) -> torch.Tensor:
    """[N,4] px boxes + [N,2] image size -> [N,4] box space of fastmatch's pair head: the 2D
    boxes' ``box_img`` and what ``box_lid`` predicts for a 3D box (NaN rows stay NaN)."""
    return _box_part(geometry_2d(boxes, wh))


def geometry_3d(box7: torch.Tensor, counts: torch.Tensor, pts: torch.Tensor, scale_m: float) -> torch.Tensor:
    """box7 [M,7] m, counts [M], box-frame points [M,P,3] m -> [M,14] features."""
    xyz = box7[:, :3]
    rng = torch.linalg.norm(xyz[:, :2], dim=1)
    bearing = torch.atan2(xyz[:, 1], xyz[:, 0])
    spread = pts.std(dim=1, unbiased=False) / box7[:, 3:6].clamp_min(1e-2)
    zr = (pts[:, :, 2].amax(1) - pts[:, :, 2].amin(1)) / box7[:, 5].clamp_min(1e-2)
    return torch.cat([xyz / scale_m, (rng / scale_m)[:, None], torch.cos(bearing)[:, None],
                      torch.sin(bearing)[:, None], torch.log(box7[:, 3:6].clamp_min(1e-2)),
                      torch.log1p(counts)[:, None] / 5, spread, zr[:, None]], 1)


@register_model("fastmatch")
class FastMatch(MatchingModel):
    score_range = (0.0, 1.0)

    def __init__(self, config):
        super().__init__(config)
        c = self.config
        E, G = int(c.get("embed_dim", 64)), int(c.get("geo_dim", 64))
        self.geo_scale_m = float(c.get("geo_scale_m", 50.0))
        self.img_backbone = SmallCNN(tuple(c.get("cnn_widths", (16, 32, 64))))
        self.lid_backbone = TinyPointNet((3, *c.get("pointnet_dims", (32, 64, 128))))
        self.img_geo = mlp([N_GEO_2D, G, G], last_act=True)
        self.lid_geo = mlp([N_GEO_3D, G, G], last_act=True)
        self.img_head = mlp([self.img_backbone.out_dim + G, 2 * E, E])
        self.lid_head = mlp([self.lid_backbone.out_dim + G, 2 * E, E])
        self.lid_to_box = mlp([N_GEO_3D, 2 * G, 2 * G, 4])
        self.pair_head = mlp([2 * E + 1 + 4, int(c.get("pair_hidden", 64)), 1])
        self.cosine_weight = float(c.get("cosine_weight", 0.5))
        self.box_gain = float(c.get("box_gain", 1.0))

    box_features = staticmethod(box_features)

    def set_box_gain(self, gain: float, *, rescale: bool = True) -> None:
        """Set ``box_gain`` (> 0, unit-free); with ``rescale`` the pair head's box-difference weights
        are divided by (gain / old gain)^2, so every score stays the same."""
        gain = float(gain)
        if not (gain > 0 and gain < float("inf")):
            raise ValueError(f"box_gain must be a finite number > 0, got {gain}")
        if rescale and gain != self.box_gain:
            with torch.no_grad():
                self.pair_head[0].weight[:, -4:] *= (self.box_gain / gain) ** 2
        self.box_gain = gain
        self.config["box_gain"] = gain

    def embed(self, batch: ModelBatch) -> Embeddings:
        g2 = geometry_2d(batch.boxes_2d, batch.image_wh)
        g3 = geometry_3d(batch.boxes_3d, batch.point_counts, batch.crops_3d, self.geo_scale_m)
        gi, gl = self.img_geo(g2), self.lid_geo(g3)
        fi = self.img_head(torch.cat([self.img_backbone(batch.crops_2d), gi], 1))
        fl = self.lid_head(torch.cat([self.lid_backbone(batch.crops_3d), gl], 1))
        extra = {"box_img": _box_part(g2), "box_lid": self.lid_to_box(g3)}
        return Embeddings(F.normalize(fi, dim=1), F.normalize(fl, dim=1), extra)

    def score_pairs(self, a: torch.Tensor, box_img: torch.Tensor, b: torch.Tensor,
                    box_lid: torch.Tensor) -> torch.Tensor:
        """Pair logits [...] from img [..., E], box_img [..., 4], lid [..., E], box_lid [..., 4]
        (broadcast against each other)."""
        x = torch.cat([(a * b), (a - b).abs(), (a * b).sum(-1, keepdim=True), (self.box_gain * (box_img - box_lid)) ** 2], -1)
        return self.pair_head(x).squeeze(-1)

    def pair_logits(self, emb: Embeddings) -> torch.Tensor:
        N, M = len(emb.img), len(emb.lid)
        if not (N and M):
            return emb.img.new_zeros((N, M))
        return self.score_pairs(emb.img[:, None], emb.extra["box_img"][:, None], emb.lid[None],
                                emb.extra["box_lid"][None])

    def score(self, emb: Embeddings, batch: ModelBatch) -> torch.Tensor:
        return torch.sigmoid(self.pair_logits(emb))

    def train_logits(self, emb: Embeddings, batch: ModelBatch) -> list[TrainLogits]:
        cos = emb.img @ emb.lid.T / self.temperature
        return [TrainLogits(cos, "cosine", self.cosine_weight), TrainLogits(self.pair_logits(emb), "logit", 1.0)]
