"""``xcalib demo``: the whole story on a synthetic site with exact ground truth, then on real frames.

1. generate a small synthetic roadside site (rendered images, ray-cast LiDAR, noisy detections);
2. match every frame with the shipped model and score it against the true matches;
3. calibrate camera<-LiDAR from the detections alone (no labels, no initial guess) and score the
   pose against the true extrinsics;
4. when ``../shared/data/a9_sample`` (or ``--real``) exists, calibrate those real frames too and
   report their residuals.

Writes ``<out>/index.html`` (links to one HTML report per calibration run), ``<out>/summary.json``
and per run ``calibration.json`` / ``.npz`` and overlay PNGs. Steps whose pieces are missing
(e.g. no shipped weights) are skipped with a message, not a crash.
"""

from __future__ import annotations

import html
import json
import logging
import time
from pathlib import Path
from typing import Optional

import typer

_EXAMPLE = ("Example: xcalib demo --out xcalib-demo\n\n"
            "         xcalib demo --n-frames 10 --no-real --json")


def _write_tiny_frames(out: Path, num_frames: int = 3, seed: int = 0) -> Path:
    """A few synthetic frames: boxes of points in front of a camera, 2D boxes from projection."""
    import numpy as np

    from ..geometry import (CameraIntrinsics, box7_corners, boxes2d_from_points, center_size_to_extents,
                            make_transform, project_points)
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
        ext = center_size_to_extents(cs)
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


def _progress(console):
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, SpinnerColumn, TextColumn, TimeElapsedColumn

    return Progress(SpinnerColumn(), TextColumn("{task.description}"), BarColumn(bar_width=30), MofNCompleteColumn(),
                    TimeElapsedColumn(), console=console, transient=False)


def _step(progress, description: str, total: int):
    task = progress.add_task(description, total=max(total, 1))

    def cb(done: int, tot: int) -> None:
        progress.update(task, completed=done, total=max(tot, 1))

    def stage(name: str, done: int, tot: int) -> None:
        progress.update(task, description=f"{description} [dim]({name})[/]", completed=done, total=max(tot, 1))

    return task, cb, stage


def _fmt(v, spec: str, unit: str = "") -> str:
    try:
        f = float(v)
    except (TypeError, ValueError):
        return "-"
    if f != f:  # NaN
        return "-"
    return f"{f:{spec}}{unit}"


def _write_index(out: Path, summary: dict) -> Path:
    e = html.escape
    rows, thumbs = [], []
    for name, run in summary.get("calibrations", {}).items():
        figs = [f for f in run.get("figures", []) if not f.endswith("_bringup.png")]
        picks = [next((f for f in figs if "/overlays/" in f), None), next((f for f in figs if "matching" in f), None)]
        for fig in [f for f in picks if f]:
            src = Path(fig).relative_to(out).as_posix()
            thumbs.append(f'<figure><a href="{e(src)}"><img src="{e(src)}" alt="{e(name)}"></a>'
                          f"<figcaption>{e(name)}: {e(Path(src).name)}</figcaption></figure>")
        link = Path(run["report"]).relative_to(out).as_posix() if run.get("report") else None
        cells = [e(name), "yes" if run.get("success") else "no", e(str(run.get("pairs", "-"))),
                 _fmt(run.get("residual_px_median"), ".2f", " px"), _fmt(run.get("iou_median"), ".3f"),
                 _fmt(run.get("rotation_error_deg"), ".3f", " deg"), _fmt(run.get("translation_error_m"), ".3f", " m"),
                 f'<a href="{e(link)}">report</a>' if link else "-"]
        rows.append("<tr>" + "".join(f"<td>{c}</td>" for c in cells) + "</tr>")
    m = summary.get("matching", {})
    match_line = (f"Matching ({e(m.get('model', ''))}, {e(m.get('weights', ''))}): Top-1 {_fmt(m.get('top1'), '.1%')}, "
                  f"Top-3 {_fmt(m.get('top3'), '.1%')}, MRR {_fmt(m.get('mrr'), '.3f')} over "
                  f"{m.get('n_detections', 0)} camera detections" if m.get("ok") else
                  f"Matching skipped: {e(m.get('message', ''))}")
    page = f"""<!doctype html><html lang="en"><head><meta charset="utf-8"><title>xcalib demo</title>
<style>body {{ font-family: system-ui, sans-serif; margin: 24px; }} table {{ border-collapse: collapse; }}
th, td {{ border: 1px solid #ddd; padding: 4px 10px; }} th {{ background: #f5f5f5; }}
figure {{ display: inline-block; margin: 8px; width: 45%; }} img {{ width: 100%; border: 1px solid #ccc; }}</style>
</head><body>
<h1>xcalib demo</h1><p>{match_line}</p>
<table><tr><th>run</th><th>calibrated</th><th>pairs</th><th>residual median</th><th>IoU median</th>
<th>rotation error</th><th>translation error</th><th></th></tr>{''.join(rows)}</table>
<p>Total time {summary.get('seconds', 0):.1f} s. Numbers: <a href="summary.json">summary.json</a>.</p>
{''.join(thumbs)}</body></html>
"""
    from ..io.files import atomic_write

    atomic_write(out / "index.html", [page.encode()])
    return out / "index.html"


def _precision_cell(r) -> str:
    """The demo table's precision row: fine, or COARSE (a starting point, not a pose for fusing the
    sensors), with the 95 % bound, as `xcalib calibrate` prints it."""
    rot, trans = r.bound95
    if r.coarse:
        return f"[yellow]COARSE[/]: 95 % bound {rot:.2f} deg / {trans:.2f} m (a starting point)"
    return f"fine: 95 % bound {rot:.2f} deg / {trans:.2f} m"


def register(app: typer.Typer) -> None:
    @app.command("demo", help="End-to-end demo: synthetic site -> matching -> calibration with no labels and no "
                              "initial guess -> HTML report; then the real A9 sample frames when present.\n\n"
                              + _EXAMPLE)
    def demo(
        out: Path = typer.Option(Path("xcalib-demo"), "--out", help="Output folder (reports, summary.json)."),
        n_frames: int = typer.Option(20, "--n-frames", min=3, help="Synthetic frames to generate."),
        seed: int = typer.Option(5, "--seed", help="Seed of the synthetic traffic (unseen by the shipped weights)."),
        site_seed: int = typer.Option(0, "--site-seed", help="Synthetic site (0: the one the shipped weights "
                                                             "were trained for; others show what does not transfer)."),
        model: str = typer.Option("fastmatch", "--model", help="Matcher model (shipped weights, site 'synthetic')."),
        weights: Optional[Path] = typer.Option(None, "--weights", help="Use these weights instead of the shipped ones."),
        real: Optional[Path] = typer.Option(None, "--real", help="Real frame folder (default ../shared/data/a9_sample)."),
        no_real: bool = typer.Option(False, "--no-real", help="Skip the real-frames part."),
        seed_with_matcher: bool = typer.Option(False, "--seed-with-matcher",
                                               help="Let the matcher's scores seed the calibration's hypotheses "
                                                    "(default: geometry alone)."),
        as_json: bool = typer.Option(False, "--json", help="Print the summary as JSON on stdout."),
        weights_site: str = typer.Option("synthetic", "--site", help="Site whose weights the matcher loads."),
        config: Optional[Path] = typer.Option(None, "--config", help="Model config YAML for the matcher."),
        device: str = typer.Option("cpu", "--device", help="Device of the matcher (cpu, cuda, auto)."),
        n_image: Optional[int] = typer.Option(None, "--n-image", min=1,
                                              help="The reference's quick demo: one synthetic frame with this many "
                                                   "camera boxes (default 3 when --n-lidar is given) -> match and print."),
        n_lidar: Optional[int] = typer.Option(None, "--n-lidar", min=1,
                                              help="The reference's quick demo: this many LiDAR boxes (default 5)."),
    ) -> None:
        from rich.console import Console
        from rich.panel import Panel
        from rich.table import Table

        from . import _demo

        if n_image is not None or n_lidar is not None:  # the reference's one-frame demo
            matcher, why = _demo.load_matcher(model, weights, weights_site, config, device)
            if matcher is None:
                typer.echo(f"error: no matcher: {why}", err=True)
                raise typer.Exit(1)
            for line in _demo.quick_match_demo(matcher, n_image or 3, n_lidar or 5, seed):
                typer.echo(line)
            return
        # far objects hold few LiDAR points by nature; the per-kind protocol warnings would only clutter the demo
        logging.getLogger("xcalib.protocol").setLevel(logging.ERROR)
        console = Console(stderr=as_json, highlight=False)
        t_start = time.perf_counter()
        out.mkdir(parents=True, exist_ok=True)
        summary: dict = {"out": str(out), "seed": seed, "site_seed": site_seed}
        console.print(Panel.fit("[b]xcalib demo[/b]: camera-LiDAR matching and targetless calibration\n"
                                "synthetic site with exact ground truth, then real frames when available",
                                border_style="cyan"))
        real_dir = None if no_real else _demo.find_real_frames(real)
        n_steps = 4 if real_dir is not None else 3
        with _progress(console) as progress:
            # 1. synthetic site
            _, cb, _ = _step(progress, f"[1/{n_steps}] synthetic site {site_seed}", n_frames)
            data = _demo.synthetic_site(n_frames, seed, site_seed=site_seed, progress=cb)
            site = data.site
            summary["synthetic"] = {"frames": n_frames, "image": f"{site.width}x{site.height}",
                                    "mount": site.mount, "camera_height_m": round(float(site.values.get(
                                        "camera_height", float("nan"))), 2), "seconds": round(data.seconds, 2)}
            # 2. matching
            matcher, why = _demo.load_matcher(model, weights, weights_site, config, device,
                                              own_site=site_seed == _demo.SHIPPED_SITE_SEED)
            if matcher is not None:
                _, cb, _ = _step(progress, f"[2/{n_steps}] matching ({model})", n_frames)
                mo = _demo.match_frames(matcher, data.frames, progress=cb)
            else:
                mo = _demo.MatchingOutcome(False, f"no matcher: {why}", model)
                progress.console.print(f"[yellow][2/{n_steps}] matching skipped[/]: {why}")
            summary["matching"] = mo.to_dict()
            summary["matching"]["weights"] = str(weights) if weights else "shipped weights, site 'synthetic'"
            # 3. calibration (no labels, no initial guess)
            _, _, stage = _step(progress, f"[3/{n_steps}] calibrating", 1)
            syn = _demo.calibrate_frames(
                data.frames, site.intrinsics, out / "synthetic", truth=data.truth,
                matcher=mo.matcher if seed_with_matcher else None,
                matches=mo.results or None, style=_demo.ReportStyle(
                    title=f"xcalib demo: synthetic roadside site {site_seed} (traffic seed {seed})",
                    extra=({"matcher": f"{mo.model} ({weights or 'shipped weights'})", "matcher Top-1": mo.top1,
                            "matcher Top-3": mo.top3, "matcher MRR": mo.mrr} if mo.ok else None)),
                progress=stage)
            summary["calibrations"] = {"synthetic": syn.to_dict()}
            # 4. real frames
            real_out = None
            if real_dir is not None:
                try:
                    from ..io.frames import read_frames

                    seq = read_frames(real_dir)
                    _, cb, stage = _step(progress, f"[4/{n_steps}] real: {real_dir.name}",
                                         len(seq))
                    frames = []
                    for k, fr in enumerate(seq):
                        frames.append(fr)
                        cb(k + 1, len(seq))
                    intr = getattr(seq, "intrinsics", None)
                    real_out = _demo.calibrate_frames(
                        frames, intr, out / real_dir.name,
                        style=_demo.ReportStyle(title=f"xcalib demo: real frames {real_dir.name}", max_frames=3),
                        progress=stage)
                    summary["calibrations"][real_dir.name] = real_out.to_dict()
                    if mo.matcher is not None and real_out.result is not None and real_out.result.success:
                        agree, n_cmp = _demo.matcher_agreement(mo.matcher, frames, real_out.result)
                        summary["calibrations"][real_dir.name].update(matcher_agreement=agree,
                                                                      matcher_agreement_pairs=n_cmp)
                except Exception as exc:  # noqa: BLE001 - real data is a bonus, not a requirement
                    progress.console.print(f"[yellow]real frames skipped[/]: {type(exc).__name__}: {exc}")
                    summary["calibrations"][real_dir.name] = {"ok": False, "message": f"{type(exc).__name__}: {exc}"}
            elif not no_real:
                progress.console.print("[dim]no ../shared/data/a9_sample beside the repository: real-frames part "
                                       "skipped (use --real FOLDER)[/]")
        summary["seconds"] = round(time.perf_counter() - t_start, 2)
        index = _write_index(out, summary)
        summary["index"] = str(index)
        from ..io.files import atomic_write

        atomic_write(out / "summary.json", [(json.dumps(summary, indent=1) + "\n").encode()])

        # ------------------------------------------------------------------ figures
        t = Table(title="Synthetic site vs ground truth", show_header=True, header_style="bold")
        t.add_column("what")
        t.add_column("value", justify="right")
        t.add_row("site", f"{summary['synthetic']['mount']}, camera {summary['synthetic']['camera_height_m']} m up")
        t.add_row("frames", f"{n_frames} x {summary['synthetic']['image']} px")
        if mo.ok:
            t.add_row(f"matching Top-1 / Top-3 ({mo.model})", f"{mo.top1:.1%} / {mo.top3:.1%}")
            t.add_row("matching MRR", f"{mo.mrr:.3f} over {mo.n_rows} detections")
            t.add_row("matcher latency p50", f"{mo.latency_ms_p50:.1f} ms / frame")
        else:
            short = mo.message.split(" (looked in")[0].replace("no matcher: ", "")
            t.add_row("matching", f"[yellow]skipped[/]: {short[:90]}")
        r = syn.result
        if r is not None and r.success:
            t.add_row("calibration", "[green]success[/]")
            t.add_row("rotation error", f"{syn.rotation_error_deg:.3f} deg")
            t.add_row("translation error", f"{syn.translation_error_m:.3f} m")
            t.add_row("residual (median)", f"{r.residual_px_median:.2f} px, IoU {r.iou_median:.3f}")
            t.add_row("pairs correct / recovered", f"{syn.pair_precision:.1%} / {syn.pair_recall:.1%} ({r.n_pairs} pairs)")
            t.add_row("precision", _precision_cell(r))
            t.add_row("calibration time", f"{syn.seconds:.1f} s")
        else:
            t.add_row("calibration", f"[red]failed[/]: {syn.message}")
        console.print(t)
        if real_out is not None:
            rt = Table(title=f"Real frames: {real_dir} (no ground truth)", header_style="bold")
            rt.add_column("what")
            rt.add_column("value", justify="right")
            rr = real_out.result
            if rr is not None and rr.success:
                off = None if rr.diagnostics is None else rr.diagnostics.centre_offset_px_median
                rt.add_row("calibration", "[green]success[/]")
                rt.add_row("matched pairs", f"{rr.n_pairs} over {real_out.n_frames} frames")
                rt.add_row("residual (median / mean)", f"{rr.residual_px_median:.2f} / {rr.reproj_error_px:.2f} px")
                rt.add_row("IoU projected 3D vs 2D (median)", f"{rr.iou_median:.3f}")
                rt.add_row("box-centre offset (median)", f"{_fmt(off, '.1f', ' px')} (reference: ~30 px)")
                rt.add_row("1-sigma rot / trans", f"{max(rr.rotation_std_deg):.3f} deg / {max(rr.translation_std_m):.3f} m")
                rt.add_row("precision", _precision_cell(rr))
                rt.add_row("calibration time", f"{real_out.seconds:.1f} s")
                rs = summary["calibrations"][real_dir.name]
                if "matcher_agreement" in rs:
                    rt.add_row(f"{mo.model} (synthetic weights) = calib. pairs",
                               f"{rs['matcher_agreement']:.1%} of {rs['matcher_agreement_pairs']}")
            else:
                rt.add_row("calibration", f"[red]failed[/]: {real_out.message}")
            console.print(rt)
            agree = summary["calibrations"][real_dir.name].get("matcher_agreement")
            if agree is not None and agree < 0.8:
                console.print(f"[dim]The shipped weights belong to the synthetic site; bring a matcher up at this site "
                              f"without labels: xcalib bootstrap {real_dir} --site my-site[/]")
        console.print(f"report: [link=file://{index.resolve()}]{index}[/link]  ({summary['seconds']:.1f} s in total)")
        if as_json:
            typer.echo(json.dumps(summary))
        if r is None or not r.success:
            raise typer.Exit(1)
