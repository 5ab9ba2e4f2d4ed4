"""Time laws of pick-and-place moves: how fast the platform runs along each move's fixed geometric shape.

A move's *shape* is its :class:`~delta_env.trajectories.Segment` at unit duration: the arch x(tau) for the shape
parameter tau in [0, 1] (lift, travel and descent blended by quintics, docs/design.md section 5). A
:class:`TimeLaw` gives tau and its first two time derivatives at every control sample, so the reference is

    x(t) = x(tau(t)),   xd = x'(tau) taud,   xdd = x''(tau) taud^2 + x'(tau) taudd,

on exactly the same path whatever the timing. The env's default timing is the fixed peak acceleration of
:mod:`delta_env.cycles` (tau = t / T); a :class:`MoveTiming` object (for example the payload-adaptive,
time-optimal planner of :mod:`controllers.timing`) times every move instead, and may retime a carry while
it runs.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from delta_env.trajectories import Segment, evaluate_segments, require_sample_period

DEFAULT_TORQUE_SHARE = 0.2
"""Share of the drive's envelope and speed limit (after the planner's margin) that moves are planned within by
default: the share up to which the model-based controller tracks within 0.5 mm on the nominal robot
(docs/design.md section 9)."""


@dataclass(frozen=True, eq=False)
class TimeLaw:
    """tau(t) of one move, sampled at ``dt`` from the move's start (sample 0) to its end.

    The shape itself starts and ends at rest (x' = x'' = 0 at tau = 0 and 1), so every finite law gives a
    rest-to-rest move: the fixed timing is tau = t / T with a constant taud = 1 / T.

    Attributes:
        dt: Sample period (s).
        tau: Shape parameter, ``(n,)``, non-decreasing from exactly 0 to exactly 1.
        tau_dot: d tau / dt (1/s), ``(n,)``.
        tau_ddot: d^2 tau / dt^2 (1/s^2), ``(n,)``.
    """

    dt: float
    tau: NDArray[np.float64]
    tau_dot: NDArray[np.float64]
    tau_ddot: NDArray[np.float64]

    def __post_init__(self) -> None:
        require_sample_period(self.dt)
        arrays = [np.array(getattr(self, name), dtype=float) for name in ("tau", "tau_dot", "tau_ddot")]
        if not all(array.ndim == 1 and array.shape == arrays[0].shape for array in arrays) or len(arrays[0]) < 2:
            shapes = [array.shape for array in arrays]
            raise ValueError(f"tau, tau_dot and tau_ddot must be 1-D of one length >= 2, got shapes {shapes}")
        tau = arrays[0]
        if not all(np.all(np.isfinite(array)) for array in arrays):
            raise ValueError("a time law must be finite")
        if tau[0] != 0.0 or tau[-1] != 1.0 or np.any(np.diff(tau) < 0.0):
            raise ValueError(f"tau must rise from 0 to 1 without going back, got {tau[0]} .. {tau[-1]}")
        for name, array in zip(("tau", "tau_dot", "tau_ddot"), arrays, strict=True):
            array.setflags(write=False)
            object.__setattr__(self, name, array)

    @property
    def duration(self) -> float:
        """Move time (s) from the first to the last sample."""
        return (len(self.tau) - 1) * self.dt

    def __len__(self) -> int:
        return len(self.tau)


def move_samples(shape: Segment, law: TimeLaw) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Platform position (m), velocity (m/s) and acceleration (m/s^2), each ``(n, 3)``, of ``shape`` timed by ``law``.

    ``shape`` is used at unit duration, whatever its ``duration`` field says.
    """
    unit = shape.unit()
    x, dx, ddx = evaluate_segments([unit], np.zeros(len(law), dtype=int), law.tau)
    velocity = dx * law.tau_dot[:, None]
    acceleration = ddx * (law.tau_dot**2)[:, None] + dx * law.tau_ddot[:, None]
    return x, velocity, acceleration


class MoveTiming(Protocol):
    """Times every move of an episode; the env calls it at reset, and during carries if it retimes online.

    Attributes:
        retimes_online: True if :meth:`retime` may return a new law while a carry runs; the env then calls it
            at every control step of every carry.
    """

    retimes_online: bool

    def carry(self, shape: Segment, declared_mass: float) -> TimeLaw:
        """The time law of a move with an object; ``declared_mass`` (kg) is the object's true mass, which a
        timing may use (a per-object payload schedule) or ignore (one that does not weigh its objects)."""

    def empty(self, shape: Segment) -> TimeLaw:
        """The time law of a move with the empty gripper."""

    def retime(self, shape: Segment, law: TimeLaw, index: int) -> TimeLaw | None:
        """A new law for the carry that follows ``law`` and is at its sample ``index`` now, or None to keep it.

        A new law must repeat ``law``'s samples 0 .. ``index`` exactly: the past cannot change.
        """
