"""Input protocol v1.0: per-frame input checks for ``Matcher.match`` and friends.

``validate_frame_inputs`` never raises; it returns ``ProtocolViolation`` records.
``enforce`` turns them into behaviour for ``validate="warn" | "strict" | "off"``:
errors raise :class:`ProtocolError` in warn and strict mode, warnings raise in strict mode
and are logged once per code (per :class:`WarningRegistry`, not a hidden global) in warn mode.
"""

from __future__ import annotations

import logging
import threading
from dataclasses import dataclass
from typing import Iterable

import numpy as np

from .geometry.boxes import as_box7, points_in_boxes
from .geometry.boxes import detect_box3d_convention  # re-exported  # noqa: F401
from .geometry.camera import CameraIntrinsics  # re-exported  # noqa: F401

__all__ = [
    "PROTOCOL_VERSION", "MAX_DETECTIONS_2D", "MAX_DETECTIONS_3D", "MIN_IMAGE_HW", "MIN_BBOX_PX",
    "MIN_POINTS_PER_BOX", "VALIDATE_MODES", "CameraIntrinsics", "ProtocolViolation",
    "ProtocolError", "validate_frame_inputs", "enforce", "WarningRegistry",
    "detect_box3d_convention", "check_validate_mode",
]

PROTOCOL_VERSION = "1.0"
MAX_DETECTIONS_2D = 32
MAX_DETECTIONS_3D = 32
MIN_IMAGE_HW = (480, 640)
MIN_BBOX_PX = 8
MIN_POINTS_PER_BOX = 50
DEFAULT_BBOX_EXPANSION = 1.25
VALIDATE_MODES = ("warn", "strict", "off")

log = logging.getLogger("xcalib.protocol")


@dataclass(frozen=True)
class ProtocolViolation:
    """One failed check: ``code`` (e.g. ``"bboxes_2d.small"``), ``severity`` ("error" |
    "warning") and a human ``message``."""

    code: str
    severity: str
    message: str

    def __str__(self) -> str:
        return f"[{self.severity}] {self.code}: {self.message}"


class ProtocolError(ValueError):
    """Inputs violate protocol v1.0; ``.violations`` lists what was wrong."""

    def __init__(self, violations: Iterable[ProtocolViolation]):
        self.violations = list(violations)
        lines = "\n".join(f"  {v}" for v in self.violations)
        super().__init__(
            f"frame inputs violate xcalib input protocol v{PROTOCOL_VERSION}:\n{lines}\n"
            "See docs/protocol.md for the contract."
        )


def _err(code: str, msg: str) -> ProtocolViolation:
    return ProtocolViolation(code, "error", msg)


def _warn(code: str, msg: str) -> ProtocolViolation:
    return ProtocolViolation(code, "warning", msg)


def _check_image(image, out: list) -> tuple[int, int] | None:
    if not isinstance(image, np.ndarray):
        out.append(_err("image.type", f"image must be a numpy array [H, W, 3] uint8, got {type(image).__name__}"))
        return None
    if image.ndim != 3 or image.shape[2] != 3:
        out.append(_err("image.shape", f"image must have shape [H, W, 3] (RGB), got {image.shape}"))
        return None
    h, w = image.shape[:2]
    if h == 0 or w == 0:
        out.append(_err("image.empty", f"image has zero size {image.shape}"))
        return None
    if image.dtype in (np.float32, np.float64):
        out.append(_warn("image.dtype", f"image is {image.dtype}; assumed already scaled to [0, 1] and passed through"))
    elif image.dtype != np.uint8:
        out.append(_err("image.dtype", f"image must be uint8 RGB (0-255), got dtype {image.dtype}"))
    if h < MIN_IMAGE_HW[0] or w < MIN_IMAGE_HW[1]:
        out.append(_warn("image.resolution",
                         f"image is {w}x{h}; below the {MIN_IMAGE_HW[1]}x{MIN_IMAGE_HW[0]} floor (crops will be upsampled)"))
    return h, w


def _check_points(pc, out: list) -> np.ndarray | None:
    if not isinstance(pc, np.ndarray):
        out.append(_err("point_cloud.type", f"point_cloud must be a numpy array [P, >=3], got {type(pc).__name__}"))
        return None
    if pc.ndim != 2 or pc.shape[1] < 3:
        out.append(_err("point_cloud.shape", f"point_cloud must have shape [P, >=3] (x, y, z, ...), got {pc.shape}"))
        return None
    if pc.shape[0] == 0:
        out.append(_warn("point_cloud.empty", "point_cloud has no points; every 3D crop will be dropped"))
        return pc
    xyz = pc[:, :3]
    if xyz.dtype.kind != "f":
        out.append(_warn("point_cloud.dtype", f"point_cloud XYZ is {xyz.dtype}, not floating point; it will be cast to float32"))
    elif not np.all(np.isfinite(xyz)):
        n = int((~np.isfinite(xyz)).any(axis=1).sum())
        out.append(_err("point_cloud.finite", f"point_cloud has {n} point(s) with NaN/Inf in x, y, z"))
        return None
    return pc


def _as_array(x, name: str, out: list) -> np.ndarray | None:
    try:
        return np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        out.append(_err(f"{name}.type", f"{name} could not be read as a numeric array ({exc})"))
        return None


def _check_boxes2d(b2, hw, out: list) -> None:
    a = _as_array(b2, "bboxes_2d", out)
    if a is None:
        return
    if a.size == 0:
        out.append(_warn("bboxes_2d.empty", "no 2D boxes; the result will have no matches"))
        return
    if a.ndim != 2 or a.shape[1] < 4:
        out.append(_err("bboxes_2d.shape", f"bboxes_2d must have shape [K, 4] (x1, y1, x2, y2), got {a.shape}"))
        return
    a = a[:, :4]
    if not np.all(np.isfinite(a)):
        out.append(_err("bboxes_2d.finite", f"bboxes_2d has NaN/Inf in row(s) {np.nonzero(~np.isfinite(a).all(1))[0].tolist()}"))
        return
    bad = (a[:, 2] <= a[:, 0]) | (a[:, 3] <= a[:, 1])
    if bad.any():
        out.append(_warn("bboxes_2d.order",
                         f"{int(bad.sum())} bbox(es) have x2<=x1 or y2<=y1 (rows {np.nonzero(bad)[0].tolist()}); they will be dropped"))
    small = ~bad & (((a[:, 2] - a[:, 0]) < MIN_BBOX_PX) | ((a[:, 3] - a[:, 1]) < MIN_BBOX_PX))
    if small.any():
        out.append(_warn("bboxes_2d.small",
                         f"{int(small.sum())} bbox(es) are smaller than {MIN_BBOX_PX}px on a side (rows {np.nonzero(small)[0].tolist()})"))
    if hw is not None:
        h, w = hw
        outside = (a[:, 2] <= 0) | (a[:, 0] >= w) | (a[:, 3] <= 0) | (a[:, 1] >= h)
        if outside.any():
            out.append(_warn("bboxes_2d.bounds",
                             f"{int(outside.sum())} bbox(es) lie entirely outside the {w}x{h} image (rows {np.nonzero(outside)[0].tolist()})"))
    if len(a) > MAX_DETECTIONS_2D:
        out.append(_warn("bboxes_2d.count",
                         f"{len(a)} 2D boxes exceed the {MAX_DETECTIONS_2D}-detection TensorRT envelope (TensorRT frames are split into chunks)"))


def _check_boxes3d(b3, pc, out: list, expansion: float) -> None:
    a = _as_array(b3, "bboxes_3d", out)
    if a is None:
        return
    if a.size == 0:
        out.append(_warn("bboxes_3d.empty", "no 3D boxes; the result will have no matches"))
        return
    if a.ndim != 2 or a.shape[1] != 6:
        out.append(_err("bboxes_3d.shape", f"bboxes_3d must have shape [M, 6] (extents or centre+dims), got {a.shape}"))
        return
    if not np.all(np.isfinite(a)):
        out.append(_err("bboxes_3d.finite", f"bboxes_3d has NaN/Inf in row(s) {np.nonzero(~np.isfinite(a).all(1))[0].tolist()}"))
        return
    box7 = as_box7(a)
    degenerate = np.any(box7[:, 3:6] <= 0, axis=1)
    if degenerate.any():
        out.append(_warn("bboxes_3d.degenerate",
                         f"{int(degenerate.sum())} 3D box(es) have an axis with extent <= 0 (rows {np.nonzero(degenerate)[0].tolist()}); they will be dropped"))
    if len(a) > MAX_DETECTIONS_3D:
        out.append(_warn("bboxes_3d.count",
                         f"{len(a)} 3D boxes exceed the {MAX_DETECTIONS_3D}-detection TensorRT envelope (TensorRT frames are split into chunks)"))
    if pc is not None and len(pc) and (~degenerate).any():
        counts = points_in_boxes(pc, box7[~degenerate], expansion=expansion).sum(axis=1)
        sparse = np.nonzero(~degenerate)[0][counts < MIN_POINTS_PER_BOX]
        if len(sparse):
            out.append(_warn("bboxes_3d.sparse",
                             f"{len(sparse)} 3D box(es) hold fewer than {MIN_POINTS_PER_BOX} points inside the "
                             f"{expansion:g}x expanded box (rows {sparse.tolist()}); empty crops are dropped"))


def validate_frame_inputs(image, point_cloud, bboxes_2d, bboxes_3d, *,
                          bbox_expansion: float = DEFAULT_BBOX_EXPANSION) -> list[ProtocolViolation]:
    """Check one frame against protocol v1.0. Never raises; returns the violations found."""
    out: list[ProtocolViolation] = []
    hw = _check_image(image, out)
    pc = _check_points(point_cloud, out)
    _check_boxes2d(bboxes_2d, hw, out)
    _check_boxes3d(bboxes_3d, pc, out, bbox_expansion)
    return out


class WarningRegistry:
    """Remembers which warning codes were already logged (thread-safe)."""

    def __init__(self) -> None:
        self._seen: set[str] = set()
        self._lock = threading.Lock()

    def first_time(self, code: str) -> bool:
        with self._lock:
            if code in self._seen:
                return False
            self._seen.add(code)
            return True

    def reset(self) -> None:
        with self._lock:
            self._seen.clear()


_DEFAULT_REGISTRY = WarningRegistry()


def check_validate_mode(mode: str) -> str:
    if mode not in VALIDATE_MODES:
        raise ValueError(f"validate must be one of {VALIDATE_MODES}, got {mode!r}")
    return mode


def enforce(violations: Iterable[ProtocolViolation], mode: str = "warn",
            registry: WarningRegistry | None = None) -> list[ProtocolViolation]:
    """Apply a validation mode. The mode is checked even when there are no violations.

    "off": nothing. "strict": raise :class:`ProtocolError` on any violation. "warn": raise on
    errors only; log each warning code once per registry. Returns the violations.
    """
    check_validate_mode(mode)
    violations = list(violations)
    if mode == "off" or not violations:
        return violations
    if mode == "strict":
        raise ProtocolError(violations)
    errors = [v for v in violations if v.severity == "error"]
    if errors:
        raise ProtocolError(errors)
    reg = registry or _DEFAULT_REGISTRY
    for v in violations:
        if reg.first_time(v.code):
            log.warning("%s (further '%s' warnings are not repeated)", v, v.code)
    return violations
