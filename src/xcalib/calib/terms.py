"""Cost terms by name: the ``xcalib.cost_terms`` registry and the one description of a fit's cost.

A cost term is registered under a name in the entry-point group ``xcalib.cost_terms``
(:mod:`xcalib.plugins`; xcalib's own in ``pyproject.toml``, a third party's in its own package)
as a *factory*: a callable ``factory(ctx: TermContext, **options) -> CostTerm`` that builds the
term for one fit from the matched pairs (``ctx``) and the options the configuration gives it::

    [project.entry-points."xcalib.cost_terms"]
    camera_height = "my_pkg.height:camera_height"     # def camera_height(ctx, *, height_m, sigma_m=0.05)

``CalibConfig(cost_terms=("camera_height:height_m=6.2",))`` then adds the term to every fit of
the calibration: the pose refinement (``refine.lsq``), the self-calibration refit (``selfcal``),
the misfit refits (``misfit``, ``boxmodel``) and the uncertainty (``uncertainty``: the pose's
covariance with the term's residuals and parameters). Each of them builds its cost with
:func:`xcalib.calib.refine.build_cost` from a :class:`CostSpec` (the box-edge term's occlusion
shaping + the named terms), which the calibration makes once from the config
(:meth:`CostSpec.from_config`).

Built-in factories (registered the same way): ``box_edges`` (``refine.box_edges``, always the
first term; its settings are ``occlusion_tau`` / ``occlusion_slope``), ``pose_prior`` (a known pose and its 1-sigma),
``focal_scale``, ``principal_point`` and ``time_offset`` (the self-calibration adds these from
``refine_intrinsics`` / ``time_offset``; they cannot be named in ``cost_terms``).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from .config import CalibConfig, TermSpec
from .cost import CostTerm, FocalScaleTerm, Occlusion, PosePriorTerm, PrincipalPointTerm
from .diagnostics import NoiseModel
from .pose import Pose
from .term_registry import GROUP, STAGE_TERMS, check_terms, cost_terms, term_factory

__all__ = ["TermContext", "CostSpec", "cost_terms", "term_factory", "check_terms", "pose_block", "occlusion_of",
           "pose_prior", "focal_scale", "principal_point", "time_offset", "STAGE_TERMS", "GROUP"]


@dataclass(frozen=True)
class TermContext:
    """What a term factory sees: the calibration frames (``inputs.CalibFrame``), the matched pairs
    per frame (rows [n,2]: 2D index, 3D index), the intrinsics, the linearisation pose and the
    per-edge noise model of the fit (None: the default)."""

    frames: list
    pairs: list
    intr: Any
    pose: Pose
    noise: NoiseModel | None = None


# --- built-in factories ---------------------------------------------------------------------------

def pose_prior(ctx: TermContext, *, rotvec_deg: tuple = (0.0, 0.0, 0.0), t_m: tuple = (0.0, 0.0, 0.0),
               sigma_deg: float = 1.0, sigma_m: float = 0.1) -> CostTerm:
    """A known pose (rotation vector, deg, and translation, m, of ``T_cam_lidar``) with its 1-sigma."""
    from scipy.spatial.transform import Rotation

    R = Rotation.from_rotvec(np.radians(np.asarray(rotvec_deg, dtype=np.float64).reshape(3))).as_matrix()
    if not (sigma_deg > 0 and sigma_m > 0):
        raise ValueError(f"pose_prior: sigma_deg and sigma_m must be > 0, got {sigma_deg}, {sigma_m}")
    return PosePriorTerm(Pose(R, np.asarray(t_m, dtype=np.float64).reshape(3)), float(sigma_deg), float(sigma_m))


def focal_scale(ctx: TermContext, *, sigma_log: float | None = None) -> CostTerm:
    """A common log scale of fx, fy (``cost.FocalScaleTerm``)."""
    return FocalScaleTerm(sigma_log)


def principal_point(ctx: TermContext, *, sigma_px: float | None = None) -> CostTerm:
    """A shift of (cx, cy), px (``cost.PrincipalPointTerm``)."""
    return PrincipalPointTerm(sigma_px)


def time_offset(ctx: TermContext, *, velocity_mps: Any = None, dt0: float = 0.0) -> CostTerm:
    """The camera-minus-LiDAR time offset (``cost.TimeOffsetTerm``), given each pair's velocity [n,3]."""
    from .cost import TimeOffsetTerm

    n = int(sum(len(p) for p in ctx.pairs))
    v = np.zeros((n, 3)) if velocity_mps is None else np.asarray(velocity_mps, dtype=np.float64)
    return TimeOffsetTerm(v, dt0)


@dataclass(frozen=True)
class CostSpec:
    """The cost of every fit of one calibration: the box-edge term's occlusion shaping (None: none)
    and the extra terms named in the config (built per fit by their factories, after the terms a
    stage adds itself)."""

    occlusion: Occlusion | None = Occlusion()
    terms: tuple[TermSpec, ...] = ()

    @classmethod
    def from_config(cls, config: CalibConfig) -> "CostSpec":
        return cls(Occlusion(config.occlusion_tau, config.occlusion_slope, config.censor_occluded_edges),
                   tuple(config.cost_terms))

    @classmethod
    def of(cls, value: "CostSpec | Occlusion | None") -> "CostSpec":
        """A spec from what the stages pass as their ``occlusion`` argument: a ``CostSpec``, an
        ``Occlusion`` (the box-edge term alone) or None (no occlusion shaping, no extra terms)."""
        if isinstance(value, CostSpec):
            return value
        if value is None or isinstance(value, Occlusion):
            return cls(value, ())
        raise TypeError(f"expected a CostSpec, an Occlusion or None, got {type(value).__name__}")

    def with_occlusion(self, occlusion: Occlusion | None) -> "CostSpec":
        """The same extra terms with another occlusion shaping (None: none)."""
        return replace(self, occlusion=occlusion)

    def extra_terms(self, ctx: TermContext) -> list[CostTerm]:
        """The named terms built for one fit."""
        return [term_factory(spec.name)(ctx, **spec.kwargs) for spec in self.terms]


def occlusion_of(value: "CostSpec | Occlusion | None") -> Occlusion | None:
    """The occlusion shaping of a stage's ``occlusion`` argument (a spec's, or the argument itself)."""
    return value.occlusion if isinstance(value, CostSpec) else value


def pose_block(r0: np.ndarray, J: np.ndarray, n_rows: int):
    """The pose part of a linearised fit whose first ``n_rows`` residuals are the box edges:
    (edge residuals [n_rows], edge Jacobian [n_rows, 6], information [6,6] of the other residuals
    or None). Extra parameters (columns beyond 6) are profiled out (the edge Jacobian projected
    off them, so ``J^T J`` of the result is the pose's marginal information); with only the
    box-edge term the inputs come back unchanged (and None)."""
    if J.shape[1] == 6 and len(r0) == n_rows:
        return r0, J, None
    Jp, Je = J[:, :6], J[:, 6:]
    if Je.shape[1]:
        S, *_ = np.linalg.lstsq(Je, Jp, rcond=None)
        Jp = Jp - Je @ S
    rest = Jp[n_rows:]
    return r0[:n_rows], Jp[:n_rows], rest.T @ rest
