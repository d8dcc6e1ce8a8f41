"""3D detections as stacks emit them -> xcalib's box7 (LiDAR frame, yaw about z).

Read: ``vision_msgs`` Detection3DArray (ROS 1 and ROS 2 layouts) and Autoware's
``DetectedObjects`` / ``TrackedObjects`` (``autoware_perception_msgs`` and
``autoware_auto_perception_msgs``: bounding boxes, cylinders, footprint polygons). Boxes in
another frame than the cloud's are moved into it through the recording's static tf. A box turned
about x/y (a tilted roadside LiDAR, a box pitched by a slope) by up to ``max_tilt_deg`` is
flattened to its heading (yaw of its x axis) and counted; beyond it the message is refused.
Boxes without an orientation (all identity quaternions, or Autoware's ``orientation_availability
== UNAVAILABLE``) are returned without yaw (``yawless``) so that the calibration re-estimates it
from the points, as for yaw-less boxes of any other source.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...errors import FormatError
from ._convert import MAX_BOX_CENTER_M

__all__ = ["AUTOWARE_3D", "Boxes3D", "boxes3d_any", "MAX_TILT_DEG", "autoware_types"]

MAX_TILT_DEG = 10.0  # boxes turned about x/y by more are refused; up to it they are flattened to yaw
_FLAT_DEG = 0.05  # below this a box counts as level (float noise of a yaw-only quaternion)

AUTOWARE_3D = tuple(f"{pkg}/msg/{t}" for pkg in ("autoware_perception_msgs", "autoware_auto_perception_msgs")
                    for t in ("DetectedObjects", "TrackedObjects"))

_AUTOWARE_MSGS = {
    "ObjectClassification": "uint8 label\nfloat32 probability\n",
    "Shape": "uint8 type\ngeometry_msgs/Polygon footprint\ngeometry_msgs/Vector3 dimensions\n",
    "DetectedObjectKinematics": "geometry_msgs/PoseWithCovariance pose_with_covariance\nbool has_position_covariance\n"
                                "uint8 orientation_availability\ngeometry_msgs/TwistWithCovariance twist_with_covariance\n"
                                "bool has_twist\nbool has_twist_covariance\n",
    "DetectedObject": "float32 existence_probability\n{p}/ObjectClassification[] classification\n"
                      "{p}/DetectedObjectKinematics kinematics\n{p}/Shape shape\n",
    "DetectedObjects": "std_msgs/Header header\n{p}/DetectedObject[] objects\n",
    "TrackedObjectKinematics": "geometry_msgs/PoseWithCovariance pose_with_covariance\nuint8 orientation_availability\n"
                               "geometry_msgs/TwistWithCovariance twist_with_covariance\n"
                               "geometry_msgs/AccelWithCovariance acceleration_with_covariance\nbool is_stationary\n",
    "TrackedObject": "unique_identifier_msgs/UUID object_id\nfloat32 existence_probability\n"
                     "{p}/ObjectClassification[] classification\n{p}/TrackedObjectKinematics kinematics\n{p}/Shape shape\n",
    "TrackedObjects": "std_msgs/Header header\n{p}/TrackedObject[] objects\n",
}


def autoware_types() -> dict[str, str]:
    """Message definitions (``.msg`` text) of the Autoware object messages, both packages, and
    ``unique_identifier_msgs/UUID``: used when a bag does not embed its own."""
    out = {"unique_identifier_msgs/msg/UUID": "uint8[16] uuid\n"}
    for pkg in ("autoware_perception_msgs", "autoware_auto_perception_msgs"):
        for name, text in _AUTOWARE_MSGS.items():
            out[f"{pkg}/msg/{name}"] = text.replace("{p}", pkg)
    return out


@dataclass(frozen=True)
class Boxes3D:
    """``box7`` [M, 7] in the cloud's frame; ``ids`` per box; ``yawless`` when no box carried an
    orientation; ``flattened`` boxes turned about x/y (by up to ``max_tilt_deg``), ``max_tilt_deg``
    the largest such turn."""

    box7: np.ndarray
    ids: list[str]
    yawless: bool
    flattened: int
    max_tilt_deg: float


def _err(where, problem: str) -> FormatError:
    """``where``: (bag, topic[, message index])."""
    if len(where) > 2 and where[2] is not None:
        problem = f"message {where[2]}: {problem}"
    return FormatError(where[0], problem, field=where[1])


def _quat_matrix(q: np.ndarray) -> np.ndarray:
    x, y, z, w = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def _raw(msg, where):
    """(centres [M,3], quaternions [M,4] xyzw, sizes [M,3], ids, orientation known per box) of either type."""
    rows, quats, sizes, ids, known = [], [], [], [], []
    if hasattr(msg, "detections"):  # vision_msgs Detection3DArray
        for det in msg.detections:
            p, q, s = det.bbox.center.position, det.bbox.center.orientation, det.bbox.size
            rows.append([p.x, p.y, p.z])
            quats.append([q.x, q.y, q.z, q.w])
            sizes.append([s.x, s.y, s.z])
            ids.append(str(getattr(det, "id", "")))
            known.append(True)
        return rows, quats, sizes, ids, known
    for i, obj in enumerate(msg.objects):  # Autoware DetectedObjects / TrackedObjects
        pose = obj.kinematics.pose_with_covariance.pose
        p, q, shape = pose.position, pose.orientation, obj.shape
        d = shape.dimensions
        size = [d.x, d.y, d.z]
        centre = np.array([p.x, p.y, p.z], dtype=np.float64)
        if int(shape.type) == 1:  # CYLINDER: dimensions.x is the diameter
            size = [d.x, d.x, d.z]
        elif int(shape.type) == 2:  # POLYGON: the footprint (object frame) bounds the box
            pts = np.array([[v.x, v.y] for v in shape.footprint.points], dtype=np.float64).reshape(-1, 2)
            if len(pts) < 3:
                raise _err(where, f"object {i}: POLYGON shape with {len(pts)} footprint point(s)")
            lo, hi = pts.min(axis=0), pts.max(axis=0)
            mid = np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, 0.0])
            qv = np.array([q.x, q.y, q.z, q.w], dtype=np.float64)
            n = np.linalg.norm(qv)
            centre = centre + (_quat_matrix(qv / n) @ mid if n > 0 else mid)
            size = [hi[0] - lo[0], hi[1] - lo[1], d.z]
        elif int(shape.type) != 0:
            raise _err(where, f"object {i}: unknown shape type {int(shape.type)} (0 box, 1 cylinder, 2 polygon)")
        rows.append(centre.tolist())
        quats.append([q.x, q.y, q.z, q.w])
        sizes.append(size)
        uid = getattr(obj, "object_id", None)
        ids.append(bytes(np.asarray(uid.uuid, dtype=np.uint8)).hex() if uid is not None else "")
        known.append(int(getattr(obj.kinematics, "orientation_availability", 2)) != 0)
    return rows, quats, sizes, ids, known


def boxes3d_any(msg, where, T_lidar_det: np.ndarray | None = None, max_tilt_deg: float = MAX_TILT_DEG) -> Boxes3D:
    """Detection3DArray / DetectedObjects / TrackedObjects -> :class:`Boxes3D` in the LiDAR frame
    (``T_lidar_det``: the detections' frame -> the cloud's, None when they are the same)."""
    rows, quats, sizes, ids, known = _raw(msg, where)
    c = np.asarray(rows, dtype=np.float64).reshape(-1, 3)
    q = np.asarray(quats, dtype=np.float64).reshape(-1, 4)
    s = np.asarray(sizes, dtype=np.float64).reshape(-1, 3)
    if not (np.all(np.isfinite(c)) and np.all(np.isfinite(q)) and np.all(np.isfinite(s))):
        raise _err(where, "3D detections hold non-finite centre, orientation or size values")
    if len(s) and not np.all(s > 0):
        k = int(np.flatnonzero(~np.all(s > 0, axis=1))[0])
        raise _err(where, f"detection {k}: box size {s[k].tolist()} is not positive")
    far = np.maximum(np.abs(c).max(axis=1), s.max(axis=1)) > MAX_BOX_CENTER_M if len(c) else np.zeros(0, bool)
    if np.any(far):
        k = int(np.flatnonzero(far)[0])
        raise _err(where, f"detection {k}: centre {c[k].tolist()} / size beyond {MAX_BOX_CENTER_M:g} m")
    n = np.linalg.norm(q, axis=1)
    if len(n) and not np.all(n > 1e-6):
        raise _err(where, f"detection {int(np.flatnonzero(n <= 1e-6)[0])}: zero orientation quaternion")
    if len(n) and not np.all(np.abs(n - 1.0) <= 0.1):
        k = int(np.flatnonzero(np.abs(n - 1.0) > 0.1)[0])
        raise _err(where, f"detection {k}: orientation {q[k].tolist()} is not a unit quaternion (norm {n[k]:.3g})")
    identity = np.all(np.abs(q[:, :3]) == 0.0, axis=1) if len(q) else np.zeros(0, bool)
    yawless = bool(len(q)) and (bool(np.all(identity)) or not any(known))
    R_T = np.eye(3) if T_lidar_det is None else np.asarray(T_lidar_det, dtype=np.float64)[:3, :3]
    t_T = np.zeros(3) if T_lidar_det is None else np.asarray(T_lidar_det, dtype=np.float64)[:3, 3]
    out = np.zeros((len(c), 7))
    flattened, worst = 0, 0.0
    for k in range(len(c)):
        R = R_T @ _quat_matrix(q[k] / n[k])
        tilt = float(np.degrees(np.arccos(np.clip(R[2, 2], -1.0, 1.0))))  # the box's z axis off the vertical
        if tilt > max_tilt_deg:
            raise _err(where, f"detection {k}: the box is turned {tilt:.1f} deg about x/y in the LiDAR frame; "
                              f"xcalib's 3D boxes turn about z only (boxes up to {max_tilt_deg:g} deg are "
                              "flattened to their heading)")
        if tilt > _FLAT_DEG:
            flattened += 1
            worst = max(worst, tilt)
        out[k, :3] = R_T @ c[k] + t_T
        out[k, 3:6] = s[k]
        if T_lidar_det is None and tilt <= _FLAT_DEG:  # a yaw-only quaternion: its yaw as written
            yaw = 2.0 * np.arctan2(q[k, 2] / n[k], q[k, 3] / n[k])
            out[k, 6] = (yaw + np.pi) % (2 * np.pi) - np.pi if abs(yaw) > np.pi else yaw
        else:
            out[k, 6] = np.arctan2(R[1, 0], R[0, 0])  # heading of the box's x axis
    if yawless and T_lidar_det is not None:
        yawless = bool(np.allclose(R_T[:2, :2], np.eye(2), atol=1e-9))
    return Boxes3D(out, ids, yawless, flattened, worst)
