"""Frozen option records for wide public functions (issue 28: no function takes more than 8
parameters).

A function with many settings takes one typed, frozen record (``TrainOptions``, ``MatchOptions``,
...) whose fields hold the defaults, in one place. Where users call the function with the old
keyword arguments (the reference package's API), it accepts them as ``**overrides``:
:func:`resolve` checks each name against the record's fields (an unknown one is a ``TypeError``
naming it and the accepted names, as Python's own message) and folds them in with
``dataclasses.replace``. :class:`Options` checks the type of each field when a record is built,
so ``epochs="3"`` is a ``TypeError`` naming the field, the expected type and the value.
:func:`document` gives the function a signature for ``help()`` / ``inspect.signature`` that
lists the record's fields with their defaults (read from the record, not repeated).

Pure Python; imported by every layer.
"""

from __future__ import annotations

import dataclasses
import difflib
import inspect
import numbers
import os
import types
import typing
from typing import Any, Callable, Iterable, Literal, Mapping, Sequence, TypeVar, Union, get_args, get_origin

__all__ = ["Options", "resolve", "bind_positional", "split_overrides", "document", "check_field_types"]

R = TypeVar("R")

_HINTS: dict[type, dict[str, Any]] = {}


def _hints(cls: type) -> dict[str, Any]:
    h = _HINTS.get(cls)
    if h is None:
        try:
            h = typing.get_type_hints(cls)
        except Exception:  # an annotation that cannot be evaluated: no type checks for that class
            h = {}
        _HINTS[cls] = h
    return h


def _ok(value: Any, tp: Any) -> bool | None:
    """True / False when ``value`` fits / does not fit ``tp``; None when ``tp`` is not checked."""
    if tp is Any:
        return None
    origin = get_origin(tp)
    if origin is Union or (hasattr(types, "UnionType") and isinstance(tp, types.UnionType)):
        verdicts = [_ok(value, a) for a in get_args(tp)]
        if any(v is True for v in verdicts):
            return True
        return None if any(v is None for v in verdicts) else False
    if origin is Literal:
        return value in get_args(tp)
    if tp is type(None):
        return value is None
    if tp in _SIMPLE:
        return _SIMPLE[tp](value)
    if tp is str:
        return isinstance(value, str)
    if tp is os.PathLike or (isinstance(tp, type) and issubclass(tp, os.PathLike)):
        return isinstance(value, (os.PathLike, str)) or None
    if origin in (tuple, list, Sequence, typing.Sequence) or tp in (tuple, list):
        return isinstance(value, (tuple, list)) or None
    if origin in (dict, Mapping, typing.Mapping) or tp is dict:
        return isinstance(value, Mapping) or None
    return None  # any other annotation (arrays, callables, classes of other layers): not checked


def _type_name(tp: Any) -> str:
    return getattr(tp, "__name__", None) or str(tp).replace("typing.", "")


_CHECKS: dict[type, list[tuple[str, Any, Callable[[Any], bool | None]]]] = {}


def _is_int(v: Any) -> bool:
    return type(v) is int or (isinstance(v, numbers.Integral) and not isinstance(v, bool))


def _is_float(v: Any) -> bool:
    return type(v) in (float, int) or (isinstance(v, numbers.Real) and not isinstance(v, bool))


def _is_bool(v: Any) -> bool:
    return isinstance(v, bool) or type(v).__name__ == "bool_"


_SIMPLE = {int: _is_int, float: _is_float, bool: _is_bool}


def _compile(tp: Any) -> Callable[[Any], bool | None]:
    """A fast :func:`_ok` for ``tp`` where it is a union of str / int / float / bool / None."""
    parts = get_args(tp) if (get_origin(tp) is Union or (hasattr(types, "UnionType")
                                                         and isinstance(tp, types.UnionType))) else (tp,)
    if not all(p in (str, type(None)) or p in _SIMPLE for p in parts):
        return lambda v: _ok(v, tp)
    plain = tuple(p for p in parts if p in (str, type(None)))
    preds = tuple(_SIMPLE[p] for p in parts if p in _SIMPLE)
    return lambda v: isinstance(v, plain) or any(f(v) for f in preds)


def _checks(cls: type) -> list[tuple[str, Any, Callable[[Any], bool | None]]]:
    """(field, annotation, predicate) of the fields of ``cls`` whose annotation is checked (cached)."""
    out = _CHECKS.get(cls)
    if out is None:
        hints = _hints(cls)
        out = []
        for f in dataclasses.fields(cls):
            tp = hints.get(f.name)
            if tp is not None and _ok(_NEVER, tp) is False:  # else no value is ever refused: not checked
                out.append((f.name, tp, _compile(tp)))
        _CHECKS[cls] = out
    return out


class _Never:
    """A value no checked annotation accepts."""


_NEVER = _Never()


def check_field_types(record: Any, where: str | None = None) -> None:
    """TypeError (ValueError for a ``Literal`` value not among its choices) naming the first field
    of dataclass ``record`` whose value does not fit its annotation."""
    for name, tp, ok in _checks(type(record)):
        value = getattr(record, name)
        if ok(value) is False:
            who = where or type(record).__name__
            choices = _choices(tp)
            if choices and isinstance(value, str):
                raise ValueError(f"{who}: {name} must be one of {choices}, got {value!r}")
            raise TypeError(f"{who}: {name} must be {_type_name(tp)}, got {type(value).__name__} {value!r}")


def _choices(tp: Any) -> list[Any]:
    """The values of the ``Literal`` parts of ``tp`` (empty when it has none)."""
    if get_origin(tp) is Literal:
        return list(get_args(tp))
    if get_origin(tp) is Union or (hasattr(types, "UnionType") and isinstance(tp, types.UnionType)):
        return [c for a in get_args(tp) for c in _choices(a)]
    return []


class Options:
    """Mixin of frozen option dataclasses: each field's value is checked against its annotation
    when the record is built (:func:`check_field_types`). A subclass with its own
    ``__post_init__`` calls ``super().__post_init__()``."""

    def __post_init__(self) -> None:
        check_field_types(self)

    def replace(self: R, **overrides: Any) -> R:
        """A copy with ``overrides`` (field names only; an unknown name is a TypeError naming it)."""
        return resolve(type(self), self, overrides)

    @classmethod
    def field_names(cls) -> tuple[str, ...]:
        return tuple(f.name for f in dataclasses.fields(cls))


_NAMES: dict[type, frozenset[str]] = {}


def _names(cls: type) -> frozenset[str]:
    got = _NAMES.get(cls)
    if got is None:
        got = _NAMES[cls] = frozenset(f.name for f in dataclasses.fields(cls))
    return got


def _unknown(where: str, name: str, accepted: Iterable[str]) -> TypeError:
    accepted = sorted(accepted)
    close = difflib.get_close_matches(name, accepted, n=1)
    hint = f" (did you mean {close[0]!r}?)" if close else ""
    return TypeError(f"{where}() got an unexpected keyword argument {name!r}{hint}; "
                     f"accepted: {', '.join(accepted)}")


def resolve(cls: type[R], base: R | None, overrides: Mapping[str, Any], *, where: str | None = None) -> R:
    """``base`` (None: ``cls()``, the defaults) with ``overrides`` folded in by
    ``dataclasses.replace``. An override that is not a field of ``cls`` raises TypeError naming it
    and the accepted names (``where``: the function named in the message); a value of the wrong
    type raises from the record's checks. ``base`` of another type is a TypeError."""
    where = where or cls.__name__
    if base is not None and not isinstance(base, cls):
        raise TypeError(f"{where}: options must be a {cls.__name__}, got {type(base).__name__}")
    names = _names(cls)
    for k in overrides:
        if k not in names:
            raise _unknown(where, k, names)
    if base is None:
        return cls(**overrides)
    return dataclasses.replace(base, **overrides) if overrides else base


def bind_positional(names: Sequence[str], args: Sequence[Any], overrides: Mapping[str, Any],
                    where: str) -> dict[str, Any]:
    """``overrides`` plus the extra positional ``args`` named by ``names`` in order (the reference's
    positional parameters after the fixed ones). Too many, or a name given both ways, is a
    TypeError, as Python's own."""
    if len(args) > len(names):
        raise TypeError(f"{where}() takes at most {len(names)} optional positional arguments "
                        f"({', '.join(names)}) but {len(args)} were given")
    out = dict(overrides)
    for name, value in zip(names, args):
        if name in out:
            raise TypeError(f"{where}() got multiple values for argument {name!r}")
        out[name] = value
    return out


def split_overrides(overrides: Mapping[str, Any], groups: Sequence[type | Iterable[str]],
                    where: str) -> list[dict[str, Any]]:
    """``overrides`` split by ``groups`` (a dataclass: its field names; else an iterable of names);
    a name in none of them is a TypeError naming it and every accepted name."""
    sets = [g if isinstance(g, frozenset) else _names(g) if isinstance(g, type) else frozenset(g) for g in groups]
    out: list[dict[str, Any]] = [{} for _ in sets]
    for k, v in overrides.items():
        for s, d in zip(sets, out):
            if k in s:
                d[k] = v
                break
        else:
            raise _unknown(where, k, set().union(*sets))
    return out


def _default(f: dataclasses.Field) -> Any:
    if f.default is not dataclasses.MISSING:
        return f.default
    if f.default_factory is not dataclasses.MISSING:  # type: ignore[misc]
        return f.default_factory()  # type: ignore[misc]
    return inspect.Parameter.empty


def document(*records: type, positional: Sequence[str] = (), skip: Iterable[str] = (),
             extra: Sequence[inspect.Parameter] = (), keep_kwargs: bool = False) -> Callable[[Callable], Callable]:
    """Decorator: ``fn``'s signature for ``help()`` / ``inspect.signature`` lists the fields of
    ``records`` as parameters with the records' defaults, in place of ``*args`` (``positional``:
    the fields that may also be given by position, in that order) and ``**overrides`` (the others,
    keyword-only). ``skip``: fields not offered by keyword; ``extra``: more keyword-only parameters
    (accepted through ``**overrides`` but not fields of a record); ``keep_kwargs``: ``**overrides``
    stays in the signature (it takes more names than the records'). The function itself is
    unchanged: it still takes the record and ``**overrides``."""
    skip = set(skip)

    def deco(fn: Callable) -> Callable:
        sig = inspect.signature(fn)
        fixed = [p for p in sig.parameters.values() if p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)]
        fields = {f.name: f for r in records for f in dataclasses.fields(r) if f.name not in skip}
        hints = {k: v for r in records for k, v in _hints(r).items()}
        pos = [inspect.Parameter(n, inspect.Parameter.POSITIONAL_OR_KEYWORD, default=_default(fields[n]),
                                 annotation=hints.get(n, inspect.Parameter.empty)) for n in positional]
        kw = [inspect.Parameter(n, inspect.Parameter.KEYWORD_ONLY, default=_default(f),
                                annotation=hints.get(n, inspect.Parameter.empty))
              for n, f in fields.items() if n not in positional]
        before = [p for p in fixed if p.kind in (p.POSITIONAL_ONLY, p.POSITIONAL_OR_KEYWORD)]
        after = [p for p in fixed if p.kind is p.KEYWORD_ONLY]
        names = {p.name for p in before + pos}
        kw = [p for p in kw if p.name not in names] + [p for p in extra if p.name not in names]
        kw_names = {p.name for p in kw}
        own = [p for p in after if p.name not in kw_names]  # the function's own keyword-only parameters
        params = before + pos + [p for p in own if p.name != "options"] + kw + [p for p in own if p.name == "options"]
        if keep_kwargs:
            params += [p for p in sig.parameters.values() if p.kind is p.VAR_KEYWORD]
        fn.__signature__ = sig.replace(parameters=params)  # type: ignore[attr-defined]
        return fn

    return deco
