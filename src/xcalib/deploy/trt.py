"""TensorRT engines through ``trtexec`` (torch-free).

``find_trtexec`` looks, in order, at an explicit path, ``$PATH``, ``/usr/src/tensorrt/bin``,
``/opt/nvidia/tensorrt/bin`` and ``/usr/local/tensorrt/bin``. ``trtexec_command`` builds one
graph's command line with the envelope profiles (protocol v1.0 §5) as
``--minShapes/--optShapes/--maxShapes`` over every input of the graph (the batch axis takes
min/opt/max, the other axes their exported sizes), the precision flag and the extra arguments.
Engines: ``<engine_dir>/<graph>.<precision>.engine``, logs beside them; ``engines.json``
records the ONNX hashes and the command of each engine.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from pathlib import Path
from typing import Sequence

from .chunking import PROTOCOL_ENVELOPE, Envelope
from .errors import TrtBuildError, TrtexecNotFoundError
from .manifest import GraphInfo, Manifest
from .result import BuildResult

__all__ = ["SEARCH_DIRS", "PRECISIONS", "find_trtexec", "check_precision", "shapes_arg", "trtexec_command",
           "build_engines"]

SEARCH_DIRS = ("/usr/src/tensorrt/bin", "/opt/nvidia/tensorrt/bin", "/usr/local/tensorrt/bin")
PRECISIONS = {"fp32": [], "fp16": ["--fp16"], "int8": ["--int8"], "best": ["--best"]}


def find_trtexec(explicit: str | Path | None = None) -> Path:
    """Path of ``trtexec``; :class:`TrtexecNotFoundError` lists every place looked at."""
    looked: list[str] = []
    if explicit is not None:
        p = Path(explicit)
        if p.is_dir():
            p = p / "trtexec"
        if p.is_file() and os.access(p, os.X_OK):
            return p
        raise TrtexecNotFoundError(f"trtexec not found at the given path {p} (missing or not executable)")
    w = shutil.which("trtexec")
    if w:
        return Path(w)
    looked.append(f"$PATH ({os.environ.get('PATH', '')})")
    for d in SEARCH_DIRS:
        p = Path(d) / "trtexec"
        if p.is_file() and os.access(p, os.X_OK):
            return p
        looked.append(str(p))
    raise TrtexecNotFoundError("trtexec (TensorRT) not found; looked in " + "; ".join(looked) +
                               ". Install TensorRT (JetPack on Jetson/Thor) or give its path: trtexec=/path/to/trtexec "
                               "(command line: --trtexec /path/to/trtexec)")


def check_precision(precision: str) -> str:
    p = str(precision).lower()
    if p not in PRECISIONS:
        raise ValueError(f"precision must be one of {sorted(PRECISIONS)}, got {precision!r}")
    return p


def shapes_arg(graph: GraphInfo, rows: int) -> str:
    """``name:AxBxC,...`` for every input with the batch axis set to ``rows``."""
    parts = []
    for t in graph.inputs:
        dims = [str(rows) if isinstance(d, str) else str(int(d)) for d in t.shape]
        parts.append(f"{t.name}:{'x'.join(dims)}")
    return ",".join(parts)


def trtexec_command(trtexec: str | Path, onnx_path: Path, engine_path: Path, graph: GraphInfo, *,
                    precision: str = "fp16", envelope: Envelope | None = None,
                    extra_args: Sequence[str] = ()) -> list[str]:
    """The ``trtexec`` argument list of one graph."""
    prof = (envelope or PROTOCOL_ENVELOPE).profile(graph.role)
    return [str(trtexec), f"--onnx={onnx_path}", f"--saveEngine={engine_path}",
            f"--minShapes={shapes_arg(graph, prof.min)}", f"--optShapes={shapes_arg(graph, prof.opt)}",
            f"--maxShapes={shapes_arg(graph, prof.max)}", *PRECISIONS[check_precision(precision)],
            *[str(a) for a in extra_args]]


def build_engines(onnx_folder: Path, engine_dir: Path, manifest: Manifest, trtexec: Path, *, precision: str = "fp16",
                  extra_args: Sequence[str] = (), envelope: Envelope | None = None, timeout_s: float | None = None):
    """Run trtexec for every graph of ``manifest``; returns a ``BuildResult`` (target "trt")."""
    onnx_folder, engine_dir = Path(onnx_folder), Path(engine_dir)
    engine_dir.mkdir(parents=True, exist_ok=True)
    res = BuildResult("trt", manifest.model, engine_dir, site=manifest.site, precision=precision)
    record = {"precision": precision, "trtexec": str(trtexec), "onnx_folder": str(onnx_folder),
              "weights_sha256": manifest.weights_sha256, "engines": {}}
    if precision == "int8":
        res.notes.append("int8 without a calibration cache: trtexec uses placeholder scales, so the engine's "
                         "accuracy is not representative (pass --calib=<cache> through extra_trt_args)")
    for name, g in manifest.graphs.items():
        engine = engine_dir / f"{name}.{precision}.engine"
        logf = engine_dir / f"{name}.{precision}.log"
        cmd = trtexec_command(trtexec, onnx_folder / g.file, engine, g, precision=precision, envelope=envelope,
                              extra_args=extra_args)
        with open(logf, "w") as fh:
            fh.write("$ " + " ".join(cmd) + "\n")
            fh.flush()
            try:
                rc = subprocess.run(cmd, stdout=fh, stderr=subprocess.STDOUT, timeout=timeout_s).returncode
            except subprocess.TimeoutExpired:
                raise TrtBuildError(f"trtexec timed out after {timeout_s} s building {engine} (log: {logf})") from None
        res.logs.append(logf)
        if rc != 0:
            raise TrtBuildError(f"trtexec exited with code {rc} building {engine} from {onnx_folder / g.file} "
                                f"(log: {logf})")
        if not engine.is_file():
            raise TrtBuildError(f"trtexec wrote no engine {engine} (log: {logf})")
        res.artifacts.append(engine)
        record["engines"][name] = {"engine": engine.name, "onnx": g.file, "onnx_sha256": g.sha256, "command": cmd}
    (engine_dir / "engines.json").write_text(json.dumps(record, indent=2))
    res.artifacts.append(engine_dir / "engines.json")
    return res
