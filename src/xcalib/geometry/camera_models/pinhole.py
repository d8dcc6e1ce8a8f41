"""Pinhole cameras: no distortion, and OpenCV radial-tangential / rational / thin-prism /
tilted-sensor distortion (4, 5, 8, 12 or 14 coefficients; ROS ``plumb_bob`` and
``rational_polynomial``) — today's :class:`~xcalib.geometry.camera.CameraIntrinsics`."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, ClassVar

import numpy as np

from . import _radtan
from .base import CameraModel, ratio_normalise

if TYPE_CHECKING:
    from ..camera import CameraIntrinsics

__all__ = ["Pinhole", "PinholeRadtan", "MIN_DEPTH"]

#: camera-frame depth (m) a pinhole camera needs to see a point
MIN_DEPTH = 1e-6
_E_Z = np.array([0.0, 0.0, 1.0])


def _check_radtan(cls: str, dist, lengths=_radtan.RADTAN_LENGTHS) -> tuple[float, ...]:
    if dist is None:
        return ()
    try:
        d = np.asarray(dist, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise ValueError(f"{cls}.distortion: expected a list of numbers, got {dist!r}") from None
    if d.size not in lengths:
        want = ", ".join(str(n) for n in lengths if n)
        raise ValueError(f"{cls}.distortion: expected {want} OpenCV coefficients "
                         f"(k1 k2 p1 p2 [k3 [k4 k5 k6 [s1 s2 s3 s4 [tauX tauY]]]]), got {d.size}")
    if not np.all(np.isfinite(d)):
        raise ValueError(f"{cls}.distortion: expected finite coefficients, got {d.tolist()}")
    return tuple(float(v) for v in d)


@dataclass(frozen=True)
class Pinhole(CameraModel):
    """Ideal pinhole: ``u = fx X/Z + cx``, ``v = fy Y/Z + cy``; valid for ``Z > 1e-6``."""

    name: ClassVar[str] = "pinhole"

    @property
    def is_pinhole(self) -> bool:
        return True

    def _normalise(self, P, jac):
        valid = P[:, 2] > MIN_DEPTH
        z = np.where(valid, P[:, 2], 1.0)
        m, J = ratio_normalise(P, z, np.broadcast_to(_E_Z, P.shape) if jac else None)
        return m, J, valid

    def _lift(self, m):
        return np.column_stack([m, np.ones(len(m))]), np.ones(len(m), dtype=bool)

    def to_intrinsics(self) -> "CameraIntrinsics":
        from ..camera import CameraIntrinsics

        return CameraIntrinsics(self.fx, self.fy, self.cx, self.cy, None, self.width, self.height)


@dataclass(frozen=True)
class PinholeRadtan(Pinhole):
    """Pinhole with OpenCV distortion ``(k1, k2, p1, p2[, k3[, k4, k5, k6[, s1..s4[, tauX, tauY]]]])``.

    Valid region: in front of the camera and inside the radius where the radial polynomial is
    still one-to-one (``max_radius``; past it the polynomial folds points back into the image)."""

    distortion: tuple[float, ...] = ()

    name: ClassVar[str] = "pinhole_radtan"
    param_names: ClassVar[tuple[str, ...]] = ("distortion",)

    def _check_params(self) -> None:
        d = _check_radtan(type(self).__name__, self.distortion)
        object.__setattr__(self, "distortion", d)
        object.__setattr__(self, "_d14", _radtan.full14(d))
        object.__setattr__(self, "_rmax", _radtan.monotone_radius(self._d14, 1e3))

    @property
    def max_radius(self) -> float:
        """Normalised radius (tan of the angle off axis) up to which the model is one-to-one."""
        return self._rmax

    def _distort(self, m, jac):
        return _radtan.distort_within(m, self._d14, self._rmax, jac)

    def _undistort(self, md):
        return _radtan.undistort_within(md, self._d14, self._rmax)

    def to_intrinsics(self) -> "CameraIntrinsics":
        from ..camera import CameraIntrinsics

        return CameraIntrinsics(self.fx, self.fy, self.cx, self.cy,
                                np.array(self.distortion) if self.distortion else None, self.width, self.height)

    @classmethod
    def from_intrinsics(cls, intr: "CameraIntrinsics") -> "Pinhole":
        """The model of a :class:`CameraIntrinsics` (``Pinhole`` when it has no distortion)."""
        if intr.distortion is None:
            return Pinhole(intr.fx, intr.fy, intr.cx, intr.cy, intr.width, intr.height)
        return cls(intr.fx, intr.fy, intr.cx, intr.cy, intr.width, intr.height, tuple(intr.distortion.tolist()))
