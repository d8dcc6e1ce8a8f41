"""Camera-model names: the built-in table, the aliases the formats use, the entry points of
``xcalib.camera_models`` and :func:`canonical_name`.

This sits below both :mod:`.camera` (whose pinhole-only readers check a ``model`` name) and
:mod:`.camera_models` (whose pinhole models build a ``CameraIntrinsics``), so neither imports the
other in a circle; it imports nothing of xcalib.
"""

from __future__ import annotations

from typing import Any

__all__ = ["ENTRY_POINT_GROUP", "BUILTIN", "ALIASES", "entry_points", "available_models", "canonical_name"]

ENTRY_POINT_GROUP = "xcalib.camera_models"

#: xcalib's own models, ``name -> "module:Class"`` (used when the package metadata is absent)
BUILTIN = {
    "pinhole": "xcalib.geometry.camera_models.pinhole:Pinhole",
    "pinhole_radtan": "xcalib.geometry.camera_models.pinhole:PinholeRadtan",
    "kannala_brandt": "xcalib.geometry.camera_models.kannala_brandt:KannalaBrandt",
    "unified": "xcalib.geometry.camera_models.unified:Unified",
    "ucm": "xcalib.geometry.camera_models.unified:UCM",
    "eucm": "xcalib.geometry.camera_models.unified:EUCM",
    "double_sphere": "xcalib.geometry.camera_models.double_sphere:DoubleSphere",
}

#: other names the formats use for the same models
ALIASES = {
    "radtan": "pinhole_radtan", "plumb_bob": "pinhole_radtan", "rational_polynomial": "pinhole_radtan",
    "opencv": "pinhole_radtan", "equidistant": "kannala_brandt", "fisheye": "kannala_brandt",
    "kb": "kannala_brandt", "kb4": "kannala_brandt", "mei": "unified", "omni": "unified",
    "ds": "double_sphere",
}


def entry_points() -> dict[str, Any]:
    """The entry points of ``xcalib.camera_models`` by name ({} when the metadata is absent)."""
    try:
        from importlib.metadata import entry_points as _eps

        eps = _eps(group=ENTRY_POINT_GROUP)
    except Exception:  # noqa: BLE001 - metadata absent or unreadable: the built-ins still work
        return {}
    return {ep.name: ep for ep in eps}


def available_models() -> list[str]:
    """Every model name known: the built-ins and the entry points of ``xcalib.camera_models``."""
    return sorted(set(BUILTIN) | set(entry_points()))


def canonical_name(name: str) -> str:
    """The registry name of ``name`` (aliases such as ``equidistant`` resolved); ValueError if unknown."""
    key = str(name).strip().lower().replace("-", "_")
    key = ALIASES.get(key, key)
    if key in BUILTIN or key in entry_points():
        return key
    raise ValueError(f"unknown camera model {name!r}; expected one of {', '.join(available_models())} "
                     f"(or an alias: {', '.join(sorted(ALIASES))})")
