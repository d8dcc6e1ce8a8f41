"""``xcalib train``: train a matcher on labelled HDF5 caches (or site folders)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Optional

import typer

from ..engine.recipes import XCALIB_RECIPE

_EXAMPLE = ("Example: xcalib synth --out labelled --frames 20 --no-images   (a small labelled site first: train.h5, "
            "val.h5, test.h5)\n\n"
            "Example: xcalib train --model fastmatch --train-data labelled/train.h5 --val-data labelled/val.h5 "
            "--epochs 2 --site mysite")


def register(app: typer.Typer) -> None:
    @app.command("train", help="Train a matching model (Adam, warm-up + cosine, best by val MRR). "
                               "Runs under torchrun for several processes.\n\n" + _EXAMPLE)
    def train_cmd(
        model: str = typer.Option("fastmatch", "--model", help="Registered model name."),
        train_data: Path = typer.Option(..., "--train-data", help="Training cache (.h5) or site folder."),
        val_data: Optional[Path] = typer.Option(None, "--val-data", help="Validation cache (.h5)."),
        config: Optional[Path] = typer.Option(None, "--config", help="YAML merged over the model defaults."),
        epochs: int = typer.Option(XCALIB_RECIPE.epochs, "--epochs"),
        lr: float = typer.Option(XCALIB_RECIPE.lr, "--lr"),
        warmup_epochs: float = typer.Option(XCALIB_RECIPE.warmup_epochs, "--warmup-epochs"),
        frames_per_batch: int = typer.Option(4, "--frames-per-batch"),
        weights: Optional[Path] = typer.Option(None, "--weights", help="Warm start from these weights (strict)."),
        resume: bool = typer.Option(False, "--resume", help="Continue from OUTPUT_DIR/last.pt."),
        output_dir: Path = typer.Option(Path("runs/train"), "--output-dir"),
        site: Optional[str] = typer.Option(None, "--site", help="Also install the best weights as this site "
                                                                 "(under $XCALIB_HOME/sites/SITE)."),
        device: str = typer.Option("auto", "--device"),
        seed: int = typer.Option(42, "--seed"),
        limit_train_frames: Optional[int] = typer.Option(None, "--limit-train-frames"),
        limit_val_frames: Optional[int] = typer.Option(None, "--limit-val-frames"),
        as_json: bool = typer.Option(False, "--json", help="Machine-readable summary."),
        force: bool = typer.Option(False, "--force", help="Replace a previous run's files in OUTPUT_DIR."),
    ) -> None:
        import contextlib
        import os

        import torch.distributed as dist

        from ..engine.checkpoint import read_config, site_dirs, write_checksum
        from ..io.files import atomic_dir, claim_output
        from ..engine.trainer import shutdown_distributed, train

        if not resume and not force:  # a previous run's best/last checkpoints are not silently replaced
            for f in ("best.pth", "best.yaml", "last.pt"):
                if (output_dir / f).exists():
                    raise FileExistsError(f"{output_dir / f} already exists (a previous run); pass --force to "
                                          "replace it or --resume to continue it")
        with contextlib.ExitStack() as claims:  # outputs claimed before training: a second run is refused now
            primary = os.environ.get("RANK", "0") == "0"  # under torchrun, rank 0 writes for all
            if primary:
                claims.enter_context(claim_output(output_dir, "output folder"))
            if site and primary:
                claims.enter_context(claim_output(site_dirs(site)[0], f"site {site!r}"))
            cfg = read_config(config) if config else None
            recipe = XCALIB_RECIPE.kwargs(epochs=epochs, lr=lr, warmup_epochs=warmup_epochs)
            best = train(model, train_data, val_data, config=cfg, **recipe,
                         frames_per_batch=frames_per_batch, weights=weights, resume=resume or None,
                         output_dir=output_dir, device=device, seed=seed, limit_train_frames=limit_train_frames,
                         limit_val_frames=limit_val_frames, progress=not as_json)
            rank = dist.get_rank() if dist.is_initialized() else 0
            shutdown_distributed()
            if rank != 0:
                return
            installed = None
            if site:
                d = site_dirs(site)[0]
                with atomic_dir(d, keep_existing=True) as tmp:  # other models' files of the site are kept
                    shutil.copyfile(best, tmp / f"{model}.pth")
                    write_checksum(tmp / f"{model}.pth")
                    shutil.copyfile(best.with_suffix(".yaml"), tmp / f"{model}.yaml")
                if (d / f"{model}.pt").is_file():  # one set of weights per model in a site folder
                    (d / f"{model}.pt").unlink()
                installed = str(d / f"{model}.pth")
        hist = json.loads((Path(output_dir) / "history.json").read_text())
        bestrow = max(hist, key=lambda h: h["val_mrr"])
        summary = {"model": model, "best": str(best), "installed": installed, "epochs": len(hist),
                   "best_epoch": bestrow["epoch"], "val_top1": bestrow["val_top1"], "val_mrr": bestrow["val_mrr"]}
        typer.echo(json.dumps(summary) if as_json else
                   f"best {model}: epoch {bestrow['epoch']} val top1 {bestrow['val_top1']:.4f} "
                   f"mrr {bestrow['val_mrr']:.4f} -> {best}" + (f" (installed as site {site!r})" if site else ""))
