"""The ``xcalib.cost_terms`` registry: term factories by name (:mod:`xcalib.plugins` entry points),
and the check of the terms a ``CalibConfig`` names. Standard library only (``CalibConfig`` checks
its terms with it; :mod:`xcalib.calib.terms` builds them)."""

from __future__ import annotations

import inspect
import warnings
from typing import Any, Callable

from ..plugins import PluginWarning
from ..plugins import entries as plugin_entries
from ..plugins import load as load_plugin

__all__ = ["GROUP", "STAGE_TERMS", "cost_terms", "term_factory", "check_terms"]

GROUP = "xcalib.cost_terms"
#: terms the stages add themselves (from refine_intrinsics / time_offset) or always (box_edges)
STAGE_TERMS = {"box_edges": "it is always the first term (set occlusion_tau / occlusion_slope)",
               "focal_scale": "set refine_intrinsics='focal' (or 'auto')",
               "principal_point": "set refine_intrinsics='focal+center'",
               "time_offset": "set time_offset='estimate' (or 'auto', or seconds)"}

_FACTORIES: dict[str, Callable[..., Any]] = {}  # loaded entries (the registry's own bookkeeping)


def cost_terms() -> dict[str, Callable[..., Any]]:
    """Every registered term factory by name (xcalib's own and every installed plugin's); a plugin
    that fails to load is reported (``xcalib.plugins.PluginWarning``) and left out."""
    out = {}
    for entry in plugin_entries(GROUP):
        key = f"{entry.name}={entry.value}"
        if key not in _FACTORIES:
            obj = load_plugin(entry)
            if obj is None:
                continue
            if not callable(obj):
                warnings.warn(f"xcalib plugin {entry.name!r} ({GROUP} = {entry.value!r}, from {entry.dist}) is not "
                              f"a callable factory(ctx, **options) -> CostTerm", PluginWarning, stacklevel=2)
                continue
            _FACTORIES[key] = obj
        out[entry.name] = _FACTORIES[key]
    return out


def term_factory(name: str) -> Callable[..., Any]:
    """The factory registered as ``name``; ValueError naming the registered ones otherwise."""
    found = cost_terms()
    if name not in found:
        raise ValueError(f"CalibConfig.cost_terms: no cost term named {name!r}; registered ({GROUP}): "
                         f"{', '.join(sorted(found))}")
    return found[name]


def check_terms(specs: tuple) -> None:
    """``specs`` (``config.TermSpec``s): ValueError for a name that is not registered, a term the
    stages add themselves, a term named twice or an option its factory does not take (named)."""
    seen = set()
    for spec in specs:
        if spec.name in STAGE_TERMS:
            raise ValueError(f"CalibConfig.cost_terms: {spec.name!r} is added by the calibration itself: "
                             f"{STAGE_TERMS[spec.name]}")
        if spec.name in seen:
            raise ValueError(f"CalibConfig.cost_terms: {spec.name!r} is named twice")
        seen.add(spec.name)
        factory = term_factory(spec.name)
        try:
            inspect.signature(factory).bind(None, **spec.kwargs)
        except TypeError as exc:
            raise ValueError(f"CalibConfig.cost_terms: term {spec.name!r}: options {spec.kwargs} do not fit "
                             f"{getattr(factory, '__name__', factory)}{inspect.signature(factory)}: {exc}") from None
        except ValueError:  # a builtin without a signature: checked when built
            pass
