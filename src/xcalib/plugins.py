"""Extension points discovered through Python entry points (``importlib.metadata``), the packaging
standard: a third-party package adds a frame source, a command, ... by declaring it in its own
``pyproject.toml``, with no edit to xcalib::

    [project.entry-points."xcalib.sources"]
    csvdets = "my_pkg.csv_source"          # a module that calls xcalib.io.sources.register_source

    [project.entry-points."xcalib.commands"]
    hello = "my_pkg.hello_cmd"             # a module with register(app: typer.Typer)

xcalib registers its own extensions the same way (``pyproject.toml``), so the built-ins are no
special case. The built-in entries below (:data:`BUILTIN`) are the base of every group, so a source
tree without (or newer than) its installed metadata still has them. A plugin that fails to load is reported by
name (a :class:`PluginWarning` and :func:`plugin_errors`), never dropped silently.

Layer: bottom (standard library only); each registry (``io.sources``, ``cli``) calls
:func:`entries` for its group.
"""

from __future__ import annotations

import importlib
import warnings
from dataclasses import dataclass
from importlib import metadata
from typing import Any

__all__ = ["GROUPS", "BUILTIN", "PluginEntry", "PluginWarning", "entries", "load", "plugin_errors"]

#: The extension groups xcalib reads.
GROUPS = ("xcalib.sources", "xcalib.commands", "xcalib.camera_models", "xcalib.formats", "xcalib.models",
          "xcalib.cost_terms", "xcalib.executors")

#: xcalib's own entries: the base of every group (so a source checkout on sys.path, or one newer than
#: its installed metadata, has them); an installed xcalib declares the same in pyproject.toml.
BUILTIN: dict[str, dict[str, str]] = {
    "xcalib.sources": {"frames": "xcalib.io.frames", "hdf5": "xcalib.io.hdf5", "bags": "xcalib.io.bags",
                       "formats": "xcalib.formats"},
    "xcalib.commands": {n: f"xcalib.cli.{n.replace('-', '_')}_cmd" for n in (
        "demo", "match", "calibrate", "calibrate-many", "detect", "bootstrap", "train", "validate", "export", "synth", "cache", "convert",
        "bag", "monitor", "version", "reference")},
    "xcalib.formats": {n: f"xcalib.formats.export:{n.upper()}" for n in (
        "kitti", "calib_json", "lucid", "calib_txt", "opencalib", "openlabel", "ros", "urdf", "tf_static", "nuscenes",
        "json", "npz", "waymo", "sustech")},
    "xcalib.models": {"calibrefine": "xcalib.models.calibrefine:CalibRefine", "crlite": "xcalib.models.crlite:CRLite",
                      "crlite_2dpe": "xcalib.models.crlite:CRLite2DPE", "crlite_vit_exp1": "xcalib.models.vit_models:ViTExp1",
                      "crlite_vit_exp3": "xcalib.models.vit_models:ViTExp3",
                      "crlite_vit_exp4": "xcalib.models.vit_models:ViTExp4", "fastmatch": "xcalib.models.fastmatch:FastMatch"},
    "xcalib.cost_terms": {"box_edges": "xcalib.calib.refine:box_edges",
                          **{n: f"xcalib.calib.terms:{n}" for n in ("pose_prior", "focal_scale", "principal_point",
                                                                   "time_offset")}},
}


class PluginWarning(UserWarning):
    """A declared plugin could not be loaded."""


@dataclass(frozen=True)
class PluginEntry:
    """One declared extension: its group, name, ``module[:attr]`` value and the distribution that
    declares it (``"xcalib"`` for the built-ins)."""

    group: str
    name: str
    value: str
    dist: str


_ERRORS: dict[tuple[str, str], str] = {}  # (group, name) -> why it failed (the registry's bookkeeping)


def entries(group: str) -> list[PluginEntry]:
    """Every extension declared for ``group``: xcalib's own first, then other distributions',
    sorted by name within each; a later declaration of a name replaces an earlier one."""
    if group not in GROUPS:
        raise ValueError(f"unknown plugin group {group!r}; groups: {', '.join(GROUPS)}")
    found: dict[str, PluginEntry] = {}
    # the built-ins first (a source checkout may be newer than the metadata of its install), then
    # every distribution's declarations (xcalib's own, then the others') on top
    for name, value in BUILTIN.get(group, {}).items():
        found[name] = PluginEntry(group, name, value, "xcalib")
    eps = metadata.entry_points(group=group)
    for ep in sorted(eps, key=lambda e: (_dist_name(e) != "xcalib", e.name)):
        found[ep.name] = PluginEntry(group, ep.name, ep.value, _dist_name(ep))
    return list(found.values())


def _dist_name(ep) -> str:
    dist = getattr(ep, "dist", None)
    return (dist.metadata["Name"] if dist is not None else "") or "?"


def load(entry: PluginEntry) -> Any | None:
    """Import ``entry`` (``module`` or ``module:attr``); on failure a :class:`PluginWarning`
    naming the plugin, its distribution and the error, and None."""
    try:
        mod, _, attr = entry.value.partition(":")
        obj = importlib.import_module(mod.strip())
        for part in filter(None, attr.strip().split(".")):
            obj = getattr(obj, part)
        _ERRORS.pop((entry.group, entry.name), None)
        return obj
    except Exception as exc:  # noqa: BLE001 - any plugin failure is reported, never fatal to xcalib
        why = f"{type(exc).__name__}: {exc}"
        _ERRORS[(entry.group, entry.name)] = why
        warnings.warn(f"xcalib plugin {entry.name!r} ({entry.group} = {entry.value!r}, from {entry.dist}) "
                      f"failed to load: {why}", PluginWarning, stacklevel=2)
        return None


def plugin_errors() -> dict[str, str]:
    """``"group:name" -> reason`` for every plugin that failed to load in this process."""
    return {f"{g}:{n}": why for (g, n), why in sorted(_ERRORS.items())}
