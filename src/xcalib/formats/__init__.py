"""Dataset formats and calibration conventions (KITTI, CalibAnything, Waymo, nuScenes) and
calibration export/import. Every reader raises :class:`xcalib.errors.FormatError` naming the
file and field; every transform's direction is stated in its docstring (xcalib's own
convention: :mod:`xcalib.geometry`)."""

from .kitti import (  # noqa: F401
    KittiCalibration,
    KittiFrames,
    KittiLabels,
    box7_to_protocol,
    camera_boxes_to_lidar,
    kitti_frames,
    lidar_boxes_to_camera,
    load_kitti_calibration,
    load_kitti_labels,
    project_box7,
    read_velodyne_bin,
    write_kitti_calibration,
)
