"""A site: one LiDAR and several cameras calibrated in one run (:func:`calibrate_site`), kept as
one transform tree (:class:`SiteCalibration`) and written as ROS files (:func:`write_site_ros`);
a recording's frames streamed in bounded memory first (:func:`stream_views`).
Layer: above :mod:`xcalib.calib`, below ``cli`` / ``viz``."""

from .calibration import CameraAgreement, CameraCalibration, SiteCalibration, calibrate_site, optical_frame
from .ros import write_site_ros
from .stream import StreamConfig, stream_views

__all__ = ["CameraAgreement", "CameraCalibration", "SiteCalibration", "calibrate_site", "optical_frame",
           "write_site_ros", "StreamConfig", "stream_views"]
