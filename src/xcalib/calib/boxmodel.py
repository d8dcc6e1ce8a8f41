"""3D box models for calibration: the 3D boxes' shapes from the LiDAR points (``boxshape``: yaw
re-estimation, point hulls; re-exported here) and the 2D outline of a 3D box as a detector draws
it, a nuisance fitted with the pose (``outline_edge_term``, ``fit_outline``).

``boxshape`` sits below the refinement (``inputs`` uses it); this module above it
(``fit_outline`` fits with ``refine.build_cost``).
"""

from __future__ import annotations

import numpy as np

from .boxshape import (YawFit, YawFitSettings, estimate_yaw_from_points, expand_by_scan_gap,  # noqa: F401
                       fit_yaw_to_points, lidar_angular_step, shapes_from_points)

__all__ = ["YawFit", "fit_yaw_to_points", "estimate_yaw_from_points", "lidar_angular_step", "expand_by_scan_gap",
           "outline_edge_term", "fit_outline", "OUTLINE_PRIOR", "OUTLINE_PARAMS",
           "shapes_from_points"]


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
    from .cost import BoxEdgeTerm

    class OutlineEdgeTerm(BoxEdgeTerm):
        name = "box_outline"
        n_params = 3
        x_scale = (1e-2, 1e-2, 1e-2)

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
            w = np.maximum(e[:, 2] - e[:, 0] + self.obs[:, 2] - self.obs[:, 0], 0.0)
            h = np.maximum(e[:, 3] - e[:, 1] + self.obs[:, 3] - self.obs[:, 1], 0.0)
            return e + np.column_stack([a[0] * w, a[1] * h, -a[0] * w, -a[2] * h])

        def residuals(self, state):
            r = super().residuals(state)
            return np.concatenate([r, np.asarray(state.params[self.name], dtype=np.float64) / self.prior])

        def clusters(self):
            c = np.repeat(np.arange(len(self.obs)), 4)
            return np.concatenate([c, len(self.obs) + np.arange(3)])

    return OutlineEdgeTerm()


def fit_outline(frames, pairs, intr, pose, noise, f_scale: float, occlusion) -> dict:
    """The detector-outline offsets (``outline_edge_term``) fitted jointly with the pose at
    ``pose`` (matches held): what the 2D boxes say about how they relate to the 3D outlines in use.
    Returns {"sides", "top", "bottom": shares of the projected box size (positive: the 2D box lies
    inside), "sd": their 1-sigma (Jacobian), "pose_shift": [deg, m] the pose moves when they are
    freed, "n_pairs"}; {} with fewer than 12 pairs."""
    from .refine import build_cost

    n = int(sum(len(p) for p in pairs))
    if n < 12:
        return {}
    model = build_cost(frames, pairs, intr, pose, noise, occlusion, edge=outline_edge_term)
    fit = model.fit(f_scale=f_scale, max_nfev=60)
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
