"""Pinhole camera intrinsics with OpenCV distortion (pixels)."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["CameraIntrinsics"]

_DIST_LENGTHS = (0, 4, 5, 8, 12, 14)


@dataclass(frozen=True)
class CameraIntrinsics:
    """Camera intrinsics in pixels.

    ``fx, fy`` focal lengths, ``cx, cy`` principal point, ``distortion`` OpenCV-ordered
    coefficients (k1, k2, p1, p2[, k3[, k4, k5, k6]]) or None for a rectified image.
    ``width``/``height`` (optional) are the image size the intrinsics belong to.
    """

    fx: float
    fy: float
    cx: float
    cy: float
    distortion: np.ndarray | None = field(default=None, compare=False)
    width: int | None = None
    height: int | None = None

    def __post_init__(self) -> None:
        for name in ("fx", "fy", "cx", "cy"):
            value = getattr(self, name)
            try:
                value = float(value)
            except (TypeError, ValueError):
                raise ValueError(f"CameraIntrinsics.{name}: expected a number, got {value!r}") from None
            if not np.isfinite(value):
                raise ValueError(f"CameraIntrinsics.{name}: expected a finite number, got {value}")
            object.__setattr__(self, name, value)
        if self.fx <= 0 or self.fy <= 0:
            raise ValueError(
                f"CameraIntrinsics: focal lengths must be positive pixels, got fx={self.fx}, fy={self.fy}"
            )
        if self.distortion is not None:
            d = np.asarray(self.distortion, dtype=np.float64).reshape(-1)
            if d.size == 0 or not np.any(d):
                d = None
            elif d.size not in _DIST_LENGTHS:
                raise ValueError(
                    "CameraIntrinsics.distortion: expected 4, 5, 8, 12 or 14 OpenCV coefficients "
                    f"(k1 k2 p1 p2 [k3 [k4 k5 k6]]), got {d.size}"
                )
            elif not np.all(np.isfinite(d)):
                raise ValueError(f"CameraIntrinsics.distortion: expected finite coefficients, got {d.tolist()}")
            object.__setattr__(self, "distortion", d)
        for name in ("width", "height"):
            value = getattr(self, name)
            if value is not None:
                if int(value) <= 0:
                    raise ValueError(f"CameraIntrinsics.{name}: expected a positive pixel count, got {value}")
                object.__setattr__(self, name, int(value))
        if self.width is not None and self.height is not None:
            self.check_image_size(self.width, self.height)

    # ------------------------------------------------------------------ views
    @property
    def K(self) -> np.ndarray:
        """3x3 float64 camera matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def dist_coeffs(self) -> np.ndarray:
        """Distortion as float64 (5 zeros when there is none)."""
        if self.distortion is None:
            return np.zeros(5)
        return np.asarray(self.distortion, dtype=np.float64).copy()

    @property
    def has_distortion(self) -> bool:
        return self.distortion is not None

    # ----------------------------------------------------------- constructors
    @classmethod
    def from_matrix(cls, K: Any, distortion: Any = None, *, width: int | None = None,
                    height: int | None = None) -> "CameraIntrinsics":
        """Build from a 3x3 matrix ``K`` (pixels)."""
        K = np.asarray(K, dtype=np.float64)
        if K.shape != (3, 3):
            raise ValueError(f"CameraIntrinsics.from_matrix: K must be 3x3, got shape {K.shape}")
        return cls(K[0, 0], K[1, 1], K[0, 2], K[1, 2], distortion, width, height)

    @classmethod
    def from_dict(cls, d: dict, *, source: str = "intrinsics") -> "CameraIntrinsics":
        """From ``{fx, fy, cx, cy[, distortion][, width, height]}`` (also accepts ``K``); a
        ``model`` other than pinhole / pinhole_radtan is a ValueError (never read as pinhole)."""
        if isinstance(d, dict) and d.get("model") is not None:
            _check_pinhole_model(d["model"], source)
        if "K" in d and not all(k in d for k in ("fx", "fy", "cx", "cy")):
            return cls.from_matrix(np.asarray(d["K"], dtype=np.float64).reshape(3, 3),
                                   d.get("distortion"), width=d.get("width"), height=d.get("height"))
        missing = [k for k in ("fx", "fy", "cx", "cy") if k not in d]
        if missing:
            raise ValueError(f"{source}: missing key(s) {missing}; expected fx, fy, cx, cy (pixels)")
        return cls(d["fx"], d["fy"], d["cx"], d["cy"], d.get("distortion"), d.get("width"), d.get("height"))

    @classmethod
    def from_json(cls, path: str | Path) -> "CameraIntrinsics":
        """Read a JSON file like ``{"fx":..,"fy":..,"cx":..,"cy":..,"distortion":[..]}``."""
        from ..errors import FormatError

        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"intrinsics file not found: {path}")
        try:
            d = json.loads(path.read_text(encoding="utf-8"))
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise FormatError(path, f"not valid JSON ({exc})") from None
        return cls.from_json_object(d, path)

    @classmethod
    def from_json_object(cls, d, path) -> "CameraIntrinsics":
        """Intrinsics from the parsed JSON ``d`` of file ``path``: ``{"fx", "fy", "cx", "cy"}`` or
        ``{"K"}``; anything else is a FormatError naming the file and the missing key."""
        from ..errors import FormatError

        if not isinstance(d, dict):
            raise FormatError(path, f"expected a JSON object, got {type(d).__name__}")
        if d.get("model") is not None:
            _check_pinhole_model(d["model"], path)
        missing = [k for k in ("fx", "fy", "cx", "cy") if k not in d]
        if missing and "K" not in d:
            raise FormatError(path, f"missing key; expected fx, fy, cx, cy (pixels) or K [3,3], found {sorted(d)}",
                              field=missing[0])
        try:
            return cls.from_dict(d, source="CameraIntrinsics")
        except (TypeError, ValueError, OverflowError) as exc:
            raise FormatError(path, str(exc)) from None

    def to_dict(self) -> dict:
        out: dict[str, Any] = {"fx": self.fx, "fy": self.fy, "cx": self.cx, "cy": self.cy,
                               "distortion": [] if self.distortion is None else self.distortion.tolist()}
        if self.width is not None:
            out["width"] = self.width
        if self.height is not None:
            out["height"] = self.height
        return out

    def with_image_size(self, width: int, height: int) -> "CameraIntrinsics":
        return CameraIntrinsics(self.fx, self.fy, self.cx, self.cy, self.distortion, width, height)

    # ----------------------------------------------------------------- checks
    def check_image_size(self, width: int, height: int) -> None:
        """Raise ValueError when the principal point lies far outside a width x height image."""
        if not (-0.25 * width <= self.cx <= 1.25 * width and -0.25 * height <= self.cy <= 1.25 * height):
            raise ValueError(
                f"CameraIntrinsics: principal point ({self.cx:.1f}, {self.cy:.1f}) px lies far outside "
                f"the {width}x{height} image; expected roughly 0..{width} x 0..{height}"
            )

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, CameraIntrinsics):
            return NotImplemented
        return (np.allclose(self.K, other.K) and np.allclose(self.dist_coeffs[:5], other.dist_coeffs[:5])
                and self.width == other.width and self.height == other.height)

    def __hash__(self) -> int:
        return hash((self.fx, self.fy, self.cx, self.cy))


def _check_pinhole_model(model, path) -> None:
    """A ``model`` other than pinhole (+ OpenCV distortion) given to a pinhole-only reader is a
    FormatError (a ValueError) naming the field; its other parameters are never silently dropped."""
    from ..errors import FormatError
    from .camera_models import canonical_name

    try:
        name = canonical_name(model) if isinstance(model, str) else None
    except ValueError as exc:
        raise FormatError(path, str(exc), "model") from None
    if name not in ("pinhole", "pinhole_radtan"):
        raise FormatError(path, f"a {model!r} camera cannot be read as pinhole intrinsics (CameraIntrinsics is "
                                "pinhole + OpenCV distortion); read it with xcalib.formats.cameras.read_camera",
                          "model")
