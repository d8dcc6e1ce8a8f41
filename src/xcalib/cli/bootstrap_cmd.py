"""``xcalib bootstrap``: unlabelled recording of a new site -> site weights (no matcher needed)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Optional

import typer

_EXAMPLE = ("Example (the first 10 A9 frames; a few minutes: about 150 s of CPU):\n\nxcalib bootstrap ../shared/data/a9_sample "
            "--intrinsics ../shared/data/a9_sample/intrinsics.json --site a9_south1 --model fastmatch --limit 10\n\n"
            "A recording too short to determine the pose is refused as poorly constrained; the message says why "
            "and what to add.")


def register(app: typer.Typer) -> None:
    @app.command("bootstrap", help="Bring a matcher up at a new site from unlabelled frames: calibrate from the "
                                   "detections alone, pseudo-label by projection, train, and install the weights "
                                   "where `Matcher.from_pretrained(MODEL, site=SITE)` finds them "
                                   "($XCALIB_HOME/sites/SITE).\n\n" + _EXAMPLE)
    def bootstrap_cmd(
        frames: Path = typer.Argument(..., help="Recording: frame folder, HDF5 cache or any source read_frames opens."),
        intrinsics: Optional[Path] = typer.Option(None, "--intrinsics", "-K", help="Intrinsics: xcalib intrinsics JSON {fx, fy, cx, cy, distortion}, or with a \"model\" "
                                                       "(kannala_brandt, unified, ucm, eucm, double_sphere: docs/camera-models.md), or a "
                                                       "camera file (ROS CameraInfo YAML, Kalibr camchain -- one of several: FILE#cam1 --, OpenCV YAML/JSON) "
                                                  "(pixels); default: the recording's own (e.g. its intrinsics.json)."),
        site: str = typer.Option(..., "--site", help="Name to install the weights under."),
        model: str = typer.Option("fastmatch", "--model", help="Registered model name."),
        limit: Optional[int] = typer.Option(None, "--limit", min=1, help="Use only the first N frames."),
        init: str = typer.Option("auto", "--init", help="Starting weights: auto (the 'synthetic' site if present, "
                                                        "else scratch) | scratch | SITE | weights path."),
        steps: int = typer.Option(600, "--steps", min=1, help="Training steps."),
        mode: Optional[str] = typer.Option(None, "--mode", help="heads | full (default: full from scratch, "
                                                                "else heads)."),
        out_dir: Optional[Path] = typer.Option(None, "--out", help="Also save the weights + calibration here."),
        no_install: bool = typer.Option(False, "--no-install", help="Do not install as a site (needs --out)."),
        max_rot_std: float = typer.Option(0.5, "--max-rot-std", help="Refuse a pose whose 1-sigma rotation "
                                          "uncertainty exceeds this (deg)."),
        max_trans_std: float = typer.Option(0.25, "--max-trans-std", help="Refuse a pose whose 1-sigma translation "
                                            "uncertainty exceeds this (m); loosen for short recordings."),
        seed: int = typer.Option(0, "--seed"),
        device: str = typer.Option("cpu", "--device"),
        as_json: bool = typer.Option(False, "--json", help="Machine-readable summary on stdout."),
        force: bool = typer.Option(False, "--force", help="Replace the files of an existing --out folder."),
    ) -> None:
        import itertools

        from rich.console import Console
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

        from ..calib.config import CalibConfig
        from ..formats.cameras import read_intrinsics
        from ..io.frames import read_frames
        from ..oneshot.bootstrap import bootstrap

        if no_install and out_dir is None:
            raise typer.BadParameter("--no-install needs --out DIR (the weights must go somewhere)")
        if out_dir is not None and not force and out_dir.exists() and (not out_dir.is_dir() or any(out_dir.iterdir())):
            raise FileExistsError(f"{out_dir} already exists; pass --force to replace it")
        source = read_frames(frames)
        K = read_intrinsics(intrinsics) if intrinsics is not None else getattr(source, "intrinsics", None)
        if K is None and hasattr(source, "__getitem__") and len(source):  # HDF5 caches: per-frame /calibration
            K = getattr(source[0], "intrinsics", None)
        if K is None:
            raise typer.BadParameter(f"--intrinsics is required: {frames} carries no camera intrinsics")
        n_total = len(source) if hasattr(source, "__len__") else None
        n = min(limit, n_total) if (limit and n_total is not None) else (limit or n_total)
        it = itertools.islice(iter(source), limit) if limit else iter(source)
        console = Console(stderr=True)
        with Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
                      TextColumn("{task.fields[info]}"), TimeElapsedColumn(), console=console,
                      transient=as_json) as bar:
            t_obs = bar.add_task("observe + calibrate", total=n, info="")
            t_fit = bar.add_task("train", total=steps, info="", start=False)

            def on_frame(k, rep):
                state = "calibrated" if rep.calibrated else f"next pose attempt at frame {rep.next_calibration_at}"
                bar.update(t_obs, completed=k, info=state)

            def on_step(k, total, loss):  # total covers every gain candidate adapt trains
                if k == 1:
                    bar.start_task(t_fit)
                bar.update(t_fit, completed=k, total=total, info=f"loss {loss:.3f}")

            res = bootstrap(it, K, site, model=model, init=init, steps=steps, mode=mode, install=not no_install,
                            calib_config=CalibConfig(max_rot_std_deg=max_rot_std, max_trans_std_m=max_trans_std),
                            out_dir=out_dir, device=device, seed=seed, on_frame=on_frame, on_step=on_step)
        summary = res.summary()
        if as_json:
            typer.echo(json.dumps(summary))
            return
        a = res.adapt
        typer.echo(res.calibration.summary())
        typer.echo(f"trained {model} ({res.init}, mode {a.mode}) on {a.n_pairs} pseudo-labelled pairs in "
                   f"{a.n_train_frames} frames ({a.n_heldout_frames} held out): loss {a.loss_first:.3f} -> "
                   f"{a.loss_last:.3f}")
        h = res.heldout
        if h is None:
            typer.echo("held-out Top-1 not reported: no frame was held out")
        elif h.verified:
            typer.echo(f"held-out Top-1 {h.reported_top1:.3f}, checked: {h.message}")
        else:
            typer.echo(f"held-out Top-1 {h.message}")
        if len(a.gain_trials) > 1:
            typer.echo("box-geometry gain kept on the held-out frames: " + ", ".join(
                f"{g.box_gain:.3g} (Top-1 {g.top1:.3f}, loss {g.loss:.3f}{', kept' if g.chosen else ''})"
                for g in a.gain_trials))
        if res.threshold is not None:
            t = res.threshold
            typer.echo(f"site match threshold {t.threshold:.2f} (chosen without labels: the default matches agree "
                       f"with the pseudo-labels of {t.n_frames} frames at precision {t.precision:.2f}, recall "
                       f"{t.recall:.2f}); match() uses it when no match_threshold is given")
        if res.site_default is not None:
            d = res.site_default
            typer.echo(f"site default matching: {d.source} (held-out {d.n_frames} frames, {d.n_pose} pose pairs: "
                       f"adapted model alone Top-1/precision/recall {d.model_top1:.2f}/{d.model_precision:.2f}/"
                       f"{d.model_recall:.2f} vs pose {d.pose_top1:.2f}/{d.pose_precision:.2f}/{d.pose_recall:.2f}); "
                       "match(geometry='off') keeps the model, use_calibration=True fuses")
        where = res.paths.get("weights") or res.paths.get("out_weights")
        typer.echo(f"weights: {where}" + (f"  (load with Matcher.from_pretrained({model!r}, site={site!r}))"
                                          if not no_install else ""))
