"""``fit``: the one optimisation loop of xcalib (supervised training and one-shot adaptation).

A loop is: per step set the learning rate from a :class:`Schedule`, compute the loss (the
caller's ``loss_at(step)``), clear the gradients, back-propagate, clip the gradient norm, step
the optimiser, record the loss. Checkpoints are the caller's ``on_step`` hook (``xcalib.train``
writes its per-epoch files between calls; one-shot adaptation keeps its start state in memory).
``xcalib.engine.trainer.train`` runs one ``fit`` per epoch; ``xcalib.oneshot.adapt`` one per
adaptation (its results are unchanged bit for bit by the move to this loop).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Iterable, Literal, Sequence

import torch

__all__ = ["Schedule", "make_optimizer", "fit", "OPTIMIZERS", "SCHEDULES"]

OPTIMIZERS = ("adam", "adamw")
SCHEDULES = ("cosine", "none")


@dataclass(frozen=True)
class Schedule:
    """Learning rate per step: linear warm-up over ``warmup_steps`` (``base_lr * (step+1) /
    warmup_steps``), then ``"cosine"`` decay from ``base_lr`` to ``min_lr_ratio * base_lr`` at
    ``total_steps`` (held there after), or ``"none"`` (constant ``base_lr``)."""

    base_lr: float
    total_steps: int
    warmup_steps: int = 0
    min_lr_ratio: float = 0.0
    kind: Literal["cosine", "none"] = "cosine"

    def __post_init__(self) -> None:
        if self.kind not in SCHEDULES:
            raise ValueError(f"scheduler must be one of {SCHEDULES}, got {self.kind!r}")

    def lr_at(self, step: int) -> float:
        w = self.warmup_steps
        if w > 0 and step < w:
            return self.base_lr * (step + 1) / w
        if self.kind == "none":
            return self.base_lr
        span = max(self.total_steps - w, 1)
        r = self.min_lr_ratio
        return self.base_lr * (r + (1 - r) * 0.5 * (1 + math.cos(math.pi * min(step - w, span) / span)))


def make_optimizer(params: Sequence[torch.nn.Parameter], kind: Literal["adam", "adamw"], lr: float,
                   weight_decay: float = 0.0) -> torch.optim.Optimizer:
    """Adam or AdamW over ``params``."""
    if kind == "adam":
        return torch.optim.Adam(params, lr=lr, weight_decay=weight_decay)
    if kind == "adamw":
        return torch.optim.AdamW(params, lr=lr, weight_decay=weight_decay)
    raise ValueError(f"optimizer must be one of {OPTIMIZERS}, got {kind!r}")


def fit(optimizer: torch.optim.Optimizer, params: Sequence[torch.nn.Parameter], schedule: Schedule,
        loss_at: Callable[[int], torch.Tensor], steps: Iterable[int], *, grad_clip: float = 0.0,
        zero_nonfinite: bool = False, on_step: Callable[[int, float], None] | None = None) -> list[float]:
    """Run the optimisation ``steps`` (global step numbers, which the schedule reads); returns the
    per-step losses. ``zero_nonfinite``: a NaN/Inf loss becomes a zero-gradient step (keeps
    distributed ranks stepping together) instead of poisoning the weights. A loss that needs no
    gradient (nothing to train in that batch) is recorded without a step."""
    losses: list[float] = []
    for step in steps:
        lr = schedule.lr_at(step)
        for group in optimizer.param_groups:
            group["lr"] = lr
        loss = loss_at(step)
        if zero_nonfinite and not torch.isfinite(loss):
            loss = loss.nan_to_num(0.0, 0.0, 0.0) * 0.0
        optimizer.zero_grad(set_to_none=True)
        if loss.requires_grad:
            loss.backward()
            if grad_clip:
                torch.nn.utils.clip_grad_norm_(params, grad_clip)
            optimizer.step()
        losses.append(float(loss.detach()))
        if on_step is not None:
            on_step(step, losses[-1])
    return losses
