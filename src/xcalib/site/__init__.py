"""A site: one LiDAR and several cameras calibrated in one run (:func:`calibrate_site`), kept as
one transform tree (:class:`SiteCalibration`) and written as ROS files (:func:`write_site_ros`).
Layer: above :mod:`xcalib.calib`, below ``cli`` / ``viz``."""

from .calibration import CameraAgreement, CameraCalibration, SiteCalibration, calibrate_site, optical_frame
from .ros import write_site_ros

__all__ = ["CameraAgreement", "CameraCalibration", "SiteCalibration", "calibrate_site", "optical_frame",
           "write_site_ros"]
