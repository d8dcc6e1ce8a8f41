"""Injected drift for tests and benchmarks: a frame as a camera moved by a known change would
have seen it, made by moving the frame's 3D boxes (and points) in the LiDAR frame.

A change ``(rotation_deg [3], translation_m [3])`` is in the convention of ``Pose.moved`` /
``Pose.delta`` (what the monitor reports): the moved pose is ``R' = exp([w]x) R``, ``t' = t + dt``
(camera axes). Moving every LiDAR-frame point to ``M X`` makes the calibration ``T``
project it where the moved camera ``T'`` sees it: ``T' X = T M X``, ``M = T'^-1 T``. Boxes keep their size and
turn only about z (the box's tilt of a fraction of a degree is not representable; its effect on
a box's outline is below a centimetre for changes under 1 deg).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..calib.pose import Pose
from ..geometry.boxes import extents_to_center_size
from ..geometry.transforms import invert_transform
from ..types import Frame

__all__ = ["moved_pose", "inject_change", "move_frame"]


def moved_pose(pose, rotation_deg, translation_m) -> Pose:
    """``pose`` (anything ``Pose.parse`` takes) moved by the change (deg about / m along camera axes)."""
    return Pose.parse(pose).moved(np.radians(np.asarray(rotation_deg, float)), np.asarray(translation_m, float))


def _move_box7(b7: np.ndarray, M: np.ndarray) -> np.ndarray:
    out = np.array(b7, dtype=np.float64).reshape(-1, 7)
    out[:, :3] = out[:, :3] @ M[:3, :3].T + M[:3, 3]
    out[:, 6] += np.arctan2(M[1, 0], M[0, 0])
    return out


def inject_change(frame: Frame, calibration, rotation_deg, translation_m) -> Frame:
    """``frame`` as seen by the camera moved by the change from ``calibration`` (a pose):
    3D boxes (protocol [M,6] of either convention, box7 [M,7], ``meta["box7"]``) and the point
    cloud moved by ``T'^-1 T``. A zero change returns the frame unchanged."""
    if not np.any(rotation_deg) and not np.any(translation_m):
        return frame
    T = Pose.parse(calibration).T
    return move_frame(frame, invert_transform(moved_pose(calibration, rotation_deg, translation_m).T) @ T)


def move_frame(frame: Frame, M: np.ndarray) -> Frame:
    """``frame`` with its 3D boxes and point cloud moved by the rigid transform ``M`` [4,4] in the
    LiDAR frame (e.g. ``T0^-1 T_i``: a frame whose ground-truth pose is ``T_i`` as the pose ``T0``
    sees it)."""
    M = np.asarray(M, dtype=np.float64)
    b3 = np.asarray(frame.bboxes_3d, dtype=np.float64)
    if b3.size == 0:
        new3 = b3
    elif b3.shape[1] == 7:
        new3 = _move_box7(b3, M)
    else:
        ext = np.all(b3[:, 3:6] >= b3[:, 0:3], axis=1)
        cs = np.where(ext[:, None], extents_to_center_size(b3), np.abs(b3))
        cs = np.where(ext[:, None], cs, np.hstack([b3[:, :3], np.abs(b3[:, 3:])]))
        cs[:, :3] = cs[:, :3] @ M[:3, :3].T + M[:3, 3]
        half = cs[:, 3:] / 2
        new3 = np.where(ext[:, None], np.hstack([cs[:, :3] - half, cs[:, :3] + half]), cs)
    meta = dict(frame.meta)
    if meta.get("box7") is not None and np.shape(meta["box7"]) == (len(b3), 7):
        meta["box7"] = _move_box7(meta["box7"], M)
    pc = np.asarray(frame.point_cloud)
    if pc.ndim == 2 and len(pc):
        pc = pc.copy()
        pc[:, :3] = (pc[:, :3].astype(np.float64) @ M[:3, :3].T + M[:3, 3]).astype(pc.dtype)
    return replace(frame, bboxes_3d=np.asarray(new3, dtype=np.asarray(frame.bboxes_3d).dtype), point_cloud=pc,
                   meta=meta)
