"""Weights files: ``<model>.pt`` (torch payload) + ``<model>.yaml`` (config), strict loading,
site lookup.

Payload (``torch.save`` dict): ``format`` "xcalib-weights-v1", ``model_name``,
``package_version``, ``config`` (the full model config, no device), ``dtype`` ("float32" or
"float16": storage dtype of floating tensors) and ``state_dict``, also under the reference's
key ``model_state_dict`` (the same tensors: stored once).

Bit-exactness: loading restores every tensor exactly as stored (float16 values are upcast to
the model's float32 exactly), so ``save -> load -> save`` writes identical tensors and a
float32 save reloads bit-for-bit.

Site weights are looked up in ``$XCALIB_HOME/sites/<site>/`` (default
``~/.cache/xcalib/sites/<site>/``) first, then in the packaged ``xcalib/weights/<site>/``.
"""

from __future__ import annotations

import io
import os
from importlib import resources
from pathlib import Path
from typing import Any

import torch
import yaml

from .._version import __version__
from ..errors import XcalibError
from ..io._files import atomic_write

__all__ = ["FORMAT", "WeightsMismatchError", "WeightsNotFoundError", "xcalib_home", "site_dirs",
           "find_site_weights", "save_weights", "read_checkpoint", "load_state_strict", "write_config",
           "read_config", "list_sites"]

FORMAT = "xcalib-weights-v1"
WEIGHT_SUFFIXES = (".pth", ".pt")  # save_pretrained writes .pth (as the reference); .pt still loads


class WeightsMismatchError(XcalibError, ValueError):
    """A checkpoint does not fit the model built from the config."""


class WeightsNotFoundError(XcalibError, FileNotFoundError):
    """No weights for a model at a site (or at a given path)."""


def xcalib_home() -> Path:
    return Path(os.environ.get("XCALIB_HOME") or Path.home() / ".cache" / "xcalib")


def packaged_weights_dir() -> Path:
    return Path(str(resources.files("xcalib").joinpath("weights")))


def site_dirs(site: str) -> list[Path]:
    """Where weights of ``site`` are looked for, in order (user site first)."""
    return [xcalib_home() / "sites" / site, packaged_weights_dir() / site]


def list_sites() -> dict[str, list[str]]:
    """{site: [models]} over the user and packaged weight folders."""
    out: dict[str, set[str]] = {}
    for root in (xcalib_home() / "sites", packaged_weights_dir()):
        if root.is_dir():
            for d in root.iterdir():
                models = {p.stem for s in WEIGHT_SUFFIXES for p in d.glob(f"*{s}")} if d.is_dir() else set()
                if models:
                    out.setdefault(d.name, set()).update(models)
    return {k: sorted(v) for k, v in sorted(out.items())}


def weights_in_dir(d: Path, model: str) -> Path | None:
    for s in WEIGHT_SUFFIXES:
        if (d / f"{model}{s}").is_file():
            return d / f"{model}{s}"
    return None


def find_site_weights(model: str, site: str) -> Path:
    """Weights file of ``model`` at ``site``; raises :class:`WeightsNotFoundError` saying how to
    make them."""
    for d in site_dirs(site):
        p = weights_in_dir(d, model)
        if p is not None:
            return p
    have = list_sites()
    looked = ", ".join(str(d) for d in site_dirs(site))
    raise WeightsNotFoundError(
        f"no weights for model {model!r} at site {site!r} (looked in {looked}). "
        f"Train them with `xcalib train --model {model} --train-data TRAIN.h5 --val-data VAL.h5 --site {site}` "
        f"or bootstrap them from unlabelled frames with `xcalib bootstrap --model {model} --site {site} ...`; "
        f"weights available: {have or 'none'}")


def write_config(path: Path, config: dict[str, Any]) -> Path:
    cfg = {k: v for k, v in config.items() if k not in ("device", "weights_path")}
    return atomic_write(path, [yaml.safe_dump(cfg, sort_keys=False).encode()])


def read_config(path: Path) -> dict[str, Any]:
    from ..errors import FormatError

    try:
        cfg = yaml.safe_load(Path(path).read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise FormatError(path, f"not a readable YAML config ({exc})") from None
    if not isinstance(cfg, dict):
        raise FormatError(path, f"expected a YAML mapping, got {type(cfg).__name__}")
    return cfg


def save_weights(model: torch.nn.Module, path: Path, *, model_name: str, config: dict[str, Any],
                 dtype: str = "float32", extra: dict[str, Any] | None = None) -> Path:
    if dtype not in ("float32", "float16"):
        raise ValueError(f"dtype must be 'float32' or 'float16', got {dtype!r}")
    sd = {}
    for k, v in model.state_dict().items():
        v = v.detach().cpu()
        sd[k] = v.to(torch.float16) if dtype == "float16" and v.is_floating_point() else v.clone()
    payload = {"format": FORMAT, "model_name": model_name, "package_version": __version__,
               "config": {k: v for k, v in config.items() if k not in ("device", "weights_path")},
               "dtype": dtype, "state_dict": sd, "model_state_dict": sd, **(extra or {})}
    buf = io.BytesIO()
    torch.save(payload, buf)
    return atomic_write(path, [buf.getbuffer()])


def read_checkpoint(path: Path) -> dict[str, Any]:
    """Payload dict; a bare state dict or a trainer checkpoint ({"model_state_dict": ...}) is
    wrapped as ``{"state_dict": ...}``."""
    path = Path(path)
    if not path.is_file():
        raise WeightsNotFoundError(f"weights file not found: {path}")
    try:
        obj = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # noqa: BLE001 - torch raises many types for bad files
        raise WeightsMismatchError(f"{path}: not a readable torch checkpoint ({exc})") from None
    if isinstance(obj, dict) and "state_dict" in obj:
        return obj
    if isinstance(obj, dict) and "model_state_dict" in obj:
        return {**obj, "state_dict": obj["model_state_dict"]}
    if isinstance(obj, dict) and all(isinstance(v, torch.Tensor) for v in obj.values()):
        return {"state_dict": obj}
    raise WeightsMismatchError(f"{path}: no state dict inside (keys {sorted(obj)[:8] if isinstance(obj, dict) else type(obj)})")


def load_state_strict(model: torch.nn.Module, state_dict: dict[str, torch.Tensor], source: str) -> None:
    """Load every tensor exactly; any missing, unexpected or mis-shaped key is an error."""
    own = model.state_dict()
    missing = sorted(set(own) - set(state_dict))
    unexpected = sorted(set(state_dict) - set(own))
    shapes = [f"{k}: checkpoint {tuple(state_dict[k].shape)} vs model {tuple(own[k].shape)}"
              for k in own if k in state_dict and tuple(state_dict[k].shape) != tuple(own[k].shape)]
    if missing or unexpected or shapes:
        parts = []
        if missing:
            parts.append(f"{len(missing)} missing key(s) {missing[:5]}")
        if unexpected:
            parts.append(f"{len(unexpected)} unexpected key(s) {unexpected[:5]}")
        if shapes:
            parts.append(f"{len(shapes)} shape mismatch(es) {shapes[:3]}")
        raise WeightsMismatchError(f"{source}: checkpoint does not fit the model config: " + "; ".join(parts))
    with torch.no_grad():
        for k, t in own.items():
            t.copy_(state_dict[k].to(t.dtype))
