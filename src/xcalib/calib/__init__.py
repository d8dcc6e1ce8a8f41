"""Targetless camera<-LiDAR calibration from detections.

Public API: :func:`calibrate` (many frames or the reference's one-frame form),
:func:`calibrate_single`, :func:`derive_matches` -> :class:`PseudoLabels`,
:class:`CalibrationResult`, :func:`write_report`. Modules: ``inputs`` (normalisation),
``boxmodel`` (yaw / point outlines), ``boxproj`` (batched projection), ``hypotheses``
(bring-up), ``refine`` (least squares + matching), ``matching``, ``report``, ``api``.
Heavy modules load lazily.
"""

from __future__ import annotations

import importlib

from .result import CalibrationResult

_LAZY = {"calibrate": "api", "calibrate_single": "api", "derive_matches": "matching", "PseudoLabels": "matching",
         "write_report": "report"}

__all__ = ["CalibrationResult", *_LAZY]


def __getattr__(name: str):
    mod = _LAZY.get(name)
    if mod is None:
        raise AttributeError(f"module 'xcalib.calib' has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{mod}"), name)
    globals()[name] = value
    return value
