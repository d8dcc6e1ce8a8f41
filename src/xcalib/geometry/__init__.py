"""Pure-numpy geometry: cameras, poses, boxes, projections. No torch here.

The convention, stated once and used everywhere in xcalib:

* **LiDAR frame** — the frame the point cloud and the 3D boxes are given in (sensor or
  global; consistency is what matters). Metres.
* **Camera frame** — OpenCV optical: x right, y down, z forward. Metres.
* **Extrinsics** ``T_cam_lidar`` ([4,4]) map LiDAR-frame points to the camera frame:
  ``X_cam = R @ X_lidar + t``. Every "rotation"/"translation" in xcalib is this direction
  unless a name says otherwise (e.g. ``T_lidar_cam``).
* **Projection** ``P = K [R|t]`` ([3,4]) maps LiDAR-frame points to pixels (u right, v down,
  origin at the top-left corner of the image), with OpenCV distortion applied to the
  normalised coordinates when the intrinsics carry it.
* **Camera models** (:mod:`xcalib.geometry.camera_models`): ``CameraIntrinsics`` is the
  pinhole (+ OpenCV distortion) case; ``get_model(name)`` gives the others (Kannala-Brandt,
  unified/Mei, UCM, EUCM, double sphere) with ``project``/``unproject``/``project_jacobian`` on
  camera-frame points, and points outside a model's valid region flagged, never wrapped.
* **Pixels** for 2D boxes (x1, y1, x2, y2); **radians** for angles unless an argument says
  ``degrees``; quaternions (x, y, z, w) unless ``order="wxyz"``.
"""

from .boxes import *  # noqa: F401,F403
from .boxes import __all__ as _boxes_all
from .camera import CameraIntrinsics
from .camera_models import CameraModel, as_camera_model, available_models, get_model, model_from_dict
from .projection import *  # noqa: F401,F403
from .projection import __all__ as _proj_all
from .rotations import *  # noqa: F401,F403
from .rotations import __all__ as _rot_all
from .transforms import *  # noqa: F401,F403
from .transforms import __all__ as _tf_all

__all__ = ["CameraIntrinsics", "CameraModel", "as_camera_model", "available_models", "get_model",
           "model_from_dict", *_boxes_all, *_proj_all, *_rot_all, *_tf_all]
