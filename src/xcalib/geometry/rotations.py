"""Rotations: matrix / Euler / quaternion / rotation vector (scipy underneath).

Matrices are active rotations ``x' = R @ x``. Quaternions are (x, y, z, w) unless
``order="wxyz"``. Euler sequences follow scipy: lower case = extrinsic (fixed axes),
upper case = intrinsic (moving axes). Angles are radians unless ``degrees=True``.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

__all__ = [
    "euler_to_matrix", "matrix_to_euler", "quaternion_to_matrix", "matrix_to_quaternion",
    "rotvec_to_matrix", "matrix_to_rotvec", "is_rotation_matrix", "orthonormalize",
    "rotation_angle", "check_rotation_matrix", "orthonormality_error", "so3_exp", "so3_left_jacobian",
]


def _check_order(order: str) -> str:
    if order not in ("xyzw", "wxyz"):
        raise ValueError(f"quaternion order must be 'xyzw' or 'wxyz', got {order!r}")
    return order


def euler_to_matrix(angles, seq: str = "xyz", degrees: bool = False) -> np.ndarray:
    """Euler angles ([3] or [N,3]) -> rotation matrix ([3,3] or [N,3,3])."""
    return Rotation.from_euler(seq, np.asarray(angles, dtype=np.float64), degrees=degrees).as_matrix()


def matrix_to_euler(R, seq: str = "xyz", degrees: bool = False) -> np.ndarray:
    """Rotation matrix ([3,3] or [N,3,3]) -> Euler angles."""
    return Rotation.from_matrix(np.asarray(R, dtype=np.float64)).as_euler(seq, degrees=degrees)


def quaternion_to_matrix(q, order: str = "xyzw") -> np.ndarray:
    """Quaternion ([4] or [N,4]) -> rotation matrix. Raises ValueError for zero norm."""
    q = np.asarray(q, dtype=np.float64)
    if q.shape[-1] != 4:
        raise ValueError(f"quaternion must have 4 components, got shape {q.shape}")
    norm = np.linalg.norm(q, axis=-1)
    if np.any(norm < 1e-12) or not np.all(np.isfinite(q)):
        bad = q.reshape(-1, 4)[(norm.reshape(-1) < 1e-12) | ~np.all(np.isfinite(q.reshape(-1, 4)), axis=1)]
        raise ValueError(f"quaternion ({order}): zero norm or non-finite components; expected a finite, non-zero 4-vector, got {bad[0].tolist()}")
    if _check_order(order) == "wxyz":
        q = np.roll(q, -1, axis=-1)
    return Rotation.from_quat(q).as_matrix()


def matrix_to_quaternion(R, order: str = "xyzw", canonical: bool = True) -> np.ndarray:
    """Rotation matrix -> unit quaternion (w >= 0 when ``canonical``)."""
    q = Rotation.from_matrix(np.asarray(R, dtype=np.float64)).as_quat(canonical=canonical)
    if _check_order(order) == "wxyz":
        q = np.roll(q, 1, axis=-1)
    return q


def rotvec_to_matrix(rotvec) -> np.ndarray:
    """Axis-angle vector (radians) -> rotation matrix."""
    return Rotation.from_rotvec(np.asarray(rotvec, dtype=np.float64)).as_matrix()


def _skew(w: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])


def so3_exp(rotvec) -> np.ndarray:
    """Axis-angle vector (radians, one [3]) -> rotation matrix by Rodrigues' formula (the same
    matrix as ``rotvec_to_matrix`` to rounding, without scipy's per-call overhead; series near 0)."""
    w = np.asarray(rotvec, dtype=np.float64).reshape(3)
    th2 = float(w @ w)
    K = _skew(w)
    if th2 < 1e-12:  # Taylor: sin(th)/th = 1 - th^2/6, (1 - cos th)/th^2 = 1/2 - th^2/24
        a, b = 1.0 - th2 / 6.0, 0.5 - th2 / 24.0
    else:
        th = np.sqrt(th2)
        a, b = np.sin(th) / th, (1.0 - np.cos(th)) / th2
    return np.eye(3) + a * K + b * (K @ K)


def so3_left_jacobian(rotvec) -> np.ndarray:
    """Left Jacobian of SO(3) at ``rotvec``: d(exp([w + d]x) y) = -[exp([w]x) y]x J_l(w) d (first order)."""
    w = np.asarray(rotvec, dtype=np.float64).reshape(3)
    th2 = float(w @ w)
    K = _skew(w)
    if th2 < 1e-12:
        b, c = 0.5 - th2 / 24.0, 1.0 / 6.0 - th2 / 120.0
    else:
        th = np.sqrt(th2)
        b, c = (1.0 - np.cos(th)) / th2, (th - np.sin(th)) / (th2 * th)
    return np.eye(3) + b * K + c * (K @ K)


def matrix_to_rotvec(R) -> np.ndarray:
    """Rotation matrix -> axis-angle vector (radians)."""
    return Rotation.from_matrix(np.asarray(R, dtype=np.float64)).as_rotvec()


def orthonormality_error(R) -> float:
    """max(|R R^T - I|, |det R - 1|) of a [3,3] matrix: 0 for an exact rotation."""
    R = np.asarray(R, dtype=np.float64)
    return float(max(np.abs(R @ R.T - np.eye(3)).max(), abs(np.linalg.det(R) - 1.0)))


def is_rotation_matrix(R, tol: float = 1e-6) -> bool:
    """True when ``R`` is 3x3, orthonormal within ``tol`` and has determinant +1."""
    R = np.asarray(R, dtype=np.float64)
    if R.shape != (3, 3) or not np.all(np.isfinite(R)):
        return False
    return orthonormality_error(R) <= tol


def check_rotation_matrix(R, name: str = "rotation", tol: float = 1e-4) -> np.ndarray:
    """Return ``R`` as float64 [3,3], or raise ValueError saying how far from a rotation it is."""
    R = np.asarray(R, dtype=np.float64)
    if R.shape != (3, 3):
        raise ValueError(f"{name}: expected a 3x3 rotation matrix, got shape {R.shape}")
    if not np.all(np.isfinite(R)):
        raise ValueError(f"{name}: rotation matrix has NaN/Inf entries")
    err = float(np.abs(R @ R.T - np.eye(3)).max())
    det = float(np.linalg.det(R))
    if err > tol or abs(det - 1.0) > tol:
        raise ValueError(
            f"{name}: not a rotation matrix (max |R R^T - I| = {err:.2e}, det = {det:.6f}; "
            f"tolerance {tol:.0e})"
        )
    return R


def orthonormalize(R) -> np.ndarray:
    """Nearest rotation matrix (SVD projection, det +1)."""
    U, _, Vt = np.linalg.svd(np.asarray(R, dtype=np.float64))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt


def rotation_angle(R_a, R_b=None, degrees: bool = True) -> float:
    """Geodesic angle between two rotations (or of one rotation from identity)."""
    R_a = np.asarray(R_a, dtype=np.float64)
    R = R_a if R_b is None else R_a @ np.asarray(R_b, dtype=np.float64).T
    c = np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)
    angle = float(np.arccos(c))
    # arccos loses precision near 0; use the rotation vector there
    if angle < 1e-3:
        angle = float(np.linalg.norm(Rotation.from_matrix(orthonormalize(R)).as_rotvec()))
    return float(np.degrees(angle)) if degrees else angle
