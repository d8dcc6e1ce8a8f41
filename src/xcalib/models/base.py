"""``MatchingModel``: the interface every registered matcher implements.

Two stages so callers (Matcher, one-shot adaptation, ONNX export) can reach the parts:
``embed(batch) -> Embeddings`` (per-detection vectors, context included) and
``score(emb, batch) -> [N,M]`` (inference similarity; its range is ``score_range``).
``train_logits(emb, batch)`` gives the matrices the trainer's loss uses. Scores between
detections of different frames of a batch are meaningless (the trainer masks them).
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field
from typing import Any

import torch
import torch.nn.functional as F
from torch import nn

from .inputs import ModelBatch

__all__ = ["Embeddings", "TrainLogits", "MatchingModel", "cosine_matrix"]


@dataclass
class Embeddings:
    """img [N,E], lid [M,E]; ``extra`` holds model-specific tensors (e.g. class log-probs)."""

    img: torch.Tensor
    lid: torch.Tensor
    extra: dict[str, torch.Tensor] = field(default_factory=dict)


@dataclass
class TrainLogits:
    """A training score matrix [N,M]; ``kind`` "cosine" (already divided by tau: row/column
    cross-entropy) or "logit" (cross-entropy + binary cross-entropy); ``weight`` in the loss."""

    logits: torch.Tensor
    kind: str = "cosine"
    weight: float = 1.0


def cosine_matrix(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    return F.normalize(a, dim=1) @ F.normalize(b, dim=1).T


class MatchingModel(nn.Module):
    """Base class; subclasses set ``score_range`` and implement embed/score/train_logits."""

    model_name: str = ""
    score_range: tuple[float, float] = (-1.0, 1.0)
    fill_value: float | None = None  # value of pairs a model does not score (None: all scored)

    def __init__(self, config: dict[str, Any]):
        super().__init__()
        self.config = copy.deepcopy(dict(config))
        self.temperature = float(self.config.get("temperature", 0.07))

    def embed(self, batch: ModelBatch) -> Embeddings:
        raise NotImplementedError

    def score(self, emb: Embeddings, batch: ModelBatch) -> torch.Tensor:
        return cosine_matrix(emb.img, emb.lid)

    def train_logits(self, emb: Embeddings, batch: ModelBatch) -> list[TrainLogits]:
        return [TrainLogits(cosine_matrix(emb.img, emb.lid) / self.temperature, "cosine", 1.0)]

    def score_pairs(self, *pair_tensors: torch.Tensor) -> torch.Tensor:
        """Pair-head logits [...] (raw, before the sigmoid) of pairs given as the embedding
        tensors of both sides broadcast to a common leading shape: the image side first
        (``img`` then its ``extra`` tensors in order), then the LiDAR side likewise. Models
        without a pair head (cosine scoring) do not implement it."""
        raise NotImplementedError(f"{self.model_name or type(self).__name__} has no pair head")

    def forward(self, batch: ModelBatch, train: bool = False):
        emb = self.embed(batch)
        return self.train_logits(emb, batch) if train else self.score(emb, batch)

    def num_parameters(self) -> int:
        return int(sum(p.numel() for p in self.parameters()))
