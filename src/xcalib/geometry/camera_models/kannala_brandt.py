"""Kannala-Brandt / OpenCV ``cv::fisheye`` / ROS ``equidistant`` / Kalibr ``pinhole-equi``.

``theta = atan2(sqrt(X^2 + Y^2), Z)`` (the angle off the optical axis, so fields of view past
180 degrees are fine), ``theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8)``,
``(mx, my) = theta_d (X, Y) / sqrt(X^2 + Y^2)``. Valid while ``theta_d`` keeps increasing with
``theta`` (``max_angle``, at most pi); OpenCV's own implementation computes ``theta`` from
``X/Z`` and so folds points behind the camera into the image; here they are flagged.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from .base import CameraModel

__all__ = ["KannalaBrandt"]


@dataclass(frozen=True)
class KannalaBrandt(CameraModel):
    """Equidistant fisheye with four coefficients ``k = (k1, k2, k3, k4)``."""

    k: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0)

    name: ClassVar[str] = "kannala_brandt"
    param_names: ClassVar[tuple[str, ...]] = ("k",)
    max_angle_limit: ClassVar[float] = math.pi

    def _check_params(self) -> None:
        cls = type(self).__name__
        try:
            k = np.asarray(self.k, dtype=np.float64).reshape(-1)
        except (TypeError, ValueError):
            raise ValueError(f"{cls}.k: expected 4 numbers (k1 k2 k3 k4), got {self.k!r}") from None
        if k.size != 4:
            raise ValueError(f"{cls}.k: expected 4 coefficients (k1 k2 k3 k4), got {k.size}")
        if not np.all(np.isfinite(k)):
            raise ValueError(f"{cls}.k: expected finite coefficients, got {k.tolist()}")
        object.__setattr__(self, "k", tuple(float(v) for v in k))
        th = np.linspace(0.0, math.pi, 20001)[1:]
        slope = self._dpoly(th)
        bad = ~(slope > 0)
        tmax = math.pi if not np.any(bad) else float(th[max(int(np.argmax(bad)) - 1, 0)])
        if tmax <= 0.05:
            raise ValueError(f"{cls}.k: theta_d(theta) decreases right away (k={list(self.k)}); "
                             "expected a distortion that keeps theta_d increasing over the field of view")
        object.__setattr__(self, "_tmax", tmax)

    @property
    def max_angle(self) -> float:
        """Largest angle off the optical axis (radians) the model is one-to-one up to."""
        return self._tmax

    def _poly(self, th):
        k1, k2, k3, k4 = self.k
        t2 = th * th
        return th * (1 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))

    def _dpoly(self, th):
        k1, k2, k3, k4 = self.k
        t2 = th * th
        return 1 + t2 * (3 * k1 + t2 * (5 * k2 + t2 * (7 * k3 + t2 * 9 * k4)))

    def _normalise(self, P, jac):
        X, Y, Z = P[:, 0], P[:, 1], P[:, 2]
        rho2 = X * X + Y * Y
        rho = np.sqrt(rho2)
        th = np.arctan2(rho, Z)
        valid = th <= self._tmax
        td = self._poly(th)
        small = rho < 1e-12 * np.abs(Z)
        s = td / rho  # scale theta_d / rho; on the axis its limit is 1/Z
        if small.any():
            valid &= ~(small & (Z <= 0))  # straight behind (or the origin): no direction in the image
            s[small] = 1.0 / np.where(Z[small] > 0, Z[small], 1.0)
        rho_s = np.where(small, 1.0, rho) if jac else None
        m = P[:, :2] * s[:, None]
        if not jac:
            return m, None, valid
        n2 = rho2 + Z * Z
        dth_drho = Z / n2
        dth_dz = -rho / n2
        dtd = self._dpoly(th)
        # ds/drho = (dtd dth/drho rho - td) / rho^2 ; ds/dZ = dtd dth/dZ / rho
        ds_drho = np.where(small, 0.0, (dtd * dth_drho * rho_s - td) / (rho_s * rho_s))
        ds_dz = np.where(small, -1.0 / np.where(Z > 0, Z * Z, 1.0), dtd * dth_dz / rho_s)
        ds = np.empty((len(P), 3))
        ds[:, 0] = ds_drho * np.where(small, 0.0, X / rho_s)
        ds[:, 1] = ds_drho * np.where(small, 0.0, Y / rho_s)
        ds[:, 2] = ds_dz
        J = np.zeros((len(P), 2, 3))
        J[:, 0, 0] = s
        J[:, 1, 1] = s
        J += P[:, :2, None] * ds[:, None, :]
        return m, J, valid

    def _lift(self, m):
        rd = np.sqrt(np.einsum("ij,ij->i", m, m))
        # theta_d(theta) = rd by Newton's method, from theta = rd
        th = np.minimum(rd, self._tmax)
        for _ in range(30):
            f = self._poly(th) - rd
            step = f / self._dpoly(th)
            th = np.clip(th - step, 0.0, self._tmax)
            if np.all(np.abs(step) < 1e-15):
                break
        ok = np.abs(self._poly(th) - rd) < 1e-10 * np.maximum(1.0, rd)
        sin_t = np.sin(th)
        with np.errstate(invalid="ignore", divide="ignore"):
            scale = np.where(rd > 1e-300, sin_t / np.where(rd > 1e-300, rd, 1.0), 1.0)
        rays = np.column_stack([m * scale[:, None], np.cos(th)])
        return rays, ok
