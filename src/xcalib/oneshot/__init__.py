"""One-shot, label-free adaptation of a matcher to a new site.

``Matcher.oneshot(intrinsics, **options) -> OneShotSession`` (session.py): observe frames,
calibrate without correspondences (pose_gate.py), pseudo-label by projection (pseudo.py),
fine-tune with a confidence-weighted loss (loss.py, adapt.py), save site weights.
``bootstrap`` (bootstrap.py): a recording of a new site -> site weights, no matcher needed.
Importing this package does not import torch; its modules do.
"""

from __future__ import annotations

import importlib

_LAZY = {
    "OneShotSession": "xcalib.oneshot.session",
    "OneShotOptions": "xcalib.oneshot.session",
    "SessionAdaptOptions": "xcalib.oneshot.session",
    "AdaptOptions": "xcalib.oneshot.adapt",
    "BootstrapOptions": "xcalib.oneshot.bootstrap",
    "ObserveReport": "xcalib.oneshot.session",
    "OneShotError": "xcalib.oneshot.session",
    "NotCalibratedError": "xcalib.oneshot.session",
    "ImageSizeChangedError": "xcalib.oneshot.session",
    "AdaptReport": "xcalib.oneshot.adapt",
    "CalibrationUpdate": "xcalib.oneshot.pose_gate",
    "PseudoTargets": "xcalib.oneshot.pseudo",
    "bootstrap": "xcalib.oneshot.bootstrap",
    "BootstrapResult": "xcalib.oneshot.bootstrap",
}

__all__ = list(_LAZY)


def __getattr__(name: str):
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'xcalib.oneshot' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value
