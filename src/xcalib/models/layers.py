"""Small shared layers: batch-size-safe BatchNorm, MLP helpers."""

from __future__ import annotations

from typing import Sequence

import torch
import torch.nn.functional as F
from torch import nn

__all__ = ["SafeBatchNorm1d", "linear_ln_relu", "mlp"]


class SafeBatchNorm1d(nn.BatchNorm1d):
    """BatchNorm1d that accepts a batch of one in training mode.

    With one sample per channel the batch statistics are undefined (plain BatchNorm raises);
    this layer then normalises with its running statistics and leaves them unchanged, so a
    frame with a single detection trains instead of crashing.
    """

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if self.training and (x.shape[0] * (x.shape[2] if x.dim() == 3 else 1)) <= 1:
            return F.batch_norm(x, self.running_mean, self.running_var, self.weight, self.bias,
                                False, 0.0, self.eps)
        return super().forward(x)


def linear_ln_relu(d_in: int, d_out: int, dropout: float = 0.0) -> nn.Sequential:
    """Linear + LayerNorm + ReLU (+ Dropout)."""
    layers: list[nn.Module] = [nn.Linear(d_in, d_out), nn.LayerNorm(d_out), nn.ReLU(inplace=True)]
    if dropout > 0:
        layers.append(nn.Dropout(dropout))
    return nn.Sequential(*layers)


def mlp(dims: Sequence[int], *, dropout: float = 0.0, norm: str = "ln", last_act: bool = False) -> nn.Sequential:
    """Stack of Linear(+norm+ReLU) layers over ``dims``; the last layer is plain unless ``last_act``."""
    layers: list[nn.Module] = []
    for i in range(len(dims) - 1):
        layers.append(nn.Linear(dims[i], dims[i + 1]))
        if i < len(dims) - 2 or last_act:
            if norm == "ln":
                layers.append(nn.LayerNorm(dims[i + 1]))
            elif norm == "bn":
                layers.append(SafeBatchNorm1d(dims[i + 1]))
            layers.append(nn.ReLU(inplace=True))
            if dropout > 0:
                layers.append(nn.Dropout(dropout))
    return nn.Sequential(*layers)
