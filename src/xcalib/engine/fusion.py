"""Calibration-aware scoring: fuse a model's similarity with the projection geometry (torch-free).

When the rig's ``T_cam_lidar`` is known (a ``CalibrationResult``), each (2D box i, 3D box j)
pair also has a geometric score: the IoU of 3D box j projected through the calibration with 2D
box i (``xcalib.calib.matching.derive_matches(...).iou``; yaw-less boxes get their yaw and a
point-hull outline from the points, as in ``calibrate``). The two are pooled log-linearly
(a weighted logarithmic opinion pool of the two "is a match" probabilities)::

    p_model = s                      (models with score range [0, 1]: pair probabilities)
            = (s + 1) / 2            (cosine models, range [-1, 1])
    p_geo   = clip(IoU, eps, 1 - eps)
    fused   = sigmoid((1 - w) * logit(p_model) + w * logit(p_geo))

mapped back to the model's score range (``2 fused - 1`` for cosine models). ``w`` = 0 is the
model alone, ``w`` = 1 the geometry alone; IoU 0.5 is neutral evidence, a 3D box that projects
outside the image or far from the 2D box (IoU 0) pulls the pair towards 0. Entries equal to
the model's ``fill_value`` (pairs it does not score) keep it. ``FUSION_WEIGHT`` = 0.85 /
``GEO_EPS`` = 0.02 were chosen on the tuning sequences of ``benchmarks/bench_oneshot.py`` (site B
seeds 202-204, fastmatch after one-shot adaptation): the smallest weight reaching the best
tuning Top-1 (1.000; w = 0.5: 0.998, w = 0.3: 0.986, model alone: 0.953); eps in 0.005-0.05
changed nothing at w >= 0.5. The geometry is only as good as the pose: with the pose off by
0.5 deg / 0.2 m the same tuning Top-1 is 0.991 (w = 0.85) / 0.987 (w = 0.5), off by 1 deg /
0.5 m 0.928 / 0.951, off by 2 deg / 1 m 0.831 / 0.939 (model alone 0.953): give a matcher a
calibration it can trust (``use_calibration=False`` or a lower ``Matcher.fusion_weight``
otherwise).
This module never imports torch (the ONNX Runtime matcher uses it too).
"""

from __future__ import annotations

import numpy as np

__all__ = ["FUSION_WEIGHT", "GEO_EPS", "POSE_IOU_GATE", "USE_CALIBRATION", "fuse_scores", "geometric_iou", "is_multi_camera",
           "resolve_use_calibration"]

FUSION_WEIGHT = 0.85
GEO_EPS = 0.02
POSE_IOU_GATE = 0.3  # pose-only matches: projected IoU at least this (as ``derive_matches``'s gate)
USE_CALIBRATION = ("auto", True, False)
_P_CLIP = 1e-6


def is_multi_camera(images, camera_per_det) -> bool:
    """True when the detections come from more than one camera (a calibration is of one camera)."""
    if images is None:
        return False
    if camera_per_det is None:
        return len(images) > 1
    return len(set(camera_per_det)) > 1


def resolve_use_calibration(use_calibration, calibration, multi_camera: bool) -> bool:
    """Whether ``match`` fuses: "auto" -> when a calibration is set (single-camera frames only);
    True -> required (error without one); False -> never."""
    if use_calibration not in USE_CALIBRATION or not isinstance(use_calibration, (str, bool)):
        raise ValueError(f"use_calibration must be 'auto', True or False, got {use_calibration!r}")
    if use_calibration is False:
        return False
    if calibration is None:
        if use_calibration is True:
            raise ValueError("use_calibration=True but the matcher has no calibration: call "
                             "set_calibration(CalibrationResult) or load site weights with a calibration.json")
        return False
    if multi_camera:
        if use_calibration is True:
            raise ValueError("use_calibration=True: the calibration is of one camera, but the frame is multi-camera "
                             "(images/camera_per_det); match each camera's detections separately")
        return False
    return True


def geometric_iou(image, point_cloud, bboxes_2d, bboxes_3d, calibration, kept_2d, kept_3d,
                  box7=None) -> np.ndarray:
    """[K',M'] IoU of each kept 2D box (pixels) with each kept 3D box (LiDAR frame) projected
    through ``calibration`` (its intrinsics). ``box7`` [M,7]: yawed boxes for the projection
    when ``bboxes_3d`` are axis-aligned [M,6]."""
    from ..calib.matching import derive_matches

    meta = {} if box7 is None else {"box7": box7}
    frame = _GeoFrame(image, point_cloud, bboxes_2d, bboxes_3d, meta)
    iou = derive_matches(frame, calibration).iou
    return iou[np.ix_(np.asarray(kept_2d, np.int64), np.asarray(kept_3d, np.int64))]


class _GeoFrame:
    """The fields ``derive_matches`` reads from a frame (no copy of the arrays)."""

    def __init__(self, image, point_cloud, bboxes_2d, bboxes_3d, meta):
        self.image, self.point_cloud, self.bboxes_2d, self.bboxes_3d, self.meta = (
            image, point_cloud, bboxes_2d, bboxes_3d, meta)


def _logit(p: np.ndarray) -> np.ndarray:
    p = np.clip(p, _P_CLIP, 1.0 - _P_CLIP)
    return np.log(p) - np.log1p(-p)


def fuse_scores(similarity: np.ndarray, iou: np.ndarray, *, score_range=(0.0, 1.0), weight: float = FUSION_WEIGHT,
                eps: float = GEO_EPS, fill_value: float | None = None) -> np.ndarray:
    """Fused [K',M'] float32 scores in ``score_range`` (see the module docstring)."""
    if not 0.0 <= weight <= 1.0:
        raise ValueError(f"fusion weight must be in [0, 1], got {weight}")
    if not 0.0 < eps < 0.5:
        raise ValueError(f"eps must be in (0, 0.5), got {eps}")
    s = np.asarray(similarity, dtype=np.float64)
    if s.shape != np.shape(iou):
        raise ValueError(f"similarity {s.shape} and IoU {np.shape(iou)} shapes differ")
    if s.size == 0:
        return np.asarray(similarity, dtype=np.float32).copy()
    lo, hi = float(score_range[0]), float(score_range[1])
    p_model = (s - lo) / (hi - lo)
    p_geo = np.clip(np.asarray(iou, dtype=np.float64), eps, 1.0 - eps)
    z = (1.0 - weight) * _logit(p_model) + weight * _logit(p_geo)
    fused = lo + (hi - lo) / (1.0 + np.exp(-z))
    if fill_value is not None:
        fused = np.where(s == fill_value, fill_value, fused)
    return fused.astype(np.float32)
