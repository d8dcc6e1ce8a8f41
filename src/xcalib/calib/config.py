"""``CalibConfig``: every setting of ``xcalib.calibrate`` in one frozen, typed record.

Defaults live here and nowhere else. ``calibrate(frames, intrinsics, config)`` takes one;
the older keyword form (``calibrate(frames, K, gate=0.3, max_rot_std_deg=0.5)``) is mapped
onto it by :meth:`CalibConfig.from_kwargs`, which names any keyword it does not know.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, fields
from typing import Any, Literal, get_args

__all__ = ["CalibConfig", "YawMode", "BoxModel", "UncertaintyMode", "IntrinsicsMode", "TimeOffsetMode",
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
            1 deg / 0.5 m by default): the pose is not determined by the data.
        max_rot_bound_deg / max_trans_bound_m: fail when the 95 % bound of the reported per-axis
            1-sigma (``uncertainty.bound95``; it also counts each object once and the 3D box model,
            see ``uncertainty``) exceeds these: the pose is determined but too uncertain to be of
            use. A success promises the pose within that bound.
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
        time_offset: camera time minus LiDAR time (s). None: no offset; a number: that fixed
            offset; "auto": estimated from moving objects when observable, else none (with a
            warning); "estimate": estimated, refused when not observable. 3D boxes are moved by
            their velocity (given, or from tracks over the frames' LiDAR times) times dt.
        time_offset_max_std_s: largest 1-sigma (s) of an estimated offset that "auto" uses.
    Cost:
        occlusion_tau / occlusion_slope: inward edge residuals beyond tau (sigma units) are
            compressed by slope (occlusion only ever shrinks a 2D box).
    Speed:
        workers: processes for the independent parts of one calibration (the quick refinement of
            each candidate, the mirrored-image and second-pose searches of the misfit checks):
            "auto" (the CPUs this process may use; 1 inside a worker of a pool, e.g. a batch of
            calibrations) or an int >= 1. The result is the same for every value.
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
    misfit_check: bool = True
    uncertainty: UncertaintyMode = "clusters"
    reestimate_yaw: YawMode = "auto"
    box_model: BoxModel = "auto"
    max_baseline_m: float | None = 8.0
    max_hyp_frames: int = 10
    max_refine: int = 6
    max_candidates: int = 1500
    refine_intrinsics: IntrinsicsMode = "auto"
    focal_max_std: float = 0.01
    time_offset: TimeOffsetMode | float | None = None
    time_offset_max_std_s: float = 0.02
    occlusion_tau: float = 1.5
    occlusion_slope: float = 0.2
    workers: int | Literal["auto"] = "auto"
    seed: int = 0

    def __post_init__(self) -> None:
        object.__setattr__(self, "time_offset", parse_time_offset(self.time_offset))
        for name, allowed in (("reestimate_yaw", YawMode), ("box_model", BoxModel), ("uncertainty", UncertaintyMode),
                              ("refine_intrinsics", IntrinsicsMode)):
            if getattr(self, name) not in get_args(allowed):
                raise ValueError(f"CalibConfig.{name}: expected one of {get_args(allowed)}, got {getattr(self, name)!r}")
        if not (0.0 < self.gate_iou <= 1.0):
            raise ValueError(f"CalibConfig.gate_iou: expected an IoU in (0, 1], got {self.gate_iou}")
        for name in ("max_rot_std_deg", "max_trans_std_m", "max_rot_bound_deg", "max_trans_bound_m", "occlusion_tau", "occlusion_slope", "focal_max_std",
                     "time_offset_max_std_s"):
            if not getattr(self, name) > 0:
                raise ValueError(f"CalibConfig.{name}: expected > 0, got {getattr(self, name)}")
        for name in ("min_pairs", "max_hyp_frames", "max_refine", "max_candidates"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"CalibConfig.{name}: expected >= 1, got {getattr(self, name)}")
        if not (self.workers == "auto" or (isinstance(self.workers, int) and not isinstance(self.workers, bool)
                                           and self.workers >= 1)):
            raise ValueError(f"CalibConfig.workers: expected 'auto' or an int >= 1, got {self.workers!r}")
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
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "CalibConfig":
        """Inverse of :meth:`to_dict`; unknown keys (a newer version's) are ignored."""
        names = {f.name for f in fields(cls)}
        return cls(**{k: v for k, v in dict(d).items() if k in names})
