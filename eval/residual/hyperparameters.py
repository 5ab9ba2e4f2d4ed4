"""The hyperparameters of ``python -m eval.residual``: the file beside the tool and ``--hyperparams`` overrides.

The SB3 keyword arguments of each algorithm are one TOML table of ``eval/residual/hyperparams/residual.toml``
(:func:`load_hyperparameters`); ``--hyperparams key:value ...`` overrides any of them as the RL Zoo does
(:func:`override_hyperparameters`), each value a TOML value and a dotted key one entry of a table.
"""

from __future__ import annotations

import copy
import inspect
import math
import re
import tomllib
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from controllers.residual import algorithm_class

HYPERPARAMETER_FILE = Path(__file__).resolve().parent / "hyperparams" / "residual.toml"
"""The SB3 hyperparameters of each algorithm, one TOML table per algorithm."""

BARE_WORD = re.compile(r"auto(_[0-9.eE+-]+)?")
"""The ``--hyperparams`` values that are not TOML but read as strings: SB3's ``auto`` and ``auto_<initial>`` of
``ent_coef`` and ``target_entropy``. Any other word must be quoted (``'"value"'``)."""

SET_BY_THE_TOOL = frozenset({"seed", "device", "verbose", "tensorboard_log", "_init_setup_model"})
"""Constructor arguments the tool sets itself (``--seed``, ``--tensorboard``), not ``--hyperparams`` keys."""


def load_hyperparameters(algo: str, path: Path = HYPERPARAMETER_FILE) -> dict[str, Any]:
    """The SB3 keyword arguments of ``algo`` (one of ``ALGORITHMS``) from the hyperparameter file."""
    with path.open("rb") as file:
        tables = tomllib.load(file)
    if algo not in tables:
        raise ValueError(f"{path} has no [{algo}] table; it has {sorted(tables)}")
    return copy.deepcopy(tables[algo])


def parse_hyperparameter_value(key: str, text: str) -> Any:
    """The value of one ``--hyperparams key:value`` item: a TOML value (``1e-3``, ``[64, 64]``, ``true``,
    ``"auto"``, ``{ net_arch = [64, 64] }``), or the text itself for ``auto`` / ``auto_<initial>``
    (:data:`BARE_WORD`). A non-finite number is refused."""
    if BARE_WORD.fullmatch(text):
        return text
    try:
        value = tomllib.loads(f"value = {text}")["value"]
    except tomllib.TOMLDecodeError as error:
        hint = " (TOML writes true and false in lower case)" if text in ("True", "False") else ""
        raise ValueError(
            f"--hyperparams {key}: {text!r} is not a TOML value{hint}; quote a string, e.g. {key}:'\"{text}\"' "
            f"({error})"
        ) from None
    if isinstance(value, float) and not math.isfinite(value):
        raise ValueError(f"--hyperparams {key}: {text!r} must be a finite number")
    return value


def override_hyperparameters(hyperparameters: dict[str, Any], items: Sequence[str], algo: str) -> dict[str, Any]:
    """``hyperparameters`` with the ``--hyperparams`` items ``key:value`` applied (a new dict).

    A key must be a keyword argument of the algorithm's constructor; a dotted key (``policy_kwargs.net_arch``)
    sets one entry of a table-valued argument and leaves its other entries.
    """
    allowed = set(inspect.signature(algorithm_class(algo).__init__).parameters) - {"self", "policy", "env"}
    allowed -= SET_BY_THE_TOOL
    result = copy.deepcopy(hyperparameters)
    for item in items:
        key, separator, text = item.partition(":")
        if not separator or not key or not text:
            raise ValueError(f"--hyperparams items are key:value, got {item!r}")
        name, *path = key.split(".")
        if not all(path):
            raise ValueError(f"--hyperparams {key}: a dotted key needs a name between the dots")
        if name in SET_BY_THE_TOOL:
            raise ValueError(f"--hyperparams {key}: {name!r} is set by the tool (--seed, --tensorboard), not here")
        if name not in allowed:
            raise ValueError(f"--hyperparams {key}: {name!r} is not an argument of {algo}; known: {sorted(allowed)}")
        value = parse_hyperparameter_value(key, text)
        if not path:
            result[name] = value
            continue
        table, owner = result.setdefault(name, {}), name
        for part in [*path[:-1], None]:  # None: the table that takes the value
            if not isinstance(table, dict):
                raise ValueError(f"--hyperparams {key}: {owner!r} is {table!r}, not a table")
            if part is not None:
                table, owner = table.setdefault(part, {}), part
        table[path[-1]] = value
    return result
