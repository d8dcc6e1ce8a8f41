"""``xcalib synth``: write a synthetic site (train/val/test HDF5 caches + site.json) with exact GT."""

from __future__ import annotations

import json
from pathlib import Path

import typer

_EXAMPLE = ("Example: xcalib synth --out sites/a --frames 200 --seed 1 --preset roadside "
            "--set camera_height=10 --contact-sheet sheet.png")


def _parse_set(items: list[str]) -> dict:
    out = {}
    for item in items:
        if "=" not in item:
            raise typer.BadParameter(f"--set expects KEY=VALUE (e.g. camera_height=9.5), got {item!r}")
        k, v = item.split("=", 1)
        try:
            val = json.loads(v)
        except json.JSONDecodeError:
            val = v
        out[k.strip()] = tuple(val) if isinstance(val, list) else val
    return out


def register(app: typer.Typer) -> None:
    @app.command("synth", help=f"Generate a synthetic camera+LiDAR site with exact ground truth.\n\n{_EXAMPLE}")
    def synth(
        out: Path = typer.Option(..., "--out", "-o", help="Output folder (train.h5, val.h5, test.h5, site.json)."),
        frames: int = typer.Option(100, "--frames", "-n", min=1, help="Total frames, split 70/15/15 unless "
                                   "--train/--val/--test are given."),
        seed: int = typer.Option(0, "--seed", help="Site seed (same seed, same site and frames)."),
        preset: str = typer.Option("roadside", "--preset", help="roadside | vehicle."),
        n_train: int = typer.Option(None, "--train", help="Frames in train.h5."),
        n_val: int = typer.Option(None, "--val", help="Frames in val.h5."),
        n_test: int = typer.Option(None, "--test", help="Frames in test.h5."),
        sets: list[str] = typer.Option([], "--set", help="SiteConfig override KEY=VALUE (JSON value; "
                                       "lists are ranges), repeatable."),
        distortion: bool = typer.Option(False, "--distortion", help="OpenCV lens distortion."),
        no_images: bool = typer.Option(False, "--no-images", help="Labels-only: blank images (fast)."),
        no_lidar: bool = typer.Option(False, "--no-lidar", help="No point clouds (fast)."),
        lossless: bool = typer.Option(False, "--lossless", help="PNG instead of JPEG image blobs."),
        contact: Path = typer.Option(None, "--contact-sheet", help="Also write a PNG grid of test frames."),
        as_json: bool = typer.Option(False, "--json", help="Machine-readable output."),
        force: bool = typer.Option(False, "--force", help="Replace an existing output."),
    ) -> None:
        from rich.console import Console
        from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

        from ..data.synth import PRESETS, iter_frames, sample_site, write_site

        if preset not in PRESETS:
            raise typer.BadParameter(f"--preset must be one of {sorted(PRESETS)}, got {preset!r}")
        overrides = _parse_set(sets)
        if distortion:
            overrides["distortion"] = True
        if n_train is None and n_val is None and n_test is None:
            n_val = n_test = max(1, round(0.15 * frames)) if frames >= 3 else 0
            n_train = max(frames - n_val - n_test, 0)
        n_train, n_val, n_test = n_train or 0, n_val or 0, n_test or 0
        if out.exists() and not force and (not out.is_dir() or any(out.iterdir())):
            raise FileExistsError(f"{out} already exists; pass --force to replace it")
        console = Console(stderr=True)
        totals = {"train": n_train, "val": n_val, "test": n_test}
        with Progress(TextColumn("{task.description}"), BarColumn(), TextColumn("{task.completed}/{task.total}"),
                      TimeElapsedColumn(), console=console, transient=as_json) as progress:
            # the splits are written one after the other: each one's clock starts when the one before
            # it is done (every clock counted from the start of all of them)
            tasks = {s: progress.add_task(f"{s:5s}", total=max(n, 1), start=False) for s, n in totals.items()}
            order = [s for s, n in totals.items() if n > 0]
            if order:
                progress.start_task(tasks[order[0]])

            def _advance(split: str, k: int, n: int) -> None:
                progress.update(tasks[split], completed=k)
                if k >= n and split in order and order.index(split) + 1 < len(order):
                    progress.start_task(tasks[order[order.index(split) + 1]])

            write_site(out, n_train, n_val, n_test, seed=seed, preset=preset, progress=_advance,
                       render_images=not no_images, lidar=not no_lidar,
                       image_format="png" if lossless else "jpeg", overwrite=force, **overrides)
        info = json.loads((out / "site.json").read_text())
        sheet = None
        if contact is not None:
            from ..data.synth import contact_sheet

            site = sample_site(seed, preset, **overrides)
            fr = [next(iter_frames(site, 1, seed=1000 * seed + 3, start=15 * k, render_images=not no_images,
                                   lidar=not no_lidar)) for k in range(6)]  # spread over the test sequence
            sheet = str(contact_sheet(fr, contact, cols=3))
        result = {"out": str(out), "splits": info["splits"], "T_cam_lidar": info["T_cam_lidar"],
                  "intrinsics": info["intrinsics"], "contact_sheet": sheet}
        if as_json:
            typer.echo(json.dumps(result))
        else:
            console.print(f"wrote site (seed {seed}, preset {preset}) to {out}: "
                          + ", ".join(f"{s}.h5 {n} frames" for s, n in totals.items())
                          + (f"; contact sheet {sheet}" if sheet else ""), highlight=False)
