"""One validation path for every settings section: a dataclass, its type hints and its field constraints.

:func:`parse` builds a settings dataclass from a mapping (a plain dict, YAML, ``key=value`` overrides or an
OmegaConf/Hydra node) by the dataclass's fields: the type hint of a field says what it accepts, the field's
``metadata`` (written with :func:`setting`) adds constraints. Every error is a :class:`SettingError` (a
:class:`robocal.errors.ConfigError`) in one format, naming the full dotted key and the value given::

    calibration.outlier_alpha: must be in (0, 1); got 2
    calibration.nosie_mm: unknown setting; got 0.01. Did you mean 'noise_mm'? Known: fixed, ftol, ...

Types understood: ``bool``, ``int``, ``float``, ``str``, ``Literal[...]``, ``None`` / ``Optional``, unions
(``str | tuple[int, ...]``: the first member that accepts the value wins), ``tuple[X, ...]``, fixed-length
``tuple[X, Y]``, ``list[X]`` / ``Sequence[X]``, ``Mapping[str, X]`` / ``dict``, ``Any`` and nested dataclasses.

Coercions a YAML or command-line user expects, and no others: an integer where a number is expected becomes a
float; a string in scientific notation (``1e-3``, which YAML 1.1 and so ``key=value`` overrides leave a
string) becomes a float where a number is expected; a list becomes a tuple; ``null`` for a list or mapping
setting is empty and for a nested section its defaults. A bool is never taken for a number, nor a number or
a string for a bool; numbers must be finite unless the field says ``finite=False``.

Field constraints (:func:`setting` or ``field(metadata={...})``):

``gt``, ``ge``, ``lt``, ``le``
    bounds of a number (of each number when the value is a list of them; not of the values of a mapping).
``choices``
    the allowed strings (of each string when the value is a list of them; not of the values of a mapping).
``convert``
    ``value -> value`` applied to the given value first (e.g. a YAML 1.1 ``off`` read as ``False``, or a
    shorthand form); it may raise ``ValueError`` / ``TypeError`` with the reason.
``check``
    ``value -> str | None`` on the parsed value: an error text, or None when fine.
``finite``
    False lets ``inf`` / ``nan`` through.
``settable``
    False: the field is not a setting (set in code only), a key of that name is unknown.

Cross-field rules go in a ``validate(self)`` method of the dataclass, called after construction. A ``convert``,
``check`` or ``validate`` may raise :class:`SettingError` with a key relative to its field (or to its class):
the parser puts the full path in front.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import numbers
import re
import types
import typing
from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import Any, Literal, TypeVar, Union

import numpy as np

from robocal.errors import ConfigError

__all__ = [
    "SettingError",
    "check_fields",
    "closest_name",
    "parse",
    "setting",
    "sub_settings",
    "unknown_choice",
    "unknown_setting",
]

T = TypeVar("T")

#: the value of a required key that was not given
_NOTHING: Any = object()
#: what ``float()`` reads but YAML 1.1 (PyYAML, ``key=value`` overrides) leaves a string: ``1e-3``, ``-2E+5``
_SCIENTIFIC = re.compile(r"[-+]?(\d+\.?\d*|\.\d+)[eE][-+]?\d+")
_CONSTRAINTS = ("gt", "ge", "lt", "le", "choices", "convert", "check", "finite", "settable")


class SettingError(ConfigError):
    """A setting is wrong: ``key`` is the full dotted key, ``reason`` what is expected, ``value`` what was given."""

    def __init__(self, key: str, reason: str, value: Any = _NOTHING, hint: str = "") -> None:
        self.key = key
        self.reason = reason
        self.value = value
        self.hint = hint
        got = "nothing" if value is _NOTHING else _show(value)
        text = f"{key}: {reason}; got {got}" if key else f"{reason}; got {got}"
        super().__init__(f"{text}. {hint}" if hint else text)

    def under(self, prefix: str) -> SettingError:
        """The same error with ``prefix`` put in front of its key (a relative key made full)."""
        return SettingError(_join(prefix, self.key), self.reason, self.value, self.hint)


def setting(
    default: Any = dataclasses.MISSING,
    *,
    default_factory: Any = dataclasses.MISSING,
    gt: float | None = None,
    ge: float | None = None,
    lt: float | None = None,
    le: float | None = None,
    choices: Iterable[str] | None = None,
    convert: Callable[[Any], Any] | None = None,
    check: Callable[[Any], str | None] | None = None,
    finite: bool = True,
    settable: bool = True,
) -> Any:
    """``dataclasses.field`` with the constraints of the field in its metadata (see the module docstring)."""
    meta: dict[str, Any] = {
        k: v
        for k, v in (("gt", gt), ("ge", ge), ("lt", lt), ("le", le), ("convert", convert), ("check", check))
        if v is not None
    }
    if choices is not None:
        meta["choices"] = tuple(choices)
    if not finite:
        meta["finite"] = False
    if not settable:
        meta["settable"] = False
    if default_factory is not dataclasses.MISSING:
        return dataclasses.field(default_factory=default_factory, metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


def parse(cls: type[T], mapping: Any, section: str = "calibration", *, ignore: Iterable[str] = ()) -> T:
    """``cls`` (a dataclass) from ``mapping`` (a mapping, an OmegaConf node, or None for the defaults).

    ``section`` is the dotted key of the mapping, put in front of every key an error names; keys in
    ``ignore`` are dropped (settings of someone else that share the section). Raises :class:`SettingError`.
    """
    return _build(cls, mapping, section, frozenset(ignore))


def sub_settings(cls: type) -> Callable[[Any], None]:
    """A ``check`` that parses a mapping field as the settings dataclass ``cls`` (errors name its keys)."""

    def check(value: Any) -> None:
        _build(cls, value, "", frozenset())

    return check


def check_fields(obj: Any, section: str) -> None:
    """Check the values of a constructed settings dataclass against its fields' types and constraints
    (for a ``__post_init__``, so that direct construction is checked the same way)."""
    hints = _hints(type(obj))
    for f in dataclasses.fields(obj):
        if f.init and f.metadata.get("settable", True):
            _field_value(f, hints[f.name], getattr(obj, f.name), _join(section, f.name))


# ------------------------------------------------------------------------------------------------ internals


def _show(value: Any) -> str:
    text = repr(_plain(value))
    return text if len(text) <= 80 else text[:77] + "..."


def _join(prefix: str, key: str) -> str:
    if not prefix:
        return key
    if not key:
        return prefix
    return f"{prefix}{key}" if key.startswith("[") else f"{prefix}.{key}"


def _plain(value: Any) -> Any:
    """OmegaConf nodes as plain dicts and lists (interpolations resolved); anything else as is."""
    if type(value).__module__.startswith("omegaconf"):
        from omegaconf import OmegaConf

        if OmegaConf.is_config(value):
            return OmegaConf.to_container(value, resolve=True)
    return value


_HINTS: dict[type, dict[str, Any]] = {}


def _hints(cls: type) -> dict[str, Any]:
    """The resolved type hints of a settings dataclass; its fields' metadata checked once (a typo is a bug)."""
    if cls not in _HINTS:
        for f in dataclasses.fields(cls):
            wrong = sorted(set(f.metadata) - set(_CONSTRAINTS))
            if wrong:
                raise TypeError(
                    f"{cls.__name__}.{f.name}: unknown setting constraint(s) {wrong}; known: {_CONSTRAINTS}"
                )
        _HINTS[cls] = typing.get_type_hints(cls)
    return _HINTS[cls]


def _build(cls: type[T], mapping: Any, path: str, ignore: frozenset[str]) -> T:
    data = _plain(mapping)
    if data is None:
        data = {}
    if not isinstance(data, Mapping):
        raise SettingError(path, "must be a mapping of settings", data)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init and f.metadata.get("settable", True)}  # type: ignore[arg-type]
    for key in data:
        if key not in fields and key not in ignore:
            raise unknown_setting(path, key, data[key], sorted(fields))
    hints = _hints(cls)
    kwargs: dict[str, Any] = {}
    for name, f in fields.items():
        if name in data:
            kwargs[name] = _field_value(f, hints[name], data[name], _join(path, name))
        elif f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
            raise SettingError(_join(path, name), "is required")
    obj = cls(**kwargs)
    validate = getattr(obj, "validate", None)
    if callable(validate):
        try:
            validate()
        except SettingError as exc:
            raise exc.under(path) from None
    return obj


def closest_name(word: Any, names: Iterable[str], aliases: Mapping[str, str] | None = None) -> str | None:
    """The known name closest to ``word`` (difflib), or None when none is close. ``aliases`` maps other
    spellings of a name to it (``{"levenberg-marquardt": "lm"}``), so that a long or a class name finds its
    short name too."""
    known = list(names)
    pool = {n: n for n in known}
    for alias, name in (aliases or {}).items():
        if name in pool:
            pool.setdefault(alias.lower(), name)
    for w in dict.fromkeys((str(word), str(word).lower())):  # as written first (keys are case-sensitive)
        close = difflib.get_close_matches(w, list(pool), n=1)
        if close:
            return pool[close[0]]
    return None


def unknown_setting(path: str, key: Any, value: Any, known: Iterable[str]) -> SettingError:
    """The error of a key ``key`` of section ``path`` that is no setting: the closest known key, and the known."""
    names = sorted(known)
    close = closest_name(key, names)
    hint = f"Did you mean {close!r}? " if close else ""
    return SettingError(_join(path, str(key)), "unknown setting", value, f"{hint}Known: {', '.join(names)}")


def unknown_choice(
    path: str, value: Any, known: Iterable[str], aliases: Mapping[str, str] | None = None
) -> SettingError:
    """The error of a value of ``path`` that is none of the ``known`` names: the allowed ones, and the closest
    (also through ``aliases``, see :func:`closest_name`)."""
    names = sorted(known)
    close = closest_name(value, names, aliases)
    return SettingError(path, f"must be one of {names}", value, f"Did you mean {close!r}?" if close else "")


def _field_value(f: dataclasses.Field[Any], tp: Any, value: Any, path: str) -> Any:
    meta = f.metadata
    convert = meta.get("convert")
    if convert is not None:
        try:
            value = convert(_plain(value))
        except SettingError as exc:
            raise exc.under(path) from None
        except (TypeError, ValueError) as exc:
            raise SettingError(path, str(exc), value) from None
    out = _coerce(tp, value, path, meta)
    check = meta.get("check")
    if check is not None:
        try:
            problem = check(out)
        except SettingError as exc:
            raise exc.under(path) from None
        if problem:
            raise SettingError(path, problem, value)
    return out


def _is_union(tp: Any) -> bool:
    return typing.get_origin(tp) in (Union, types.UnionType)


def _coerce(tp: Any, v: Any, path: str, meta: Mapping[str, Any]) -> Any:
    """``v`` as type ``tp`` with the constraints ``meta`` on its numbers and strings, or a SettingError."""
    v = _plain(v)
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if tp is Any:
        return v
    if _is_union(tp):
        return _union(tp, args, v, path, meta)
    out: Any = _MISMATCH
    if tp is type(None):
        if v is None:
            return None
    elif origin is Literal:
        if any(v == a and type(v) is type(a) for a in args):
            return v
        raise SettingError(path, f"must be one of {list(args)}", v)
    elif dataclasses.is_dataclass(tp) and isinstance(tp, type):
        return v if isinstance(v, tp) else _build(tp, v, path, frozenset())
    elif tp in (bool, int, float, str):
        out = _scalar(tp, v, path, meta)
    elif origin in (tuple, list, Sequence) or tp in (tuple, list):
        return _sequence(tp, origin or tp, args, v, path, meta)
    elif origin in (dict, Mapping) or tp in (dict, Mapping):
        out = _mapping(args, v, path)
    else:
        raise TypeError(f"robocal.config cannot parse a setting of type {tp!r} ({path})")
    if out is _MISMATCH:
        raise SettingError(path, f"must be {_describe(tp, meta)}", v)
    return out


#: what :func:`_scalar` and :func:`_mapping` return for a value not of the type (the caller says what it must be)
_MISMATCH = object()


def _scalar(tp: type, v: Any, path: str, meta: Mapping[str, Any]) -> Any:
    """``v`` as a bool, int, float (also from scientific notation text) or str within ``meta``'s bounds or
    choices; :data:`_MISMATCH` when it is not one."""
    if tp is bool:
        if isinstance(v, bool | np.bool_):
            return bool(v)
    elif tp is int:
        if isinstance(v, numbers.Integral) and not isinstance(v, bool | np.bool_):
            return _bounded(int(v), path, meta, v)
    elif tp is float:
        if isinstance(v, str) and _SCIENTIFIC.fullmatch(v.strip()):
            v = float(v)
        if isinstance(v, numbers.Real) and not isinstance(v, bool | np.bool_):
            x = float(v)
            if meta.get("finite", True) and not math.isfinite(x):
                raise SettingError(path, "must be a finite number", v)
            return _bounded(x, path, meta, v)
    elif tp is str and isinstance(v, bool | np.bool_) and {"on", "off"} <= set(meta.get("choices") or ()):
        return "on" if v else "off"  # YAML 1.1 reads a bare on / off as a boolean (a CLI override, a config file)
    elif isinstance(v, str):
        choices = meta.get("choices")
        if choices is not None and v not in choices:
            raise SettingError(path, f"must be one of {list(choices)}", v)
        return v
    return _MISMATCH


def _mapping(args: tuple[Any, ...], v: Any, path: str) -> Any:
    """``v`` as a dict of string keys and values of ``args[1]`` (empty for None); :data:`_MISMATCH` when it is
    not a mapping."""
    if v is None:
        return {}
    if not isinstance(v, Mapping):
        return _MISMATCH
    vt = args[1] if len(args) == 2 else Any
    out = {}
    for k, x in v.items():
        if not isinstance(k, str):
            raise SettingError(path, "must have string keys", v)
        out[k] = _coerce(vt, x, _join(path, k), {})  # the field's constraints are not its values
    return out


def _sequence(tp: Any, origin: Any, args: tuple[Any, ...], v: Any, path: str, meta: Mapping[str, Any]) -> Any:
    empty: Any = [] if origin is list else ()
    if v is None:
        return empty
    if isinstance(v, np.ndarray):
        v = v.tolist()
    if not isinstance(v, list | tuple):
        raise SettingError(path, f"must be {_describe(tp, meta)}", v)
    if origin is tuple and args and not (len(args) == 2 and args[1] is Ellipsis):
        if len(v) != len(args):
            raise SettingError(path, f"must be {_describe(tp, meta)}", v)
        items = [_coerce(a, x, f"{path}[{i}]", meta) for i, (a, x) in enumerate(zip(args, v, strict=True))]
    else:
        item = args[0] if args else Any
        items = [_coerce(item, x, f"{path}[{i}]", meta) for i, x in enumerate(v)]
    return items if origin is list else tuple(items)


def _union(tp: Any, members: tuple[Any, ...], v: Any, path: str, meta: Mapping[str, Any]) -> Any:
    if v is None and type(None) in members:
        return None
    failed: list[tuple[Any, SettingError]] = []
    for m in members:
        if m is type(None):
            continue
        try:
            return _coerce(m, v, path, meta)
        except SettingError as exc:
            failed.append((m, exc))
    # one member of the value's kind failed inside (an item of a list, a key of a section): that error is the
    # useful one; otherwise say what the union accepts
    deeper = [e for m, e in failed if _same_kind(m, v) and e.key != path]
    if len(deeper) == 1:
        raise deeper[0]
    raise SettingError(path, f"must be {_describe(tp, meta)}", v)


def _same_kind(tp: Any, v: Any) -> bool:
    origin = typing.get_origin(tp) or tp
    if isinstance(v, str):
        return tp is str or origin is Literal
    if isinstance(v, list | tuple | np.ndarray):
        return origin in (tuple, list, Sequence)
    if isinstance(v, Mapping):
        return origin in (dict, Mapping) or dataclasses.is_dataclass(tp)
    return False


def _bounded(x: float, path: str, meta: Mapping[str, Any], given: Any) -> Any:
    gt, ge, lt, le = (meta.get(k) for k in ("gt", "ge", "lt", "le"))
    ok = (gt is None or x > gt) and (ge is None or x >= ge) and (lt is None or x < lt) and (le is None or x <= le)
    if not ok:
        raise SettingError(path, f"must be {_bounds_text(meta)}", given)
    return x


def _num(x: float) -> str:
    return format(x, "g")


def _bounds_text(meta: Mapping[str, Any]) -> str:
    gt, ge, lt, le = (meta.get(k) for k in ("gt", "ge", "lt", "le"))
    low = (gt, "(") if gt is not None else (ge, "[") if ge is not None else None
    high = (lt, ")") if lt is not None else (le, "]") if le is not None else None
    if low is not None and high is not None:
        return f"in {low[1]}{_num(low[0])}, {_num(high[0])}{high[1]}"
    if low is not None:
        return f"{'>' if gt is not None else '>='} {_num(low[0])}"
    assert high is not None
    return f"{'<' if lt is not None else '<='} {_num(high[0])}"


_NAMES = {bool: ("true or false", "true/false values"), int: ("an integer", "integers"), float: ("a number", "numbers")}


def _describe(tp: Any, meta: Mapping[str, Any], plural: bool = False) -> str:
    """What a value of type ``tp`` (with the string choices / number bounds of ``meta``) looks like, in words."""
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if _is_union(tp):
        parts = [_describe(a, meta, plural) for a in args if a is not type(None)]
        text = parts[0] if len(parts) == 1 else ", ".join(parts[:-1]) + " or " + parts[-1]
        return text + (" or null" if type(None) in args else "")
    if tp in _NAMES:
        text = _NAMES[tp][plural]
        if tp is not bool and any(k in meta for k in ("gt", "ge", "lt", "le")):
            text += f" {_bounds_text(meta)}"
        return text
    if tp is str:
        choices = meta.get("choices")
        if choices:
            return repr(choices[0]) if len(choices) == 1 else f"one of {list(choices)}"
        return "strings" if plural else "a string"
    if tp is type(None):
        return "null"
    if origin is Literal:
        return f"one of {list(args)}"
    if origin in (tuple, list, Sequence) or tp in (tuple, list):
        if origin is tuple and args and not (len(args) == 2 and args[1] is Ellipsis):
            if len(set(args)) == 1:
                return f"{'lists' if plural else 'a list'} of {len(args)} {_describe(args[0], meta, True)}"
            return f"{'lists' if plural else 'a list'} [{', '.join(_describe(a, meta) for a in args)}]"
        item = _describe(args[0], meta, True) if args else "values"
        return f"{'lists' if plural else 'a list'} of {item}"
    if origin in (dict, Mapping) or tp in (dict, Mapping) or dataclasses.is_dataclass(tp):
        if len(args) == 2 and args[1] is not Any:
            return f"{'mappings' if plural else 'a mapping'} of names to {_describe(args[1], meta, True)}"
        return "mappings" if plural else "a mapping"
    return "values" if plural else "a value"
