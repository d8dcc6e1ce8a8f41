"""Double sphere camera model (Usenko, Demmel & Cremers 2018; Kalibr ``ds-none``).

``d1 = |P|``, ``zeta = xi d1 + Z``, ``d2 = sqrt(X^2 + Y^2 + zeta^2)``,
``(mx, my) = (X, Y) / (alpha d2 + (1 - alpha) zeta)``; ``xi`` in [-1, 1], ``alpha`` in [0, 1].
Valid for ``Z > -w2 d1``, ``w2 = (w1 + xi) / sqrt(2 w1 xi + xi^2 + 1)``,
``w1 = alpha / (1 - alpha)`` (alpha <= 0.5) or ``(1 - alpha) / alpha``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from .base import CameraModel, check_range, ratio_normalise

__all__ = ["DoubleSphere"]


@dataclass(frozen=True)
class DoubleSphere(CameraModel):
    xi: float = 0.0
    alpha: float = 0.5

    name: ClassVar[str] = "double_sphere"
    param_names: ClassVar[tuple[str, ...]] = ("xi", "alpha")
    max_angle_limit: ClassVar[float] = math.pi

    def _check_params(self) -> None:
        cls = type(self).__name__
        object.__setattr__(self, "xi", check_range(cls, "xi", self.xi, -1.0, 1.0))
        object.__setattr__(self, "alpha", check_range(cls, "alpha", self.alpha, 0.0, 1.0))
        a, xi = self.alpha, self.xi
        w1 = (1 - a) / a if a > 0.5 else a / (1 - a)
        w2 = (w1 + xi) / math.sqrt(2 * w1 * xi + xi * xi + 1)
        object.__setattr__(self, "_w2", w2)

    def _normalise(self, P, jac):
        a, xi = self.alpha, self.xi
        X, Y, Z = P[:, 0], P[:, 1], P[:, 2]
        r2 = X * X + Y * Y
        d1 = np.sqrt(r2 + Z * Z)
        zeta = xi * d1 + Z
        d2 = np.sqrt(r2 + zeta * zeta)
        den = a * d2 + (1 - a) * zeta
        valid = (Z > -self._w2 * d1) & (d1 > 0) & (den > 0)
        den = np.where(valid, den, 1.0)
        dden = None
        if jac:
            d1s = np.where(d1 > 0, d1, 1.0)[:, None]
            d2s = np.where(d2 > 0, d2, 1.0)[:, None]
            dzeta = xi * P / d1s
            dzeta[:, 2] += 1.0
            dd2 = (np.column_stack([X, Y, np.zeros_like(X)]) + zeta[:, None] * dzeta) / d2s
            dden = a * dd2 + (1 - a) * dzeta
        m, J = ratio_normalise(P, den, dden)
        return m, J, valid

    def _lift(self, m):
        a, xi = self.alpha, self.xi
        r2 = np.einsum("ij,ij->i", m, m)
        disc2 = 1 - (2 * a - 1) * r2
        ok = disc2 >= 0
        mz = (1 - a * a * r2) / (a * np.sqrt(np.where(ok, disc2, 0.0)) + 1 - a)
        disc1 = mz * mz + (1 - xi * xi) * r2
        ok &= disc1 >= 0
        k = (mz * xi + np.sqrt(np.where(disc1 >= 0, disc1, 0.0))) / (mz * mz + r2)
        rays = np.column_stack([k[:, None] * m, k * mz - xi])
        return rays, ok & np.isfinite(k)
