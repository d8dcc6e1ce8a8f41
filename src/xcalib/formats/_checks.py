"""Validation helpers shared by the format readers: every failure is a ``FormatError`` naming
the file and the field, what was expected and what was found."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ..errors import FormatError
from ..geometry.camera import check_camera_numbers
from ..geometry.rotations import orthonormality_error, orthonormalize, quaternion_to_matrix

__all__ = ["ROTATION_TOL", "REPAIR_TOL", "require_numbers", "as_matrix", "checked_rotation", "checked_quaternion",
           "require", "as_float"]

#: A rotation read from a file is accepted as-is when max|R R^T - I| and |det - 1| are within this.
ROTATION_TOL = 1e-5
#: ``repair=True`` re-orthonormalises rotations whose error is within this (and no further).
REPAIR_TOL = 1e-3


def require(d: dict, key: str, path, field_prefix: str = "", kind: type | None = None) -> Any:
    """``d[key]`` or a FormatError naming the missing field; ``kind=dict``/``list`` also checks
    the value's type."""
    if not isinstance(d, dict):
        raise FormatError(path, f"expected a JSON object, got {type(d).__name__}", field_prefix.rstrip(".") or None)
    if key not in d:
        have = ", ".join(sorted(map(str, d))) or "nothing"
        raise FormatError(path, f"missing key (found: {have})", f"{field_prefix}{key}")
    v = d[key]
    if kind is not None and not isinstance(v, kind):
        raise FormatError(path, f"expected a JSON {'object' if kind is dict else 'array'}, got {type(v).__name__}",
                          f"{field_prefix}{key}")
    return v


def require_numbers(values, path, field: str, *, integral: bool = False):
    """``values`` (a number or nested lists of numbers) unchanged, or a FormatError naming the
    field when an entry is a string, a bool, null or a mapping (YAML / JSON readers: ``"500"``
    or ``true`` is not a focal length); ``integral``: non-negative integers only."""
    def bad(v):  # (the offending value,) or None
        if isinstance(v, (list, tuple)):
            for x in v:
                b = bad(x)
                if b is not None:
                    return b
            return None
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            return (v,)
        if integral and (not isinstance(v, int) or v < 0):
            return (v,)
        return None

    b = bad(values)
    if b is not None:
        raise FormatError(path, f"expected {'an integer' if integral else 'numbers'}, found {b[0]!r:.60} "
                                f"({type(b[0]).__name__})", field)
    return values


def as_float(value, path, field: str) -> float:
    """A finite float, or a FormatError naming the field (a JSON true / false is not a number)."""
    if isinstance(value, (bool, np.bool_)):
        raise FormatError(path, f"expected a number, got {value!r}", field)
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise FormatError(path, f"expected a number, got {value!r}", field) from None
    if not np.isfinite(v):
        raise FormatError(path, f"expected a finite number, got {v}", field)
    return v


def as_matrix(values, shape: tuple[int, ...], path, field: str, *, alt_shapes=()) -> np.ndarray:
    """Numbers -> float64 array of ``shape`` (flat lists are reshaped row-major).

    ``alt_shapes`` lists other accepted shapes (e.g. a [4,4] for a [3,4] whose last row is
    ``0 0 0 1``); the result is always ``shape``. A JSON true / false is not a number (as in
    :func:`as_float`; NumPy would read it as 1.0 / 0.0).
    """
    try:
        a = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError):
        raise FormatError(path, f"expected {_shape_str(shape)} numbers, got non-numeric values", field) from None
    n = int(np.prod(shape))
    if a.size == n:
        a = a.reshape(shape)
    else:
        for alt in alt_shapes:
            if a.size == int(np.prod(alt)):
                a = a.reshape(alt)[tuple(slice(0, s) for s in shape)]
                break
        else:
            accepted = " or ".join(_shape_str(s) for s in (shape, *alt_shapes))
            raise FormatError(path, f"expected {accepted} = {n} numbers, got {a.size} (shape {a.shape})", field)
    if _holds_bool(values):  # checked once the values are known to be a small regular array
        raise FormatError(path, f"expected {_shape_str(shape)} numbers, got true / false", field)
    if not np.all(np.isfinite(a)):
        raise FormatError(path, "matrix has NaN/Inf entries", field)
    return a


def _holds_bool(values) -> bool:
    """Whether ``values`` (a number, nested lists, an array) is or holds a bool."""
    if isinstance(values, np.ndarray):
        return values.dtype == np.bool_ or (values.dtype == object and any(map(_holds_bool, values.ravel())))
    if isinstance(values, (list, tuple)):
        return any(map(_holds_bool, values))
    return isinstance(values, (bool, np.bool_))


def _shape_str(shape) -> str:
    return "x".join(str(s) for s in shape)


def checked_rotation(R, path, field: str, *, repair: bool = False) -> np.ndarray:
    """Accept a [3,3] rotation within ``ROTATION_TOL``; with ``repair`` re-orthonormalise one
    within ``REPAIR_TOL``; otherwise raise FormatError stating the error and the tolerances."""
    R = as_matrix(R, (3, 3), path, field)
    err = orthonormality_error(R)
    if err <= ROTATION_TOL:
        return R
    if repair and err <= REPAIR_TOL and np.linalg.det(R) > 0:
        return orthonormalize(R)
    hint = (" (within the repair tolerance: pass repair=True / --repair to re-orthonormalise)"
            if err <= REPAIR_TOL and not repair else "")
    raise FormatError(
        path, f"not a rotation matrix: error {err:.2e} (max |R R^T - I|, |det - 1|) exceeds the "
              f"tolerance {ROTATION_TOL:.0e}{hint}", field)


def checked_quaternion(q, path, field: str, order: str = "xyzw") -> np.ndarray:
    """A [4] quaternion -> [3,3] rotation; zero norm or non-finite -> FormatError."""
    q = as_matrix(q, (4,), path, field)
    if np.linalg.norm(q) < 1e-9:
        raise FormatError(path, f"quaternion has zero norm ({order} = {q.tolist()})", field)
    return quaternion_to_matrix(q, order=order)


def path_str(path: str | Path | None) -> str:
    return "<input>" if path is None else str(path)


def plausible_camera(intr, path, field: str = "intrinsics"):
    """``intr`` (a pinhole ``CameraIntrinsics``) when its numbers can be a real camera's
    (``geometry.camera.check_camera_numbers``: every value within ``MAX_PIXELS``, then
    ``check_plausible``), else a FormatError naming the file and ``field``."""
    if intr is None or not hasattr(intr, "check_plausible") or not hasattr(intr, "fx"):
        return intr
    try:
        check_camera_numbers(intr)
    except ValueError as exc:
        raise FormatError(path, str(exc), field) from None
    return intr
