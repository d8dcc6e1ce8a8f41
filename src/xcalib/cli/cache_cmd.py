"""``xcalib cache build`` / ``xcalib cache info``: HDF5 frame caches (../shared/specs/hdf5-cache-format.md)."""

from __future__ import annotations

import json
from pathlib import Path

import typer

_BUILD_EX = "Example: xcalib cache build ../shared/data/a9_sample --out a9.h5 --lossless"
_INFO_EX = "Example: xcalib cache info site/test.h5 --json"


def register(app: typer.Typer) -> None:
    cache_app = typer.Typer(help="Build and inspect HDF5 frame caches.\n\n" + _BUILD_EX, no_args_is_help=True)
    app.add_typer(cache_app, name="cache")

    @cache_app.command("build", help=f"Write frames (a frame folder or any read_frames source) to an HDF5 cache.\n\n{_BUILD_EX}")
    def build(
        frames_dir: Path = typer.Argument(..., help="Frame folder (manifest.json + frame_*/) or another frame source."),
        out: Path = typer.Option(..., "--out", "-o", help="Output .h5 file (written atomically)."),
        lidar_name: str = typer.Option("lidar", "--lidar-name", help="Subgroup name under /point_clouds."),
        lossless: bool = typer.Option(False, "--lossless", help="Store PNG instead of JPEG blobs (exact images)."),
        quality: int = typer.Option(92, "--quality", min=1, max=100, help="JPEG quality."),
        as_json: bool = typer.Option(False, "--json", help="Machine-readable output."),
        force: bool = typer.Option(False, "--force", help="Replace an existing cache."),
    ) -> None:
        from rich.console import Console
        from rich.progress import Progress

        if out.exists() and not force:
            raise FileExistsError(f"{out} already exists; pass --force to replace it")

        from ..io.frames import read_frames
        from ..io.hdf5 import cache_summary, write_cache

        console = Console(stderr=True)
        seq = read_frames(frames_dir)
        n = len(seq)
        with Progress(console=console, transient=True, disable=as_json) as progress:
            task = progress.add_task(f"caching {n} frames", total=n)
            path = write_cache(out, (seq[i] for i in range(n)), lidar_name=lidar_name,
                               image_format="png" if lossless else "jpeg", jpeg_quality=quality,
                               progress=lambda k: progress.update(task, completed=k))
        summary = cache_summary(path)
        if as_json:
            typer.echo(json.dumps(summary))
        else:
            console.print(f"wrote {summary['frames']} frames to {path} "
                          f"(cameras: {', '.join(summary['cameras'])}; calibration: "
                          f"{'yes' if summary['calibration'] else 'no'})", highlight=False)

    @cache_app.command("info", help=f"Counts, cameras, LiDARs and calibration of an HDF5 cache.\n\n{_INFO_EX}")
    def info(
        cache: Path = typer.Argument(..., help="The .h5 cache."),
        as_json: bool = typer.Option(False, "--json", help="Machine-readable output."),
    ) -> None:
        from rich.console import Console
        from rich.table import Table

        from ..io.hdf5 import cache_summary

        s = cache_summary(cache)
        if as_json:
            typer.echo(json.dumps(s))
            return
        t = Table(title=str(cache), show_header=False)
        t.add_row("frames", f"{s['frames']} ({s['first_key']} .. {s['last_key']})")
        t.add_row("label sensor", f"{s['label_sensor']} (of {', '.join(s['label_sensors'])})")
        t.add_row("cameras", ", ".join(f"{c} ({s['image_blobs'].get(c, 0)} blobs)" for c in s["cameras"]))
        t.add_row("lidars", ", ".join(s["lidars"]))
        t.add_row("2D / 3D detections", f"{s['detections_2d']} / {s['detections_3d']}")
        t.add_row("GT matches", str(s["matches"]))
        cal = s["calibration"]
        t.add_row("calibration", "none" if not cal else "; ".join(
            f"{c}: intrinsics={'yes' if v['intrinsics'] else 'no'}, extrinsics={v['extrinsics'] or 'no'}"
            for c, v in cal.items()))
        Console().print(t)
