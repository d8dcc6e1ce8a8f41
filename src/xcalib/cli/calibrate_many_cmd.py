"""``xcalib calibrate-many``: many recordings calibrated on a process pool or a Ray cluster, one table."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from .detect_cmd import detect_flag, detect_request, detector_2d_flag, lidar_mode_flag

# paragraphs reflowed (a single newline would show as a ragged line break); "\\[" keeps rich from
# reading "[ray]" as a markup tag (it printed "pip install 'xcalib'")
_HELP = "\n\n".join(" ".join(p.split("\n")) for p in """Calibrate many recordings (sites, cameras, days) and collect the results in one table.

LIST_OR_GLOB are frame sources (any `xcalib calibrate` SOURCE), glob patterns ("runs/*/frames"),
folders whose sub-folders are recordings, or list files (.txt/.lst/.list: one path per line,
relative to the list's folder and inside it). Each is calibrated on its own (defaults; --camera / --intrinsics
apply to all) on a local process pool (--executor process, --jobs N) or a Ray cluster
(--executor ray \\[--ray-address ADDR]; pip install 'xcalib\\[ray]'). Writes OUT/<name>/calibration.json
per recording and OUT/results.csv, OUT/results.json and OUT/index.html (a recording that cannot
be opened is a row with its error). Exit code 1 when any recording was refused or failed.

Recordings without detections (only images, CameraInfo and clouds): --detect makes them in each worker with xcalib's
own detectors, as `xcalib calibrate --detect` does (needs the onnx extra).

Example: xcalib calibrate-many "recordings/*" --out runs/batch --jobs 2

Example: xcalib calibrate-many recordings.txt --out runs/batch --executor ray

Example: xcalib calibrate-many "raw/*.mcap" --detect --out runs/raw_batch""".split("\n\n"))


def register(app: typer.Typer) -> None:
    @app.command("calibrate-many", help=_HELP)
    def calibrate_many_command(
        recordings: list[str] = typer.Argument(..., metavar="LIST_OR_GLOB...", help="Recordings, globs, folders or list files."),
        out: Path = typer.Option(..., "--out", "-o", help="Output folder (tables, index, one folder per recording)."),
        executor: str = typer.Option("process", "--executor", "-e", help="process | ray | serial."),
        jobs: int = typer.Option(0, "--jobs", "-j", help="Worker processes / local Ray CPUs (0: the CPUs)."),
        ray_address: str = typer.Option(None, "--ray-address", help="Ray cluster to join (default: a local one)."),
        camera: str = typer.Option(None, "--camera", "-c", help="Camera to calibrate in every recording."),
        intrinsics: Path = typer.Option(None, "--intrinsics", "-k", help="Intrinsics for every recording: "
                                     "JSON (with or without a camera \"model\") or a CameraInfo / Kalibr / OpenCV camera file "
                                     "(one camera of a Kalibr camchain: FILE#cam1)."),
        seed: int = typer.Option(0, "--seed", help="Random seed of the hypothesis sampling."),
        as_json: bool = typer.Option(False, "--json", help="Print the table as JSON."),
        force: bool = typer.Option(False, "--force", help="Write into an existing, non-empty folder."),
        detect: bool = detect_flag(),
        detector_2d: Path = detector_2d_flag(),
        lidar_mode: str = lidar_mode_flag(),
    ) -> None:
        from rich.console import Console
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

        from ..batch import calibrate_many, expand_recordings
        from ..calib.config import CalibConfig

        if executor not in ("process", "ray", "serial"):
            raise typer.BadParameter("expected process, ray or serial", param_hint="--executor")
        if jobs < 0:
            raise typer.BadParameter("expected >= 0", param_hint="--jobs")
        dcfg = detect_request(detect, detector_2d, lidar_mode)  # calibrate's flags, checked the same way
        if out.exists() and not force and (not out.is_dir() or any(out.iterdir())):
            raise FileExistsError(f"{out} already exists; pass --force to write into it")
        recordings = [str(p) for p in expand_recordings(recordings)]  # a pattern naming nothing: said before the bar
        console = Console(stderr=True)
        with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                      console=console, disable=as_json) as bar:
            task = bar.add_task("calibrate", total=None)

            def progress(done: int, total: int, rec) -> None:
                bar.update(task, completed=done, total=total, description=f"calibrate ({rec.name})")

            summary = calibrate_many(recordings, out, config=CalibConfig(seed=seed), executor=executor,
                                     jobs=jobs or None, camera=camera, intrinsics=intrinsics, ray_address=ray_address,
                                     progress=progress, detect=dcfg)
        if as_json:
            typer.echo(json.dumps(json.loads(summary.json.read_text()), indent=1))
        else:
            for r in summary.records:
                verdict = "ok" if r.success else ("ERROR" if r.error else f"refused ({r.refusal})")
                sig = f"  1-sigma (norm over axes) {r.rot_sigma_deg:.3f} deg / {r.trans_sigma_m:.3f} m" if r.rot_sigma_deg is not None else ""
                typer.echo(f"{r.name}: {verdict}{sig}  [{r.time_s:.1f} s]" + (f"  {r.error}" if r.error else ""))
            n = len(summary.records)
            typer.echo(f"{summary.n_success} of {n} calibrated, {summary.n_error} error(s); wrote {summary.csv}, "
                       f"{summary.json} and {summary.html}")
        if summary.n_success < len(summary.records):
            raise typer.Exit(1)
