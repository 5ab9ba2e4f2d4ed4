"""Records as tables: the one writer of every value the project saves or hashes, scenarios, robot files and what a
controller knows (:class:`controllers.setup.ControllerSetup`), and the one reader of the tables back into
dataclasses (:func:`from_table`, driven by their type hints), whether they were stored as TOML or JSON.

A table holds TOML values only: dataclasses and named tuples become tables of their fields, mappings tables of
their entries, tuples, lists and arrays lists, paths strings and None the string :data:`NONE_MARKER` (TOML has no
null); the reader turns them back into the types the hints name (named tuples, ``Mapping[str, X]``, ``NDArray``,
``Path``). A record's content hash is that of its table, so that no field can be left out of a cache key.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import tomllib
import types
import typing
from collections.abc import Mapping
from pathlib import Path, PurePath
from typing import Any, Literal

import numpy as np

NONE_MARKER = "none"
"""How a table writes an optional field's None."""


def to_table(value: Any) -> Any:
    """``value`` as nested dicts and lists of TOML values."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {item.name: to_table(getattr(value, item.name)) for item in dataclasses.fields(value)}
    if value is None:
        return NONE_MARKER
    if isinstance(value, tuple) and hasattr(value, "_fields"):  # a named tuple
        return {name: to_table(item) for name, item in zip(value._fields, value, strict=True)}
    if isinstance(value, tuple | list):
        return [to_table(item) for item in value]
    if isinstance(value, Mapping):
        return {str(key): to_table(item) for key, item in value.items()}
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, PurePath):
        return value.as_posix()
    return value


def content_hash(table: Any) -> str:
    """16 hex digits of the SHA-256 of ``table`` (:func:`to_table`'s form) as sorted JSON."""
    return hashlib.sha256(json.dumps(table, sort_keys=True).encode()).hexdigest()[:16]


def _is_table(hint: Any) -> bool:
    """Whether a field of type ``hint`` is a TOML table: a dataclass (the records' nested parts)."""
    return isinstance(hint, type) and dataclasses.is_dataclass(hint)


def _is_named_tuple(hint: Any) -> bool:
    """Whether ``hint`` is a named tuple class (written as a table of its fields)."""
    return isinstance(hint, type) and issubclass(hint, tuple) and hasattr(hint, "_fields")


def read_toml(text: str, source: str) -> dict[str, Any]:
    """The table of TOML ``text``; ValueError naming ``source`` if it is not valid TOML."""
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as error:
        raise ValueError(f"{source}: not valid TOML: {error}") from None


def _describe(hint: Any) -> str:
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin is Literal:
        return "one of " + ", ".join(repr(a) for a in args)
    if origin in (typing.Union, types.UnionType):
        return " or ".join(_describe(a) if a is not type(None) else f'"{NONE_MARKER}"' for a in args)
    if origin is tuple and args[-1] is Ellipsis:
        return f"an array of {_describe(args[0]).split()[-1]}s"
    if origin is tuple:
        return f"an array of {len(args)} {_describe(args[0]).split()[-1]}s"
    if _is_table(hint) or _is_named_tuple(hint) or origin in (Mapping, dict):
        return "a table"
    if origin is np.ndarray:
        return "an array of numbers"
    if hint is Path:
        return "a path string"
    return {float: "a number", int: "an integer", bool: "a boolean", str: "a string"}.get(hint, str(hint))


def _convert(path: str, hint: Any, value: Any) -> Any:
    """``value`` read from TOML as the Python value of type ``hint``; ValueError naming ``path``."""
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin in (typing.Union, types.UnionType):
        if type(None) in args and value == NONE_MARKER:
            return None
        (inner,) = (a for a in args if a is not type(None))
        if isinstance(value, dict):  # a table: its own fields name the error
            return _convert(path, inner, value)
        try:
            return _convert(path, inner, value)
        except ValueError:
            raise ValueError(f"{path} must be {_describe(hint)}, got {value!r}") from None
    ok = True
    if hint is float:
        ok = isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)
        value = float(value) if ok else value
    elif hint is int:
        ok = isinstance(value, int) and not isinstance(value, bool)
    elif hint in (bool, str):
        ok = isinstance(value, hint)
    elif origin is Literal:
        ok = value in args
    elif origin is tuple and args[-1] is Ellipsis:  # tuple[X, ...], e.g. an array of tables
        ok = isinstance(value, list)
        if ok:
            return tuple(_convert(f"{path}[{n}]", args[0], v) for n, v in enumerate(value))
    elif origin is tuple:
        ok = isinstance(value, list) and len(value) == len(args)
        if ok:
            return tuple(_convert(f"{path}[{n}]", a, v) for n, (a, v) in enumerate(zip(args, value, strict=True)))
    elif _is_table(hint):
        ok = isinstance(value, dict)
        if ok:
            return from_table(hint, value, path)
    elif _is_named_tuple(hint):
        ok = isinstance(value, dict)
        if ok:
            return _named_tuple(hint, value, path)
    elif origin in (Mapping, dict):  # Mapping[str, X]: a table of entries
        ok = isinstance(value, dict)
        if ok:
            return {key: _convert(f"{path}.{key}", args[1], item) for key, item in value.items()}
    elif origin is np.ndarray:  # NDArray[np.float64]: nested lists of numbers
        try:
            array = np.array(value, dtype=np.float64)
        except (TypeError, ValueError):
            ok = False
        else:
            ok = isinstance(value, list) and bool(np.all(np.isfinite(array)))
            if ok:
                return array
    elif hint is Path:
        ok = isinstance(value, str)
        if ok:
            return Path(value)
    else:  # pragma: no cover - a field type this reader does not know is a programming error
        raise TypeError(f"{path}: no TOML conversion for {hint!r}")
    if not ok:
        raise ValueError(f"{path} must be {_describe(hint)}, got {value!r}")
    return value


def _named_tuple(cls: type, table: dict[str, Any], path: str) -> Any:
    """Named tuple ``cls`` from its table: every field given, each converted and checked."""
    hints = typing.get_type_hints(cls)
    if set(table) != set(cls._fields):
        raise ValueError(f"{path} must have the fields {', '.join(cls._fields)}, got {', '.join(sorted(table))}")
    return cls(**{name: _convert(f"{path}.{name}", hints[name], table[name]) for name in cls._fields})


def from_table(cls: type, table: dict[str, Any], path: str) -> Any:
    """Build dataclass ``cls`` from a TOML table: unknown keys rejected, every field converted and checked.

    Raises:
        ValueError: naming the field, its dotted place under ``path`` (the table's own, "" at the top level).
    """
    hints = typing.get_type_hints(cls)
    names = [item.name for item in dataclasses.fields(cls)]
    where = f"{path}." if path else ""
    unknown = sorted(set(table) - set(names))
    if unknown:
        raise ValueError(f"unknown key(s) {', '.join(where + k for k in unknown)}; allowed: {', '.join(names)}")
    values = {key: _convert(where + key, hints[key], value) for key, value in table.items()}
    try:
        return cls(**values)
    except ValueError as error:
        raise ValueError(f"{path}: {error}" if path else str(error)) from None
