"""Torch-free host-side steps of ``Matcher.match`` shared by the PyTorch and ONNX Runtime
paths: input validation (protocol v1.0), assignment of matches from a similarity matrix and
the ``match`` / ``match_frame`` bodies themselves (:func:`run_match`, :func:`frame_match_args`)."""

from __future__ import annotations

import inspect
import logging
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..geometry.boxes import center_size_to_extents
from ..options import Options, bind_positional, resolve, split_overrides
from ..protocol import WarningRegistry, check_validate_mode, enforce, validate_frame_inputs
from ..types import Frame, MatchResult
from .assign import ASSIGNMENTS, assign  # noqa: F401  (re-exported: the matchers import them from here)
from .domain import (BOOTSTRAP_HINT, SHIPPED_SITES, check_geometry_mode, geometry_match_result, out_of_domain,
                     site_geometry_result)
from .fusion import fuse_scores, geometric_iou, is_multi_camera, resolve_use_calibration

__all__ = ["ASSIGNMENTS", "assign", "validate_match_inputs", "run_match", "frame_match_args", "MatchInputs",
           "MatchOptions", "match_request", "MATCH_POSITIONAL", "MATCH_FRAME_EXTRAS", "MATCH_FRAME_PARAMS"]

log = logging.getLogger("xcalib.matcher")


def validate_match_inputs(image, point_cloud, bboxes_2d, bboxes_3d, mode: str, *, bbox_expansion: float,
                          registry: WarningRegistry | None = None) -> None:
    """Validate one frame with ``mode`` "warn" | "strict" | "off"; box7 rows [M,7] are checked
    through their axis-aligned size."""
    check_validate_mode(mode)
    if mode == "off":
        return
    b3 = bboxes_3d
    a3 = np.asarray(b3, dtype=np.float64) if not isinstance(b3, np.ndarray) else b3
    if a3.ndim == 2 and a3.shape[1] == 7 and np.all(np.isfinite(a3)):
        b3 = center_size_to_extents(a3[:, :6])
    violations = validate_frame_inputs(image, point_cloud, bboxes_2d, b3, bbox_expansion=bbox_expansion)
    enforce(violations, mode, registry=registry)


@dataclass(frozen=True)
class MatchInputs:
    """One frame as ``match`` takes it: image, point cloud [P,3+], 2D boxes [N,4] px, 3D boxes [M,6]
    extents (or [M,7] box7); for multi-camera frames the per-camera ``images`` and the camera of
    each 2D box (``camera_per_det``); ``box7`` [M,7] (the yaw of the 3D boxes); the camera's
    ``intrinsics`` (geometric consensus)."""

    image: Any
    point_cloud: Any
    bboxes_2d: Any
    bboxes_3d: Any
    images: Any = None
    camera_per_det: Any = None
    box7: Any = None
    intrinsics: Any = None


@dataclass(frozen=True)
class MatchOptions(Options):
    """How ``match`` turns a frame into matches, the same for the torch and the ONNX Runtime matcher
    (``Matcher.match`` / ``OnnxMatcher.match`` document each): ``top_k``, ``match_threshold`` (None:
    the site's), ``validate``, ``assignment``, ``use_calibration``, ``geometry``, ``return_latency``.
    The defaults here are the only ones: ``match`` takes this record (``options=``) and/or its fields
    as keyword arguments (the first four also by position, the reference's order)."""

    top_k: int = 1
    match_threshold: float | None = None
    validate: str = "warn"
    assignment: str = "argmax"
    use_calibration: str | bool = "auto"
    geometry: str = "auto"
    return_latency: bool = False


#: ``match``'s optional positional parameters after the four arrays, in the reference's order
MATCH_POSITIONAL = ("top_k", "match_threshold", "return_latency", "validate")
#: ``match``'s keyword arguments that are frame inputs, not options (fields of :class:`MatchInputs`)
MATCH_FRAME_EXTRAS = ("images", "camera_per_det", "box7", "intrinsics")
_FRAME_EXTRAS = frozenset(MATCH_FRAME_EXTRAS)
#: the same as parameters (``help()`` / ``inspect.signature`` of ``match``)
MATCH_FRAME_PARAMS = tuple(inspect.Parameter(n, inspect.Parameter.KEYWORD_ONLY, default=None)
                           for n in MATCH_FRAME_EXTRAS)


def match_request(arrays: tuple, args: tuple, options: MatchOptions | None,
                  overrides: dict[str, Any]) -> tuple[MatchInputs, MatchOptions]:
    """The (frame, options) of a ``match(image, point_cloud, bboxes_2d, bboxes_3d, *args,
    options=None, **overrides)`` call: ``args`` are :data:`MATCH_POSITIONAL` in order; a keyword
    is a frame input (:data:`MATCH_FRAME_EXTRAS`) or a :class:`MatchOptions` field; any other
    name is a TypeError naming it and the accepted ones."""
    kw = bind_positional(MATCH_POSITIONAL, args, overrides, "match")
    extras, opts = split_overrides(kw, [_FRAME_EXTRAS, MatchOptions], "match")
    return MatchInputs(*arrays, **extras), resolve(MatchOptions, options, opts, where="match")


def run_match(m, frame: MatchInputs, options: MatchOptions, *, score_range, fill_value: float | None) -> MatchResult:
    """One frame through matcher ``m`` (``Matcher`` or ``OnnxMatcher``: ``crop_config``,
    ``warning_registry``, ``prepare``, ``similarity`` -> numpy [K',M'], ``calibration``,
    ``fusion_weight``, ``fusion_eps``, ``model_name``, ``device``). ``latency_ms`` = crop + model
    (+ projection and fusion) wall time, validation excluded (``return_latency``: the model's
    ``similarity`` call alone); matches in the caller's numbering. ``geometry`` / ``intrinsics``:
    geometric consensus instead of the model (:mod:`xcalib.engine.domain`). ``match_threshold``
    None: the site threshold in the model config (``xcalib.oneshot.threshold``), else 0.
    ``score_range`` / ``fill_value``: the model's."""
    image, point_cloud, bboxes_2d, bboxes_3d = frame.image, frame.point_cloud, frame.bboxes_2d, frame.bboxes_3d
    images, camera_per_det, box7, intrinsics = frame.images, frame.camera_per_det, frame.box7, frame.intrinsics
    top_k, match_threshold, validate, assignment = options.top_k, options.match_threshold, options.validate, \
        options.assignment
    use_calibration, geometry, return_latency = options.use_calibration, options.geometry, options.return_latency
    if assignment not in ASSIGNMENTS:
        raise ValueError(f"assignment must be one of {ASSIGNMENTS}, got {assignment!r}")
    check_geometry_mode(geometry)
    if match_threshold is None:  # the site's threshold (chosen by bootstrap, in the model config), else 0
        match_threshold = float(m.config.get("match_threshold", 0.0))
    multi_cam = is_multi_camera(images, camera_per_det)
    fuse = resolve_use_calibration(use_calibration, m.calibration, multi_cam)
    validate_match_inputs(image, point_cloud, bboxes_2d, bboxes_3d, validate,
                          bbox_expansion=m.crop_config.bbox_expansion, registry=m.warning_registry)
    t0 = time.perf_counter()
    frame = (image, point_cloud, bboxes_2d, bboxes_3d if box7 is None else box7)
    if geometry == "on" and not multi_cam:
        res, why = geometry_match_result(m, *frame, intrinsics=intrinsics, match_threshold=match_threshold, t0=t0)
        if res is not None:
            return res
        log.warning("match(geometry='on'): %s; the model's scores are returned", why)
    if fuse and geometry == "auto" and use_calibration == "auto" and site_default_source(m) == "geometry":
        return site_geometry_result(m, *frame[:3], bboxes_3d, box7=box7, t0=t0)  # every box: no model needed
    multi = {"images": images, "camera_per_det": camera_per_det} if images is not None else {}
    inputs = m.prepare(image, point_cloud, bboxes_2d, bboxes_3d, **multi)
    t1 = time.perf_counter()
    sim = m.similarity(inputs)
    forward_ms = (time.perf_counter() - t1) * 1000.0
    k2, k3 = inputs.kept_2d, inputs.kept_3d
    geo, weight = None, 0.0
    if fuse and sim.size:
        geo = geometric_iou(image, point_cloud, bboxes_2d, bboxes_3d, m.calibration, k2, k3, box7=box7)
        weight = float(m.fusion_weight)
        sim = fuse_scores(sim, geo, score_range=score_range, weight=weight, eps=m.fusion_eps, fill_value=fill_value)
    elif geometry == "auto" and not multi_cam and getattr(m, "site", None) in SHIPPED_SITES:
        why = out_of_domain(sim, score_range, fill_value)
        if why or intrinsics is not None:  # with intrinsics the consensus is fast and beats off-site weights
            res, none_why = geometry_match_result(m, *frame, intrinsics=intrinsics, match_threshold=match_threshold,
                                                  t0=t0)
            _warn_off_site(m, why, res is not None, none_why)
            if res is not None:
                return res
    ms = forward_ms if return_latency else (time.perf_counter() - t0) * 1000.0
    top, pairs = assign(sim, top_k=top_k, threshold=match_threshold, method=assignment, fill_value=fill_value)
    matches = [(int(k2[i]), int(k3[j]), s) for i, j, s in pairs]
    return MatchResult(similarity=sim, top_indices=top, matches=matches, kept_2d_indices=k2.astype(np.int64),
                       kept_3d_indices=k3.astype(np.int64), latency_ms=ms, model=m.model_name,
                       device=str(m.device), assignment=assignment, geometry_iou=geo, fusion_weight=weight,
                       source="fused" if geo is not None else "model")


def site_default_source(m) -> str:
    """The site's default path recorded by bootstrap (``config["site_default"]["source"]``), "" if none."""
    d = m.config.get("site_default") if isinstance(getattr(m, "config", None), dict) else None
    src = d.get("source") if isinstance(d, dict) else None
    return src if src in ("geometry", "fused") else ""


def _warn_off_site(m, why: str, geometric: bool, none_why: str) -> None:
    """Warn once per matcher that its shipped weights are off site (and what ``match`` did)."""
    if not m.warning_registry.first_time("off-site"):
        return
    what = (f"their scores on this frame are out of domain ({why})" if why
            else "they were trained on synthetic sites, not on this one")
    did = ("matched by geometric consensus instead (MatchResult.source='geometry')" if geometric
           else f"no geometric consensus either ({none_why}): the model's scores are unreliable")
    log.warning("%s with the shipped %r weights and no site calibration: %s; %s. %s", m.model_name, m.site, what, did,
                BOOTSTRAP_HINT)


def frame_match_args(frame: Frame, kw: dict) -> tuple[tuple, dict]:
    """``match`` arguments of a :class:`~xcalib.types.Frame`: its arrays, plus (unless given in
    ``kw``) its per-camera images for multi-camera frames, ``meta["box7"]`` and its intrinsics."""
    kw = dict(kw)
    if frame.images and frame.camera_per_det is not None:
        kw.setdefault("images", frame.images)
        kw.setdefault("camera_per_det", frame.camera_per_det)
    if frame.meta and "box7" in frame.meta:
        kw.setdefault("box7", frame.meta["box7"])
    if frame.intrinsics is not None:
        kw.setdefault("intrinsics", frame.intrinsics)
    return frame.inputs(), kw
