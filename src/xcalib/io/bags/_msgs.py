"""Typestores for reading and writing bags without ROS: the stock ROS 1 (noetic) / ROS 2
(humble) message sets plus ``vision_msgs`` (ROS 1 1.x and ROS 2 4.x layouts), registered here
because the stock stores lack them (a bag's own embedded definitions win when it has them)."""

from __future__ import annotations

from typing import Literal

__all__ = ["VISION_MSGS_ROS1", "VISION_MSGS_ROS2", "typestore", "DET2D", "DET3D", "IMAGE", "COMPRESSED",
           "CAMERA_INFO", "POINTCLOUD2", "TF", "TF_TYPES", "STRING", "SUPPORTED_TYPES", "DET3D_TYPES"]

IMAGE = "sensor_msgs/msg/Image"
COMPRESSED = "sensor_msgs/msg/CompressedImage"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
POINTCLOUD2 = "sensor_msgs/msg/PointCloud2"
DET2D = "vision_msgs/msg/Detection2DArray"
DET3D = "vision_msgs/msg/Detection3DArray"
TF = "tf2_msgs/msg/TFMessage"
TF_TYPES = (TF, "tf/msg/tfMessage")
STRING = "std_msgs/msg/String"
DET3D_TYPES = (DET3D, *(f"{pkg}/msg/{t}" for pkg in ("autoware_perception_msgs", "autoware_auto_perception_msgs")
                        for t in ("DetectedObjects", "TrackedObjects")))
SUPPORTED_TYPES = (POINTCLOUD2, IMAGE, COMPRESSED, CAMERA_INFO, DET2D, *DET3D_TYPES, *TF_TYPES, STRING)

# vision_msgs 4.x (ROS 2 humble and later)
VISION_MSGS_ROS2 = {
    "vision_msgs/msg/Point2D": "float64 x\nfloat64 y\n",
    "vision_msgs/msg/Pose2D": "vision_msgs/Point2D position\nfloat64 theta\n",
    "vision_msgs/msg/BoundingBox2D": "vision_msgs/Pose2D center\nfloat64 size_x\nfloat64 size_y\n",
    "vision_msgs/msg/ObjectHypothesis": "string class_id\nfloat64 score\n",
    "vision_msgs/msg/ObjectHypothesisWithPose":
        "vision_msgs/ObjectHypothesis hypothesis\ngeometry_msgs/PoseWithCovariance pose\n",
    "vision_msgs/msg/Detection2D": "std_msgs/Header header\nvision_msgs/ObjectHypothesisWithPose[] results\n"
                                   "vision_msgs/BoundingBox2D bbox\nstring id\n",
    "vision_msgs/msg/Detection2DArray": "std_msgs/Header header\nvision_msgs/Detection2D[] detections\n",
    "vision_msgs/msg/BoundingBox3D": "geometry_msgs/Pose center\ngeometry_msgs/Vector3 size\n",
    "vision_msgs/msg/Detection3D": "std_msgs/Header header\nvision_msgs/ObjectHypothesisWithPose[] results\n"
                                   "vision_msgs/BoundingBox3D bbox\nstring id\n",
    "vision_msgs/msg/Detection3DArray": "std_msgs/Header header\nvision_msgs/Detection3D[] detections\n",
}

# vision_msgs 1.x (ROS 1 noetic)
VISION_MSGS_ROS1 = {
    "vision_msgs/msg/BoundingBox2D": "geometry_msgs/Pose2D center\nfloat64 size_x\nfloat64 size_y\n",
    "vision_msgs/msg/ObjectHypothesisWithPose": "int64 id\nfloat64 score\ngeometry_msgs/PoseWithCovariance pose\n",
    "vision_msgs/msg/Detection2D": "std_msgs/Header header\nvision_msgs/ObjectHypothesisWithPose[] results\n"
                                   "vision_msgs/BoundingBox2D bbox\nsensor_msgs/Image source_img\n",
    "vision_msgs/msg/Detection2DArray": "std_msgs/Header header\nvision_msgs/Detection2D[] detections\n",
    "vision_msgs/msg/BoundingBox3D": "geometry_msgs/Pose center\ngeometry_msgs/Vector3 size\n",
    "vision_msgs/msg/Detection3D": "std_msgs/Header header\nvision_msgs/ObjectHypothesisWithPose[] results\n"
                                   "vision_msgs/BoundingBox3D bbox\nsensor_msgs/PointCloud2 source_cloud\n",
    "vision_msgs/msg/Detection3DArray": "std_msgs/Header header\nvision_msgs/Detection3D[] detections\n",
}


def typestore(ros: Literal[1, 2], vision_layout: Literal["ros1", "ros2"] | None = None):
    """A fresh rosbags typestore: noetic (``ros=1``) or humble (``ros=2``) plus vision_msgs in
    ``vision_layout`` (default: the ROS version's own)."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC if ros == 1 else Stores.ROS2_HUMBLE)
    layout = vision_layout or ("ros1" if ros == 1 else "ros2")
    defs = VISION_MSGS_ROS1 if layout == "ros1" else VISION_MSGS_ROS2
    types = {}
    for name, text in defs.items():
        types.update(get_types_from_msg(text, name))
    if ros == 1:  # noetic's stock set lacks tf's message
        for name in TF_TYPES:
            types.update(get_types_from_msg("geometry_msgs/TransformStamped[] transforms\n", name))
    from ._objects import autoware_types  # Autoware DetectedObjects / TrackedObjects (both packages)

    for name, text in autoware_types().items():
        if name not in store.fielddefs:
            types.update(get_types_from_msg(text, name))
    store.register(types)
    return store
