"""Camera intrinsics files with their camera model kept.

=================  ===========================================================================
format             models it can express
=================  ===========================================================================
``intrinsics_json`` every model (``{"model": ..., "fx", "fy", "cx", "cy", <params>, "width", "height"}``)
``camera_info``    ROS CameraInfo YAML: ``plumb_bob`` (pinhole, 4-5 coefficients),
                   ``rational_polynomial`` (8), ``equidistant`` (Kannala-Brandt)
``kalibr``         Kalibr camchain YAML: ``pinhole-none``, ``pinhole-radtan``, ``pinhole-equi``,
                   ``omni-none``, ``omni-radtan`` (unified), ``ds-none``, ``eucm-none`` (EUCM, and
                   UCM as ``beta = 1``)
``opencv_yaml``    ``cv::FileStorage`` YAML / JSON (``camera_matrix``, ``distortion_coefficients``,
``opencv_json``    ``image_width``, ``image_height``; ``fisheye_model: 1`` for ``cv::fisheye``):
                   pinhole with 4-14 coefficients, Kannala-Brandt
=================  ===========================================================================

A model a format cannot express is refused (:class:`UnsupportedModelError` names the model,
the format and the formats that can) — never written as a different model. Readers validate
every field (:class:`~xcalib.errors.FormatError` naming file, field and problem); writers are
atomic.
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import FormatError
from ..geometry.camera_models import (EUCM, UCM, CameraModel, DoubleSphere, KannalaBrandt, Pinhole,
                                      PinholeRadtan, Unified, as_camera_model, model_from_dict)
from ..io.files import MAX_TEXT_BYTES, atomic_write, read_text
from ._checks import plausible_camera

__all__ = ["CAMERA_FORMATS", "UnsupportedModelError", "read_camera", "read_intrinsics", "write_camera", "camera_text",
           "detect_camera_format", "formats_for", "read_kalibr_camchain", "split_camera_ref"]

CAMERA_FORMATS = ("intrinsics_json", "camera_info", "kalibr", "opencv_yaml", "opencv_json")
_SUFFIX = {"intrinsics_json": ".json", "camera_info": ".yaml", "kalibr": ".yaml", "opencv_yaml": ".yaml",
           "opencv_json": ".json"}


class UnsupportedModelError(ValueError):
    """A file format cannot express a camera model (nothing was written)."""


# ----------------------------------------------------------------------------- helpers
def _trimmed(dist: tuple[float, ...]) -> tuple[float, ...]:
    d = list(dist)
    while d and d[-1] == 0.0:
        d.pop()
    return tuple(d)


def _radtan_fit(cam: PinholeRadtan | Pinhole, sizes: tuple[int, ...]) -> tuple[float, ...] | None:
    """The coefficients padded to the shortest of ``sizes`` that holds every non-zero one."""
    d = _trimmed(getattr(cam, "distortion", ()))
    for n in sizes:
        if len(d) <= n:
            return d + (0.0,) * (n - len(d))
    return None


def _field_of(exc: Exception) -> str | None:
    m = re.match(r"^[\w<>]+\.(\w+):", str(exc))
    return m.group(1) if m else None


def _unsupported(cam: CameraModel, fmt: str, detail: str = "") -> UnsupportedModelError:
    extra = f" ({detail})" if detail else ""
    return UnsupportedModelError(f"the {fmt} format cannot express a {cam.name} camera{extra}")


def _finite_list(values, path, field: str, sizes: tuple[int, ...] | None = None) -> list[float]:
    if values is None:
        values = []
    if not isinstance(values, (list, tuple)):
        raise FormatError(path, f"expected a list of numbers, got {type(values).__name__}", field)
    out = []
    for i, v in enumerate(values):
        if isinstance(v, bool):
            raise FormatError(path, f"expected a number at index {i}, got {v!r}", field)
        try:
            f = float(v)
        except (TypeError, ValueError):
            raise FormatError(path, f"expected a number at index {i}, got {v!r:.40}", field) from None
        if not math.isfinite(f):
            raise FormatError(path, f"expected finite numbers, got {f} at index {i}", field)
        out.append(f)
    if sizes is not None and len(out) not in sizes:
        raise FormatError(path, f"expected {' or '.join(map(str, sizes))} values, got {len(out)}", field)
    return out


def _size(value, path, field: str) -> int | None:
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not float(value).is_integer() or value <= 0:
        raise FormatError(path, f"expected a positive pixel count, got {value!r:.40}", field)
    return int(value)


def _K_params(K: np.ndarray, path, field: str) -> tuple[float, float, float, float]:
    if not np.all(np.isfinite(K)):
        raise FormatError(path, "expected finite numbers", field)
    if abs(K[0, 1]) > 1e-12 or np.abs(K[2] - [0, 0, 1]).max() > 1e-12 or abs(K[1, 0]) > 1e-12:
        raise FormatError(path, f"expected [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] (no skew), got {K.tolist()}",
                          field)
    return float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2])


def _build(path, field: str, factory, *args, **kwargs) -> CameraModel:
    try:
        return factory(*args, **kwargs)
    except (TypeError, ValueError) as exc:
        raise FormatError(path, str(exc), field) from None


def formats_for(camera) -> list[str]:
    """The formats of :data:`CAMERA_FORMATS` that can express ``camera``."""
    cam = as_camera_model(camera)
    out = []
    for fmt in CAMERA_FORMATS:
        try:
            _ENCODERS[fmt](cam, "camera", check_only=True)
        except UnsupportedModelError:
            continue
        out.append(fmt)
    return out


# ------------------------------------------------------------------------ xcalib JSON
def _enc_xcalib(cam: CameraModel, name: str, check_only: bool = False) -> str:
    return "" if check_only else json.dumps(cam.to_dict(), indent=2) + "\n"


def _dec_xcalib(text: str, path, camera: str | None) -> CameraModel:
    try:
        d = json.loads(text)
    except json.JSONDecodeError as exc:
        raise FormatError(path, f"not valid JSON ({exc})") from None
    if not isinstance(d, dict):
        raise FormatError(path, f"expected a JSON object, got {type(d).__name__}")
    for key in ("fx", "fy", "cx", "cy"):
        if key not in d:
            raise FormatError(path, f"missing; expected fx, fy, cx, cy (pixels), found {sorted(d)}", key)
    for key in ("width", "height"):
        _size(d.get(key), path, key)
    try:
        return model_from_dict(d, source="intrinsics")
    except (TypeError, ValueError) as exc:
        field = _field_of(exc) or ("model" if "camera model" in str(exc) else None)
        raise FormatError(path, str(exc), field) from None


# ----------------------------------------------------------------- ROS CameraInfo YAML
def _mat(rows: int, cols: int, data) -> dict:
    return {"rows": rows, "cols": cols, "data": [float(v) for v in np.asarray(data, dtype=np.float64).reshape(-1)]}


def _enc_camera_info(cam: CameraModel, name: str, check_only: bool = False) -> str:
    if type(cam) in (Pinhole, PinholeRadtan):
        d = _radtan_fit(cam, (5, 8))
        if d is None:
            raise _unsupported(cam, "camera_info", "ROS has no thin-prism or tilt coefficients")
        model = "plumb_bob" if len(d) == 5 else "rational_polynomial"
    elif type(cam) is KannalaBrandt:
        d, model = cam.k, "equidistant"
    else:
        raise _unsupported(cam, "camera_info")
    if check_only:
        return ""
    import yaml

    K = cam.K
    out: dict[str, Any] = {}
    if cam.width is not None and cam.height is not None:
        out.update(image_width=cam.width, image_height=cam.height)
    out.update(camera_name=name, camera_matrix=_mat(3, 3, K), distortion_model=model,
               distortion_coefficients=_mat(1, len(d), d), rectification_matrix=_mat(3, 3, np.eye(3)),
               projection_matrix=_mat(3, 4, np.hstack([K, np.zeros((3, 1))])))
    return yaml.safe_dump(out, sort_keys=False)


def _yaml_mapping(text: str, path) -> dict:
    import yaml

    try:
        d = yaml.safe_load(text)
    except (yaml.YAMLError, RecursionError, ValueError, TypeError) as exc:
        raise FormatError(path, f"not valid YAML ({type(exc).__name__}: {str(exc)[:200]})") from None
    if not isinstance(d, dict):
        raise FormatError(path, "not a camera file: expected a JSON object or a YAML mapping of keys, got "
                                f"{type(d).__name__} {str(d)[:40]!r}")
    return d


def _ros_matrix(d: dict, key: str, shape, path) -> np.ndarray:
    node = d.get(key)
    if not isinstance(node, dict) or "data" not in node:
        raise FormatError(path, f"missing or not a {{rows, cols, data}} mapping (got {type(node).__name__})", key)
    data = _finite_list(node["data"], path, f"{key}.data")
    if len(data) != int(np.prod(shape)):
        raise FormatError(path, f"expected {int(np.prod(shape))} numbers ({shape[0]}x{shape[1]}), got {len(data)}",
                          f"{key}.data")
    return np.asarray(data).reshape(shape)


_ROS_SIZES = {"plumb_bob": (0, 4, 5), "rational_polynomial": (8,), "equidistant": (4,)}


def _dec_camera_info(text: str, path, camera: str | None) -> CameraModel:
    d = _yaml_mapping(text, path)
    fx, fy, cx, cy = _K_params(_ros_matrix(d, "camera_matrix", (3, 3), path), path, "camera_matrix.data")
    model = d.get("distortion_model", "plumb_bob")
    if model not in _ROS_SIZES:
        raise FormatError(path, f"unknown distortion_model {model!r}; expected one of {', '.join(_ROS_SIZES)}",
                          "distortion_model")
    coeffs: list[float] = []
    if "distortion_coefficients" in d:
        node = d["distortion_coefficients"]
        if not isinstance(node, dict):
            raise FormatError(path, "expected a {rows, cols, data} mapping", "distortion_coefficients")
        coeffs = _finite_list(node.get("data"), path, "distortion_coefficients.data", _ROS_SIZES[model])
    elif model != "plumb_bob":
        raise FormatError(path, f"missing; a {model} camera needs its coefficients", "distortion_coefficients")
    if "rectification_matrix" in d:
        R = _ros_matrix(d, "rectification_matrix", (3, 3), path)
        if np.abs(R - np.eye(3)).max() > 1e-9:
            raise FormatError(path, "not identity (a stereo-rectified camera_info is not a plain camera)",
                              "rectification_matrix")
    w = _size(d.get("image_width"), path, "image_width")
    h = _size(d.get("image_height"), path, "image_height")
    if model == "equidistant":
        return _build(path, "distortion_coefficients", KannalaBrandt, fx, fy, cx, cy, w, h, tuple(coeffs))
    if not any(coeffs):
        return _build(path, "camera_matrix", Pinhole, fx, fy, cx, cy, w, h)
    return _build(path, "distortion_coefficients", PinholeRadtan, fx, fy, cx, cy, w, h, tuple(coeffs))


# -------------------------------------------------------------------- Kalibr camchain
def _kalibr_entry(cam: CameraModel) -> tuple[str, list[float], str, list[float]]:
    f = [cam.fx, cam.fy, cam.cx, cam.cy]
    t = type(cam)
    if t in (Pinhole, PinholeRadtan):
        d = _radtan_fit(cam, (0, 4))
        if d is None:
            raise _unsupported(cam, "kalibr", "Kalibr's radtan has 4 coefficients (k1 k2 p1 p2)")
        return "pinhole", f, ("radtan" if d else "none"), list(d)
    if t is KannalaBrandt:
        return "pinhole", f, "equidistant", list(cam.k)
    if t is Unified:
        d = _trimmed(cam.distortion)
        return "omni", [cam.xi, *f], ("radtan" if d else "none"), (list(cam.distortion) if d else [])
    if t is DoubleSphere:
        return "ds", [cam.xi, cam.alpha, *f], "none", []
    if t in (EUCM, UCM):
        return "eucm", [cam.alpha, cam.beta, *f], "none", []
    raise _unsupported(cam, "kalibr")


def _enc_kalibr(cam: CameraModel, name: str, check_only: bool = False) -> str:
    model, intr, dmodel, dist = _kalibr_entry(cam)
    if check_only:
        return ""
    import yaml

    entry: dict[str, Any] = {"camera_model": model, "intrinsics": [float(v) for v in intr],
                             "distortion_model": dmodel, "distortion_coeffs": [float(v) for v in dist]}
    if cam.width is not None and cam.height is not None:
        entry["resolution"] = [cam.width, cam.height]
    entry["rostopic"] = f"/{name}/image_raw"
    return yaml.safe_dump({"cam0": entry}, sort_keys=False)


_KALIBR = {  # camera_model -> (intrinsics names, distortion models allowed)
    "pinhole": (("fu", "fv", "pu", "pv"), ("radtan", "equidistant", "none")),
    "omni": (("xi", "fu", "fv", "pu", "pv"), ("radtan", "none")),
    "ds": (("xi", "alpha", "fu", "fv", "pu", "pv"), ("none",)),
    "eucm": (("alpha", "beta", "fu", "fv", "pu", "pv"), ("none",)),
}
_KALIBR_DIST = {"radtan": (4,), "equidistant": (4,), "none": (0,)}


def _kalibr_camera(entry: Any, path, key: str) -> CameraModel:
    p = f"{key}."
    if not isinstance(entry, dict):
        raise FormatError(path, f"expected a mapping, got {type(entry).__name__}", key)
    model = entry.get("camera_model")
    if model not in _KALIBR:
        raise FormatError(path, f"unsupported camera_model {model!r}; expected one of {', '.join(_KALIBR)}",
                          p + "camera_model")
    names, dists = _KALIBR[model]
    intr = _finite_list(entry.get("intrinsics"), path, p + "intrinsics", (len(names),))
    dmodel = entry.get("distortion_model", "none")
    if dmodel not in dists:
        raise FormatError(path, f"{model}-{dmodel!s} is not supported; with camera_model {model} expected "
                                f"distortion_model {' or '.join(dists)}", p + "distortion_model")
    dist = _finite_list(entry.get("distortion_coeffs", []), path, p + "distortion_coeffs", _KALIBR_DIST[dmodel])
    w = h = None
    if "resolution" in entry:
        res = entry["resolution"]
        if not isinstance(res, (list, tuple)) or len(res) != 2:
            raise FormatError(path, f"expected [width, height], got {res!r:.40}", p + "resolution")
        w, h = _size(res[0], path, p + "resolution"), _size(res[1], path, p + "resolution")
    v = dict(zip(names, intr))
    f = (v["fu"], v["fv"], v["pu"], v["pv"], w, h)
    fld = p + "intrinsics"
    if model == "pinhole":
        if dmodel == "equidistant":
            return _build(path, p + "distortion_coeffs", KannalaBrandt, *f, tuple(dist))
        if dmodel == "radtan" and any(dist):
            return _build(path, p + "distortion_coeffs", PinholeRadtan, *f, tuple(dist))
        return _build(path, fld, Pinhole, *f)
    if model == "omni":
        return _build(path, fld, Unified, *f, v["xi"], tuple(dist) if any(dist) else ())
    if model == "ds":
        return _build(path, fld, DoubleSphere, *f, v["xi"], v["alpha"])
    return _build(path, fld, EUCM, *f, v["alpha"], v["beta"])


def read_kalibr_camchain(path) -> dict[str, CameraModel]:
    """Every ``camN`` of a Kalibr camchain (or camera) YAML, by its key."""
    path = Path(path)
    d = _yaml_mapping(read_text(path, max_bytes=MAX_TEXT_BYTES, what="Kalibr YAML"), path)
    return _kalibr_all(d, path)


def _kalibr_all(d: dict, path) -> dict[str, CameraModel]:
    keys = sorted((k for k in d if isinstance(k, str) and re.fullmatch(r"cam\d+", k)), key=lambda k: int(k[3:]))
    if not keys:
        raise FormatError(path, f"no camN entries (a Kalibr camchain has cam0, cam1, ...); found {sorted(map(str, d))}")
    return {k: _kalibr_camera(d[k], path, k) for k in keys}


def _dec_kalibr(text: str, path, camera: str | None) -> CameraModel:
    cams = _kalibr_all(_yaml_mapping(text, path), path)
    if camera is None:
        if len(cams) > 1:
            first = next(iter(cams))
            raise FormatError(path, f"{len(cams)} cameras ({', '.join(cams)}); name one: {Path(path).name}#{first} "
                                    f"(--intrinsics {Path(path).name}#{first}; convert: --camera {first}; "
                                    f"read_camera(path, camera={first!r}))")
        camera = next(iter(cams))
    if camera not in cams:
        raise FormatError(path, f"no camera {camera!r}; found {', '.join(cams)}", camera)
    return cams[camera]


# ------------------------------------------------------------ OpenCV FileStorage
def _opencv_dist(cam: CameraModel) -> tuple[tuple[float, ...], bool]:
    t = type(cam)
    if t is KannalaBrandt:
        return cam.k, True
    if t is Pinhole:
        return (0.0,) * 5, False
    if t is PinholeRadtan:
        return _radtan_fit(cam, (5, 8, 12, 14)), False
    raise _unsupported(cam, "OpenCV", "cv::FileStorage calibration files hold pinhole and cv::fisheye cameras")


def _enc_opencv(cam: CameraModel, json_format: bool, check_only: bool) -> str:
    dist, fisheye = _opencv_dist(cam)
    if check_only:
        return ""
    import cv2

    flags = cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_MEMORY
    flags |= cv2.FILE_STORAGE_FORMAT_JSON if json_format else cv2.FILE_STORAGE_FORMAT_YAML
    fs = cv2.FileStorage("camera" + (".json" if json_format else ".yaml"), flags)
    if cam.width is not None and cam.height is not None:
        fs.write("image_width", int(cam.width))
        fs.write("image_height", int(cam.height))
    fs.write("camera_matrix", cam.K)
    fs.write("distortion_coefficients", np.asarray(dist, dtype=np.float64).reshape(-1, 1))
    fs.write("fisheye_model", int(fisheye))
    return fs.releaseAndGetString()


def _dec_opencv(text: str, path, camera: str | None) -> CameraModel:
    import cv2

    try:
        fs = cv2.FileStorage(text, cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY)
    except cv2.error as exc:
        raise FormatError(path, f"not a cv::FileStorage YAML/JSON file ({str(exc).strip()[-160:]})") from None
    try:
        if not fs.isOpened():
            raise FormatError(path, "not a cv::FileStorage YAML/JSON file")

        def mat(key):
            node = fs.getNode(key)
            if node.empty() or node.isNone():
                return None
            if not node.isMap():
                raise FormatError(path, "expected an opencv-matrix", key)
            for dim in ("rows", "cols"):  # checked before OpenCV allocates rows x cols (NaN: "insufficient memory")
                d = node.getNode(dim)
                if d.empty() or not d.isInt() or not 1 <= int(d.real()) <= 16:
                    raise FormatError(path, f"{dim} must be an integer 1..16 (a camera matrix or distortion "
                                            f"vector), got {d.real() if d.isReal() or d.isInt() else d.string()!r}",
                                      f"{key}.{dim}")
            try:
                m = node.mat()
            except cv2.error as exc:
                raise FormatError(path, f"not a valid opencv-matrix ({str(exc).strip()[-120:]})", key) from None
            if m is None:
                raise FormatError(path, "expected an opencv-matrix", key)
            return np.asarray(m, dtype=np.float64)

        def integer(key):
            node = fs.getNode(key)
            if node.empty() or node.isNone():
                return None
            if not node.isInt():
                raise FormatError(path, "expected an integer", key)
            return int(node.real())

        K = mat("camera_matrix")
        if K is None:
            raise FormatError(path, "missing; expected a 3x3 opencv-matrix", "camera_matrix")
        if K.shape != (3, 3):
            raise FormatError(path, f"expected 3x3, got {'x'.join(map(str, K.shape))}", "camera_matrix")
        fx, fy, cx, cy = _K_params(K, path, "camera_matrix")
        D = mat("distortion_coefficients")
        D = np.zeros(0) if D is None else D
        if D.ndim != 2 or 1 not in D.shape:
            raise FormatError(path, f"expected a row or column vector, got {'x'.join(map(str, D.shape))}",
                              "distortion_coefficients")
        dist = _finite_list(D.reshape(-1).tolist(), path, "distortion_coefficients")
        fisheye = integer("fisheye_model") or 0
        w = _size(integer("image_width"), path, "image_width")
        h = _size(integer("image_height"), path, "image_height")
    finally:
        fs.release()
    if fisheye:
        if len(dist) != 4:
            raise FormatError(path, f"a cv::fisheye camera (fisheye_model: 1) has 4 coefficients, got {len(dist)}",
                              "distortion_coefficients")
        return _build(path, "distortion_coefficients", KannalaBrandt, fx, fy, cx, cy, w, h, tuple(dist))
    if not any(dist):
        return _build(path, "camera_matrix", Pinhole, fx, fy, cx, cy, w, h)
    return _build(path, "distortion_coefficients", PinholeRadtan, fx, fy, cx, cy, w, h, tuple(dist))


_ENCODERS = {
    "intrinsics_json": _enc_xcalib,
    "camera_info": _enc_camera_info,
    "kalibr": _enc_kalibr,
    "opencv_yaml": lambda cam, name, check_only=False: _enc_opencv(cam, False, check_only),
    "opencv_json": lambda cam, name, check_only=False: _enc_opencv(cam, True, check_only),
}
_DECODERS = {"intrinsics_json": _dec_xcalib, "camera_info": _dec_camera_info, "kalibr": _dec_kalibr,
             "opencv_yaml": _dec_opencv, "opencv_json": _dec_opencv}


# --------------------------------------------------------------------------- public
def detect_camera_format(path, text: str | None = None) -> str:
    """The camera format of ``path`` from its content (FormatError when none fits)."""
    path = Path(path)
    if text is None:
        text = read_text(path, max_bytes=MAX_TEXT_BYTES, what="camera file")
    head = text.lstrip()[:64]
    if head.startswith("%YAML:1.0") or "!!opencv-matrix" in text:
        return "opencv_yaml"
    if head.startswith("{"):
        try:
            d = json.loads(text)
        except json.JSONDecodeError as exc:
            raise FormatError(path, f"not valid JSON ({exc})") from None
        if isinstance(d, dict) and isinstance(d.get("camera_matrix"), dict) and "type_id" in d["camera_matrix"]:
            return "opencv_json"
        return "intrinsics_json"
    d = _yaml_mapping(text, path)
    if any(isinstance(k, str) and re.fullmatch(r"cam\d+", k) for k in d):
        return "kalibr"
    if "camera_matrix" in d:
        return "camera_info"
    raise FormatError(path, "not a camera file xcalib knows (xcalib intrinsics JSON, ROS camera_info, Kalibr "
                            f"camchain, OpenCV YAML/JSON); found keys {sorted(map(str, d))[:12]}")


def split_camera_ref(ref, camera: str | None = None) -> tuple[Path, str | None]:
    """``FILE#cam1`` -> (``FILE``, ``"cam1"``): a camera file with the camera of a Kalibr camchain
    picked after ``#`` (what ``--intrinsics`` of every command accepts). A path that exists as
    given is taken whole (a ``#`` in a file name is kept); ``camera`` (the keyword of
    :func:`read_camera`) may name the same camera again, not another one (ValueError)."""
    path = Path(ref)
    text = str(ref)
    if path.is_file() or "#" not in text:
        return path, camera
    base, frag = text.rsplit("#", 1)
    if not frag or not base:
        raise ValueError(f"{text!r}: expected FILE#CAMERA (e.g. camchain.yaml#cam1), got an empty "
                         f"{'camera' if not frag else 'file'} name")
    if camera is not None and camera != frag:
        raise ValueError(f"{text!r} names camera {frag!r} but camera={camera!r} was given too; name one")
    return Path(base), frag


def read_camera(path, fmt: str | None = None, *, camera: str | None = None) -> CameraModel:
    """A :class:`CameraModel` from a camera file (``fmt`` one of :data:`CAMERA_FORMATS`, default:
    detected); ``camera`` picks one camera of a Kalibr camchain (``cam1``), as does a path
    ``camchain.yaml#cam1`` (:func:`split_camera_ref`). Only a camchain has cameras to pick: a
    camera named for another format is a FormatError."""
    path, camera = split_camera_ref(path, camera)
    if not path.is_file():
        raise FileNotFoundError(f"camera file not found: {path}")
    text = read_text(path, max_bytes=MAX_TEXT_BYTES, what="camera file")
    fmt = fmt or detect_camera_format(path, text)
    if fmt not in _DECODERS:
        raise ValueError(f"unknown camera format {fmt!r}; expected one of {', '.join(CAMERA_FORMATS)}")
    if camera is not None and fmt != "kalibr":
        raise FormatError(path, f"camera {camera!r} named, but this {fmt} file holds one camera (only a Kalibr "
                                "camchain has cameras to pick: FILE#cam1); give the file alone")
    cam = _DECODERS[fmt](text, path, camera)
    if cam.is_pinhole:  # a real camera's numbers (focal lengths, principal point, distortion), named
        try:
            intr = cam.to_intrinsics()
        except ValueError as exc:
            if isinstance(exc, FormatError):
                raise
            raise FormatError(path, str(exc)) from None
        plausible_camera(intr, path, "camera")
    return cam


def read_intrinsics(path, *, camera: str | None = None):
    """The camera of a command's ``--intrinsics FILE``: xcalib's intrinsics JSON (with or without a
    ``model``: ``xcalib.io.read_intrinsics_json``), or any camera file :func:`read_camera` reads (ROS
    CameraInfo YAML, Kalibr camchain -- ``camera``, or ``path`` given as ``camchain.yaml#cam1``,
    picks one of several --, OpenCV YAML / JSON).
    Pinhole models come back as ``CameraIntrinsics``, wide-angle ones as their ``CameraModel``."""
    from ..io.frames import read_intrinsics_json

    path, camera = split_camera_ref(path, camera)
    if not path.is_file():
        raise FileNotFoundError(f"intrinsics file not found: {path}")
    fmt = detect_camera_format(path)
    if fmt == "intrinsics_json" and camera is None:
        return read_intrinsics_json(path)
    cam = read_camera(path, fmt, camera=camera)
    return cam.to_intrinsics() if cam.is_pinhole else cam


def camera_text(camera, fmt: str, *, camera_name: str = "camera") -> str:
    """The file content of ``camera`` in ``fmt`` (UnsupportedModelError when it cannot express it)."""
    if fmt not in _ENCODERS:
        raise ValueError(f"unknown camera format {fmt!r}; expected one of {', '.join(CAMERA_FORMATS)}")
    cam = as_camera_model(camera)
    try:
        return _ENCODERS[fmt](cam, camera_name)
    except UnsupportedModelError as exc:
        raise UnsupportedModelError(f"{exc}; formats that can: {', '.join(formats_for(cam))}") from None


def write_camera(camera, path, fmt: str | None = None, *, camera_name: str = "camera",
                 overwrite: bool = True) -> Path:
    """Write ``camera`` (a :class:`CameraModel` or :class:`CameraIntrinsics`) atomically;
    ``fmt`` defaults to ``intrinsics_json`` for ``.json`` and ``camera_info`` for ``.yaml``."""
    path = Path(path)
    if fmt is None:
        fmt = "intrinsics_json" if path.suffix.lower() == ".json" else "camera_info"
    text = camera_text(camera, fmt, camera_name=camera_name)
    return atomic_write(path, [text.encode("utf-8")], overwrite=overwrite)
