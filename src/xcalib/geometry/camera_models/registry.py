"""Camera models by name.

xcalib's own models are declared as entry points of the group ``xcalib.camera_models`` in
``pyproject.toml``; another package adds a model by declaring one more entry point there
(``mymodel = "mypkg.cams:MyModel"``, a :class:`~.base.CameraModel` subclass). When the package
metadata is absent (a source checkout on ``PYTHONPATH``) the built-in table of
:mod:`xcalib.geometry.camera_names` is used; a third-party entry point never replaces a built-in name.
"""

from __future__ import annotations

import importlib

from .. import camera_names
from ..camera_names import ALIASES, ENTRY_POINT_GROUP, available_models, canonical_name
from .base import CameraModel

__all__ = ["ENTRY_POINT_GROUP", "ALIASES", "available_models", "get_model", "model_from_dict",
           "canonical_name", "as_camera_model", "as_calibration_camera", "calibration_camera_from_dict"]


def _load(target: str) -> type:
    module, _, attr = target.partition(":")
    return getattr(importlib.import_module(module), attr)


def get_model(name: str) -> type[CameraModel]:
    """The :class:`CameraModel` subclass registered as ``name`` (or an alias of it)."""
    key = canonical_name(name)
    if key in camera_names.BUILTIN:
        return _load(camera_names.BUILTIN[key])
    ep = camera_names.entry_points()[key]
    try:
        cls = ep.load()
    except Exception as exc:  # noqa: BLE001 - a broken plug-in names itself
        raise ValueError(f"camera model {key!r}: entry point {ep.value!r} failed to load ({exc})") from None
    if not (isinstance(cls, type) and issubclass(cls, CameraModel)):
        raise ValueError(f"camera model {key!r}: entry point {ep.value!r} is not a CameraModel subclass")
    return cls


def model_from_dict(d: dict, *, source: str = "intrinsics") -> CameraModel:
    """A model from xcalib's intrinsics JSON object ``{"model", "fx", "fy", "cx", "cy", <params>,
    "width", "height"}``; no ``model`` key means ``pinhole_radtan`` (``pinhole`` without
    distortion), today's intrinsics files. Raises ValueError naming the field."""
    if not isinstance(d, dict):
        raise ValueError(f"{source}: expected an object, got {type(d).__name__}")
    name = d.get("model")
    if name is None:
        name = "pinhole_radtan" if d.get("distortion") else "pinhole"
    if not isinstance(name, str):
        raise ValueError(f"{source}.model: expected a model name, got {name!r}")
    cls = get_model(name)
    required = ("fx", "fy", "cx", "cy", *cls.param_names)
    optional = {"distortion"} if cls.name == "pinhole_radtan" or cls.name == "unified" else set()
    missing = [k for k in required if k not in d and k not in optional]
    if missing:
        raise ValueError(f"{source}.{missing[0]}: missing; a {cls.name} camera needs {', '.join(required)}")
    known = {"model", "fx", "fy", "cx", "cy", "width", "height", *cls.param_names}
    extra = sorted(k for k in d if k not in known)
    if cls.name == "pinhole" and d.get("distortion") in ([], None):
        extra = [k for k in extra if k != "distortion"]
    if extra:
        raise ValueError(f"{source}.{extra[0]}: not a parameter of the {cls.name} model "
                         f"(expected {', '.join(sorted(known))})")
    kwargs = {k: d[k] for k in ("fx", "fy", "cx", "cy", *cls.param_names) if k in d}
    for k in ("width", "height"):
        if d.get(k) is not None:
            kwargs[k] = d[k]
    for k, v in list(kwargs.items()):
        if isinstance(v, list):
            kwargs[k] = tuple(v)
    return cls(**kwargs)


def as_camera_model(camera) -> CameraModel:
    """A :class:`CameraModel` for ``camera``: a model is returned as it is; a
    :class:`~xcalib.geometry.camera.CameraIntrinsics` becomes ``pinhole``/``pinhole_radtan``."""
    if isinstance(camera, CameraModel):
        return camera
    from ..camera import CameraIntrinsics
    from .pinhole import PinholeRadtan

    if isinstance(camera, CameraIntrinsics):
        return PinholeRadtan.from_intrinsics(camera)
    raise TypeError(f"expected a CameraModel or CameraIntrinsics, got {type(camera).__name__}")


def as_calibration_camera(camera):
    """What the calibration projects with: a :class:`CameraIntrinsics` for the pinhole models
    (today's path, results unchanged) and the model itself for every other one."""
    from ..camera import CameraIntrinsics

    if isinstance(camera, CameraModel) and camera.name in ("pinhole", "pinhole_radtan"):
        return camera.to_intrinsics()
    if isinstance(camera, (CameraModel, CameraIntrinsics)):
        return camera
    raise TypeError(f"expected a CameraModel or CameraIntrinsics, got {type(camera).__name__}")


def calibration_camera_from_dict(d: dict, *, source: str = "intrinsics"):
    """:func:`as_calibration_camera` of an intrinsics object: ``CameraIntrinsics.from_dict`` when it
    has no ``model`` (or a pinhole one), :func:`model_from_dict` otherwise."""
    from ..camera import CameraIntrinsics

    name = d.get("model") if isinstance(d, dict) else None
    if name is None or canonical_name(name) in ("pinhole", "pinhole_radtan"):
        return CameraIntrinsics.from_dict(d, source=source)
    return model_from_dict(d, source=source)
