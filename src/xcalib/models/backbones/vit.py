"""A crop-sized Vision Transformer written here: conv patch embedding, CLS token, learned
position embedding, pre-norm ``nn.TransformerEncoder`` (GELU), final LayerNorm.
Input [N,3,S,S] normalised crops; output [N, embed_dim]."""

from __future__ import annotations

import torch
from torch import nn

__all__ = ["CropViT"]


class CropViT(nn.Module):
    def __init__(self, img_size: int = 64, patch_size: int = 8, embed_dim: int = 256, depth: int = 6,
                 num_heads: int = 8, mlp_ratio: float = 4.0, dropout: float = 0.0, pool: str = "cls"):
        super().__init__()
        if img_size % patch_size:
            raise ValueError(f"vit: crop_size {img_size} must be a multiple of patch_size {patch_size}")
        if embed_dim % num_heads:
            raise ValueError(f"vit: embed_dim {embed_dim} must be divisible by num_heads {num_heads}")
        if pool not in ("cls", "mean"):
            raise ValueError(f"vit.pool must be 'cls' or 'mean', got {pool!r}")
        n = (img_size // patch_size) ** 2
        self.patch = nn.Conv2d(3, embed_dim, patch_size, patch_size)
        self.cls_token = nn.Parameter(torch.zeros(1, 1, embed_dim))
        self.pos_embed = nn.Parameter(torch.zeros(1, n + 1, embed_dim))
        nn.init.trunc_normal_(self.cls_token, std=0.02)
        nn.init.trunc_normal_(self.pos_embed, std=0.02)
        layer = nn.TransformerEncoderLayer(embed_dim, num_heads, int(embed_dim * mlp_ratio), dropout,
                                           activation="gelu", batch_first=True, norm_first=True)
        self.encoder = nn.TransformerEncoder(layer, depth, enable_nested_tensor=False)
        self.norm = nn.LayerNorm(embed_dim)
        self.pool = pool
        self.img_size = img_size
        self.out_dim = embed_dim

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if x.shape[-1] != self.img_size or x.shape[-2] != self.img_size:
            raise ValueError(f"vit: expected crops of {self.img_size}x{self.img_size}, got {tuple(x.shape[-2:])}")
        t = self.patch(x).flatten(2).transpose(1, 2)
        t = torch.cat([self.cls_token.expand(t.shape[0], -1, -1), t], dim=1) + self.pos_embed  # traceable N
        t = self.norm(self.encoder(t))
        return t[:, 0] if self.pool == "cls" else t[:, 1:].mean(dim=1)
