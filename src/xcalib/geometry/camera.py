"""Pinhole camera intrinsics with OpenCV distortion (pixels)."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["CameraIntrinsics", "MAX_PIXELS", "check_camera_numbers"]

_DIST_LENGTHS = (0, 4, 5, 8, 12, 14)

#: Largest focal length or |principal point| (px) a camera file may hold (images are at most ~1e5 px
#: wide; beyond that the numbers are corrupt, not a camera).
MAX_PIXELS = 1.0e6


def check_camera_numbers(intr) -> None:
    """Raise ValueError unless the numbers of ``intr`` (a pinhole ``CameraIntrinsics``) can be a real
    camera's: fx, fy, |cx|, |cy| within :data:`MAX_PIXELS`, then :meth:`CameraIntrinsics.check_plausible`
    (focal lengths against the image size, square-ish pixels, distortion). The readers' one rule
    (``formats._checks.plausible_camera``, the HDF5 cache), each wrapping it in a FormatError."""
    big = max(abs(float(intr.fx)), abs(float(intr.fy)), abs(float(intr.cx)), abs(float(intr.cy)))
    if not big <= MAX_PIXELS:
        raise ValueError(f"fx={intr.fx:g}, fy={intr.fy:g}, cx={intr.cx:g}, cy={intr.cy:g}: beyond "
                         f"{MAX_PIXELS:g} px (corrupt data)")
    intr.check_plausible()


def _non_number(value, integral: bool = False):
    """``(entry,)`` for the first entry of ``value`` (a number or nested lists of numbers) that
    is not a number (a string, a bool, null, a mapping; a non-integral or out-of-range value when
    ``integral``), or None."""
    if isinstance(value, (list, tuple)):
        for v in value:
            bad = _non_number(v, integral)
            if bad is not None:
                return bad
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return (value,)
    if integral and (not isinstance(value, int) or not 0 < value <= 1_000_000):
        return (value,)
    return None


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
        if not np.all(np.isfinite(K)):
            raise ValueError(f"CameraIntrinsics.from_matrix: K has NaN/Inf entries: {K.tolist()}")
        scale = max(abs(K[0, 0]), abs(K[1, 1]), 1.0)
        if abs(K[0, 1]) > 1e-6 * scale or abs(K[1, 0]) > 1e-6 * scale or np.abs(K[2] - [0, 0, 1]).max() > 1e-6:
            raise ValueError("CameraIntrinsics.from_matrix: K must be [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] "
                             f"(no skew, K[2,2] = 1), got {K.tolist()}")
        return cls(K[0, 0], K[1, 1], K[0, 2], K[1, 2], distortion, width, height)

    def check_plausible(self, width: int | None = None, height: int | None = None) -> None:
        """Raise ValueError when these intrinsics cannot be a real camera's for a ``width`` x
        ``height`` image (default: their own size): focal lengths below 1 px, outside 1/50..100x
        the image's larger side or with fx/fy beyond 4; distortion coefficients beyond 1e3, or a
        radial distortion factor outside 0.1..10 within the image (e.g. k1 = 1e6)."""
        w, h = width or self.width, height or self.height
        if min(self.fx, self.fy) < 1.0:
            raise ValueError(f"CameraIntrinsics: focal lengths fx={self.fx:g}, fy={self.fy:g} px are below 1 px")
        if not 0.25 <= self.fx / self.fy <= 4.0:
            raise ValueError(f"CameraIntrinsics: fx/fy = {self.fx / self.fy:.3g} (fx={self.fx:g}, fy={self.fy:g}); "
                             "pixels are not that far from square")
        if w and h:
            side = float(max(w, h))
            for name in ("fx", "fy"):
                v = getattr(self, name)
                if not side / 50 <= v <= side * 100:
                    raise ValueError(f"CameraIntrinsics.{name} = {v:g} px is implausible for a {w}x{h} image "
                                     f"(expected {side / 50:g}..{side * 100:g})")
        if self.distortion is None:
            return
        d = np.asarray(self.distortion, dtype=np.float64)
        if np.abs(d).max() > 1e3:
            raise ValueError(f"CameraIntrinsics.distortion: coefficients {d.tolist()} beyond 1e3 are absurd")
        if not (w and h):
            return
        k = np.zeros(8)
        k[:min(d.size, 8)] = d[:8]
        r_max = max(max(self.cx, w - self.cx) / self.fx, max(self.cy, h - self.cy) / self.fy)
        r2 = np.linspace(0.0, r_max, 33) ** 2
        num = 1 + k[0] * r2 + k[1] * r2 ** 2 + k[4] * r2 ** 3
        den = 1 + k[5] * r2 + k[6] * r2 ** 2 + k[7] * r2 ** 3
        with np.errstate(all="ignore"):
            f = num / den
        if not np.all(np.isfinite(f)) or f.min() < 0.1 or f.max() > 10:
            raise ValueError(f"CameraIntrinsics.distortion: {d.tolist()} scales radii by {np.nanmin(f):.3g}.."
                             f"{np.nanmax(f):.3g} within the {w}x{h} image (expected 0.1..10): absurd coefficients")

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

        import os
        import stat

        from ..errors import FormatError

        path = Path(path)
        if not path.exists():
            raise FileNotFoundError(f"intrinsics file not found: {path}")
        st = os.stat(path)  # the geometry layer cannot use io.files: the same checks, inline
        if not stat.S_ISREG(st.st_mode):
            raise FormatError(path, "refusing to read a FIFO, device or folder; expected a regular intrinsics file")
        if st.st_size > 1 << 20:
            raise FormatError(path, f"intrinsics file is {st.st_size} bytes; the limit is {1 << 20} bytes")
        try:
            d = json.loads(path.read_bytes()[: (1 << 20) + 1].decode("utf-8"))
        except (UnicodeDecodeError, ValueError, RecursionError) as exc:
            raise FormatError(path, f"not valid JSON ({type(exc).__name__}: {str(exc)[:120]})") from None
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
        for key in ("fx", "fy", "cx", "cy", "K", "distortion", "width", "height"):
            if key in d and not (key == "distortion" and d[key] is None):
                bad = _non_number(d[key], integral=key in ("width", "height"))
                if bad is not None:
                    raise FormatError(path, f"expected {'an integer' if key in ('width', 'height') else 'numbers'}, "
                                            f"found {bad[0]!r:.60} ({type(bad[0]).__name__})", field=key)
        try:
            intr = cls.from_dict(d, source="CameraIntrinsics")
            intr.check_plausible()
            return intr
        except (TypeError, ValueError, OverflowError) as exc:
            head = str(exc).split(":", 1)[0]  # "CameraIntrinsics.distortion: ..." names the field
            field = head.rpartition(".")[2] if head.startswith("CameraIntrinsics.") and " " not in head else None
            raise FormatError(path, str(exc), field) from None

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
    from .camera_names import canonical_name

    try:
        name = canonical_name(model) if isinstance(model, str) else None
    except ValueError as exc:
        raise FormatError(path, str(exc), "model") from None
    if name not in ("pinhole", "pinhole_radtan"):
        raise FormatError(path, f"a {model!r} camera cannot be read as pinhole intrinsics (CameraIntrinsics is "
                                "pinhole + OpenCV distortion); read it with xcalib.formats.cameras.read_camera",
                          "model")
