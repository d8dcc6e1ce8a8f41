"""``xcalib demo`` (provisional): load and validate a frame folder and print a summary.

Uses ``--frames`` when given, else the A9 sample at ``../shared/data/a9_sample`` beside the
repository (or ``$XCALIB_SHARED_DATA/a9_sample``), else a tiny synthetic frame set it writes
into ``--out``. A later issue replaces this with the full matching + calibration demo.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import typer

_EXAMPLE = "Example: xcalib demo --out xcalib-demo   (or: xcalib demo --frames ../shared/data/a9_sample --json)"


def _default_frames() -> Path | None:
    env = os.environ.get("XCALIB_SHARED_DATA")
    candidates = [Path(env) / "a9_sample"] if env else []
    repo = Path(__file__).resolve().parents[3]  # src/xcalib/cli/demo_cmd.py -> repository root
    candidates += [repo.parent / "shared" / "data" / "a9_sample", Path.cwd().parent / "shared" / "data" / "a9_sample"]
    return next((c for c in candidates if (c / "manifest.json").is_file()), None)


def _write_tiny_frames(out: Path, num_frames: int = 3, seed: int = 0) -> Path:
    """A few synthetic frames: boxes of points in front of a camera, 2D boxes from projection."""
    import numpy as np

    from ..geometry import CameraIntrinsics, box7_corners, boxes2d_from_points, make_transform, project_points
    from ..io.frames import write_frame_folder
    from ..types import Frame

    rng = np.random.default_rng(seed)
    K = CameraIntrinsics(700.0, 700.0, 320.0, 240.0, width=640, height=480)
    # LiDAR x forward, y left, z up -> camera x right, y down, z forward
    T = make_transform(np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]]), [0.0, 0.2, -0.1])
    frames = []
    for i in range(num_frames):
        m = 4
        cs = np.column_stack([rng.uniform(8, 30, m), rng.uniform(-6, 6, m), np.full(m, 0.0),
                              rng.uniform(3.5, 4.8, m), rng.uniform(1.6, 2.0, m), rng.uniform(1.4, 1.8, m)])
        ext = np.hstack([cs[:, :3] - cs[:, 3:] / 2, cs[:, :3] + cs[:, 3:] / 2])
        inside = [rng.uniform(e[:3], e[3:], size=(300, 3)) for e in ext]
        ground = np.column_stack([rng.uniform(2, 40, 3000), rng.uniform(-15, 15, 3000), np.full(3000, -1.0)])
        pts = np.vstack(inside + [ground]).astype(np.float32)
        uv, _ = project_points(box7_corners(np.hstack([cs, np.zeros((m, 1))])).reshape(-1, 3), K,
                               T[:3, :3], T[:3, 3])
        b2 = np.clip(boxes2d_from_points(uv.reshape(m, 8, 2)), 0, [639, 479, 639, 479])
        image = np.full((480, 640, 3), 90, np.uint8)
        for x1, y1, x2, y2 in b2.astype(int):
            image[y1:y2, x1:x2] = rng.integers(60, 255, 3)
        frames.append(Frame(image=image, point_cloud=pts, bboxes_2d=b2.astype(np.float32),
                            bboxes_3d=ext.astype(np.float32), camera_name="synthetic_cam", frame_key=f"{i:04d}",
                            match_matrix=np.eye(m, dtype=bool), extrinsics=T))
    write_frame_folder(out, frames, camera="synthetic_cam", intrinsics=K, split="demo")
    return out


def register(app: typer.Typer) -> None:
    @app.command("demo", help=f"Load and validate a frame folder and print a summary (provisional demo).\n\n{_EXAMPLE}")
    def demo(
        frames: Path = typer.Option(None, "--frames", help="Frame folder (manifest.json + frame_*/detections.json)."),
        out: Path = typer.Option(Path("xcalib-demo"), "--out", help="Output folder for summary.json (and synthetic frames)."),
        as_json: bool = typer.Option(False, "--json", help="Machine-readable output."),
    ) -> None:
        from rich.console import Console
        from rich.table import Table

        from ..io.frames import read_frames
        from ..protocol import validate_frame_inputs

        console = Console(stderr=as_json)
        out.mkdir(parents=True, exist_ok=True)
        src = frames or _default_frames()
        if src is None:
            src = _write_tiny_frames(out / "frames")
            console.print(f"[yellow]A9 sample not found; wrote {len(read_frames(src))} synthetic frames to {src}[/]")
        seq = read_frames(src)
        rows = []
        with console.status(f"loading {len(seq)} frames from {src}"):
            for fr in seq:
                viol = validate_frame_inputs(*fr.inputs())
                rows.append({
                    "frame_key": fr.frame_key, "image": f"{fr.image_size[0]}x{fr.image_size[1]}",
                    "points": int(len(fr.point_cloud)), "fields": list(fr.point_fields),
                    "bboxes_2d": fr.num_2d, "bboxes_3d": fr.num_3d,
                    "errors": [v.code for v in viol if v.severity == "error"],
                    "warnings": sorted({v.code for v in viol if v.severity == "warning"}),
                })
        n_err = sum(bool(r["errors"]) for r in rows)
        summary = {"frames": str(src), "camera": getattr(seq, "camera", ""), "num_frames": len(rows),
                   "frames_with_errors": n_err, "per_frame": rows}
        (out / "summary.json").write_text(json.dumps(summary, indent=1) + "\n")
        if as_json:
            typer.echo(json.dumps(summary))
        else:
            table = Table(title=f"{src} ({summary['camera'] or 'camera ?'})")
            for col in ("frame", "image", "points", "2D", "3D", "errors", "warnings"):
                table.add_column(col, justify="right" if col in ("points", "2D", "3D") else "left")
            for r in rows:
                table.add_row(r["frame_key"], r["image"], f"{r['points']:,}", str(r["bboxes_2d"]), str(r["bboxes_3d"]),
                              ", ".join(r["errors"]) or "-", ", ".join(r["warnings"]) or "-")
            console.print(table)
            console.print(f"{len(rows)} frames, {n_err} with protocol errors; summary written to {out / 'summary.json'}")
        if n_err:
            raise typer.Exit(1)
