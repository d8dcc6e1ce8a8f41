"""``xcalib validate``: Top-1 / Top-3 / MRR and latency of models on an HDF5 cache -> report JSON."""

from __future__ import annotations

import json
from pathlib import Path
from typing import List, Optional

import typer

_EXAMPLE = ("Example: xcalib validate --model fastmatch --model crlite --hdf5 site/test.h5 "
            "--output report.json --site synthetic")
_HELP = ("Evaluate matchers on a labelled HDF5 cache (--hdf5); or, given a frame SOURCE instead, check "
         "that source: read every frame and say what a calibration will see (frames, 2D / 3D boxes, "
         "points, intrinsics, recorded poses, labels, times) and what is missing.\n\n" + _EXAMPLE + "\n\n"
         "Example: xcalib validate ../shared/data/a9_sample")


#: options of one mode only: given in the other mode, a usage error names them (never silently ignored)
_HDF5_ONLY = ("model", "site", "weights", "config", "device", "runtime", "onnx_dir")
_SOURCE_ONLY = ("camera", "decode")


def _given(ctx: typer.Context, names) -> list[str]:
    """The options among ``names`` given on the command line (or from the environment), as --flags."""
    out = []
    for name in names:  # by name: typer may carry its own copy of click's ParameterSource
        if getattr(ctx.get_parameter_source(name), "name", "") in ("COMMANDLINE", "ENVIRONMENT"):
            out.append("--" + name.replace("_", "-"))
    return out


def register(app: typer.Typer) -> None:
    @app.command("validate", help=_HELP)
    def validate(
        ctx: typer.Context,
        source: Optional[Path] = typer.Argument(None, metavar="SOURCE",
                                                help="A frame source to check (frame folder, HDF5 cache, "
                                                     "KITTI, bag, ...); leave out with --hdf5."),
        model: List[str] = typer.Option(["fastmatch"], "--model", help="Model name (repeatable)."),
        hdf5: Optional[Path] = typer.Option(None, "--hdf5", help="Labelled HDF5 cache (with match_matrix): "
                                                                 "evaluate the matchers on it."),
        camera: Optional[str] = typer.Option(None, "--camera", help="SOURCE: the camera of a multi-camera source."),
        decode: bool = typer.Option(False, "--decode", help="SOURCE: decode every image (by default a frame folder's "
                                                            "or an HDF5 cache's image sizes come from the image "
                                                            "headers, and 3 frames' images are decoded whole)."),
        output: Optional[Path] = typer.Option(None, "--output", help="Write the report JSON here."),
        site: str = typer.Option("synthetic", "--site", help="Site whose weights to use."),
        weights: Optional[Path] = typer.Option(None, "--weights", help="Weights file/dir (single model only)."),
        config: Optional[Path] = typer.Option(None, "--config", help="Model config YAML (single model only)."),
        device: Optional[str] = typer.Option("cpu", "--device", help="cpu, cuda or auto."),
        limit_frames: Optional[int] = typer.Option(None, "--limit-frames", help="Evaluate (or, with SOURCE, check) the first N frames."),
        as_json: bool = typer.Option(False, "--json", help="Print the report JSON."),
        force: bool = typer.Option(False, "--force", help="Replace an existing --output file."),
        runtime: str = typer.Option("torch", "--runtime", help="torch, or onnx: torch-free ONNX Runtime over the "
                                                               "graphs of `xcalib export` (needs --onnx-dir)."),
        onnx_dir: Optional[Path] = typer.Option(None, "--onnx-dir", help="--runtime onnx: export root (OUT of "
                                                                          "`xcalib export`) or a <model>_<site> folder."),
    ) -> None:
        if source is not None and hdf5 is not None:
            raise typer.BadParameter("give a frame SOURCE to check it, or --hdf5 CACHE to evaluate matchers on "
                                     "it, not both", param_hint="SOURCE / --hdf5")
        if source is None and hdf5 is None:
            raise typer.BadParameter("give a frame SOURCE to check it (xcalib validate ../shared/data/a9_sample), "
                                     "or --hdf5 CACHE to evaluate matchers on a labelled cache", param_hint="SOURCE")
        wrong = _given(ctx, _HDF5_ONLY) if source is not None else _given(ctx, _SOURCE_ONLY)
        if wrong:
            mode = ("only to --hdf5 CACHE (evaluating matchers), not to checking a frame SOURCE" if source is not None
                    else "only to checking a frame SOURCE, not to --hdf5 CACHE")
            raise typer.BadParameter(f"{', '.join(wrong)} appl{'y' if len(wrong) > 1 else 'ies'} {mode}",
                                     param_hint=", ".join(wrong))
        if output is not None and output.exists() and not force:
            raise FileExistsError(f"{output} already exists; pass --force to replace it")
        if source is not None:
            from .source_check import check_source, print_check

            report = check_source(source, camera=camera, limit=limit_frames, decode=decode)
            if output is not None:
                from ..io.files import atomic_write

                atomic_write(output, [json.dumps(report, indent=2).encode()])
            if as_json:
                typer.echo(json.dumps(report))
            else:
                print_check(report)
            raise typer.Exit(0 if report["readable"] else 1)
        from rich.progress import Progress

        from ..engine.evaluate import REPORT_SCHEMA, evaluate_matcher, portable_path, report_entry
        from ..io.hdf5 import CacheReader
        from .match_cmd import load_matcher

        if runtime not in ("torch", "onnx"):
            raise typer.BadParameter(f"--runtime must be torch or onnx, got {runtime!r}", param_hint="--runtime")
        if runtime == "onnx" and onnx_dir is None:
            raise typer.BadParameter("--runtime onnx needs --onnx-dir", param_hint="--onnx-dir")
        if (weights or config) and len(model) > 1:
            raise typer.BadParameter("--weights/--config need exactly one --model", param_hint="--weights")
        results, dev = {}, None
        with CacheReader(hdf5) as reader:
            n = len(reader) if limit_frames is None else min(limit_frames, len(reader))
            with Progress(transient=True, disable=as_json) as bar:
                for name in model:
                    if runtime == "onnx":
                        from ..deploy.ort_runtime import load_onnx

                        m = load_onnx(onnx_dir, model=name, site=site)
                    else:
                        m = load_matcher(name, site, weights, config, device)
                    dev = str(m.device)
                    task = bar.add_task(f"validate {name}", total=n)
                    met, wall = evaluate_matcher(m, reader, limit=limit_frames,
                                                 progress=lambda k, t=task: bar.update(t, completed=k))
                    results[name] = report_entry(met, wall)
        report = {"_schema": REPORT_SCHEMA, "site": site, "hdf5": portable_path(hdf5), "device": dev,
                  "runtime": runtime, "results": results}
        if output is not None:
            from ..io.files import atomic_write

            atomic_write(output, [json.dumps(report, indent=2).encode()])
        # a cache without labels (match_matrix) evaluates no frame: said, and exit 1, not scores of 0 that look like a model's
        unlabelled = bool(results) and all(r["n_frames"] == 0 for r in results.values())
        note = (f"{hdf5}: no frame with labels (match_matrix) was evaluated, so the scores are of no frame; a cache "
                f"without labels can be checked as a frame source: xcalib validate {hdf5}")
        if as_json:
            typer.echo(json.dumps(report))
            if unlabelled:
                typer.echo(note, err=True)
                raise typer.Exit(1)
            return
        from rich.console import Console
        from rich.table import Table

        t = Table(title=f"{hdf5.name} ({site})")
        for col in ("model", "top1", "top3", "mrr", "frame top1", "p50 ms", "frames"):
            t.add_column(col, justify="right")
        for name, r in results.items():
            t.add_row(name, f"{r['top1']:.4f}", f"{r['top3']:.4f}", f"{r['mrr']:.4f}", f"{r['frame_top1']:.4f}",
                      f"{r.get('latency_ms_p50', float('nan')):.1f}", str(r["n_frames"]))
        Console().print(t)
        if unlabelled:
            typer.echo(note, err=True)
            raise typer.Exit(1)
