"""``train``: supervised training of a matching model on frames with a ``match_matrix``.

Defaults: the reference package's (:data:`REFERENCE_RECIPE`: AdamW, constant lr 1e-4, 10
epochs); the paper's recipe (:data:`XCALIB_RECIPE`: Adam, linear warm-up then cosine decay to
``min_lr`` per step, 100 epochs) is what ``xcalib train`` uses. Best checkpoint by validation
MRR. The optimisation loop is :func:`xcalib.engine.fit.fit`. Frames are batched (``frames_per_batch``); scores
between detections of different frames are masked. Loss per model output: multi-positive
cross-entropy over rows and columns (every positive of a row is a target) on logits; outputs
of kind "logit" add a class-balanced binary cross-entropy so their sigmoid is a probability.
Augmentation: the LiDAR crops are re-sampled every epoch and the boxes jittered (``box_jitter``),
seeded by ``seed`` and the epoch.

Distributed: run the same script under ``torchrun --nproc_per_node=N``; each rank trains on
its shard of every epoch's frames inside DistributedDataParallel (gloo on CPU, NCCL on GPU);
validation counts are all-reduced; rank 0 writes the files. Call ``shutdown_distributed()`` once
training is over (the ``xcalib train`` command does): every rank waits for the others, then
the process group is destroyed before the interpreter shuts down.

Outputs in ``output_dir``: ``best.pth`` + ``best.yaml`` (loadable by
``Matcher.from_pretrained(model, weights=".../best.pth")``), ``last.pt`` (resume state, one
file overwritten each epoch) and ``history.json``.
"""

from __future__ import annotations

import gc
import json
import logging
import math
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable, Sequence

import numpy as np
import torch
import torch.distributed as dist

from ..data.crops import CropConfig, FrameInputs, crop_images, crop_points, gather_box_points, resample_points
from ..types import Frame, as_frame
from ..io.files import atomic_write
from ..options import document, resolve
from .checkpoint import (WeightsMismatchError, checksum_path, load_resume_state, load_state_strict, read_checkpoint,
                         save_resume_state, save_weights, write_config)
from .fit import Schedule, fit, make_optimizer
from .recipes import REFERENCE_RECIPE, XCALIB_RECIPE, Recipe, TrainOptions  # noqa: F401 - re-exported
from .metrics import MatchingMetrics, MetricsAccumulator

__all__ = ["train", "finetune", "Recipe", "TrainOptions", "REFERENCE_RECIPE", "XCALIB_RECIPE", "shutdown_distributed", "TrainSample", "prepare_samples", "matching_loss", "evaluate", "load_frames"]

log = logging.getLogger("xcalib.train")


@dataclass
class TrainSample:
    """One frame, cropped once: image crops, grouped box-frame points (re-sampled per epoch)
    and the ground truth restricted to the kept detections."""

    crops_2d: np.ndarray
    points: np.ndarray
    counts: np.ndarray
    boxes_2d: np.ndarray
    boxes_3d: np.ndarray
    image_size: tuple[int, int]
    gt: np.ndarray
    key: str = ""

    def inputs(self, n_points: int, rng: np.random.Generator, jitter: float = 0.0) -> FrameInputs:
        """Model inputs with freshly resampled points; ``jitter`` > 0 also perturbs the boxes
        (2D corners by ``jitter`` x box size px, 3D centres by ``jitter`` x box dims, Gaussian)."""
        return self.draw(n_points, rng, jitter)[0]

    def draw(self, n_points: int, rng: np.random.Generator, jitter: float = 0.0,
             max_3d: int | None = None) -> tuple[FrameInputs, np.ndarray]:
        """(inputs, ground truth [N,M']). ``max_3d``: keep every 3D box with a match plus random
        unmatched ones up to this many columns (negative sampling; None keeps all)."""
        m = len(self.counts)
        cols = np.arange(m)
        pts, counts, b3, gt = self.points, self.counts, self.boxes_3d, self.gt
        if max_3d is not None and m > max_3d:
            pos = gt.any(axis=0)
            neg = np.nonzero(~pos)[0]
            k = max(max_3d - int(pos.sum()), 0)
            cols = np.sort(np.concatenate([np.nonzero(pos)[0], rng.choice(neg, min(k, len(neg)), replace=False)]))
            keep = np.zeros(m, dtype=bool)
            keep[cols] = True
            pts, counts, b3, gt = pts[np.repeat(keep, counts)], counts[cols], b3[cols], gt[:, cols]
        crops = resample_points(pts, counts, n_points, rng)
        n = len(self.crops_2d)
        b2 = self.boxes_2d
        if jitter > 0:
            wh = np.tile(b2[:, 2:4] - b2[:, 0:2], 2)
            b2 = (b2 + rng.normal(0, jitter, b2.shape) * wh).astype(np.float32)
            b3 = b3.copy()
            b3[:, :3] += (rng.normal(0, jitter, (len(cols), 3)) * b3[:, 3:6]).astype(np.float32)
        fi = FrameInputs(self.crops_2d, crops, b2, b3, counts, self.image_size, np.arange(n), np.arange(len(cols)))
        return fi, gt


def load_frames(data, limit: int | None = None, split: str = "train") -> Iterable[Frame]:
    """Frames from a sequence of ``Frame``s, an .h5 cache path or a folder/site accepted by
    ``xcalib.io.hdf5.open_dataset`` (its ``split``)."""
    if isinstance(data, (str, Path)):
        from ..io.hdf5 import open_dataset  # an .h5 file opens as a CacheReader

        frames: Iterable[Frame] = open_dataset(data, split)
    else:
        frames = data
    for i, f in enumerate(frames):
        if limit is not None and i >= limit:
            break
        yield as_frame(f)


def prepare_samples(data, cfg: CropConfig, limit: int | None = None,
                    split: str = "train") -> tuple[list[TrainSample], int]:
    """Crop every usable frame once. Returns (samples, number of frames skipped: no ground
    truth, or no positive among the kept detections). A list of ``TrainSample`` passes through
    (prepare once, train several models with the same crop settings)."""
    if isinstance(data, (list, tuple)) and data and all(isinstance(x, TrainSample) for x in data):
        return list(data[:limit] if limit is not None else data), 0
    out, skipped = [], 0
    for f in load_frames(data, limit, split):
        if f.match_matrix is None:
            skipped += 1
            continue
        if f.images and f.camera_per_det is not None:
            from ..data.crops import prepare_frame

            fi = prepare_frame(f.image, f.point_cloud, f.bboxes_2d, f.bboxes_3d, cfg,
                               images=f.images, camera_per_det=f.camera_per_det)
            crops2, k2 = fi.crops_2d, fi.kept_2d
        else:
            crops2, k2 = crop_images(f.image, f.bboxes_2d, cfg.crop_size, keep_aspect=cfg.keep_aspect,
                                     normalize=cfg.normalize)
        _, box7, counts, k3 = crop_points(f.point_cloud, f.bboxes_3d, 1, expansion=cfg.bbox_expansion,
                                          min_points=cfg.min_points)
        gt = np.asarray(f.match_matrix, dtype=bool)[np.ix_(k2, k3)]
        if not gt.any():
            skipped += 1
            continue
        pts, counts = gather_box_points(f.point_cloud, box7, cfg.bbox_expansion)
        b2 = np.asarray(f.bboxes_2d, dtype=np.float32).reshape(-1, 4)[k2]
        out.append(TrainSample(crops2, pts, counts, b2, box7, f.image_size, gt, f.frame_key))
    return out, skipped


def matching_loss(outputs, batch, gt: torch.Tensor, label_smoothing: float = 0.0) -> torch.Tensor:
    """Sum over model outputs of weight * (row/column multi-positive CE [+ balanced BCE]).
    ``label_smoothing`` eps: each row's target puts 1 - eps on its positives and eps spread
    uniformly over the row's candidates (same frame)."""
    same = batch.same_frame()
    total = gt.new_zeros((), dtype=torch.float32)
    for out in outputs:
        L = out.logits.float().masked_fill(~same, float("-inf"))
        ce = L.new_zeros(())
        for S, G, V in ((L, gt, same), (L.T, gt.T, same.T)):
            rows = G.any(dim=1)
            if rows.any():
                lse = torch.logsumexp(S[rows], 1)
                pos = S[rows].masked_fill(~G[rows], float("-inf"))
                term = lse - torch.logsumexp(pos, 1)
                if label_smoothing:
                    v = V[rows]
                    mean_logit = S[rows].masked_fill(~v, 0.0).sum(1) / v.sum(1).clamp(min=1)
                    term = (1 - label_smoothing) * term + label_smoothing * (lse - mean_logit)
                ce = ce + term.mean() / 2
        if out.kind == "logit":
            bce = torch.nn.functional.binary_cross_entropy_with_logits(
                out.logits.float(), gt.float(), reduction="none")
            pos, neg = gt & same, ~gt & same
            terms = [bce[m].mean() for m in (pos, neg) if m.any()]
            ce = ce + sum(terms) / max(len(terms), 1)
        total = total + out.weight * ce
    return total


def _block_gt(gts: Sequence[np.ndarray], device) -> torch.Tensor:
    n, m = sum(g.shape[0] for g in gts), sum(g.shape[1] for g in gts)
    out = np.zeros((n, m), dtype=bool)
    i = j = 0
    for g in gts:
        out[i:i + g.shape[0], j:j + g.shape[1]] = g
        i, j = i + g.shape[0], j + g.shape[1]
    return torch.from_numpy(out).to(device)


@torch.no_grad()
def evaluate(model, samples: Sequence[TrainSample], n_points: int, device, seed: int = 0,
             acc: MetricsAccumulator | None = None) -> MetricsAccumulator:
    """Inference scores (``model.score``) of every sample -> accumulator. Each frame's points are
    resampled with ``default_rng(seed)``, exactly as ``Matcher.match`` does with the config seed."""
    from ..models.inputs import ModelBatch

    acc = acc or MetricsAccumulator()
    was = model.training
    model.eval()
    for i, s in enumerate(samples):
        fi = s.inputs(n_points, np.random.default_rng(seed))
        t0 = time.perf_counter()
        b = ModelBatch.from_frames([fi], device)
        sim = model.score(model.embed(b), b).float().cpu().numpy()
        acc.add(sim, s.gt, (time.perf_counter() - t0) * 1000.0)
    model.train(was)
    return acc


def _dist_setup(device: str) -> tuple[int, int, torch.device]:
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if world > 1 and not dist.is_initialized():
        use_cuda = torch.cuda.is_available() and device != "cpu"
        dist.init_process_group("nccl" if use_cuda else "gloo")
    rank = dist.get_rank() if dist.is_initialized() else 0
    world = dist.get_world_size() if dist.is_initialized() else 1
    if device in ("auto", None):
        device = "cuda" if torch.cuda.is_available() else "cpu"
    dev = torch.device(device)
    if dev.type == "cuda" and world > 1:
        dev = torch.device("cuda", int(os.environ.get("LOCAL_RANK", rank)))
        torch.cuda.set_device(dev)
    return rank, world, dev


def shutdown_distributed() -> None:
    """End a ``torchrun`` job cleanly: barrier, then destroy the process group (no-op when not distributed)."""
    if dist.is_available() and dist.is_initialized():
        dist.barrier()
        dist.destroy_process_group()
        gc.collect()


def _allreduce(x: np.ndarray) -> np.ndarray:
    if not dist.is_initialized():
        return x
    t = torch.from_numpy(x.astype(np.float64))
    dist.all_reduce(t)
    return t.numpy()


def _site_config(model: str, site: str | None) -> dict[str, Any] | None:
    """The config of ``model``'s weights at ``site`` (its YAML), or None when there are none."""
    if site is None:
        return None
    from .checkpoint import WeightsNotFoundError, find_site_weights, read_config

    try:
        w = find_site_weights(model, site)
    except WeightsNotFoundError:
        return None
    y = w.with_suffix(".yaml")
    return read_config(y) if y.is_file() else read_checkpoint(w).get("config")


def _describe_data(data) -> str:
    return str(data) if isinstance(data, (str, Path)) else f"<{type(data).__name__}>"


@document(TrainOptions)
def train(model, train_data, val_data=None, *, options: TrainOptions | None = None, **overrides: Any) -> Path:
    """Train ``model`` (a registered name or a ``MatchingModel``); returns the path of ``best.pth``.

    The reference's signature and defaults (:data:`REFERENCE_RECIPE`; xcalib's CLI uses
    :data:`XCALIB_RECIPE`). train_data / val_data: ``Frame`` sequences with ``match_matrix``,
    .h5 caches, or site folders / names (``load_dataset(data, "train"/"val")``).
    Settings: a :class:`TrainOptions` (``options=``; ``TrainOptions.from_recipe(XCALIB_RECIPE)`` for
    the paper's recipe) and/or its fields as keyword arguments, which replace the record's values:
    model_name, config, site, epochs, lr, weight_decay, optimizer, warmup_epochs, scheduler, min_lr,
    temperature, label_smoothing, stage1_weight, stage2_weight, weights, output_dir, device, seed,
    limit_train_frames, limit_val_frames, pairwise_batch_size, frames_per_batch, grad_clip, resume,
    progress, weights_dtype, box_jitter, max_3d (each documented on :class:`TrainOptions`). An
    unknown keyword is a TypeError naming it; a value of the wrong type a TypeError naming the field.
    Writes ``best.pth`` (``model_state_dict``, ``epoch``, ``metrics``, ``train_args``; loadable
    by ``Matcher.from_pretrained(model, weights=...)``) + ``best.yaml``, ``last.pt``, ``history.json``.
    """
    o = resolve(TrainOptions, options, overrides, where="train")
    model_name, config, site, epochs, lr = o.model_name, o.config, o.site, o.epochs, o.lr
    weight_decay, optimizer, warmup_epochs, scheduler, min_lr = o.weight_decay, o.optimizer, o.warmup_epochs, \
        o.scheduler, o.min_lr
    temperature, label_smoothing, stage1_weight, stage2_weight = o.temperature, o.label_smoothing, \
        o.stage1_weight, o.stage2_weight
    weights, output_dir, device, seed = o.weights, o.output_dir, o.device, o.seed
    limit_train_frames, limit_val_frames, pairwise_batch_size = o.limit_train_frames, o.limit_val_frames, \
        o.pairwise_batch_size
    frames_per_batch, grad_clip, resume, progress = o.frames_per_batch, o.grad_clip, o.resume, o.progress
    weights_dtype, box_jitter, max_3d = o.weights_dtype, o.box_jitter, o.max_3d
    from ..models import MatchingModel, create_model
    from ..models.inputs import ModelBatch

    if isinstance(model, str) and model_name is not None and model_name != model:
        raise ValueError(f"train: model={model!r} but model_name={model_name!r}")
    rank, world, dev = _dist_setup(device)
    torch.manual_seed(seed)
    if isinstance(model, str):
        over = {k: v for k, v in (("temperature", temperature), ("stage1_weight", stage1_weight),
                                  ("stage2_weight", stage2_weight)) if v is not None}
        base = config if config is not None else _site_config(model, site)
        net: MatchingModel = create_model(model, base, **over)
    else:
        net = model
        for k, v in (("temperature", temperature), ("stage1_weight", stage1_weight), ("stage2_weight", stage2_weight)):
            if v is not None and hasattr(net, k):
                setattr(net, k, float(v))
                net.config[k] = float(v)
    name = net.model_name
    if model_name is not None and model_name != name:
        raise ValueError(f"train: model_name={model_name!r} but the model is {name!r}")
    if weights is not None:
        load_state_strict(net, read_checkpoint(Path(weights))["state_dict"], str(weights))
    net.to(dev)
    cfg = CropConfig.from_config(net.config)
    P = cfg.point_cloud_size
    t0 = time.perf_counter()
    train_s, skip_t = prepare_samples(train_data, cfg, limit_train_frames, split="train")
    val_s, skip_v = prepare_samples(val_data, cfg, limit_val_frames, split="val") if val_data is not None else ([], 0)
    if not train_s:
        where = f"{train_data}" if isinstance(train_data, (str, Path)) else "train"
        if not skip_t:  # an empty cache, e.g. the train.h5 of `xcalib synth ... --train 0`
            raise ValueError(f"{where}: no training frames (an empty cache); write a labelled site with "
                             "`xcalib synth --out site --frames 20 --no-images` or `xcalib cache build`")
        raise ValueError(f"{where}: no usable training frame (each needs a match_matrix with a positive among "
                         f"the kept detections; {skip_t} skipped)")
    if rank == 0:
        log.info("train %s: %d train frames (%d skipped), %d val frames (%d skipped), cropped in %.1fs",
                 name, len(train_s), skip_t, len(val_s), skip_v, time.perf_counter() - t0)
    train_args = {"model": name, "site": site, "epochs": epochs, "lr": lr, "weight_decay": weight_decay,
                  "optimizer": optimizer, "warmup_epochs": warmup_epochs, "scheduler": scheduler, "min_lr": min_lr,
                  "temperature": float(getattr(net, "temperature", float("nan"))), "label_smoothing": label_smoothing,
                  "stage1_weight": getattr(net, "stage1_weight", None), "stage2_weight": getattr(net, "stage2_weight", None),
                  "seed": seed, "frames_per_batch": frames_per_batch, "grad_clip": grad_clip,
                  "pairwise_batch_size": pairwise_batch_size, "box_jitter": box_jitter, "max_3d": max_3d,
                  "train_data": _describe_data(train_data), "val_data": _describe_data(val_data)}
    out = Path(output_dir)
    if rank == 0:
        out.mkdir(parents=True, exist_ok=True)

    ddp = torch.nn.parallel.DistributedDataParallel(net, find_unused_parameters=True) if world > 1 else net
    params = [p for p in net.parameters() if p.requires_grad]
    opt = make_optimizer(params, optimizer, lr, weight_decay)

    per_rank = math.ceil(len(train_s) / world)
    steps_per_epoch = math.ceil(per_rank / max(1, frames_per_batch))
    schedule = Schedule(lr, epochs * steps_per_epoch, int(round(warmup_epochs * steps_per_epoch)),
                        min_lr / lr if lr else 0.0, scheduler)
    start_epoch, best_mrr, history = 0, -math.inf, []  # without val data "MRR" is -loss, which may be < -1
    if resume:
        rpath = out / "last.pt" if resume is True else Path(resume)
        state = load_resume_state(rpath)  # torch.load(weights_only=True): a crafted file cannot run code
        load_state_strict(net, state["state_dict"], str(rpath))
        try:
            opt.load_state_dict(state["optimizer"])
        except (KeyError, ValueError, TypeError, RuntimeError) as exc:
            raise WeightsMismatchError(rpath, f"optimizer state does not fit ({exc})", "optimizer") from None
        start_epoch, best_mrr, history = state["epoch"] + 1, state["best_mrr"], state["history"]
    best_path = out / "best.pth"
    if rank == 0 and not resume:  # a previous run's best must not pair with this run's best.yaml
        for stale in (best_path, checksum_path(best_path)):
            stale.unlink(missing_ok=True)

    bar = None
    if progress and rank == 0:
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

        bar = Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
                       TextColumn("{task.fields[info]}"), TimeRemainingColumn(), transient=False)
        bar.start()
        task = bar.add_task(f"train {name}", total=(epochs - start_epoch) * steps_per_epoch, info="")
    try:
        for epoch in range(start_epoch, epochs):
            t_ep = time.perf_counter()
            net.train()
            order = np.random.default_rng([seed, epoch]).permutation(len(train_s))
            order = np.resize(order, per_rank * world)[rank::world]  # same number of steps on every rank
            rng = np.random.default_rng([seed, epoch, rank, 1])

            def loss_at(g: int, epoch=epoch, order=order, rng=rng) -> torch.Tensor:
                step = g - epoch * steps_per_epoch
                idx = order[step * frames_per_batch:(step + 1) * frames_per_batch]
                if len(idx) == 0:
                    idx = order[:1]
                drawn = [train_s[i].draw(P, rng, box_jitter, max_3d) for i in idx]
                batch = ModelBatch.from_frames([d[0] for d in drawn], dev)
                gt = _block_gt([d[1] for d in drawn], dev)
                return matching_loss(ddp(batch, train=True), batch, gt, label_smoothing)

            def on_step(g: int, value: float, epoch=epoch, seen=[]) -> None:  # noqa: B006 - per-epoch list
                seen.append(value)
                if bar is not None:
                    bar.update(task, advance=1, info=f"epoch {epoch + 1}/{epochs} loss {np.mean(seen):.3f}")

            first = epoch * steps_per_epoch
            # non-finite losses become zero steps: keeps every rank stepping together
            losses = fit(opt, params, schedule, loss_at, range(first, first + steps_per_epoch), grad_clip=grad_clip,
                         zero_nonfinite=True, on_step=on_step)
            tot = _allreduce(np.array([float(np.sum(losses)), float(len(losses))]))
            mean_loss = float(tot[0] / max(tot[1], 1.0))
            if val_s:
                acc = evaluate(net, val_s[rank::world], P, dev, cfg.seed)
                met = MetricsAccumulator.from_sums(_allreduce(acc.sums()))
            else:
                met = MatchingMetrics(mrr=-mean_loss)
            row = {"epoch": epoch + 1, "lr": opt.param_groups[0]["lr"], "train_loss_mean": mean_loss,
                   "val_top1": met.top1, "val_top3": met.top3, "val_mrr": met.mrr, "wall_s": time.perf_counter() - t_ep}
            history.append(row)
            if rank == 0:
                if met.mrr > best_mrr:
                    best_mrr = met.mrr
                    # yaml first, weights last: the yaml is the same for every save of a run and a
                    # stale best.pth was removed at the start, so a kill never pairs files of two runs
                    write_config(out / "best.yaml", net.config)
                    save_weights(net, best_path, model_name=name, config=net.config, dtype=weights_dtype,
                                 extra={"epoch": epoch + 1, "metrics": met.to_dict(), "train_args": train_args})
                save_resume_state(out / "last.pt", state_dict=net.state_dict(), optimizer=opt.state_dict(),
                                  epoch=epoch, best_mrr=best_mrr, history=history, model_name=name,
                                  config=net.config)
                atomic_write(out / "history.json", [json.dumps(history, indent=1).encode()])
                if bar is not None:
                    bar.update(task, info=f"epoch {epoch + 1}/{epochs} loss {mean_loss:.3f} "
                                          f"val top1 {met.top1:.3f} mrr {met.mrr:.3f}")
                else:
                    log.info("epoch %d/%d loss %.4f val top1 %.4f mrr %.4f", epoch + 1, epochs, mean_loss,
                             met.top1, met.mrr)
            if dist.is_initialized():
                dist.barrier()
    finally:
        if bar is not None:
            bar.stop()
        if world > 1:
            # release DDP's reducer (it holds gloo/NCCL work) while the interpreter is fully alive
            del ddp
            gc.collect()
    net.eval()
    if not best_path.exists() and rank == 0:
        raise RuntimeError(f"train: no best checkpoint was written in {out}")
    return best_path


def finetune(matcher, train_data, val_data=None, *, output_dir: str | Path = "runs/finetune",
             device: str | None = None, **kwargs: Any) -> Path:
    """``Matcher.train``: :func:`train` the matcher's model in place (on ``device``, default the
    matcher's), load the best checkpoint back strictly and return the model to the matcher's
    device in eval mode. Returns the path of ``best.pth``."""
    best = train(matcher.model, train_data, val_data, output_dir=output_dir,
                 device=str(device if device is not None else matcher.device), **kwargs)
    load_state_strict(matcher.model, read_checkpoint(best)["state_dict"], str(best))
    matcher.model.to(matcher.device).eval()
    return Path(best)
