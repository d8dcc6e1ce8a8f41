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

Box-gain selection (fastmatch's pair-head box term, ``box_gain="auto"``): how far to trust the
pose's geometry depends on the site (real detector boxes sit several times further from the
projected 3D boxes than synthetic ones), so each candidate gain is trained from the same start
with the same batches, and the one with the best held-out pseudo-label score wins (Top-1, then
the held-out matching loss; a tie keeps the first, simplest candidate). Every candidate's score
is recorded in :class:`AdaptReport`.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import numpy as np
import torch

from ..engine.fit import Schedule, fit, make_optimizer
from ..engine.trainer import evaluate
from ..options import Options, document, resolve
from .evidence import Observation
from .loss import weighted_matching_loss
from .pseudo import PseudoTargets

__all__ = ["AdaptReport", "GainTrial", "ADAPT_MODES", "BOX_GAIN_SCALE", "auto_box_gain", "trainable_parameters",
           "pseudo_top1", "pseudo_loss", "adapt_model", "holdout_split", "AdaptOptions"]

log = logging.getLogger("xcalib.oneshot")

ADAPT_MODES = ("heads", "full")
_BACKBONES = ("img_backbone.", "lid_backbone.")


@dataclass
class GainTrial:
    """One candidate ``box_gain`` of a selection: its held-out pseudo-label Top-1 (fraction) and
    matching loss (confidence-weighted CE, nats; lower is better) after training, and the
    training loss over its last tenth of steps."""

    box_gain: float
    top1: float = float("nan")
    loss: float = float("nan")
    loss_last: float = float("nan")
    chosen: bool = False


@dataclass
class AdaptReport:
    """What one ``adapt`` call did. Top-1 values are fractions of held-out camera detections whose
    best-scoring LiDAR box is their pseudo-match (NaN without held-out pseudo-matches)."""

    trained: bool
    mode: str
    steps: int = 0
    n_train_frames: int = 0
    n_heldout_frames: int = 0
    heldout_frames: list[int] = field(default_factory=list)  # Observation.index of the held-out frames
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
    gain_trials: list[GainTrial] = field(default_factory=list)
    losses: list[float] = field(default_factory=list)

    @property
    def n_bank_pairs(self) -> int:
        """The reference's name of :attr:`n_pairs` (pseudo-labelled pairs trained on)."""
        return self.n_pairs

    def to_dict(self) -> dict:
        d = dict(self.__dict__)
        d["losses"] = [float(v) for v in self.losses]
        d["gain_trials"] = [dict(g.__dict__) for g in self.gain_trials]
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


def pseudo_loss(model, observations: Sequence[Observation], targets: Sequence[PseudoTargets], n_points: int,
                device, seed: int) -> float:
    """Mean per-frame :func:`weighted_matching_loss` (nats) of ``model`` on pseudo-labelled
    frames, deterministic crops as :func:`pseudo_top1`; NaN when no frame has a pseudo-match."""
    from ..models.inputs import ModelBatch

    vals = []
    with torch.no_grad():
        for o, t in zip(observations, targets):
            if o.empty or not t.n_pairs:
                continue
            b = ModelBatch.from_frames([o.inputs(n_points, np.random.default_rng(seed))], device)
            pos, w, neg = _block([t], device)
            vals.append(float(weighted_matching_loss(model.train_logits(model.embed(b), b), b, pos, w, neg)))
    return float(np.mean(vals)) if vals else float("nan")


def holdout_split(n: int, fraction: float, min_frames: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(train indices, held-out indices): every k-th frame held out (deterministic, spread in time);
    ``floor(n * fraction)`` frames, raised to ``min_frames`` while at least as many stay for training."""
    if not (0.0 <= fraction < 1.0):
        raise ValueError(f"holdout must be a fraction in [0, 1), got {fraction}")
    n_hold = int(math.floor(n * fraction))
    if n_hold < min_frames <= n - min_frames:
        n_hold = int(min_frames)
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


def _box_space(model, rects: np.ndarray, wh: tuple[int, int]) -> np.ndarray:
    """[M,4] px rectangles -> [M,4] in the space the model predicts boxes in
    (``model.box_features``, e.g. fastmatch's centre and log sizes as image fractions)."""
    b = torch.from_numpy(np.asarray(rects, np.float64))
    return model.box_features(b, b.new_tensor([float(wh[0]), float(wh[1])]).expand(len(b), 2)).numpy()


BOX_GAIN_SCALE = 3.4  # box_gain="auto": gain x mean pair residual; chosen on bench_oneshot's tuning sequences


def auto_box_gain(model, observations: Sequence[Observation], targets: Sequence[PseudoTargets], augment,
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
        d = _box_space(model, fi.boxes_2d[i], fi.image_size) - _box_space(model, r[j], fi.image_size)
        res.append(np.linalg.norm(d, axis=1))
    r = np.concatenate(res) if res else np.zeros(0)
    r = r[np.isfinite(r)]
    if not len(r):
        return float(lo)
    return float(np.clip(BOX_GAIN_SCALE / max(float(r.mean()), 1e-6), lo, hi))


def _box_loss(model, box_lid: torch.Tensor, fis, tgs, augment, device) -> torch.Tensor:
    """Mean squared error of predicted 2D boxes [M,4] against the pose's (NaN rows skipped)."""
    tgt = np.concatenate([_box_space(model, augment.project(fi, t), fi.image_size) for fi, t in zip(fis, tgs)])
    ok = np.isfinite(tgt).all(1)
    if not ok.any():
        return box_lid.new_zeros(())
    sel = torch.from_numpy(np.flatnonzero(ok)).to(device)
    return ((box_lid[sel] - torch.from_numpy(tgt[ok]).to(box_lid)) ** 2).sum(1).mean()


def _gain_candidates(box_gain, model, observations, targets, augment) -> list[float | None]:
    """Candidate gains of ``box_gain`` (None: the model's own). "auto" = (None, "residual");
    "residual" = :func:`auto_box_gain` (needs ``augment``, dropped without); duplicates dropped."""
    if box_gain is None or isinstance(box_gain, (int, float)):
        return [None if box_gain is None else float(box_gain)]
    if isinstance(box_gain, str):
        if box_gain not in ("auto", "residual"):
            raise ValueError(f"box_gain must be a number, None, 'auto', 'residual' or a sequence of those, "
                             f"got {box_gain!r}")
        box_gain = (None, "residual") if box_gain == "auto" else ("residual",)
    own = getattr(model, "box_gain", None)
    out: list[float | None] = []
    for g in box_gain:
        if isinstance(g, str) and g == "auto":
            raise ValueError("box_gain: 'auto' cannot be a candidate of a sequence; use None and 'residual'")
        if g == "residual":
            if augment is None:
                continue
            g = auto_box_gain(model, observations, targets, augment)
        g = None if g is None else float(g)
        key = own if g is None else g
        if all((own if h is None else h) != key for h in out):
            out.append(g)
    return out or [None]


@dataclass(frozen=True)
class AdaptOptions(Options):
    """How :func:`adapt_model` trains (the defaults in one place; ``adapt_model`` documents each):
    mode ("heads" | "full"), lr, frames_per_batch, anchor (L2 pull to the starting weights),
    holdout / min_holdout (held-out share / minimum frames), grad_clip, keep_if_worse, min_pairs,
    eval_seed (point sampling of the Top-1 evaluation), seed (batches, augmentation), augment (a
    ``GeometricAugment`` or None), p_augment, box_weight, box_gain, progress (``(step, total,
    loss)`` callback or None)."""

    mode: str = "heads"
    lr: float = 1e-3
    frames_per_batch: int = 4
    anchor: float = 1e-2
    holdout: float = 0.2
    min_holdout: int = 0
    grad_clip: float = 5.0
    keep_if_worse: bool = False
    min_pairs: int = 8
    eval_seed: int = 0
    seed: int = 0
    augment: Any = None
    p_augment: float = 1.0
    box_weight: float = 0.0
    box_gain: Any = None
    progress: Callable[[int, int, float], None] | None = None


@document(AdaptOptions)
def adapt_model(model, observations: Sequence[Observation], targets: Sequence[PseudoTargets], *, steps: int,
                n_points: int, device, options: AdaptOptions | None = None, **overrides: Any) -> AdaptReport:
    """Fine-tune ``model`` in place on pseudo-labelled ``observations`` (see the module docstring):
    ``steps`` optimiser steps with ``n_points`` points per LiDAR crop on ``device``; the other
    settings are an :class:`AdaptOptions` (``options=``) and/or its fields as keyword arguments.

    ``augment``: optional :class:`xcalib.oneshot.augment.GeometricAugment` applied to a share
    ``p_augment`` of the training frames. ``box_weight`` > 0 (with ``augment``, for models whose
    embeddings carry ``box_lid``/``box_img``, e.g. fastmatch): adds ``box_weight`` x the mean
    squared error of the model's predicted 2D box of every 3D box against where the pose puts it
    (:meth:`GeometricAugment.project`), so the geometry branch learns the site's projection.
    ``box_gain``: for models with ``set_box_gain`` (fastmatch), set the gain on the pair head's
    box differences before training without rescaling its weights, i.e. the box term starts
    (gain / old gain)^2 times stronger: with a known pose the geometry is what transfers, and
    differences of a few pixels (small, far objects) become resolvable (the old gain comes back on
    revert; Top-1 before is measured with it). A number: that gain; None: the model's own;
    ``"residual"`` (needs ``augment``): :func:`auto_box_gain` over the training frames; a sequence
    of those: each is trained from the same start with the same batches (``steps`` each, so the
    time multiplies) and the best on the held-out frames is kept (higher pseudo-label Top-1, then
    lower :func:`pseudo_loss`; ties keep the earlier candidate); ``"auto"`` = ``(None, "residual")``.
    Without held-out pseudo-matches the first candidate is trained alone. Returns an
    :class:`AdaptReport` (``gain_trials``: every candidate's scores); ``trained=False`` (weights
    untouched) when fewer than ``min_pairs`` pseudo-matches are available for training.
    """
    o = resolve(AdaptOptions, options, overrides, where="adapt_model")
    mode, lr, frames_per_batch, anchor, holdout, min_holdout = o.mode, o.lr, o.frames_per_batch, o.anchor, \
        o.holdout, o.min_holdout
    grad_clip, keep_if_worse, min_pairs, eval_seed, seed = o.grad_clip, o.keep_if_worse, o.min_pairs, o.eval_seed, \
        o.seed
    augment, p_augment, box_weight, box_gain, progress = o.augment, o.p_augment, o.box_weight, o.box_gain, o.progress
    t0 = time.perf_counter()
    if steps < 0:
        raise ValueError(f"steps must be >= 0, got {steps}")
    if frames_per_batch < 1:
        raise ValueError(f"frames_per_batch must be >= 1, got {frames_per_batch}")
    named = trainable_parameters(model, mode)
    usable = [k for k, o in enumerate(observations) if not o.empty]
    tr_rel, ho_rel = holdout_split(len(usable), holdout, min_holdout)
    tr = [usable[k] for k in tr_rel]
    ho = [usable[k] for k in ho_rel]
    n_pairs = int(sum(targets[k].n_pairs for k in tr))
    rep = AdaptReport(trained=False, mode=mode, n_train_frames=len(tr), n_heldout_frames=len(ho), n_pairs=n_pairs,
                      heldout_frames=[int(getattr(observations[k], "index", k)) for k in ho],
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
    can_gain = hasattr(model, "set_box_gain")
    gains = _gain_candidates(box_gain, model, [observations[k] for k in tr], [targets[k] for k in tr], augment) \
        if can_gain else [None]
    if rep.n_heldout_pairs == 0:
        gains = gains[:1]
    tr_obs, tr_t = [observations[k] for k in tr], [targets[k] for k in tr]
    best: tuple | None = None  # (key, trial index, state, losses, gain)
    plan = _TrainPlan(steps=steps, n_points=n_points, device=device, lr=lr, frames_per_batch=frames_per_batch,
                      anchor=anchor, grad_clip=grad_clip, seed=seed, augment=augment, p_augment=p_augment,
                      box_weight=box_weight)
    for k, g in enumerate(gains):
        if k:
            model.load_state_dict(start)
        gain = old_gain if g is None else g
        if can_gain and gain is not None:
            model.set_box_gain(float(gain), rescale=False)
        losses = _train(model, named, tr_obs, tr_t, plan,
                        progress=None if progress is None else
                        (lambda i, n, v, k=k: progress(k * steps + i, len(gains) * steps, v)))
        trial = GainTrial(box_gain=float("nan") if gain is None else float(gain),
                          loss_last=float(np.mean(losses[-max(1, steps // 10):])))
        finite = all(torch.isfinite(v).all() for v in model.state_dict().values() if v.is_floating_point())
        if finite:
            trial.top1 = pseudo_top1(model, ho_obs, ho_t, n_points, device, eval_seed)
            if len(gains) > 1:
                trial.loss = pseudo_loss(model, ho_obs, ho_t, n_points, device, eval_seed)
        rep.gain_trials.append(trial)
        # higher Top-1, then lower held-out loss; NaN ranks last; a tie keeps the earlier candidate
        key = (trial.top1 if np.isfinite(trial.top1) else -1.0, -trial.loss if np.isfinite(trial.loss) else -np.inf)
        if finite and (best is None or key > best[0]):
            best = (key, k, {n: v.detach().clone() for n, v in model.state_dict().items()}
                    if len(gains) > 1 else None, losses, gain)
    if best is not None:
        _, k, state, rep.losses, gain = best
        if state is not None:
            model.load_state_dict(state)
            if can_gain and gain is not None:
                model.set_box_gain(float(gain), rescale=False)
        rep.gain_trials[k].chosen = True
        rep.box_gain = float(gain) if can_gain and gain is not None else float("nan")
        rep.top1_after = rep.gain_trials[k].top1
    else:
        rep.losses = losses
        rep.top1_after = float("nan")
    rep.steps = steps
    rep.loss_first, rep.loss_last = rep.losses[0], float(np.mean(rep.losses[-max(1, steps // 10):]))
    worse = np.isfinite(rep.top1_before) and np.isfinite(rep.top1_after) and rep.top1_after < rep.top1_before
    if best is None or (worse and not keep_if_worse):
        model.load_state_dict(start)
        if old_gain is not None and can_gain:
            model.set_box_gain(old_gain, rescale=False)
        rep.reverted = True
        rep.message = ("reverted: training produced non-finite weights" if best is None else
                       f"reverted: held-out Top-1 against pseudo-labels fell from {rep.top1_before:.3f} to "
                       f"{rep.top1_after:.3f}")
        log.warning("one-shot adapt %s", rep.message)
        rep.top1_after = rep.top1_before
    else:
        rep.trained = True
        rep.message = f"trained {steps} steps on {n_pairs} pseudo-labelled pairs in {len(tr)} frames"
        if len(gains) > 1:
            rep.message += "; box_gain " + ", ".join(
                f"{t.box_gain:.3g}: held-out Top-1 {t.top1:.3f}, loss {t.loss:.3f}" + (" (chosen)" if t.chosen else "")
                for t in rep.gain_trials)
    rep.elapsed_s = time.perf_counter() - t0
    return rep


@dataclass(frozen=True)
class _TrainPlan:
    """The settings of one adaptation run (``adapt_model`` documents each)."""

    steps: int
    n_points: int
    device: Any
    lr: float
    frames_per_batch: int
    anchor: float
    grad_clip: float
    seed: int
    augment: Any
    p_augment: float
    box_weight: float


def _train(model, named, observations, targets, plan: _TrainPlan, *, progress) -> list[float]:
    """``plan.steps`` Adam steps (:func:`xcalib.engine.fit.fit`, cosine decay to 5% of ``lr``) on
    ``named`` parameters (the rest frozen, model in eval mode); the batches and augmentations
    depend on ``plan.seed`` only. Returns the per-step losses."""
    steps, n_points, device, lr, frames_per_batch = plan.steps, plan.n_points, plan.device, plan.lr, \
        plan.frames_per_batch
    anchor, grad_clip, seed, augment, p_augment, box_weight = plan.anchor, plan.grad_clip, plan.seed, plan.augment, \
        plan.p_augment, plan.box_weight
    from ..models.inputs import ModelBatch

    anchors = [p.detach().clone() for _, p in named]
    flags = {n: p.requires_grad for n, p in model.named_parameters()}
    train_names = {n for n, _ in named}
    for n, p in model.named_parameters():
        p.requires_grad_(n in train_names)
    params = [p for _, p in named]
    opt = make_optimizer(params, "adam", lr)
    schedule = Schedule(lr, steps, min_lr_ratio=0.05, kind="cosine")  # cosine decay to 5% of lr
    rng = np.random.default_rng([seed, 17])
    torch.manual_seed(seed)
    was_training = model.training
    model.eval()
    order = np.zeros(0, np.int64)

    def loss_at(step: int) -> torch.Tensor:
        nonlocal order
        if len(order) < frames_per_batch:
            order = np.concatenate([order, rng.permutation(len(observations))])
        pick, order = order[:frames_per_batch], order[frames_per_batch:]
        fis, tg = [], []
        for i in pick:
            fi, t = observations[i].inputs(n_points, rng), targets[i]
            if augment is not None and rng.random() < p_augment:
                fi, t = augment.apply(fi, t, rng)
            fis.append(fi)
            tg.append(t)
        batch = ModelBatch.from_frames(fis, device)
        pos, w, neg = _block(tg, device)
        emb = model.embed(batch)
        loss = weighted_matching_loss(model.train_logits(emb, batch), batch, pos, w, neg)
        if box_weight > 0 and augment is not None and "box_lid" in emb.extra:
            loss = loss + box_weight * _box_loss(model, emb.extra["box_lid"], fis, tg, augment, device)
        if anchor > 0:
            loss = loss + anchor * sum(((p - a) ** 2).sum() for p, a in zip(params, anchors))
        return loss

    try:
        return fit(opt, params, schedule, loss_at, range(steps), grad_clip=grad_clip,
                   on_step=None if progress is None else (lambda step, v: progress(step + 1, steps, v)))
    finally:
        for n, p in model.named_parameters():
            p.requires_grad_(flags[n])
        model.train(was_training)
        model.eval()
