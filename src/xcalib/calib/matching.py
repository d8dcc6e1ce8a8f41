"""Pseudo-labels: one-to-one (2D box, 3D box) matches derived by projection through a calibration."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .inputs import prepare_frames
from .pose import Pose
from .refine import match_frame

__all__ = ["PseudoLabels", "derive_matches"]


@dataclass
class PseudoLabels:
    """Matches of one frame in the caller's numbering.

    pairs [n,2] int64 (2D index, 3D index); confidence [n] in [0,1] (IoU of the projected 3D box
    with its 2D box); match_matrix [K,M] bool; projected [M,4] px clipped projected 3D boxes
    (NaN where not visible); iou [K,M] IoU of every 2D box with every projected 3D box.
    """

    pairs: np.ndarray
    confidence: np.ndarray
    match_matrix: np.ndarray
    projected: np.ndarray
    iou: np.ndarray

    def __len__(self) -> int:
        return len(self.pairs)


def derive_matches(frame, calibration, *, gate: float = 0.3, intrinsics=None) -> PseudoLabels:
    """Match a frame's 2D and 3D boxes through ``calibration`` (Hungarian, IoU >= ``gate``).

    ``frame`` is an ``xcalib.types.Frame`` or an (image, point_cloud, bboxes_2d, bboxes_3d) tuple;
    ``calibration`` a successful ``CalibrationResult`` (its intrinsics are used unless
    ``intrinsics`` is given), an (R, t) pair or a [4,4] ``T_cam_lidar`` together with ``intrinsics``.
    3D boxes are prepared as the calibration prepared them (its config), else as ``calibrate`` would.
    """
    if not (0.0 < gate <= 1.0):
        raise ValueError(f"derive_matches: gate must be an IoU in (0, 1], got {gate}")
    if hasattr(calibration, "success") and not calibration.success:
        raise ValueError(f"derive_matches: the calibration failed ({calibration.message})")
    pose = Pose.parse(calibration, "derive_matches: calibration")
    R, t = pose.R, pose.t
    intr = intrinsics if intrinsics is not None else getattr(calibration, "intrinsics", None)
    cfg = getattr(calibration, "config", None)
    kw = {} if cfg is None else {"reestimate_yaw": cfg.reestimate_yaw, "box_model": cfg.box_model}
    frs, intr, _ = prepare_frames([frame], intr, **kw)
    fr = frs[0]
    K = len(np.asarray(frame.bboxes_2d if hasattr(frame, "bboxes_2d") else frame[2]).reshape(-1, 4))
    b3 = np.asarray(frame.bboxes_3d if hasattr(frame, "bboxes_3d") else frame[3])
    M = len(b3) if b3.size else 0
    pairs, iou_p, rects = match_frame(fr, intr, R, t, gate_iou=gate)
    from .boxproj import iou_batched

    iou_full = np.zeros((K, M))
    proj_full = np.full((M, 4), np.nan)
    if fr.n3:
        proj_full[fr.idx3d] = rects
    if fr.n2 and fr.n3:
        iou_full[np.ix_(fr.idx2d, fr.idx3d)] = iou_batched(rects[None], fr.boxes2d)[0]
    out_pairs = np.column_stack([fr.idx2d[pairs[:, 0]], fr.idx3d[pairs[:, 1]]]).astype(np.int64) if len(pairs) \
        else np.zeros((0, 2), dtype=np.int64)
    mm = np.zeros((K, M), dtype=bool)
    mm[out_pairs[:, 0], out_pairs[:, 1]] = True
    return PseudoLabels(pairs=out_pairs, confidence=np.asarray(iou_p, dtype=np.float64), match_matrix=mm,
                        projected=proj_full, iou=iou_full)
