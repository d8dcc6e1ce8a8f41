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
* ``WideLensTerm``: a pinhole camera widened into Mei's unified model by one parameter ``xi``
  (0: the given pinhole); used by the lens-misfit check (``misfit.lens_check``).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from scipy.optimize import least_squares

from ..geometry.camera import CameraIntrinsics
from ..geometry.camera_models import CameraModel, Unified
from ..geometry.camera_models import pixels_per_metre as camera_pixels_per_metre
from ..geometry.camera_models.outline import outline_extremes, outline_rects_and_extremes
from ..geometry.rotations import so3_left_jacobian
from .boxproj import MIN_DEPTH_M, project_ragged, project_rects, ragged_outlines
from .diagnostics import NoiseModel
from .pose import Pose
from .solver import LOSSES, trf_fit

__all__ = ["shift_principal_point", "PoseState", "CostTerm", "Occlusion", "BoxEdgeTerm", "PosePriorTerm", "FocalScaleTerm",
           "PrincipalPointTerm", "TimeOffsetTerm", "WideLensTerm", "CostModel", "Tangent", "CostFit", "edge_sigma", "INWARD", "POSE_X_SCALE"]

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

    def tangents(self, state: PoseState, x: np.ndarray, base: CameraIntrinsics) -> list["Tangent"] | None:
        """Per parameter, how the state moves with it (for the analytic Jacobian); None: unknown
        (the model then falls back to finite differences). ``base``: the model's intrinsics."""
        return [] if not self.n_params else None

    def own_jacobian(self, state: PoseState, n_params: int, col: int) -> np.ndarray | None:
        """d residuals / d x [n, n_params] of a term whose residuals depend on its own parameters
        only (``col``: where they start); None: not known (finite differences)."""
        return None

    #: True for a term whose residuals depend on the pose and on its own parameters and that gives their
    #: derivative (``pose_jacobian``): its parameters then leave the model's Jacobian analytic
    has_pose_jacobian: bool = False

    def pose_jacobian(self, state: PoseState, rotvec: np.ndarray, tangents: list["Tangent"], col: int) -> np.ndarray:
        """d residuals / d x [n, 6 + len(tangents)] of a ``has_pose_jacobian`` term (``col``: where its own
        parameters start; ``tangents``: every parameter's, as ``BoxEdgeTerm.jacobian`` takes them)."""
        raise NotImplementedError


@dataclass(frozen=True)
class Tangent:
    """The derivative of the state with respect to one parameter: of fx, fy, cx, cy (px), of
    the outline shift (LiDAR frame, m, [n,3] or None) and of a ``WideLensTerm``'s unified-model
    ``xi`` (whose focal length f (1 + xi) moves with it)."""

    fx: float = 0.0
    fy: float = 0.0
    cx: float = 0.0
    cy: float = 0.0
    shift: np.ndarray | None = None
    xi: float = 0.0


@dataclass(frozen=True)
class Occlusion:
    """Occlusion (and a detector's truncation) only ever moves a 2D box edge *into* the projected
    outline: inward residuals beyond ``tau`` (sigma units) are compressed by ``slope``.

    ``censor``: an edge of a matched 2D box that lies on a nearer matched box's 2D box (LiDAR range
    order, ``censor.occluded_edges``) is a bound, not a measurement: only its outward residual counts
    (a hinge at 0; the edge term builds the mask, ``CalibConfig.censor_occluded_edges``); "auto":
    only where the residuals show those edges inside the projection (``censor.censor_evidence``)."""

    tau: float = 1.5
    slope: float = 0.2
    censor: bool | str = False

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
               noise: NoiseModel, outline_sigma_m: np.ndarray | None = None,
               scores: np.ndarray | None = None) -> np.ndarray:
    """Per-pair 1-sigma (px) of an edge residual at ``pose`` under the error model ``noise``, plus
    each outline's own uncertainty ``outline_sigma_m`` [n] (m, seen at depth Z; e.g. a 3D box
    whose yaw the LiDAR points leave open) and, where ``noise.sigma_score`` > 0, the part that grows
    as the 2D box's detector score ``scores`` [n] falls below ``noise.score_ref`` (None: no scores)."""
    s, fz = _pair_features(obs, outlines, intr, pose)
    var = noise.sigma_px ** 2 + (fz * noise.sigma_3d_m) ** 2 + (noise.sigma_size * s) ** 2
    if outline_sigma_m is not None:
        var = var + (fz * np.asarray(outline_sigma_m, dtype=np.float64)) ** 2
    if scores is not None and noise.sigma_score > 0:
        deficit = np.clip(noise.score_ref - np.asarray(scores, dtype=np.float64), 0.0, None)
        var = var + (noise.sigma_score * s * deficit) ** 2
    return np.sqrt(var)


def _distort_with_jacobian(x: np.ndarray, y: np.ndarray, d: np.ndarray):
    """OpenCV distortion of normalised coordinates (clamped to +-1.5 as ``boxproj.project_rects``)
    and its Jacobian: (xd, yd, dxd/dx, dxd/dy, dyd/dx, dyd/dy), zero across a clamped coordinate."""
    if np.any(d[12:14]):
        raise NotImplementedError("tilted-sensor distortion (tauX, tauY) is not supported")
    k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4 = d[:12]
    mx, my = (np.abs(x) < 1.5).astype(np.float64), (np.abs(y) < 1.5).astype(np.float64)
    x, y = np.clip(x, -1.5, 1.5), np.clip(y, -1.5, 1.5)
    r2 = x * x + y * y
    r4 = r2 * r2
    a = 1 + k1 * r2 + k2 * r4 + k3 * r4 * r2
    b = 1 + k4 * r2 + k5 * r4 + k6 * r4 * r2
    radial = a / b
    drad = ((k1 + 2 * k2 * r2 + 3 * k3 * r4) * b - a * (k4 + 2 * k5 * r2 + 3 * k6 * r4)) / (b * b)  # d radial / d r2
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x) + s1 * r2 + s2 * r4
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y + s3 * r2 + s4 * r4
    tx, ty = s1 + 2 * s2 * r2, s3 + 2 * s4 * r2  # thin prism, per d r2
    a11 = radial + 2 * x * x * drad + 2 * p1 * y + 6 * p2 * x + 2 * x * tx
    a12 = 2 * x * y * drad + 2 * p1 * x + 2 * p2 * y + 2 * y * tx
    a21 = 2 * x * y * drad + 2 * p1 * x + 2 * p2 * y + 2 * x * ty
    a22 = radial + 2 * y * y * drad + 6 * p1 * y + 2 * p2 * x + 2 * y * ty
    return xd, yd, a11 * mx, a12 * my, a21 * mx, a22 * my


class BoxEdgeTerm(CostTerm):
    """Edges of projected 3D outlines [n,S,3] (LiDAR frame, m) vs matched 2D boxes [n,4] (px)."""

    name = "box_edges"

    def __init__(self, outlines: np.ndarray, obs: np.ndarray, size: tuple[int, int], sigma_px: np.ndarray,
                 occlusion: Occlusion | None = Occlusion(), censored: np.ndarray | None = None):
        self.outlines, self.obs, self.size = outlines, obs, size
        # [n,4] edges that are only a bound (hidden behind a nearer box): inward residuals cost 0
        self.censored = None if censored is None or not np.any(censored) else np.asarray(censored, dtype=bool)
        self.w = (1.0 / np.asarray(sigma_px, dtype=np.float64))[:, None]
        self.occlusion = occlusion
        # an edge that cannot be projected (behind the camera) costs the box's own size
        self.fallback = np.sqrt((obs[:, 2] - obs[:, 0]) * (obs[:, 3] - obs[:, 1]))[:, None]
        self._last = None  # the last projection (see _projection)
        self._ragged = None  # the outlines without their padding (see _projection), made on first use

    def edges(self, state: PoseState) -> np.ndarray:
        """Unweighted, unshaped residuals [n,4] (px): projected rectangle - 2D box."""
        rects, valid = self._projection(state)[:2]
        return np.where(valid[:, None], rects - self.obs, self.fallback)

    def _projection(self, state: PoseState):
        """The projection of the outlines at ``state``: (rects, valid, u, v). For a
        ``CameraIntrinsics``, ``boxproj.project_ragged`` of the outlines without their padding
        (the same rects and valid as ``project_rects``; a fit's outlines are padded to the longest
        one, most of them several times over, and the padding was projected at every step), the
        vertices' pixels u, v [N]; for another camera model,
        ``project_rects``' rects and valid, the rest None. The last one is kept: least squares
        asks for the residuals and then the Jacobian at the same point. Keyed by everything the
        projection depends on."""
        intr = state.intr
        if not isinstance(intr, CameraIntrinsics) or not len(self.obs):  # rects only (see _model_jacobian)
            return self._model_projection(state)[:2] + (None, None)
        key = (state.pose.R.tobytes(), state.pose.t.tobytes(), intr.fx, intr.fy, intr.cx, intr.cy,
               None if intr.distortion is None else np.asarray(intr.distortion, dtype=np.float64).tobytes(),
               None if state.shift_m is None else np.asarray(state.shift_m).tobytes())
        if self._last is not None and self._last[0] == key:
            return self._last[1]
        out = project_ragged(self._points(state.shift_m), self.ragged.starts, state.pose.R, state.pose.t, intr,
                             self.size)
        self._last = (key, out)
        return out

    def _model_projection(self, state: PoseState):
        """(rects, valid, points) at ``state`` for a camera model (or no boxes): ``project_rects``' rects
        and valid and, for a ``CameraModel``, the outline points [n,4,3] defining each edge, found in
        the same projection (``outline_rects_and_extremes``; None where that call does not
        give them): :meth:`_model_jacobian` differentiates at them instead of projecting the outlines
        again at the pose of the residuals. Kept, keyed by everything the projection depends on."""
        intr = state.intr
        key = (state.pose.R.tobytes(), state.pose.t.tobytes(), intr,
               None if state.shift_m is None else np.asarray(state.shift_m).tobytes())
        if self._last is not None and self._last[0] == key:
            return self._last[1]
        outlines = self.outlines if state.shift_m is None else self.outlines + state.shift_m[:, None, :]
        if isinstance(intr, CameraModel) and len(self.obs):
            out = outline_rects_and_extremes(outlines, state.pose.R, state.pose.t, intr, self.size,
                                             min_distance=MIN_DEPTH_M)
        else:
            out = project_rects(outlines, state.pose.R, state.pose.t, intr, self.size) + (None,)
        self._last = (key, out)
        return out

    @property
    def ragged(self):
        """``boxproj.ragged_outlines`` of the outlines (made once)."""
        if self._ragged is None:
            self._ragged = ragged_outlines(self.outlines)
        return self._ragged

    def _points(self, shift_m) -> np.ndarray:
        """The outlines' vertices without padding [N,3], each moved by its outline's ``shift_m``
        [n,3] (None: not moved; the same sums as ``outlines + shift_m[:, None, :]``)."""
        rg = self.ragged
        return rg.flat if shift_m is None else rg.flat + np.repeat(np.asarray(shift_m), rg.lengths, axis=0)

    def shape(self, r: np.ndarray) -> np.ndarray:
        """Weighted edge residuals [n,4] -> the cost's residuals [n,4]: the occlusion shaping, then
        the censored edges' inward residuals set to 0 (only an outward one counts)."""
        if self.occlusion is not None:
            r = self.occlusion.shape(r)
        if self.censored is not None:
            r = np.where(self.censored & (r * INWARD > 0), 0.0, r)
        return r

    def shape_slope(self, r: np.ndarray) -> np.ndarray:
        """d shape / d r [n,4] at the weighted residuals ``r`` [n,4]."""
        g = np.ones_like(r)
        if self.occlusion is not None:
            g = np.where(r * INWARD > self.occlusion.tau, self.occlusion.slope, g)
        if self.censored is not None:
            g = np.where(self.censored & (r * INWARD > 0), 0.0, g)
        return g

    def residuals(self, state: PoseState) -> np.ndarray:
        return self.shape(self.edges(state) * self.w).ravel()

    def clusters(self) -> np.ndarray:
        return np.repeat(np.arange(len(self.obs)), 4)

    def jacobian(self, state: PoseState, rotvec: np.ndarray, extra: list[Tangent]) -> np.ndarray:
        """d residuals / d (rotvec, dt, extra parameters) [4n, 6 + len(extra)], analytic: the
        derivative of each rectangle edge is that of the corner defining it (zero where the edge
        is clipped to the image or the box cannot be projected), through the distortion model and
        the occlusion shaping. ``rotvec``: the rotation part of x (the pose is exp([w]x) R0).
        Only the (at most 4) extreme corners of each outline are differentiated."""
        D = self.weighted_jacobian(state, rotvec, extra)
        if len(self.obs) and (self.occlusion is not None or self.censored is not None):
            D = D * self.shape_slope(self.edges(state) * self.w)[..., None]
        return D.reshape(4 * len(self.obs), D.shape[-1])

    def weighted_jacobian(self, state: PoseState, rotvec: np.ndarray, extra: list[Tangent]) -> np.ndarray:
        """:meth:`jacobian` before the occlusion shaping, per edge [n,4,6 + len(extra)]: d (edges x w) / d x
        (a variant that moves the edges further, ``boxmodel``'s outline offsets, shapes its own edges)."""
        n, P = len(self.obs), 6 + len(extra)
        if n == 0:
            return np.zeros((0, 4, P))
        if not isinstance(state.intr, CameraIntrinsics):
            return self._model_jacobian(state, rotvec, extra)
        R, t, intr = state.pose.R, state.pose.t, state.intr
        rects, valid, u, v = self._projection(state)
        W, H = self.size
        lim = np.array([W, H, W, H], dtype=np.float64)
        # an edge clipped to the image does not move: the unclipped edge e (the defining corner's u or
        # v) lies strictly inside (0, lim) exactly where the rectangle, clipped to [0, lim], does (a
        # clipped edge is 0 or lim; an invalid rectangle is NaN: False)
        with np.errstate(invalid="ignore"):
            inside = (rects > 0.0) & (rects < lim)
        # derivatives at the defining corners only [n,4,...]
        sel = self._points(None)[self._defining(u, v, valid)]
        if state.shift_m is not None:
            sel = sel + np.asarray(state.shift_m)[:, None, :]
        Ys = _rows_matmul(sel, R.T)
        izs = 1.0 / np.where(valid[:, None], Ys[..., 2] + t[2], 1.0)
        xs, ys = (Ys[..., 0] + t[0]) * izs, (Ys[..., 1] + t[1]) * izs
        dist = _distortion(intr)
        if dist is None:
            xds, yds, a11, a12, a21, a22 = xs, ys, 1.0, 0.0, 0.0, 1.0
        else:
            xds, yds, a11, a12, a21, a22 = _distort_with_jacobian(xs, ys, dist)
        is_u = np.array([True, False, True, False])
        f = np.where(is_u, intr.fx, intr.fy)
        c1 = f * np.where(is_u, a11, a21)  # d edge / d xn
        c2 = f * np.where(is_u, a12, a22)  # d edge / d yn
        a = np.stack([c1 * izs, c2 * izs, -(c1 * xs + c2 * ys) * izs], -1)  # d edge / d X_cam [n,4,3]
        D = np.empty((n, 4, P))
        cr = np.empty_like(a)  # R c x a (np.cross costs more than the arithmetic at these sizes)
        cr[..., 0] = Ys[..., 1] * a[..., 2] - Ys[..., 2] * a[..., 1]
        cr[..., 1] = Ys[..., 2] * a[..., 0] - Ys[..., 0] * a[..., 2]
        cr[..., 2] = Ys[..., 0] * a[..., 1] - Ys[..., 1] * a[..., 0]
        D[..., :3] = _rows_matmul(cr, so3_left_jacobian(rotvec))  # rotation: (R c x a) J_l
        D[..., 3:6] = a
        dn = np.where(is_u, xds, yds)
        for k, tg in enumerate(extra):
            col = np.where(is_u, tg.fx, tg.fy) * dn + np.where(is_u, tg.cx, tg.cy)
            if tg.shift is not None:
                col = col + np.einsum("nek,nk->ne", a, tg.shift @ R.T)
            D[..., 6 + k] = col
        D *= ((inside & valid[:, None]) * self.w)[..., None]
        return D


    def _defining(self, u: np.ndarray, v: np.ndarray, valid: np.ndarray) -> np.ndarray:
        """[n,4] rows of the unpadded vertices (``ragged.flat``) that define each rectangle's edges
        (u min, v min, u max, v max): ``argmin`` / ``argmax`` over the padded row, the first vertex
        at the extreme (never on the padding, a copy of the first vertex after the others);
        an invalid rectangle's first vertex (its derivative is zeroed)."""
        rg = self.ragged
        uu, vv = u[rg.padded], v[rg.padded]  # [n,S] the padded rows' pixels
        idx = np.column_stack([uu.argmin(1), vv.argmin(1), uu.argmax(1), vv.argmax(1)])  # (never on the padding)
        idx += rg.starts[:, None]
        return np.where(valid[:, None], idx, rg.starts[:, None])

    def _model_jacobian(self, state: PoseState, rotvec: np.ndarray, extra: list[Tangent]) -> np.ndarray:
        """:meth:`weighted_jacobian` for a camera model (``xcalib.geometry.camera_models``): each rectangle
        edge moves with the outline point that defines it (``outline_extremes``: the extreme of the
        densified edges), through the model's own Jacobian ``project_jacobian``; the rest as for
        ``CameraIntrinsics``."""
        n, P = len(self.obs), 6 + len(extra)
        R, t, cam = state.pose.R, state.pose.t, state.intr
        rects, valid, sel = self._model_projection(state)
        if sel is None:  # [n,4,3] the points defining u_min, v_min, u_max, v_max
            outlines = self.outlines if state.shift_m is None else self.outlines + np.asarray(state.shift_m)[:, None, :]
            sel = outline_extremes(outlines, R, t, cam)
        Ys = _rows_matmul(sel, R.T)
        uv, Juv, _ = cam.project_jacobian((Ys + t).reshape(-1, 3))
        comp = np.array([0, 1, 0, 1])  # u, v, u, v
        ext = uv.reshape(n, 4, 2)[:, np.arange(4), comp]  # [n,4] the unclipped edges
        a = Juv.reshape(n, 4, 2, 3)[:, np.arange(4), comp, :]  # d edge / d X_cam [n,4,3]
        good = valid[:, None] & np.isfinite(ext) & np.all(np.isfinite(a), axis=2)
        ext, a = np.where(good, ext, 0.0), np.where(good[..., None], a, 0.0)
        W, H = self.size
        inside = (ext > 0.0) & (ext < np.array([W, H, W, H], dtype=np.float64))
        D = np.empty((n, 4, P))
        cr = np.empty_like(a)  # R c x a
        cr[..., 0] = Ys[..., 1] * a[..., 2] - Ys[..., 2] * a[..., 1]
        cr[..., 1] = Ys[..., 2] * a[..., 0] - Ys[..., 0] * a[..., 2]
        cr[..., 2] = Ys[..., 0] * a[..., 1] - Ys[..., 1] * a[..., 0]
        D[..., :3] = _rows_matmul(cr, so3_left_jacobian(rotvec))
        D[..., 3:6] = a
        is_u = comp == 0
        dn = (ext - np.where(is_u, cam.cx, cam.cy)) / np.where(is_u, cam.fx, cam.fy)  # u = fx * dn + cx
        for k, tg in enumerate(extra):
            col = np.where(is_u, tg.fx, tg.fy) * dn + np.where(is_u, tg.cx, tg.cy)
            if tg.shift is not None:
                col = col + np.einsum("nek,nk->ne", a, tg.shift @ R.T)
            if tg.xi:
                col = col + tg.xi * _xi_slope(cam, Ys + t, ext - np.where(is_u, cam.cx, cam.cy), a)
            D[..., 6 + k] = col
        D *= ((inside & good) * self.w)[..., None]
        return D


def _xi_slope(cam: Unified, X: np.ndarray, centred: np.ndarray, a: np.ndarray) -> np.ndarray:
    """d edge / d xi [n,4] of a unified camera whose focal length is f (1 + xi) (``WideLensTerm``), at
    the camera-frame points ``X`` [n,4,3] defining the edges (the extreme's own move along its edge
    is of second order): u - cx = f (1 + xi) D(m), m = (X, Y) / (Z + xi |P|), so
    d u / d xi = (u - cx) / (1 + xi) + f (1 + xi) dD/dm . dm/dxi, and dm/dxi = -m |P| / (Z + xi |P|) is
    what moving the point along the optical axis by |P|^2 / (|P| + xi Z) does to m: the second term
    is the point's own derivative ``a`` [n,4,3] (d edge / d X_cam) along z times that. ``centred``:
    the edges minus the principal point. Rows that are not finite give 0 (invalid rows are masked)."""
    d = np.sqrt(np.einsum("nek,nek->ne", X, X))
    with np.errstate(divide="ignore", invalid="ignore"):
        out = centred / (1.0 + cam.xi) + a[..., 2] * (d * d / (d + cam.xi * X[..., 2]))
    return np.where(np.isfinite(out), out, 0.0)


def _rows_matmul(a: np.ndarray, m: np.ndarray) -> np.ndarray:
    """``a @ m`` for a [..., k] stack of rows and one [k, j] matrix, as one matrix product (numpy's
    stacked ``@`` makes one small product per leading index: most of the Jacobian's time)."""
    return (a.reshape(-1, a.shape[-1]) @ m).reshape(a.shape[:-1] + (m.shape[1],))


def _distortion(intr: CameraIntrinsics) -> np.ndarray | None:
    """The 14 OpenCV coefficients of ``intr`` (None when there is no distortion)."""
    if intr.distortion is None:
        return None
    d = np.zeros(14)
    v = np.asarray(intr.distortion, dtype=np.float64).reshape(-1)
    d[: v.size] = v
    return d if np.any(d) else None


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

    def tangents(self, state: PoseState, x: np.ndarray, base: CameraIntrinsics) -> list[Tangent]:
        return [Tangent(fx=state.intr.fx, fy=state.intr.fy)]  # d (f e^x) / dx = f e^x

    def own_jacobian(self, state: PoseState, n_params: int, col: int) -> np.ndarray:
        J = np.zeros((0 if self.sigma_log is None else 1, n_params))
        if self.sigma_log is not None:
            J[0, col] = 1.0 / self.sigma_log
        return J


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

    def tangents(self, state: PoseState, x: np.ndarray, base: CameraIntrinsics) -> list[Tangent]:
        W, H = base.width, base.height
        cx, cy = base.cx + float(x[0]), base.cy + float(x[1])  # held within the image (20 %): no derivative there
        inx = 1.0 if W is None or H is None or -0.2 * W < cx < 1.2 * W else 0.0
        iny = 1.0 if W is None or H is None or -0.2 * H < cy < 1.2 * H else 0.0
        return [Tangent(cx=inx), Tangent(cy=iny)]

    def own_jacobian(self, state: PoseState, n_params: int, col: int) -> np.ndarray:
        J = np.zeros((0 if self.sigma_px is None else 2, n_params))
        if self.sigma_px is not None:
            J[0, col], J[1, col + 1] = 1.0 / self.sigma_px, 1.0 / self.sigma_px
        return J


class WideLensTerm(CostTerm):
    """One parameter ``xi`` >= 0 that widens a pinhole ``CameraIntrinsics`` (with at most the
    radial-tangential k1, k2, p1, p2) into Mei's unified model ``Unified(xi)`` whose focal length
    is ``f (1 + xi)``: the same scale at the image centre, ever more compressed towards the rim
    (``xi = 0``: the given pinhole; ~1.75: close to an equidistant fisheye over 180 degrees).
    ``fixed``: hold ``xi`` at this value (the pinhole alternative, projected the same way). Put a
    ``FocalScaleTerm`` after it to free the focal length too. ``start``: the fit's first ``xi``
    (its parameter is the step from there). Its Jacobian column is analytic (``Tangent.xi``, the
    unified model's derivative at the points defining the edges, ``_xi_slope``; a forward difference
    beside a term with its own ``pose_jacobian``), as are the pose and focal columns (the unified
    model's own ``project_jacobian``)."""

    name = "wide_lens_xi"
    n_params = 1
    x_scale = (0.05,)
    MAX_XI = 4.0

    def __init__(self, base: CameraIntrinsics, fixed: float | None = None, start: float = 0.0):
        d = np.zeros(0) if base.distortion is None else np.asarray(base.distortion, dtype=np.float64)
        if np.any(d[4:]):
            raise ValueError("WideLensTerm: only k1, k2, p1, p2 distortion can be widened")
        self.base, self.fixed, self.start = base, fixed, float(start)
        self.d4 = tuple(float(v) for v in np.pad(d[:4], (0, 4 - len(d[:4])))) if np.any(d) else ()

    @staticmethod
    def applies(intr) -> bool:
        """True for a pinhole ``CameraIntrinsics`` whose distortion the unified model carries."""
        if not isinstance(intr, CameraIntrinsics):
            return False
        return intr.distortion is None or not np.any(np.asarray(intr.distortion, dtype=np.float64)[4:])

    def camera(self, xi: float) -> Unified:
        b = self.base
        return Unified(fx=b.fx * (1 + xi), fy=b.fy * (1 + xi), cx=b.cx, cy=b.cy, width=b.width, height=b.height,
                       xi=xi, distortion=self.d4)

    def apply(self, state: PoseState, x: np.ndarray) -> PoseState:
        xi = float(np.clip(self.start + x[0], 0.0, self.MAX_XI)) if self.fixed is None else float(self.fixed)
        state.params[self.name] = np.array([xi])
        state.intr = self.camera(xi)
        return state

    def tangents(self, state: PoseState, x: np.ndarray, base: CameraIntrinsics) -> list[Tangent]:
        """d xi / d x: 1 inside [0, ``MAX_XI``], 0 where the clip holds it or ``fixed`` (at a bound, the
        side a forward step towards x's sign takes, as the finite difference it replaces)."""
        if self.fixed is not None:
            return [Tangent()]
        v, up = self.start + float(x[0]), float(x[0]) >= 0.0
        free = 0.0 < v < self.MAX_XI or (v == 0.0 and up) or (v == self.MAX_XI and not up)
        return [Tangent(xi=1.0 if free else 0.0)]

    def residuals(self, state: PoseState) -> np.ndarray:
        return np.zeros(0)

    def own_jacobian(self, state: PoseState, n_params: int, col: int) -> np.ndarray:
        return np.zeros((0, n_params))


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

    def tangents(self, state: PoseState, x: np.ndarray, base: CameraIntrinsics) -> list[Tangent]:
        return [Tangent(shift=self.v)]

    def own_jacobian(self, state: PoseState, n_params: int, col: int) -> np.ndarray:
        return np.zeros((0, n_params))


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
        self._last_state: tuple[bytes, PoseState] | None = None  # see state

    @property
    def n_params(self) -> int:
        return 6 + sum(t.n_params for t in self.terms)

    def state(self, x: np.ndarray) -> PoseState:
        """The state at ``x``. The last one is kept, keyed by x's bytes: least squares asks for the
        residuals and then the Jacobian at the same x (a state is only read once built: the terms
        change it in ``apply`` alone)."""
        x = np.array(x, dtype=np.float64)  # our own copy: the state keeps views of it
        key = x.tobytes()
        if self._last_state is not None and self._last_state[0] == key:
            return self._last_state[1]
        st = PoseState(self.pose0.moved(x[:3], x[3:6]), self.intr)
        k = 6
        for term in self.terms:
            if term.n_params:
                st = term.apply(st, x[k:k + term.n_params])
                k += term.n_params
        self._last_state = (key, st)
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
        """The robust fit from x = 0: scipy's trust-region least squares (``method="trf"``), run by
        ``solver.trf_fit`` (the same algorithm and iterates, without scipy's per-call machinery) where
        the Jacobian is analytic, by scipy itself where it is numeric."""
        if self.has_analytic_jacobian() and loss in LOSSES:
            res = trf_fit(self.residuals, self.analytic_jacobian, np.zeros(self.n_params), self.x_scale(), loss=loss,
                          f_scale=f_scale, max_nfev=max_nfev)
        else:
            jac = self.analytic_jacobian if self.has_analytic_jacobian() else "2-point"
            res = least_squares(self.residuals, np.zeros(self.n_params), jac=jac, loss=loss, f_scale=f_scale,
                                method="trf", x_scale=self.x_scale(), max_nfev=max_nfev)
        st = self.state(res.x)
        return CostFit(pose=st.pose, params=dict(st.params), cost=float(res.cost), residuals=res.fun, x=res.x)

    _TANGENT_TERMS = (FocalScaleTerm, PrincipalPointTerm, TimeOffsetTerm)
    #: terms whose parameters may get a forward-difference column (the rest of the Jacobian analytic):
    #: ``WideLensTerm``'s xi where a ``has_pose_jacobian`` term is in the model (elsewhere its tangent)
    NUMERIC_TERMS = (WideLensTerm,)

    def has_analytic_jacobian(self) -> bool:
        """True when every parameterised term is one whose effect on the projection is known (each
        at most once): focal scale, principal point, time offset, one with its own ``pose_jacobian``
        (``boxmodel``'s outline offsets) -- or a ``NUMERIC_TERMS`` one, whose own columns are then
        forward differences."""
        kinds = [type(t) for t in self.terms if t.n_params]
        # the derivative is the pinhole-radtan model's, or a camera model's own (project_jacobian)
        return (isinstance(self.intr, (CameraIntrinsics, CameraModel))
                and all(k in self._TANGENT_TERMS + self.NUMERIC_TERMS or k.has_pose_jacobian for k in kinds)
                and len(set(kinds)) == len(kinds))

    def analytic_jacobian(self, x: np.ndarray) -> np.ndarray:
        """d residuals / d x [len(residuals), n_params]: the box-edge terms analytically
        (``BoxEdgeTerm.jacobian``), the others from their own derivative or, where a term gives
        none (a pose prior), by central differences of that term alone (no projection)."""
        x = np.asarray(x, dtype=np.float64)
        st = self.state(x)
        n = self.n_params
        tangents: list[Tangent] = []
        cols, k, numeric = [], 6, []
        for term in self.terms:
            if term.n_params:
                tg = term.tangents(st, x[k:k + term.n_params], self.intr)
                if tg is None or (any(g.xi for g in tg) and any(t.has_pose_jacobian for t in self.terms)):
                    # a term with no tangent, or a lens xi beside a term that differentiates the pose
                    # itself (it knows fx, cx, shift, not xi): its columns below, by forward differences
                    tg = [Tangent()] * term.n_params
                    numeric += list(range(k, k + term.n_params))
                tangents += tg
                cols.append(k)
                k += term.n_params
            else:
                cols.append(-1)
        blocks = []
        for term, col in zip(self.terms, cols):
            if type(term) is BoxEdgeTerm:
                blocks.append(term.jacobian(st, x[:3], tangents))
                continue
            if term.has_pose_jacobian:
                blocks.append(term.pose_jacobian(st, x[:3], tangents, col))
                continue
            J = term.own_jacobian(st, n, col) if term.n_params else None
            if J is None:
                J = self._term_differences(term, x)
            blocks.append(J)
        J = np.concatenate(blocks) if blocks else np.zeros((0, n))
        if numeric:
            J[:, numeric] = self._forward_columns(x, numeric)
        return J

    def _forward_columns(self, x: np.ndarray, cols: list[int]) -> np.ndarray:
        """Forward differences of all residuals along the parameters ``cols`` [len(r), len(cols)],
        with the step of scipy's "2-point" scheme (sqrt(eps) max(1, |x|), towards x's sign)."""
        r0 = self.residuals(x)
        out = np.empty((len(r0), len(cols)))
        for j, k in enumerate(cols):
            h = np.sqrt(np.finfo(np.float64).eps) * (1.0 if x[k] >= 0 else -1.0) * max(1.0, abs(float(x[k])))
            xh = x.copy()
            xh[k] = x[k] + h
            out[:, j] = (self.residuals(xh) - r0) / (xh[k] - x[k])
        return out

    def _term_differences(self, term: CostTerm, x: np.ndarray, eps: float = 1e-6) -> np.ndarray:
        r0 = term.residuals(self.state(x))
        J = np.zeros((len(r0), self.n_params))
        for k in range(self.n_params):
            dx = np.zeros(self.n_params)
            dx[k] = eps
            J[:, k] = (term.residuals(self.state(x + dx)) - term.residuals(self.state(x - dx))) / (2 * eps)
        return J

    def jacobian(self, x: np.ndarray | None = None, eps: float = 1e-6) -> tuple[np.ndarray, np.ndarray]:
        """(residuals r0, Jacobian J [len(r0), n_params]) at ``x`` (default 0): analytic where
        ``has_analytic_jacobian`` (pinhole-radtan cameras), else central differences with step ``eps``."""
        x = np.zeros(self.n_params) if x is None else np.asarray(x, float)
        r0 = self.residuals(x)
        if self.has_analytic_jacobian():
            return r0, self.analytic_jacobian(x)
        J = np.zeros((len(r0), self.n_params))
        for k in range(self.n_params):
            dx = np.zeros(self.n_params)
            dx[k] = eps
            J[:, k] = (self.residuals(x + dx) - self.residuals(x - dx)) / (2 * eps)
        return r0, J
