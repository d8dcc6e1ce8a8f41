"""Confidence-weighted matching loss on pseudo-labels.

For every model output (``TrainLogits``) of a multi-frame batch:

* cross-entropy over the rows and the columns that hold a pseudo-match, each term weighted by
  that match's confidence (weights normalised to sum 1); logits of other frames' detections and
  of ambiguous pairs (neither pseudo-match nor geometric negative) are masked out;
* outputs of kind "logit" add a class-balanced binary cross-entropy: positives weighted by
  confidence, geometric negatives weight 1, ambiguous pairs ignored.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

__all__ = ["weighted_matching_loss"]


def _weighted_ce(L: torch.Tensor, pos: torch.Tensor, w: torch.Tensor, allowed: torch.Tensor) -> torch.Tensor:
    rows = pos.any(dim=1)
    if not rows.any():
        return L.new_zeros(())
    S = L[rows].masked_fill(~(allowed[rows] | pos[rows]), float("-inf"))
    tgt = S.masked_fill(~pos[rows], float("-inf"))
    ce = torch.logsumexp(S, 1) - torch.logsumexp(tgt, 1)
    rw = (w[rows] * pos[rows]).sum(1)
    return (rw * ce).sum() / rw.sum().clamp_min(1e-8)


def weighted_matching_loss(outputs, batch, positive: torch.Tensor, weight: torch.Tensor,
                           negative: torch.Tensor) -> torch.Tensor:
    """Sum over outputs of ``out.weight`` x (weighted row/column CE [+ balanced weighted BCE]).

    positive / negative: [N,M] bool over the whole batch (block-diagonal by frame); weight: [N,M]
    float confidences of the positives.
    """
    same = batch.same_frame()
    pos = positive & same
    neg = negative & same
    allowed = pos | neg
    total = weight.new_zeros((), dtype=torch.float32)
    for out in outputs:
        L = out.logits.float()
        ce = 0.5 * (_weighted_ce(L, pos, weight, allowed) + _weighted_ce(L.T, pos.T, weight.T, allowed.T))
        if out.kind == "logit":
            bce = F.binary_cross_entropy_with_logits(L, pos.float(), reduction="none")
            terms = []
            if pos.any():
                wp = weight[pos]
                terms.append((bce[pos] * wp).sum() / wp.sum().clamp_min(1e-8))
            if neg.any():
                terms.append(bce[neg].mean())
            if terms:
                ce = ce + sum(terms) / len(terms)
        total = total + out.weight * ce
    return total
