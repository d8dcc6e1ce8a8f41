"""``xcalib export``: ONNX graphs (with a parity check) or TensorRT engines of a model's weights."""

from __future__ import annotations

import json
from pathlib import Path
from typing import List, Optional

import typer

_EXAMPLE = ("Example: xcalib export --model crlite --site synthetic --format onnx --out onnx\n\n"
            "         xcalib export --model crlite --site synthetic --format trt --precision fp16 --out engines "
            "--trt-arg=--memPoolSize=workspace:2048")


def register(app: typer.Typer) -> None:
    @app.command("export", help="Export a model for deployment: ONNX (+ parity vs PyTorch) or TensorRT "
                                "engines (trtexec). Files go to OUT/<model>_<site>/.\n\n" + _EXAMPLE)
    def export(
        model: str = typer.Option(..., "--model", help="Registered model name."),
        fmt: str = typer.Option("onnx", "--format", help="onnx or trt."),
        out: Path = typer.Option(Path("onnx"), "--out", help="Output root; files go to OUT/<model>_<site>/."),
        site: str = typer.Option("synthetic", "--site", help="Site whose weights to export."),
        weights: Optional[Path] = typer.Option(None, "--weights", help="Weights file or directory (else the site's)."),
        config: Optional[Path] = typer.Option(None, "--config", help="Model config YAML."),
        precision: str = typer.Option("fp16", "--precision", help="TensorRT precision: fp32, fp16, int8 or best."),
        trtexec: Optional[Path] = typer.Option(None, "--trtexec", help="Path of trtexec (else searched)."),
        trt_arg: List[str] = typer.Option([], "--trt-arg", help="Extra trtexec argument (repeatable)."),
        onnx_dir: Optional[Path] = typer.Option(None, "--onnx-dir", help="TRT: build from this ONNX export."),
        allow_random: bool = typer.Option(False, "--allow-random", help="Export random weights (testing only)."),
        no_verify: bool = typer.Option(False, "--no-verify", help="Skip the parity check (reported as not OK)."),
        as_json: bool = typer.Option(False, "--json", help="Machine-readable output."),
        force: bool = typer.Option(False, "--force", help="Replace an existing OUT/<model>_<site>/ export."),
    ) -> None:
        if fmt not in ("onnx", "trt"):
            raise typer.BadParameter(f"--format must be onnx or trt, got {fmt!r}", param_hint="--format")
        if fmt == "trt":  # before the ONNX export: a missing trtexec is said at once, not after it
            from ..deploy.trt import find_trtexec

            find_trtexec(trtexec)
        from rich.console import Console

        from ..engine.matcher import Matcher

        console = Console(stderr=True, quiet=as_json)
        with console.status(f"loading {model} ({site})"):
            if allow_random and weights is None:
                from ..engine.checkpoint import WeightsNotFoundError

                try:
                    m = Matcher.from_pretrained(model, config=config, device="cpu", site=site)
                except WeightsNotFoundError:
                    m = Matcher(model, device="cpu", allow_random=True)
            else:
                m = Matcher.from_pretrained(model, weights=weights, config=config, device="cpu", site=site)
        with console.status(f"exporting {model} to {fmt} (parity check included)"):
            res = m.build(fmt, out, site=site if m.weights_path is not None else None, allow_random=allow_random,
                          site_folder=True, overwrite=force,
                          verify=not no_verify, precision=precision, trtexec=trtexec, extra_trt_args=trt_arg,
                          onnx_dir=onnx_dir)
        d = res.to_dict()
        if as_json:
            typer.echo(json.dumps(d))
        else:
            from rich.table import Table

            t = Table(title=f"{res.model} ({res.site}) -> {res.output_dir}")
            t.add_column("parity check")
            t.add_column("max |torch - onnx|", justify="right")
            for k, v in res.parity.items():
                t.add_row(k, f"{v:.2e}")
            Console().print(t)
            for a in res.artifacts:
                typer.echo(f"wrote {a}")
            for n in res.notes:
                typer.echo(f"note: {n}")
            typer.echo(f"parity {'OK' if res.parity_ok else 'NOT OK'} (tolerance {res.tolerance:.0e})")
        if not res.parity_ok and not no_verify:
            raise typer.Exit(1)
