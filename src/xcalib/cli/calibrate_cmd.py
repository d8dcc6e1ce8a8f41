"""``xcalib calibrate``: targetless camera<-LiDAR calibration of a frame folder, with a report."""

from __future__ import annotations

import json
from pathlib import Path

import typer

_HELP = """Estimate T_cam_lidar from the frames' 2D and 3D detections (no target, no labels, no guess).

Writes DIR/calibration.json + .npz, DIR/summary.txt and overlay PNGs (DIR/overlays/).
Exit code 1 when the frames do not determine the pose (the reason is printed and saved).

Example: xcalib calibrate ../shared/data/a9_sample --intrinsics ../shared/data/a9_sample/intrinsics.json --out runs/a9_calib
"""


def register(app: typer.Typer) -> None:
    @app.command("calibrate", help=_HELP)
    def calibrate_command(
        frames: Path = typer.Argument(..., help="Frame source: frame folder, HDF5 cache, KITTI, nuScenes/mmdet3d "
                                                "pickle, bag/MCAP, ... (xcalib.io.sources)."),
        camera: str = typer.Option(None, "--camera", "-c", help="Camera of a multi-camera source."),
        frame_range: str = typer.Option(None, "--frames", help="Frames to use: 0:8, 0,3,5, 8: (indices)."),
        intrinsics: Path = typer.Option(None, "--intrinsics", "-k",
                                        help="Intrinsics JSON {fx, fy, cx, cy, distortion}; default: the folder's."),
        out: Path = typer.Option(Path("calibration_report"), "--out", "-o", help="Report folder."),
        prior: Path = typer.Option(None, "--prior", help="Initial guess: a calibration .json/.npz (skips bring-up)."),
        box_model: str = typer.Option("auto", "--box-model", help="auto | corners | points (3D box outline)."),
        max_overlays: int = typer.Option(8, "--max-overlays", help="Overlay PNGs to draw (0: none)."),
        limit: int = typer.Option(0, "--limit", help="Use only the first N frames (0: all)."),
        seed: int = typer.Option(0, "--seed", help="Random seed of the hypothesis sampling."),
        as_json: bool = typer.Option(False, "--json", help="Print the result dict as JSON."),
        force: bool = typer.Option(False, "--force", help="Replace an existing report folder."),
    ) -> None:
        from rich.console import Console
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

        from ..calib.api import calibrate
        from ..calib.report import write_report
        from ..calib.result import CalibrationResult
        from ..io._files import atomic_dir
        from ..io.frames import read_frames, read_intrinsics_json

        if out.exists() and not force and (not out.is_dir() or any(out.iterdir())):
            raise FileExistsError(f"{out} already exists; pass --force to replace it")
        console = Console(stderr=True)
        try:
            seq = read_frames(frames, camera=camera, frames=frame_range)
        except ValueError as exc:
            raise typer.BadParameter(str(exc), param_hint="--frames") from None
        n = len(seq) if limit <= 0 else min(limit, len(seq))
        if n == 0:
            raise typer.BadParameter(f"{frames}: no frames found", param_hint="FRAMES")
        if intrinsics is not None:
            intr = read_intrinsics_json(intrinsics)
        else:
            intr = getattr(seq, "intrinsics", None)
            if intr is None and n:  # HDF5 caches carry the intrinsics per frame (/calibration)
                intr = getattr(seq[0], "intrinsics", None)
            if intr is None:
                raise typer.BadParameter(f"{frames} has no intrinsics.json; pass --intrinsics K.json",
                                         param_hint="--intrinsics")
        prior_res = CalibrationResult.load(prior) if prior is not None else None
        with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                      console=console, disable=as_json, transient=False) as bar:
            task = bar.add_task("reading frames", total=n)
            items = []
            for i in range(n):
                items.append(seq[i])
                bar.advance(task)
            tasks: dict[str, int] = {}

            def progress(stage: str, done: int, total: int) -> None:
                if stage not in tasks:
                    tasks[stage] = bar.add_task(stage, total=total)
                bar.update(tasks[stage], completed=done, total=total)

            result = calibrate(items, intr, prior=prior_res, box_model=box_model, seed=seed, progress=progress)
            from ..viz.report import write_calibration_report  # HTML page: numbers + overlays

            with atomic_dir(out, overwrite=force) as tmp:  # the whole folder is swapped in at once
                paths = write_report(result, items, tmp, max_overlays=max_overlays, progress=progress)
                html = write_calibration_report(tmp, result, items, calibration_overlays=paths.overlays,
                                                max_frames=max_overlays, title=f"xcalib calibrate: {frames}").html
            moved = {p: out / Path(p).relative_to(tmp) for p in (paths.json, paths.npz, paths.summary, html,
                                                                  *paths.overlays)}
            paths.json, paths.npz, paths.summary, html = (moved[p] for p in (paths.json, paths.npz, paths.summary,
                                                                            html))
            paths.overlays = [moved[p] for p in paths.overlays]
        if as_json:
            typer.echo(json.dumps(result.to_dict(), indent=2))
        else:
            typer.echo(paths.summary.read_text())
            typer.echo(f"wrote {paths.json}, {paths.npz}, {paths.summary} and {len(paths.overlays)} overlay(s)")
            typer.echo(f"report: {html}")
        if not result.success:
            raise typer.Exit(1)
