"""The 3D-box part of the noise model weighted per matched pair (``MonitorConfig.pair_noise``).

The calibration's noise model (``NoiseModel``) gives each box edge a variance
``sigma_px^2 + (f/Z sigma_3d)^2 + (sigma_size s)^2 (+ outline, score parts)`` and the cost weighs
the four edges of a pair as if their errors were independent. The 3D parts are not: an error of
the 3D box's centre moves its edges together (left and right alike for a sideways error), an
error of its size moves opposite edges apart. Per pair the covariance of the four weighted edge
residuals (units of the edge sigma) is

    C = v0 I + (v_c / m_c) N_c N_c^T + (v_s / m_s) N_s N_s^T

with ``N_c`` [4,3] the edges' derivative with respect to the box centre (LiDAR axes, m) and
``N_s`` [4,3] with respect to its relative size along its own three axes, both exact from the pose
Jacobian: an edge is set by one outline point (the extreme one), and the edge's derivative with
respect to that point's position in camera axes is the edge's derivative with respect to the pose
translation. ``v_c``, ``v_s`` are the noise model's centre and size variances of the pair's edges
and ``m_c``, ``m_s`` the mean diagonal of ``N N^T`` over the pair's informative edges: every part
keeps the per-edge variance the calibration fitted (the mean of C's diagonal is 1, the
independent model's), only the four edges' correlation is added. ``v0`` is the rest (2D, the
outline's own, the score's). Where the 3D parts are 0 the model is the independent one exactly.
Edges without information (clipped) are left out (identity rows). The yaw error has no part of
its own in ``NoiseModel``; its effect is in the fitted centre / size variances.
"""

from __future__ import annotations

import numpy as np

from ..calib.cost import edge_sigma
from ..calib.diagnostics import NoiseModel

__all__ = ["pair_covariance", "pair_whitening", "box_axes"]


def box_axes(box7: np.ndarray) -> np.ndarray:
    """[n,3,3] each box's axes (rows: length, width, height directions) in LiDAR axes from box7 yaw."""
    yaw = np.asarray(box7, dtype=np.float64)[:, 6]
    c, s = np.cos(yaw), np.sin(yaw)
    A = np.zeros((len(yaw), 3, 3))
    A[:, 0, 0], A[:, 0, 1] = c, s
    A[:, 1, 0], A[:, 1, 1] = -s, c
    A[:, 2, 2] = 1.0
    return A


def pair_covariance(Jt: np.ndarray, R: np.ndarray, ext: np.ndarray, box7: np.ndarray, v_c: np.ndarray,
                    v_s: np.ndarray, info: np.ndarray) -> np.ndarray:
    """[n,4,4] each pair's covariance of its four weighted edge residuals (see the module docstring).

    Jt [n,4,3]: the weighted edges' derivative with respect to the pose translation (camera axes);
    R [3,3]: LiDAR -> camera rotation; ext [n,4,3]: each edge's extreme outline point (LiDAR, m);
    box7 [n,7]: the matched 3D boxes; v_c, v_s [n]: the centre and size parts of the edge variance
    in units of the edge's variance (each in [0, 1], their sum at most 1); info [n,4]: edges that
    carry information (the others get an identity row and column)."""
    m = np.asarray(info, dtype=np.float64)
    Nc = np.einsum("nei,ik->nek", Jt, R) * m[..., None]  # d edge / d centre (LiDAR axes)
    A = box_axes(box7)
    dev = ext - np.asarray(box7, dtype=np.float64)[:, None, :3]
    Ns = np.einsum("nek,nak->nea", Nc, A) * np.einsum("nek,nak->nea", dev, A)  # d edge / d relative size per axis
    cnt = np.maximum(m.sum(1), 1.0)
    v0 = 1.0 - v_c - v_s
    C = np.zeros((len(m), 4, 4))
    for N, v in ((Nc, v_c), (Ns, v_s)):
        mean = np.einsum("nek,nek->n", N, N) / cnt
        ok = mean > 1e-300
        k = np.where(ok, v / np.where(ok, mean, 1.0), 0.0)
        v0 = v0 + np.where(ok, 0.0, v)  # a part with no shape stays on the diagonal
        C += k[:, None, None] * np.einsum("nek,nfk->nef", N, N)
    C += v0[:, None, None] * np.eye(4)[None]
    mm = m[:, :, None] * m[:, None, :]
    return C * mm + (1.0 - m)[:, :, None] * np.eye(4)[None]


def pair_whitening(C: np.ndarray) -> np.ndarray:
    """[n,4,4] L^-1 per pair with L L^T = C (Cholesky): whitened rows are ``L^-1`` times the pair's four."""
    L = np.linalg.cholesky(C)
    return np.linalg.inv(L)


def parts(obs: np.ndarray, outlines: np.ndarray, intr, pose, noise: NoiseModel, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(v_c, v_s) [n]: the noise model's centre and size variances of each pair's edges in units of the
    edge's own variance (``w`` [n]: 1 / the edge sigma the cost weighs by, ``edge_sigma``)."""
    sc = edge_sigma(obs, outlines, intr, pose, NoiseModel(0.0, noise.sigma_3d_m, 0.0))
    ss = edge_sigma(obs, outlines, intr, pose, NoiseModel(0.0, 0.0, noise.sigma_size))
    v_c, v_s = (sc * w) ** 2, (ss * w) ** 2
    tot = v_c + v_s
    over = tot > 1.0 - 1e-9  # never more than the whole variance (the 2D part is floored above 0)
    f = np.where(over, (1.0 - 1e-9) / np.maximum(tot, 1e-300), 1.0)
    return v_c * f, v_s * f
