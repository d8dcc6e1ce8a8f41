"""The calibration cost: a ``CostModel`` of ``CostTerm`` objects that declare their residuals.

The parameter vector is the pose update ``x[:6]`` (rotation vector rad, applied on the left:
``R <- exp([w]x) R0``; translation m, camera frame: ``t <- t0 + dt``) followed by the extra
parameters each term declares (``CostTerm.n_params``, e.g. a focal-length scale). A term may
change the state the others see (``apply``: a focal term rescales the intrinsics every other
term projects with) and contributes a block of residuals (``residuals``), each already divided
by its sigma. A new term (time offset, principal point, ...) is one class.

Terms here:

* ``BoxEdgeTerm``: the four edges of the clipped enclosing rectangle of each matched projected
  3D outline minus its 2D box (px), divided by the per-pair sigma of the ``NoiseModel`` (2D box
  noise, 3D centre error seen at depth Z, 3D size error), with the ``Occlusion`` shaping
  (inward edges -- an occluded or truncated 2D box -- pull less).
* ``PosePriorTerm``: a known pose with its 1-sigma.
* ``FocalScaleTerm``: one log scale of fx and fy (optional prior); used by the misfit check and
  by the intrinsics refinement (``selfcal``).
* ``PrincipalPointTerm``: a shift of (cx, cy) in pixels (optional prior).
* ``TimeOffsetTerm``: the camera-minus-LiDAR time offset dt (s); every matched 3D outline is moved
  by its velocity times dt before projection (``PoseState.shift_m``).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from scipy.optimize import least_squares

from ..geometry.camera import CameraIntrinsics
from ..geometry.camera_models import pixels_per_metre as camera_pixels_per_metre
from .boxproj import project_rects
from .diagnostics import NoiseModel
from .pose import Pose

__all__ = ["shift_principal_point", "PoseState", "CostTerm", "Occlusion", "BoxEdgeTerm", "PosePriorTerm", "FocalScaleTerm",
           "PrincipalPointTerm", "TimeOffsetTerm", "CostModel", "CostFit", "edge_sigma", "INWARD", "POSE_X_SCALE"]

INWARD = np.array([-1.0, -1.0, 1.0, 1.0])  # sign of (pred - obs) per edge when the 2D box lies inside
POSE_X_SCALE = (1e-3, 1e-3, 1e-3, 0.05, 0.05, 0.05)  # typical step: rad, rad, rad, m, m, m


@dataclass
class PoseState:
    """What the terms see for one parameter vector: the pose, the intrinsics (possibly rescaled
    by a term), every term's own parameters by term name, and ``shift_m``: a translation [n,3]
    (LiDAR frame, m) of each matched 3D outline before projection (a time-offset term sets it)."""

    pose: Pose
    intr: CameraIntrinsics
    params: dict[str, np.ndarray] = field(default_factory=dict)
    shift_m: np.ndarray | None = None


class CostTerm:
    """A block of weighted residuals (dimensionless, ~N(0,1) for a good fit)."""

    name: str = "term"
    n_params: int = 0
    x_scale: tuple[float, ...] = ()

    def apply(self, state: PoseState, x: np.ndarray) -> PoseState:
        """Fold this term's parameters ``x`` [n_params] into the state (default: record them)."""
        if self.n_params:
            state.params[self.name] = x
        return state

    def residuals(self, state: PoseState) -> np.ndarray:
        raise NotImplementedError

    def clusters(self) -> np.ndarray | None:
        """Cluster index per residual (residuals sharing an error source, for the sandwich); None: none."""
        return None


@dataclass(frozen=True)
class Occlusion:
    """Occlusion (and a detector's truncation) only ever moves a 2D box edge *into* the projected
    outline: inward residuals beyond ``tau`` (sigma units) are compressed by ``slope``."""

    tau: float = 1.5
    slope: float = 0.2

    def shape(self, r: np.ndarray) -> np.ndarray:
        """Weighted edge residuals [n,4] (pred - obs) -> shaped [n,4]."""
        s = r * INWARD
        s = np.where(s > self.tau, self.tau + self.slope * (s - self.tau), s)
        return s * INWARD


def _pair_features(obs: np.ndarray, outlines: np.ndarray, intr: CameraIntrinsics, pose: Pose):
    """Per pair: 2D box size s (px, sqrt of its area) and f/Z (px per metre at the box centre)."""
    s = np.sqrt(np.clip((obs[:, 2] - obs[:, 0]) * (obs[:, 3] - obs[:, 1]), 0, None))
    ctr = outlines.mean(1) @ pose.R.T + pose.t
    if not isinstance(intr, CameraIntrinsics):  # camera-model dispatch: the model's local scale
        return s, camera_pixels_per_metre(intr, ctr)
    z = np.maximum(ctr[:, 2], 1.0)
    return s, np.sqrt(intr.fx * intr.fy) / z


def edge_sigma(obs: np.ndarray, outlines: np.ndarray, intr: CameraIntrinsics, pose: Pose,
               noise: NoiseModel, outline_sigma_m: np.ndarray | None = None) -> np.ndarray:
    """Per-pair 1-sigma (px) of an edge residual at ``pose`` under the error model ``noise``, plus
    each outline's own uncertainty ``outline_sigma_m`` [n] (m, seen at depth Z; e.g. a 3D box
    whose yaw the LiDAR points leave open)."""
    s, fz = _pair_features(obs, outlines, intr, pose)
    var = noise.sigma_px ** 2 + (fz * noise.sigma_3d_m) ** 2 + (noise.sigma_size * s) ** 2
    if outline_sigma_m is not None:
        var = var + (fz * np.asarray(outline_sigma_m, dtype=np.float64)) ** 2
    return np.sqrt(var)


class BoxEdgeTerm(CostTerm):
    """Edges of projected 3D outlines [n,S,3] (LiDAR frame, m) vs matched 2D boxes [n,4] (px)."""

    name = "box_edges"

    def __init__(self, outlines: np.ndarray, obs: np.ndarray, size: tuple[int, int], sigma_px: np.ndarray,
                 occlusion: Occlusion | None = Occlusion()):
        self.outlines, self.obs, self.size = outlines, obs, size
        self.w = (1.0 / np.asarray(sigma_px, dtype=np.float64))[:, None]
        self.occlusion = occlusion
        # an edge that cannot be projected (behind the camera) costs the box's own size
        self.fallback = np.sqrt((obs[:, 2] - obs[:, 0]) * (obs[:, 3] - obs[:, 1]))[:, None]

    def edges(self, state: PoseState) -> np.ndarray:
        """Unweighted, unshaped residuals [n,4] (px): projected rectangle - 2D box."""
        outlines = self.outlines if state.shift_m is None else self.outlines + state.shift_m[:, None, :]
        rects, valid = project_rects(outlines, state.pose.R, state.pose.t, state.intr, self.size)
        return np.where(valid[:, None], rects - self.obs, self.fallback)

    def residuals(self, state: PoseState) -> np.ndarray:
        r = self.edges(state) * self.w
        if self.occlusion is not None:
            r = self.occlusion.shape(r)
        return r.ravel()

    def clusters(self) -> np.ndarray:
        return np.repeat(np.arange(len(self.obs)), 4)


class PosePriorTerm(CostTerm):
    """A known pose with 1-sigma ``sigma_deg`` (rotation) and ``sigma_m`` (translation)."""

    name = "pose_prior"

    def __init__(self, prior: Pose, sigma_deg: float, sigma_m: float):
        self.prior, self.sigma = prior, np.array([sigma_deg] * 3 + [sigma_m] * 3, dtype=np.float64)

    def residuals(self, state: PoseState) -> np.ndarray:
        return state.pose.delta(self.prior) / self.sigma


class FocalScaleTerm(CostTerm):
    """One parameter: log of a common scale of fx and fy (so the fitted focal is exp(x) f);
    with ``sigma_log`` a Gaussian prior on it."""

    name = "focal_scale"
    n_params = 1
    x_scale = (1e-2,)

    def __init__(self, sigma_log: float | None = None):
        self.sigma_log = sigma_log

    def apply(self, state: PoseState, x: np.ndarray) -> PoseState:
        state.params[self.name] = x
        s = float(np.exp(x[0]))
        state.intr = replace(state.intr, fx=state.intr.fx * s, fy=state.intr.fy * s)
        return state

    def residuals(self, state: PoseState) -> np.ndarray:
        if self.sigma_log is None:
            return np.zeros(0)
        return np.asarray(state.params[self.name], dtype=np.float64) / self.sigma_log


def shift_principal_point(intr: CameraIntrinsics, dx_px: float, dy_px: float) -> CameraIntrinsics:
    """``intr`` with (cx, cy) moved by (dx, dy) px; with a known image size held within 20 % of it
    beyond the edges (a trial step of a fit far outside the image is not an intrinsics error)."""
    cx, cy = intr.cx + dx_px, intr.cy + dy_px
    W, H = intr.width, intr.height
    if W is not None and H is not None:
        cx, cy = float(np.clip(cx, -0.2 * W, 1.2 * W)), float(np.clip(cy, -0.2 * H, 1.2 * H))
    return replace(intr, cx=cx, cy=cy)


class PrincipalPointTerm(CostTerm):
    """Two parameters: the shift (px) of the principal point (cx, cy); with ``sigma_px`` a Gaussian
    prior on it."""

    name = "principal_point"
    n_params = 2
    x_scale = (1.0, 1.0)

    def __init__(self, sigma_px: float | None = None):
        self.sigma_px = sigma_px

    def apply(self, state: PoseState, x: np.ndarray) -> PoseState:
        state.params[self.name] = x
        state.intr = shift_principal_point(state.intr, float(x[0]), float(x[1]))
        return state

    def residuals(self, state: PoseState) -> np.ndarray:
        if self.sigma_px is None:
            return np.zeros(0)
        return np.asarray(state.params[self.name], dtype=np.float64) / self.sigma_px


class TimeOffsetTerm(CostTerm):
    """One parameter: dt = camera time - LiDAR time (s). Each matched 3D outline moves by
    ``velocity_mps`` [n,3] (LiDAR frame, relative to the rig) times dt: where the object was when
    the camera exposed. ``dt0`` is a fixed offset the parameter is added to."""

    name = "time_offset"
    n_params = 1
    x_scale = (1e-2,)

    def __init__(self, velocity_mps: np.ndarray, dt0: float = 0.0):
        self.v, self.dt0 = np.asarray(velocity_mps, dtype=np.float64).reshape(-1, 3), float(dt0)

    def apply(self, state: PoseState, x: np.ndarray) -> PoseState:
        state.params[self.name] = x
        shift = self.v * (self.dt0 + float(x[0]))
        state.shift_m = shift if state.shift_m is None else state.shift_m + shift
        return state

    def residuals(self, state: PoseState) -> np.ndarray:
        return np.zeros(0)


@dataclass
class CostFit:
    """A fitted cost: the pose, each term's parameters, the robust cost and the residuals at the optimum."""

    pose: Pose
    params: dict[str, np.ndarray]
    cost: float
    residuals: np.ndarray
    x: np.ndarray


class CostModel:
    """Terms around a linearisation pose ``pose0``; parameters as described in the module docstring."""

    def __init__(self, terms: list[CostTerm], pose0: Pose, intr: CameraIntrinsics):
        self.terms, self.pose0, self.intr = list(terms), pose0, intr

    @property
    def n_params(self) -> int:
        return 6 + sum(t.n_params for t in self.terms)

    def state(self, x: np.ndarray) -> PoseState:
        st = PoseState(self.pose0.moved(x[:3], x[3:6]), self.intr)
        k = 6
        for term in self.terms:
            if term.n_params:
                st = term.apply(st, x[k:k + term.n_params])
                k += term.n_params
        return st

    def residuals(self, x: np.ndarray) -> np.ndarray:
        st = self.state(x)
        return np.concatenate([term.residuals(st) for term in self.terms])

    def clusters(self) -> np.ndarray:
        """Cluster per residual; residuals of terms without clusters are their own cluster."""
        out, base = [], 0
        st = self.state(np.zeros(self.n_params))
        for term in self.terms:
            c = term.clusters()
            n = len(term.residuals(st)) if c is None else len(c)
            c = np.arange(n) if c is None else np.asarray(c)
            out.append(c + base)
            base += int(c.max()) + 1 if len(c) else 0
        return np.concatenate(out) if out else np.zeros(0, dtype=np.int64)

    def x_scale(self) -> np.ndarray:
        return np.concatenate([POSE_X_SCALE, *[t.x_scale for t in self.terms if t.n_params]])

    def fit(self, *, f_scale: float, max_nfev: int, loss: str = "soft_l1") -> CostFit:
        res = least_squares(self.residuals, np.zeros(self.n_params), loss=loss, f_scale=f_scale, method="trf",
                            x_scale=self.x_scale(), max_nfev=max_nfev)
        st = self.state(res.x)
        return CostFit(pose=st.pose, params=dict(st.params), cost=float(res.cost), residuals=res.fun, x=res.x)

    def jacobian(self, x: np.ndarray | None = None, eps: float = 1e-6) -> tuple[np.ndarray, np.ndarray]:
        """(residuals r0, numeric Jacobian J [len(r0), n_params]) at ``x`` (default 0)."""
        x = np.zeros(self.n_params) if x is None else np.asarray(x, float)
        r0 = self.residuals(x)
        J = np.zeros((len(r0), self.n_params))
        for k in range(self.n_params):
            dx = np.zeros(self.n_params)
            dx[k] = eps
            J[:, k] = (self.residuals(x + dx) - self.residuals(x - dx)) / (2 * eps)
        return r0, J
