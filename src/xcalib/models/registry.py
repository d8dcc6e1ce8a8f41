"""Model registry (timm-like): ``create_model``, ``list_models``, ``default_config``.

Every model has a YAML default config in ``xcalib/models/configs/<name>.yaml``; a config
given to :func:`create_model` is deep-merged over it, so partial configs work and the
resulting full config travels with saved weights.
"""

from __future__ import annotations

import copy
from importlib import resources
from typing import Any, Callable, Mapping

import yaml

__all__ = ["register_model", "create_model", "list_models", "default_config", "merge_config",
           "UnknownModelError", "model_class"]

_REGISTRY: dict[str, type] = {}


class UnknownModelError(KeyError):
    """The model name is not registered."""

    def __str__(self) -> str:  # KeyError would quote the whole message
        return str(self.args[0])


def register_model(name: str) -> Callable[[type], type]:
    def deco(cls: type) -> type:
        if name in _REGISTRY:
            raise ValueError(f"model {name!r} is registered twice")
        cls.model_name = name
        _REGISTRY[name] = cls
        return cls
    return deco


def list_models() -> list[str]:
    """Registered model names, sorted."""
    return sorted(_REGISTRY)


def model_class(name: str) -> type:
    if name not in _REGISTRY:
        raise UnknownModelError(f"unknown model {name!r}; available: {', '.join(list_models())}")
    return _REGISTRY[name]


def default_config(name: str) -> dict[str, Any]:
    """The packaged default config of ``name`` (a fresh dict)."""
    model_class(name)
    text = resources.files("xcalib.models").joinpath("configs", f"{name}.yaml").read_text()
    cfg = yaml.safe_load(text) or {}
    cfg["model"] = name
    return cfg


def merge_config(base: Mapping[str, Any], over: Mapping[str, Any] | None) -> dict[str, Any]:
    """Deep merge ``over`` onto ``base`` (dicts merge, everything else replaces)."""
    out = copy.deepcopy(dict(base))
    for k, v in (over or {}).items():
        if isinstance(v, Mapping) and isinstance(out.get(k), Mapping):
            out[k] = merge_config(out[k], v)
        else:
            out[k] = copy.deepcopy(v)
    return out


def create_model(name: str, config: Mapping[str, Any] | None = None, **overrides: Any):
    """Build model ``name`` (random weights) from its default config merged with ``config`` and
    ``overrides``. Raises :class:`UnknownModelError` for an unknown name and ``ValueError``
    when ``config['model']`` names another model."""
    cls = model_class(name)
    if config is not None and config.get("model", name) != name:
        raise ValueError(f"config is for model {config.get('model')!r}, not {name!r}")
    cfg = merge_config(merge_config(default_config(name), config), overrides)
    cfg["model"] = name
    cfg.pop("device", None)
    cfg.pop("weights_path", None)
    return cls(cfg)
