"""``manifest.json`` of an ONNX export folder (torch-free).

Written beside the graphs by :func:`xcalib.deploy.build.build`; read by the ONNX Runtime
matcher and the TensorRT builder. Fields: ``format`` ("xcalib-onnx-v1"), ``model``, ``site``,
``family`` ("cosine" | "hybrid" | "pairwise"), ``config`` (full model config), ``weights_sha256``
(hash of the exported state dict), ``opset``, ``exporter``, ``xcalib_version``,
``torch_version``, ``host`` (top_k, fill_value, pair activation), ``graphs`` {name: GraphInfo}
and the ``parity`` figures with ``parity_ok``.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from .errors import OnnxFolderError

__all__ = ["FORMAT", "MANIFEST", "TensorInfo", "GraphInfo", "Manifest", "sha256_file", "read_manifest",
           "write_manifest", "folder_name"]

FORMAT = "xcalib-onnx-v1"
MANIFEST = "manifest.json"
FAMILIES = ("cosine", "hybrid", "pairwise")


def sha256_file(path: Path, chunk: int = 1 << 20) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while True:
            b = f.read(chunk)
            if not b:
                break
            h.update(b)
    return h.hexdigest()


def folder_name(model: str, site: str) -> str:
    """``<model>_<site>``: the folder of one model's graphs for one site's weights."""
    return f"{model}_{site}"


@dataclass
class TensorInfo:
    """A graph input or output: name, shape (ints; the dynamic axis is a str) and dtype."""

    name: str
    shape: list
    dtype: str = "float32"


@dataclass
class GraphInfo:
    """One ONNX graph: file name, sha256, inputs/outputs, dynamic axis name and envelope role."""

    file: str
    sha256: str
    inputs: list[TensorInfo]
    outputs: list[TensorInfo]
    axis: str
    role: str  # "image" | "lidar" | "stage2" | "pairwise"

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "GraphInfo":
        return cls(file=d["file"], sha256=d["sha256"], inputs=[TensorInfo(**t) for t in d["inputs"]],
                   outputs=[TensorInfo(**t) for t in d["outputs"]], axis=d["axis"], role=d["role"])


@dataclass
class Manifest:
    model: str
    site: str
    family: str
    config: dict[str, Any]
    weights_sha256: str
    opset: int
    graphs: dict[str, GraphInfo]
    host: dict[str, Any] = field(default_factory=dict)
    exporter: str = ""
    xcalib_version: str = ""
    torch_version: str = ""
    parity: dict[str, float] = field(default_factory=dict)
    parity_ok: bool = False
    format: str = FORMAT

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any], path: Path) -> "Manifest":
        if d.get("format") != FORMAT:
            raise OnnxFolderError(path, f"expected format {FORMAT!r}, got {d.get('format')!r}", "format")
        missing = [k for k in ("model", "site", "family", "config", "weights_sha256", "opset", "graphs") if k not in d]
        if missing:
            raise OnnxFolderError(path, f"missing key(s) {missing}")
        if d["family"] not in FAMILIES:
            raise OnnxFolderError(path, f"family must be one of {FAMILIES}, got {d['family']!r}", "family")
        try:
            graphs = {k: GraphInfo.from_dict(v) for k, v in d["graphs"].items()}
        except (KeyError, TypeError) as exc:
            raise OnnxFolderError(path, f"malformed graph entry ({exc})", "graphs") from None
        kw = {k: d[k] for k in ("host", "exporter", "xcalib_version", "torch_version", "parity", "parity_ok") if k in d}
        return cls(model=d["model"], site=d["site"], family=d["family"], config=d["config"],
                   weights_sha256=d["weights_sha256"], opset=int(d["opset"]), graphs=graphs, **kw)


def write_manifest(folder: Path, manifest: Manifest) -> Path:
    from ..io.files import atomic_write

    return atomic_write(Path(folder) / MANIFEST, [json.dumps(manifest.to_dict(), indent=2, default=str).encode()])


def read_manifest(folder: Path, *, verify_files: bool = True) -> Manifest:
    """Read ``<folder>/manifest.json``; with ``verify_files`` every graph file must exist and
    match its recorded sha256 (a corrupted or replaced graph is an error naming the file)."""
    folder = Path(folder)
    path = folder / MANIFEST
    if not path.is_file():
        raise OnnxFolderError(path, "no manifest.json: not an ONNX folder written by Matcher.build('onnx') / "
                                    "`xcalib export --format onnx`")
    from ..errors import FormatError
    from ..io.files import load_json

    try:
        d = load_json(path, what="manifest")
    except (OSError, FormatError) as exc:
        raise OnnxFolderError(path, f"not readable JSON ({exc})") from None
    if not isinstance(d, dict):
        raise OnnxFolderError(path, f"expected a JSON object, got {type(d).__name__}")
    m = Manifest.from_dict(d, path)
    if verify_files:
        for name, g in m.graphs.items():
            gp = folder / g.file
            if not gp.is_file():
                raise OnnxFolderError(gp, f"graph {name!r} listed in {path.name} is missing")
            digest = sha256_file(gp)
            if digest != g.sha256:
                raise OnnxFolderError(gp, f"graph {name!r} is corrupted or was replaced: sha256 {digest[:12]}... "
                                          f"!= {g.sha256[:12]}... recorded in {path.name}")
    return m
