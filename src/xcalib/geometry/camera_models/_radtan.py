"""OpenCV radial-tangential (+ rational, thin-prism, tilted-sensor) distortion on normalised
coordinates, with its 2x2 Jacobian, its inverse, and the radius up to which it is one-to-one."""

from __future__ import annotations

import math

import numpy as np

RADTAN_LENGTHS = (0, 4, 5, 8, 12, 14)


def full14(dist) -> np.ndarray:
    d = np.zeros(14)
    if dist is not None and len(dist):
        dist = np.asarray(dist, dtype=np.float64).reshape(-1)
        d[: dist.size] = dist
    return d


def tilt_matrix(tau_x: float, tau_y: float) -> np.ndarray:
    """OpenCV's ``computeTiltProjectionMatrix`` (tilted sensor, the 13th/14th coefficients)."""
    cx, sx, cy, sy = math.cos(tau_x), math.sin(tau_x), math.cos(tau_y), math.sin(tau_y)
    rot_x = np.array([[1, 0, 0], [0, cx, sx], [0, -sx, cx]], dtype=np.float64)
    rot_y = np.array([[cy, 0, -sy], [0, 1, 0], [sy, 0, cy]], dtype=np.float64)
    rxy = rot_y @ rot_x
    proj_z = np.array([[rxy[2, 2], 0, -rxy[0, 2]], [0, rxy[2, 2], -rxy[1, 2]], [0, 0, 1]])
    return proj_z @ rxy


def distort(m: np.ndarray, d: np.ndarray, jac: bool):
    """Distorted normalised coordinates [N,2] of ``m`` and, if ``jac``, d(md)/d(m) [N,2,2]."""
    k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4, tx, ty = d
    x, y = m[:, 0], m[:, 1]
    r2 = x * x + y * y
    r4 = r2 * r2
    a = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
    b = 1 + r2 * (k4 + r2 * (k5 + r2 * k6))
    radial = a / b
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x) + s1 * r2 + s2 * r4
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y + s3 * r2 + s4 * r4
    J = None
    if jac:
        da = k1 + r2 * (2 * k2 + 3 * k3 * r2)
        db = k4 + r2 * (2 * k5 + 3 * k6 * r2)
        drad = (da * b - a * db) / (b * b)  # d radial / d r2
        J = np.empty((len(m), 2, 2))
        J[:, 0, 0] = radial + 2 * x * x * drad + 2 * p1 * y + 6 * p2 * x + 2 * s1 * x + 4 * s2 * r2 * x
        J[:, 0, 1] = 2 * x * y * drad + 2 * p1 * x + 2 * p2 * y + 2 * s1 * y + 4 * s2 * r2 * y
        J[:, 1, 0] = 2 * x * y * drad + 2 * p1 * x + 2 * p2 * y + 2 * s3 * x + 4 * s4 * r2 * x
        J[:, 1, 1] = radial + 2 * y * y * drad + 6 * p1 * y + 2 * p2 * x + 2 * s3 * y + 4 * s4 * r2 * y
    md = np.stack([xd, yd], axis=1)
    if tx or ty:
        T = tilt_matrix(tx, ty)
        h = md @ T[:, :2].T + T[:, 2]
        out = h[:, :2] / h[:, 2:3]
        if jac:
            # d out / d md = (T[:2,:2] - out * T[2,:2]) / w
            Jt = (T[None, :2, :2] - out[:, :, None] * T[None, 2:3, :2]) / h[:, 2, None, None]
            J = np.matmul(Jt, J)
        md = out
    return md, J


def monotone_radius(d: np.ndarray, r_cap: float) -> float:
    """The normalised radius up to which the radial part ``r * a(r^2)/b(r^2)`` keeps increasing
    (and ``b`` stays positive), searched up to ``r_cap``; ``inf`` when it never turns."""
    k1, k2, k3, k4, k5, k6 = d[0], d[1], d[4], d[5], d[6], d[7]
    if not any((k1, k2, k3, k4, k5, k6)):
        return math.inf
    r = np.concatenate([np.linspace(0.0, 1.0, 2001)[1:], np.geomspace(1.0, r_cap, 4000)[1:]])
    r2 = r * r
    a = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
    b = 1 + r2 * (k4 + r2 * (k5 + r2 * k6))
    da = k1 + r2 * (2 * k2 + 3 * k3 * r2)
    db = k4 + r2 * (2 * k5 + 3 * k6 * r2)
    # d/dr (r a/b) = a/b + 2 r^2 (a' b - a b') / b^2
    with np.errstate(over="ignore", invalid="ignore"):
        slope = a / b + 2 * r2 * (da * b - a * db) / (b * b)
        bad = ~(slope > 0) | ~(b > 0) | ~(a / b > 0)
    if not np.any(bad):
        return math.inf
    i = int(np.argmax(bad))
    return float(r[max(i - 1, 0)]) if i > 0 else 0.0


def undistort(md: np.ndarray, d: np.ndarray, r_max: float, iters: int = 40):
    """Invert :func:`distort` by Newton's method from ``m = md``; ``(m, converged [N])``."""
    m = md.copy()
    if d[12] or d[13]:
        T = tilt_matrix(d[12], d[13])
        Ti = np.linalg.inv(T)
        h = md @ Ti[:, :2].T + Ti[:, 2]
        m = h[:, :2] / h[:, 2:3]
        target = md
    else:
        target = md
    # a start inside the monotonic range (the distorted radius can exceed it)
    if math.isfinite(r_max):
        r = np.linalg.norm(m, axis=1)
        shrink = np.minimum(1.0, 0.9 * r_max / np.maximum(r, 1e-300))
        m = m * shrink[:, None]
    for _ in range(iters):
        f, J = distort(m, d, True)
        res = f - target
        det = J[:, 0, 0] * J[:, 1, 1] - J[:, 0, 1] * J[:, 1, 0]
        det = np.where(np.abs(det) > 1e-300, det, 1e-300)
        dx = (J[:, 1, 1] * res[:, 0] - J[:, 0, 1] * res[:, 1]) / det
        dy = (-J[:, 1, 0] * res[:, 0] + J[:, 0, 0] * res[:, 1]) / det
        step = np.stack([dx, dy], axis=1)
        # damp steps that would leave the monotonic range
        m_new = m - step
        if math.isfinite(r_max):
            rn = np.linalg.norm(m_new, axis=1)
            over = rn > r_max
            if np.any(over):
                m_new[over] = 0.5 * (m[over] + m_new[over] * (r_max / rn[over])[:, None])
        m = m_new
        if np.all(np.abs(step) < 1e-15):
            break
    f, _ = distort(m, d, False)
    ok = np.all(np.abs(f - target) < 1e-9, axis=1) & np.all(np.isfinite(m), axis=1)
    if math.isfinite(r_max):
        ok &= np.linalg.norm(m, axis=1) <= r_max
    return m, ok


def distort_within(m: np.ndarray, d: np.ndarray, r_max: float, jac: bool):
    """A camera model's distortion step: ``(md [N,2], J [N,2,2] or None, valid [N])``, valid
    where ``m`` lies within ``r_max`` (the one-to-one radius); the identity when ``d`` is all 0."""
    if not np.any(d):
        return m, None, np.ones(len(m), dtype=bool)
    valid = np.ones(len(m), dtype=bool)
    if math.isfinite(r_max):
        valid = np.einsum("ij,ij->i", m, m) <= r_max ** 2
    md, J = distort(m, d, jac)
    return md, J, valid


def undistort_within(md: np.ndarray, d: np.ndarray, r_max: float):
    """The inverse step of :func:`distort_within`: ``(m [N,2], converged [N])``."""
    if not np.any(d):
        return md, np.ones(len(md), dtype=bool)
    return undistort(md, d, r_max)
