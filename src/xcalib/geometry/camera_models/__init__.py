"""Camera models: pinhole, pinhole + OpenCV distortion, Kannala-Brandt (OpenCV fisheye),
unified (Mei), UCM, extended UCM and double sphere — project, unproject and the Jacobian of
projection, vectorised, with valid-region flags (see :mod:`.base`).

>>> import numpy as np
>>> from xcalib.geometry.camera_models import get_model
>>> cam = get_model("kannala_brandt")(fx=300, fy=300, cx=640, cy=400, k=(0.01, 0, 0, 0))
>>> uv, valid = cam.project(np.array([[1.0, 0.0, -0.1]]))  # 95.7 degrees off axis
>>> bool(valid[0])
True
"""

from .base import CameraModel
from .double_sphere import DoubleSphere
from .kannala_brandt import KannalaBrandt
from .outline import densify_box_edges, pixels_per_metre, project_outline_rects
from .pinhole import Pinhole, PinholeRadtan
from .registry import (ALIASES, ENTRY_POINT_GROUP, as_calibration_camera, as_camera_model, available_models,
                       calibration_camera_from_dict, canonical_name, get_model, model_from_dict)
from .unified import EUCM, UCM, Unified

__all__ = ["CameraModel", "Pinhole", "PinholeRadtan", "KannalaBrandt", "Unified", "UCM", "EUCM",
           "DoubleSphere", "ALIASES", "ENTRY_POINT_GROUP", "as_camera_model", "as_calibration_camera",
           "calibration_camera_from_dict", "available_models",
           "canonical_name", "get_model", "model_from_dict", "densify_box_edges", "pixels_per_metre",
           "project_outline_rects"]
