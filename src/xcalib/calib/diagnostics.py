"""``CalibDiagnostics``: what ``calibrate`` computed on the way to its verdict (typed, saved with the result).

Reports draw from it (bring-up pose, per-frame residuals, uncertainty parts, misfit checks)
instead of re-computing with defaults. Pure records: numpy only.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, fields
from typing import Any, NamedTuple

import numpy as np

__all__ = ["NoiseModel", "CandidateSummary", "FrameSummary", "FrameSelectionSummary", "MisfitCheck", "UncertaintyParts", "SelfCalDiagnostics",
           "CalibDiagnostics", "bound95"]


class NoiseModel(NamedTuple):
    """Per-edge disagreement model of a matched pair: ``sigma^2 = sigma_px^2 + (f sigma_3d_m / Z)^2
    + (sigma_size s)^2 + (sigma_score s (score_ref - q))^2`` (2D box noise px; 3D centre error m
    seen at depth Z; relative 3D size error of a box s px large; relative 2D box noise per unit of
    the detector score ``q`` below ``score_ref``, the most confident matched box's score: a
    detector's less confident boxes are noisier, fitted per calibration by ``refine.estimate_noise``;
    0 when the boxes carry no scores or all the same)."""

    sigma_px: float = 1.0
    sigma_3d_m: float = 0.03
    sigma_size: float = 0.01
    sigma_score: float = 0.0
    score_ref: float = 1.0


@dataclass
class CandidateSummary:
    """A refined candidate pose: score (sum of matched IoU) and its distance from the best."""

    score: float
    rot_deg_from_best: float
    trans_m_from_best: float
    baseline_m: float


@dataclass
class FrameSummary:
    """Per frame at the final pose: detections, matched pairs, median edge residual (px) and IoU."""

    key: str
    n_2d: int
    n_3d: int
    pairs: int
    px_median: float | None
    iou_median: float | None


@dataclass
class FrameSelectionSummary:
    """Which frames of the recording the calibration used (``selection``): frames given and used,
    distinct objects (3D tracks) in all frames and in the used ones, how objects were told apart
    ("tracks" | "positions" | "none"), the budget (``CalibConfig.max_frames``), the used frames'
    indices among those given, and the selection's time (s)."""

    n_frames_given: int = 0
    n_frames_used: int = 0
    n_objects: int = 0
    n_objects_used: int = 0
    object_identity: str = ""
    max_frames: int | None = None
    used_indices: list[int] = field(default_factory=list)
    elapsed_s: float = 0.0


@dataclass
class MisfitCheck:
    """One model-misfit test: its statistic, the limit and whether it flagged the fit."""

    name: str
    statistic: float
    limit: float
    flagged: bool
    detail: str = ""


@dataclass
class UncertaintyParts:
    """The pieces of the reported 1-sigma (6-vectors: deg about camera x,y,z; m along x,y,z).

    jacobian: linearised (sandwich) sigma; halves: difference of the two frame-half poses;
    jackknife: leave-one-pair-out sigma (few matches); objects: sigma from resampling objects
    (tracks repeated across frames count once); occlusion: pose shift without the occlusion
    model; floor: the model-misfit floor; selfcal: the pose spread that estimating the intrinsics /
    time offset adds (marginal minus conditional sigma, ``selfcal``); clusters: the sandwich sigma clustered by object
    (every object's pairs over all frames share one error); frames: the leave-frames-out jackknife
    sigma (what the verdict judges the pose by, in place of the halves); n_objects: distinct objects;
    box_model: how the floor was weighed (robust costs of the outlines in use and of the box corners,
    the corners' posterior weight, the pose shift to them; ``uncertainty.box_model_floor``);
    outline: the pose shift when common outline offsets are fitted; object_outline: the pose's
    sigma with every object's own outline offsets as random effects (``boxmodel.fit_object_outline``;
    None where the objects' outlines do not differ beyond the noise); occlusion_noise / outline_noise: the
    1-sigma sampling noise of the occlusion / outline shift (``uncertainty.shift_noise_sd``): the reported
    sigma counts of each shift only the part beyond it (``uncertainty.excess``); clusters_dof: the
    Bell-McCaffrey degrees of freedom of each axis of ``clusters`` (``clusters`` is the CR2 sigma times
    t_{0.975, dof} / 1.96, so that 2 sigma stays a 95 % bound with few objects); clusters_corr: the
    6x6 correlation of the (raw) CR2 covariance; clusters_dof_cross: the 6x6 relative covariance of
    its six variance estimates (1 / ``clusters_dof`` on the diagonal; ``uncertainty.cr2_covariance``),
    from which the degrees of freedom of any sum of its variances follow (``uncertainty.bound_dof``);
    hidden / hidden_noise: the pose shift when the box edges that lie on a nearer matched box are
    censored (bounds, only their outward residual counts; ``uncertainty.hidden_edge_shift``) and its
    sampling noise: a systematic part added in quadrature beyond that noise (None: not computed, or
    the fit censors them already); centre_model: the pose's 1-sigma under the fitted noise model with
    its 3D centre error as a rigid shift of each box (``uncertainty.centre_model_sd``; measured, not
    part of the reported sigma); centre_noise: the 3D centre, 2D edge and size errors the boxes' residuals
    show, split by how they move a box's edges (``uncertainty.centre_noise``: sigma_px, sigma_3d_m, sigma_size,
    se_3d_var, n_used, measured); centre_shift: the pose's 1-sigma under that error model where a centre
    error was measured (``uncertainty.centre_shift_sd``; stored, not part of the sigma); centre_floor: the
    fitted noise model's sigma with that measured centre error as a rigid shift of each box, the reported
    sigma's floor per axis (``uncertainty.centre_floor_sd``; None where no centre error was measured); focal_box_model: what refine_intrinsics="auto"'s choice of a fitted
    focal length adds where the given focal length with the 2D outline offsets free explains the
    boxes as well (``selfcal.focal_box_model_sd``): in the reported sigma only (None: none); principal_point:
    what a given cx that the boxes do not resolve with the rotation free carries (the pose's move for a shift of
    cx by its 1-sigma, ``uncertainty.principal_point_part``; wide-angle models, where the principal point's
    resolution rule would otherwise refuse): in the reported sigma only (None: not added)."""

    jacobian: list[float] | None = None
    halves: list[float] | None = None
    jackknife: list[float] | None = None
    objects: list[float] | None = None
    occlusion: list[float] | None = None
    floor: list[float] | None = None
    selfcal: list[float] | None = None
    clusters: list[float] | None = None
    frames: list[float] | None = None
    n_objects: int = 0
    box_model: dict = field(default_factory=dict)
    outline: list[float] | None = None
    object_outline: list[float] | None = None
    occlusion_noise: list[float] | None = None
    outline_noise: list[float] | None = None
    clusters_dof: list[float] | None = None
    clusters_corr: list[list[float]] | None = None
    clusters_dof_cross: list[list[float]] | None = None
    hidden: list[float] | None = None
    hidden_noise: list[float] | None = None
    centre_model: list[float] | None = None
    centre_noise: dict | None = None
    centre_shift: list[float] | None = None
    centre_floor: list[float] | None = None
    focal_box_model: list[float] | None = None
    principal_point: list[float] | None = None


@dataclass
class SelfCalDiagnostics:
    """Intrinsics and time offset estimated with the pose (``selfcal``), and why / why not.

    intrinsics_mode / time_offset_mode: what was asked (``CalibConfig``). intrinsics_given: the
    intrinsics passed in (dict); fx_used, fy_used, cx_used, cy_used: those the pose was computed
    with (px). focal_scale: used / given focal (1 = kept); focal_scale_std: its 1-sigma (relative),
    also when it was measured but not used; focal_estimated: whether the estimate was used.
    principal_shift_px [2] / principal_std_px [2]: estimated (cx, cy) shift and 1-sigma.
    time_offset_s: camera time minus LiDAR time applied to the 3D boxes (None: none);
    time_offset_std_s: 1-sigma of an estimated one; time_offset_source: "none" | "fixed" |
    "estimated" | "fallback". velocity_source: "given" | "tracks" | "nearest" | "" (how the 3D box
    velocities were obtained); n_moving_pairs: matched pairs of moving objects (> 0.5 m/s);
    ego_motion: ego motion compensated (known ego poses). stamp_offset_s: median camera - LiDAR
    stamp difference of the frames (for comparison; never used). time_offset_trigger: why an offset
    was estimated although none was asked for ("" : it was asked for, or none was): the default run's
    time-offset misfit check, which found the sensors out of time. notes: warnings and reasons."""

    intrinsics_mode: str = "none"
    intrinsics_given: dict | None = None
    fx_used: float | None = None
    fy_used: float | None = None
    cx_used: float | None = None
    cy_used: float | None = None
    focal_scale: float = 1.0
    focal_scale_std: float | None = None
    focal_estimated: bool = False
    principal_shift_px: list[float] | None = None
    principal_std_px: list[float] | None = None
    time_offset_mode: str = "none"
    time_offset_s: float | None = None
    time_offset_std_s: float | None = None
    time_offset_source: str = "none"
    velocity_source: str = ""
    n_moving_pairs: int = 0
    ego_motion: bool = False
    stamp_offset_s: float | None = None
    time_offset_trigger: str = ""
    notes: list[str] = field(default_factory=list)


def bound95(sd3, *, cov=None, dof: float = np.inf) -> float:
    """Radius (same unit) within which a 3-vector error lies with 95 % probability.

    ``|e|^2`` is taken as a scaled chi-square (Welch-Satterthwaite): with ``T`` the trace of the
    error's covariance and ``d = T^2 / |cov|_F^2`` its effective degrees of freedom, ``|e|^2 ~ (T/d)
    chi2_d``. The covariance is ``cov`` (3x3, correlations included) or, when None, independent axes
    with 1-sigma ``sd3``. When ``T`` is itself estimated with ``dof`` (Satterthwaite) degrees of
    freedom (few objects, ``uncertainty.bound_dof``) the ratio is an F: radius^2 = ``T F_{0.95}(d,
    dof)``, the multivariate form of the t interval (one dominant axis: ``t_{0.975, dof}`` sigma; many
    degrees of freedom: the chi-square bound). One dominant axis gives 1.96 sigma, three equal
    independent ones 2.80 sigma (``2 |sd|`` would say 3.46 sigma: a 99.3 % bound that refuses poses
    the data determine). Infinite when any variance is."""
    from scipy.special import chdtri, fdtri  # chi2.isf / f.ppf without importing scipy.stats (seconds)

    if cov is None:  # independent axes: the sums as before, bit for bit
        v = np.asarray(sd3, dtype=np.float64) ** 2
        if not np.all(np.isfinite(v)) or np.isnan(dof):
            return float("inf")
        s2, s4 = float(v.sum()), float((v ** 2).sum())
    else:
        cov = np.asarray(cov, dtype=np.float64)
        if not np.all(np.isfinite(cov)) or np.isnan(dof):
            return float("inf")
        s2, s4 = float(np.trace(cov)), float(np.sum(cov * cov))
    if s2 <= 0:
        return 0.0
    if not np.isfinite(dof):
        return float(np.sqrt(s4 / s2 * chdtri(s2 * s2 / s4, 0.05)))
    return float(np.sqrt(s2 * fdtri(s2 * s2 / s4, max(float(dof), 0.5), 0.95)))


@dataclass
class CalibDiagnostics:
    """Everything ``calibrate`` measured besides the headline numbers of ``CalibrationResult``."""

    seed_source: str = "geometry"          # "geometry" | "matcher" | "prior"
    n_hypotheses: int = 0
    sparse_search: bool = False
    pooled_search: bool = False
    split_searches: int = 0                # hypothesis searches split by LiDAR azimuth (crowded frames)
    bringup_T: list | None = None          # [4,4] best bring-up pose, before refinement
    bringup_error_vs_final: list[float] | None = None
    score: float = float("nan")
    runner_up_score: float = 0.0
    ambiguity_runner_up_score: float = 0.0
    refine_history: list[float] = field(default_factory=list)
    candidates: list[CandidateSummary] = field(default_factory=list)
    noise_model: NoiseModel = NoiseModel()
    uncertainty: UncertaintyParts = field(default_factory=UncertaintyParts)
    centre_offset_px_median: float | None = None
    n_2d: int = 0
    n_3d: int = 0
    max_pairs_per_frame: int = 0
    matched_places: int | None = None
    matched_places_off_line: int | None = None
    max_baseline_m: float | None = None
    misfit: list[MisfitCheck] = field(default_factory=list)
    selfcal: SelfCalDiagnostics = field(default_factory=SelfCalDiagnostics)
    box_model: str = ""                    # outlines used: "corners" | "points" | "corners+points" ("": 3D boxes with yaw, corners)
    box_model_px: list[float] | None = None  # median edge residual (px) of the [point-hull, corner] outline fits compared
    box_fit: dict = field(default_factory=dict)  # the box observation model fitted to the data (``boxmodel.fit_outline``)
    refusal: str = ""                      # short code of the refusal reason ("" on success)
    refused_T: list | None = None          # [4,4] the refined pose that was refused (a failed result has none)
    frames: list[FrameSummary] = field(default_factory=list)  # the used frames (see ``selection``)
    selection: FrameSelectionSummary = field(default_factory=FrameSelectionSummary)
    elapsed_s: float = 0.0

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["noise_model"] = dict(self.noise_model._asdict())
        if not d["noise_model"]["sigma_score"]:  # no score term: the record as before scores were used
            d["noise_model"].pop("sigma_score")
            d["noise_model"].pop("score_ref")
        return _jsonable(d)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "CalibDiagnostics":
        names = {f.name for f in fields(cls)}
        d = {k: v for k, v in dict(d).items() if k in names}
        d["noise_model"] = NoiseModel(**d.get("noise_model", {}))
        known = {f.name for f in fields(UncertaintyParts)}  # a newer version's parts are ignored
        d["uncertainty"] = UncertaintyParts(**{k: v for k, v in dict(d.get("uncertainty") or {}).items() if k in known})
        d["candidates"] = [CandidateSummary(**c) for c in d.get("candidates", [])]
        d["misfit"] = [MisfitCheck(**c) for c in d.get("misfit", [])]
        sc = {k: v for k, v in dict(d.get("selfcal") or {}).items() if k in {f.name for f in fields(SelfCalDiagnostics)}}
        d["selfcal"] = SelfCalDiagnostics(**sc)
        d["frames"] = [FrameSummary(**c) for c in d.get("frames", [])]
        known = {f.name for f in fields(FrameSelectionSummary)}
        d["selection"] = FrameSelectionSummary(**{k: v for k, v in dict(d.get("selection") or {}).items() if k in known})
        if d.get("score") is None:
            d["score"] = float("nan")
        return cls(**d)


def _jsonable(v):
    if isinstance(v, dict):
        return {k: _jsonable(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_jsonable(x) for x in v]
    if isinstance(v, np.ndarray):
        return _jsonable(v.tolist())
    if isinstance(v, (np.floating, float)):
        return float(v) if np.isfinite(v) else None
    if isinstance(v, (np.integer,)):
        return int(v)
    if isinstance(v, np.bool_):
        return bool(v)
    return v
