"""Adapting a matching model on pseudo-labelled observations (partial or full fine-tune).

Modes (which parameters train; the rest stay frozen):

* ``"heads"`` — everything except the per-modality feature backbones (``img_backbone``,
  ``lid_backbone``): position/geometry encoders, projections, fusion and pair heads;
* ``"full"`` — every parameter (training from scratch, e.g. ``xcalib bootstrap`` without a
  starting site).

The model stays in eval mode (dropout off, normalisation statistics frozen), the loss is
:func:`xcalib.oneshot.loss.weighted_matching_loss`, and an L2 pull towards the starting weights
(``anchor``) keeps a few frames from dragging the model far. Top-1 against the pseudo-labels is
measured on the **same** held-out observations, with the same crops and point samples, before and
after. The starting weights are restored when training produces non-finite weights, and (unless
``keep_if_worse``) when held-out Top-1 drops.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np
import torch

from ..engine.trainer import evaluate
from .evidence import Observation
from .loss import weighted_matching_loss
from .pseudo import PseudoTargets

__all__ = ["AdaptReport", "ADAPT_MODES", "BOX_GAIN_SCALE", "auto_box_gain", "trainable_parameters", "pseudo_top1",
           "adapt_model", "holdout_split"]

log = logging.getLogger("xcalib.oneshot")

ADAPT_MODES = ("heads", "full")
_BACKBONES = ("img_backbone.", "lid_backbone.")


@dataclass
class AdaptReport:
    """What one ``adapt`` call did. Top-1 values are fractions of held-out camera detections whose
    best-scoring LiDAR box is their pseudo-match (NaN without held-out pseudo-matches)."""

    trained: bool
    mode: str
    steps: int = 0
    n_train_frames: int = 0
    n_heldout_frames: int = 0
    n_pairs: int = 0
    n_heldout_pairs: int = 0
    n_trainable: int = 0
    loss_first: float = float("nan")
    loss_last: float = float("nan")
    top1_before: float = float("nan")
    top1_after: float = float("nan")
    reverted: bool = False
    message: str = ""
    elapsed_s: float = 0.0
    box_gain: float = float("nan")
    losses: list[float] = field(default_factory=list)

    def to_dict(self) -> dict:
        d = dict(self.__dict__)
        d["losses"] = [float(v) for v in self.losses]
        return d


def trainable_parameters(model: torch.nn.Module, mode: str) -> list[tuple[str, torch.nn.Parameter]]:
    """(name, parameter) pairs that ``mode`` trains (see the module docstring)."""
    if mode not in ADAPT_MODES:
        raise ValueError(f"adapt mode must be one of {ADAPT_MODES}, got {mode!r}")
    out = [(n, p) for n, p in model.named_parameters() if mode == "full" or not n.startswith(_BACKBONES)]
    if not out:
        raise ValueError(f"adapt mode {mode!r}: model {getattr(model, 'model_name', '?')} has no parameter outside "
                         "its backbones; use mode='full'")
    return out


@dataclass
class _Labelled:
    """An observation with a ground-truth-like matrix, the shape ``trainer.evaluate`` reads."""

    obs: Observation
    gt: np.ndarray

    def inputs(self, n_points: int, rng: np.random.Generator):
        return self.obs.inputs(n_points, rng)


def pseudo_top1(model, observations: Sequence[Observation], targets: Sequence[PseudoTargets], n_points: int,
                device, seed: int) -> float:
    """Top-1 of ``model`` against pseudo-matches (NaN when there is none); deterministic crops."""
    items = [_Labelled(o, t.positive) for o, t in zip(observations, targets) if t.n_pairs and not o.empty]
    if not items:
        return float("nan")
    return float(evaluate(model, items, n_points, device, seed).result().top1)


def holdout_split(n: int, fraction: float) -> tuple[np.ndarray, np.ndarray]:
    """(train indices, held-out indices): every k-th frame held out (deterministic, spread in time)."""
    if not (0.0 <= fraction < 1.0):
        raise ValueError(f"holdout must be a fraction in [0, 1), got {fraction}")
    n_hold = int(math.floor(n * fraction))
    if n_hold == 0:
        return np.arange(n), np.zeros(0, np.int64)
    hold = np.unique(np.round(np.linspace(0, n - 1, n_hold + 2)[1:-1]).astype(np.int64))
    return np.setdiff1d(np.arange(n), hold), hold


def _block(targets: Sequence[PseudoTargets], device) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    n = sum(t.positive.shape[0] for t in targets)
    m = sum(t.positive.shape[1] for t in targets)
    pos, neg = np.zeros((n, m), bool), np.zeros((n, m), bool)
    w = np.zeros((n, m), np.float32)
    i = j = 0
    for t in targets:
        a, b = t.positive.shape
        pos[i:i + a, j:j + b], neg[i:i + a, j:j + b], w[i:i + a, j:j + b] = t.positive, t.negative, t.weight
        i, j = i + a, j + b
    return (torch.from_numpy(pos).to(device), torch.from_numpy(w).to(device), torch.from_numpy(neg).to(device))


def _box_features(rects: np.ndarray, wh: tuple[int, int]) -> np.ndarray:
    """[M,4] px rectangles -> [M,4] (centre x, y as image fractions, log width, log height fractions)."""
    W, H = wh
    w = np.maximum(rects[:, 2] - rects[:, 0], 1e-3) / W
    h = np.maximum(rects[:, 3] - rects[:, 1], 1e-3) / H
    return np.stack([(rects[:, 0] + rects[:, 2]) / (2 * W), (rects[:, 1] + rects[:, 3]) / (2 * H), np.log(w),
                     np.log(h)], 1)


BOX_GAIN_SCALE = 3.4  # box_gain="auto": gain x mean pair residual; chosen on bench_oneshot's tuning sequences


def auto_box_gain(observations: Sequence[Observation], targets: Sequence[PseudoTargets], augment,
                  lo: float = 1.0, hi: float = 100.0) -> float:
    """``BOX_GAIN_SCALE`` / mean norm of (2D box - projected 3D box) features over the pseudo-matches
    (centre as image fractions, log sizes; the site's detector-vs-pose noise), clipped to [lo, hi]:
    sharp sites get a sharp box term, loose detections or poses a gentle one. ``lo`` without pairs."""
    res = []
    for o, t in zip(observations, targets):
        i, j = np.nonzero(t.positive)
        if o.empty or not len(i):
            continue
        fi = o.inputs(1, np.random.default_rng(0))
        r = augment.project(fi, None)
        d = _box_features(fi.boxes_2d[i].astype(np.float64), fi.image_size) - _box_features(r[j], fi.image_size)
        res.append(np.linalg.norm(d, axis=1))
    r = np.concatenate(res) if res else np.zeros(0)
    r = r[np.isfinite(r)]
    if not len(r):
        return float(lo)
    return float(np.clip(BOX_GAIN_SCALE / max(float(r.mean()), 1e-6), lo, hi))


def _box_loss(box_lid: torch.Tensor, fis, tgs, augment, device) -> torch.Tensor:
    """Mean squared error of predicted 2D boxes [M,4] against the pose's (NaN rows skipped)."""
    tgt = np.concatenate([_box_features(augment.project(fi, t), fi.image_size) for fi, t in zip(fis, tgs)])
    ok = np.isfinite(tgt).all(1)
    if not ok.any():
        return box_lid.new_zeros(())
    sel = torch.from_numpy(np.flatnonzero(ok)).to(device)
    return ((box_lid[sel] - torch.from_numpy(tgt[ok]).to(box_lid)) ** 2).sum(1).mean()


def adapt_model(model, observations: Sequence[Observation], targets: Sequence[PseudoTargets], *, steps: int,
                n_points: int, device, mode: str = "heads", lr: float = 1e-3, frames_per_batch: int = 4,
                anchor: float = 1e-2, holdout: float = 0.2, grad_clip: float = 5.0, keep_if_worse: bool = False,
                min_pairs: int = 8, eval_seed: int = 0, seed: int = 0, augment=None, p_augment: float = 1.0,
                box_weight: float = 0.0, box_gain: float | str | None = None,
                progress: Callable[[int, int, float], None] | None = None) -> AdaptReport:
    """Fine-tune ``model`` in place on pseudo-labelled ``observations`` (see the module docstring).

    ``augment``: optional :class:`xcalib.oneshot.augment.GeometricAugment` applied to a share
    ``p_augment`` of the training frames. ``box_weight`` > 0 (with ``augment``, for models whose
    embeddings carry ``box_lid``/``box_img``, e.g. fastmatch): adds ``box_weight`` x the mean
    squared error of the model's predicted 2D box of every 3D box against where the pose puts it
    (:meth:`GeometricAugment.project`), so the geometry branch learns the site's projection.
    ``box_gain``: for models with ``set_box_gain`` (fastmatch), set the gain on the pair head's
    box differences before training without rescaling its weights, i.e. the box term starts
    (gain / old gain)^2 times stronger: with a known pose the geometry is what transfers, and
    differences of a few pixels (small, far objects) become resolvable (the old gain comes back on
    revert; Top-1 before is measured with it). ``"auto"`` (needs ``augment``): :func:`auto_box_gain`
    over the training frames. Returns an :class:`AdaptReport`; ``trained=False``
    (weights untouched) when fewer than ``min_pairs`` pseudo-matches are available for training.
    """
    from ..models.inputs import ModelBatch

    t0 = time.perf_counter()
    if steps < 0:
        raise ValueError(f"steps must be >= 0, got {steps}")
    if frames_per_batch < 1:
        raise ValueError(f"frames_per_batch must be >= 1, got {frames_per_batch}")
    named = trainable_parameters(model, mode)
    usable = [k for k, o in enumerate(observations) if not o.empty]
    tr_rel, ho_rel = holdout_split(len(usable), holdout)
    tr = [usable[k] for k in tr_rel]
    ho = [usable[k] for k in ho_rel]
    n_pairs = int(sum(targets[k].n_pairs for k in tr))
    rep = AdaptReport(trained=False, mode=mode, n_train_frames=len(tr), n_heldout_frames=len(ho), n_pairs=n_pairs,
                      n_heldout_pairs=int(sum(targets[k].n_pairs for k in ho)),
                      n_trainable=int(sum(p.numel() for _, p in named)))
    ho_obs, ho_t = [observations[k] for k in ho], [targets[k] for k in ho]
    rep.top1_before = pseudo_top1(model, ho_obs, ho_t, n_points, device, eval_seed)
    if n_pairs < max(1, min_pairs) or steps == 0:
        rep.message = (f"not trained: {n_pairs} pseudo-labelled pair(s) in {len(tr)} training frame(s), need at least "
                       f"{max(1, min_pairs)}" if steps else "not trained: steps=0")
        rep.top1_after = rep.top1_before
        rep.elapsed_s = time.perf_counter() - t0
        return rep

    start = {k: v.detach().clone() for k, v in model.state_dict().items()}
    old_gain = getattr(model, "box_gain", None)
    if box_gain == "auto":
        box_gain = auto_box_gain([observations[k] for k in tr], [targets[k] for k in tr], augment) \
            if augment is not None else None
    if box_gain is not None and hasattr(model, "set_box_gain"):
        model.set_box_gain(float(box_gain), rescale=False)
        rep.box_gain = float(box_gain)
    anchors = [p.detach().clone() for _, p in named]
    flags = {n: p.requires_grad for n, p in model.named_parameters()}
    train_names = {n for n, _ in named}
    for n, p in model.named_parameters():
        p.requires_grad_(n in train_names)
    params = [p for _, p in named]
    opt = torch.optim.Adam(params, lr=lr)
    rng = np.random.default_rng([seed, 17])
    torch.manual_seed(seed)
    was_training = model.training
    model.eval()
    order = np.zeros(0, np.int64)
    try:
        for step in range(steps):
            if len(order) < frames_per_batch:
                order = np.concatenate([order, rng.permutation(len(tr))])
            pick, order = order[:frames_per_batch], order[frames_per_batch:]
            fis, tg = [], []
            for i in pick:
                fi, t = observations[tr[i]].inputs(n_points, rng), targets[tr[i]]
                if augment is not None and rng.random() < p_augment:
                    fi, t = augment.apply(fi, t, rng)
                fis.append(fi)
                tg.append(t)
            batch = ModelBatch.from_frames(fis, device)
            pos, w, neg = _block(tg, device)
            for g in opt.param_groups:  # cosine decay to 5% of lr
                g["lr"] = lr * (0.05 + 0.95 * 0.5 * (1 + math.cos(math.pi * step / max(steps, 1))))
            emb = model.embed(batch)
            loss = weighted_matching_loss(model.train_logits(emb, batch), batch, pos, w, neg)
            if box_weight > 0 and augment is not None and "box_lid" in emb.extra:
                loss = loss + box_weight * _box_loss(emb.extra["box_lid"], fis, tg, augment, device)
            if anchor > 0:
                loss = loss + anchor * sum(((p - a) ** 2).sum() for p, a in zip(params, anchors))
            opt.zero_grad(set_to_none=True)
            if loss.requires_grad:
                loss.backward()
                if grad_clip:
                    torch.nn.utils.clip_grad_norm_(params, grad_clip)
                opt.step()
            rep.losses.append(float(loss.detach()))
            if progress is not None:
                progress(step + 1, steps, rep.losses[-1])
    finally:
        for n, p in model.named_parameters():
            p.requires_grad_(flags[n])
        model.train(was_training)
        model.eval()
    rep.steps = steps
    rep.loss_first, rep.loss_last = rep.losses[0], float(np.mean(rep.losses[-max(1, steps // 10):]))
    finite = all(torch.isfinite(v).all() for v in model.state_dict().values() if v.is_floating_point())
    rep.top1_after = pseudo_top1(model, ho_obs, ho_t, n_points, device, eval_seed) if finite else float("nan")
    worse = np.isfinite(rep.top1_before) and np.isfinite(rep.top1_after) and rep.top1_after < rep.top1_before
    if not finite or (worse and not keep_if_worse):
        model.load_state_dict(start)
        if old_gain is not None and hasattr(model, "set_box_gain"):
            model.set_box_gain(old_gain, rescale=False)
        rep.reverted = True
        rep.message = ("reverted: training produced non-finite weights" if not finite else
                       f"reverted: held-out Top-1 against pseudo-labels fell from {rep.top1_before:.3f} to "
                       f"{rep.top1_after:.3f}")
        log.warning("one-shot adapt %s", rep.message)
        rep.top1_after = rep.top1_before
    else:
        rep.trained = True
        rep.message = f"trained {steps} steps on {n_pairs} pseudo-labelled pairs in {len(tr)} frames"
    rep.elapsed_s = time.perf_counter() - t0
    return rep
