"""The reference's one-frame calibration, ``Matcher.calibrate(image, point_cloud, bboxes_2d,
bboxes_3d, intrinsics, *, match_threshold=0.5, ransac_reproj_px=8.0, validate="warn")``.

The pose comes from :func:`xcalib.calib.api.calibrate` on the one frame (geometry decides; a
frame that leaves the pose ambiguous is a failure, not a guess). The reference's options keep
their meaning as far as that pipeline allows:

* ``validate``: the protocol checks run first ("warn": errors such as a NaN point cloud raise
  ``ProtocolError``; "strict": warnings too; "off": none);
* ``match_threshold``: only pairs the matcher scores at or above it may seed pose hypotheses
  (a frame with none left is solved from geometry alone);
* ``ransac_reproj_px``: ``n_inliers`` counts the matched pairs whose projected 3D box lies
  within this many pixels of its 2D box (mean absolute edge residual), the role of the
  reference's RANSAC inlier threshold.
"""

from __future__ import annotations

import numpy as np

from .result import CalibrationResult

__all__ = ["calibrate_frame", "one_frame", "ThresholdedScores"]


class ThresholdedScores:
    """A matcher view whose similarities below ``threshold`` are NaN (not a candidate), or None
    (no prior) when nothing in the frame reaches it."""

    def __init__(self, matcher, threshold: float):
        self.matcher = matcher
        self.threshold = float(threshold)

    def match(self, image, point_cloud, bboxes_2d, bboxes_3d):
        res = self.matcher.match(image, point_cloud, bboxes_2d, bboxes_3d, validate="off")
        sim = np.asarray(res.similarity, dtype=np.float64)
        keep = sim >= self.threshold
        if not keep.any():
            raise LookupError(f"no matcher score reaches match_threshold={self.threshold}")
        res.similarity = np.where(keep, sim, np.nan).astype(np.float32)
        return res


def inlier_count(image, point_cloud, bboxes_2d, bboxes_3d, result: CalibrationResult, max_px: float) -> int:
    """Matched pairs of ``result`` (one frame) whose mean edge residual is <= ``max_px``."""
    from .inputs import prepare_frames
    from .refine import pair_metrics

    if not result.success or not result.pairs or not len(result.pairs[0]):
        return 0
    cf, intr, _ = prepare_frames([(image, point_cloud, bboxes_2d, bboxes_3d)], result.intrinsics)
    fr = cf[0]
    row = {int(c): k for k, c in enumerate(fr.idx2d)}
    col = {int(c): k for k, c in enumerate(fr.idx3d)}
    pairs = np.array([(row[i], col[j]) for i, j in result.pairs[0] if i in row and j in col], np.int64).reshape(-1, 2)
    px, _ = pair_metrics(cf, intr, result.rotation, result.translation, [pairs])
    return int(np.sum(px <= max_px))


def one_frame(image, point_cloud, bboxes_2d, bboxes_3d, intrinsics, **options) -> tuple[tuple, object, dict]:
    """The reference's one-frame arguments (positional or by name) as :func:`calibrate_frame` takes
    them: ``((image, point_cloud, bboxes_2d, bboxes_3d), intrinsics, options)``."""
    return (image, point_cloud, bboxes_2d, bboxes_3d), intrinsics, options


def calibrate_frame(matcher, inputs: tuple, intrinsics, *, match_threshold: float = 0.5, ransac_reproj_px: float = 8.0,
                    validate: str = "warn", **calib_options) -> CalibrationResult:
    """One frame -> ``CalibrationResult`` (see the module docstring); ``inputs``: (image, point_cloud,
    bboxes_2d, bboxes_3d) (:func:`one_frame` binds the reference's call); ``calib_options`` go to
    :func:`xcalib.calib.api.calibrate`."""
    image, point_cloud, bboxes_2d, bboxes_3d = inputs
    from .api import calibrate

    if not ransac_reproj_px > 0:
        raise ValueError(f"ransac_reproj_px must be > 0, got {ransac_reproj_px}")
    matcher.validate_inputs(image, point_cloud, bboxes_2d, bboxes_3d, validate)
    res = calibrate([(image, point_cloud, bboxes_2d, bboxes_3d)], intrinsics,
                    matcher=ThresholdedScores(matcher, match_threshold), **calib_options)
    if res.success:
        res.n_inliers = inlier_count(image, point_cloud, bboxes_2d, bboxes_3d, res, ransac_reproj_px)
    return res
