"""Drift monitoring: watch a calibrated camera's detections and say when it has moved, how far,
and how sure (:class:`Monitor`, :class:`MonitorConfig`; outputs in :mod:`xcalib.monitor.output`)."""

from .core import JSON_FIELDS, CameraMonitor, DriftEvent, Monitor, MonitorConfig, MonitorStatus, load_calibration

__all__ = ["Monitor", "MonitorConfig", "MonitorStatus", "DriftEvent", "CameraMonitor", "load_calibration",
           "JSON_FIELDS"]
