"""Records as tables: the one writer of every value the project saves or hashes, scenarios, robot files and what a
controller knows (:class:`controllers.registry.ControllerSetup`).

A table holds TOML values only: dataclasses and named tuples become tables of their fields, mappings tables of
their entries, tuples, lists and arrays lists, paths strings and None the string :data:`NONE_MARKER` (TOML has no
null). A record's content hash is that of its table, so that no field can be left out of a cache key.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from collections.abc import Mapping
from pathlib import PurePath
from typing import Any

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
