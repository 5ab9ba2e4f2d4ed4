"""The pure core of time-optimal path parameterization: per-gridpoint linear constraints in, a time law out.

A path q(s), s in [s_0, s_N], is run at the path speed sd = ds/dt. With u = sdd and x = sd^2 every
constraint of the planner is linear at each gridpoint s_i (TOPP-RA's canonical form):

    A_i u + B_i x <= G_i  (row-wise),    0 <= x <= X_i,

and x_{i+1} = x_i + 2 (s_{i+1} - s_i) u_i, so sdd is constant on every grid interval. :func:`solve` finds the
fastest such profile with toppra (reachability analysis: backward controllable sets, then a greedy forward
pass) and returns it as a :class:`RawProfile`, s(t) piecewise quadratic in time: C1, with sdd steps.

The constraints are used in toppra's *interpolation* discretization: stage i must satisfy the constraints at
s_i with (u_i, x_i) and at s_{i+1} with (u_i, x_i + 2 Delta_i u_i), so every grid interval is checked at both
its ends. This matters at rest-to-rest ends of our shapes, where q'(s) = 0 and the constraints at the end
gridpoint alone do not bound u.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from toppra.algorithm import TOPPRA
from toppra.constraint import DiscretizationType
from toppra.constraint.linear_constraint import LinearConstraint
from toppra.interpolator import AbstractGeometricPath

X_CAP = 1e12
"""Largest x = sd^2 (1/s^2 for a unit path) handed to toppra, where no constraint bounds the speed (q' = 0)."""


@dataclass(frozen=True, eq=False)
class StageConstraints:
    """Linear constraints ``a u + b x <= g`` at every gridpoint and the speed bound ``x <= x_max``.

    Attributes:
        gridpoints: Path positions s_i, ``(N + 1,)``, strictly increasing.
        a: Coefficients of u = sdd, ``(N + 1, m)``.
        b: Coefficients of x = sd^2, ``(N + 1, m)``.
        g: Right-hand sides, ``(N + 1, m)``.
        x_max: Largest x at each gridpoint, ``(N + 1,)``, > 0 (capped at :data:`X_CAP`).
    """

    gridpoints: NDArray[np.float64]
    a: NDArray[np.float64]
    b: NDArray[np.float64]
    g: NDArray[np.float64]
    x_max: NDArray[np.float64]

    def __post_init__(self) -> None:
        n = len(self.gridpoints)
        if n < 2 or np.any(np.diff(self.gridpoints) <= 0.0):
            raise ValueError(f"gridpoints must be >= 2 strictly increasing values, got {n} points")
        shape = np.shape(self.a)
        if len(shape) != 2 or shape[0] != n or np.shape(self.b) != shape or np.shape(self.g) != shape:
            raise ValueError(f"a, b, g must share the shape (N + 1, m) = ({n}, m), got {shape}, {np.shape(self.b)}")
        if np.shape(self.x_max) != (n,) or np.any(~(np.asarray(self.x_max) > 0.0)):
            raise ValueError(f"x_max must be ({n},) positive values, got shape {np.shape(self.x_max)}")


class _Rows(LinearConstraint):
    """The constraints of a :class:`StageConstraints` in toppra's canonical form (v = a u + b x, F = I)."""

    def __init__(self, stages: StageConstraints) -> None:
        super().__init__()
        self.stages = stages
        self.discretization_type = DiscretizationType.Interpolation
        self.dof = stages.a.shape[1]

    def compute_constraint_params(
        self, path: AbstractGeometricPath, gridpoints: np.ndarray, *args: object, **kwargs: object
    ) -> tuple[np.ndarray | None, ...]:
        stages = self.stages
        n, m = stages.a.shape
        identity = np.broadcast_to(np.eye(m), (n, m, m))
        xbound = np.column_stack((np.zeros(n), np.minimum(stages.x_max, X_CAP)))
        return stages.a, stages.b, np.zeros((n, m)), identity, stages.g, None, xbound


class _Interval(AbstractGeometricPath):
    """A path that is only its interval: toppra needs the interval, the constraints carry the geometry."""

    def __init__(self, start: float, end: float) -> None:
        self._interval = np.array([start, end])

    def __call__(self, path_positions: float | np.ndarray, order: int = 0) -> np.ndarray:
        raise NotImplementedError("the constraints are precomputed; the path is never evaluated")

    @property
    def dof(self) -> int:
        return 1

    @property
    def path_interval(self) -> np.ndarray:
        return self._interval

    @property
    def waypoints(self) -> None:
        return None


@dataclass(frozen=True, eq=False)
class RawProfile:
    """A time law s(t) with constant sdd between knots: the time-optimal profile, C1 in time.

    Before ``time[0]`` s stays at ``s[0]`` with the speed ``sd[0]`` (0 for a move's start); after ``time[-1]``
    it stays at ``s[-1]`` at rest.

    Attributes:
        time: Knot times t_i (s), ``(K + 1,)``, strictly increasing from 0.
        s: Path positions at the knots, ``(K + 1,)``.
        sd: Path speeds at the knots (1/s), ``(K + 1,)``, >= 0, 0 at the last knot.
        sdd: Path acceleration on each interval (1/s^2), ``(K,)``.
    """

    time: NDArray[np.float64]
    s: NDArray[np.float64]
    sd: NDArray[np.float64]
    sdd: NDArray[np.float64]

    @property
    def duration(self) -> float:
        """Time from the first to the last knot (s)."""
        return float(self.time[-1] - self.time[0])

    def _locate(self, t: NDArray[np.float64]) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
        index = np.clip(np.searchsorted(self.time, t, side="right") - 1, 0, len(self.sdd) - 1)
        return index, np.clip(t, self.time[0], self.time[-1]) - self.time[index]

    def state(self, t: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """s and sd (1/s) at times ``t`` (s), held at the ends."""
        t = np.asarray(t, dtype=float)
        index, local = self._locate(t)
        u = self.sdd[index]
        s = self.s[index] + self.sd[index] * local + 0.5 * u * local**2
        sd = self.sd[index] + u * local
        return s, np.where((t < self.time[0]) | (t > self.time[-1]), 0.0, sd)

    def integral(
        self, t: NDArray[np.float64], f: Callable[[NDArray[np.float64]], NDArray[np.float64]] = np.asarray
    ) -> NDArray[np.float64]:
        """The integral of f(s(t')) dt' from the first knot to each ``t`` (s), s held at the ends.

        Exact for f a polynomial of degree <= 5 (s(t) is quadratic on each interval: Gauss-Legendre with six
        nodes integrates degree 11); the default f(s) = s.
        """
        t = np.asarray(t, dtype=float)
        nodes, weights = np.polynomial.legendre.leggauss(6)

        def piece(index: NDArray[np.int64], length: NDArray[np.float64]) -> NDArray[np.float64]:
            local = 0.5 * length[..., None] * (nodes + 1.0)
            start, speed, acceleration = (array[index][..., None] for array in (self.s, self.sd, self.sdd))
            s = start + speed * local + 0.5 * acceleration * local**2
            return 0.5 * length * np.sum(weights * f(s), axis=-1)

        intervals = np.arange(len(self.sdd))
        knots = np.concatenate(([0.0], np.cumsum(piece(intervals, np.diff(self.time)))))
        index, local = self._locate(t)
        inside = knots[index] + piece(index, local)
        before = (t - self.time[0]) * f(self.s[0])
        after = knots[-1] + (t - self.time[-1]) * f(self.s[-1])
        return np.where(t < self.time[0], before, np.where(t > self.time[-1], after, inside))

    def until(self, t_cut: float) -> RawProfile:
        """This profile up to ``t_cut`` (s, inside it), with a knot inserted there."""
        keep = int(np.searchsorted(self.time, t_cut, side="left"))
        s_cut, sd_cut = self.state(np.array([t_cut]))
        return RawProfile(
            np.append(self.time[:keep], t_cut),
            np.append(self.s[:keep], s_cut),
            np.append(self.sd[:keep], sd_cut),
            self.sdd[:keep] if keep > 0 else self.sdd[:0],
        )

    def then(self, other: RawProfile) -> RawProfile:
        """This profile followed by ``other`` (whose knot 0 is this one's last state), ``other`` shifted in time."""
        return RawProfile(
            np.concatenate((self.time, other.time[1:] - other.time[0] + self.time[-1])),
            np.concatenate((self.s, other.s[1:])),
            np.concatenate((self.sd, other.sd[1:])),
            np.concatenate((self.sdd, other.sdd)),
        )


def solve(stages: StageConstraints, sd_start: float = 0.0) -> RawProfile:
    """The time-optimal profile from ``sd_start`` (1/s) at the first gridpoint to rest at the last one.

    Raises:
        ValueError: if toppra finds no feasible profile (the start speed is not controllable or a gridpoint
            admits no state).
    """
    if not (math.isfinite(sd_start) and sd_start >= 0.0):
        raise ValueError(f"sd_start must be a finite speed >= 0, got {sd_start}")
    grid = np.asarray(stages.gridpoints, dtype=float)
    algorithm = TOPPRA([_Rows(stages)], _Interval(grid[0], grid[-1]), gridpoints=grid, solver_wrapper="seidel")
    _, sd, _ = algorithm.compute_parameterization(sd_start, 0.0)
    if sd is None or np.any(~np.isfinite(sd)):
        raise ValueError(f"no feasible time law from sd = {sd_start} on [{grid[0]}, {grid[-1]}] (toppra failed)")
    sd = np.asarray(sd, dtype=float)
    sd[0] = sd_start  # toppra's forward pass may have nudged the start into its controllable set
    steps = np.diff(grid)
    mean_speed = 0.5 * (sd[:-1] + sd[1:])
    if np.any(mean_speed <= 0.0):
        raise ValueError("the profile stops inside the path (a grid interval has zero speed at both ends)")
    durations = steps / mean_speed
    # sdd from the states actually kept: toppra clips x_{i+1} into the controllable set after x_i + 2 Delta u_i.
    sdd = (sd[1:] - sd[:-1]) / durations
    return RawProfile(np.concatenate(([0.0], np.cumsum(durations))), grid.copy(), sd, sdd)
