"""The change test's estimate iterated to the window's own pose change (``MonitorConfig.iterate_steps``).

A frame's box-edge residuals are linearised once, where it is matched (the calibration until a
drift is found). The occlusion shaping (inward residuals beyond ``tau`` noise sigmas compressed by
``slope``) and the soft-L1 weights evaluated there read a real move as occlusion and outliers: the
one-step estimate of a window after a 10 cm step along the view axis recovers 0.4-0.9 of it
(docs/monitor.md). The projection itself is close to linear over such a move, the shaping and the
weights are not. So each frame keeps its *unshaped* residual rows (``EdgeRows``: the weighted
residual ``e0`` at the calibration and its Jacobian ``J``, which the monitor computes from the same
13 projected poses anyway), and a segment's estimate is refined by Gauss-Newton steps on them,
the shaping and the weights recomputed at the current estimate (``iterated_fit``): no projection,
no matching, a few microseconds per residual row.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["EdgeRows", "stack_rows", "normal_equations", "iterated_fit", "object_shares"]


@dataclass(frozen=True)
class EdgeRows:
    """One frame's informative residual rows: ``e0`` [m] the unshaped weighted residual (pred - obs,
    in noise-model sigmas) at the calibration (linear model: e(x) = e0 + J x), ``J`` [m,6] its
    Jacobian in x (rotation vector rad, translation m, camera axes), ``sgn`` [m] the edge's inward
    sign (``calib.cost.INWARD``: the occlusion shaping acts on sgn * e), ``obj`` [m] the matched
    object's id, ``fs``: the soft-L1 loss's scale the frame was weighted with."""

    e0: np.ndarray
    J: np.ndarray
    sgn: np.ndarray
    obj: np.ndarray
    fs: float


def stack_rows(parts: list[EdgeRows]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The rows of several frames as one set: e0 [M], J [M,6], sgn [M], obj [M], fs [M]."""
    parts = [p for p in parts if p is not None and len(p.e0)]
    if not parts:
        return np.zeros(0), np.zeros((0, 6)), np.zeros(0), np.zeros(0, dtype=np.int64), np.zeros(0)
    return (np.concatenate([p.e0 for p in parts]), np.concatenate([p.J for p in parts]),
            np.concatenate([p.sgn for p in parts]), np.concatenate([p.obj for p in parts]),
            np.concatenate([np.full(len(p.e0), p.fs) for p in parts]))


def _shaped(rows, x: np.ndarray, tau: float, slope: float, fixed: np.ndarray | None = None, part: str = ""):
    """Shaped residual r [M], its Jacobian [M,6] and the soft-L1 weights w [M] at pose change x
    (``fixed`` and ``part``: the soft-L1 weights ("weights") or the shaping's branch ("shaping")
    taken at the pose change ``fixed`` instead)."""
    e0, J, sgn, _, fs = rows
    s = (e0 + J @ x) * sgn
    sf = s if fixed is None else (e0 + J @ fixed) * sgn
    out = sf > tau if part == "shaping" else s > tau
    r = np.where(out, tau + slope * (s - tau), s) * sgn
    Jr = J * np.where(out, slope, 1.0)[:, None]
    rw = r if part != "weights" else np.where(sf > tau, tau + slope * (sf - tau), sf) * sgn
    w = 1.0 / np.sqrt(1.0 + (rw / fs) ** 2)
    return r, Jr, w


def normal_equations(rows, x: np.ndarray, tau: float, slope: float, part: str = "") -> tuple[np.ndarray, np.ndarray, float]:
    """The weighted normal equations of ``rows`` linearised at x (relative to the calibration, as
    the monitor's frames): H [6,6], g [6], c with the estimate -H^-1 g (``_Rec``'s convention).
    ``part``: "weights" / "shaping" kept at the calibration (x = 0) instead of x."""
    r, Jr, w = _shaped(rows, x, tau, slope, np.zeros(6) if part else None, part)
    rr = r - Jr @ x
    JW = Jr * w[:, None]
    return Jr.T @ JW, JW.T @ rr, float(np.sum(w * rr * rr))


def object_shares(rows, x: np.ndarray, tau: float, slope: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per object, its share of the normal equations at x: sorted ids [K], H [K,6,6], g [K,6]."""
    r, Jr, w = _shaped(rows, x, tau, slope)
    rr = r - Jr @ x
    JW = Jr * w[:, None]
    u, inv = np.unique(rows[3], return_inverse=True)
    HG = np.concatenate([(JW[:, :, None] * Jr[:, None, :]).reshape(-1, 36), JW * rr[:, None]], 1)
    out = np.zeros((len(u), 42))
    np.add.at(out, inv, HG)
    return u, out[:, :36].reshape(-1, 6, 6), out[:, 36:]


def iterated_fit(rows, steps: int, tau: float, slope: float, x0: np.ndarray | None = None,
                 part: str = "") -> tuple[np.ndarray, np.ndarray, np.ndarray, float] | None:
    """Gauss-Newton on the unshaped rows: from ``x0`` (default the calibration), ``steps``
    re-linearisations, each with the shaping and the weights at the current estimate. Returns the
    point of the last linearisation and its normal equations (x_lin, H, g, c): the estimate is
    -H^-1 g. None where a step's H is singular."""
    x = np.zeros(6) if x0 is None else np.asarray(x0, dtype=np.float64)
    H, g, c = normal_equations(rows, x, tau, slope, part)
    for _ in range(int(steps)):
        try:
            xn = -np.linalg.solve(H, g)
        except np.linalg.LinAlgError:
            return None
        if not np.all(np.isfinite(xn)):
            return None
        x = xn
        H, g, c = normal_equations(rows, x, tau, slope, part)
    return x, H, g, c
