"""``CalibConfig``: every setting of ``xcalib.calibrate`` in one frozen, typed record.

Defaults live here and nowhere else. ``calibrate(frames, intrinsics, config)`` takes one;
the older keyword form (``calibrate(frames, K, gate=0.3, max_rot_std_deg=0.5)``) is mapped
onto it by :meth:`CalibConfig.from_kwargs`, which names any keyword it does not know.
"""

from __future__ import annotations

import dataclasses
import operator
from dataclasses import dataclass, fields
from typing import Any, Literal, get_args

from .term_registry import check_terms

__all__ = ["CalibConfig", "TermSpec", "YawMode", "BoxModel", "UncertaintyMode", "IntrinsicsMode", "TimeOffsetMode",
           "parse_time_offset"]

YawMode = Literal["auto", "always", "never"]
BoxModel = Literal["auto", "corners", "points"]
UncertaintyMode = Literal["clusters", "objects", "frames"]
IntrinsicsMode = Literal["auto", "none", "focal", "focal+center"]
TimeOffsetMode = Literal["auto", "estimate"]


def parse_time_offset(value: "str | float | None") -> "str | float | None":
    """``time_offset`` from a config value or the command line: "auto", "estimate", "none"/"" (None)
    or a number of seconds (camera time minus LiDAR time). Raises ValueError otherwise."""
    if value is None or isinstance(value, bool):
        if isinstance(value, bool):
            raise ValueError(f"CalibConfig.time_offset: expected 'auto', 'estimate', seconds or None, got {value!r}")
        return None
    if isinstance(value, (int, float)):
        v = float(value)
        if not (abs(v) < 10.0):  # also refuses NaN
            raise ValueError(f"CalibConfig.time_offset: a fixed offset must be finite and within 10 s, got {value!r}")
        return v
    text = str(value).strip().lower()
    if text in ("auto", "estimate"):
        return text
    if text in ("none", "", "off"):
        return None
    try:
        return parse_time_offset(float(text))
    except ValueError:
        raise ValueError(f"CalibConfig.time_offset: expected 'auto', 'estimate', seconds or None, got {value!r}") from None

def _frozen(value: Any) -> Any:
    """``value`` with lists (JSON arrays) as tuples, so a term's options stay hashable."""
    if isinstance(value, (list, tuple)):
        return tuple(_frozen(v) for v in value)
    if isinstance(value, dict):
        raise ValueError(f"a cost-term option must be a number, string, bool or list, got a mapping {value!r}")
    return value


def _option_value(text: str) -> Any:
    """A value of ``name:key=value`` from the command line: JSON (numbers, lists, true/false) or a string."""
    import json

    try:
        return json.loads(text)
    except ValueError:
        return text


def _split_top(text: str) -> list[str]:
    """``text`` split at the commas outside brackets (``a=1,b=[1,2]`` -> ``a=1``, ``b=[1,2]``)."""
    out, depth, cur = [], 0, ""
    for ch in text:
        depth += (ch in "[(") - (ch in "])")
        if ch == "," and depth == 0:
            out.append(cur)
            cur = ""
        else:
            cur += ch
    return out + [cur]


@dataclass(frozen=True)
class TermSpec:
    """One extra cost term of ``CalibConfig.cost_terms``: the name it is registered under (entry-point
    group ``xcalib.cost_terms``, see :mod:`xcalib.calib.terms`) and its options (keyword arguments of
    its factory, as sorted (key, value) pairs)."""

    name: str
    options: tuple[tuple[str, Any], ...] = ()

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name.strip():
            raise ValueError(f"CalibConfig.cost_terms: a term needs a name (a string), got {self.name!r}")
        opts = self.options.items() if isinstance(self.options, dict) else self.options
        object.__setattr__(self, "name", self.name.strip())
        object.__setattr__(self, "options", tuple(sorted((str(k), _frozen(v)) for k, v in opts)))

    @classmethod
    def parse(cls, value: "TermSpec | str | dict[str, Any]") -> "TermSpec":
        """A term from a ``TermSpec``, a name (``"camera_height"``), ``"name:key=value,key=value"``
        (the command line's form; values JSON where they parse) or a mapping ``{"name": ..., "options":
        {...}}`` (the form ``to_dict`` writes) or ``{"name": ..., key: value, ...}``."""
        if isinstance(value, TermSpec):
            return value
        if isinstance(value, str):
            name, _, rest = value.partition(":")
            opts = {}
            for item in filter(None, (x.strip() for x in _split_top(rest))):
                key, eq, text = item.partition("=")
                if not eq:
                    raise ValueError(f"CalibConfig.cost_terms: {value!r}: expected name:key=value,..., got {item!r}")
                opts[key.strip()] = _option_value(text.strip())
            return cls(name, tuple(opts.items()))
        if isinstance(value, dict):
            d = dict(value)
            if "name" not in d:
                raise ValueError(f"CalibConfig.cost_terms: a term mapping needs a 'name', got keys {sorted(d)}")
            name, opts = d.pop("name"), d.pop("options", None)
            if opts is None:
                opts = d
            elif d:
                raise ValueError(f"CalibConfig.cost_terms: term {name!r}: unknown keys {sorted(d)} beside 'options'")
            return cls(name, tuple(dict(opts).items()) if isinstance(opts, dict) else tuple(map(tuple, opts)))
        raise ValueError(f"CalibConfig.cost_terms: expected a term name, mapping or TermSpec, got {value!r}")

    @property
    def kwargs(self) -> dict[str, Any]:
        return dict(self.options)

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "options": {k: list(v) if isinstance(v, tuple) else v for k, v in self.options}}


# older keyword names -> config fields
_ALIASES = {"gate": "gate_iou"}


@dataclass(frozen=True)
class CalibConfig:
    """Settings of one calibration (pixels, metres, degrees).

    Matching / acceptance:
        gate_iou: IoU gate of the final one-to-one matches.
        min_pairs: fewest matched pairs a pose may rest on.
        min_explained: fail when the pose explains fewer than this fraction of the 2D boxes.
        ambiguity_ratio: fail when a distinct runner-up pose scores at least this fraction of the best.
        max_rot_std_deg / max_trans_std_m: fail when the norm of the 1-sigma vector that the frames
            verify (Jacobian, frame halves, occlusion; the 0.4 sigma) exceeds these (2 sigma within
            1 deg / 0.5 m by default): the pose is not determined by the data. A pose whose reported
            95 % bound is within ``fine_rot_bound_deg`` / ``fine_trans_bound_m`` is judged with the
            occlusion shift counted only beyond its own noise (``decision.data_sd_beyond_noise``).
        max_rot_bound_deg / max_trans_bound_m: fail when the 95 % bound of the reported per-axis
            1-sigma (``uncertainty.bound95``; it also counts each object once and the 3D box model,
            see ``uncertainty``) exceeds these: the pose is determined but too uncertain to be of
            use. A success promises the pose within that bound.
        fine_rot_bound_deg / fine_trans_bound_m: a success whose 95 % bound exceeds either is
            reported as coarse (``CalibrationResult.coarse``, a line in ``summary()``): the pose is
            determined, but 95 % sure only within that bound, not within this line (1 deg / 0.5 m:
            the line every benchmark calls a wrong pose beyond). A coarse pose is a starting point
            (a prior, a monitor's reference), not a pose for fusing the sensors. Set
            ``max_rot_bound_deg`` / ``max_trans_bound_m`` to these values to refuse coarse poses.
            Why coarse poses are not refused by default: the 16 real A9 frames with labelled boxes
            give a 95 % bound of 1.02 deg / 0.74 m, and every A9 success measured (all 16 frames, 17
            of 17 random 8-frame and 20 of 20 random 12-frame subsets, the detector-box runs) would be
            refused (docs/calibration.md, "Coarse successes").
        misfit_check: refuse a pose whose residuals show the model does not fit (wrong focal
            length, sensors out of time, mixed cameras, mirrored image) or cannot check the given
            focal length (``focal_unverifiable``); see ``misfit``. False turns both off.
        uncertainty: "clusters" (default) adds to the Jacobian and frame-halves sigma the sandwich
            clustered by object (the same car in many frames carries one error, so repeated
            frames add no information) and the model-misfit floor; "objects" also resamples
            objects (bootstrap); "frames": Jacobian and frame halves only (the 0.4 behaviour).
    Inputs:
        reestimate_yaw: "auto" (re-estimate yaw from the points for yaw-less [M,6] boxes),
            "always", "never".
        box_model: "auto" | "corners" | "points" (outline of each 3D box, see ``inputs``).
        detector_scores: weigh the 2D boxes by their detector scores (``meta["scores_2d"]``): the
            per-edge error model gains a score term fitted on the run's residuals
            (``refine.estimate_noise``). Off by default: on the realism suite it made two wrong
            successes in 120 detector runs (``detector_all`` site 18, ``detector_truncation`` site
            14) and moved the A9 detector-box pose 0.34 deg from the labelled one
            (docs/calibration.md, "Boxes from a camera detector").
    Bring-up:
        max_baseline_m: assume the camera within this distance of the LiDAR-frame origin (retried
            without it when the search fails); None: never assume it.
        max_hyp_frames: frames (or frame groups) searched for hypotheses.
        max_refine: distinct hypotheses refined.
        max_candidates: candidate (2D, 3D) pairs per hypothesis search (bounds memory: the search
            is quadratic in them; crowded frames are split by LiDAR azimuth, then subsampled).
    Self-calibration (see ``selfcal``):
        refine_intrinsics: "none" keeps the given intrinsics; "focal" estimates a common scale of
            fx, fy (ratio kept) with the pose and refuses when the data cannot constrain it;
            "focal+center" also the principal point; "auto" estimates the focal length only where
            the data constrains it (1-sigma of the scale below ``focal_max_std``) and otherwise
            keeps the given one (the misfit check then applies).
        focal_max_std: largest 1-sigma (relative) of an estimated focal scale that is used.
        focal_keep_box_model: with "auto", keep the given focal length (and its pose) where the joint
            fit would replace it but the given one with the 2D outline offsets free explains the boxes
            at least as well, and the focal-length and principal-point checks accept the given
            intrinsics at that pose (``selfcal.given_focal_kept``). On by default since session 14
            (off in session 13: without the principal-point part, realism principal_point+3%W
            site 18 let a pose 0.9 deg off through).
        time_offset: camera time minus LiDAR time (s). None: no offset; a number: that fixed
            offset; "auto": estimated from moving objects when observable, else none (with a
            warning); "estimate": estimated, refused when not observable. 3D boxes are moved by
            their velocity (given, or from tracks over the frames' LiDAR times) times dt.
        time_offset_max_std_s: largest 1-sigma (s) of an estimated offset that "auto" uses.
    Cost:
        occlusion_tau / occlusion_slope: inward edge residuals beyond tau (sigma units) are
            compressed by slope (occlusion only ever shrinks a 2D box).
        censor_occluded_edges: an edge of a matched 2D box that lies on the 2D box of a nearer
            matched object (LiDAR range order; ``calib.censor``) counts only outward (a censored,
            one-sided residual): a box of the visible part ends at its occluder, the hidden edge
            lies further out. "auto": only when this run's own residuals show those edges lying
            inside the projected outlines (``censor.censor_evidence``: boxes of the visible part);
            edges that behave as exact observations (amodal boxes) are kept. Default off: measured
            on the shared real sets, True refuses correct A9 poses and "auto" made one wrong
            success on an A9 detector subset (docs/camera-models.md); for visible-part boxes only.
        cost_terms: extra cost terms added to every fit of the calibration (refinement,
            self-calibration, misfit refits, uncertainty), each a :class:`TermSpec` (or its name,
            ``"name:key=value"`` or mapping): a term registered in the entry-point group
            ``xcalib.cost_terms`` (built in: ``pose_prior``; a plugin adds its own). Empty: the
            box-edge term alone.
    Whole recordings:
        max_frames: the most frames one calibration uses. A recording with more is reduced to
            that many informative frames (``selection``: every distinct object first, then new
            places, image cells, depths and bearings, spread over time); with fewer, every frame
            is used (no selection). None: always every frame.
    Speed:
        workers: processes for the independent parts of one calibration (the per-frame outlines,
            the pose search, the quick refinement of each candidate, the full one of the two
            finalists, the misfit checks' searches and refits), one pool for the whole call:
            "auto" (the CPUs this process may use) or an int >= 1; either is 1 inside a worker of a
            pool (a batch of calibrations, a Ray worker). The result is the same for every value.
    seed: seeds every random choice.
    """

    gate_iou: float = 0.3
    min_pairs: int = 4
    min_explained: float = 0.3
    ambiguity_ratio: float = 0.85
    max_rot_std_deg: float = 0.5
    max_trans_std_m: float = 0.25
    max_rot_bound_deg: float = 2.0
    max_trans_bound_m: float = 1.2
    fine_rot_bound_deg: float = 1.0
    fine_trans_bound_m: float = 0.5
    misfit_check: bool = True
    uncertainty: UncertaintyMode = "clusters"
    reestimate_yaw: YawMode = "auto"
    box_model: BoxModel = "auto"
    detector_scores: bool = False
    max_baseline_m: float | None = 8.0
    max_hyp_frames: int = 10
    max_refine: int = 6
    max_candidates: int = 1500
    refine_intrinsics: IntrinsicsMode = "auto"
    focal_max_std: float = 0.01
    focal_keep_box_model: bool = True
    time_offset: TimeOffsetMode | float | None = None
    time_offset_max_std_s: float = 0.02
    occlusion_tau: float = 1.5
    occlusion_slope: float = 0.2
    censor_occluded_edges: bool | Literal["auto"] = False
    cost_terms: tuple[TermSpec, ...] = ()
    workers: int | Literal["auto"] = "auto"
    max_frames: int | None = 200
    seed: int = 0

    def __post_init__(self) -> None:
        object.__setattr__(self, "time_offset", parse_time_offset(self.time_offset))
        terms = self.cost_terms
        terms = (terms,) if isinstance(terms, (str, dict, TermSpec)) else tuple(terms or ())
        object.__setattr__(self, "cost_terms", tuple(TermSpec.parse(v) for v in terms))
        if self.cost_terms:  # names and options checked against the registry (loads xcalib.cost_terms)
            check_terms(self.cost_terms)
        for name, allowed in (("reestimate_yaw", YawMode), ("box_model", BoxModel), ("uncertainty", UncertaintyMode),
                              ("refine_intrinsics", IntrinsicsMode)):
            if getattr(self, name) not in get_args(allowed):
                raise ValueError(f"CalibConfig.{name}: expected one of {get_args(allowed)}, got {getattr(self, name)!r}")
        if not isinstance(self.focal_keep_box_model, bool):
            raise ValueError(f"CalibConfig.focal_keep_box_model: expected True or False, got {self.focal_keep_box_model!r}")
        if self.censor_occluded_edges not in (True, False, "auto"):
            raise ValueError(f"CalibConfig.censor_occluded_edges: expected True, False or 'auto', "
                             f"got {self.censor_occluded_edges!r}")
        if not (0.0 < self.gate_iou <= 1.0):
            raise ValueError(f"CalibConfig.gate_iou: expected an IoU in (0, 1], got {self.gate_iou}")
        for name in ("max_rot_std_deg", "max_trans_std_m", "max_rot_bound_deg", "max_trans_bound_m",
                     "fine_rot_bound_deg", "fine_trans_bound_m", "occlusion_tau", "occlusion_slope", "focal_max_std",
                     "time_offset_max_std_s"):
            if not getattr(self, name) > 0:
                raise ValueError(f"CalibConfig.{name}: expected > 0, got {getattr(self, name)}")
        for name in ("min_pairs", "max_hyp_frames", "max_refine", "max_candidates"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"CalibConfig.{name}: expected >= 1, got {getattr(self, name)}")
        if not (self.workers == "auto" or (isinstance(self.workers, int) and not isinstance(self.workers, bool)
                                           and self.workers >= 1)):
            raise ValueError(f"CalibConfig.workers: expected 'auto' or an int >= 1, got {self.workers!r}")
        if self.max_frames is not None:
            try:
                n = operator.index(self.max_frames)
            except TypeError:
                n = None
            if n is None or isinstance(self.max_frames, bool) or n < 2:
                raise ValueError(f"CalibConfig.max_frames: expected an int >= 2 or None, got {self.max_frames!r}")
            object.__setattr__(self, "max_frames", int(n))
        if self.max_baseline_m is not None and not self.max_baseline_m > 0:
            raise ValueError(f"CalibConfig.max_baseline_m: expected > 0 or None, got {self.max_baseline_m}")

    def replace(self, **changes: Any) -> "CalibConfig":
        """A copy with ``changes`` (field names only)."""
        return dataclasses.replace(self, **changes)

    @classmethod
    def from_kwargs(cls, base: "CalibConfig | None" = None, **kwargs: Any) -> "CalibConfig":
        """``base`` (default: the defaults) with the older keyword arguments of ``calibrate`` applied.

        ``gate`` is ``gate_iou``; ``reestimate_yaw=True/False`` is "always"/"never". Raises
        TypeError naming every unknown keyword.
        """
        names = {f.name for f in fields(cls)}
        changes: dict[str, Any] = {}
        unknown = []
        for key, value in kwargs.items():
            name = _ALIASES.get(key, key)
            if name not in names:
                unknown.append(key)
                continue
            if name == "reestimate_yaw" and isinstance(value, bool):
                value = "always" if value else "never"
            changes[name] = value
        if unknown:
            raise TypeError(f"calibrate: unknown keyword argument(s) {', '.join(sorted(unknown))}; "
                            f"CalibConfig fields are {', '.join(sorted(names))} (and 'gate' for gate_iou)")
        return dataclasses.replace(base or cls(), **changes)

    def to_dict(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        d["cost_terms"] = [t.to_dict() for t in self.cost_terms]
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "CalibConfig":
        """Inverse of :meth:`to_dict`; unknown keys (a newer version's) are ignored."""
        names = {f.name for f in fields(cls)}
        return cls(**{k: v for k, v in dict(d).items() if k in names})
