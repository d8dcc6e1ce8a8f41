"""Dataset formats and calibration conventions (KITTI, CalibAnything/OpenCalib, Waymo, nuScenes,
mmdetection3d infos, OpenLABEL, ROS) and calibration export/import.

Every reader raises :class:`xcalib.errors.FormatError` naming the file and field; every
transform's direction is stated in its docstring. Whatever a file's own convention, what comes
out is xcalib's ``T_cam_lidar`` (LiDAR -> OpenCV camera, :mod:`xcalib.geometry`).

* :mod:`.kitti` — ``load_kitti_calibration``, ``kitti_frames`` (``Sequence[Frame]``), labels.
* :mod:`.calibanything` / :mod:`.calibanything_scene` — lucid_calib.json, calib.json, calib.txt,
  OpenCalib JSON; ``calibanything_frames``.
* :mod:`.waymo` — FLU <-> optical, vehicle -> camera, Waymo -> KITTI, ``.tfrecord`` calibrations.
* :mod:`.nuscenes` — ``calibrated_sensor`` records; :mod:`.mmdet3d` — info pickles as frames.
* :mod:`.pandaset` — PandaSet sequences (cuboids, ego poses, timestamps) as frames.
* :mod:`.openlabel`, :mod:`.ros` — export targets; :mod:`.export` — the format registry
  (``export_calibration``, ``read_calibration``, ``FORMATS``).
"""

from .calibanything import (  # noqa: F401
    read_calib_json,
    read_calib_txt,
    read_lucid_calib,
    read_opencalib,
    write_calib_json,
    write_calib_txt,
    write_lucid_calib,
    write_opencalib,
)
from .calibanything_scene import calibanything_frames, is_calibanything_scene  # noqa: F401
from .export import FORMATS, detect_format, export_calibration, read_calibration  # noqa: F401
from .kitti import (  # noqa: F401
    KittiCalibration,
    KittiFrames,
    KittiLabels,
    box7_to_protocol,
    camera_boxes_to_lidar,
    is_kitti_root,
    kitti_frames,
    lidar_boxes_to_camera,
    load_kitti_calibration,
    load_kitti_labels,
    project_box7,
    read_velodyne_bin,
    write_kitti_calibration,
)
from .mmdet3d import mmdet3d_frames, read_mmdet3d_infos  # noqa: F401
from .pandaset import PandaSetFrames, is_pandaset_root, pandaset_frames  # noqa: F401
from .sustech import SustechFrames, is_sustech_root  # noqa: F401
from .nuscenes import calibrated_sensor_to_T, nuscenes_T_cam_lidar, T_to_calibrated_sensor  # noqa: F401
from .waymo import read_waymo_tfrecord, waymo_extrinsic_to_T_cam_lidar, waymo_to_kitti_calibration  # noqa: F401
