"""The camera-model interface every model implements (pure numpy, vectorised).

A camera model maps camera-frame points ``P = (X, Y, Z)`` (OpenCV optical frame: x right,
y down, z forward; metres) to pixels ``(u, v)`` and pixels back to unit rays. Every model here
has the same last step, ``u = fx * mx + cx``, ``v = fy * my + cy``, from model-specific
*normalised* coordinates ``(mx, my)``; a model implements

* ``_normalise(P) -> (m [N,2], dm/dP [N,2,3] or None, valid [N])``, and
* ``_lift(m) -> (rays [N,3], valid [N])`` its inverse up to scale,

and, when it carries a lens distortion applied to ``m`` (pinhole and unified models with
OpenCV radial-tangential coefficients), ``_distort``/``_undistort``.

**Valid region.** A point outside a model's domain (behind a pinhole camera, beyond the
monotonic range of a distortion polynomial, past the unified models' limit ``z > -w * d``) is
*flagged*: ``valid`` is False and its pixel is NaN. It is never folded back into the image,
where a polynomial past its turning point or a ray from behind the camera would otherwise
land as a plausible but wrong pixel.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any, ClassVar

import numpy as np

__all__ = ["CameraModel", "check_finite", "check_range"]


def check_finite(cls_name: str, name: str, value: Any) -> float:
    try:
        out = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{cls_name}.{name}: expected a number, got {value!r}") from None
    if not math.isfinite(out):
        raise ValueError(f"{cls_name}.{name}: expected a finite number, got {out}")
    return out


def check_range(cls_name: str, name: str, value: Any, lo: float, hi: float, *,
                lo_open: bool = False, hi_open: bool = False) -> float:
    out = check_finite(cls_name, name, value)
    bad = (out <= lo if lo_open else out < lo) or (out >= hi if hi_open else out > hi)
    if bad:
        left = "(" if lo_open else "["
        right = ")" if hi_open else "]"
        raise ValueError(f"{cls_name}.{name}: expected a value in {left}{lo:g}, {hi:g}{right}, got {out:g}")
    return out


@dataclass(frozen=True)
class CameraModel:
    """Base of every camera model: focal lengths and principal point in pixels, optional image
    size. Subclasses are frozen dataclasses adding their own parameters; ``name`` is the
    registry name (:func:`xcalib.geometry.camera_models.get_model`)."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: int | None = None
    height: int | None = None

    name: ClassVar[str] = "base"
    #: model-specific parameters (beyond fx, fy, cx, cy, width, height), in to_dict order
    param_names: ClassVar[tuple[str, ...]] = ()
    #: largest angle from the optical axis the model can describe at all (radians)
    max_angle_limit: ClassVar[float] = math.pi / 2

    def __post_init__(self) -> None:
        cls = type(self).__name__
        for name in ("fx", "fy", "cx", "cy"):
            object.__setattr__(self, name, check_finite(cls, name, getattr(self, name)))
        if self.fx <= 0 or self.fy <= 0:
            raise ValueError(f"{cls}: focal lengths must be positive pixels, got fx={self.fx}, fy={self.fy}")
        for name in ("width", "height"):
            value = getattr(self, name)
            if value is not None:
                if isinstance(value, bool) or not float(value).is_integer() or int(value) <= 0:
                    raise ValueError(f"{cls}.{name}: expected a positive pixel count, got {value!r}")
                object.__setattr__(self, name, int(value))
        self._check_params()

    # ----------------------------------------------------------- subclass API
    def _check_params(self) -> None:
        """Validate/normalise the model's own parameters (ValueError naming the field)."""

    def _normalise(self, P: np.ndarray, jac: bool):  # pragma: no cover - abstract
        raise NotImplementedError

    def _lift(self, m: np.ndarray):  # pragma: no cover - abstract
        raise NotImplementedError

    def _distort(self, m: np.ndarray, jac: bool):
        """Lens distortion on normalised coordinates: ``(md, dmd/dm [N,2,2] or None, valid)``."""
        return m, None, np.ones(len(m), dtype=bool)

    def _undistort(self, md: np.ndarray):
        return md, np.ones(len(md), dtype=bool)

    # ------------------------------------------------------------- public API
    @property
    def K(self) -> np.ndarray:
        """3x3 float64 matrix of the affine last step (fx, fy, cx, cy)."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def image_size(self) -> tuple[int, int] | None:
        return None if self.width is None or self.height is None else (self.width, self.height)

    @property
    def is_pinhole(self) -> bool:
        """True for the models a straight line stays (nearly) straight in: pinhole (+radtan)."""
        return False

    def project(self, points) -> tuple[np.ndarray, np.ndarray]:
        """Camera-frame points [N,3] (m) -> ``(uv [N,2] px, valid [N] bool)``; NaN where invalid."""
        uv, _, valid = self._project(points, jac=False)
        return uv, valid

    def project_jacobian(self, points) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(uv [N,2], d uv / d P [N,2,3], valid [N])``; NaN rows where invalid."""
        return self._project(points, jac=True)

    def unproject(self, uv) -> tuple[np.ndarray, np.ndarray]:
        """Pixels [N,2] -> ``(unit rays [N,3] in the camera frame, valid [N] bool)``; NaN where
        the pixel is outside the model's image of its valid region."""
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        md = np.empty_like(uv)
        md[:, 0] = (uv[:, 0] - self.cx) / self.fx
        md[:, 1] = (uv[:, 1] - self.cy) / self.fy
        finite = np.all(np.isfinite(md), axis=1)
        md = np.where(finite[:, None], md, 0.0)
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            m, ok_d = self._undistort(md)
            rays, ok_l = self._lift(m)
            norm = np.linalg.norm(rays, axis=1)
            rays = rays / norm[:, None]
        valid = finite & ok_d & ok_l & np.all(np.isfinite(rays), axis=1)
        if np.any(valid):
            # a ray the forward model cannot take (outside its valid region) is not a valid ray
            with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
                _, _, back = self._normalise(np.where(valid[:, None], rays, [0.0, 0.0, 1.0]), False)
            valid &= back
        rays[~valid] = np.nan
        return rays, valid

    def in_image(self, uv, margin: float = 0.0) -> np.ndarray:
        """[N] bool: pixel inside the ``width x height`` image (needs the image size)."""
        if self.image_size is None:
            raise ValueError(f"{type(self).__name__}: the image size (width, height) is not set")
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        with np.errstate(invalid="ignore"):
            return ((uv[:, 0] >= -margin) & (uv[:, 0] <= self.width + margin)
                    & (uv[:, 1] >= -margin) & (uv[:, 1] <= self.height + margin))

    def field_of_view(self) -> tuple[float, float] | None:
        """(horizontal, vertical) field of view in degrees over the image, from unprojecting the
        centres of the four image edges (None without an image size)."""
        if self.image_size is None:
            return None
        W, H = self.width, self.height
        rays, valid = self.unproject([[0.0, self.cy], [W, self.cy], [self.cx, 0.0], [self.cx, H]])
        if not np.all(valid):
            return None
        ang = np.degrees(np.arccos(np.clip(rays[:, 2], -1, 1)))
        return float(ang[0] + ang[1]), float(ang[2] + ang[3])

    def check_image_size(self, width: int, height: int) -> None:
        """Raise ValueError when the principal point lies far outside a width x height image."""
        if not (-0.25 * width <= self.cx <= 1.25 * width and -0.25 * height <= self.cy <= 1.25 * height):
            raise ValueError(
                f"{type(self).__name__}: principal point ({self.cx:.1f}, {self.cy:.1f}) px lies far outside "
                f"the {width}x{height} image; expected roughly 0..{width} x 0..{height}"
            )

    def scaled(self, focal_scale: float) -> "CameraModel":
        """The same model with fx, fy multiplied by ``focal_scale`` (self-calibration)."""
        return self.replace(fx=self.fx * focal_scale, fy=self.fy * focal_scale)

    def replace(self, **changes) -> "CameraModel":
        values = {f.name: getattr(self, f.name) for f in fields(self)}
        values.update(changes)
        return type(self)(**values)

    def with_image_size(self, width: int, height: int) -> "CameraModel":
        return self.replace(width=width, height=height)

    # ----------------------------------------------------------- serialising
    def params(self) -> dict[str, Any]:
        """The model-specific parameters as JSON-ready values."""
        out: dict[str, Any] = {}
        for name in self.param_names:
            value = getattr(self, name)
            out[name] = list(value) if isinstance(value, tuple) else value
        return out

    def to_dict(self) -> dict[str, Any]:
        """xcalib's intrinsics JSON: ``{"model", "fx", "fy", "cx", "cy", <params>, "width", "height"}``."""
        out: dict[str, Any] = {"model": self.name, "fx": self.fx, "fy": self.fy, "cx": self.cx, "cy": self.cy}
        out.update(self.params())
        if self.width is not None:
            out["width"] = self.width
        if self.height is not None:
            out["height"] = self.height
        return out

    # ------------------------------------------------------------- internals
    def _project(self, points, jac: bool):
        P = np.asarray(points, dtype=np.float64)
        if P.ndim != 2 or P.shape[1] < 3:
            raise ValueError(f"{type(self).__name__}.project: expected points [N,3], got shape {P.shape}")
        P = P[:, :3]
        finite = np.all(np.isfinite(P), axis=1)
        if not finite.all():
            P = np.where(finite[:, None], P, [0.0, 0.0, 1.0])
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            m, dm, ok_n = self._normalise(P, jac)
            md, dd, ok_d = self._distort(m, jac)
        valid = finite & ok_n & ok_d
        uv = np.empty_like(md)
        uv[:, 0] = self.fx * md[:, 0] + self.cx
        uv[:, 1] = self.fy * md[:, 1] + self.cy
        valid &= np.all(np.isfinite(uv), axis=1)
        uv[~valid] = np.nan
        if not jac:
            return uv, None, valid
        J = dm if dd is None else np.matmul(dd, dm)
        J = J * np.array([self.fx, self.fy])[None, :, None]
        J[~valid] = np.nan
        return uv, J, valid


def ratio_normalise(P: np.ndarray, den: np.ndarray, dden: np.ndarray | None):
    """``m = (X, Y) / den`` and, given ``d den / d P`` [N,3], ``dm/dP`` [N,2,3]."""
    inv = 1.0 / den
    m = P[:, :2] * inv[:, None]
    if dden is None:
        return m, None
    J = np.zeros((len(P), 2, 3))
    J[:, 0, 0] = inv
    J[:, 1, 1] = inv
    J -= m[:, :, None] * (dden * inv[:, None])[:, None, :]
    return m, J
