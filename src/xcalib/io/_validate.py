"""Validation of the numbers frame readers load (detections.json, HDF5 caches): finite boxes that
are not inverted, rigid extrinsics, integral counts. Every failure is a FormatError naming the
file, the field and the row."""

from __future__ import annotations

import numpy as np

from ..errors import FormatError
from .pointcloud import MAX_COORD_M

__all__ = ["check_boxes_2d", "check_boxes_3d", "check_rigid", "check_count", "RIGID_TOL"]

#: max |R R^T - I| / |det R - 1| of a rotation in frame extrinsics (files store 6+ digits).
RIGID_TOL = 1e-3


def _first_bad(ok: np.ndarray) -> int:
    return int(np.flatnonzero(~ok)[0])


def check_boxes_2d(source, field: str, b: np.ndarray) -> np.ndarray:
    """[K,4] pixels: finite, ``x1 <= x2`` and ``y1 <= y2``."""
    if len(b) == 0:
        return b
    fin = np.isfinite(b).all(axis=1)
    if not fin.all():
        i = _first_bad(fin)
        raise FormatError(source, f"row {i}: NaN/Inf in a 2D box {b[i].tolist()}", field)
    ok = (b[:, 2] >= b[:, 0]) & (b[:, 3] >= b[:, 1])
    if not ok.all():
        i = _first_bad(ok)
        raise FormatError(source, f"row {i}: inverted 2D box {b[i].tolist()} (need x1 <= x2, y1 <= y2)", field)
    return b


#: Largest |coordinate| or size (m) of a 3D box: the point clouds' own limit.
MAX_BOX_M = MAX_COORD_M


def check_boxes_3d(source, field: str, b: np.ndarray) -> np.ndarray:
    """[M,6] (extents: max >= min; or centre + positive sizes) or [M,7] box7 (positive sizes); finite."""
    if len(b) == 0:
        return b
    fin = np.isfinite(b).all(axis=1)
    if not fin.all():
        i = _first_bad(fin)
        raise FormatError(source, f"row {i}: NaN/Inf in a 3D box {b[i].tolist()}", field)
    far = (np.abs(b[:, :6]) > MAX_BOX_M).any(axis=1)
    if far.any():
        i = _first_bad(~far)
        raise FormatError(source, f"row {i}: a 3D box coordinate or size beyond {MAX_BOX_M:g} m {b[i].tolist()} "
                                  "(LiDAR frames are metres: corrupt data or wrong units)", field)
    sizes_ok = (b[:, 3:6] > 0).all(axis=1)
    ok = sizes_ok if b.shape[1] == 7 else ((b[:, 3:6] >= b[:, 0:3]).all(axis=1) | sizes_ok)
    if not ok.all():
        i = _first_bad(ok)
        raise FormatError(source, f"row {i}: inverted 3D box {b[i].tolist()} (extents need max >= min, "
                                  "centre boxes positive sizes)", field)
    return b


def check_rigid(source, field: str, T: np.ndarray) -> np.ndarray:
    """A finite [4,4] rigid transform: orthonormal rotation (det +1), last row 0 0 0 1."""
    from ..geometry.rotations import orthonormality_error

    T = np.asarray(T, dtype=np.float64)
    if T.shape != (4, 4) or not np.isfinite(T).all():
        raise FormatError(source, f"expected a finite 4x4 matrix, got shape {list(T.shape)}", field)
    if np.abs(T[3] - [0.0, 0.0, 0.0, 1.0]).max() > 1e-9:
        raise FormatError(source, f"last row must be [0, 0, 0, 1], got {T[3].tolist()}", field)
    err = orthonormality_error(T[:3, :3])
    if err > RIGID_TOL:
        raise FormatError(source, f"not a rigid transform: rotation error {err:.2e} (max |R R^T - I|, |det - 1|) "
                                  f"exceeds {RIGID_TOL:g}", field)
    return T


def check_count(source, field: str, value) -> int:
    """A non-negative integral count (``3.7`` or ``-1`` is a FormatError, not 3)."""
    a = np.asarray(value)
    if a.size != 1 or a.dtype.kind not in "iuf" or a.dtype.kind == "b":
        raise FormatError(source, f"expected one integer, got {a.dtype} of shape {a.shape}", field)
    v = a.reshape(()).item()
    if isinstance(v, float) and (not np.isfinite(v) or v != int(v)):
        raise FormatError(source, f"expected an integer count, got {v!r}", field)
    if int(v) < 0:
        raise FormatError(source, f"expected a count >= 0, got {int(v)}", field)
    return int(v)
