"""The shared argument checks: accepted values pass through, refused ones name the value and range."""

import math

import numpy as np
import pytest

from delta_env.validation import (
    require_count,
    require_generator,
    require_in,
    require_instance,
    require_interval,
    require_joint_vector,
    require_positive,
    require_vectors,
)


@pytest.mark.parametrize("value", [0.0, 1.0, 2.5])
def test_require_in_accepts_closed_interval(value: float) -> None:
    assert require_in("x", value, 0.0, 2.5, unit="m") == value


@pytest.mark.parametrize(
    ("value", "kwargs"),
    [
        (0.0, {"low_open": True}),
        (2.5, {"high_open": True}),
        (-0.1, {}),
        (math.nan, {}),
        (math.inf, {}),
        (True, {}),
        ("1", {}),
    ],
)
def test_require_in_refuses_with_name_interval_and_value(value: object, kwargs: dict) -> None:
    with pytest.raises(ValueError, match=r"^x must be a finite number in [\[(]0, 2.5[\])] m, got ") as error:
        require_in("x", value, 0.0, 2.5, unit="m", **kwargs)  # type: ignore[arg-type]
    assert repr(value) in str(error.value)


def test_require_positive_and_count() -> None:
    assert require_positive("mass", 1e-9, "kg") == 1e-9
    with pytest.raises(ValueError, match=r"mass must be a finite number in \(0, inf\) kg, got 0"):
        require_positive("mass", 0, "kg")
    assert require_count("n", 3) == 3
    for bad in (0, 1.5, True):
        with pytest.raises(ValueError, match="n must be an integer >= 1"):
            require_count("n", bad)  # type: ignore[arg-type]


def test_require_interval() -> None:
    assert require_interval("range", (0.0, 4.0), 0.0, 20.0, unit="kg") == (0.0, 4.0)
    for bad in ((4.0, 0.0), (-1.0, 1.0), (0.0, 30.0), (0.0,), "ab"):
        with pytest.raises(ValueError, match="range must be a pair"):
            require_interval("range", bad, 0.0, 20.0, unit="kg")  # type: ignore[arg-type]


def test_require_joint_vector() -> None:
    np.testing.assert_array_equal(require_joint_vector("q", [1, 2, 3]), [1.0, 2.0, 3.0])
    for bad in ([1.0, 2.0], [1.0, np.nan, 2.0]):
        with pytest.raises(ValueError, match=r"q must be 3 finite values \(one per joint\)"):
            require_joint_vector("q", bad)


def test_bounded_checks_name_the_entry_and_the_range() -> None:
    assert require_count("bits", 17, 8, 32) == 17
    with pytest.raises(ValueError, match=r"bits must be an integer in \[8, 32\], got 33"):
        require_count("bits", 33, 8, 32)
    np.testing.assert_array_equal(require_joint_vector("scale", (1, 2, 3), 0.0, 10.0, low_open=True), [1, 2, 3])
    with pytest.raises(ValueError, match=r"scale\[1\] must be a finite number in \(0, 10\], got 0.0"):
        require_joint_vector("scale", (1.0, 0.0, 1.0), 0.0, 10.0, low_open=True)


def test_vectors_generator_and_instance() -> None:
    assert require_vectors("xyz", np.zeros((4, 2, 3))).shape == (4, 2, 3)
    for bad, message in ((np.zeros((4, 2)), "last axis of length 3"), ([0.0, np.inf, 0.0], "must be finite")):
        with pytest.raises(ValueError, match=message):
            require_vectors("xyz", bad)
    rng = np.random.default_rng(0)
    assert require_generator(rng) is rng
    with pytest.raises(TypeError, match=r"rng must be a numpy\.random\.Generator"):
        require_generator(0)
    with pytest.raises(ValueError, match="config must be a dict, got list"):
        require_instance("config", [], dict)
