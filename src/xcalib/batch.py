"""Many recordings calibrated through an executor: ``calibrate_many`` (CLI: ``xcalib calibrate-many``).

Each recording (any frame source ``xcalib.io.sources`` opens: a frame folder, an HDF5 cache, a
KITTI folder, a bag, ...) is calibrated on its own with ``xcalib.calibrate`` and the default
settings (or a given :class:`~xcalib.calib.config.CalibConfig`). The work runs on an executor:

* ``"process"`` (default): a local process pool of ``jobs`` workers (default: the CPUs);
* ``"ray"``: a Ray cluster (``pip install xcalib[ray]``): the one started by ``ray.init()`` here
  (local) or the one at ``ray_address``, the same job spread over its nodes;
* ``"serial"``: one after the other in this process.

Every recording's result lands in ``OUT/<name>/calibration.json``; a recording that cannot be
opened or raises is a row with its ``error``, never a crash of the batch. One table of all of
them is written as ``OUT/results.csv`` and ``OUT/results.json`` with an HTML index
``OUT/index.html``. The rows do not depend on the executor or the worker count (one
calibration per process, ``workers=1``, seeded), only the timings do.

Recordings are given as paths, glob patterns (``runs/*/frames``), folders whose sub-folders are
recordings, or a list file (``.txt`` / ``.lst`` / ``.list``: one path per line, ``#`` comments,
relative to the list file's folder and inside it).
"""

from __future__ import annotations

import csv
import glob
import html
import io
import json
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from .calib.config import CalibConfig
from .detect.pipeline import DetectConfig
from .errors import FormatError, MissingFileError
from .io.files import atomic_write, inside, read_text, safe_name
from .options import Options, document, resolve

__all__ = ["BatchRecord", "BatchSummary", "BatchOptions", "calibrate_many", "expand_recordings", "write_tables", "Executor",
           "LIST_SUFFIXES"]

Executor = Literal["process", "ray", "serial"]
LIST_SUFFIXES = (".txt", ".lst", ".list")
_GLOB_CHARS = set("*?[")


@dataclass
class BatchRecord:
    """One recording's row: where it came from, the verdict and pose (LiDAR -> camera, ``T`` [4,4]
    row-major, None when refused or failed), the reported 1-sigma norms, the time it took and any
    error (the recording could not be opened or the calibration raised)."""

    name: str
    source: str
    success: bool = False
    refusal: str = ""
    message: str = ""
    error: str = ""
    frames: int = 0
    n_pairs: int = 0
    rot_sigma_deg: float | None = None
    trans_sigma_m: float | None = None
    T: list | None = None
    result: str = ""  # the result file, relative to the batch folder
    time_s: float = 0.0

    def row(self) -> dict:
        """A flat row for the CSV (the pose as translation and rotation vector)."""
        d = {k: v for k, v in asdict(self).items() if k != "T"}
        if self.T is not None:
            from .geometry.rotations import matrix_to_rotvec

            T = np.asarray(self.T, dtype=np.float64)
            rv = np.degrees(matrix_to_rotvec(T[:3, :3]))
            d.update(tx_m=T[0, 3], ty_m=T[1, 3], tz_m=T[2, 3], rx_deg=rv[0], ry_deg=rv[1], rz_deg=rv[2])
        return d


@dataclass
class BatchSummary:
    """The rows (in the order of the recordings) and the files written."""

    records: list[BatchRecord]
    out_dir: Path
    csv: Path
    json: Path
    html: Path
    executor: str = "process"
    wall_s: float = 0.0
    meta: dict = field(default_factory=dict)

    @property
    def n_success(self) -> int:
        return sum(r.success for r in self.records)

    @property
    def n_error(self) -> int:
        return sum(bool(r.error) for r in self.records)


# ------------------------------------------------------------------------------ recordings

def _read_list(path: Path) -> list[Path]:
    out = []
    for k, line in enumerate(read_text(path, what="recording list").splitlines(), 1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        try:
            out.append(inside(path.parent, s, source=path, field=f"line {k}"))
        except MissingFileError:
            raise
        except FormatError as exc:  # (inside's own hint names a Python argument the command line lacks)
            raise FormatError(path, f"{s!r} points outside the list's folder (absolute or '..'): a list names "
                              "recordings inside its own folder; give the others as arguments or glob patterns, or "
                              "write the list next to them", exc.field) from exc
    if not out:
        raise FormatError(path, "the list names no recording (one path per line)")
    return out


def _is_recording(p: Path) -> bool:
    from .io.sources import find_source

    try:
        find_source(p)
        return True
    except (ValueError, FileNotFoundError, OSError):
        return False


def expand_recordings(specs: str | os.PathLike | Sequence[str | os.PathLike]) -> list[Path]:
    """Recording paths from paths, glob patterns, folders of recordings and list files (see the
    module docstring), in the order given (a glob's and a folder's matches sorted), duplicates
    dropped. Raises FileNotFoundError for a path or pattern that names nothing."""
    specs = [specs] if isinstance(specs, (str, os.PathLike)) else list(specs)
    out: list[Path] = []
    for spec in specs:
        s = os.fspath(spec)
        p = Path(s)
        if p.is_file() and p.suffix.lower() in LIST_SUFFIXES:
            found = _read_list(p)
        elif _GLOB_CHARS & set(s) and not p.exists():
            found = [Path(m) for m in sorted(glob.glob(s, recursive=True))]
            if not found:
                raise FileNotFoundError(f"no recording matches {s!r}")
        elif p.is_dir() and not _is_recording(p):
            found = [c for c in sorted(p.iterdir()) if not c.name.startswith(".") and _is_recording(c)]
            if not found:
                raise FileNotFoundError(f"{p} is no recording and holds none")
        elif p.exists():
            found = [p]
        else:
            raise FileNotFoundError(f"recording not found: {p}")
        out += found
    seen, uniq = set(), []
    for p in out:
        key = os.path.realpath(p)
        if key not in seen:
            seen.add(key)
            uniq.append(p)
    return uniq


def _names(paths: list[Path]) -> list[str]:
    """A unique, file-safe name per recording: its path relative to the recordings' common folder."""
    absd = [os.path.abspath(p) for p in paths]
    root = os.path.commonpath(absd) if len(absd) > 1 else os.path.dirname(absd[0])
    names, used = [], set()
    for a in absd:
        rel = os.path.relpath(a, root)
        base = safe_name(Path(rel).with_suffix("").as_posix().replace("/", "__"), default="recording")
        name, k = base, 2
        while name in used:
            name, k = f"{base}-{k}", k + 1
        used.add(name)
        names.append(name)
    return names


# ------------------------------------------------------------------------------ one task

@dataclass(frozen=True)
class _Task:
    name: str
    source: str
    out_dir: str
    config: dict
    camera: str | None = None
    intrinsics: str | None = None
    detect: DetectConfig | None = None


def _open(task: _Task):
    """The recording's frames: as the source holds them, or with xcalib's own detections
    (``task.detect``: a bag read without its detection topics, every frame detected now)."""
    from .io.sources import open_source

    if task.detect is None:
        return open_source(task.source, camera=task.camera) if task.camera else open_source(task.source)
    from .detect import DetectedFrames, open_sensors

    return DetectedFrames(open_sensors(task.source, task.camera), task.detect).run()


def _run_one(task: _Task) -> BatchRecord:
    """Calibrate one recording and save its result; every failure becomes the row's ``error``."""
    import warnings

    t0 = time.perf_counter()
    rec = BatchRecord(name=task.name, source=task.source)
    try:
        from .calib.api import calibrate
        from .formats.cameras import read_intrinsics

        seq = _open(task)
        frames = [seq[i] for i in range(len(seq))]
        intr = read_intrinsics(task.intrinsics) if task.intrinsics else getattr(seq, "intrinsics", None)
        rec.frames = len(frames)
        if not frames:
            raise ValueError("no frames")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # fallbacks are in the result's diagnostics
            res = calibrate(frames, intr, CalibConfig.from_dict(task.config).replace(workers=1))
        if task.detect is not None:  # a refusal names weak detections where they are the cause
            from .detect import explain_refusal

            res = explain_refusal(res, frames, intr)
        rec.success, rec.message, rec.n_pairs = bool(res.success), res.message, int(res.n_pairs)
        rec.refusal = res.diagnostics.refusal if res.diagnostics is not None else ""
        if res.rotation_std_deg is not None and np.all(np.isfinite(res.rotation_std_deg)):
            rec.rot_sigma_deg = float(np.linalg.norm(res.rotation_std_deg))
            rec.trans_sigma_m = float(np.linalg.norm(res.translation_std_m))
        if res.success:
            rec.T = np.asarray(res.extrinsics, dtype=np.float64).tolist()
        path = Path(task.out_dir) / task.name / "calibration.json"
        res.save(path)
        rec.result = f"{task.name}/calibration.json"
    except Exception as exc:  # noqa: BLE001 - one bad recording must not stop the batch
        rec.success, rec.error = False, f"{type(exc).__name__}: {exc}"
    rec.time_s = time.perf_counter() - t0
    return rec


# ------------------------------------------------------------------------------ executors

def _run_serial(tasks, on_done):
    out = []
    for t in tasks:
        out.append(_run_one(t))
        on_done(out[-1])
    return out


def _run_process(tasks, on_done, jobs: int):
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor, as_completed

    ctx = mp.get_context("fork" if "fork" in mp.get_all_start_methods() else "spawn")
    out: list = [None] * len(tasks)
    with ProcessPoolExecutor(max(1, min(jobs, len(tasks))), mp_context=ctx) as ex:
        futs = {ex.submit(_run_one, t): k for k, t in enumerate(tasks)}
        for f in as_completed(futs):
            out[futs[f]] = f.result()
            on_done(out[futs[f]])
    return out


def _run_ray(tasks, on_done, address: str | None, jobs: int | None):
    try:
        import ray
    except ImportError:
        raise RuntimeError("the Ray executor needs Ray: pip install 'xcalib[ray]'") from None
    started = False
    if not ray.is_initialized():
        kw = {"address": address} if address else ({"num_cpus": jobs} if jobs else {})
        ray.init(include_dashboard=False, log_to_driver=False, **kw)
        started = True
    try:
        remote = ray.remote(num_cpus=1)(_run_one)
        refs = [remote.remote(t) for t in tasks]
        index = {r: k for k, r in enumerate(refs)}
        out: list = [None] * len(tasks)
        pending = list(refs)
        while pending:
            done, pending = ray.wait(pending, num_returns=1)
            for r in done:
                out[index[r]] = ray.get(r)
                on_done(out[index[r]])
        return out
    finally:
        if started:
            ray.shutdown()


# ------------------------------------------------------------------------------ tables

_COLUMNS = ["name", "source", "success", "refusal", "error", "frames", "n_pairs", "rot_sigma_deg", "trans_sigma_m",
            "tx_m", "ty_m", "tz_m", "rx_deg", "ry_deg", "rz_deg", "time_s", "result", "message"]


def write_tables(out_dir: Path, records: list[BatchRecord], meta: dict) -> tuple[Path, Path, Path]:
    """``results.csv``, ``results.json`` and ``index.html`` of the rows under ``out_dir`` (atomic)."""
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=_COLUMNS, extrasaction="ignore")
    w.writeheader()
    for r in records:
        w.writerow({k: ("" if v is None else v) for k, v in r.row().items()})
    p_csv = atomic_write(out_dir / "results.csv", [buf.getvalue().encode()])
    doc = {"format": "xcalib-batch-v1", **meta, "recordings": [asdict(r) for r in records]}
    p_json = atomic_write(out_dir / "results.json", [json.dumps(doc, indent=1, default=float).encode()])
    p_html = atomic_write(out_dir / "index.html", [_html(records, meta).encode()])
    return p_csv, p_json, p_html


def _fmt(v, nd: int = 3) -> str:
    return "" if v is None else f"{v:.{nd}f}" if isinstance(v, float) else str(v)


def _html(records: list[BatchRecord], meta: dict) -> str:
    e = html.escape
    n_ok = sum(r.success for r in records)
    n_err = sum(bool(r.error) for r in records)
    rows = []
    for r in records:
        d = r.row()
        verdict = "success" if r.success else ("error" if r.error else f"refused: {r.refusal}")
        cls = "ok" if r.success else ("err" if r.error else "no")
        link = f'<a href="{e(r.result)}">result</a>' if r.result else ""
        pose = (f"t = ({_fmt(d['tx_m'])}, {_fmt(d['ty_m'])}, {_fmt(d['tz_m'])}) m, r = ({_fmt(d['rx_deg'], 2)}, "
                f"{_fmt(d['ry_deg'], 2)}, {_fmt(d['rz_deg'], 2)}) deg" if r.T is not None else "")
        rows.append(f'<tr class="{cls}"><td>{e(r.name)}</td><td>{e(verdict)}</td><td>{r.frames}</td><td>{r.n_pairs}</td>'
                    f"<td>{_fmt(r.rot_sigma_deg)}</td><td>{_fmt(r.trans_sigma_m)}</td><td>{e(pose)}</td>"
                    f"<td>{r.time_s:.1f}</td><td>{link}</td><td>{e(r.error or r.message)}</td>"
                    f"<td>{e(r.source)}</td></tr>")
    return ("<!doctype html><html><head><meta charset='utf-8'><title>xcalib calibrate-many</title><style>"
            "body{font-family:sans-serif;margin:1.5em}table{border-collapse:collapse}td,th{border:1px solid #ccc;"
            "padding:3px 6px;font-size:13px;text-align:left}tr.ok td:nth-child(2){color:#070}"
            "tr.no td:nth-child(2){color:#a60}tr.err td:nth-child(2){color:#c00}</style></head><body>"
            f"<h1>xcalib calibrate-many</h1><p>{len(records)} recording(s): {n_ok} calibrated, "
            f"{len(records) - n_ok - n_err} refused, {n_err} error(s); executor {e(str(meta.get('executor', '')))}, "
            f"{meta.get('wall_s', 0.0):.1f} s. Tables: <a href='results.csv'>results.csv</a>, "
            "<a href='results.json'>results.json</a>.</p><table><tr><th>recording</th><th>verdict</th><th>frames</th>"
            "<th>pairs</th><th>rot 1-sigma, norm (deg)</th><th>trans 1-sigma, norm (m)</th><th>T_cam_lidar</th><th>time (s)</th>"
            "<th>file</th><th>message</th><th>source</th></tr>" + "".join(rows) + "</table></body></html>\n")


# ------------------------------------------------------------------------------ the batch

@dataclass(frozen=True)
class BatchOptions(Options):
    """How :func:`calibrate_many` runs (the defaults in one place; it documents each): executor
    ("process" | "ray" | "serial"), jobs, camera, intrinsics, ray_address, progress, detect (a
    :class:`~xcalib.detect.DetectConfig`: every recording's detections made by xcalib's detectors,
    as ``xcalib calibrate --detect``; None: the recordings' own)."""

    executor: Executor = "process"
    jobs: int | None = None
    camera: str | None = None
    intrinsics: str | os.PathLike | None = None
    ray_address: str | None = None
    progress: Callable[[int, int, BatchRecord], None] | None = None
    detect: DetectConfig | None = None


@document(BatchOptions)
def calibrate_many(recordings, out_dir, *, config: CalibConfig | None = None, options: BatchOptions | None = None,
                   **overrides: Any) -> BatchSummary:
    """Calibrate every recording (paths / globs / folders / list files, see ``expand_recordings``)
    on ``executor`` and write the per-recording results and the tables under ``out_dir``.

    ``jobs``: worker processes of the local pool or CPUs of a local Ray instance (default: the
    CPUs). ``camera`` / ``intrinsics``: the camera to calibrate and an intrinsics JSON for every
    recording (default: each source's own). ``progress(done, total, record)`` after each one.
    ``detect``: make every recording's detections with xcalib's detectors (a ``DetectConfig``; the
    detector is loaded once here first, so a missing ``onnx`` extra or a bad model file is said
    before any recording runs).
    These settings: a :class:`BatchOptions` (``options=``) and/or its fields as keyword arguments.
    """
    o = resolve(BatchOptions, options, overrides, where="calibrate_many")
    executor, jobs, camera, intrinsics, ray_address, progress = o.executor, o.jobs, o.camera, o.intrinsics, \
        o.ray_address, o.progress
    from .calib.parallel import available_cpus

    if executor not in ("process", "ray", "serial"):
        raise ValueError(f"executor: expected 'process', 'ray' or 'serial', got {executor!r}")
    if intrinsics is not None:  # a bad camera file (or FILE#cam of a camchain) named once, before any recording runs
        from .formats.cameras import read_intrinsics

        read_intrinsics(intrinsics)
    if o.detect is not None:
        from .detect import load_detector

        load_detector(o.detect.detector_2d, o.detect.camera, o.detect.classes_2d)
    paths = expand_recordings(recordings)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    cfg = (config or CalibConfig()).replace(workers=1)
    tasks = [_Task(name, str(p), str(out), cfg.to_dict(), camera, None if intrinsics is None else str(intrinsics),
                   o.detect) for name, p in zip(_names(paths), paths)]
    n_done = [0]

    def on_done(rec: BatchRecord) -> None:
        n_done[0] += 1
        if progress:
            progress(n_done[0], len(tasks), rec)

    t0 = time.perf_counter()
    jobs_n = jobs or available_cpus()
    if executor == "serial" or (executor == "process" and jobs_n == 1):
        records = _run_serial(tasks, on_done)
    elif executor == "process":
        records = _run_process(tasks, on_done, jobs_n)
    else:
        records = _run_ray(tasks, on_done, ray_address, jobs)
    meta = {"executor": executor, "jobs": jobs_n if executor != "ray" else jobs, "wall_s": time.perf_counter() - t0,
            "config": cfg.to_dict(), "detect": None if o.detect is None else _detect_meta(o.detect)}
    p_csv, p_json, p_html = write_tables(out, records, meta)
    return BatchSummary(records, out, p_csv, p_json, p_html, executor, meta["wall_s"], meta)


def _detect_meta(config: DetectConfig) -> dict:
    """How the detections were made (results.json): the detector file and the settings."""
    d = asdict(config)
    return {k: (list(v) if isinstance(v, tuple) else v) for k, v in d.items()}
