"""xcalib: camera-LiDAR cross-modal matching and targetless extrinsic calibration.

``import xcalib`` is cheap and never imports torch: the heavy parts (``Matcher``, ``train``,
``calibrate``, ...) load on first use. Geometry convention: see :mod:`xcalib.geometry`.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

from ._version import __version__
from .geometry.camera import CameraIntrinsics
from .protocol import (
    PROTOCOL_VERSION,
    ProtocolError,
    ProtocolViolation,
    detect_box3d_convention,
    validate_frame_inputs,
)
from .types import Frame, MatchResult

# public name -> module that defines it (imported lazily)
_LAZY = {
    "Matcher": "xcalib.engine.matcher",
    "train": "xcalib.engine.trainer",
    "create_model": "xcalib.models",
    "list_models": "xcalib.models",
    "BuildResult": "xcalib.deploy.build",
    "OnnxMatcher": "xcalib.deploy.ort_runtime",
    "CalibrationResult": "xcalib.calib.result",
    "CalibConfig": "xcalib.calib.config",
    "calibrate": "xcalib.calib.api",
    "Monitor": "xcalib.monitor",
    "MonitorConfig": "xcalib.monitor",
    "load_dataset": "xcalib.io.hdf5",
    "read_frames": "xcalib.io.frames",
    "draw_matching_overlay": "xcalib.viz.matching",
    "draw_calibration_overlay": "xcalib.viz.calibration",
}

__all__ = [
    "__version__", "PROTOCOL_VERSION", "CameraIntrinsics", "ProtocolError", "ProtocolViolation",
    "validate_frame_inputs", "detect_box3d_convention", "Frame", "MatchResult", *_LAZY,
]


def __getattr__(name: str):
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'xcalib' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(__all__))


if TYPE_CHECKING:  # pragma: no cover
    from .calib.api import calibrate
    from .calib.config import CalibConfig
    from .calib.result import CalibrationResult
    from .engine.matcher import Matcher
    from .engine.trainer import train
