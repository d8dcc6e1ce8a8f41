"""File readers and writers: point clouds, images, frame folders (HDF5 caches in ``xcalib.io.hdf5``).

Every reader fails with :class:`xcalib.errors.FormatError` naming the file, the field and the
problem (``FileNotFoundError`` for a missing file), and returns nothing half-read.
"""

from .frames import (
    FRAME_FOLDER_FORMAT,
    FrameFolder,
    is_frame_folder,
    read_detections,
    read_frames,
    read_intrinsics_json,
    register_reader,
    write_frame_folder,
)
from .images import decode_image, encode_image, encode_jpeg, read_image, write_image
from .pointcloud import PCD_ENCODINGS, PointCloud, load_points, read_point_cloud, write_pcd, write_points

__all__ = [
    "PointCloud", "read_point_cloud", "load_points", "write_pcd", "write_points", "PCD_ENCODINGS",
    "read_image", "decode_image", "encode_image", "encode_jpeg", "write_image",
    "FRAME_FOLDER_FORMAT", "FrameFolder", "read_frames", "write_frame_folder", "read_detections",
    "read_intrinsics_json", "is_frame_folder", "register_reader",
]
