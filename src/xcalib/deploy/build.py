"""``Matcher.build``: ONNX export with parity checks, TensorRT engines via ``trtexec``.

``build(matcher, "onnx", output_dir)`` writes the graphs + ``manifest.json`` into ``output_dir``
itself (default ``./onnx/<model>/``, as the reference); with ``site_folder=True`` (what ``xcalib
export`` uses) into ``<output_dir>/<model>_<site>/``, a folder name that keeps the weights of two
sites apart. It checks every graph
output and the end-to-end similarity against torch on two frames: random crops with distinct
box centres, and real-shaped crops of a synthetic roadside frame. Pass: max |torch - onnx| <=
``parity_tolerance`` (1e-4). ``BuildResult.parity_ok`` is False when parity was not checked.

``build(matcher, "trt", output_dir, precision=...)`` (re)uses the ONNX folder only when its
manifest names the same model, site and weights hash, then drives ``trtexec`` (see
:mod:`xcalib.deploy.trt`).
"""

from __future__ import annotations

import hashlib
import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import torch

from .. import __version__
from ..data.crops import CropConfig, FrameInputs
from .errors import OnnxFolderError, RandomWeightsError, StaleOnnxError
from .manifest import MANIFEST, Manifest, folder_name, read_manifest, write_manifest
from .onnx_export import EXPORTER, OPSET, cpu_copy, export_plan, make_plan, run_torch
from .onnx_feeds import frame_feeds, pair_feeds
from .result import PARITY_TOLERANCE, BuildResult
from ..options import Options, document, resolve

__all__ = ["BuildResult", "BuildOptions", "build", "state_hash", "random_inputs", "synthetic_inputs", "resolve_site",
           "PARITY_TOLERANCE"]

log = logging.getLogger("xcalib.deploy")
TRT_TARGETS = ("trt", "tensorrt", "engine")


# ---------------------------------------------------------------------------------- inputs
def state_hash(model: torch.nn.Module) -> str:
    """sha256 of the model's state dict (names, dtypes, shapes, bytes), device independent."""
    h = hashlib.sha256()
    for k, v in sorted(model.state_dict().items()):
        t = v.detach().cpu().contiguous()
        h.update(f"{k}|{t.dtype}|{tuple(t.shape)}".encode())
        h.update(t.numpy().tobytes() if t.dtype != torch.bfloat16 else t.float().numpy().tobytes())
    return h.hexdigest()


def random_inputs(cfg: CropConfig, n: int = 5, m: int = 7, seed: int = 0,
                  image_size: tuple[int, int] = (1920, 1080)) -> FrameInputs:
    """Random crops with distinct, plausible box centres: 2D boxes px in a W x H image, box7
    (LiDAR frame, m) 5..60 m ahead with random yaw, point counts 5..2000."""
    rng = np.random.default_rng(seed)
    W, H = image_size
    S, P = int(cfg.crop_size), int(cfg.point_cloud_size)
    wh2 = rng.uniform(20, 200, (n, 2))
    xy = np.stack([rng.uniform(0, W - 200, n), rng.uniform(0, H - 200, n)], 1)
    boxes_2d = np.hstack([xy, xy + wh2]).astype(np.float32)
    ctr = np.stack([rng.uniform(5, 60, m), rng.uniform(-20, 20, m), rng.uniform(-1.5, 0.5, m)], 1)
    dims = np.stack([rng.uniform(1.5, 5, m), rng.uniform(1.5, 2.5, m), rng.uniform(1.4, 2.0, m)], 1)
    box7 = np.hstack([ctr, dims, rng.uniform(-np.pi, np.pi, (m, 1))]).astype(np.float32)
    crops_3d = (rng.uniform(-0.5, 0.5, (m, P, 3)) * dims[:, None, :]).astype(np.float32)
    return FrameInputs(rng.standard_normal((n, 3, S, S)).astype(np.float32), crops_3d, boxes_2d, box7,
                       rng.integers(5, 2000, m).astype(np.int64), (W, H), np.arange(n), np.arange(m))


def synthetic_inputs(cfg: CropConfig, seed: int = 0, min_dets: int = 2) -> FrameInputs:
    """Real-shaped inputs: the crops of a synthetic roadside frame (rendered image, ray-cast
    LiDAR) with at least ``min_dets`` kept detections per side."""
    from ..data.crops import prepare_frame
    from ..data.synth import iter_frames, sample_site

    site = sample_site(seed)
    for frame in iter_frames(site, 20, seed=seed):
        inp = prepare_frame(frame.image, frame.point_cloud, frame.bboxes_2d, frame.bboxes_3d, cfg)
        if inp.num_2d >= min_dets and inp.num_3d >= min_dets:
            return inp
    raise RuntimeError(f"synthetic site {seed}: no frame with >= {min_dets} detections per side in 20 frames")


def resolve_site(matcher, site: str | None, weights_sha: str, allow_random: bool) -> str:
    if site:
        return str(site)
    if getattr(matcher, "site", None):
        return str(matcher.site)
    return "random" if allow_random and matcher.weights_path is None else f"local-{weights_sha[:8]}"


# ---------------------------------------------------------------------------------- parity
def _max_abs(a: np.ndarray, b: np.ndarray) -> float:
    if a.shape != b.shape:
        return float("inf")
    return float(np.max(np.abs(a.astype(np.float64) - b.astype(np.float64)))) if a.size else 0.0


def check_parity(plan, folder: Path, matcher, cases: dict[str, FrameInputs]) -> dict[str, float]:
    """Per-graph outputs and end-to-end similarity, ONNX Runtime (CPU) vs torch."""
    from .ort_runtime import OnnxMatcher

    om = OnnxMatcher(folder)
    out: dict[str, float] = {}
    graphs = {g.name: g for g in plan.graphs}
    for case, inp in cases.items():
        img, lid = frame_feeds(inp)
        t_side = {"image": run_torch(graphs["image_embed"], img), "lidar": run_torch(graphs["lidar_embed"], lid)}
        o_side = {"image": om.run_graph("image_embed", img), "lidar": om.run_graph("lidar_embed", lid)}
        for role, gname in (("image", "image_embed"), ("lidar", "lidar_embed")):
            for k, v in t_side[role].items():
                out[f"{gname}/{k}[{case}]"] = _max_abs(v, o_side[role][k])
        if "pair_score" in graphs:
            n, m = inp.num_2d, inp.num_3d
            feeds = pair_feeds(t_side["image"], t_side["lidar"], np.repeat(np.arange(n), m), np.tile(np.arange(m), n))
            out[f"pair_score/logit[{case}]"] = _max_abs(run_torch(graphs["pair_score"], feeds)["logit"],
                                                        om.run_graph("pair_score", feeds)["logit"])
        out[f"similarity[{case}]"] = _max_abs(matcher.similarity(inp), om.similarity(inp))
    return out


# ---------------------------------------------------------------------------------- build
def export_onnx(matcher, folder: Path, *, site: str, weights_sha: str, opset: int = OPSET, verify: bool = True,
                parity_tolerance: float = PARITY_TOLERANCE, parity_seed: int = 0) -> BuildResult:
    """Export ``matcher`` into ``folder`` and check parity. The graphs and manifest are written
    into a temporary folder beside it and swapped in whole (``atomic_dir``): a killed export
    leaves the previous folder intact, never a mix of old graphs and a new manifest."""
    from ..io.files import atomic_dir

    folder = Path(folder)
    if folder.is_dir() and any(folder.iterdir()) and not (folder / MANIFEST).is_file():
        raise OnnxFolderError(folder, "exists, is not empty and holds no manifest.json: refusing to overwrite it")
    res = BuildResult("onnx", matcher.model_name, folder, site=site, tolerance=parity_tolerance)
    with atomic_dir(folder, overwrite=True) as tmp:  # replaces an earlier export of the same model + site
        model = cpu_copy(matcher.model)
        cfg = matcher.crop_config
        trace = random_inputs(cfg, 3, 4, seed=parity_seed + 101)
        plan = make_plan(model, trace)
        graphs = export_plan(plan, trace, tmp, opset)
        man = Manifest(model=matcher.model_name, site=site, family=plan.family, config=dict(matcher.config),
                       weights_sha256=weights_sha, opset=opset, graphs=graphs, host=plan.host, exporter=EXPORTER,
                       xcalib_version=__version__, torch_version=torch.__version__)
        write_manifest(tmp, man)
        if verify:
            try:
                import onnxruntime  # noqa: F401
            except ImportError:
                res.notes.append("onnxruntime is not installed: parity NOT checked (parity_ok is False)")
            else:
                cases = {"random": random_inputs(cfg, 5, 7, seed=parity_seed),
                         "synthetic": synthetic_inputs(cfg, seed=parity_seed)}
                res.parity = check_parity(plan, tmp, matcher, cases)
                res.parity_checked = True
        else:
            res.notes.append("verify=False: parity NOT checked (parity_ok is False)")
        man.parity, man.parity_ok = res.parity, res.parity_ok
        write_manifest(tmp, man)
        if getattr(matcher, "calibration", None) is not None:  # OnnxMatcher fuses it into match, as Matcher
            matcher.calibration.save(tmp / "calibration.json")
    res.artifacts = [folder / g.file for g in graphs.values()] + [folder / MANIFEST]
    level = logging.INFO if res.parity_ok else logging.WARNING
    log.log(level, "%s: ONNX export to %s, parity %s (max |diff| %.3g, tolerance %.0e)", matcher.model_name, folder,
            "OK" if res.parity_ok else "NOT OK", res.max_parity_error, parity_tolerance)
    return res


def _check_folder(man_folder: Path, model: str, site: str, weights_sha: str) -> Manifest:
    man = read_manifest(man_folder)
    path = man_folder / MANIFEST
    if man.model != model:
        raise OnnxFolderError(path, f"holds model {man.model!r}, not {model!r}", "model")
    if man.site != site:
        raise OnnxFolderError(path, f"holds weights of site {man.site!r}, not {site!r}", "site")
    if man.weights_sha256 != weights_sha:
        raise StaleOnnxError(path, f"graphs were exported from other weights (sha256 {man.weights_sha256[:12]}... != "
                                   f"the matcher's {weights_sha[:12]}...); re-export them", "weights_sha256")
    return man


def _refuse_existing(folder: Path) -> None:
    if folder.exists() and (not folder.is_dir() or any(folder.iterdir())):
        raise FileExistsError(f"{folder} already exists; pass --force to replace it")


@dataclass(frozen=True)
class BuildOptions(Options):
    """The settings of :func:`build` (the defaults in one place; ``build`` documents each): site,
    allow_random, verify, opset, parity_tolerance, precision, onnx_dir, trtexec, extra_trt_args,
    envelope, timeout_s, device, site_folder, overwrite."""

    site: str | None = None
    allow_random: bool = False
    verify: bool = True
    opset: int = OPSET
    parity_tolerance: float = PARITY_TOLERANCE
    precision: str = "fp16"
    onnx_dir: str | Path | None = None
    trtexec: str | Path | None = None
    extra_trt_args: Sequence[str] = ()
    envelope: Any = None
    timeout_s: float | None = None
    device: Any = None  # accepted for the reference (graphs are traced on a CPU copy)
    site_folder: bool = False
    overwrite: bool = True


@document(BuildOptions)
def build(matcher, target: str = "onnx", output_dir: str | Path | None = None, *, options: BuildOptions | None = None,
          **overrides: Any) -> BuildResult:
    """Export ``matcher`` (see module docstring). ``target``: "onnx" or "trt" ("tensorrt",
    "engine"). The files go to ``output_dir`` (default ``./onnx/<model>/`` for ONNX,
    ``./engines/<model>/`` for TRT, as the reference), or with ``site_folder`` to
    ``<output_dir>/<model>_<site>/`` (roots ``./onnx`` / ``./engines``). ``device``: accepted
    for the reference; the graphs are always traced from a CPU copy (the matcher is untouched).
    ``site`` defaults to the matcher's site, else
    ``local-<weights hash>``. A matcher whose weights were never loaded is refused unless
    ``allow_random``. TRT: ``onnx_dir`` = an existing export folder to build from (it must match
    model, site and weights); otherwise the graphs are exported (or reused when current) into
    the engine folder. ``precision`` "fp32" | "fp16" | "int8" | "best". ``overwrite=False``
    refuses a target folder that exists and is not empty (FileExistsError). The settings: a
    :class:`BuildOptions` (``options=``) and/or its fields as keyword arguments."""
    o = resolve(BuildOptions, options, overrides, where="build")
    site, allow_random, verify, opset, parity_tolerance, precision = o.site, o.allow_random, o.verify, o.opset, \
        o.parity_tolerance, o.precision
    onnx_dir, trtexec, extra_trt_args, envelope, timeout_s = o.onnx_dir, o.trtexec, o.extra_trt_args, o.envelope, \
        o.timeout_s
    site_folder, overwrite = o.site_folder, o.overwrite
    t = str(target).lower()
    if t != "onnx" and t not in TRT_TARGETS:
        raise ValueError(f"target must be 'onnx' or one of {TRT_TARGETS}, got {target!r}")
    if matcher.weights_path is None and not allow_random:
        raise RandomWeightsError(
            f"{matcher.model_name}: the matcher's weights were never loaded (random initialisation); load them with "
            f"Matcher.from_pretrained({matcher.model_name!r}, ...) or pass allow_random=True (testing only)")
    weights_sha = state_hash(matcher.model)
    site = resolve_site(matcher, site, weights_sha, allow_random)
    name = folder_name(matcher.model_name, site)

    def place(default_root: str) -> Path:
        if site_folder:
            return (Path(output_dir) if output_dir is not None else Path(default_root)) / name
        return Path(output_dir) if output_dir is not None else Path(default_root) / matcher.model_name

    if not overwrite:  # the CLI's gate: an earlier export is replaced only with --force
        _refuse_existing(place("onnx" if t == "onnx" else "engines"))
    if t == "onnx":
        return export_onnx(matcher, place("onnx"), site=site, weights_sha=weights_sha, opset=opset, verify=verify,
                           parity_tolerance=parity_tolerance)

    from . import trt

    exe = trt.find_trtexec(trtexec)  # fail before any export
    precision = trt.check_precision(precision)
    engine_dir = place("engines")
    notes: list[str] = []
    parity: dict[str, float] = {}
    checked = False
    if onnx_dir is not None:
        src = Path(onnx_dir)
        if not (src / MANIFEST).is_file() and (src / name / MANIFEST).is_file():
            src = src / name
        man = _check_folder(src, matcher.model_name, site, weights_sha)
    else:
        src = engine_dir
        man = None
        if (src / MANIFEST).is_file():
            try:
                man = _check_folder(src, matcher.model_name, site, weights_sha)
                notes.append(f"reused current ONNX graphs in {src} (same model, site and weights hash)")
            except OnnxFolderError as exc:
                notes.append(f"re-exported ONNX graphs: {exc}")
                man = None
        if man is None:
            r = export_onnx(matcher, src, site=site, weights_sha=weights_sha, opset=opset, verify=verify,
                            parity_tolerance=parity_tolerance)
            notes += r.notes
            man = read_manifest(src)
    parity, checked = dict(man.parity), bool(man.parity)
    res = trt.build_engines(src, engine_dir, man, exe, precision=precision, extra_args=extra_trt_args,
                            envelope=envelope, timeout_s=timeout_s)
    res.parity, res.parity_checked, res.tolerance = parity, checked, parity_tolerance
    res.notes = notes + res.notes
    return res
