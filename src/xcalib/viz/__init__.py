"""Pictures: calibration overlays (``viz.calibration``) and matching overlays (``viz.matching``).

Imported lazily by ``xcalib``; submodules import OpenCV inside their functions.
"""
