"""Unified camera models: Mei's unified (``xi`` + radial-tangential, Kalibr ``omni-radtan``),
the unified camera model UCM (``alpha``) and the extended UCM (``alpha``, ``beta``; Kalibr
``eucm-none``), after Mei & Rives 2007, Khomutenko et al. 2016 and Usenko et al. 2018.

All three divide ``(X, Y)`` by a denominator that grows with the distance of the point, which
lets them describe fields of view past 180 degrees; each is valid for ``Z > -w * d`` with
``w`` from its parameters (the condition of Usenko et al.), flagged otherwise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from . import _radtan
from .base import CameraModel, check_range, ratio_normalise
from .pinhole import _check_radtan

__all__ = ["Unified", "UCM", "EUCM"]


def _alpha_w(alpha: float) -> float:
    return (1 - alpha) / alpha if alpha > 0.5 else alpha / (1 - alpha)


@dataclass(frozen=True)
class Unified(CameraModel):
    """Mei's unified model: ``(mx, my) = (X, Y) / (Z + xi * |P|)`` then OpenCV radial-tangential
    distortion ``(k1, k2, p1, p2)`` (or none). ``xi >= 0``; ``xi = 0`` is a pinhole, ``xi = 1`` a
    parabolic mirror; fields of view past 180 degrees need ``xi > 1``."""

    xi: float = 0.0
    distortion: tuple[float, ...] = ()

    name: ClassVar[str] = "unified"
    param_names: ClassVar[tuple[str, ...]] = ("xi", "distortion")
    max_angle_limit: ClassVar[float] = math.pi

    def _check_params(self) -> None:
        cls = type(self).__name__
        object.__setattr__(self, "xi", check_range(cls, "xi", self.xi, 0.0, 1e3))
        d = _check_radtan(cls, self.distortion, lengths=(0, 4))
        object.__setattr__(self, "distortion", d)
        object.__setattr__(self, "_d14", _radtan.full14(d))
        object.__setattr__(self, "_rmax", _radtan.monotone_radius(self._d14, 1e3))
        object.__setattr__(self, "_w", self.xi if self.xi <= 1 else 1 / self.xi)

    def _normalise(self, P, jac):
        d = np.sqrt(np.einsum("ij,ij->i", P, P))
        valid = (P[:, 2] > -self._w * d) & (d > 0)
        den = np.where(valid, P[:, 2] + self.xi * d, 1.0)
        dden = None
        if jac:
            dden = self.xi * P / np.where(d > 0, d, 1.0)[:, None]
            dden[:, 2] += 1.0
        m, J = ratio_normalise(P, den, dden)
        return m, J, valid

    def _distort(self, m, jac):
        return _radtan.distort_within(m, self._d14, self._rmax, jac)

    def _undistort(self, md):
        return _radtan.undistort_within(md, self._d14, self._rmax)

    def _lift(self, m):
        xi = self.xi
        r2 = np.einsum("ij,ij->i", m, m)
        disc = 1 + (1 - xi * xi) * r2
        ok = disc >= 0
        fac = (xi + np.sqrt(np.where(ok, disc, 0.0))) / (r2 + 1)
        rays = np.column_stack([fac[:, None] * m, fac - xi])
        return rays, ok


@dataclass(frozen=True)
class EUCM(CameraModel):
    """Extended unified model: ``(mx, my) = (X, Y) / (alpha * rho + (1 - alpha) * Z)`` with
    ``rho = sqrt(beta (X^2 + Y^2) + Z^2)``; ``alpha`` in [0, 1], ``beta > 0``."""

    alpha: float = 0.5
    beta: float = 1.0

    name: ClassVar[str] = "eucm"
    param_names: ClassVar[tuple[str, ...]] = ("alpha", "beta")
    max_angle_limit: ClassVar[float] = math.pi

    def _check_params(self) -> None:
        cls = type(self).__name__
        object.__setattr__(self, "alpha", check_range(cls, "alpha", self.alpha, 0.0, 1.0))
        object.__setattr__(self, "beta", check_range(cls, "beta", self.beta, 0.0, 1e6, lo_open=True))

    def _normalise(self, P, jac):
        a, b = self.alpha, self.beta
        X, Y, Z = P[:, 0], P[:, 1], P[:, 2]
        rho = np.sqrt(b * (X * X + Y * Y) + Z * Z)
        w = _alpha_w(a) if 0 < a < 1 else (0.0 if a == 0 else 0.0)
        valid = (Z > -w * rho) & (rho > 0)
        den = a * rho + (1 - a) * Z
        valid &= den > 0
        den = np.where(valid, den, 1.0)
        dden = None
        if jac:
            rs = np.where(rho > 0, rho, 1.0)
            dden = np.column_stack([a * b * X / rs, a * b * Y / rs, a * Z / rs + (1 - a)])
        m, J = ratio_normalise(P, den, dden)
        return m, J, valid

    def _lift(self, m):
        a, b = self.alpha, self.beta
        r2 = np.einsum("ij,ij->i", m, m)
        g = 1 - a
        disc = 1 - (a - g) * b * r2
        ok = disc >= 0
        k = (1 - a * a * b * r2) / (a * np.sqrt(np.where(ok, disc, 0.0)) + g)
        rays = np.column_stack([m, k])
        return rays, ok & np.isfinite(k)


@dataclass(frozen=True)
class UCM(EUCM):
    """Unified camera model in the ``alpha`` form: ``(X, Y) / (alpha * |P| + (1 - alpha) * Z)``
    (Mei's with ``xi = alpha / (1 - alpha)`` and the focal length times ``1 - alpha``)."""

    name: ClassVar[str] = "ucm"
    param_names: ClassVar[tuple[str, ...]] = ("alpha",)

    def _check_params(self) -> None:
        if float(self.beta) != 1.0:
            raise ValueError(f"UCM.beta: the UCM has beta = 1 (use EUCM for other values), got {self.beta}")
        super()._check_params()
