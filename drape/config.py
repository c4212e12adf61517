"""Configurations are data: TOML files read into frozen dataclasses, validated on load.

A dataclass is its own schema. Each field's type says what TOML value it takes (``float``
accepts integers, ``tuple[float, ...]`` an array, a nested dataclass a table, ``dict[str, X]`` a
table of named X (user-chosen keys), ``Literal`` one of a few strings);
``field(metadata={"check": ..., "doc": ...})`` adds a range check and the text
used in error messages. Unknown keys are refused with the closest known names. Cross-field rules
live in the dataclass's ``validate()`` method, which raises :class:`~drape.errors.InputError`.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import tomllib
import typing
from pathlib import Path
from typing import Any, Callable, Literal

from drape.errors import InputError

Check = Callable[[Any], "str | None"]


# --- range checks: each returns None when the value is fine, else what was expected ----------

def positive(value) -> str | None:
    return None if value > 0 else "a number > 0"


def non_negative(value) -> str | None:
    return None if value >= 0 else "a number >= 0"


def in_range(lo: float, hi: float, *, lo_open=False, hi_open=False) -> Check:
    def check(value):
        ok_lo = value > lo if lo_open else value >= lo
        ok_hi = value < hi if hi_open else value <= hi
        if ok_lo and ok_hi:
            return None
        return f"a number in {'(' if lo_open else '['}{lo}, {hi}{')' if hi_open else ']'}"
    return check


def each(check: Check) -> Check:
    """Apply ``check`` to every item of an array."""
    def check_all(values):
        for item in values:
            problem = check(item)
            if problem:
                return f"an array of {problem.removeprefix('a ')}s"
        return None
    return check_all


def setting(default, doc: str = "", check: Check | None = None, unit: str = ""):
    """A dataclass field with a documentation string, a unit and a range check."""
    meta = {"doc": doc, "unit": unit, "check": check}
    if isinstance(default, (list, dict)):
        return dataclasses.field(default_factory=lambda: default, metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


# --- reading ----------------------------------------------------------------------------------

def read_toml(path: str | Path) -> dict:
    """Read a TOML file; a missing or malformed file is an InputError naming it."""
    path = Path(path)
    if not path.is_file():
        raise InputError("file not found" if not path.exists() else "not a file",
                         source=str(path), expected="the path of an existing TOML file")
    try:
        with path.open("rb") as stream:
            return tomllib.load(stream)
    except tomllib.TOMLDecodeError as error:
        raise InputError(f"not valid TOML ({error})", source=str(path),
                         expected="TOML syntax, e.g. key = 1.0 and [section] headers") from None
    except UnicodeDecodeError:
        raise InputError("not a text file", source=str(path),
                         expected="a UTF-8 TOML file") from None


def _type_name(tp) -> str:
    origin = typing.get_origin(tp)
    if tp is float:
        return "a number"
    if tp is int:
        return "an integer"
    if tp is bool:
        return "true or false"
    if tp is str:
        return "a string"
    if origin is Literal:
        return "one of " + ", ".join(repr(v) for v in typing.get_args(tp))
    if origin is tuple:
        item = _type_name(typing.get_args(tp)[0]).removeprefix("a ").removeprefix("an ")
        return "an array of " + item + "s"
    if origin is dict:
        item = _type_name(typing.get_args(tp)[1])
        if " or " in item:
            return f"a table of values ({item})"
        return "a table of " + item.removeprefix("a ").removeprefix("an ") + "s"
    if origin in (typing.Union, getattr(__import__("types"), "UnionType", None)):
        return " or ".join(_type_name(a) for a in typing.get_args(tp) if a is not type(None))
    if dataclasses.is_dataclass(tp):
        return "a table"
    return str(tp)


def _convert(tp, value, key: str, source: str | None):
    """Convert a TOML value to the field type ``tp`` or raise an InputError."""
    origin = typing.get_origin(tp)
    bad = InputError("wrong type", source=source, key=key, value=value, expected=_type_name(tp))
    if origin in (typing.Union, getattr(__import__("types"), "UnionType", None)):
        options = typing.get_args(tp)
        if value is None and type(None) in options:
            return None
        for option in options:
            if option is type(None):
                continue
            if dataclasses.is_dataclass(option) and isinstance(value, dict):
                return _convert(option, value, key, source)   # a table: its own errors
            try:
                return _convert(option, value, key, source)
            except InputError:
                continue
        raise bad
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise bad
        if not math.isfinite(value):
            raise InputError("not a finite number", source=source, key=key, value=value,
                             expected="a finite number")
        return float(value)
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise bad
        return value
    if tp is bool:
        if not isinstance(value, bool):
            raise bad
        return value
    if tp is str:
        if not isinstance(value, str):
            raise bad
        return value
    if origin is Literal:
        if value not in typing.get_args(tp):
            raise InputError("not a known choice", source=source, key=key, value=value,
                             expected=_type_name(tp))
        return value
    if origin is tuple:
        if not isinstance(value, list):
            raise bad
        item_type = typing.get_args(tp)[0]
        return tuple(_convert(item_type, item, f"{key}[{i}]", source)
                     for i, item in enumerate(value))
    if origin is dict:
        if not isinstance(value, dict):
            raise bad
        item_type = typing.get_args(tp)[1]
        return {name: _convert(item_type, item, f"{key}.{name}", source)
                for name, item in value.items()}
    if dataclasses.is_dataclass(tp):
        if not isinstance(value, dict):
            raise bad
        return from_mapping(tp, value, source=source, prefix=key)
    raise TypeError(f"config field type {tp!r} is not supported")


def from_mapping(cls, data: dict, *, source: str | None = None, prefix: str = ""):
    """Build the dataclass ``cls`` from a TOML table, checking keys, types and ranges.

    Missing keys take the field's default. The instance's ``validate()`` (if any) runs last.
    """
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    full = (lambda name: f"{prefix}.{name}" if prefix else name)
    for key, value in data.items():
        if key not in fields:
            close = difflib.get_close_matches(key, fields, n=3, cutoff=0.6)
            hint = f"; did you mean {' or '.join(repr(c) for c in close)}?" if close else ""
            shown = {} if isinstance(value, dict) else {"value": value}   # a table: too long
            raise InputError(f"unknown key{hint}", source=source, key=full(key), **shown,
                             expected=f"one of the known keys here: {', '.join(fields)}")
    values = {}
    for name, fld in fields.items():
        if name not in data:
            if fld.default is dataclasses.MISSING and fld.default_factory is dataclasses.MISSING:
                raise InputError("required key is missing", source=source, key=full(name),
                                 expected=_type_name(hints[name]))
            continue
        value = _convert(hints[name], data[name], full(name), source)
        check = fld.metadata.get("check")
        if check is not None and value is not None:
            problem = check(value)
            if problem:
                raise InputError("out of range", source=source, key=full(name), value=data[name],
                                 expected=problem)
        values[name] = value
    instance = cls(**values)
    validate = getattr(instance, "validate", None)
    if validate is not None:
        try:
            validate()
        except InputError as error:
            raise error.located(source, prefix or None) from None
    return instance


def to_mapping(instance) -> dict:
    """The TOML-ready table of a config dataclass (tuples as lists, None left out)."""
    out = {}
    for fld in dataclasses.fields(instance):
        value = getattr(instance, fld.name)
        if value is None:
            continue
        if dataclasses.is_dataclass(value):
            value = to_mapping(value)
        elif isinstance(value, dict):
            value = {k: to_mapping(v) if dataclasses.is_dataclass(v) else v
                     for k, v in value.items()}
        elif isinstance(value, tuple):
            value = [to_mapping(v) if dataclasses.is_dataclass(v)
                     else list(v) if isinstance(v, tuple) else v for v in value]
        out[fld.name] = value
    return out


def field_default(fld: dataclasses.Field):
    """A config field's default (its factory's value where it has one), or
    ``dataclasses.MISSING`` for a required setting."""
    if fld.default is not dataclasses.MISSING:
        return fld.default
    if fld.default_factory is not dataclasses.MISSING:
        return fld.default_factory()
    return dataclasses.MISSING


def describe(cls, prefix: str = "") -> list[tuple[str, str, str, str]]:
    """(key, type, default, doc) for every field of a config dataclass, nested ones included."""
    rows = []
    hints = typing.get_type_hints(cls)
    for fld in dataclasses.fields(cls):
        key = f"{prefix}.{fld.name}" if prefix else fld.name
        tp = hints[fld.name]
        default = field_default(fld)
        default = None if default is dataclasses.MISSING else default
        inner = _table_type(tp)
        if inner is not None:
            kind, sub = inner
            rows.extend(describe(sub, {"table": key, "dict": f"{key}.<name>",
                                       "array": f"{key}[]"}[kind]))
            continue
        doc = fld.metadata.get("doc", "")
        unit = fld.metadata.get("unit", "")
        rows.append((key, _type_name(tp), repr(default), f"{doc} [{unit}]" if unit else doc))
    return rows


def _table_type(tp):
    """('table' | 'dict' | 'array', dataclass) when a field holds tables, else None."""
    if dataclasses.is_dataclass(tp):
        return "table", tp
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin is dict and dataclasses.is_dataclass(args[1]):
        return "dict", args[1]
    if origin is tuple and args and dataclasses.is_dataclass(args[0]):
        return "array", args[0]
    if origin in (typing.Union, getattr(__import__("types"), "UnionType", None)):
        tables = [a for a in args if dataclasses.is_dataclass(a)]
        if len(tables) == 1:
            return "table", tables[0]
    return None
