"""The reference package's deployment commands: ``xcalib export-onnx`` and ``xcalib build-trt``.

Same flags as the reference; xcalib never downloads, so ``--repo`` / ``--revision`` / ``--token``
are refused with a message naming ``xcalib bootstrap`` and the local alternatives (exit 1).
``xcalib export`` is xcalib's own command (ONNX or TRT, ``OUT/<model>_<site>/`` folders).
"""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Optional

import typer

NO_HUB = ("xcalib never downloads weights (--repo/--revision/--token given): use site weights "
          "(packaged or under $XCALIB_HOME/sites/<site>/, made by `xcalib train --site` or `xcalib bootstrap`), "
          "or a local --weights .pth/.pt file or save_pretrained directory")


def _refuse_hub(repo, revision, token) -> None:
    if repo is not None or revision is not None or token is not None:
        typer.echo(f"error: {NO_HUB}", err=True)
        raise typer.Exit(1)


def register(app: typer.Typer) -> None:
    @app.command("export-onnx", help="The reference's ONNX export: load the pretrained weights and write the graphs "
                                     "into --output (default ./onnx/<model>/) with a parity check; exit 1 when "
                                     "parity is not OK.\n\nExample: xcalib export-onnx --model crlite --site "
                                     "synthetic --output onnx/crlite")
    def export_onnx(
        model: str = typer.Option("crlite", "--model", help="Registered model name."),
        site: str = typer.Option("synthetic", "--site", help="Site whose weights to export."),
        weights: Optional[Path] = typer.Option(None, "--weights", help=".pth/.pt file or save_pretrained directory."),
        config: Optional[Path] = typer.Option(None, "--config", help="Model config YAML."),
        repo: Optional[str] = typer.Option(None, "--repo", help="Refused: xcalib never downloads."),
        revision: Optional[str] = typer.Option(None, "--revision", help="Refused: xcalib never downloads."),
        token: Optional[str] = typer.Option(None, "--token", help="Refused: xcalib never downloads."),
        device: Optional[str] = typer.Option(None, "--device", help="Device the weights are loaded on."),
        output: Optional[Path] = typer.Option(None, "--output", help="Output folder (default ./onnx/<model>/)."),
        export_device: str = typer.Option("cpu", "--export-device",
                                          help="Accepted for the reference; xcalib always traces a CPU copy."),
        force: bool = typer.Option(False, "--force", help="Replace an existing export in the output folder."),
    ) -> None:
        _refuse_hub(repo, revision, token)
        from ..engine.matcher import Matcher

        m = Matcher.from_pretrained(model, weights=weights, config=config, device=device or "cpu", site=site)
        res = m.build("onnx", output if output is not None else Path("onnx") / model,
                      site=site if weights is None else None, overwrite=force)
        for a in res.artifacts:
            typer.echo(f"wrote {a}")
        worst = f"{res.max_parity_error:.3g}" if res.parity else "not checked"
        typer.echo(f"worst parity |torch - onnx| = {worst} ({'OK' if res.parity_ok else 'NOT OK'}, "
                   f"tolerance {res.tolerance:.0e})")
        if not res.parity_ok:
            raise typer.Exit(1)

    @app.command("build-trt", context_settings={"allow_extra_args": True, "ignore_unknown_options": True},
                 help="The reference's TensorRT build: trtexec on an existing ONNX export (no export here). "
                      "Arguments after -- go to trtexec. Exit 1 when trtexec is missing (2 is for usage errors).\n\n"
                      "Example: xcalib build-trt --model crlite --site synthetic --precision fp16 -- --verbose")
    def build_trt(
        ctx: typer.Context,
        model: str = typer.Option("crlite", "--model", help="Registered model name."),
        site: str = typer.Option("synthetic", "--site", help="Site of the exported weights."),
        config: Optional[Path] = typer.Option(None, "--config", help="Accepted for the reference; the ONNX "
                                                                       "folder's manifest carries the config."),
        onnx_dir: Optional[Path] = typer.Option(None, "--onnx-dir", help="ONNX export (default ./onnx/<model>_<site>/)."),
        engine_dir: Optional[Path] = typer.Option(None, "--engine-dir",
                                                  help="Engine folder (default ./engines/<model>_<site>/)."),
        precision: str = typer.Option("fp16", "--precision", help="fp32, fp16 or best (int8: xcalib's addition)."),
        trtexec: Optional[Path] = typer.Option(None, "--trtexec", help="Path of trtexec (else searched)."),
        log_dir: Optional[Path] = typer.Option(None, "--log-dir", help="Also copy the trtexec logs here."),
    ) -> None:
        from ..deploy import trt
        from ..deploy.errors import OnnxFolderError
        from ..deploy.manifest import folder_name, read_manifest

        try:
            exe = trt.find_trtexec(trtexec)
        except FileNotFoundError as exc:
            typer.echo(f"error: {exc}", err=True)
            raise typer.Exit(1)  # a missing tool is a failure, not a usage error (exit 2)
        src = onnx_dir if onnx_dir is not None else Path("onnx") / folder_name(model, site)
        man = read_manifest(src)
        if man.model != model:
            raise OnnxFolderError(src / "manifest.json", f"holds model {man.model!r}, not {model!r}", "model")
        out = engine_dir if engine_dir is not None else Path("engines") / folder_name(model, site)
        res = trt.build_engines(src, out, man, exe, precision=trt.check_precision(precision), extra_args=list(ctx.args))
        if log_dir is not None:
            log_dir.mkdir(parents=True, exist_ok=True)
            for p in res.logs:
                shutil.copyfile(p, log_dir / p.name)
        for a in res.artifacts:
            typer.echo(f"wrote {a}")
