"""Argument checks shared by every package: each error names the value and the allowed range."""

from __future__ import annotations

import math
import numbers

import numpy as np
from numpy.typing import ArrayLike, NDArray


def _interval(low: float, high: float, low_open: bool, high_open: bool) -> str:
    """The interval in math notation; an infinite bound is always open (no finite number reaches it)."""
    opening = "(" if low_open or low == -math.inf else "["
    closing = ")" if high_open or high == math.inf else "]"
    return f"{opening}{low:g}, {high:g}{closing}"


def require_in(
    name: str,
    value: float,
    low: float = -math.inf,
    high: float = math.inf,
    *,
    unit: str = "",
    low_open: bool = False,
    high_open: bool = False,
) -> float:
    """``value`` as a float if it is a finite real number in the interval, else ``ValueError``.

    Args:
        name: What the value is, as the caller's user knows it (an argument or field name).
        value: The number to check.
        low, high: Bounds of the allowed interval (closed unless ``low_open`` / ``high_open``).
        unit: Unit shown after the interval in the message, e.g. ``"m"``.
    """
    ok = isinstance(value, numbers.Real) and not isinstance(value, bool) and math.isfinite(value)
    if ok:
        ok = (value > low if low_open else value >= low) and (value < high if high_open else value <= high)
    if not ok:
        suffix = f" {unit}" if unit else ""
        interval = _interval(low, high, low_open, high_open)
        raise ValueError(f"{name} must be a finite number in {interval}{suffix}, got {value!r}")
    return float(value)


def require_positive(name: str, value: float, unit: str = "") -> float:
    """``value`` as a float if it is finite and > 0, else ``ValueError``."""
    return require_in(name, value, 0.0, math.inf, unit=unit, low_open=True)


def require_count(name: str, value: int, minimum: int = 1, maximum: int | None = None) -> int:
    """``value`` if it is an integer in [``minimum``, ``maximum``] (bools refused), else ``ValueError``."""
    ok = not isinstance(value, bool) and isinstance(value, numbers.Integral) and value >= minimum
    if maximum is None:
        if not ok:
            raise ValueError(f"{name} must be an integer >= {minimum}, got {value!r}")
    elif not (ok and value <= maximum):
        raise ValueError(f"{name} must be an integer in [{minimum}, {maximum}], got {value!r}")
    return int(value)


def require_interval(
    name: str, value: tuple[float, float], low: float = -math.inf, high: float = math.inf, *, unit: str = ""
) -> tuple[float, float]:
    """A pair ``(a, b)`` with ``low <= a <= b <= high``, both finite, else ``ValueError``."""
    try:
        a, b = (float(v) for v in value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a pair (min, max), got {value!r}") from None
    if not (math.isfinite(a) and math.isfinite(b) and low <= a <= b <= high):
        suffix = f" {unit}" if unit else ""
        raise ValueError(f"{name} must be a pair {low:g} <= min <= max <= {high:g}{suffix}, got {value!r}")
    return a, b


def require_joint_vector(
    name: str,
    value: ArrayLike,
    low: float = -math.inf,
    high: float = math.inf,
    *,
    unit: str = "",
    low_open: bool = False,
) -> NDArray[np.float64]:
    """``value`` as a float array of shape (3,) (one entry per joint) if every entry is finite.

    With ``low`` / ``high``, each entry must also lie in the interval; the error names the entry.
    """
    try:
        array = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be 3 finite values (one per joint), got {value!r}") from None
    if array.shape != (3,) or not np.isfinite(array).all():
        raise ValueError(f"{name} must be 3 finite values (one per joint), got {value!r}")
    if low > -math.inf or high < math.inf:
        for index, entry in enumerate(array.tolist()):
            require_in(f"{name}[{index}]", entry, low, high, unit=unit, low_open=low_open)
    return array


_FLOAT64 = np.dtype(np.float64)


def require_torques(action: object) -> NDArray[np.float64]:
    """``action`` as a float array of 3 motor torques (N m) if it is 3 finite real numbers (integer or floating
    kinds; bool, complex, str and object arrays are refused before converting), else ``ValueError``."""
    if type(action) is np.ndarray and action.dtype is _FLOAT64 and action.shape == (3,):
        torque = action  # the usual action (the env's 1 kHz step): nothing to convert
    else:
        try:
            raw = np.asarray(action)
        except ValueError:  # a ragged sequence
            raw = None
        if raw is None or raw.dtype.kind not in "iuf":
            raise ValueError(f"action must be 3 finite real motor torques (N m), got {action!r}")
        torque = np.asarray(raw, dtype=float)
        if torque.shape != (3,):
            raise ValueError(f"action must be 3 finite real motor torques (N m), got shape {torque.shape}")
    t0, t1, t2 = torque.tolist()
    if not (math.isfinite(t0) and math.isfinite(t1) and math.isfinite(t2)):
        raise ValueError(f"action must be 3 finite real motor torques (N m), got {action!r}")
    return torque


def require_vectors(name: str, value: ArrayLike) -> NDArray[np.float64]:
    """``value`` as a float array of shape (..., 3) (joint or Cartesian vectors) if every entry is finite."""
    array = np.asarray(value, dtype=float)
    if array.ndim == 0 or array.shape[-1] != 3:
        raise ValueError(f"{name} must have a last axis of length 3, got shape {array.shape}")
    if not np.all(np.isfinite(array)):
        raise ValueError(f"{name} must be finite, got {array}")
    return array


def require_generator(rng: object) -> np.random.Generator:
    """``rng`` if it is a ``numpy.random.Generator``, else ``TypeError`` (a seed is not accepted)."""
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"rng must be a numpy.random.Generator (np.random.default_rng(seed)), got {rng!r}")
    return rng


def require_instance(name: str, value: object, kind: type) -> object:
    """``value`` if it is an instance of ``kind``, else ``ValueError`` naming the type it got."""
    if not isinstance(value, kind):
        raise ValueError(f"{name} must be a {kind.__name__}, got {type(value).__name__}")
    return value
