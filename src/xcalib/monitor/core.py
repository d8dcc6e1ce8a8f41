"""``Monitor``: watch a calibrated camera's detections and say when (and how far) it has moved.

For every frame the 2D boxes are matched to the projected 3D boxes through the current pose
(``calib.refine.match_frame``) and the box-edge cost of ``calib.cost`` is linearised there
(``CostModel.jacobian``): residuals ``r`` [4n] (each already divided by its sigma of the
calibration's noise model) and their Jacobian ``J`` [4n, 6] with respect to a pose change
``x = (rotation vector rad, translation m)`` in camera axes (``R <- exp([x0:3]) R``,
``t <- t + x3:6``), relative to the calibration. A segment of frames gives a robust (soft-L1,
iteratively reweighted) least-squares estimate of ``x`` with a cluster-robust covariance (one
cluster per object: the 3D box's track id when the frames carry one, else per matched pair).

Every ``stride`` frames a decision tests (``stats``): the recent segments of ``window``,
``2 window``, ... frames against the reference segment before them (a change point), and the
longest recent segment against the calibration itself (with the calibration's own 1-sigma).
The threshold comes from ``false_alarm_rate`` (per frame). A decision is ``ok`` (no change and
the window could have seen one of ``max_detectable_*``), ``drift`` (a change; the estimate and the
frame it started) or ``unknown`` (too few matched objects, or the boxes constrain the pose too
weakly: the message says which). After a drift the monitor matches and linearises new frames
at the drifted pose. Memory: ``history`` frames of linearised residuals, whatever the stream's
length.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Iterable, Literal

import numpy as np

from ..calib.cost import INWARD, CostModel, Occlusion
from ..calib.diagnostics import NoiseModel
from ..calib.inputs import YAW_OPEN_SIGMA, CalibFrame, prepare_frames
from ..calib.pose import Pose
from ..calib.boxproj import project_rects
from ..calib.refine import DEFAULT_NOISE, F_SCALE, edge_term, match_frame
from ..calib.result import CalibrationResult
from ..geometry.boxes import as_box7, check_boxes3d
from ..geometry.camera import CameraIntrinsics
from . import pairnoise, spread, stats
from .fastyaw import fit_yaw_batch, maybe_in_view
from .iterate import EdgeRows, iterated_fit, object_shares, stack_rows

__all__ = ["MonitorConfig", "MonitorStatus", "DriftEvent", "CameraMonitor", "Monitor", "State", "load_calibration",
           "JSON_FIELDS"]

State = Literal["ok", "drift", "unknown"]

#: keys of every JSON line (``MonitorStatus.to_dict``)
JSON_FIELDS = ("frame", "time_s", "camera", "state", "rotation_change_deg", "translation_change_m",
               "rotation_sigma_deg", "translation_sigma_m", "detectable_rotation_deg", "detectable_translation_m",
               "change_frame", "change_time_s", "n_frames", "n_pairs", "statistic", "threshold", "weak_axes",
               "message")


@dataclass(frozen=True)
class MonitorConfig:
    """Settings of the drift monitor.

    window: frames of the shortest recent segment; stride: frames between decisions; scales:
    recent segments of window * 2^k frames, k < scales; history: frames kept (reference
    segment, change-point search; bounds memory); false_alarm_rate: expected false alarms per
    frame (default 1 per 10,000); fps: frame rate where frames carry no time; min_pairs:
    matched pairs a segment needs; min_objects: distinct matched objects it needs (where frames carry
    track ids); max_detectable_deg / _m: a decision is ``unknown`` when the
    change it could detect (95 % power) exceeds these on any axis; target_deg / _m: the change
    an operator wants seen (the issue's 0.25 deg / 10 cm): axes whose detectable change exceeds
    it are named in ``weak_axes`` (not observable at that size from this traffic within
    target_frames: judged on the longest window the decisions test within that many frames); calibration_sigma_deg / _m:
    the calibration's 1-sigma where the result has none; gate_iou / gate_dist: matching gates
    (``refine.match_frame``); latch: a drift stays (and the estimate follows the frames since
    the change); False: the monitor starts afresh after each alarm (benchmarks);
    leave_out_objects / leave_out_level: an alarm also needs the change to stay significant at
    ``leave_out_level`` (chi-square, 6 dof; 0: the alarm threshold itself) with this many most
    influential tracked objects left out of both segments, one after the other (one or two
    objects whose 3D boxes stay wrong for tens of frames are not a move of the camera; 0: off);
    robust_scale: the soft-L1 loss bends at the residuals' own robust scale (at least the noise
    model's), so a detector noisier than the calibration's noise model does not shrink every
    estimated change; reference_samples: the change test of each window length is calibrated
    per axis from the stream's own drift-free decisions (``CameraMonitor.axis_factors``) once it has
    this many of them (non-overlapping recent windows; REFERENCE_SAMPLES = 12 is the setting
    measured); 0 (the default): off, the single adjacent-window ``inflation`` throughout, as
    before -- measured, the calibration lifted no detection (docs/monitor.md);
    reference_confidence: each axis's factor is the upper ``reference_confidence`` bound of its
    measured variance ratio (few samples: a wider factor). ``Monitor.learn(frames)`` takes a
    drift-free reference stretch of the site for it. relinearise_band: the re-linearised window
    test (0, the default: off): a decision that raised no alarm but some of whose tests reached ``relinearise_band`` times it matches and linearises that window's frames
    again at the window's own estimate (the occlusion shaping pulls an estimate linearised at the
    calibration back towards it) and tests the refit against ``relinearise_factor`` times the
    threshold (re-linearising inflates the drift-free statistics too); relinearise_windows: at
    most this many windows (the highest statistics) per decision (CPU). Measured in
    docs/monitor.md ("The re-linearised window test"). min_inflation: the floor of the
    adjacent-window ``inflation`` (1.0, the default: a window's covariance is never taken below
    what its frames state). Below 1 the stream's own disagreement between adjacent windows may
    narrow the stated covariance, which the weighted residuals' variance overstates where the
    soft-L1 loss down-weights the 3D boxes' errors (measured in docs/monitor.md, "Do the frames'
    errors persist?"). iterate_steps: the change test's recent windows (and the offset test) on each
    window's own estimate: that many Gauss-Newton steps on the frames' unshaped residual rows, the
    occlusion shaping and the soft-L1 weights recomputed at the current estimate (``iterate``; no
    projection or matching again); the covariance and the guard's per-object shares from the normal
    equations there. 0 (the default): off, the one-step estimate linearised where the frames were
    matched. Measured in docs/monitor.md ("The change test on an iterated estimate"): it recovers
    the steps the one-step estimate shrinks but widens the drift-free statistics as much (about 2x),
    so at an equal false-alarm rate it detects no more.
    change_point_step: the change-point tests as a scan (a window-limited GLR over the change
    point): the recent segments of every multiple of ``change_point_step`` frames from twice it up
    to the longest window (5: 10, 15, ..., 80 frames) against the frames before them, in place of
    ``windows``; the threshold is the quantile of the scan's largest statistic under no change
    (``stats.scan_threshold``, simulated once per setting), so the false-alarm rate stays the
    setting; ``history`` must exceed the longest window. 0 (the default): off, the fixed windows. Measured in docs/monitor.md ("A change-point
    scan"): at an equal false-alarm rate it detects as many steps within the target frames as the
    fixed windows (54 of 72 runs), sooner in about half of the runs.
    pair_noise: the noise model's 3D-box part weighted per matched pair (``pairnoise``): a box's
    centre and size errors move its four edges together, so each pair's four residuals are whitened
    by their covariance (the per-edge variances kept, the correlation the box's geometry gives added)
    before they enter the normal equations; pinhole intrinsics only (other camera models keep the
    independent model). False (the default): the four edges weighed as independent. Measured in
    docs/monitor.md ("The 3D-box noise weighted per pair"): it states less information about the
    pose (a pose change moves one box's edges nearly as an error of its centre does) and detects
    fewer steps, later.
    difference_quantile: the change test's covariance taken at the spread of the two segments'
    difference that the objects themselves show (``spread.difference_ratio``: a sandwich clustered
    by object, at each segment's estimate; an object tracked across the boundary whose 3D box
    stays wrong alike pushes both estimates alike, so its error cancels in the difference, and the
    outlying edges' share is bounded where the soft-L1 loss bends), relative to the stated one: the
    ``difference_quantile`` quantile of the ratios of the last DIFF_SAMPLES tests of each window
    length (the stream's own, pooled: one test's ratio from tens of objects is too noisy), never
    above 1 (never wider than stated); 1 until DIFF_MIN_SAMPLES are in. The one-step change tests
    only (not with ``iterate_steps``); the offset test against the calibration keeps its
    covariance. 0 (the default): off. Measured in docs/monitor.md ("The change test's spread from
    the objects").
    """

    window: int = 20
    stride: int = 5
    scales: int = 3
    history: int = 600
    false_alarm_rate: float = 1e-4
    fps: float = 10.0
    min_pairs: int = 20
    min_objects: int = 3
    max_detectable_deg: float = 1.0
    max_detectable_m: float = 0.5
    target_deg: float = 0.25
    target_m: float = 0.10
    target_frames: int = 50
    calibration_sigma_deg: float = 0.1
    calibration_sigma_m: float = 0.05
    gate_iou: float = 0.2
    gate_dist: float = 0.5
    latch: bool = True
    power: float = 0.95
    leave_out_objects: int = 2
    leave_out_level: float = 0.01
    robust_scale: bool = True
    reference_samples: int = 0
    reference_confidence: float = 0.9
    relinearise_band: float = 0.0
    relinearise_factor: float = 2.0
    relinearise_windows: int = 1
    min_inflation: float = 1.0
    iterate_steps: int = 0
    change_point_step: int = 0
    pair_noise: bool = False
    difference_quantile: float = 0.0

    def __post_init__(self) -> None:
        if int(self.leave_out_objects) < 0:
            raise ValueError(f"MonitorConfig.leave_out_objects must be >= 0, got {self.leave_out_objects}")
        if int(self.reference_samples) < 0:
            raise ValueError(f"MonitorConfig.reference_samples must be >= 0, got {self.reference_samples}")
        if not 0.5 <= self.reference_confidence < 1.0:
            raise ValueError(f"MonitorConfig.reference_confidence must be in [0.5, 1), got {self.reference_confidence}")
        if not 0.0 <= self.relinearise_band < 1.0:
            raise ValueError(f"MonitorConfig.relinearise_band must be in [0, 1), got {self.relinearise_band}")
        if not self.relinearise_factor >= 1.0:
            raise ValueError(f"MonitorConfig.relinearise_factor must be >= 1, got {self.relinearise_factor}")
        if int(self.relinearise_windows) < 1:
            raise ValueError(f"MonitorConfig.relinearise_windows must be >= 1, got {self.relinearise_windows}")
        if not 0 <= int(self.iterate_steps) <= 10:
            raise ValueError(f"MonitorConfig.iterate_steps must be in [0, 10], got {self.iterate_steps}")
        k = int(self.change_point_step)
        if k < 0 or (k and 2 * k > max(self.windows)):
            raise ValueError(f"MonitorConfig.change_point_step must be 0 (off) or at most half the longest window "
                             f"({max(self.windows)} frames), got {self.change_point_step}")
        if not 0.25 <= self.min_inflation <= 1.0:
            raise ValueError(f"MonitorConfig.min_inflation must be in [0.25, 1], got {self.min_inflation}")
        if not 0.0 <= self.leave_out_level < 1.0:
            raise ValueError(f"MonitorConfig.leave_out_level must be in [0, 1), got {self.leave_out_level}")
        for name in ("window", "stride", "scales", "history", "min_pairs"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"MonitorConfig.{name} must be >= 1, got {getattr(self, name)}")
        if self.history < 2 * self.window:
            raise ValueError(f"MonitorConfig.history ({self.history}) must be at least 2 * window ({self.window})")
        if int(self.change_point_step) and self.history <= max(self.windows):  # the scan tests against earlier frames
            raise ValueError(f"MonitorConfig.history ({self.history}) must exceed the longest window "
                             f"({max(self.windows)} frames) with change_point_step")
        stats.threshold(self.false_alarm_rate, self.stride, 1)  # validates the rate
        if not self.fps > 0:
            raise ValueError(f"MonitorConfig.fps must be > 0, got {self.fps}")
        if not 0.0 <= self.difference_quantile < 1.0:
            raise ValueError(f"MonitorConfig.difference_quantile must be in [0, 1) (0: off), got {self.difference_quantile}")
        if not isinstance(self.pair_noise, bool):
            raise ValueError(f"MonitorConfig.pair_noise must be True or False, got {self.pair_noise!r}")

    @property
    def windows(self) -> tuple[int, ...]:
        """The recent segments' lengths the decisions test (frames): window * 2^k, k < scales."""
        return tuple(int(self.window) * 2 ** k for k in range(int(self.scales)))

    @property
    def test_windows(self) -> tuple[int, ...]:
        """The recent segments' lengths the change-point tests use (frames): ``windows``, or with
        ``change_point_step`` every multiple of it from 2 change_point_step up to the longest window."""
        k = int(self.change_point_step)
        return tuple(range(2 * k, max(self.windows) + 1, k)) if k else self.windows

    @property
    def n_tests(self) -> int:
        return len(self.windows) + 1

    @property
    def threshold(self) -> float:
        """Chi-square (6 dof) threshold of one test (with ``change_point_step``: of the scan's largest
        statistic, ``stats.scan_threshold``)."""
        if int(self.change_point_step):
            return stats.scan_threshold(self.false_alarm_rate, self.stride, self.n_tests, self.test_windows,
                                        self.history)
        return stats.threshold(self.false_alarm_rate, self.stride, self.n_tests)


@dataclass
class DriftEvent:
    """A detected change: the frame it was detected at and the frame it started (index, time);
    ``step``: the change across the change point (after minus before; 6-vector deg, deg, deg, m, m,
    m, about / along the camera axes) as the simplest ``model`` the data need ("rotation",
    "translation" or "rotation+translation", ``stats.select_model``) with its 1-sigma
    ``step_sigma``; ``change``: the pose since the change relative to the calibration (6-vector,
    all axes) with its 1-sigma ``sigma``; ``statistic``: the test's chi-square at detection."""

    camera: str
    detected_frame: int
    detected_time_s: float
    change_frame: int
    change_time_s: float
    change: np.ndarray
    sigma: np.ndarray
    step: np.ndarray
    step_sigma: np.ndarray
    model: str
    statistic: float
    before_x: np.ndarray | None = None    # pre-change estimate (rad / m) and its covariance
    before_cov: np.ndarray | None = None
    alternative: np.ndarray | None = None  # the other pure model the data do not reject either (deg / m)
    alternative_sigma: np.ndarray | None = None
    alternative_model: str = ""
    step_axes: tuple[int, ...] = ()  # the axes (0-5: rx .. tz) the reported step is on

    def to_dict(self) -> dict:
        return {"camera": self.camera, "detected_frame": self.detected_frame, "detected_time_s": self.detected_time_s,
                "change_frame": self.change_frame, "change_time_s": self.change_time_s, "model": self.model,
                "rotation_step_deg": _l(self.step[:3]), "translation_step_m": _l(self.step[3:]),
                "rotation_step_sigma_deg": _l(self.step_sigma[:3]), "translation_step_sigma_m": _l(self.step_sigma[3:]),
                "rotation_change_deg": _l(self.change[:3]), "translation_change_m": _l(self.change[3:]),
                "rotation_sigma_deg": _l(self.sigma[:3]), "translation_sigma_m": _l(self.sigma[3:]),
                "statistic": self.statistic, "step_axes": [AXIS_NAMES[a] for a in self.step_axes],
                "ambiguous_with": None if self.alternative is None else {
                    "model": self.alternative_model, "rotation_step_deg": _l(self.alternative[:3]),
                    "translation_step_m": _l(self.alternative[3:]),
                    "rotation_step_sigma_deg": _l(self.alternative_sigma[:3]),
                    "translation_step_sigma_m": _l(self.alternative_sigma[3:])}}

    def update(self, fit: "_Fit") -> None:
        """Refresh the estimates from the frames since the change (``fit``)."""
        self.change, self.sigma = _to_units(fit.x), fit.sd6
        bx = np.zeros(6) if self.before_x is None else self.before_x
        bc = np.zeros((6, 6)) if self.before_cov is None else self.before_cov
        kept = stats.pure_models(fit.x - bx, fit.cov + bc)
        _, cov, self.model = (kept[0][1], kept[0][2], kept[0][3]) if kept else \
            (fit.x - bx, fit.cov + bc, "rotation+translation")
        d, dcov = fit.x - bx, fit.cov + bc
        # the step on the fewest axes of the model the data need (sigmas: the model's, all its axes)
        xs, self.step_axes = stats.sparse_step(d, dcov, _MODEL_AXES[self.model])
        self.step, self.step_sigma = _to_units(xs), _sd_units(cov)
        # a pure rotation and a pure translation both fit (far objects: a turn about y looks like a
        # shift along x): the step is ambiguous, and the other reading is reported beside it
        if len(kept) > 1:
            kept[1] = (kept[1][0], stats.sparse_step(d, dcov, _MODEL_AXES[kept[1][3]])[0], kept[1][2], kept[1][3])
        self.alternative = _to_units(kept[1][1]) if len(kept) > 1 else None
        self.alternative_sigma = _sd_units(kept[1][2]) if len(kept) > 1 else None
        self.alternative_model = kept[1][3] if len(kept) > 1 else ""


@dataclass
class MonitorStatus:
    """One decision (a window). Changes are relative to the calibration, about / along the camera
    axes x, y, z (deg, m); sigmas are the window estimate's 1-sigma; detectable: the smallest
    change along each axis the decision detects with 95 % power (deg, m)."""

    frame: int
    time_s: float
    camera: str
    state: State
    rotation_change_deg: np.ndarray
    translation_change_m: np.ndarray
    rotation_sigma_deg: np.ndarray
    translation_sigma_m: np.ndarray
    detectable_rotation_deg: np.ndarray
    detectable_translation_m: np.ndarray
    message: str
    n_frames: int = 0
    n_pairs: int = 0
    statistic: float = 0.0
    threshold: float = 0.0
    change_frame: int | None = None
    change_time_s: float | None = None
    reason: str = ""
    weak_axes: tuple[str, ...] = ()
    weak_detectable: np.ndarray | None = None  # [6] deg / m: the detectable change weak_axes is judged on
    weak_frames: int = 0  # ... by the test of a window this long (decided within weak_frames + stride)

    def to_dict(self) -> dict:
        d = {k: getattr(self, k) for k in JSON_FIELDS}
        for k, v in d.items():
            if isinstance(v, np.ndarray):
                d[k] = _l(v)
            elif isinstance(v, float):
                d[k] = _f(v)
        d["weak_axes"] = list(self.weak_axes)
        d["weak_axes_detectable"] = None if self.weak_detectable is None else _l(self.weak_detectable)
        d["weak_axes_window"] = self.weak_frames
        d["reason"] = self.reason
        return d


def _f(v: float) -> float | None:
    return float(v) if math.isfinite(v) else None


def _l(a) -> list:
    return [_f(float(v)) for v in np.asarray(a, dtype=np.float64).ravel()]


@dataclass
class _Rec:
    """One frame, linearised at the pose ``x_lin`` (relative to the calibration) and reduced to its
    soft-L1-weighted normal equations in x relative to the calibration: H = J^T W J [6,6],
    g = J^T W r' [6] and c = r'^T W r' with r' = r - J x_lin; n_res informative residuals; box counts."""

    index: int
    time_s: float
    H: np.ndarray
    g: np.ndarray
    c: float
    n_res: int
    n2: int
    n_pairs: int
    cf: CalibFrame | None = None  # kept for the recent frames only: re-linearised at a detected change
    objects: np.ndarray | None = None  # track ids of the matched 3D boxes (None: the frame has none)
    x_lin: np.ndarray | None = None  # the pose it was linearised at (None: the calibration)
    ids3d: np.ndarray | None = None  # the frame's 3D track ids (kept with cf, for the re-linearisation)
    obj: np.ndarray | None = None  # [m] object ids of the frame's matched pairs (track ids; untracked: unique < 0)
    obj_H: np.ndarray | None = None  # [m,6,6] their share of H
    obj_g: np.ndarray | None = None  # [m,6] their share of g
    edges: EdgeRows | None = None  # the unshaped residual rows (``MonitorConfig.iterate_steps``)

    def __post_init__(self) -> None:
        # H, g, c, n_res, n_pairs, n2 as one row: a segment's sums are one stack and one cumsum
        self.row = np.concatenate([np.asarray(self.H, dtype=np.float64).ravel(), np.asarray(self.g, dtype=np.float64),
                                   [self.c, self.n_res, self.n_pairs, self.n2]])


@dataclass
class _Fit:
    x: np.ndarray          # 6-vector, rad / m, relative to the calibration
    cov: np.ndarray        # [6,6]
    n_pairs: int
    n_frames: int
    scale2: float = 1.0    # residual variance factor (1: the noise model holds)

    @property
    def sd6(self) -> np.ndarray:
        d = np.sqrt(np.clip(np.diag(self.cov), 0, None))
        return np.concatenate([np.degrees(d[:3]), d[3:]])


def _sd_units(cov: np.ndarray) -> np.ndarray:
    """1-sigma per axis of a [6,6] covariance (rad / m) in deg / m."""
    d = np.sqrt(np.clip(np.diag(cov), 0, None))
    return np.concatenate([np.degrees(d[:3]), d[3:]])


def _to_units(x: np.ndarray) -> np.ndarray:
    """rad/m 6-vector -> deg/m."""
    return np.concatenate([np.degrees(x[:3]), x[3:]])


class _Sums:
    """Cumulative sums of the frames' normal equations: any run of frames is one subtraction."""

    def __init__(self, recs: list[_Rec]):
        rows = np.stack([q.row for q in recs]) if len(recs) else np.zeros((0, 46))
        C = np.concatenate([np.zeros((1, 46)), np.cumsum(rows, 0)])
        self.H, self.g = C[:, :36].reshape(-1, 6, 6), C[:, 36:42]
        self.c, self.n, self.p, self.n2 = C[:, 42], C[:, 43], C[:, 44], C[:, 45]

    def pairs(self, a: int, b: int) -> int:
        return int(self.p[b] - self.p[a])

    def fit(self, a: int, b: int, inflation: float = 1.0) -> _Fit | None:
        """Weighted least squares over frames [a, b) (soft-L1 weights of each frame's own residuals)."""
        H, g = self.H[b] - self.H[a], self.g[b] - self.g[a]
        n_res, n_pairs = self.n[b] - self.n[a], self.pairs(a, b)
        if n_pairs < 2 or n_res < 7:
            return None
        solved = _solve(H, g)
        if solved is None:
            return None
        Hinv, x = solved
        rss = float(self.c[b] - self.c[a] + x @ g)  # = sum w (r + J x)^2 at the optimum
        s2 = max(rss / max(n_res - 6, 1), 1.0)  # never less noise than the calibration's model
        return _Fit(x, Hinv * s2 * inflation, n_pairs, b - a, s2)


def _scan(sums: _Sums, n: int, min_pairs: int, lo: int = 1, hi: int | None = None) -> tuple[int, float]:
    """Most likely change point among n frames (index of the first frame after it, searched in
    [lo, hi)) and its two-sample statistic (classic covariances)."""
    k = np.arange(max(lo, 1), n if hi is None else min(hi, n))
    if not len(k):
        return n // 2, 0.0
    ok = (sums.p[k] >= min_pairs) & (sums.p[n] - sums.p[k] >= min_pairs)
    if not np.any(ok):
        return n // 2, 0.0
    k = k[ok]
    eye = 1e-12 * np.eye(6)
    Hb, gb = sums.H[k] + eye, sums.g[k]
    Ha, ga = sums.H[n] - sums.H[k] + eye, sums.g[n] - sums.g[k]
    d = np.linalg.solve(Hb, gb[..., None])[..., 0] - np.linalg.solve(Ha, ga[..., None])[..., 0]
    C = np.linalg.inv(Ha) + np.linalg.inv(Hb)
    s = np.einsum("ni,ni->n", d, np.linalg.solve(C, d[..., None])[..., 0])
    j = int(np.argmax(s))
    return int(k[j]), float(s[j])


_EPS = 1e-6


def _solve(H: np.ndarray, g: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """(H^-1, the estimate -H^-1 g) of normal equations; None where H is singular or ill-conditioned."""
    try:
        Hinv = np.linalg.inv(H)
    except np.linalg.LinAlgError:
        return None
    if not np.all(np.isfinite(Hinv)) or np.linalg.cond(H) > 1e14:
        return None
    return Hinv, -Hinv @ g


def _object_sums(recs: list[_Rec], a: int, b: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per object over frames [a, b): sorted ids [K], H [K,6,6], g [K,6]."""
    parts = [q for q in recs[a:b] if q.obj is not None and len(q.obj)]
    if not parts:
        return np.zeros(0, dtype=np.int64), np.zeros((0, 6, 6)), np.zeros((0, 6))
    ids = np.concatenate([q.obj for q in parts])
    u, inv = np.unique(ids, return_inverse=True)
    HG = np.concatenate([np.concatenate([q.obj_H.reshape(-1, 36), q.obj_g], 1) for q in parts])
    out = np.zeros((len(u), 42))
    np.add.at(out, inv, HG)
    return u, out[:, :36].reshape(-1, 6, 6), out[:, 36:]


def _share_table(recs: list[_Rec], bounds: list[int]) -> spread.SegmentTable | None:
    """The history's per-object shares as a ``spread.SegmentTable`` split at ``bounds`` (once per
    decision); None where the pairs are not tracked enough to cluster by object (``spread.tracked``)."""
    parts = [(j, q) for j, q in enumerate(recs) if q.obj is not None and len(q.obj)]
    ids = np.concatenate([q.obj for _, q in parts]) if parts else np.zeros(0, dtype=np.int64)
    if not spread.tracked(ids):
        return None
    return spread.SegmentTable(np.repeat([j for j, _ in parts], [len(q.obj) for _, q in parts]), ids,
                               np.concatenate([_share_rows(q) for _, q in parts]), bounds)


def _share_rows(q: _Rec) -> np.ndarray:
    """A frame's per-object shares as rows [m, 42] (H flattened, g), computed once per frame."""
    hg = getattr(q, "_hg", None)
    if hg is None:
        hg = np.concatenate([np.asarray(q.obj_H).reshape(-1, 36), np.asarray(q.obj_g).reshape(-1, 6)], 1)
        q._hg = hg
    return hg


def _total(H: np.ndarray, g: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return H.sum(0) if len(H) else np.zeros((6, 6)), g.sum(0) if len(g) else np.zeros(6)


def _solve_batch(H: np.ndarray, g: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """x = -H^-1 g, H^-1 and a usable flag per row of a batch of normal equations (a row whose H is
    (near) singular is not usable)."""
    ev = np.linalg.eigvalsh(H)
    ok = (ev[:, 0] > 1e-10 * np.maximum(ev[:, -1], 1e-300)) & np.all(np.isfinite(ev), axis=1)
    Hs = np.where(ok[:, None, None], H, np.eye(6)[None])
    inv = np.linalg.inv(Hs)
    return -np.einsum("kij,kj->ki", inv, g), inv, ok


def _perturbations(pose: Pose) -> tuple[np.ndarray, np.ndarray]:
    """R [13,3,3], t [13,3]: the pose and its central-difference steps of each of the 6 parameters
    (``Pose.moved``: R <- exp([w]x) R, t <- t + dt)."""
    from scipy.spatial.transform import Rotation

    steps = np.zeros((13, 6))
    for k in range(6):
        steps[1 + 2 * k, k], steps[2 + 2 * k, k] = _EPS, -_EPS
    Rw = Rotation.from_rotvec(steps[:, :3]).as_matrix()
    return Rw @ pose.R, pose.t + steps[:, 3:]


class CameraMonitor:
    """The monitor of one camera against its calibration (see the module docstring)."""

    def __init__(self, calibration: CalibrationResult, config: MonitorConfig | None = None, *, camera: str = ""):
        if not getattr(calibration, "success", False):
            raise ValueError(f"monitor: calibration of camera {camera or calibration.camera_name!r} has no pose "
                             f"({calibration.message or 'refused'})")
        if calibration.intrinsics is None:
            raise ValueError(f"monitor: calibration of camera {camera or calibration.camera_name!r} has no intrinsics")
        self.calibration = calibration
        self.config = config or MonitorConfig()
        self.camera = camera or calibration.camera_name or "camera"
        self.pose0 = Pose.parse(calibration, "monitor: calibration")
        self.intr: CameraIntrinsics = calibration.intrinsics
        diag = calibration.diagnostics
        self.noise: NoiseModel = diag.noise_model if diag is not None else DEFAULT_NOISE
        cfg = calibration.config
        box_model = cfg.box_model if cfg is not None else "auto"
        if diag is not None and diag.box_model in ("corners",) and box_model == "auto":
            box_model = "corners"  # the outlines the calibration chose
        self._prep = {"reestimate_yaw": cfg.reestimate_yaw if cfg is not None else "auto", "box_model": box_model}
        self.occlusion = Occlusion(cfg.occlusion_tau, cfg.occlusion_slope) if cfg is not None else Occlusion()
        rs = np.asarray(calibration.rotation_std_deg, dtype=np.float64)
        ts = np.asarray(calibration.translation_std_m, dtype=np.float64)
        # at least the configured floor: the box model's bias differs between traffic scenes
        rs = np.where(np.isfinite(rs), np.maximum(rs, self.config.calibration_sigma_deg), self.config.calibration_sigma_deg)
        ts = np.where(np.isfinite(ts), np.maximum(ts, self.config.calibration_sigma_m), self.config.calibration_sigma_m)
        self.cov_cal = np.diag(np.concatenate([np.radians(rs), ts]) ** 2)
        self.h = self.config.threshold
        self.lam = stats.detectable_lambda(self.h, self.config.power)
        lvl = float(self.config.leave_out_level)
        self.h_out = stats.threshold(lvl, 1, 1) if lvl > 0 else self.h  # without the left-out objects
        self._diffs: deque[float] = deque(maxlen=200)  # successive windows' disagreement (chi2 / 6)
        self._dratios: dict[int, deque[float]] = {}  # per window length: the objects' spread of the difference / stated
        # per tested window length: drift-free decisions' squared standardised change per axis [6]
        self._zs: dict[int, deque[np.ndarray]] = {}
        self._z_at: dict[int, int] = {}  # ... and the frame count at the last one (non-overlapping windows)
        self._scales: deque[float] = deque(maxlen=SCALE_FRAMES)  # frames' robust residual scale
        self._anon = 0  # untracked pairs' object ids (-1, -2, ...)
        # the re-linearised window test's tests: (frame count, window, statistic, re-linearised statistic)
        self.relin_trace: deque[tuple[int, int, float, float]] = deque(maxlen=RELIN_TRACE)
        self._scale_at = [-1, 0, 1.0]  # residual_scale's cache: (frames in, uses since, value)
        # frames keep their unshaped residual rows (``iterate``) where the change test iterates (or a
        # benchmark records them)
        self.keep_edges = int(self.config.iterate_steps) > 0
        self._it_cache: tuple[int, dict] = (-1, {})  # this decision's iterated window fits (``_iterated``)
        self.reset()
        self.events: list[DriftEvent] = []
        self.statuses_seen = {"ok": 0, "drift": 0, "unknown": 0}
        self.weak_seen = dict.fromkeys(AXIS_NAMES, 0)
        self._power: deque[tuple[np.ndarray, int]] = deque(maxlen=POWER_DECISIONS)  # ok decisions' detectable [6], frames
        self.n_seen = 0
        self.last_time: float | None = None
        self.last_status: MonitorStatus | None = None

    # ---------------------------------------------------------------- state
    def reset(self) -> None:
        """Forget the history (the reference) and any latched drift."""
        self.recs: deque[_Rec] = deque(maxlen=self.config.history)
        self.x_lin = np.zeros(6)  # the pose (relative to the calibration) new frames are linearised at
        self.drift: DriftEvent | None = None
        self._since_decision = 0
        self._steps = None
        self._last_pairs: np.ndarray | None = None
        self._last_block: _Fit | None = None
        self._block_end = -1

    def restart(self) -> None:
        """Start afresh after a reference stretch (``Monitor.learn``): history, decisions, events,
        frame count and time forgotten; what the stretch measured (the residual scale, the
        adjacent-window inflation, the per-axis factors of the change test) kept."""
        self.reset()
        self.events = []
        self.statuses_seen = {"ok": 0, "drift": 0, "unknown": 0}
        self.weak_seen = dict.fromkeys(AXIS_NAMES, 0)
        self._power.clear()
        self.n_seen = 0
        self.last_time = None
        self.last_status = None
        self._z_at = {}
        self._block_end, self._last_block = -1, None

    def reference_summary(self) -> dict:
        """Per tested window length: samples of the per-axis factors and the factors (None: too few)."""
        out = {}
        for L in self.config.windows:
            f = self.axis_factors(L)
            out[f"window_{L}"] = {"samples": len(self._zs.get(L, ())),
                                  "variance_factors": None if f is None else dict(zip(AXIS_NAMES, _l(f)))}
        return out

    @property
    def pose_lin(self) -> Pose:
        key = self.x_lin.tobytes()
        cached = getattr(self, "_pose_lin", None)
        if cached is None or cached[0] != key:  # moved only at a detected change: computed once per pose
            cached = self._pose_lin = (key, self.pose0.moved(self.x_lin[:3], self.x_lin[3:]))
        return cached[1]

    def estimated_pose(self) -> Pose:
        """The camera pose the monitor currently believes (the calibration unless a drift was found)."""
        if self.drift is None:
            return self.pose0
        x = np.concatenate([np.radians(self.drift.change[:3]), self.drift.change[3:]])
        return self.pose0.moved(x[:3], x[3:])

    # ---------------------------------------------------------------- frames
    def check_frame(self, frame) -> None:
        """Raise ValueError when ``frame`` does not belong to this calibration (camera name,
        image size or intrinsics differ)."""
        name = getattr(frame, "camera_name", "") or ""
        cal_name = self.calibration.camera_name or ""
        key = getattr(frame, "frame_key", "") or "?"
        if name and cal_name and name != cal_name:
            raise ValueError(f"frame {key}: camera {name!r}, but the calibration is for camera {cal_name!r}")
        fi = getattr(frame, "intrinsics", None)
        if fi is not None:
            a, b = fi, self.intr
            diffs = [f"{k} {getattr(a, k):.6g} vs {getattr(b, k):.6g}" for k in ("fx", "fy", "cx", "cy")
                     if abs(getattr(a, k) - getattr(b, k)) > 1e-3 * max(abs(getattr(b, k)), 1.0)]
            if diffs:
                raise ValueError(f"frame {key}: the frame's intrinsics differ from the calibration's "
                                 f"({'; '.join(diffs)}): another camera, or a changed lens/resolution")
        img = getattr(frame, "image", None)
        size = self.calibration.image_size
        if img is not None and size is not None and np.ndim(img) >= 2 and img.shape[0] > 1:
            got = (int(img.shape[1]), int(img.shape[0]))
            if tuple(size) != got:
                raise ValueError(f"frame {key}: image size {got[0]}x{got[1]} px, but the calibration's is "
                                 f"{size[0]}x{size[1]} px")

    def frame_time(self, frame, index: int) -> float:
        t = getattr(frame, "lidar_time_s", None)
        if t is None:
            t = (getattr(frame, "meta", None) or {}).get("timestamp")
        return float(t) if t is not None else index / self.config.fps

    def _linearise(self, cf: CalibFrame, ids3d: np.ndarray | None = None) -> _Rec:
        """Match the frame at the current pose and reduce its linearised box-edge residuals
        (``edge_term``'s weights and occlusion shaping; all 13 central-difference poses projected in
        one batched ``project_rects`` call) to normal equations, in total and per matched object
        (``ids3d``: the frame's 3D track ids; pairs without one count as objects of their own)."""
        pose = self.pose_lin
        pairs, _, _ = match_frame(cf, self.intr, pose.R, pose.t, gate_iou=self.config.gate_iou,
                                  gate_dist=self.config.gate_dist)
        self._last_pairs = pairs
        if len(pairs) == 0:
            return _Rec(0, 0.0, np.zeros((6, 6)), np.zeros(6), 0.0, 0, cf.n2, 0, ids3d=ids3d)
        term = edge_term([cf], [pairs], self.intr, pose, self.noise, self.occlusion)
        key = self.x_lin.tobytes()
        if self._steps is None or self._steps[0] != key:
            self._steps = (key, *_perturbations(pose))
        _, Rs, ts = self._steps
        whiten = bool(self.config.pair_noise) and isinstance(self.intr, CameraIntrinsics)
        if whiten:  # the corners' pixels too: each edge's extreme outline point (``pairnoise``)
            rects, valid, cu, cv = project_rects(term.outlines, Rs, ts, self.intr, term.size, corner_uv=True)
        else:
            rects, valid = project_rects(term.outlines, Rs, ts, self.intr, term.size)
        raw = np.where(valid[..., None], rects - term.obs[None], term.fallback[None]) * term.w[None]
        e = term.occlusion.shape(raw) if term.occlusion is not None else raw
        e = e.reshape(13, -1)
        r = e[0]
        J = ((e[1::2] - e[2::2]) / (2 * _EPS)).T  # [4n, 6]
        info = np.any(J != 0, axis=1) & np.isfinite(r)  # edges clipped at the border carry no information
        r, J = r[info], J[info]
        if self.config.robust_scale and len(r):  # the residuals' own scale, in noise-model sigmas
            self._scales.append(float(np.median(np.abs(r))) / 0.6745)
        fs = F_SCALE * self.residual_scale
        w = 1.0 / np.sqrt(1.0 + (r / fs) ** 2)
        rr = r - J @ self.x_lin  # x relative to the calibration
        # each matched object's share (rows are 4 edges per pair, pair-major)
        obj = self._pair_objects(cf, pairs, ids3d)
        uo, inv = np.unique(obj, return_inverse=True)
        row_obj = inv[np.repeat(np.arange(len(pairs)), 4)[info]]
        if whiten:
            H, g, c, oH, og = self._whitened(cf, pairs, term, pose, (raw, cu[0], cv[0]), (info, rr, J, w), inv)
        else:
            JW = J * w[:, None]
            H, g, c = J.T @ JW, JW.T @ rr, float(np.sum(w * rr * rr))
            P = np.zeros((len(uo), len(r)))
            P[row_obj, np.arange(len(r))] = 1.0
            oH = (P @ (JW[:, :, None] * J[:, None, :]).reshape(len(r), 36)).reshape(-1, 6, 6)
            og = P @ (JW * rr[:, None])
        edges = None
        if self.keep_edges:  # the unshaped residuals and their Jacobian (``iterate.EdgeRows``: the change
            raw = raw.reshape(13, -1)  # test re-weighted and re-shaped at any pose change without projecting)
            Jraw = ((raw[1::2] - raw[2::2]) / (2 * _EPS)).T[info]
            e0 = raw[0][info] - Jraw @ self.x_lin  # the unshaped residual at the calibration (linear model)
            sgn = np.broadcast_to(INWARD, (len(pairs), 4)).reshape(-1)[info]
            edges = EdgeRows(e0, Jraw, sgn, uo[row_obj], fs)
        return _Rec(0, 0.0, H, g, c, int(info.sum()), cf.n2, int(len(pairs)), x_lin=self.x_lin.copy(),
                    ids3d=ids3d, obj=uo, obj_H=oH, obj_g=og, edges=edges)

    def _whitened(self, cf: CalibFrame, pairs: np.ndarray, term, pose: Pose, proj: tuple, rows: tuple,
                  pair_obj: np.ndarray) -> tuple:
        """(H, g, c, per-object H, per-object g) of the frame's rows whitened per pair
        (``MonitorConfig.pair_noise``, ``pairnoise``): the soft-L1-weighted rows ``sqrt(w) r`` of each
        pair's four edges times ``L^-1`` of the pair's covariance. ``proj`` = (the 13 poses' unshaped
        weighted residuals [13,n,4], the corners' u, v [n,S] at the pose), ``rows`` = (informative edges
        [4n], their residuals relative to the calibration, Jacobian and soft-L1 weights),
        ``pair_obj`` [n]: each pair's object (0, 1, ..., every one present)."""
        raw, u, v = proj
        info, rr, J, w = rows
        n = len(pairs)
        raw = raw.reshape(13, n, 4)
        Jt = np.stack([(raw[1 + 2 * k] - raw[2 + 2 * k]) / (2 * _EPS) for k in (3, 4, 5)], -1)  # [n,4,3]
        big = np.where(np.isfinite(u), u, np.inf), np.where(np.isfinite(v), v, np.inf)
        small = np.where(np.isfinite(u), u, -np.inf), np.where(np.isfinite(v), v, -np.inf)
        idx = np.stack([np.argmin(big[0], 1), np.argmin(big[1], 1), np.argmax(small[0], 1), np.argmax(small[1], 1)], 1)
        ext = np.take_along_axis(term.outlines, idx[..., None], axis=1)  # [n,4,3] each edge's extreme point
        v_c, v_s = pairnoise.parts(term.obs, term.outlines, self.intr, pose, self.noise, term.w[:, 0])
        m = info.reshape(n, 4)
        Linv = pairnoise.pair_whitening(pairnoise.pair_covariance(Jt, pose.R, ext, cf.boxes3d[pairs[:, 1]], v_c, v_s, m))
        sw = np.sqrt(w)
        r4, J4 = np.zeros(4 * n), np.zeros((4 * n, 6))
        r4[info], J4[info] = sw * rr, sw[:, None] * J
        rho = np.einsum("nef,nf->ne", Linv, r4.reshape(n, 4))
        Jw = np.einsum("nef,nfk->nek", Linv, J4.reshape(n, 4, 6))
        Hp, gp = np.einsum("nej,nek->njk", Jw, Jw), np.einsum("nej,ne->nj", Jw, rho)
        n_obj = int(pair_obj.max()) + 1
        oH, og = np.zeros((n_obj, 6, 6)), np.zeros((n_obj, 6))
        np.add.at(oH, pair_obj, Hp)
        np.add.at(og, pair_obj, gp)
        return oH.sum(0), og.sum(0), float(np.sum(rho * rho)), oH, og

    def _pair_objects(self, cf: CalibFrame, pairs: np.ndarray, ids3d: np.ndarray | None) -> np.ndarray:
        """Object id of each matched pair: the 3D box's track id, else a fresh negative id (an
        object seen once)."""
        out = np.full(len(pairs), -1, dtype=np.int64)
        if ids3d is not None and len(pairs):
            cols = cf.idx3d[pairs[:, 1]]
            ok = cols < len(ids3d)
            out[ok] = ids3d[cols[ok]]
        bad = out < 0
        if np.any(bad):
            out[bad] = -(self._anon + 1 + np.arange(int(bad.sum())))
            self._anon += int(bad.sum())
        return out

    def _prepare(self, frame) -> CalibFrame:
        """The frame's boxes as the cost's outlines. Yaw-less [M,6] 3D boxes with a point cloud get
        their yaw from the points cheaply (``fastyaw.fit_yaw_batch``: ``fit_yaw_to_points``'s cost
        for all boxes at once on a 4 deg heading grid refined by a parabola) and their 8 corners as the
        outline (a heading the points leave ambiguous weighs as an open-yaw outline, as in
        ``prepare_frames``): one consistent box model for every frame, whatever the calibration
        used, at a few ms per frame instead of the yaw fit, scan pattern and point hulls of
        ``prepare_frames`` (~60 ms at A9 density)."""
        b3 = np.asarray(frame.bboxes_3d)
        meta = getattr(frame, "meta", None) or {}
        m7 = meta.get("box7")
        pts = getattr(frame, "point_cloud", None)
        yawless = (b3.ndim == 2 and b3.shape[1] == 6 and len(b3) > 0
                   and not (m7 is not None and np.shape(m7) == (len(b3), 7))
                   and self._prep["reestimate_yaw"] not in ("never", False))
        if yawless and pts is not None and np.ndim(pts) == 2 and len(pts):
            box7 = as_box7(check_boxes3d(b3, "bboxes_3d"))
            if np.all(np.isfinite(box7)):
                # only the boxes the camera may see (at the pose frames are matched at) need a yaw
                pose = self.pose_lin
                seen = maybe_in_view(box7, pose.R, pose.t, self.intr, self._size(frame))
                b7, ambiguous = np.array(box7, dtype=np.float64), np.ones(len(box7), dtype=bool)
                if np.any(seen):
                    b7[seen], ambiguous[seen] = fit_yaw_batch(box7[seen], pts)
                f2 = replace(frame, bboxes_3d=b7, point_cloud=np.zeros((0, 3), np.float32),
                             meta={k: v for k, v in meta.items() if k != "box7"})
                cf = prepare_frames([f2], self.intr, reestimate_yaw="never", box_model="corners")[0][0]
                amb = ambiguous[cf.idx3d]
                sig = np.where(amb, YAW_OPEN_SIGMA * np.abs(cf.boxes3d[:, 3] - cf.boxes3d[:, 4]), 0.0)
                return replace(cf, yaw_ambiguous=amb, outline_sigma_m=sig, points=None, image=None)
        cfs, _, _ = prepare_frames([frame], self.intr, **self._prep)
        return replace(cfs[0], points=None, image=None)

    def _size(self, frame) -> tuple[int, int] | None:
        """(width, height) px of the frame's image: the calibration's, else the frame's intrinsics'."""
        size = self.calibration.image_size
        if size is not None:
            return int(size[0]), int(size[1])
        fi = getattr(frame, "intrinsics", None)
        w, h = getattr(fi, "width", None), getattr(fi, "height", None)
        return (int(w), int(h)) if w and h else None

    def update(self, frame, index: int | None = None) -> MonitorStatus | None:
        """Add one frame (an ``xcalib.types.Frame`` of this camera); returns the decision when one
        is due (every ``stride`` frames once ``window`` frames are in), else None."""
        index = self.n_seen if index is None else int(index)
        self.check_frame(frame)
        t = self.frame_time(frame, index)
        if self.last_time is not None and t < self.last_time:
            raise ValueError(f"frame {getattr(frame, 'frame_key', index)!r}: time {t:.3f} s is before the previous "
                             f"frame's {self.last_time:.3f} s; frames must arrive in time order")
        self.last_time = t
        cf = self._prepare(frame)
        ids = getattr(frame, "track_ids_3d", None)
        ids = None if ids is None else np.asarray(ids, dtype=np.int64).ravel()
        rec = self._linearise(cf, ids)
        rec.index, rec.time_s, rec.cf = index, t, cf
        if ids is not None and rec.n_pairs and self._last_pairs is not None:
            cols = cf.idx3d[self._last_pairs[:, 1]]
            if len(ids) > int(cols.max()):
                rec.objects = np.unique(ids[cols][ids[cols] >= 0])
        self.recs.append(rec)
        keep = max(self.config.windows) + self.config.stride
        if len(self.recs) > keep:
            self.recs[-keep - 1].cf = None
            self.recs[-keep - 1].ids3d = None
        self.n_seen += 1
        self._since_decision += 1
        if len(self.recs) < self.config.window or self._since_decision < self.config.stride:
            return None
        self._since_decision = 0
        st = self._decide()
        self.statuses_seen[st.state] += 1
        for a in st.weak_axes:
            self.weak_seen[a] += 1
        if st.state == "ok" and st.weak_detectable is not None and np.all(np.isfinite(st.weak_detectable)):
            self._power.append((np.array(st.weak_detectable, dtype=np.float64), st.weak_frames + self.config.stride))
        self.last_status = st
        return st

    # ---------------------------------------------------------------- decisions
    def _status(self, state: State, fit: _Fit | None, message: str, reason: str, stat: float = 0.0,
                det: np.ndarray | None = None, n_frames: int = 0,
                weak_det: tuple[np.ndarray, int] | None = None) -> MonitorStatus:
        """``weak_det``: (detectable change [6] deg / m, window frames) that ``weak_axes`` is judged
        on (default: ``det`` over ``n_frames``)."""
        last = self.recs[-1]
        x = _to_units(fit.x) if fit is not None else np.full(6, np.nan)
        sd = fit.sd6 if fit is not None else np.full(6, np.nan)
        det = np.full(6, np.nan) if det is None else det
        wdet, wframes = weak_det if weak_det is not None else (det, n_frames)
        weak = self.weak_axes(wdet)
        if weak and state == "ok":
            message += f"; {_weak_message(weak, wdet, wframes + self.config.stride)}"
        ev = self.drift
        return MonitorStatus(frame=last.index, time_s=last.time_s, camera=self.camera, state=state,
                             rotation_change_deg=x[:3], translation_change_m=x[3:], rotation_sigma_deg=sd[:3],
                             translation_sigma_m=sd[3:], detectable_rotation_deg=det[:3],
                             detectable_translation_m=det[3:], message=message,
                             n_frames=n_frames, n_pairs=fit.n_pairs if fit is not None else 0,
                             statistic=float(stat), threshold=self.h,
                             change_frame=None if ev is None else ev.change_frame,
                             change_time_s=None if ev is None else ev.change_time_s, reason=reason,
                             weak_axes=weak, weak_detectable=wdet, weak_frames=int(wframes))

    def weak_axes(self, det: np.ndarray) -> tuple[str, ...]:
        """Axes ("rx" .. "tz") whose detectable change ``det`` (deg / m, 95 % power) exceeds the
        configured target change (NaN: no decision, none named)."""
        tgt = np.array([self.config.target_deg] * 3 + [self.config.target_m] * 3)
        with np.errstate(invalid="ignore"):
            return tuple(a for a, v, t in zip(AXIS_NAMES, det, tgt) if v > t)

    def _evidence(self, recs: list[_Rec]) -> tuple[str, str] | None:
        """(reason code, message) when the segment has too few matched objects, else None."""
        cfg = self.config
        n2 = sum(q.n2 for q in recs)
        npairs = sum(q.n_pairs for q in recs)
        span = f"the last {len(recs)} frames ({recs[-1].time_s - recs[0].time_s + 1.0 / cfg.fps:.1f} s)"
        if n2 == 0:
            return "no_objects", f"no objects detected by the camera in {span}"
        if npairs < cfg.min_pairs:
            frac = npairs / max(n2, 1)
            extra = "" if frac >= 0.3 else (f"; only {100 * frac:.0f} % of the {n2} 2D boxes match the projected 3D "
                                            "boxes (the camera may have moved far, or the 3D detections are missing)")
            return "too_few_objects", (f"too few objects: {npairs} matched 2D/3D box pairs in {span} "
                                       f"(need >= {cfg.min_pairs}){extra}")
        tracked = [q.objects for q in recs if q.objects is not None]
        if tracked and len(tracked) == sum(1 for q in recs if q.n_pairs):
            n_obj = len(np.unique(np.concatenate(tracked)))
            if n_obj < cfg.min_objects:
                return "too_few_objects", (f"too few objects: {npairs} matched pairs in {span} are {n_obj} distinct "
                                           f"object(s) (track ids; need >= {cfg.min_objects}): one object's 3D box "
                                           "error would pass for a change")
        return None

    @property
    def residual_scale(self) -> float:
        """The residuals' robust scale relative to the calibration's noise model (``robust_scale``):
        the median over the last SCALE_FRAMES frames of each frame's median |r| / 0.6745, at least
        1. The soft-L1 loss bends at ``F_SCALE`` times it, so a detector noisier than the model
        (4 px boxes: 3-4) is not treated as outliers, whose down-weighting would shrink every
        estimated change (to about half of a 10 cm shift in one linearisation)."""
        if self._scale_at[0] != len(self._scales) or self._scale_at[1] >= SCALE_EVERY:  # refreshed every few frames
            self._scale_at = [len(self._scales), 0, max(1.0, float(np.median(self._scales))) if self._scales else 1.0]
        self._scale_at[1] += 1
        return self._scale_at[2]

    @property
    def inflation(self) -> float:
        """Factor on every covariance: how much more successive windows disagree than their
        covariances say (75th percentile of d^T C^-1 d / 6 over adjacent non-overlapping windows,
        relative to its value for chi-square 6, at least ``min_inflation``: robust to the rare real change); INFLATION_PRIOR until MIN_DIFFS pairs are in."""
        if len(self._diffs) < MIN_DIFFS:
            return INFLATION_PRIOR
        return max(float(self.config.min_inflation), float(np.quantile(self._diffs, 0.75)) / CHI2_6_Q75_OVER_6)

    def axis_factors(self, length: int) -> np.ndarray | None:
        """Per axis (rx .. tz), the factor on the variance the change test of a ``length``-frame
        window states, measured on this stream's drift-free decisions: each sample is the test's
        change divided by its stated 1-sigma per axis, one per non-overlapping recent window
        (AXIS_SAMPLES kept); the factor is the upper ``reference_confidence`` bound of the mean
        square (m samples: mean * m / chi2_m quantile), at least MIN_AXIS_FACTOR. None until
        ``reference_samples`` samples are in (or when off): the single ``inflation`` holds then.
        The box model's errors do not spread evenly over the axes (one site's traffic states
        ry, rz, tx, tz 1.6-2.6 times too wide, rx and ty right): one scale cannot fit them."""
        k = int(self.config.reference_samples)
        z = self._zs.get(int(length))
        if k == 0 or z is None or len(z) < k:
            return None
        Z = np.asarray(z)
        v = stats.variance_upper(Z.sum(0), len(Z), self.config.reference_confidence)
        return np.maximum(v, MIN_AXIS_FACTOR)

    def _cov_scale(self, length: int, phi: float) -> tuple[np.ndarray, bool]:
        """(1-sigma factors per axis [6], calibrated?) for the test of a ``length``-frame window."""
        f = self.axis_factors(length)
        return (np.sqrt(f), True) if f is not None else (np.full(6, math.sqrt(phi)), False)

    def _sample_axes(self, pending: list[tuple[int, np.ndarray, np.ndarray]]) -> None:
        """Keep a drift-free decision's tests as samples of ``axis_factors`` (one per window length
        per ``length`` frames)."""
        for L, d, C in pending:
            if self.n_seen - self._z_at.get(L, -(10 ** 9)) < L:
                continue
            sd2 = np.diag(C)
            if not np.all(np.isfinite(d)) or not np.all(sd2 > 0):
                continue
            self._zs.setdefault(L, deque(maxlen=AXIS_SAMPLES)).append(d * d / sd2)
            self._z_at[L] = self.n_seen

    def _update_inflation(self, sums: _Sums, n: int) -> None:
        W = self.config.window
        if self.n_seen - self._block_end < W:
            return
        fit = sums.fit(n - W, n) if sums.pairs(n - W, n) >= self.config.min_pairs else None
        prev = self._last_block if self._block_end == self.n_seen - W else None
        if fit is not None and prev is not None:
            self._diffs.append(stats.chi2_stat(fit.x - prev.x, fit.cov + prev.cov) / stats.DOF)
        self._last_block, self._block_end = fit, self.n_seen

    def _decide(self) -> MonitorStatus:
        cfg = self.config
        recs = list(self.recs)
        n = len(recs)
        sums = _Sums(recs)
        self._update_inflation(sums, n)
        if self.drift is not None:
            return self._decide_latched(recs, sums)
        phi = self.inflation
        W = cfg.window
        lengths = [L for L in cfg.test_windows if L <= n] or [min(cfg.test_windows)]
        longest = max([L for L in cfg.windows if L <= n] or [W])
        why = self._evidence(recs[-longest:])
        if why is not None:
            return self._status("unknown", None, why[1], why[0], n_frames=longest)
        fit_r = sums.fit(n - longest, n)
        if fit_r is None:
            return self._status("unknown", None, "the matched boxes do not determine the pose (degenerate geometry)",
                                "degenerate", n_frames=longest)
        best_stat, best_len, det, det_t = 0.0, longest, None, None
        tests: list[tuple[float, int, _Fit, _Fit | None, np.ndarray, Any]] = []
        pending: list[tuple[int, np.ndarray, np.ndarray]] = []  # samples of axis_factors
        # weak axes are judged on the longest window tested within target_frames of a change
        L_t = max([L for L in lengths if L + cfg.stride <= cfg.target_frames] or [lengths[0]])
        table = _share_table(recs, [n - L for L in lengths]) if cfg.difference_quantile > 0 else None
        for L in lengths:  # the change-point tests: each recent segment against the frames before it
            if sums.pairs(0, n - L) < cfg.min_pairs or sums.pairs(n - L, n) < cfg.min_pairs:
                continue
            fa, fb = sums.fit(n - L, n), sums.fit(0, n - L)
            oa = None
            if cfg.iterate_steps > 0 and fa is not None:  # the recent window's own estimate (``iterate``)
                fa, oa = self._iterated(recs, n - L, n) or (fa, None)
            if fa is None or fb is None:
                continue
            if table is not None and oa is None:  # the objects' own spread of the difference
                k_d = self._difference_scale(recs, n - L, fa, fb, table)
                fa, fb = replace(fa, cov=fa.cov * k_d), replace(fb, cov=fb.cov * k_d)
            S, _ = self._cov_scale(L, phi)
            pending.append((L, fa.x - fb.x, fa.cov + fb.cov))
            C = (fa.cov + fb.cov) * np.outer(S, S)
            s = stats.chi2_stat(fa.x - fb.x, C)
            if L == longest:
                det = stats.detectable_change(C, self.lam)
            if L == L_t:
                det_t = stats.detectable_change(C, self.lam)
            tests.append((s, L, fa, fb, S, oa))
            if s > best_stat:
                best_stat, best_len = s, L
        S_r, _ = self._cov_scale(longest, phi)
        oa_r = None
        if cfg.iterate_steps > 0:
            fit_r, oa_r = self._iterated(recs, n - longest, n) or (fit_r, None)
        raw_r, fit_r = fit_r, replace(fit_r, cov=fit_r.cov * np.outer(S_r, S_r))
        s0 = stats.chi2_stat(fit_r.x, fit_r.cov + self.cov_cal)  # the offset from the calibration itself
        tests.append((s0, 0, raw_r, None, S_r, oa_r))
        if s0 > best_stat:
            best_stat, best_len = s0, 0
        det = _to_units(det if det is not None else stats.detectable_change(fit_r.cov, self.lam))
        weak_det = (_to_units(det_t), L_t) if det_t is not None else None
        held = ""
        if best_stat > self.h:  # an alarm needs the change to hold without its most influential objects
            for s, L, fa, fb, S, oa in sorted(tests, key=lambda q: -q[0]):
                if s <= self.h:
                    break
                s_lo, dropped = self._without_objects(recs, n - (L or longest), fa, fb, S, oa)
                if s_lo > self.h_out:
                    return self._alarm(recs, sums, s, L, det)
                held = held or (f"; a change (statistic {s:.1f}) rests on object(s) "
                                f"{', '.join(str(o) for o in dropped)}: without them {s_lo:.1f} < {self.h_out:.1f}")
            best_stat = min(best_stat, self.h)
        if cfg.relinearise_band > 0:
            st = self._relinearised_tests(recs, sums, tests, longest, det)
            if st is not None:
                return st
        self._sample_axes(pending)
        if np.any(det[:3] > cfg.max_detectable_deg) or np.any(det[3:] > cfg.max_detectable_m):
            axes = [f"{a} {v:.2f} {'deg' if i < 3 else 'm'}" for i, (a, v) in
                    enumerate(zip(("rx", "ry", "rz", "tx", "ty", "tz"), det))
                    if v > (cfg.max_detectable_deg if i < 3 else cfg.max_detectable_m)]
            return self._status("unknown", fit_r, "the matched boxes constrain the pose too weakly to rule out a "
                                f"change: detectable {', '.join(axes)} (limit {cfg.max_detectable_deg:g} deg / "
                                f"{cfg.max_detectable_m:g} m)", "weak_geometry", best_stat, det, longest, weak_det)
        return self._status("ok", fit_r, f"no change (statistic {best_stat:.1f} < threshold {self.h:.1f}){held}",
                            "one_object" if held else "", best_stat, det, longest, weak_det)

    def _difference_scale(self, recs: list[_Rec], a: int, fa: _Fit, fb: _Fit, table: spread.SegmentTable) -> float:
        """The factor on both segments' covariances of the test of frames [a, n) against [0, a)
        (``MonitorConfig.difference_quantile``): this test's ``spread.difference_ratio`` joins the last
        DIFF_SAMPLES of its window length; their ``difference_quantile`` quantile or this test's own
        ratio, the larger, at most 1 (1 until DIFF_MIN_SAMPLES are in, or where the ratio cannot be formed)."""
        n = len(recs)
        after, before = table.split(a)
        r = spread.difference_ratio(after, before, fa.x, fb.x, fa.cov + fb.cov)
        pool = self._dratios.setdefault(n - a, deque(maxlen=DIFF_SAMPLES))
        if np.isfinite(r):
            pool.append(r)
        if len(pool) < DIFF_MIN_SAMPLES or not np.isfinite(r):
            return 1.0
        # the stream's own (pooled) scale, but never below this test's own spread: a window whose objects
        # disagree (3D boxes wrong unlike each other: not a move of the camera) keeps its wider covariance
        return min(1.0, max(float(np.quantile(np.asarray(pool), self.config.difference_quantile)), r))

    def _relinearised_tests(self, recs: list[_Rec], sums: _Sums, tests: list, longest: int,
                            det: np.ndarray) -> MonitorStatus | None:
        """The re-linearised window test (``MonitorConfig.relinearise_band``): the tests of this
        decision whose statistic reached ``relinearise_band`` times the threshold (at most
        ``relinearise_windows``, highest first) are repeated with their recent window matched and
        linearised again at the window's own estimate (``_window_relinearised``; the frames before
        it stay at the calibration: their estimate is near it); the refit's statistic against
        ``relinearise_factor`` times the threshold (and, with the most influential objects left
        out, ``relinearise_factor`` times the leave-out threshold) raises the alarm. Every such
        test is kept in ``relin_trace``. None: no alarm."""
        cfg = self.config
        n = len(recs)
        lo, fac = cfg.relinearise_band * self.h, cfg.relinearise_factor
        todo = sorted((q for q in tests if q[0] >= lo), key=lambda q: -q[0])[:int(cfg.relinearise_windows)]
        for s, L, fa, fb, S, _ in todo:
            a = n - (L or longest)
            got = self._window_relinearised(recs, a, fa)
            if got is None:
                continue
            out, fr = got
            SS = np.outer(S, S)
            if fb is not None:
                s_r = stats.chi2_stat(fr.x - fb.x, (fr.cov + fb.cov) * SS)
            else:
                s_r = stats.chi2_stat(fr.x, fr.cov * SS + self.cov_cal)
            self.relin_trace.append((self.n_seen, int(L), float(s), float(s_r)))
            if s_r > fac * self.h:
                s_lo, _ = self._without_objects(out, a, fr, fb, S)
                if s_lo > fac * self.h_out:
                    return self._alarm(recs, sums, s_r, L, det)
        return None

    def _window_relinearised(self, recs: list[_Rec], a: int, fit: _Fit) -> tuple[list[_Rec], _Fit] | None:
        """Frames [a, n) matched and linearised again at ``fit``'s estimate (RELIN_WINDOW_ROUNDS
        rounds, each at the last refit), as copies: the history, the linearisation pose and the
        residual scale are left as they were. None where a frame no longer holds its boxes."""
        n = len(recs)
        if a < 0 or any(recs[j].cf is None for j in range(a, n)):
            return None
        saved = (self.x_lin, list(self._scales), list(self._scale_at), self._last_pairs)
        out, x, fr = list(recs), fit.x, None
        try:
            for _ in range(RELIN_WINDOW_ROUNDS):
                self.x_lin = np.array(x, dtype=np.float64)
                for j in range(a, n):
                    q = recs[j]
                    new = self._linearise(q.cf, q.ids3d)
                    new.index, new.time_s, new.cf, new.objects = q.index, q.time_s, q.cf, q.objects
                    out[j] = new
                f = _Sums(out).fit(a, n)
                if f is None:
                    return None
                fr, x = f, f.x
        finally:
            self.x_lin, self._last_pairs = saved[0], saved[3]
            self._scales.clear()
            self._scales.extend(saved[1])
            self._scale_at = saved[2]
        return out, fr

    def _iterated(self, recs: list[_Rec], a: int, n: int) -> tuple[_Fit, Any] | None:
        """The fit of frames [a, n) iterated ``iterate_steps`` Gauss-Newton steps on their unshaped
        residual rows (``iterate.iterated_fit``: the occlusion shaping and the soft-L1 weights at the
        window's own estimate, not at the calibration's residuals), its covariance from the normal
        equations there (times the residual variance factor, at least 1), and a function giving each
        object's share of them (for the leave-objects-out guard, which needs them only at an alarm).
        None where a frame lacks its rows or the fit is singular. One fit per window and decision."""
        key = (recs[-1].index, a, n)
        if self._it_cache[0] != key[0]:
            self._it_cache = (key[0], {})
        if key not in self._it_cache[1]:
            self._it_cache[1][key] = self._iterated_fit(recs, a, n)
        return self._it_cache[1][key]

    def _iterated_fit(self, recs: list[_Rec], a: int, n: int) -> tuple[_Fit, Any] | None:
        if any(q.edges is None for q in recs[a:n] if q.n_pairs):
            return None
        rows = stack_rows([q.edges for q in recs[a:n]])
        m = len(rows[0])
        if m < 7:
            return None
        tau, slope = (self.occlusion.tau, self.occlusion.slope) if self.occlusion is not None else (np.inf, 1.0)
        got = iterated_fit(rows, self.config.iterate_steps, tau, slope)
        if got is None:
            return None
        xl, H, g, c = got
        solved = _solve(H, g)
        if solved is None:
            return None
        Hinv, x = solved
        s2 = max(float(c + x @ g) / max(m - 6, 1), 1.0)
        n_pairs = int(sum(q.n_pairs for q in recs[a:n]))
        return _Fit(x, Hinv * s2, n_pairs, n - a, s2), lambda: object_shares(rows, xl, tau, slope)

    def _without_objects(self, recs: list[_Rec], a: int, fa: _Fit, fb: _Fit | None,
                         scale: np.ndarray | None = None, obj_a: Any = None) -> tuple[float, list[int]]:
        """The test of the recent frames [a, n) (``fa``) against the frames before them (``fb``; None:
        against the calibration) with the ``leave_out_objects`` most influential objects left out
        of both, one at a time (each the one whose removal lowers the statistic most); returns the
        statistic and the objects left out. An object left out that leaves too little to fit gives 0.
        ``scale``: 1-sigma factors per axis on the two-segment covariance (the test's calibration)."""
        n = len(recs)
        k_out = int(self.config.leave_out_objects)
        ids_a, Ha, ga = _object_sums(recs, a, n) if obj_a is None else obj_a()  # (obj_a: an iterated window's)
        Ta, ta = _total(Ha, ga)
        if fb is not None:
            ids_b, Hb, gb = _object_sums(recs, 0, a)
            Tb, tb = _total(Hb, gb)
            pos = np.searchsorted(ids_b, ids_a)
            pos = np.clip(pos, 0, max(len(ids_b) - 1, 0))
            inb = (len(ids_b) > 0) & (ids_b[pos] == ids_a) if len(ids_b) else np.zeros(len(ids_a), bool)
            Hb_a = np.where(inb[:, None, None], Hb[pos] if len(ids_b) else 0.0, 0.0)
            gb_a = np.where(inb[:, None], gb[pos] if len(ids_b) else 0.0, 0.0)
        fac_a = float(np.trace(fa.cov @ (Ta))) / 6.0  # the fit's covariance is inv(H) times this factor
        fac_b = float(np.trace(fb.cov @ Tb)) / 6.0 if fb is not None else 0.0
        SS = np.ones((6, 6)) if scale is None else np.outer(scale, scale)
        stat, dropped = stats.chi2_stat(fa.x - (fb.x if fb is not None else 0.0),
                                        (fa.cov + fb.cov) * SS if fb is not None else fa.cov * SS + self.cov_cal), []
        alive = np.ones(len(ids_a), dtype=bool)
        for _ in range(k_out):
            if not np.any(alive):
                break
            HA, gA = Ta[None] - Ha, ta[None] - ga
            xa, ca, oka = _solve_batch(HA, gA)
            if fb is not None:
                HB, gB = Tb[None] - Hb_a, tb[None] - gb_a
                xb, cb, okb = _solve_batch(HB, gB)
                d, C = xa - xb, (ca * fac_a + cb * fac_b) * SS[None]
                ok = oka & okb
            else:
                d, C, ok = xa, ca * fac_a * SS[None] + self.cov_cal[None], oka
            s_k = np.zeros(len(ids_a))
            if np.any(ok):
                s_k[ok] = np.einsum("ki,ki->k", d[ok], np.linalg.solve(C[ok], d[ok][..., None])[..., 0])
            s_k[~alive] = np.inf
            j = int(np.argmin(s_k))
            stat = float(s_k[j])
            dropped.append(int(ids_a[j]))
            alive[j] = False
            Ta, ta = Ta - Ha[j], ta - ga[j]
            if fb is not None:
                Tb, tb = Tb - Hb_a[j], tb - gb_a[j]
            if stat <= self.h_out:
                break
        return stat, dropped

    def _alarm(self, recs: list[_Rec], sums: _Sums, stat: float, length: int, det: np.ndarray) -> MonitorStatus:
        cfg = self.config
        n = len(recs)
        phi = self.inflation
        k, _ = _scan(sums, n, cfg.min_pairs)
        if length == 0 and k < n // 4:  # an offset from the calibration with no change point inside the history
            k = 0
        fb = _Sums(recs).fit(0, k, phi) if k > 0 else None
        fa = self._refit_after(recs, k, phi)
        ev = DriftEvent(self.camera, recs[-1].index, recs[-1].time_s, recs[k].index, recs[k].time_s, np.zeros(6),
                        np.zeros(6), np.zeros(6), np.zeros(6), "", float(stat),
                        None if fb is None else fb.x, None if fb is None else fb.cov)
        ev.update(fa)
        self.events.append(ev)
        self.drift = ev
        st = self._status("drift", fa, _drift_message(ev), "change", stat, det, n - k)
        if cfg.latch:  # new frames are matched / linearised at the moved pose; the history stays (the
            self.x_lin = np.array(fa.x, dtype=np.float64)  # change point is refined as frames come in)
        else:
            self.reset()
        return st

    def _refit_after(self, recs: list[_Rec], k: int, phi: float) -> _Fit:
        """The pose since the change point (``_relinearised``), the monitor's state restored after."""
        n = len(recs)
        lin = _Sums(recs)
        fa = lin.fit(k, n, phi) or lin.fit(n - self.config.window, n, phi)
        if fa is not None:
            fa = self._relinearised(recs, k, fa, phi)
        if not self.config.latch:
            self.x_lin = np.zeros(6)
        return fa

    def _relinearised(self, recs: list[_Rec], k: int, fit: _Fit, phi: float) -> _Fit:
        """The fit of frames [k, n) after matching and linearising again, at the estimate, every frame
        that still has its boxes and was linearised more than RELIN_TOL sigma away from it (at most
        RELIN_ITERS rounds): the occlusion shaping of the cost bends at 1.5 sigma, so a linearisation
        far from the answer (the calibration, for the frames of a change) pulls the estimate towards
        itself. ``recs`` and the history are updated."""
        n = len(recs)
        sd = np.sqrt(np.clip(np.diag(fit.cov), 1e-18, None))
        for _ in range(RELIN_ITERS):
            todo = [j for j in range(k, n) if recs[j].cf is not None and
                    (recs[j].x_lin is None or np.max(np.abs(recs[j].x_lin - fit.x) / sd) > RELIN_TOL)]
            if not todo:
                break
            self.x_lin = np.array(fit.x, dtype=np.float64)
            for j in todo:
                q = recs[j]
                new = self._linearise(q.cf, q.ids3d)
                new.index, new.time_s, new.cf, new.objects = q.index, q.time_s, q.cf, q.objects
                recs[j] = new
            fit = _Sums(recs).fit(k, n, phi) or fit
        self.recs.clear()  # the deque holds the re-linearised records too
        self.recs.extend(recs)
        return fit

    def _decide_latched(self, recs: list[_Rec], sums: _Sums) -> MonitorStatus:
        """A latched drift: while the frames before the change are in the history, the change point
        is searched again near the one found (within ``2 window`` frames: every new frame sharpens
        it, and a change point found early would mix frames from before the change into the
        estimate), the frames before it refitted; the change is the fit of the frames since."""
        ev = self.drift
        cfg = self.config
        n = len(recs)
        lin = _Sums(recs)
        k = next((j for j, q in enumerate(recs) if q.index >= ev.change_frame), n)
        if 0 < k < n:
            W2 = 2 * cfg.window
            k, _ = _scan(sums, n, cfg.min_pairs, k - W2, k + W2 + 1)
            fb = lin.fit(0, k, self.inflation) if sums.pairs(0, k) >= cfg.min_pairs else None
            if fb is not None:
                ev.before_x, ev.before_cov = fb.x, fb.cov
                ev.change_frame, ev.change_time_s = recs[k].index, recs[k].time_s
        else:
            k = 0
        fit = lin.fit(k, n, self.inflation) if sums.pairs(k, n) >= cfg.min_pairs else None
        det, s = None, 0.0
        if fit is not None:
            fit = self._relinearised(recs, k, fit, self.inflation)
            ev.update(fit)
            self.x_lin = np.array(fit.x, dtype=np.float64)
            det = _to_units(stats.detectable_change(fit.cov + self.cov_cal, self.lam))
            s = stats.chi2_stat(fit.x, fit.cov + self.cov_cal)
        return self._status("drift", fit, _drift_message(ev), "change", s, det, n - k)

    def power_statement(self) -> dict | None:
        """Per axis, the step this traffic lets the monitor see within ``target_frames`` of it: the
        smallest change along / about each camera axis alone that the decisions detect with
        ``power`` (95 %) by the test of the longest window within that many frames, as the median
        and the 90th percentile (the sparser stretches) over the last POWER_DECISIONS ``ok``
        decisions; ``seen_at_target``: per axis, whether the median is within the target change
        (the issue's 0.25 deg / 10 cm). None before the first ``ok`` decision."""
        if not self._power:
            return None
        det = np.stack([d for d, _ in self._power])
        med, p90 = np.median(det, axis=0), np.quantile(det, 0.9, axis=0)
        tgt = np.array([self.config.target_deg] * 3 + [self.config.target_m] * 3)
        return {"within_frames": int(np.median([f for _, f in self._power])), "decisions": len(det),
                "power": self.config.power,
                "rotation_deg_median": _l(med[:3]), "translation_m_median": _l(med[3:]),
                "rotation_deg_p90": _l(p90[:3]), "translation_m_p90": _l(p90[3:]),
                "seen_at_target": {a: bool(v <= t) for a, v, t in zip(AXIS_NAMES, med, tgt)}}

    def summary(self) -> dict:
        last = self.last_status
        return {"camera": self.camera, "frames": self.n_seen, "decisions": dict(self.statuses_seen),
                "state": "unknown" if last is None else last.state,
                "threshold": self.h, "false_alarm_rate_per_frame": self.config.false_alarm_rate,
                "detectable_rotation_deg": None if last is None else _l(last.detectable_rotation_deg),
                "detectable_translation_m": None if last is None else _l(last.detectable_translation_m),
                "weak_axes": [] if last is None else list(last.weak_axes),
                "weak_axes_share": {a: v / max(sum(self.statuses_seen.values()), 1) for a, v in self.weak_seen.items()
                                    if v},
                "target_change": {"rotation_deg": self.config.target_deg, "translation_m": self.config.target_m,
                                  "within_frames": self.config.target_frames},
                "power": self.power_statement(),
                "events": [e.to_dict() for e in self.events],
                "message": "no decision yet (fewer frames than one window)" if last is None else last.message}


_AXES = ("x", "y", "z")
AXIS_NAMES = ("rx", "ry", "rz", "tx", "ty", "tz")
_MODEL_AXES = {"rotation": (0, 1, 2), "translation": (3, 4, 5), "rotation+translation": (0, 1, 2, 3, 4, 5)}


def _weak_message(weak: tuple[str, ...], det: np.ndarray, n_frames: int) -> str:
    parts = [f"{'turns about' if a[0] == 'r' else 'shifts along'} {a[1]} below "
             f"{det[AXIS_NAMES.index(a)]:.2f} {'deg' if a[0] == 'r' else 'm'}" for a in weak]
    return (f"not observable from this traffic within {n_frames} frames of a change (95 % power): "
            + ", ".join(parts))
POWER_DECISIONS = 2000  # ok decisions the power statement is the median over
SCALE_FRAMES = 200  # frames the residual scale is the median over
SCALE_EVERY = 5  # ... recomputed every this many frames
RELIN_ITERS = 3  # rounds of re-linearisation of the frames after a detected change
RELIN_WINDOW_ROUNDS = 1  # rounds of the re-linearised window test (MonitorConfig.relinearise_band)
RELIN_TRACE = 20000  # the re-linearised window test's tests kept (CameraMonitor.relin_trace)
RELIN_TOL = 0.5  # a frame linearised farther than this (sigma, any axis) from the estimate is re-linearised
AXIS_SAMPLES = 400  # samples kept per window length (axis_factors)
REFERENCE_SAMPLES = 12  # MonitorConfig.reference_samples where it is switched on (CLI --reference)
MIN_AXIS_FACTOR = 0.25  # a test's variance is never taken below a quarter of the stated one on any axis
DIFF_SAMPLES = 120  # per window length: the tests whose spread ratio the difference's scale is the quantile of
DIFF_MIN_SAMPLES = 20  # ... before it replaces 1 (MonitorConfig.difference_quantile)
MIN_DIFFS = 5  # adjacent window pairs before the measured inflation replaces the prior
INFLATION_PRIOR = 2.0
CHI2_6_Q75_OVER_6 = 1.3068  # 75th percentile of chi-square(6) / 6


def _drift_message(ev: DriftEvent) -> str:
    r, t, sr, st = ev.step[:3], ev.step[3:], ev.step_sigma[:3], ev.step_sigma[3:]
    parts = []
    if ev.model != "translation":
        i = int(np.argmax(np.abs(r)))
        parts.append(f"turned {np.linalg.norm(r):.3f} deg (largest {r[i]:+.3f} deg about its {_AXES[i]} axis, "
                     f"1-sigma {sr[i]:.3f})")
    if ev.model != "rotation":
        i = int(np.argmax(np.abs(t)))
        parts.append(f"shifted {100 * np.linalg.norm(t):.1f} cm (largest {100 * t[i]:+.1f} cm along its {_AXES[i]} "
                     f"axis, 1-sigma {100 * st[i]:.1f})")
    alt = ""
    if ev.alternative is not None:
        a = ev.alternative
        if ev.alternative_model == "rotation":
            i = int(np.argmax(np.abs(a[:3])))
            alt = f"{a[i]:+.3f} deg about its {_AXES[i]} axis"
        else:
            i = int(np.argmax(np.abs(a[3:])))
            alt = f"{100 * a[3 + i]:+.1f} cm along its {_AXES[i]} axis"
        alt = f" (or, equally well, {ev.alternative_model == 'rotation' and 'turned' or 'shifted'} {alt}: this traffic cannot tell the two apart)"
    return (f"the camera has {' and '.join(parts)}{alt} since frame {ev.change_frame} (t={ev.change_time_s:.1f} s, "
            f"detected at frame {ev.detected_frame}); recalibrate")


def load_calibration(path) -> dict[str, CalibrationResult]:
    """camera name -> calibration from a result ``.json`` / ``.npz`` or a ``site_calibration.json``
    (its successful cameras). Raises FormatError for unreadable files."""
    import json

    from ..errors import FormatError
    from ..io.files import MAX_TEXT_BYTES, read_text
    from ..site.calibration import SITE_FORMAT, SiteCalibration

    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"calibration file not found: {p}")
    if p.suffix == ".json":
        try:
            d = json.loads(read_text(p, max_bytes=MAX_TEXT_BYTES, what="calibration file"))
        except (ValueError, OSError) as exc:
            raise FormatError(p, f"not a readable calibration ({type(exc).__name__}: {str(exc)[:200]})") from None
        if isinstance(d, dict) and d.get("format") == SITE_FORMAT:
            site = SiteCalibration.load(p)
            out = {c.camera: c.result for c in site.cameras if c.result.success}
            if not out:
                raise FormatError(p, "no camera of this site calibration has a pose (all refused)", "transforms")
            return out
    res = CalibrationResult.load(p)
    if not res.success:
        raise FormatError(p, f"the calibration has no pose (refused: {res.message})", "success")
    return {res.camera_name or "camera": res}


class Monitor:
    """Drift monitor of one or several cameras (``calibration``: a ``CalibrationResult``, a
    ``SiteCalibration``, a ``{camera: CalibrationResult}`` dict or a path to a result / site
    calibration file). ``update(frame)`` takes frames one at a time, in time order, and returns
    the decisions due at that frame (one per camera, usually none); ``run(frames)`` iterates them."""

    def __init__(self, calibration, config: MonitorConfig | None = None):
        if isinstance(calibration, (str, Path)):
            cals = load_calibration(calibration)
        elif isinstance(calibration, CalibrationResult):
            cals = {calibration.camera_name or "camera": calibration}
        elif isinstance(calibration, dict):
            cals = dict(calibration)
        elif hasattr(calibration, "cameras"):
            cals = {c.camera: c.result for c in calibration.cameras if c.result.success}
        else:
            raise TypeError(f"Monitor: expected a CalibrationResult, SiteCalibration, dict or path, "
                            f"got {type(calibration).__name__}")
        if not cals:
            raise ValueError("Monitor: no calibrated camera to monitor")
        self.config = config or MonitorConfig()
        self.cameras = {name: CameraMonitor(res, self.config, camera=name) for name, res in cals.items()}
        self.n_frames = 0

    @property
    def threshold(self) -> float:
        return self.config.threshold

    def update(self, frame, index: int | None = None) -> list[MonitorStatus]:
        """Add one frame (``index``: its position in the stream, default: the count so far; views of
        several cameras of one sweep share it); returns the decisions due at it (possibly none)."""
        from ..io.sources import camera_view

        out = []
        idx = self.n_frames if index is None else int(index)
        multi = getattr(frame, "images", None) is not None or getattr(frame, "camera_per_det", None) is not None
        if len(self.cameras) == 1 and not multi:
            (cm,) = self.cameras.values()
            st = cm.update(frame, idx)
            out = [st] if st is not None else []
        else:
            present = set(frame.images or {}) | set(frame.camera_per_det or []) | {frame.camera_name}
            for name, cm in self.cameras.items():
                if name not in present:
                    continue
                view = camera_view(frame, name) if multi else frame
                st = cm.update(view, idx)
                if st is not None:
                    out.append(st)
            if not any(n in present for n in self.cameras):
                raise ValueError(f"frame {frame.frame_key!r}: none of the calibrated cameras "
                                 f"({', '.join(self.cameras)}) is in it (cameras: {', '.join(sorted(present))})")
        self.n_frames = max(self.n_frames, idx + 1)
        return out

    def learn(self, frames: Iterable) -> dict:
        """Take a drift-free reference stretch of the site (the hours after a calibration, say):
        its frames calibrate each camera's change test per axis and window length
        (``CameraMonitor.axis_factors``), then every camera starts afresh (``restart``); a change
        found inside the stretch is forgotten at once (its decisions are no sample). Returns, per
        camera, the alarms inside the stretch and the factors (``reference_summary``)."""
        alarms = dict.fromkeys(self.cameras, 0)
        for f in frames:
            self.update(f)
            for name, cm in self.cameras.items():
                if cm.drift is not None:
                    alarms[name] += 1
                    cm.reset()
        for cm in self.cameras.values():
            cm.restart()
        self.n_frames = 0
        return {name: {"alarms": alarms[name], **cm.reference_summary()} for name, cm in self.cameras.items()}

    def run(self, frames: Iterable) -> Iterable[MonitorStatus]:
        for f in frames:
            yield from self.update(f)

    @property
    def state(self) -> State:
        """Overall state: drift if any camera drifted, ok if every camera's last decision is ok, else unknown."""
        states = [(cm.drift is not None and "drift") or (cm.last_status.state if cm.last_status else "unknown")
                  for cm in self.cameras.values()]
        if "drift" in states:
            return "drift"
        return "ok" if all(s == "ok" for s in states) else "unknown"

    @property
    def exit_code(self) -> int:
        """0 ok, 3 drift, 1 could not tell."""
        return {"ok": 0, "drift": 3}.get(self.state, 1)

    def summary(self) -> dict[str, Any]:
        return {"state": self.state, "exit_code": self.exit_code, "frames": self.n_frames,
                "threshold_chi2_6dof": self.threshold, "false_alarm_rate_per_frame": self.config.false_alarm_rate,
                "config": {k: getattr(self.config, k) for k in self.config.__dataclass_fields__},
                "cameras": {n: cm.summary() for n, cm in self.cameras.items()}}
