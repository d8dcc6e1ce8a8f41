"""Targetless camera<-LiDAR calibration from detections.

Public API: :func:`calibrate` (many frames or the reference's one-frame form) with a
:class:`CalibConfig`, :func:`calibrate_single`, :func:`derive_matches` -> :class:`PseudoLabels`,
:class:`CalibrationResult` (with :class:`CalibDiagnostics`), :class:`Pose`, :func:`write_report`.

Modules: ``config`` (settings), ``pose`` (the one pose type and parser), ``inputs``
(normalisation), ``boxmodel`` (yaw / point outlines), ``boxproj`` (batched projection),
``hypotheses`` + ``bringup`` (pose search without a guess), ``cost`` (the cost model and its
terms), ``refine`` (matching + robust fit), ``uncertainty``, ``decision`` (the verdict, incl.
model-misfit checks), ``selection`` (the informative frames of a long recording),
``diagnostics``, ``result``, ``matching``, ``report``, ``api``
(``calibrate``: the composition). Heavy modules load lazily.
"""

from __future__ import annotations

import importlib

from .config import CalibConfig
from .diagnostics import CalibDiagnostics
from .pose import Pose
from .result import CalibrationResult

_LAZY = {"calibrate": "api", "calibrate_single": "api", "derive_matches": "matching", "PseudoLabels": "matching",
         "write_report": "report", "pose_hypotheses": "bringup", "CostModel": "cost", "CostTerm": "cost"}

__all__ = ["CalibrationResult", "CalibConfig", "CalibDiagnostics", "Pose", *_LAZY]


def __getattr__(name: str):
    mod = _LAZY.get(name)
    if mod is None:
        raise AttributeError(f"module 'xcalib.calib' has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{mod}"), name)
    globals()[name] = value
    return value
