"""``OneShotSession``: label-free adaptation of a matcher to a new site.

Loop: :meth:`OneShotSession.observe` crops each frame **once** (the same crops serve matching
now and training later), matches it with the current model, and buffers it. The pose comes
from the correspondence-free calibrator over the buffered detections (no matcher involved, so
supervision is not circular); calibration is attempted at the explicit schedule
``next_calibration_at`` (observed-frame counts growing by ``recalibrate_growth``), and a new
pose is adopted only when it explains the whole buffer better (:class:`PoseGate`).
:meth:`adapt` fine-tunes the model on pseudo-labels projected through the pose, weighted by
confidence; the starting weights stay in memory (:meth:`reset_weights`). :meth:`save` writes a
folder ``Matcher.from_pretrained(model, weights=DIR)`` reloads bit-exactly; :meth:`save_site`
installs it where ``Matcher.from_pretrained(model, site=NAME)`` looks.

The session's matcher carries the session's pose (``matcher.calibration``, None until one is
accepted or set; a calibration the matcher had from another site is dropped), so its ``match``
fuses the model with the projection geometry, and the saved folder's ``calibration.json`` gives
the reloaded matcher the same. The session's own matching (agreement reports) uses the model
alone, so pseudo-labels never feed on themselves.
"""

from __future__ import annotations

import json
import logging
import math
import warnings
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np

from ..calib.config import CalibConfig
from ..calib.inputs import as_intrinsics
from ..calib.result import CalibrationResult
from ..engine.host import assign
from ..types import Frame
from ..options import Options, document, resolve
from .adapt import ADAPT_MODES, AdaptOptions, AdaptReport, adapt_model
from .evidence import EvidenceBuffer, Observation, observe_frame_inputs
from .pose_gate import CalibrationUpdate, PoseGate
from .pseudo import PseudoTargets, pseudo_targets

__all__ = ["OneShotSession", "OneShotOptions", "SessionAdaptOptions", "ObserveReport", "OneShotError", "ImageSizeChangedError", "NotCalibratedError"]

log = logging.getLogger("xcalib.oneshot")


_MODE_ALIASES = {"adapter": "heads", "head": "heads"}  # the reference's adaptation modes -> xcalib's


class OneShotError(RuntimeError):
    """A one-shot session cannot do what was asked in its current state."""


class NotCalibratedError(OneShotError):
    """Pseudo-labels need a calibration and the session has none yet."""


class ImageSizeChangedError(OneShotError, ValueError):
    """A frame's image size differs from the session's (one camera, one lens per session)."""


@dataclass
class ObserveReport:
    """What one :meth:`OneShotSession.observe` did.

    n_detections_2d/3d: boxes given; n_kept_2d/3d: boxes the model sees; n_matches: one-to-one
    matches of the current model with score >= ``match_threshold``; n_pseudo_pairs: matches
    implied by the current pose in this frame (0 when uncalibrated); agreement: share of those
    the model's matches reproduce (NaN without pseudo pairs); calibration: the attempt made on
    this frame, if any; next_calibration_at: observed-frame count of the next scheduled attempt;
    n_banked: pseudo-labelled pairs of this frame that training will use (confidence >=
    ``accept_confidence``); bank_size: such pairs over the whole buffer (the reference's
    feature-bank size). ``frame_id`` (property) = ``index``.
    """

    frame_key: str
    index: int
    n_detections_2d: int
    n_detections_3d: int
    n_kept_2d: int
    n_kept_3d: int
    n_matches: int
    calibrated: bool
    n_pseudo_pairs: int
    agreement: float
    buffer_frames: int
    calibration: CalibrationUpdate | None
    next_calibration_at: int
    n_banked: int = 0
    bank_size: int = 0

    @property
    def frame_id(self) -> int:
        """The reference's name of :attr:`index` (observation number in this session)."""
        return self.index


def _as_calibration(cal, intrinsics) -> CalibrationResult:
    if isinstance(cal, CalibrationResult):
        if not cal.success:
            raise ValueError(f"set_calibration: the calibration failed ({cal.message}); give a successful one")
        if cal.intrinsics is None:
            cal.intrinsics = intrinsics
        return cal
    T = np.asarray(cal, dtype=np.float64)
    if T.shape not in ((4, 4), (3, 4)) or not np.all(np.isfinite(T)):
        raise ValueError(f"set_calibration: expected a CalibrationResult or a finite 4x4 T_cam_lidar, got shape {T.shape}")
    R = T[:3, :3]
    if not np.allclose(R @ R.T, np.eye(3), atol=1e-4) or np.linalg.det(R) < 0:
        raise ValueError("set_calibration: the 3x3 block of T_cam_lidar is not a rotation")
    return CalibrationResult(success=True, intrinsics=intrinsics, rotation=R, translation=T[:3, 3],
                             method="survey", message="set_calibration")


@dataclass(frozen=True)
class OneShotOptions(Options):
    """The settings of a :class:`OneShotSession` (the defaults in one place; the class docstring
    documents each). ``OneShotSession(matcher, K, options=...)`` and/or the fields as keyword
    arguments."""

    gate: float = 0.3
    neg_iou: float = 0.05
    min_frames: int = 3
    recalibrate_growth: float = 1.5
    max_frames: int = 64
    min_gain: float = 0.0
    match_threshold: float = 0.7
    mode: str = "heads"
    calib_config: CalibConfig | None = None
    seed: int = 0
    validate: str = "warn"
    accept_confidence: float | None = None
    replay_frames: int | None = None
    max_center_dist_px: float | None = None
    bank_capacity: int | None = None
    calib_buffer: int | None = None
    calib_reproj_px: float | None = None

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.mode not in ADAPT_MODES:
            raise ValueError(f"mode must be one of {ADAPT_MODES}, got {self.mode!r}")
        if int(self.min_frames) < 1:
            raise ValueError(f"min_frames must be >= 1, got {self.min_frames}")
        if not self.recalibrate_growth >= 1.0:
            raise ValueError(f"recalibrate_growth must be >= 1, got {self.recalibrate_growth}")


_A = AdaptOptions()


@dataclass(frozen=True)
class SessionAdaptOptions(Options):
    """The settings of :meth:`OneShotSession.adapt` besides ``steps`` (its docstring documents
    each); those it shares with :func:`adapt_model` default to :class:`AdaptOptions`' values."""

    lr: float = _A.lr
    batch_size: int | None = None
    temperature: float | None = None
    mode: str | None = None
    replay_weight: float | None = None
    min_bank: int | None = None
    frames_per_batch: int = _A.frames_per_batch
    anchor: float = _A.anchor
    holdout: float = _A.holdout
    min_holdout: int = _A.min_holdout
    min_pairs: int = _A.min_pairs
    keep_if_worse: bool = _A.keep_if_worse
    augment: bool = True
    p_augment: float = _A.p_augment
    augment_options: dict | None = None
    box_weight: float = 10.0
    box_gain: float | str | tuple | None = "auto"
    progress: Callable[[int, int, float], None] | None = None


class OneShotSession:
    """Label-free site adaptation of ``matcher`` (see the module docstring).

    Args:
        matcher: an ``xcalib.Matcher`` (its model is adapted in place).
        intrinsics: ``CameraIntrinsics``, a 3x3 K or a dict (pixels).
        gate: IoU gate of pseudo-matches and of the buffer score.
        neg_iou: pairs whose projected IoU is below this are negatives in training.
        min_frames: observed frames before the first calibration attempt.
        recalibrate_growth: later attempts when the observed-frame count reaches
            ceil(growth x count at the last attempt) (>= 1 more frame).
        max_frames: evidence buffer capacity (FIFO).
        min_gain: relative buffer-score gain a new pose needs to replace the current one.
        match_threshold: score a model match needs to count in reports (0.7, the reference's).
        mode: default adaptation mode ("heads" or "full").
        calib_config: the ``CalibConfig`` of the session's calibrations (None: the defaults).
        seed: seeds pose search and training; validate: protocol mode of :meth:`observe`.
        accept_confidence: pseudo-labels below this confidence are not trained on (None: all,
            xcalib's default; the reference's 0.5 is not imposed, see docs/compat.md).
        replay_frames: the reference's name of ``max_frames`` (observations kept for training).
        max_center_dist_px, bank_capacity, calib_buffer, calib_reproj_px: the reference's
            options of its centre-distance pseudo-labels, feature bank and RANSAC buffer; xcalib
            has none of those (IoU-gated pseudo-labels on a frame buffer, a correspondence-free
            calibrator), so they are accepted, recorded in ``reference_options`` and have no
            effect (docs/compat.md).
    """

    @document(OneShotOptions)
    def __init__(self, matcher, intrinsics, *, options: OneShotOptions | None = None, **overrides: Any):
        o = resolve(OneShotOptions, options, overrides, where="OneShotSession")
        self.options = o
        gate, neg_iou, min_frames, recalibrate_growth, max_frames = o.gate, o.neg_iou, o.min_frames, \
            o.recalibrate_growth, o.max_frames
        min_gain, match_threshold, mode, calib_config, seed, validate = o.min_gain, o.match_threshold, o.mode, \
            o.calib_config, o.seed, o.validate
        accept_confidence, replay_frames, max_center_dist_px, bank_capacity, calib_buffer, calib_reproj_px = \
            o.accept_confidence, o.replay_frames, o.max_center_dist_px, o.bank_capacity, o.calib_buffer, \
            o.calib_reproj_px
        self.matcher = matcher
        self.intrinsics = as_intrinsics(intrinsics)
        self.gate, self.neg_iou = float(gate), float(neg_iou)
        self.min_frames = int(min_frames)
        self.recalibrate_growth = float(recalibrate_growth)
        self.match_threshold = float(match_threshold)
        self.mode = mode
        self.seed = int(seed)
        self.validate = validate
        self.accept_confidence = 0.0 if accept_confidence is None else float(accept_confidence)
        self.reference_options = {"max_center_dist_px": max_center_dist_px, "bank_capacity": bank_capacity,
                                  "calib_buffer": calib_buffer, "calib_reproj_px": calib_reproj_px}
        self.best_reproj_px = float("inf")  # lowest whole-buffer median residual of any solve (px)
        self._bank_cache: tuple[Any, dict[int, int]] = (None, {})
        self.buffer = EvidenceBuffer(int(replay_frames) if replay_frames is not None else max_frames)
        self.pose = PoseGate(self.intrinsics, gate_iou=gate, min_gain=min_gain, config=calib_config, seed=seed)
        self.next_calibration_at = self.min_frames
        self.image_size: tuple[int, int] | None = None
        self.history: list[AdaptReport] = []
        self.base_state = {k: v.detach().clone() for k, v in matcher.model.state_dict().items()}
        self._base_box_gain = getattr(matcher.model, "box_gain", None)
        self._sync_matcher()

    def _sync_matcher(self) -> None:
        """The matcher carries the session's current pose (None before one)."""
        self.matcher.set_calibration(self.pose.current)

    # ------------------------------------------------------------------ state
    @property
    def model(self):
        return self.matcher.model

    @property
    def calibration(self) -> CalibrationResult | None:
        """The current pose (``None`` until one is accepted or set)."""
        return self.pose.current

    @property
    def is_calibrated(self) -> bool:
        return self.pose.current is not None

    @property
    def n_observed(self) -> int:
        return self.buffer.total_seen

    @property
    def bank(self) -> EvidenceBuffer:
        """The reference's name of :attr:`buffer` (the observations adaptation trains on)."""
        return self.buffer

    @property
    def calib_session(self) -> PoseGate:
        """The reference's name of :attr:`pose` (holds the pose and decides on new solves)."""
        return self.pose

    def set_calibration(self, calibration, *, lock: bool = True) -> CalibrationResult:
        """Use a known (surveyed) pose: a successful ``CalibrationResult`` or a 4x4 ``T_cam_lidar``.
        With ``lock`` the automatic calibration never replaces it."""
        cal = _as_calibration(calibration, self.intrinsics)
        self.pose.set(cal, lock=lock)
        self._sync_matcher()
        return cal

    def reset_weights(self) -> None:
        """Restore the weights the session started with."""
        self.model.load_state_dict(self.base_state)
        if self._base_box_gain is not None:
            self.model.set_box_gain(self._base_box_gain, rescale=False)
            self._sync_box_gain()
        self.model.eval()

    def _sync_box_gain(self) -> None:
        """The matcher's config (written beside saved weights) carries the model's ``box_gain``."""
        if "box_gain" in self.model.config:
            self.matcher.update_config(box_gain=self.model.config["box_gain"])

    # ------------------------------------------------------------------ observing
    def _check_size(self, image: np.ndarray, key: str) -> None:
        if not isinstance(image, np.ndarray) or image.ndim != 3 or image.shape[2] != 3:
            raise ValueError(f"observe({key}): image must be an [H, W, 3] array, got "
                             f"{getattr(image, 'shape', type(image).__name__)}")
        wh = (int(image.shape[1]), int(image.shape[0]))
        ref = self.image_size
        if ref is None and self.intrinsics.width is not None and self.intrinsics.height is not None:
            ref = (int(self.intrinsics.width), int(self.intrinsics.height))
        if ref is not None and wh != ref:
            raise ImageSizeChangedError(
                f"observe({key}): image is {wh[0]}x{wh[1]} px but this session's camera is {ref[0]}x{ref[1]} px "
                f"(from {'the first frame' if self.image_size else 'the intrinsics'}); one session serves one camera "
                "and lens: start a new session for a different image size")
        self.intrinsics.check_image_size(*wh)

    def observe(self, image, point_cloud, bboxes_2d, bboxes_3d, *, frame_key: str | None = None,
                meta: dict | None = None, validate: str | None = None,
                progress: Callable[[str, int, int], None] | None = None) -> ObserveReport:
        """Add one frame (RGB [H,W,3]; LiDAR [P,>=3] metres; boxes in pixels / LiDAR frame).
        ``meta`` may carry ``box7`` [M,7] yawed boxes for the calibrator."""
        index = self.buffer.total_seen
        key = str(frame_key) if frame_key is not None else f"{index:06d}"
        self._check_size(image, key)
        self.matcher.validate_inputs(image, point_cloud, bboxes_2d, bboxes_3d, validate or self.validate)
        obs = observe_frame_inputs(image, point_cloud, bboxes_2d, bboxes_3d, self.matcher.crop_config,
                                   key=key, index=index, meta=meta)
        obs.frame.frame_key = f"{index:06d}"  # unique within the buffer
        if self.image_size is None:
            self.image_size = obs.image_size
        self.buffer.add(obs)
        matches = self._match(obs)
        update = None
        if self.n_observed >= self.next_calibration_at and not self.pose.locked:
            update = self._note_best(self.pose.propose(self.buffer.frames(), progress=progress))
            self.next_calibration_at = max(self.n_observed + 1,
                                           int(math.ceil(self.n_observed * self.recalibrate_growth)))
            self._sync_matcher()
        n_pseudo, agree, n_banked, bank_size = 0, float("nan"), 0, 0
        if self.is_calibrated and not obs.empty:
            t = pseudo_targets(obs, self.calibration, gate=self.gate, neg_iou=self.neg_iou)
            n_pseudo = t.n_pairs
            n_banked = int(np.sum(t.weight[t.positive] >= self.accept_confidence))
            if n_pseudo:
                mi = np.array(matches, dtype=np.int64).reshape(-1, 2)
                agree = float(t.positive[mi[:, 0], mi[:, 1]].sum() / n_pseudo)
        if self.is_calibrated:
            bank_size = self._bank_size()
        return ObserveReport(frame_key=key, index=index, n_detections_2d=int(len(np.asarray(bboxes_2d).reshape(-1, 4))),
                             n_detections_3d=int(len(np.asarray(bboxes_3d))), n_kept_2d=obs.num_2d,
                             n_kept_3d=obs.num_3d, n_matches=len(matches), calibrated=self.is_calibrated,
                             n_pseudo_pairs=n_pseudo, agreement=agree, buffer_frames=len(self.buffer),
                             calibration=update, next_calibration_at=self.next_calibration_at,
                             n_banked=n_banked, bank_size=bank_size)

    def observe_frame(self, frame: Frame, **kw) -> ObserveReport:
        """:meth:`observe` on an ``xcalib.types.Frame`` (its ``meta['box7']`` reaches the calibrator)."""
        meta = {"box7": frame.meta["box7"]} if frame.meta and "box7" in frame.meta else None
        return self.observe(frame.image, frame.point_cloud, frame.bboxes_2d, frame.bboxes_3d,
                            frame_key=frame.frame_key or None, meta=meta, **kw)

    def _match(self, obs: Observation) -> list[tuple[int, int]]:
        """One-to-one model matches (kept numbering) with score >= match_threshold."""
        if obs.empty:
            return []
        cfg = self.matcher.crop_config
        sim = self.matcher.similarity(obs.inputs(cfg.point_cloud_size, np.random.default_rng(cfg.seed)))
        _, pairs = assign(sim, threshold=self.match_threshold, method="hungarian",
                          fill_value=getattr(self.model, "fill_value", None))
        return [(i, j) for i, j, _ in pairs]

    def calibrate(self, min_pairs: int | None = None, disambiguate: bool = True, gate_factor: float | None = None,
                  min_frames: int | None = None, *,
                  progress: Callable[[str, int, int], None] | None = None) -> CalibrationUpdate:
        """Attempt a calibration on the whole buffer now; the gate decides (``accepted``).

        The reference's options: ``min_pairs`` = matched pairs the solve needs (None: the
        calibrator's own minimum); ``disambiguate=False`` adopts any successful solve without the
        whole-buffer comparison; ``min_frames``: with 0 < observed frames < min_frames the
        solve is not adopted (warming up; None: no such check). ``gate_factor`` (the reference's
        factor over its best full-buffer error) is accepted and has no effect: xcalib's gate
        compares the candidate's whole-buffer IoU score with the current pose's (``min_gain``).
        Returns a :class:`CalibrationUpdate` with the reference's fields (``success``,
        ``n_inliers``, ``n_correspondences``, ``buffer_reproj_px``, ``projection``).
        """
        frames = self.buffer.frames()
        warming = min_frames is not None and 0 < self.n_observed < int(min_frames)
        saved = self.pose.config
        if min_pairs is not None:
            self.pose.config = saved.replace(min_pairs=int(min_pairs))
        try:
            if warming:
                current, self.pose.current = self.pose.current, None
                locked, self.pose.locked = self.pose.locked, False
                try:  # solve and report, adopt nothing
                    update = self.pose.propose(frames, progress=progress, adopt_any=True)
                finally:
                    self.pose.current, self.pose.locked = current, locked
                if update.result is not None:
                    update.result.accepted = False
                update.accepted = False
                update.reason = f"warming up: {self.n_observed} of min_frames={min_frames} frames observed; not adopted"
            else:
                update = self.pose.propose(frames, progress=progress, adopt_any=not disambiguate)
        finally:
            self.pose.config = saved
        self._note_best(update)
        self._sync_matcher()
        return update

    def _bank_size(self) -> int:
        """Pseudo-labelled pairs over the buffer through the current pose (counts cached per
        observation while the pose object stays the same)."""
        cal = self.calibration
        if self._bank_cache[0] is not cal:
            self._bank_cache = (cal, {})
        counts = self._bank_cache[1]
        total = 0
        for o in self.buffer:
            if o.index not in counts:
                counts[o.index] = pseudo_targets(o, cal, gate=self.gate, neg_iou=self.neg_iou,
                                                 min_confidence=self.accept_confidence).n_pairs
            total += counts[o.index]
        return total

    def _note_best(self, update: CalibrationUpdate) -> CalibrationUpdate:
        """Track :attr:`best_reproj_px` (the reference's running best full-buffer error)."""
        if update.success and np.isfinite(update.buffer_reproj_px):
            self.best_reproj_px = min(self.best_reproj_px, float(update.buffer_reproj_px))
        return update

    # ------------------------------------------------------------------ adapting
    def pseudo_labels(self) -> list[PseudoTargets]:
        """Pseudo-targets of every buffered observation through the current pose."""
        if not self.is_calibrated:
            raise NotCalibratedError(
                f"no calibration yet after {self.n_observed} observed frame(s) (next attempt at "
                f"{self.next_calibration_at}): observe more frames with objects seen by both sensors, or give a "
                "known pose with set_calibration(...)")
        return [pseudo_targets(o, self.calibration, gate=self.gate, neg_iou=self.neg_iou,
                               min_confidence=self.accept_confidence) for o in self.buffer]

    @document(SessionAdaptOptions)
    def adapt(self, steps: int = 50, *, options: SessionAdaptOptions | None = None, **overrides: Any) -> AdaptReport:
        """Fine-tune the matcher on the pseudo-labels of the buffer (see :mod:`xcalib.oneshot.adapt`).

        ``steps`` defaults to the reference's 50 (``benchmarks/bench_oneshot.py`` and ``xcalib
        bootstrap`` pass 600). The reference's options: ``temperature`` replaces the model's
        cosine temperature during this adaptation (kept after it, as trained); ``min_bank`` is
        the reference's name of ``min_pairs``; ``mode`` "adapter" / "head" map to "heads";
        ``batch_size`` (pairs per step) and ``replay_weight`` are accepted with no effect:
        xcalib batches whole frames (``frames_per_batch``) and keeps the model near its start with
        ``anchor`` instead of a replay loss (docs/compat.md).

        ``augment``: move objects through the pose (:mod:`xcalib.oneshot.augment`; fields of
        ``GeometricAugment`` in ``augment_options``) in a share ``p_augment`` of the training
        frames, so a short recording teaches the site's geometry rather than its few objects.
        With ``augment``, models that predict each 3D box's 2D box (fastmatch) also regress it onto
        the pose's projection (``box_weight`` x squared error in image fractions / log sizes) and
        their pair head's box term is set by ``box_gain`` (see :func:`adapt_model`): "auto" trains
        the model's own gain and the gain from the site's detector-vs-pose box noise ("residual")
        and keeps the better on the held-out buffer frames (twice the training time; the report's
        ``gain_trials`` has both scores); a number or "residual": that gain alone; None: as is.
        Defaults chosen on the tuning sequences of ``benchmarks/bench_oneshot.py``.
        ``holdout`` / ``min_holdout``: the share of buffered frames (at least ``min_holdout`` while as
        many stay for training) held out of training (``AdaptReport.heldout_frames``).
        Raises :class:`NotCalibratedError` before any calibration. With fewer than ``min_pairs``
        pseudo-matches it warns and returns a report with ``trained=False`` (weights untouched).
        The settings: a :class:`SessionAdaptOptions` (``options=``) and/or its fields as keyword
        arguments (an unknown one is a TypeError naming it).
        """
        o = resolve(SessionAdaptOptions, options, overrides, where="OneShotSession.adapt")
        lr, temperature, mode, min_bank, frames_per_batch = o.lr, o.temperature, o.mode, o.min_bank, \
            o.frames_per_batch
        anchor, holdout, min_holdout, min_pairs, keep_if_worse = o.anchor, o.holdout, o.min_holdout, o.min_pairs, \
            o.keep_if_worse
        augment, p_augment, augment_options, box_weight, box_gain, progress = o.augment, o.p_augment, \
            o.augment_options, o.box_weight, o.box_gain, o.progress
        mode = _MODE_ALIASES.get(mode, mode) if mode is not None else None
        if min_bank is not None:
            min_pairs = int(min_bank)
        if temperature is not None:
            if not temperature > 0:
                raise ValueError(f"temperature must be > 0, got {temperature}")
            self.model.temperature = float(temperature)
            self.model.config["temperature"] = float(temperature)
            self.matcher.update_config(temperature=float(temperature))
        targets = self.pseudo_labels()
        obs = list(self.buffer)
        dev = self.matcher.device
        aug = None
        if augment:
            from .augment import GeometricAugment

            aug = GeometricAugment(self.intrinsics, self.calibration.rotation, self.calibration.translation,
                                   neg_iou=self.neg_iou, **(augment_options or {}))
        rep = adapt_model(self.model, obs, targets, steps=int(steps), n_points=self.matcher.crop_config.point_cloud_size,
                          device=dev, mode=mode or self.mode, lr=lr, frames_per_batch=frames_per_batch, anchor=anchor,
                          holdout=holdout, min_holdout=min_holdout, min_pairs=min_pairs, keep_if_worse=keep_if_worse,
                          eval_seed=self.matcher.crop_config.seed, seed=self.seed + len(self.history),
                          augment=aug, p_augment=p_augment, box_weight=box_weight if augment else 0.0,
                          box_gain=box_gain if augment else None, progress=progress)
        self._sync_box_gain()
        if not rep.trained and not rep.reverted and steps > 0:
            warnings.warn(f"OneShotSession.adapt: {rep.message}; the weights are unchanged", RuntimeWarning,
                          stacklevel=2)
        self.history.append(rep)
        return rep

    # ------------------------------------------------------------------ saving
    def save(self, save_dir: str | Path) -> dict[str, Path]:
        """Write ``<model>.pt`` + ``<model>.yaml`` (``Matcher.from_pretrained(model, weights=DIR)``
        reloads them bit-exactly), ``calibration.json`` (when calibrated) and ``oneshot.json``."""
        d = Path(save_dir)
        self._sync_matcher()
        info = {"format": "xcalib-oneshot-v1", "model": self.matcher.model_name, "observed_frames": self.n_observed,
                "buffer_frames": len(self.buffer), "image_size": self.image_size,
                "intrinsics": self.intrinsics.to_dict(), "calibrated": self.is_calibrated,
                "pose_locked": self.pose.locked, "adapt": [r.to_dict() for r in self.history],
                "options": {"gate": self.gate, "neg_iou": self.neg_iou, "mode": self.mode, "seed": self.seed}}
        # weights, config, calibration and oneshot.json in one folder swap: a killed or concurrent
        # save leaves the old set or the new one, never weights of one run beside metadata of another;
        # an uncalibrated session drops the folder's calibration.json (never another pose beside these)
        paths = self.matcher.save_pretrained(
            d, overwrite=True, drop=() if self.is_calibrated else ("calibration.json",),
            extra_files={"oneshot.json": json.dumps(info, indent=1, default=_json_default).encode()})
        return paths

    def save_site(self, site: str) -> dict[str, Path]:
        """:meth:`save` into the user site folder, where ``from_pretrained(model, site=site)`` looks."""
        from ..engine.checkpoint import site_dirs

        if not site or any(c in site for c in "/\\") or site in (".", ".."):
            raise ValueError(f"site: expected a plain folder name, got {site!r}")
        return self.save(site_dirs(site)[0])


def _json_default(v):
    if isinstance(v, (np.floating, np.integer)):
        return v.item()
    if isinstance(v, np.ndarray):
        return v.tolist()
    if isinstance(v, tuple):
        return list(v)
    if hasattr(v, "__dataclass_fields__"):
        return asdict(v)
    return str(v)
