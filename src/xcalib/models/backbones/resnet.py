"""Image backbones written here (no torchvision): a plain tiny ResNet-style stack and a
bottleneck ResNet. Input [N,3,S,S] normalised crops; any crop size (global average pool)."""

from __future__ import annotations

from typing import Sequence

import torch
from torch import nn

from ..layers import SafeBatchNorm1d

__all__ = ["ResNetEmbeddingDeep", "BottleneckResNet", "SmallCNN", "conv_bn_relu", "conv_stack"]


def conv_bn_relu(c_in: int, c_out: int, stride: int = 1) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(c_in, c_out, 3, stride, 1, bias=False), nn.BatchNorm2d(c_out),
                         nn.ReLU(inplace=True))


def conv_stack(widths: Sequence[int], strides: Sequence[int]) -> tuple[nn.Sequential, int]:
    """conv3x3+BN+ReLU stages from 3 input channels -> (the stack, its output channels)."""
    layers, c = [], 3
    for w, s in zip(widths, strides):
        layers.append(conv_bn_relu(c, w, s))
        c = w
    return nn.Sequential(*layers), c


class ResNetEmbeddingDeep(nn.Module):
    """crlite image branch: conv3x3+BN+ReLU 3->32->64(s2)->64->128(s2)->128->256(s2), global
    average pool, head Linear 256->256 + BN + ReLU + Dropout -> Linear ->E + ReLU -> Linear E->E."""

    def __init__(self, embed_dim: int = 256, widths: Sequence[int] = (32, 64, 64, 128, 128, 256),
                 strides: Sequence[int] = (1, 2, 1, 2, 1, 2), dropout: float = 0.1):
        super().__init__()
        self.features, c = conv_stack(widths, strides)
        self.head = nn.Sequential(nn.Linear(c, c), SafeBatchNorm1d(c), nn.ReLU(inplace=True), nn.Dropout(dropout),
                                  nn.Linear(c, embed_dim), nn.ReLU(inplace=True), nn.Linear(embed_dim, embed_dim))
        self.out_dim = embed_dim

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.head(self.features(x).mean(dim=(2, 3)))


class SmallCNN(nn.Module):
    """Fast image branch: strided conv3x3+BN+ReLU stages, global average + max pool -> [N, 2*C]."""

    def __init__(self, widths: Sequence[int] = (16, 32, 64), strides: Sequence[int] = (2, 2, 2)):
        super().__init__()
        self.features, c = conv_stack(widths, strides)
        self.out_dim = 2 * c

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        f = self.features(x)
        return torch.cat([f.mean(dim=(2, 3)), f.amax(dim=(2, 3))], dim=1)


class _Bottleneck(nn.Module):
    expansion = 4

    def __init__(self, c_in: int, width: int, stride: int):
        super().__init__()
        c_out = width * self.expansion
        self.body = nn.Sequential(
            nn.Conv2d(c_in, width, 1, bias=False), nn.BatchNorm2d(width), nn.ReLU(inplace=True),
            nn.Conv2d(width, width, 3, stride, 1, bias=False), nn.BatchNorm2d(width), nn.ReLU(inplace=True),
            nn.Conv2d(width, c_out, 1, bias=False), nn.BatchNorm2d(c_out))
        self.short = (nn.Identity() if stride == 1 and c_in == c_out else
                      nn.Sequential(nn.Conv2d(c_in, c_out, 1, stride, bias=False), nn.BatchNorm2d(c_out)))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return torch.relu(self.body(x) + self.short(x))


class BottleneckResNet(nn.Module):
    """calibrefine image branch: stem conv3x3 (s1), bottleneck stages (x4 expansion) with
    strides 1,2,2,2, adaptive average pool (any crop size) -> Linear -> ``embed_dim``, plus a
    ``num_classes`` log-softmax head. Returns (embedding [N,E], class log-probs [N,C])."""

    def __init__(self, num_blocks: Sequence[int] = (2, 2, 2, 2), base_width: int = 64,
                 embed_dim: int = 512, num_classes: int = 10):
        super().__init__()
        self.stem = conv_bn_relu(3, base_width, 1)
        stages, c = [], base_width
        for i, n in enumerate(num_blocks):
            width = base_width * (2 ** i)
            for j in range(int(n)):
                stages.append(_Bottleneck(c, width, (1 if i == 0 else 2) if j == 0 else 1))
                c = width * _Bottleneck.expansion
        self.stages = nn.Sequential(*stages)
        self.embed = nn.Linear(c, embed_dim)
        self.cls = nn.Linear(embed_dim, num_classes)
        self.out_dim = embed_dim

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        e = self.embed(self.stages(self.stem(x)).mean(dim=(2, 3)))
        return e, torch.log_softmax(self.cls(e), dim=1)
