"""``train``: supervised training of a matching model on frames with a ``match_matrix``.

Default recipe (the paper's): Adam, linear warm-up then cosine decay to ``min_lr`` (per
step), best checkpoint by validation MRR. Frames are batched (``frames_per_batch``); scores
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

Outputs in ``output_dir``: ``best.pt`` + ``best.yaml`` (loadable by
``Matcher.from_pretrained(model, weights=".../best.pt")``), ``last.pt`` (resume state, one
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
from typing import Any, Iterable, Mapping, Sequence

import numpy as np
import torch
import torch.distributed as dist

from ..data.crops import CropConfig, FrameInputs, crop_images, crop_points, gather_box_points, resample_points
from ..types import Frame
from ..io._files import atomic_write
from .checkpoint import (WeightsMismatchError, load_resume_state, load_state_strict, read_checkpoint,
                         save_resume_state, save_weights, write_config)
from .metrics import MatchingMetrics, MetricsAccumulator

__all__ = ["train", "shutdown_distributed", "TrainSample", "prepare_samples", "matching_loss", "evaluate", "load_frames"]

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


def load_frames(data, limit: int | None = None) -> Iterable[Frame]:
    """Frames from a sequence of ``Frame``s, an .h5 cache path or a folder/site accepted by
    ``xcalib.io.hdf5.load_dataset``."""
    if isinstance(data, (str, Path)):
        from ..io.hdf5 import load_dataset  # an .h5 file opens as a CacheReader

        frames: Iterable[Frame] = load_dataset(Path(data))
    else:
        frames = data
    for i, f in enumerate(frames):
        if limit is not None and i >= limit:
            break
        yield f


def prepare_samples(data, cfg: CropConfig, limit: int | None = None) -> tuple[list[TrainSample], int]:
    """Crop every usable frame once. Returns (samples, number of frames skipped: no ground
    truth, or no positive among the kept detections). A list of ``TrainSample`` passes through
    (prepare once, train several models with the same crop settings)."""
    if isinstance(data, (list, tuple)) and data and all(isinstance(x, TrainSample) for x in data):
        return list(data[:limit] if limit is not None else data), 0
    out, skipped = [], 0
    for f in load_frames(data, limit):
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


def matching_loss(outputs, batch, gt: torch.Tensor) -> torch.Tensor:
    """Sum over model outputs of weight * (row/column multi-positive CE [+ balanced BCE])."""
    same = batch.same_frame()
    total = gt.new_zeros((), dtype=torch.float32)
    for out in outputs:
        L = out.logits.float().masked_fill(~same, float("-inf"))
        ce = L.new_zeros(())
        for S, G in ((L, gt), (L.T, gt.T)):
            rows = G.any(dim=1)
            if rows.any():
                pos = S[rows].masked_fill(~G[rows], float("-inf"))
                ce = ce + (torch.logsumexp(S[rows], 1) - torch.logsumexp(pos, 1)).mean() / 2
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


def _lr_at(step: int, total: int, warmup: int, base: float, min_lr: float, scheduler: str) -> float:
    if warmup > 0 and step < warmup:
        return base * (step + 1) / warmup
    if scheduler == "cosine":
        t = (step - warmup) / max(total - warmup, 1)
        return min_lr + 0.5 * (base - min_lr) * (1 + math.cos(math.pi * min(t, 1.0)))
    if scheduler == "none":
        return base
    raise ValueError(f"scheduler must be 'cosine' or 'none', got {scheduler!r}")


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


def train(model, train_data, val_data=None, *, config: Mapping[str, Any] | None = None, epochs: int = 100,
          lr: float = 1e-3, weight_decay: float = 0.0, optimizer: str = "adam", warmup_epochs: float = 5,
          scheduler: str = "cosine", min_lr: float = 1e-6, frames_per_batch: int = 4, grad_clip: float = 5.0,
          weights: str | Path | None = None, resume: str | Path | bool | None = None,
          output_dir: str | Path = "runs/train", device: str = "auto", seed: int = 42,
          limit_train_frames: int | None = None, limit_val_frames: int | None = None,
          progress: bool = True, weights_dtype: str = "float32", box_jitter: float = 0.02,
          max_3d: int | None = None) -> Path:
    """Train ``model`` (a registered name or a ``MatchingModel``); returns the path of best.pt.

    train_data / val_data: ``Frame`` sequences with ``match_matrix``, or .h5 caches / site
    folders. max_3d: per training frame, keep the matched 3D boxes plus random unmatched ones up
    to this many (negative sampling; validation always uses all). box_jitter: training-time box perturbation (fraction of box size; 0 = off).
    weights: warm start (strict). resume: ``last.pt`` path (or True for
    ``output_dir/last.pt``) to continue an interrupted run.
    """
    from ..models import MatchingModel, create_model
    from ..models.inputs import ModelBatch

    rank, world, dev = _dist_setup(device)
    torch.manual_seed(seed)
    net: MatchingModel = create_model(model, config) if isinstance(model, str) else model
    name = net.model_name
    if weights is not None:
        load_state_strict(net, read_checkpoint(Path(weights))["state_dict"], str(weights))
    net.to(dev)
    cfg = CropConfig.from_config(net.config)
    P = cfg.point_cloud_size
    t0 = time.perf_counter()
    train_s, skip_t = prepare_samples(train_data, cfg, limit_train_frames)
    val_s, skip_v = prepare_samples(val_data, cfg, limit_val_frames) if val_data is not None else ([], 0)
    if not train_s:
        raise ValueError("train: no usable training frame (each needs a match_matrix with a positive among "
                         f"the kept detections; {skip_t} skipped)")
    if rank == 0:
        log.info("train %s: %d train frames (%d skipped), %d val frames (%d skipped), cropped in %.1fs",
                 name, len(train_s), skip_t, len(val_s), skip_v, time.perf_counter() - t0)
    out = Path(output_dir)
    if rank == 0:
        out.mkdir(parents=True, exist_ok=True)

    ddp = torch.nn.parallel.DistributedDataParallel(net, find_unused_parameters=True) if world > 1 else net
    params = [p for p in net.parameters() if p.requires_grad]
    if optimizer == "adam":
        opt = torch.optim.Adam(params, lr=lr, weight_decay=weight_decay)
    elif optimizer == "adamw":
        opt = torch.optim.AdamW(params, lr=lr, weight_decay=weight_decay)
    else:
        raise ValueError(f"optimizer must be 'adam' or 'adamw', got {optimizer!r}")

    per_rank = math.ceil(len(train_s) / world)
    steps_per_epoch = math.ceil(per_rank / max(1, frames_per_batch))
    total_steps, warm_steps = epochs * steps_per_epoch, int(round(warmup_epochs * steps_per_epoch))
    start_epoch, best_mrr, history = 0, -1.0, []
    if resume:
        rpath = out / "last.pt" if resume is True else Path(resume)
        state = load_resume_state(rpath)  # torch.load(weights_only=True): a crafted file cannot run code
        load_state_strict(net, state["state_dict"], str(rpath))
        try:
            opt.load_state_dict(state["optimizer"])
        except (KeyError, ValueError, TypeError, RuntimeError) as exc:
            raise WeightsMismatchError(rpath, f"optimizer state does not fit ({exc})", "optimizer") from None
        start_epoch, best_mrr, history = state["epoch"] + 1, state["best_mrr"], state["history"]
    best_path = out / "best.pt"

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
            losses = []
            for step in range(steps_per_epoch):
                idx = order[step * frames_per_batch:(step + 1) * frames_per_batch]
                if len(idx) == 0:
                    idx = order[:1]
                drawn = [train_s[i].draw(P, rng, box_jitter, max_3d) for i in idx]
                batch = ModelBatch.from_frames([d[0] for d in drawn], dev)
                gt = _block_gt([d[1] for d in drawn], dev)
                g = epoch * steps_per_epoch + step
                for pg in opt.param_groups:
                    pg["lr"] = _lr_at(g, total_steps, warm_steps, lr, min_lr, scheduler)
                loss = matching_loss(ddp(batch, train=True), batch, gt)
                if not torch.isfinite(loss):  # keep every rank stepping together
                    loss = loss.nan_to_num(0.0, 0.0, 0.0) * 0.0
                opt.zero_grad(set_to_none=True)
                loss.backward()
                if grad_clip:
                    torch.nn.utils.clip_grad_norm_(params, grad_clip)
                opt.step()
                losses.append(float(loss.detach()))
                if bar is not None:
                    bar.update(task, advance=1, info=f"epoch {epoch + 1}/{epochs} loss {np.mean(losses):.3f}")
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
                    save_weights(net, best_path, model_name=name, config=net.config, dtype=weights_dtype,
                                 extra={"epoch": epoch + 1, "metrics": met.to_dict()})
                    write_config(out / "best.yaml", net.config)
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
