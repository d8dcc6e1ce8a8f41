"""Weights files: ``<model>.pt`` (torch payload) + ``<model>.yaml`` (config), strict loading,
site lookup.

Payload (``torch.save`` dict): ``format`` "xcalib-weights-v1", ``model_name``,
``package_version``, ``config`` (the full model config, no device), ``dtype`` ("float32" or
"float16": storage dtype of floating tensors) and ``state_dict``, also under the reference's
key ``model_state_dict`` (the same tensors: stored once).

Bit-exactness: loading restores every tensor exactly as stored (float16 values are upcast to
the model's float32 exactly), so ``save -> load -> save`` writes identical tensors and a
float32 save reloads bit-for-bit.

Integrity: every weights file written by :func:`save_weights` gets a sidecar ``<stem>.sha256``
(``sha256sum`` format: digest of the whole file) and the payload holds ``state_sha256`` (digest of
the tensors); :func:`read_checkpoint` checks both when present and refuses non-finite weights,
so a flipped bit or NaN weights are an error, not silent garbage. Files are read with
``torch.load(weights_only=True)`` only (never a pickle that can run code).

Site weights are looked up in ``$XCALIB_HOME/sites/<site>/`` (default
``~/.cache/xcalib/sites/<site>/``) first, then in the packaged ``xcalib/weights/<site>/``.
"""

from __future__ import annotations

import hashlib
import io
import json
import os
from importlib import resources
from pathlib import Path
from typing import Any

import torch
import yaml

from .. import __version__
from ..errors import FormatError, XcalibError
from ..io.files import MAX_TEXT_BYTES, atomic_write, open_regular, read_text

__all__ = ["FORMAT", "WeightsMismatchError", "WeightsNotFoundError", "xcalib_home", "site_dirs",
           "find_site_weights", "save_weights", "read_checkpoint", "load_state_strict", "write_config",
           "read_config", "list_sites", "checksum_path", "write_checksum", "verify_checksum", "state_sha256",
           "save_resume_state", "load_resume_state", "torch_load_safe"]

FORMAT = "xcalib-weights-v1"
WEIGHT_SUFFIXES = (".pth", ".pt")  # save_pretrained writes .pth (as the reference); .pt still loads


class WeightsMismatchError(FormatError):
    """A checkpoint does not fit the model built from the config, or is not a readable, intact
    weights file (a :class:`~xcalib.errors.FormatError`). Built from (path, problem, field) or
    from one message."""

    def __init__(self, path_or_message, problem: str | None = None, field: str | None = None):
        if problem is None:
            self.path, self.field, self.problem = None, None, str(path_or_message)
            ValueError.__init__(self, str(path_or_message))
        else:
            super().__init__(path_or_message, problem, field)


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
    """A YAML mapping (safe loader; size-capped; any parse problem is a FormatError)."""
    try:
        cfg = yaml.safe_load(read_text(path, max_bytes=MAX_TEXT_BYTES, what="YAML config"))
    except FileNotFoundError:
        raise
    except FormatError:
        raise
    except (OSError, yaml.YAMLError, RecursionError, ValueError, TypeError, MemoryError) as exc:
        raise FormatError(path, f"not a readable YAML config ({type(exc).__name__}: {str(exc)[:200]})") from None
    if not isinstance(cfg, dict):
        raise FormatError(path, f"expected a YAML mapping, got {type(cfg).__name__}")
    return cfg


# ------------------------------------------------------------------------------ integrity
def checksum_path(weights: Path) -> Path:
    """The sidecar ``<stem>.sha256`` of a weights file (any suffix: ``.pt``, ``.pth``)."""
    return Path(weights).with_suffix(".sha256")


def _file_sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open_regular(path, what="weights file") as f:
        for b in iter(lambda: f.read(1 << 20), b""):
            h.update(b)
    return h.hexdigest()


def write_checksum(weights: Path) -> Path:
    """Write ``<stem>.sha256`` (``sha256sum`` format) for ``weights``; returns the sidecar."""
    weights = Path(weights)
    return atomic_write(checksum_path(weights), [f"{_file_sha256(weights)}  {weights.name}\n".encode()])


def verify_checksum(weights: Path, *, required: bool = False) -> bool:
    """Compare ``weights`` with its ``<stem>.sha256``; a mismatch is a WeightsMismatchError. Returns
    False when there is no sidecar (an error with ``required``)."""
    weights = Path(weights)
    side = checksum_path(weights)
    if not side.is_file():
        if required:
            raise WeightsMismatchError(weights, f"no checksum file {side.name} beside the weights", "sha256")
        return False
    parts = read_text(side, max_bytes=4096, what="checksum file").split()
    if not parts or len(parts[0]) != 64 or any(c not in "0123456789abcdef" for c in parts[0].lower()):
        raise WeightsMismatchError(side, "expected '<64 hex digits>  <file name>'", "sha256")
    got = _file_sha256(weights)
    if got != parts[0].lower():
        raise WeightsMismatchError(weights, f"sha256 {got[:16]}... does not match {side.name} "
                                            f"({parts[0][:16]}...): the file is corrupt or was replaced", "sha256")
    return True


def state_sha256(state_dict: dict[str, torch.Tensor]) -> str:
    """sha256 over the tensors (names, dtypes, shapes, bytes) in key order."""
    h = hashlib.sha256()
    for k in sorted(state_dict):
        t = state_dict[k].detach().cpu().contiguous()
        h.update(f"{k}|{t.dtype}|{tuple(t.shape)}|".encode())
        h.update(t.reshape(-1).view(torch.uint8).numpy().tobytes() if t.numel() else b"")
    return h.hexdigest()


def torch_load_safe(path: Path, what: str = "checkpoint") -> Any:
    """``torch.load(weights_only=True)`` of a regular file; anything unreadable (including a pickle
    that tries to build other objects) is a WeightsMismatchError naming the file."""
    path = Path(path)
    if not path.is_file():
        raise WeightsNotFoundError(f"{what} file not found: {path}")
    try:
        with open_regular(path, what=what) as fh:
            return torch.load(fh, map_location="cpu", weights_only=True)
    except FormatError:
        raise
    except Exception as exc:  # noqa: BLE001 - torch raises many types for bad files
        raise WeightsMismatchError(path, f"not a readable torch {what} (loaded with weights_only=True; "
                                         f"{type(exc).__name__}: {str(exc)[:300]})") from None


def save_weights(model: torch.nn.Module, path: Path, *, model_name: str, config: dict[str, Any],
                 dtype: str = "float32", extra: dict[str, Any] | None = None) -> Path:
    """Write the weights payload atomically and its ``<stem>.sha256`` sidecar."""
    if dtype not in ("float32", "float16"):
        raise ValueError(f"dtype must be 'float32' or 'float16', got {dtype!r}")
    sd = {}
    for k, v in model.state_dict().items():
        v = v.detach().cpu()
        sd[k] = v.to(torch.float16) if dtype == "float16" and v.is_floating_point() else v.clone()
    payload = {"format": FORMAT, "model_name": model_name, "package_version": __version__,
               "config": {k: v for k, v in config.items() if k not in ("device", "weights_path")},
               "dtype": dtype, "state_dict": sd, "model_state_dict": sd, "state_sha256": state_sha256(sd),
               **(extra or {})}
    buf = io.BytesIO()
    torch.save(payload, buf)
    out = atomic_write(path, [buf.getbuffer()])
    write_checksum(out)
    return out


def read_checkpoint(path: Path) -> dict[str, Any]:
    """Payload dict; a bare state dict or a trainer checkpoint ({"model_state_dict": ...}) is
    wrapped as ``{"state_dict": ...}``. The sidecar checksum and ``state_sha256`` are checked
    when present; non-finite weights are refused."""
    path = Path(path)
    if not path.is_file():
        raise WeightsNotFoundError(f"weights file not found: {path}")
    verify_checksum(path)
    obj = torch_load_safe(path, "weights")
    if isinstance(obj, dict) and "state_dict" in obj:
        out = obj
    elif isinstance(obj, dict) and "model_state_dict" in obj:
        out = {**obj, "state_dict": obj["model_state_dict"]}
    elif isinstance(obj, dict) and obj and all(isinstance(v, torch.Tensor) for v in obj.values()):
        out = {"state_dict": obj}
    else:
        raise WeightsMismatchError(path, "no state dict inside (keys "
                                         f"{sorted(map(str, obj))[:8] if isinstance(obj, dict) else type(obj).__name__})",
                                   "state_dict")
    sd = out["state_dict"]
    if not isinstance(sd, dict) or not all(isinstance(k, str) and isinstance(v, torch.Tensor) for k, v in sd.items()):
        raise WeightsMismatchError(path, "state_dict must map names to tensors", "state_dict")
    want = out.get("state_sha256")
    if isinstance(want, str) and state_sha256(sd) != want:
        raise WeightsMismatchError(path, "tensor checksum does not match state_sha256: the weights are corrupt",
                                   "state_sha256")
    _check_finite(sd, path)
    return out


def _check_finite(sd: dict[str, torch.Tensor], source) -> None:
    for k, t in sd.items():
        if t.is_floating_point() and t.numel() and not bool(torch.isfinite(t).all()):
            n = int((~torch.isfinite(t)).sum())
            raise WeightsMismatchError(source, f"{n} non-finite value(s) (NaN/Inf) in tensor {k!r}", k)


# --------------------------------------------------------------------------- resume state
def save_resume_state(path: Path, *, state_dict: dict[str, torch.Tensor], optimizer: dict[str, Any], epoch: int,
                      best_mrr: float, history: list[dict[str, Any]], model_name: str,
                      config: dict[str, Any]) -> Path:
    """The trainer's ``last.pt``: tensors and plain types only (loads with ``weights_only=True``);
    history and config travel as JSON text. Written atomically."""
    payload = {"format": "xcalib-resume-v2", "state_dict": {k: v.detach().cpu() for k, v in state_dict.items()},
               "optimizer": optimizer, "epoch": int(epoch), "best_mrr": float(best_mrr),
               "history_json": json.dumps(history, default=float), "model_name": str(model_name),
               "config_json": json.dumps(config, default=str)}
    buf = io.BytesIO()
    torch.save(payload, buf)
    return atomic_write(path, [buf.getbuffer()])


def load_resume_state(path: Path) -> dict[str, Any]:
    """Read a ``last.pt`` written by :func:`save_resume_state` with ``torch.load(weights_only=True)``
    (a crafted pickle cannot run code: it is a FormatError). Returns state_dict, optimizer, epoch,
    best_mrr, history, model_name, config."""
    path = Path(path)
    obj = torch_load_safe(path, "resume checkpoint")
    if not isinstance(obj, dict):
        raise WeightsMismatchError(path, f"expected a dict, got {type(obj).__name__}")
    for key in ("state_dict", "optimizer", "epoch", "best_mrr"):
        if key not in obj:
            raise WeightsMismatchError(path, "missing key (not an xcalib resume checkpoint)", key)
    if not isinstance(obj["epoch"], int) or obj["epoch"] < 0 or isinstance(obj["epoch"], bool):
        raise WeightsMismatchError(path, f"expected a non-negative integer, got {obj['epoch']!r:.40}", "epoch")
    try:
        best = float(obj["best_mrr"])
        history = json.loads(obj["history_json"]) if "history_json" in obj else list(obj.get("history", []))
        config = json.loads(obj["config_json"]) if "config_json" in obj else obj.get("config")
    except (TypeError, ValueError, RecursionError) as exc:
        raise WeightsMismatchError(path, f"malformed resume fields ({exc})", "history_json") from None
    if not isinstance(history, list) or not isinstance(obj["optimizer"], dict):
        raise WeightsMismatchError(path, "history must be a list and optimizer a dict", "optimizer")
    sd = obj["state_dict"]
    if not isinstance(sd, dict) or not all(isinstance(v, torch.Tensor) for v in sd.values()):
        raise WeightsMismatchError(path, "state_dict must map names to tensors", "state_dict")
    _check_finite(sd, path)
    return {"state_dict": sd, "optimizer": obj["optimizer"], "epoch": obj["epoch"], "best_mrr": best,
            "history": history, "model_name": obj.get("model_name"), "config": config}


def check_state_fits(own: dict[str, torch.Tensor], state_dict: dict[str, torch.Tensor], source) -> None:
    """WeightsMismatchError unless ``state_dict`` has exactly the keys and shapes of ``own``."""
    missing = sorted(set(own) - set(state_dict))
    unexpected = sorted(set(state_dict) - set(own))
    shapes = [f"{k}: checkpoint {tuple(state_dict[k].shape)} vs model {tuple(own[k].shape)}"
              for k in own if k in state_dict and tuple(state_dict[k].shape) != tuple(own[k].shape)]
    _check_finite(state_dict, source)
    if missing or unexpected or shapes:
        parts = []
        if missing:
            parts.append(f"{len(missing)} missing key(s) {missing[:5]}")
        if unexpected:
            parts.append(f"{len(unexpected)} unexpected key(s) {unexpected[:5]}")
        if shapes:
            parts.append(f"{len(shapes)} shape mismatch(es) {shapes[:3]}")
        raise WeightsMismatchError(f"{source}: checkpoint does not fit the model config: " + "; ".join(parts))


def probe_model(model: str, config: dict[str, Any], state_dict: dict[str, torch.Tensor], config_source,
                weights_source) -> None:
    """Build ``model`` from ``config`` on the meta device (no memory) and check that the checkpoint
    fits it, before the real model is allocated: a config read from a file that does not build the
    model (bad types, huge sizes) is a FormatError naming that file."""
    from ..models import create_model

    try:
        with torch.device("meta"):
            probe = create_model(model, config)
    except Exception as exc:  # noqa: BLE001 - any constructor failure means the config file is bad
        raise FormatError(config_source, f"config does not build model {model!r} "
                                         f"({type(exc).__name__}: {str(exc)[:200]})") from None
    try:
        check_state_fits(probe.state_dict(), state_dict, weights_source)
    except WeightsMismatchError as exc:
        if Path(config_source) == Path(weights_source):
            raise
        raise WeightsMismatchError(config_source, f"the weights {Path(weights_source).name} do not fit this config: "
                                                  f"{exc.problem}", "config") from None


def load_state_strict(model: torch.nn.Module, state_dict: dict[str, torch.Tensor], source: str) -> None:
    """Load every tensor exactly; any missing, unexpected or mis-shaped key is an error."""
    own = model.state_dict()
    check_state_fits(own, state_dict, source)
    with torch.no_grad():
        for k, t in own.items():
            t.copy_(state_dict[k].to(t.dtype))
