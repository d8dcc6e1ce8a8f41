"""Model registry (timm-like): ``create_model``, ``list_models``, ``default_config``, typed configs.

A model is registered with ``@register_model(name)`` (xcalib's own) or through the entry-point
group ``xcalib.models`` (:mod:`xcalib.plugins`: a third-party package declares
``name = "my_pkg.model:MyModel"``, a :class:`~xcalib.models.base.MatchingModel` subclass).

Every model has a typed config: a frozen dataclass (:func:`config_class`) with every key and its
default in one place -- for xcalib's models derived from the packaged YAML
(``xcalib/models/configs/<name>.yaml``), for a plugin its class attribute ``config_class`` (a
frozen dataclass, usually a subclass of :class:`ModelConfig`). A config given to
:func:`create_model` is deep-merged over the defaults and checked against it: an unknown key
(``embed_dimm``) or a value of the wrong kind is a ValueError naming it, never ignored. The model
still receives the merged mapping (``model.config``, which travels with saved weights) and the
typed record as ``model.typed_config``.
"""

from __future__ import annotations

import copy
import dataclasses
import difflib
from dataclasses import dataclass, fields
from importlib import resources
from typing import Any, Callable, Mapping

import yaml

from ..data.crops import CropFields

__all__ = ["register_model", "create_model", "list_models", "default_config", "merge_config",
           "UnknownModelError", "model_class", "config_class", "typed_config", "ModelConfig", "MATCHER_KEYS"]

_REGISTRY: dict[str, type] = {}
_CONFIGS: dict[str, type] = {}  # typed config class per model name (derived once)


@dataclass(frozen=True)
class ModelConfig(CropFields):
    """What every matching model's config holds: the crop settings of ``data.crops.CropFields``
    (``crop_size`` px, ``point_cloud_size`` points, ``bbox_expansion``, ``keep_aspect``,
    ``normalize``, ``min_points``, ``seed``; unchecked here, ``CropConfig`` checks them) and the
    training ``temperature``. A model's own typed config subclasses it and adds its keys."""

    temperature: float = 0.07


#: keys any model config may carry beside its own: the model's name and the matcher / site
#: settings written beside saved weights (``Matcher.update_config``, ``xcalib bootstrap``)
MATCHER_KEYS = ("model", "device", "weights_path", "match_threshold", "site_default")


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


def _load_plugins() -> None:
    """Register the models of the ``xcalib.models`` entry points not registered yet (a plugin that
    fails to load, or is no model class, is reported by name: ``xcalib.plugins.PluginWarning``)."""
    import warnings

    from ..plugins import PluginWarning, entries, load

    for entry in entries("xcalib.models"):
        if entry.name in _REGISTRY:
            continue
        cls = load(entry)
        if cls is None:
            continue
        if not isinstance(cls, type):
            warnings.warn(f"xcalib plugin {entry.name!r} (xcalib.models = {entry.value!r}, from {entry.dist}) is not a "
                          f"model class but {type(cls).__name__}", PluginWarning, stacklevel=3)
            continue
        if entry.name not in _REGISTRY:  # the module may have registered it itself
            register_model(entry.name)(cls)


def list_models() -> list[str]:
    """Registered model names (xcalib's own and the installed plugins'), sorted."""
    _load_plugins()
    return sorted(_REGISTRY)


def model_class(name: str) -> type:
    if name not in _REGISTRY:
        _load_plugins()
    if name not in _REGISTRY:
        raise UnknownModelError(f"unknown model {name!r}; available: {', '.join(list_models())}")
    return _REGISTRY[name]


def _packaged_yaml(name: str) -> dict[str, Any] | None:
    path = resources.files("xcalib.models").joinpath("configs", f"{name}.yaml")
    return (yaml.safe_load(path.read_text()) or {}) if path.is_file() else None


def _frozen_default(value: Any) -> Any:
    """A dataclass field for a YAML default (lists and mappings through a copying factory)."""
    if isinstance(value, (list, dict)):
        return dataclasses.field(default_factory=lambda v=value: copy.deepcopy(v))
    return dataclasses.field(default=value)


def config_class(name: str) -> type:
    """The typed config (a frozen dataclass) of model ``name``: the class's ``config_class`` when it
    declares one, else derived from its packaged YAML (every key typed by its default's kind)."""
    cls = model_class(name)
    if name in _CONFIGS:
        return _CONFIGS[name]
    declared = getattr(cls, "config_class", None)
    if declared is not None:
        if not (dataclasses.is_dataclass(declared) and declared.__dataclass_params__.frozen):
            raise TypeError(f"model {name!r}: config_class must be a frozen dataclass, got {declared!r}")
        _CONFIGS[name] = declared
        return declared
    defaults = _packaged_yaml(name)
    if defaults is None:
        raise UnknownModelError(f"model {name!r} has neither a config_class (a frozen dataclass) nor a packaged "
                                f"configs/{name}.yaml: its settings and their defaults are unknown")
    own = [(k, type(v), _frozen_default(v)) for k, v in defaults.items() if k not in MATCHER_KEYS]
    base = {f.name for f in fields(ModelConfig)}
    out = dataclasses.make_dataclass(f"{cls.__name__}Config", own, bases=(ModelConfig,) if base <= set(defaults) else (),
                                     frozen=True)
    out.__doc__ = f"Typed config of model {name!r} (defaults: xcalib/models/configs/{name}.yaml)."
    _CONFIGS[name] = out
    return out


def default_config(name: str) -> dict[str, Any]:
    """The default config of ``name`` (a fresh dict): the packaged YAML, or a plugin's
    ``config_class`` defaults."""
    model_class(name)
    cfg = _packaged_yaml(name)
    if cfg is None:
        cfg = _as_mapping(config_class(name)())
    cfg["model"] = name
    return cfg


def _as_mapping(record: Any) -> dict[str, Any]:
    """A typed config as the plain mapping a model and its YAML file hold (tuples as lists)."""
    def plain(v):
        if isinstance(v, (list, tuple)):
            return [plain(x) for x in v]
        if isinstance(v, dict):
            return {k: plain(x) for k, x in v.items()}
        return v
    return {f.name: plain(getattr(record, f.name)) for f in fields(record)}


def _kind_ok(default: Any, value: Any) -> bool:
    """Whether ``value`` is of the kind of ``default`` (numbers for numbers, bool for bool, ...)."""
    if default is None:
        return True
    if isinstance(default, bool):
        return isinstance(value, bool)
    if isinstance(default, (int, float)):
        return isinstance(value, (int, float)) and not isinstance(value, bool)
    if isinstance(default, str):
        return isinstance(value, str)
    if isinstance(default, (list, tuple)):
        return isinstance(value, (list, tuple))
    if isinstance(default, dict):
        return isinstance(value, Mapping)
    return True


def typed_config(name: str, config: Mapping[str, Any]) -> Any:
    """``config`` (a full or partial mapping) as model ``name``'s typed config record. ValueError
    naming an unknown key (with the closest known ones) or a value of the wrong kind."""
    ccls = config_class(name)
    known = {f.name: f for f in fields(ccls)}
    unknown = [k for k in config if k not in known and k not in MATCHER_KEYS]
    if unknown:
        hints = []
        for k in sorted(unknown):
            close = difflib.get_close_matches(str(k), list(known), n=1)
            hints.append(f"{k!r}" + (f" (did you mean {close[0]!r}?)" if close else ""))
        raise ValueError(f"model {name!r}: unknown config key(s) {', '.join(hints)}; its keys are "
                         f"{', '.join(sorted(known))}")
    proto = ccls()
    for k, v in config.items():
        if k in known and not _kind_ok(getattr(proto, k), v):
            raise ValueError(f"model {name!r}: config key {k!r} expects a {type(getattr(proto, k)).__name__} "
                             f"like {getattr(proto, k)!r}, got {type(v).__name__} {v!r}")
    return ccls(**{k: v for k, v in config.items() if k in known})


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
    when ``config['model']`` names another model, a key is not one of the model's
    (:func:`config_class`) or a value is of the wrong kind."""
    cls = model_class(name)
    if config is not None and config.get("model", name) != name:
        raise ValueError(f"config is for model {config.get('model')!r}, not {name!r}")
    cfg = merge_config(merge_config(default_config(name), config), overrides)
    cfg["model"] = name
    cfg.pop("device", None)
    cfg.pop("weights_path", None)
    typed = typed_config(name, cfg)  # unknown keys and wrong kinds: a ValueError naming them
    model = cls(cfg)
    model.typed_config = typed
    return model
