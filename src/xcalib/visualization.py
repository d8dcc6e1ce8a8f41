"""The reference's module name for the overlays: ``from xcalib.visualization import
draw_matching_overlay, draw_calibration_overlay`` (they live in :mod:`xcalib.viz`)."""

from __future__ import annotations

from .viz.calibration import draw_calibration_overlay
from .viz.matching import draw_matching_overlay

__all__ = ["draw_matching_overlay", "draw_calibration_overlay"]
