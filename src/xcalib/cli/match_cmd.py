"""``xcalib match``: match one frame (frame folder or HDF5 cache frame) -> matches table / JSON."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Optional

import typer

_EXAMPLE = ("Example: xcalib match ../shared/data/a9_sample --index 0 --model fastmatch --site synthetic --json\n\n"
            "         xcalib match site/test.h5 --key 000003 --assignment hungarian   (frame keys: xcalib cache info)")


def load_matcher(model: str, site: str, weights: Optional[Path], config: Optional[Path], device: Optional[str]):
    """Shared by match / validate: ``Matcher.from_pretrained`` with the CLI's options."""
    from ..engine.matcher import Matcher

    return Matcher.from_pretrained(model, weights=weights, config=config, device=device, site=site)


def _weights_misfit(matcher, result, site: str, weights: Optional[Path]) -> str:
    """A warning when weights the user chose (``--site NAME`` of their own, or ``--weights``) score
    this frame out of domain (:func:`xcalib.engine.domain.out_of_domain`): the matches shown come
    from scores that do not fit the data. "" when they fit, when the matches are not the model's
    alone (fused with a site calibration, or by geometric consensus: the shipped weights' fallback,
    which warns by itself), or when it cannot tell."""
    from ..engine.domain import SHIPPED_SITES, out_of_domain

    if result.source != "model" or (weights is None and site in SHIPPED_SITES):
        return ""
    why = out_of_domain(result.similarity, getattr(matcher.model, "score_range", (-1.0, 1.0)),
                        getattr(matcher.model, "fill_value", None))
    if not why:
        return ""
    chosen = f"--weights {weights}" if weights is not None else f"--site {site}"
    return (f"warning: the weights chosen with {chosen} do not fit this frame ({why}): the matches below come "
            "from scores out of their domain and are likely wrong. They were made for another site or camera: "
            "adapt a matcher to this recording (`xcalib bootstrap RECORDING --intrinsics K.json --site NAME`), "
            "or leave --site and --weights out to match by geometric consensus")


def register(app: typer.Typer) -> None:
    @app.command("match", help="Match the 2D and 3D detections of one frame.\n\n" + _EXAMPLE)
    def match(
        path: Path = typer.Argument(..., help="Frame folder (manifest or detections.json) or HDF5 cache."),
        index: int = typer.Option(0, "--index", help="Frame index inside PATH."),
        key: Optional[str] = typer.Option(None, "--key", help="Frame key (overrides --index)."),
        model: str = typer.Option("fastmatch", "--model", help="Registered model name."),
        site: str = typer.Option("synthetic", "--site", help="Site whose weights to use."),
        weights: Optional[Path] = typer.Option(None, "--weights", help="Weights file or save_pretrained dir."),
        config: Optional[Path] = typer.Option(None, "--config", help="Model config YAML."),
        device: Optional[str] = typer.Option(None, "--device", help="cpu, cuda, auto (default auto)."),
        top_k: int = typer.Option(1, "--top-k", help="Matches per camera detection (argmax)."),
        threshold: float = typer.Option(0.0, "--threshold", help="Minimum score of a match."),
        assignment: str = typer.Option("argmax", "--assignment", help="argmax or hungarian (one-to-one)."),
        validate: str = typer.Option("warn", "--validate", help="warn, strict or off."),
        as_json: bool = typer.Option(False, "--json", help="Machine-readable output."),
        use_calibration: bool = typer.Option(True, "--calibration/--no-calibration",
                                             help="Fuse the scores with the site calibration (calibration.json "
                                                  "beside the weights) when there is one."),
    ) -> None:
        from ..io.frames import read_frames

        frames = read_frames(path)
        if key is not None:
            keys = list(getattr(frames, "frame_keys", []))
            if key not in keys:
                raise typer.BadParameter(f"no frame {key!r} in {path} (keys: {keys[:10]}...)", param_hint="--key")
            index = keys.index(key)
        if not 0 <= index < len(frames):
            raise typer.BadParameter(f"{path} has {len(frames)} frame(s); got --index {index}", param_hint="--index")
        frame = frames[index]
        m = load_matcher(model, site, weights, config, device)
        r = m.match_frame(frame, top_k=top_k, match_threshold=threshold, validate=validate, assignment=assignment,
                          use_calibration="auto" if use_calibration else False)
        misfit = _weights_misfit(m, r, site, weights)
        if misfit and not as_json:
            typer.echo(misfit, err=True)
        if as_json:
            typer.echo(json.dumps({
                "frame_key": frame.frame_key, "model": r.model, "device": r.device, "latency_ms": r.latency_ms,
                "assignment": r.assignment, "num_2d": frame.num_2d, "num_3d": frame.num_3d,
                "fusion_weight": r.fusion_weight, "source": r.source, "weights_misfit": misfit,
                "kept_2d_indices": r.kept_2d_indices.tolist(), "kept_3d_indices": r.kept_3d_indices.tolist(),
                "matches": [{"index_2d": i, "index_3d": j, "score": s} for i, j, s in r.matches],
                "similarity": r.similarity.tolist()}))
            return
        from rich.console import Console
        from rich.table import Table

        fused = f", fused with the calibration (w={r.fusion_weight:g})" if r.source == "fused" else ""
        if r.source == "geometry":
            fused = ", by geometric consensus: the weights' scores did not fit this frame"
        t = Table(title=f"{frame.frame_key or path.name}: {r.model} ({len(r.matches)} matches, {r.latency_ms:.1f} ms"
                        f"{fused})")
        for col in ("2D index", "3D index", "score"):
            t.add_column(col, justify="right")
        for i, j, s in r.matches:
            t.add_row(str(i), str(j), f"{s:.3f}")
        Console().print(t)
