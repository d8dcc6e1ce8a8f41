"""Detections for recordings that have none (``xcalib detect``, ``calibrate --detect``).

* :mod:`~xcalib.detect.camera` — 2D boxes from an ONNX detector on the CPU (the shipped
  YOLOX-Nano, or the user's YOLOX / YOLOv5 / YOLOv8-layout model); needs ``xcalib[onnx]``.
* :mod:`~xcalib.detect.lidar` — label-free 3D boxes from point clouds: ground removal,
  background model (static LiDAR), grid clustering, minimum-area oriented boxes.
* :mod:`~xcalib.detect.coverage` — the share of the camera's boxes the LiDAR boxes cover at a
  pose: names "too few LiDAR objects detected" in the refusals of such calibrations.
* :mod:`~xcalib.detect.pipeline` — :class:`DetectedFrames`: any frame source with these
  detections in place of its own.

Layer: above io/data (reads frames), below calib; pure numpy/scipy/OpenCV + onnxruntime.
"""

from __future__ import annotations

from .camera import Detections2D, Detector2D, Detector2DConfig, load_detector, shipped_detector_path  # noqa: F401
from .coverage import DetectionCoverage, detection_coverage, explain_refusal  # noqa: F401
from .lidar import Background, GroundPlane, LidarDetectConfig, build_background, fit_ground, lidar_boxes  # noqa: F401
from .pipeline import DetectConfig, DetectedFrames, detect_frame, open_sensors  # noqa: F401

__all__ = ["Detections2D", "Detector2D", "Detector2DConfig", "load_detector", "shipped_detector_path",
           "Background", "GroundPlane", "LidarDetectConfig", "build_background", "fit_ground", "lidar_boxes",
           "DetectConfig", "DetectedFrames", "detect_frame", "open_sensors", "DetectionCoverage", "detection_coverage",
           "explain_refusal"]
