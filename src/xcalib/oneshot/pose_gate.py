"""The session's pose: correspondence-free calibration over the evidence buffer, with a gate.

Candidates come from ``xcalib.calib.api.calibrate`` run on the buffered frames with **no
matcher** (detections and geometry only), so the pose never depends on the matcher it will
later supervise. A fresh bring-up and, when a pose exists, a refinement seeded by it are both
tried. A candidate replaces the current pose only when it explains the **whole current buffer**
better: its buffer score (sum over frames of the IoU of every one-to-one match between projected
3D boxes and 2D boxes, IoU gate ``gate_iou``) must exceed the current pose's score on the same
buffer by the factor ``1 + min_gain``.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

from ..calib.config import CalibConfig
from ..calib.inputs import CalibFrame, prepare_frames
from ..calib.refine import match_all, pair_metrics
from ..calib.result import CalibrationResult
from ..geometry.camera import CameraIntrinsics
from ..types import Frame

__all__ = ["BufferScore", "CalibrationUpdate", "PoseGate"]

log = logging.getLogger("xcalib.oneshot")


@dataclass
class BufferScore:
    """How well one pose explains a buffer: ``score`` = sum of matched-pair IoU, ``n_pairs``
    matches, ``residual_px_median`` median box-edge residual (pixels), over ``n_frames``."""

    score: float
    n_pairs: int
    residual_px_median: float
    n_frames: int


@dataclass
class CalibrationUpdate:
    """Outcome of one calibration attempt on the buffer."""

    attempted: bool
    accepted: bool
    reason: str
    n_frames: int = 0
    candidate_score: float = float("nan")
    current_score: float = float("nan")
    elapsed_s: float = 0.0
    result: CalibrationResult | None = None  # the solve this attempt judged (None when none was run)

    # the reference's return fields (its session.calibrate returns the solve itself)
    @property
    def success(self) -> bool:
        """The solve succeeded (whether or not the gate adopted it: see ``accepted``)."""
        return self.result is not None and bool(self.result.success)

    @property
    def n_inliers(self) -> int:
        return 0 if self.result is None else int(self.result.n_inliers)

    @property
    def n_correspondences(self) -> int:
        return 0 if self.result is None else int(self.result.n_correspondences)

    @property
    def buffer_reproj_px(self) -> float:
        """Median box-edge residual (px) of the judged pose over the whole buffer (NaN without)."""
        return float("nan") if self.result is None else float(self.result.buffer_reproj_px)

    @property
    def projection(self) -> np.ndarray | None:
        """[3,4] K[R|t] of the judged pose (None when the solve failed)."""
        return self.result.projection if self.success else None


class PoseGate:
    """Holds the current pose of a static rig and decides whether a new one replaces it."""

    def __init__(self, intrinsics: CameraIntrinsics, *, gate_iou: float = 0.3, min_gain: float = 0.0,
                 config: CalibConfig | None = None, seed: int = 0):
        if not (0.0 < gate_iou <= 1.0):
            raise ValueError(f"gate_iou must be an IoU in (0, 1], got {gate_iou}")
        if min_gain < 0:
            raise ValueError(f"min_gain must be >= 0, got {min_gain}")
        self.intrinsics = intrinsics
        self.gate_iou = float(gate_iou)
        self.min_gain = float(min_gain)
        self.seed = int(seed)
        self.config = (config or CalibConfig()).replace(seed=self.seed)
        self.current: CalibrationResult | None = None
        self.locked = False
        self._prepared: dict[str, CalibFrame] = {}

    # ------------------------------------------------------------------ scoring
    def prepared(self, frames: Sequence[Frame]) -> list[CalibFrame]:
        """CalibFrames of ``frames`` (prepared once per frame key and cached)."""
        keys = [f.frame_key for f in frames]
        todo = [f for f in frames if f.frame_key not in self._prepared]
        if todo:
            cf, _, _ = prepare_frames(todo, self.intrinsics, reestimate_yaw=self.config.reestimate_yaw,
                                      box_model=self.config.box_model)
            for f, c in zip(todo, cf):
                self._prepared[f.frame_key] = c
        live = set(keys)
        for k in [k for k in self._prepared if k not in live]:
            del self._prepared[k]
        return [self._prepared[k] for k in keys]

    def score(self, frames: Sequence[Frame], calibration: CalibrationResult) -> BufferScore:
        """Buffer score of ``calibration`` on ``frames`` (see the module docstring)."""
        cf = self.prepared(frames)
        R, t = calibration.rotation, calibration.translation
        pairs = match_all(cf, self.intrinsics, R, t, gate_iou=self.gate_iou)
        px, ious = pair_metrics(cf, self.intrinsics, R, t, pairs)
        return BufferScore(score=float(np.sum(ious)), n_pairs=int(len(ious)),
                           residual_px_median=float(np.median(px)) if len(px) else float("nan"), n_frames=len(cf))

    # ------------------------------------------------------------------ updates
    def set(self, calibration: CalibrationResult, *, lock: bool = True) -> None:
        self.current = calibration
        self.locked = bool(lock)

    @staticmethod
    def _note(cal: CalibrationResult, s: BufferScore) -> None:
        """Record how well ``cal`` explains the current buffer on the result itself."""
        cal.buffer_reproj_px = s.residual_px_median
        cal.meta = {**cal.meta, "buffer_score": s.score, "buffer_pairs": s.n_pairs, "buffer_frames": s.n_frames}

    def propose(self, frames: Sequence[Frame], progress: Callable[[str, int, int], None] | None = None, *,
                adopt_any: bool = False) -> CalibrationUpdate:
        """Calibrate on ``frames`` and adopt the result only if it beats the current pose there
        (``adopt_any``: adopt any successful solve, the reference's ``disambiguate=False``)."""
        from ..calib.api import calibrate

        t0 = time.perf_counter()
        n = len(frames)
        if self.locked:
            return CalibrationUpdate(False, False, "pose locked by set_calibration(lock=True)", n)
        if n == 0:
            return CalibrationUpdate(False, False, "no frames observed yet", 0)
        frames = list(frames)
        cands: list[CalibrationResult] = []
        fresh = calibrate(frames, self.intrinsics, self.config, matcher=None, progress=progress)
        cands.append(fresh)
        if self.current is not None:
            cands.append(calibrate(frames, self.intrinsics, self.config, matcher=None, prior=self.current))
        ok = [c for c in cands if c.success]
        if not ok:
            return CalibrationUpdate(True, False, f"no pose: {fresh.message}", n, elapsed_s=time.perf_counter() - t0,
                                     result=fresh)
        scored = [(self.score(frames, c), c) for c in ok]
        best_s, best = max(scored, key=lambda x: x[0].score)
        cur = self.score(frames, self.current) if self.current is not None else None
        cur_score = cur.score if cur is not None else float("nan")
        if cur is not None and not adopt_any and not best_s.score > cur.score * (1.0 + self.min_gain):
            self._note(self.current, cur)
            self._note(best, best_s)
            best.accepted = False
            return CalibrationUpdate(True, False, f"kept the current pose: it explains the {n}-frame buffer as well "
                                                   f"(score {cur.score:.2f} vs candidate {best_s.score:.2f})",
                                     n, best_s.score, cur_score, time.perf_counter() - t0, best)
        best.accepted = True
        self._note(best, best_s)
        self.current = best
        reason = "first pose" if cur is None else f"better on the {n}-frame buffer ({best_s.score:.2f} > {cur_score:.2f})"
        log.info("one-shot calibration accepted: %s", reason)
        return CalibrationUpdate(True, True, reason, n, best_s.score, cur_score, time.perf_counter() - t0, best)
