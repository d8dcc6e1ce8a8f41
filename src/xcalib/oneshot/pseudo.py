"""Training targets from a calibration: pseudo-labels in the model's (kept) numbering.

``xcalib.calib.matching.derive_matches`` projects every 3D box through the pose and matches it
one-to-one (Hungarian, IoU gate) to the 2D boxes; each match's confidence is the IoU of the
projected box with its 2D box. Pairs whose projected IoU is below ``neg_iou`` are geometric
negatives (weight 1); non-matched pairs between ``neg_iou`` and the gate are ambiguous and are
left out of the loss.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..calib.matching import derive_matches
from ..calib.result import CalibrationResult
from .evidence import Observation

__all__ = ["PseudoTargets", "pseudo_targets"]


@dataclass
class PseudoTargets:
    """Targets of one observation, [N,M] over its kept detections.

    positive: bool pseudo-matches (one-to-one); weight: float confidence of each positive in
    [0,1] (0 elsewhere); negative: bool pairs the pose rules out (projected IoU < neg_iou).
    """

    positive: np.ndarray
    weight: np.ndarray
    negative: np.ndarray

    @property
    def n_pairs(self) -> int:
        return int(self.positive.sum())


def pseudo_targets(obs: Observation, calibration: CalibrationResult, *, gate: float = 0.3,
                   neg_iou: float = 0.05, min_confidence: float = 0.0) -> PseudoTargets:
    """Pseudo-labels of ``obs`` through ``calibration`` (see the module docstring)."""
    if not (0.0 <= neg_iou < gate):
        raise ValueError(f"neg_iou must be in [0, gate={gate}), got {neg_iou}")
    N, M = obs.num_2d, obs.num_3d
    if N == 0 or M == 0:
        z = np.zeros((N, M), dtype=bool)
        return PseudoTargets(z, np.zeros((N, M), np.float32), z.copy())
    pl = derive_matches(obs.frame, calibration, gate=gate)
    conf = np.zeros(pl.match_matrix.shape, dtype=np.float32)
    if len(pl):
        conf[pl.pairs[:, 0], pl.pairs[:, 1]] = pl.confidence
    ix = np.ix_(obs.kept_2d, obs.kept_3d)
    pos = pl.match_matrix[ix] & (conf[ix] >= min_confidence)
    w = np.where(pos, conf[ix], 0.0).astype(np.float32)
    neg = (pl.iou[ix] < neg_iou) & ~pos
    return PseudoTargets(pos, w, neg)
