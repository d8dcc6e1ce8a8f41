"""3D box models for calibration: the 3D boxes' shapes from the LiDAR points (``boxshape``: yaw
re-estimation, point hulls; re-exported here) and the 2D outline of a 3D box as a detector draws
it, a nuisance fitted with the pose (``outline_edge_term``, ``fit_outline``).

``boxshape`` sits below the refinement (``inputs`` uses it); this module above it
(``fit_outline`` fits with ``refine.build_cost``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .boxshape import (YawFit, YawFitSettings, estimate_yaw_from_points, expand_by_scan_gap,  # noqa: F401
                       fit_yaw_to_points, lidar_angular_step, shapes_from_points)

__all__ = ["YawFit", "fit_yaw_to_points", "estimate_yaw_from_points", "lidar_angular_step", "expand_by_scan_gap",
           "outline_edge_term", "fit_outline", "OUTLINE_PRIOR", "OUTLINE_PARAMS",
           "shapes_from_points", "ObjectOutlineFit", "object_outline_spread", "fit_object_outline",
           "outline_kinds", "kind_outline_edge_term", "fit_kind_outline", "OUTLINE_KIND_BOUNDS_M", "OUTLINE_KIND_NAMES",
           "OUTLINE_KIND_MIN_OBJECTS", "KIND_OUTLINE_PARAMS", "outline_extent_kinds",
           "OBJECT_OUTLINE_P", "OBJECT_OUTLINE_MIN_OBJECTS", "EDGE_NAMES"]


# --- the 2D outline of a 3D box as a detector draws it: a nuisance fitted with the pose -------------
#: 1-sigma of the prior on each outline offset (share of the projected box's width / height)
OUTLINE_PRIOR = 0.15
OUTLINE_PARAMS = ("sides", "top", "bottom")


def outline_edge_term(base, prior: float = OUTLINE_PRIOR):
    """A box-edge term (``cost.BoxEdgeTerm``) whose projected rectangles are first moved in by
    three offsets fitted with the pose, each a share of the projected box's size: ``sides`` (both
    vertical edges, symmetric: it cannot mimic a principal-point or rotation shift), ``top`` and
    ``bottom``. This is how a camera detector's box relates to the rectangle around a 3D box's
    outline: the visible vehicle is narrower than its cuboid's corner rectangle (rounded corners,
    mirrors), its roof inset, its lowest edge above the ground (PandaSet: detector boxes 11-13 %
    smaller than the corner rectangles). A Gaussian prior (``prior``) keeps the offsets near 0
    where the data do not ask for them. Objects at several depths tell the offsets (a share of the
    box size) from a camera moved along the view or up (a shift that shrinks with depth)."""
    def insets(a):  # one common (sides, top, bottom)
        return a[0], a[1], a[2]

    return _inset_edge_term(base, "box_outline", 3, insets, prior)


def _inset_edge_term(base, term_name: str, n_offsets: int, insets, prior: float):
    """The box-edge term ``base`` (``cost.BoxEdgeTerm``, its data shared, not copied) with
    ``n_offsets`` outline offsets fitted with the pose under a Gaussian prior of 1-sigma ``prior``:
    ``insets(a)`` turns the offsets into (sides, top, bottom) shares of the projected box's width /
    height (scalars, or one per pair), by which the projected rectangle is moved in."""
    from .cost import BoxEdgeTerm, Tangent

    class InsetEdgeTerm(BoxEdgeTerm):
        name = term_name
        n_params = n_offsets
        x_scale = (1e-2,) * n_offsets
        has_pose_jacobian = True

        def __init__(self):  # share the base term's data (no copy)
            self.__dict__.update(base.__dict__)
            self.prior = float(prior)

        def apply(self, state, x):
            state.params[self.name] = x
            return state

        def edges(self, state):
            e = BoxEdgeTerm.edges(self, state)
            a = state.params.get(self.name)
            if a is None:
                return e
            sides, top, bottom = insets(a)
            w = np.maximum(e[:, 2] - e[:, 0] + self.obs[:, 2] - self.obs[:, 0], 0.0)
            h = np.maximum(e[:, 3] - e[:, 1] + self.obs[:, 3] - self.obs[:, 1], 0.0)
            return e + np.column_stack([sides * w, top * h, -sides * w, -bottom * h])

        def residuals(self, state):
            r = super().residuals(state)
            return np.concatenate([r, np.asarray(state.params[self.name], dtype=np.float64) / self.prior])

        def clusters(self):
            c = np.repeat(np.arange(len(self.obs)), 4)
            return np.concatenate([c, len(self.obs) + np.arange(n_offsets)])

        def tangents(self, state, x, base):  # the offsets move neither the camera nor the 3D outlines
            return [Tangent()] * n_offsets

        def pose_jacobian(self, state, rotvec, tangents, col):
            """Analytic: the plain rectangle's edge derivative (``weighted_jacobian``) plus the
            offsets' share of its moving width / height, and d/d offsets (``insets`` is linear in
            them: a selection per pair), through the occlusion shaping at the moved edges; the
            prior rows 1 / prior."""
            n, P = len(self.obs), 6 + len(tangents)
            D = self.weighted_jacobian(state, rotvec, tangents)  # [n,4,P] d (e w) / d x
            e = BoxEdgeTerm.edges(self, state)
            a = np.asarray(state.params.get(self.name, np.zeros(n_offsets)), dtype=np.float64)
            w = e[:, 2] - e[:, 0] + self.obs[:, 2] - self.obs[:, 0]
            h = e[:, 3] - e[:, 1] + self.obs[:, 3] - self.obs[:, 1]
            sides, top, bottom = (np.broadcast_to(v, (n,)) for v in insets(a))
            dw = (D[:, 2] - D[:, 0]) * (w > 0)[:, None]  # d (w x weight) / d x [n,P]
            dh = (D[:, 3] - D[:, 1]) * (h > 0)[:, None]
            D = D + np.stack([sides[:, None] * dw, top[:, None] * dh, -sides[:, None] * dw, -bottom[:, None] * dh], 1)
            wp, hp = np.maximum(w, 0.0) * self.w[:, 0], np.maximum(h, 0.0) * self.w[:, 0]
            for k in range(n_offsets):
                unit = np.zeros(n_offsets)
                unit[k] = 1.0
                ds, dt, db = (np.broadcast_to(v, (n,)) for v in insets(unit))
                D[:, :, col + k] += np.column_stack([ds * wp, dt * hp, -ds * wp, -db * hp])
            if self.occlusion is not None or self.censored is not None:
                D = D * self.shape_slope(self.edges(state) * self.w)[..., None]
            prior = np.zeros((n_offsets, P))
            prior[np.arange(n_offsets), col + np.arange(n_offsets)] = 1.0 / self.prior
            return np.concatenate([D.reshape(4 * n, P), prior])

    return InsetEdgeTerm()


def fit_outline(frames, pairs, intr, pose, noise, f_scale: float, occlusion, fitted=None) -> dict:
    """The detector-outline offsets (``outline_edge_term``) fitted jointly with the pose at
    ``pose`` (matches held): what the 2D boxes say about how they relate to the 3D outlines in use.
    Returns {"sides", "top", "bottom": shares of the projected box size (positive: the 2D box lies
    inside), "sd": their 1-sigma (Jacobian), "pose_shift": [deg, m] the pose moves when they are
    freed, "n_pairs"}; {} with fewer than 12 pairs. ``fitted``: (model, fit) of this very refit made
    already (``uncertainty.outline_fit``, the same inputs and ``max_nfev``), used instead of refitting."""
    from .refine import build_cost

    n = int(sum(len(p) for p in pairs))
    if n < 12:
        return {}
    if fitted is None:
        model = build_cost(frames, pairs, intr, pose, noise, occlusion, edge=outline_edge_term)
        fit = model.fit(f_scale=f_scale, max_nfev=60)
    else:
        model, fit = fitted
    a = np.asarray(fit.params["box_outline"], dtype=np.float64)
    out = {k: float(v) for k, v in zip(OUTLINE_PARAMS, a)}
    try:
        _, J = model.jacobian(fit.x)
        cov = np.linalg.pinv(J.T @ J)
        out["sd"] = [float(np.sqrt(max(cov[6 + k, 6 + k], 0.0))) for k in range(3)]
    except (np.linalg.LinAlgError, ValueError):
        pass
    out["pose_shift"] = [float(v) for v in fit.pose.error(pose)]
    out["n_pairs"] = n
    return out


# --- the outline per kind of object (sized from the 3D box): a measured building block ------------
#: kinds of object by the 3D box's footprint length (m, its longer horizontal side): below the first
#: bound person-sized, above the second large (truck, bus), else a car-sized vehicle. A detector's box
#: relates to the 3D box differently per kind: a person's grows (limbs, what is carried), a car's is
#: narrower and lower (rounded body, narrower roof), a truck's or bus's nearly the cuboid. Physical
#: sizes of road users, not fitted to any data set.
OUTLINE_KIND_BOUNDS_M = (1.5, 6.5)
OUTLINE_KIND_NAMES = ("person", "vehicle", "large")
#: a kind gets offsets of its own with at least this many distinct objects (fewer: the most frequent kind's)
OUTLINE_KIND_MIN_OBJECTS = 1
#: the offsets of one kind: both vertical edges in by one share of the width, top and bottom in by one
#: share of the height. No vertical shift: within a kind (objects of about one height) a shift by a share
#: of the box height is the camera moved up or down (both scale with 1 / depth) -- with top and bottom
#: free apart, realism ``detector_outline`` refits from the truth ended 0.25-0.36 m off at sites the
#: plain fit had within 0.05 m (top +0.19, bottom -0.12)
KIND_OUTLINE_PARAMS = ("sides", "height")


def outline_kinds(frames, pairs, groups: np.ndarray) -> tuple[np.ndarray, list[str]]:
    """(kind per matched pair [n] in 0..K-1, the K kinds' names): the size kinds
    (``OUTLINE_KIND_BOUNDS_M``) holding at least ``OUTLINE_KIND_MIN_OBJECTS`` distinct objects
    (``groups``: object id per pair, pairs concatenated over the frames); an object takes the kind of
    its median footprint length (one kind per object); pairs of rarer kinds join the most frequent
    kind. Label-free: the sizes are the 3D boxes' own."""
    groups = np.asarray(groups, dtype=np.int64)
    length = np.concatenate([np.max(np.asarray(fr.boxes3d)[p[:, 1], 3:5], axis=1)
                             for fr, p in zip(frames, pairs) if len(p)] or [np.zeros(0)])
    if not len(length) or len(length) != len(groups):
        return np.zeros(len(groups), dtype=np.int64), ["all"]
    G = int(groups.max()) + 1
    obj_len = np.array([float(np.median(length[groups == g])) if np.any(groups == g) else 0.0 for g in range(G)])
    obj_kind = np.digitize(obj_len, OUTLINE_KIND_BOUNDS_M)
    count = [int(np.sum(obj_kind[np.unique(groups)] == k)) for k in range(len(OUTLINE_KIND_NAMES))]
    present = [k for k in range(len(OUTLINE_KIND_NAMES)) if count[k] >= OUTLINE_KIND_MIN_OBJECTS]
    if len(present) <= 1:
        return np.zeros(len(groups), dtype=np.int64), ["all"]
    main = max(present, key=lambda k: count[k])
    remap = np.array([present.index(k) if k in present else present.index(main) for k in range(len(OUTLINE_KIND_NAMES))])
    return remap[obj_kind[groups]], [OUTLINE_KIND_NAMES[k] for k in present]


def outline_extent_kinds(outlines: np.ndarray) -> tuple[np.ndarray, int]:
    """(kind per outline [n] in 0..K-1, K) from the outlines themselves ([n,S,3] LiDAR-frame points
    of each matched 3D box's outline): the longest horizontal extent of each against
    ``OUTLINE_KIND_BOUNDS_M``, the kinds present numbered in order. For an edge term alone (no
    object identities: every pair by its own size)."""
    pts = np.asarray(outlines, dtype=np.float64)[:, :, :2]
    if not len(pts):
        return np.zeros(0, dtype=np.int64), 1
    ext = np.nanmax(np.linalg.norm(pts[:, :, None, :] - pts[:, None, :, :], axis=3), axis=(1, 2))
    raw = np.digitize(ext, OUTLINE_KIND_BOUNDS_M)
    present = np.unique(raw)
    return np.searchsorted(present, raw).astype(np.int64), len(present)


def kind_outline_edge_term(kinds: np.ndarray | None = None, n_kinds: int | None = None, prior: float = OUTLINE_PRIOR):
    """A factory for ``refine.build_cost(edge=...)``: the box-edge term with two offsets per kind of
    object (``kinds``: kind per matched pair in 0..``n_kinds``-1, :func:`outline_kinds`):
    ``KIND_OUTLINE_PARAMS`` (sides: both vertical edges in by a share of the projected width;
    height: top and bottom in by a share of the height), each with the Gaussian prior ``prior``.
    ``kinds`` None: each pair's kind from its own outline's extent (:func:`outline_extent_kinds`), so
    that the factory serves any set of pairs (refits on resampled pairs)."""
    def make(base):
        if kinds is None:
            kind_of, K = outline_extent_kinds(base.outlines)
        else:
            kind_of, K = np.asarray(kinds, dtype=np.int64), int(n_kinds)

        def insets(a):  # per pair its kind's (sides, height, height)
            a = np.asarray(a, dtype=np.float64).reshape(K, 2)[kind_of]
            return a[:, 0], a[:, 1], a[:, 1]

        return _inset_edge_term(base, "box_outline_kinds", 2 * K, insets, prior)

    return make


def fit_kind_outline(frames, pairs, intr, pose, noise, f_scale: float, occlusion, groups: np.ndarray) -> dict:
    """The pose refitted (matches held, from ``pose``) with the detector-outline offsets of each size
    kind free (:func:`kind_outline_edge_term`), against the same refit with no offsets and with one
    common set (``outline_edge_term``). A measurement, not used by ``calibrate``: returns {"kinds":
    names, "offsets": {kind: {"sides", "top", "bottom"}}, "pose": the refitted Pose, "cost":
    {"plain", "common", "kinds"} robust costs, "pose_shift": [deg, m] from the plain refit}; {} with
    fewer than 12 pairs."""
    from .refine import build_cost

    n = int(sum(len(p) for p in pairs))
    if n < 12:
        return {}
    kinds, names = outline_kinds(frames, pairs, groups)
    fits = {tag: build_cost(frames, pairs, intr, pose, noise, occlusion, edge=edge).fit(f_scale=f_scale, max_nfev=80)
            for tag, edge in (("plain", None), ("common", outline_edge_term),
                              ("kinds", kind_outline_edge_term(kinds, len(names))))}
    a = np.asarray(fits["kinds"].params["box_outline_kinds"], dtype=np.float64).reshape(len(names), 2)
    return {"kinds": names, "offsets": {k: dict(zip(KIND_OUTLINE_PARAMS, map(float, v))) for k, v in zip(names, a)},
            "pose": fits["kinds"].pose, "cost": {k: float(f.cost) for k, f in fits.items()},
            "pose_shift": [float(v) for v in fits["kinds"].pose.error(fits["plain"].pose)]}


# --- each object's own outline: per-object edge offsets as random effects ------------------------
#: the per-object offsets are fitted only when the objects' outlines differ beyond the edge noise
#: (chi-square test of the per-object offsets against the residual scale; p-value below this)
OBJECT_OUTLINE_P = 1e-3
#: fewest distinct objects (their spread is the prior's; fewer: no estimate of it)
OBJECT_OUTLINE_MIN_OBJECTS = 4
EDGE_NAMES = ("left", "top", "right", "bottom")


@dataclass
class ObjectOutlineFit:
    """The pose refitted with one outline offset per object and edge (a share of the box size,
    positive: the 2D box lies inside the projected outline), each a random effect with the prior
    1-sigma ``tau`` [4] (left, top, right, bottom) estimated from the per-object residuals.
    ``sd``: the pose's 1-sigma (deg / m) with the offsets marginalised; ``p_value``: the test that
    made them worth fitting; ``offsets`` [G,4]: the fitted offsets per object."""

    pose: object
    sd: np.ndarray
    tau: np.ndarray
    p_value: float
    n_objects: int
    offsets: np.ndarray
    cov: np.ndarray | None = None  # [6,6] of the pose (rad, m), the offsets marginalised
    #: [6,6] (rad, m) of the pose fitted WITHOUT the objects' own outlines, under the fitted random
    #: effects (the plain fit takes each object's outline error as noise; its edges share it)
    cov_plain: np.ndarray | None = None

    @property
    def sd_plain(self) -> np.ndarray | None:
        """1-sigma (deg / m) of the pose fitted without the objects' own outlines, under the fitted
        random effects (``cov_plain``); None without it."""
        if self.cov_plain is None:
            return None
        d = np.sqrt(np.clip(np.diag(self.cov_plain), 0.0, None))
        return np.concatenate([np.degrees(d[:3]), d[3:]])

    def shift_significant(self, pose0) -> bool:
        """Whether the pose moved from ``pose0`` (the fit without the objects' own outlines) by more
        than the two fits' difference scatters under the random-effects model: ``d^2 = delta^T
        V^-1 delta`` beyond the 99 % point of chi-square with 6 degrees of freedom (a Hausman test,
        :meth:`shift_d2`; the 6-dof point also where ``V`` has a lower rank). Where
        it does not, the objects' outlines leave the pose where it was, and the fit without them
        (which has less scatter) is kept."""
        from scipy.special import chdtri

        d2, dof = self.shift_d2(pose0)
        # the 6-dof quantile whatever the rank: a level <= 1 % for any rank, and a move where ``V``
        # vanishes is left untested. Conservative on purpose: A9 detector boxes, random 12-frame subsets,
        # with the rank's own quantile 8 of 20 moved (d^2 9.4-15.2 on 2-4 dof) and 2 ended 0.51-0.56 m
        # from the labelled pose (kept: 0.2-0.35 m); realism detector_all site 14 still moves (22.2)
        return dof > 0 and d2 > float(chdtri(6, 0.01))

    def shift_d2(self, pose0) -> tuple[float, int]:
        """(d^2, degrees of freedom) of the pose's move from ``pose0``. Both fits are unbiased when the
        objects' outlines are random effects, and this one is the efficient one, so their difference
        has the covariance ``V = cov_plain - cov`` (Hausman 1978; eigenvalues below 1e-6 of the largest
        dropped with their directions: the two fits agree there by construction). Without
        ``cov_plain``, ``V = cov`` (a conservative stand-in: the difference scatters less than either
        fit). (0, 0) without a covariance."""
        if self.cov is None:
            return 0.0, 0
        d = np.asarray(self.pose.delta(pose0), dtype=np.float64)
        d = np.concatenate([np.radians(d[:3]), d[3:]])
        V = self.cov if self.cov_plain is None else self.cov_plain - self.cov
        if not np.all(np.isfinite(V)):
            return 0.0, 0
        S = np.diag(1.0 / np.sqrt(np.clip(np.diag(self.cov), 1e-30, None)))  # radians vs metres: scale-free
        lam, U = np.linalg.eigh(S @ (0.5 * (V + V.T)) @ S)
        keep = lam > 1e-6 * max(float(lam.max()), 1e-30)
        if not np.any(keep):
            return 0.0, 0
        y = U[:, keep].T @ (S @ d)
        return float(np.sum(y ** 2 / lam[keep])), int(keep.sum())

    def summary(self, pose0) -> dict:
        """JSON-ready record (``diagnostics.box_fit["objects"]``): the spread of the objects' outlines and
        the pose shift from ``pose0`` (the fit without them)."""
        d2, dof = self.shift_d2(pose0)
        return {"tau": {k: float(v) for k, v in zip(EDGE_NAMES, self.tau)}, "p_value": float(self.p_value),
                "shift_d2": d2, "shift_dof": dof,
                "n_objects": int(self.n_objects), "sd": [float(v) for v in self.sd],
                "pose_shift": [float(v) for v in self.pose.error(pose0)], "applied": bool(self.shift_significant(pose0))}


def _edge_share_derivative(term, size: np.ndarray) -> np.ndarray:
    """d residual / d offset [n,4] of a box-edge term at its last residuals: an offset ``a`` moves
    the expected 2D edge into the outline by ``a`` x the box size (``size`` [n,4]: w, h, w, h)."""
    from .cost import INWARD

    d = -INWARD * size * term.w
    return d


def _shape_slope(term, r: np.ndarray) -> np.ndarray:
    """Slope [n,4] of the term's occlusion shaping (and censoring) at the weighted residuals ``r`` [n,4]."""
    return term.shape_slope(r)


def object_outline_spread(term, groups: np.ndarray, state) -> tuple[np.ndarray, float, float]:
    """(tau [4], residual scale, p-value): the spread of the objects' own outline offsets.

    Each object's offset per edge is estimated from its inlier residuals at ``state`` (linearised,
    the pose held); their robust spread (MAD over objects; left and right edges pooled, one spread
    for both sides) less the share the edge noise explains is ``tau`` (method of moments, 0 where
    the noise explains it all). The p-value tests the
    per-object offsets against the noise alone (chi-square over objects and edges)."""
    from scipy.special import chdtrc

    n = len(term.obs)
    raw = np.where(np.isfinite(term.edges(state)), term.edges(state), 0.0) * term.w
    r = term.shape(raw)
    size = _box_size(term.obs)
    s_row = (_edge_share_derivative(term, size) * _shape_slope(term, raw)).ravel()
    r = r.ravel()
    informative = np.any(term.jacobian(state, np.zeros(3), []) != 0, axis=1)  # edges clipped at the border: none
    sig = 1.4826 * float(np.median(np.abs(r[informative]))) if np.any(informative) else 0.0
    if not sig > 0:
        return np.zeros(4), sig, 1.0
    inl = informative & (np.abs(r) <= 3.0 * sig)
    edge, obj = np.tile(np.arange(4), n), np.repeat(groups, 4)
    G = int(groups.max()) + 1
    num, den = np.zeros((G, 4)), np.zeros((G, 4))
    np.add.at(num, (obj, edge), np.where(inl, s_row * r, 0.0))
    np.add.at(den, (obj, edge), np.where(inl, s_row ** 2, 0.0))
    ok = den > 1e-12
    a = np.where(ok, -num / np.where(ok, den, 1.0), 0.0)
    nv = np.where(ok, sig ** 2 / np.where(ok, den, 1.0), np.inf)
    tau2 = np.zeros(4)
    for ks in ((0, 2), (1,), (3,)):  # left and right pooled: a detector has no preferred side
        v = np.concatenate([a[ok[:, k], k] - np.median(a[ok[:, k], k]) for k in ks if ok[:, k].any()] or [np.zeros(0)])
        if len(v) >= OBJECT_OUTLINE_MIN_OBJECTS * len(ks):
            mad = 1.4826 * float(np.median(np.abs(v)))
            tau2[list(ks)] = max(mad ** 2 - float(np.median(np.concatenate([nv[ok[:, k], k] for k in ks]))), 0.0)
    dof = int(ok.sum())
    p = float(chdtrc(dof, float(np.sum(a[ok] ** 2 / nv[ok])))) if dof else 1.0
    return np.sqrt(tau2), sig, p


def _box_size(obs: np.ndarray) -> np.ndarray:
    w, h = obs[:, 2] - obs[:, 0], obs[:, 3] - obs[:, 1]
    return np.column_stack([w, h, w, h])


def fit_object_outline(frames, pairs, intr, pose, noise, f_scale: float, occlusion,
                       groups: np.ndarray) -> ObjectOutlineFit | None:
    """The pose refitted (matches held) with every object's own outline offsets as random effects.

    A detector draws each object's visible outline, not the rectangle around its 3D box: a car a
    few per cent narrower or lower than another, the same car alike over the frames. A common
    offset (``outline_edge_term``) leaves each object's own part, which objects near the camera
    turn into a bias along the view axis (realism ``detector_outline``: 0.6 m at a site whose
    every pair is right). Here each object (``groups``: object id per matched pair, in pair order)
    gets four offsets (left, top, right, bottom; shares of the 2D box size) with a zero-mean
    Gaussian prior whose 1-sigma per edge is the objects' spread estimated from the residuals
    (:func:`object_outline_spread`): exact boxes give a spread of 0 and nothing changes. Fitted
    only when the per-object offsets are significant (p < ``OBJECT_OUTLINE_P``), with at least
    ``OBJECT_OUTLINE_MIN_OBJECTS`` objects, a pinhole camera and no extra cost terms; else None."""
    from scipy import sparse
    from scipy.optimize import least_squares

    from ..geometry.camera import CameraIntrinsics
    from .cost import INWARD, POSE_X_SCALE, PoseState
    from .refine import edge_term
    from .terms import CostSpec

    spec = CostSpec.of(occlusion)
    groups = np.asarray(groups, dtype=np.int64)
    n = int(sum(len(p) for p in pairs))
    if spec.terms or not isinstance(intr, CameraIntrinsics) or n < 12 or len(groups) != n:
        return None
    G = int(groups.max()) + 1
    if G < OBJECT_OUTLINE_MIN_OBJECTS:
        return None
    term = edge_term(frames, pairs, intr, pose, noise, spec.occlusion)
    tau, sig, p = object_outline_spread(term, groups, PoseState(pose, intr))
    free = np.flatnonzero(tau > 0)
    if p >= OBJECT_OUTLINE_P or not len(free):
        return None
    W, H = term.size
    obs0 = term.obs.copy()
    cov_plain = _plain_covariance(term, PoseState(pose, intr), groups, tau, sig)
    on_border = np.column_stack([obs0[:, 0] <= 0.5, obs0[:, 1] <= 0.5, obs0[:, 2] >= W - 0.5, obs0[:, 3] >= H - 0.5])
    size = _box_size(obs0) * ~on_border  # an edge on the image border is where the image ends: no offset
    k = len(free)
    # common offsets (sides, top, bottom; prior OUTLINE_PRIOR as ``outline_edge_term``) + each object's own
    lam = np.concatenate([np.full(3, sig / OUTLINE_PRIOR), np.tile(sig / tau[free], G)])
    common = np.array([[1.0, 0, 0], [0, 1.0, 0], [1.0, 0, 0], [0, 0, 1.0]])  # edge <- (sides, top, bottom)
    cols = groups[:, None] * k + np.arange(k)[None, :]  # [n,k] column (after pose and common) of each pair's free edges
    rows = 4 * np.arange(n)[:, None] + free[None, :]
    P = 9 + G * k

    def setx(x):
        a = (common @ x[6:9])[None, :] + np.zeros((n, 4))
        a[:, free] += x[9:].reshape(G, k)[groups]
        term.obs = obs0 + INWARD * a * size
        return PoseState(pose.moved(x[:3], x[3:6]), intr)

    def resid(x):
        st = setx(x)
        return np.concatenate([term.residuals(st), x[6:] * lam])

    def jac(x):
        st = setx(x)
        Jp = term.jacobian(st, x[:3], [])
        raw = np.where(np.isfinite(term.edges(st)), term.edges(st), 0.0) * term.w
        da = _edge_share_derivative(term, size) * _shape_slope(term, raw)  # [n,4]
        Jc = (da[:, :, None] * common[None]).reshape(4 * n, 3)
        edges = sparse.hstack([sparse.csr_matrix(np.hstack([Jp, Jc])), sparse.csr_matrix(
            (da[:, free].ravel(), (rows.ravel(), cols.ravel())), shape=(4 * n, G * k))])
        prior = sparse.hstack([sparse.csr_matrix((P - 6, 6)), sparse.diags(lam)])
        return sparse.vstack([edges, prior]).tocsr()

    try:
        res = least_squares(resid, np.zeros(P), jac=jac, loss="soft_l1", f_scale=f_scale, method="trf", tr_solver="lsmr",
                            x_scale=np.concatenate([POSE_X_SCALE, np.full(P - 6, 1e-2)]), max_nfev=60)
        J = jac(res.x).toarray()
    except (np.linalg.LinAlgError, ValueError):
        term.obs = obs0
        return None
    r = res.fun
    term.obs = obs0
    if not np.all(np.isfinite(res.x)):
        return None
    m = 4 * n
    s = 1.4826 * float(np.median(np.abs(r[:m])))
    use = np.concatenate([np.abs(r[:m]) <= 3.0 * max(s, 1e-9), np.ones(len(r) - m, dtype=bool)])
    try:
        cov = np.linalg.inv(J[use].T @ J[use])[:6, :6] * sig ** 2
    except np.linalg.LinAlgError:
        return None
    d = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    sd = np.concatenate([np.degrees(d[:3]), d[3:]])
    offs = np.zeros((G, 4)) + common @ res.x[6:9]
    offs[:, free] += res.x[9:].reshape(G, k)
    return ObjectOutlineFit(pose.moved(res.x[:3], res.x[3:6]), sd, tau, p, G, offs, cov, cov_plain)


def _plain_covariance(term, state, groups: np.ndarray, tau: np.ndarray, sig: float) -> np.ndarray | None:
    """[6,6] (rad, m) of the pose fitted without per-object outline offsets (at ``state``), when the
    objects' outlines are random effects of per-edge 1-sigma ``tau`` [4] (shares of the box size):
    ``A (sig^2 J^T J + sum_{object, edge} tau_e^2 b b^T) A`` with ``A = (J^T J)^-1`` over the inlier
    edges and ``b`` the summed Jacobian rows that one object's offset on one edge moves (its edges
    over all frames share that offset). Edges on the image border carry no offset. None when the
    edges leave the pose undetermined."""
    n = len(term.obs)
    Jp = term.jacobian(state, np.zeros(3), [])
    raw = np.where(np.isfinite(term.edges(state)), term.edges(state), 0.0) * term.w
    r = term.shape(raw).ravel()
    inl = np.any(Jp != 0, axis=1) & (np.abs(r) <= 3.0 * max(sig, 1e-9))
    J = Jp * inl[:, None]
    try:
        A = np.linalg.inv(J.T @ J)
    except np.linalg.LinAlgError:
        return None
    W, H = term.size
    obs = term.obs
    on_border = np.column_stack([obs[:, 0] <= 0.5, obs[:, 1] <= 0.5, obs[:, 2] >= W - 0.5, obs[:, 3] >= H - 0.5])
    da = (_edge_share_derivative(term, _box_size(obs) * ~on_border) * _shape_slope(term, raw)).ravel()  # [4n]
    G = int(groups.max()) + 1
    b = np.zeros((G, 4, 6))
    np.add.at(b, (np.repeat(groups, 4), np.tile(np.arange(4), n)), J * da[:, None])
    B = np.einsum("gei,gej,e->ij", b, b, np.asarray(tau, dtype=np.float64) ** 2)
    return sig ** 2 * A + A @ B @ A
