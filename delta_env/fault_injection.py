"""The env's fault injection: draws an episode's faults, starts them on time, applies them to the plant and the
readings, and records the truth (docs/design.md section 5, "Faults"; what each kind does: the ``Faults`` section of
:class:`~delta_env.env.DeltaPickPlaceEnv`)."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from delta_env.faults import SENSOR_KINDS, FaultDraw, FaultSpec, InjectedFault
from delta_env.plant import DeltaPlant
from delta_env.trajectories import Trajectory

OBSTACLE_LEAD = 0.05
"""How long (s) before the platform reaches it the obstacle of a collision fault is put in its path."""

OBSTACLE_MIN_SPEED = 0.05
"""Reference speed (m/s) from which the platform counts as moving towards the obstacle: it is put ahead of the first
such sample at or after the drawn time."""


@dataclass
class _RunningFault:
    """A fault of the episode that has started: it acts on steps ``first`` to ``last`` (obstacle: from its
    placement; it counts as active while in contact); a drive fault holds its joint's torque within ``limit`` (N m)."""

    draw: FaultDraw
    first: int
    last: int
    record: int = -1  # its index in FaultInjector.injected, once recorded
    limit: float = math.inf


class FaultInjector:
    """The faults of a :class:`~delta_env.env.DeltaPickPlaceEnv`'s episodes, from their draw to their truth.

    The env calls :meth:`draw` last in its reset, :meth:`schedule_carry` at each pick and, in an episode that
    drew a fault (:attr:`faulty`), :meth:`before_physics` and :meth:`after_step` around each step's physics and
    :meth:`corrupt_readings` on its observation. Steps are the env's control steps (step n returns observation
    n + 1).

    Args:
        specs: The faults an episode may draw.
        plant: The plant the faults act on: its external forces, obstacle and payload.
        peak_torque: The drive's peak torque (N m), which a drive fault limits to a fraction.
        dt: The control period (s).
        drop_object: Releases the object held at a slip and returns its mass (kg); the env's truth of the mass
            carried becomes 0.

    Attributes:
        injected: The truth of this episode's faults, in the order they started (cleared by :meth:`draw`).
        faulty: Whether this episode drew a fault: the one check of the env's hot path.
    """

    def __init__(
        self,
        specs: Sequence[FaultSpec],
        plant: DeltaPlant,
        peak_torque: float,
        dt: float,
        drop_object: Callable[[], float],
    ) -> None:
        self.specs = tuple(specs)
        self.plant = plant
        self.peak_torque = peak_torque
        self.dt = dt
        self._drop_object = drop_object
        self.injected: list[InjectedFault] = []
        self.faulty = False
        self._starts: dict[int, list[tuple[FaultDraw, int]]] = {}  # step -> (fault, its drawn step) starting
        self._carry_faults: dict[int, list[FaultDraw]] = {}  # carry -> its faults, scheduled at its pick
        self._running: list[_RunningFault] = []

    def draw(self, rng: np.random.Generator, n_carries: int) -> None:
        """Draw the episode's faults (last of the reset's draws) and schedule those timed from the reset."""
        self.injected = []
        self._running = []
        self._starts = {}
        self._carry_faults = {}
        drawn = [spec.draw(rng, n_carries) for spec in self.specs]
        self.faulty = any(draw is not None for draw in drawn)
        for draw in drawn:
            if draw is None:
                continue
            if draw.carry is None:
                self._schedule(draw, max(1, round(draw.when / self.dt)) - 1, 0)
            else:
                self._carry_faults.setdefault(draw.carry, []).append(draw)

    def schedule_carry(self, cycle: int, pick: int, place_indices: NDArray[np.int_]) -> None:
        """At the pick of ``cycle`` (step ``pick``): the steps of its carry's faults, from the carry's length now
        (``place_indices`` of the reference followed now)."""
        faults = self._carry_faults.pop(cycle, None)
        if faults is None:
            return
        if cycle >= len(place_indices):  # a stop dropped this carry's place: it ends at rest, holding
            return
        place = int(place_indices[cycle])
        for draw in faults:
            self._schedule(draw, pick + max(1, round(draw.when * (place - pick))) - 1, pick)

    def _schedule(self, draw: FaultDraw, step: int, earliest: int) -> None:
        """Start ``draw`` at ``step``; put an obstacle in place ``OBSTACLE_LEAD`` earlier, not before ``earliest``."""
        start = step
        if draw.detail == "obstacle":
            start = max(step - round(OBSTACLE_LEAD / self.dt), earliest)
        self._starts.setdefault(start, []).append((draw, step))

    def before_physics(
        self, n: int, torque: NDArray[np.float64], trajectory: Trajectory, carrying: int | None
    ) -> NDArray[np.float64]:
        """Start the faults due at step ``n`` and apply those acting on the plant; returns the torque (N m) the drive
        holds.

        Args:
            n: The step about to be taken.
            torque: The command within the drive's envelope (N m), (3,); not modified.
            trajectory: The reference followed now.
            carrying: The carry (by pick order) whose object the gripper holds, or None.
        """
        for draw, step in self._starts.pop(n, ()):
            self._start(draw, step, n, trajectory, carrying, torque)
        self._running = running = [fault for fault in self._running if fault.last >= n]
        for fault in running:
            draw = fault.draw
            if draw.kind == "drive_fault":
                torque = torque.copy()
                self._limit_drive(fault, torque)
            elif draw.kind == "collision" and draw.detail != "obstacle":
                self.plant.apply_external_force(draw.size * np.array(draw.direction), draw.joint)
        return torque

    def _limit_drive(self, fault: _RunningFault, torque: NDArray[np.float64]) -> None:
        """Hold the drive fault's joint within its limit in ``torque`` (modified) and record what it withheld."""
        joint, limit = fault.draw.joint, fault.limit
        asked = float(torque[joint])
        torque[joint] = min(max(asked, -limit), limit)
        withheld = abs(asked) - limit
        record = self.injected[fault.record]
        if withheld > record.withheld:
            self.injected[fault.record] = replace(record, withheld=withheld)

    def _start(
        self,
        draw: FaultDraw,
        step: int,
        n: int,
        trajectory: Trajectory,
        carrying: int | None,
        torque: NDArray[np.float64],
    ) -> None:
        """Begin ``draw`` (drawn for ``step``) at step ``n``, whose command (N m) is ``torque``, or drop it if it can
        no longer happen."""
        dt = self.dt
        size = draw.size
        withheld = math.nan
        limit = math.inf
        if draw.kind == "drive_fault":  # the limit (N m): a fraction of the onset's command or of the peak torque
            limit = draw.size * (abs(float(torque[draw.joint])) if draw.detail == "command" else self.peak_torque)
            size, withheld = limit / self.peak_torque, 0.0
        if draw.kind == "slip":
            places = trajectory.place_indices
            if draw.carry >= len(places):  # a stop dropped its place
                return
            place = int(places[draw.carry])
            if not (carrying == draw.carry and n < place):
                return
            size = self._drop_object()
            last = place - 1
        elif draw.detail == "obstacle":
            speeds = np.linalg.norm(trajectory.xyz_dot[step + 1 :], axis=1)
            moving = np.flatnonzero(speeds >= OBSTACLE_MIN_SPEED)
            if not len(moving):
                return
            hit = step + 1 + int(moving[0])
            self.plant.obstacle.place(trajectory.xyz[hit], trajectory.xyz_dot[hit])
            self._running.append(_RunningFault(draw, n, hit - 1 + max(1, round(draw.duration / dt))))
            return
        else:
            last = n + max(1, round(draw.duration / dt)) - 1
        fault = _RunningFault(draw, n, last, len(self.injected), limit)
        self._running.append(fault)
        record = InjectedFault(draw.kind, n, last - n + 1, (n + 1) * dt, draw.joint, size, draw.detail, withheld)
        self.injected.append(record)

    def after_step(self, n: int) -> tuple[str, ...]:
        """Record the obstacle's contact, end the faults whose last step was step ``n`` (the step just taken); the
        kinds acting on it."""
        kinds = []
        for fault in self._running:
            draw = fault.draw
            if draw.detail == "obstacle":
                force = self.plant.obstacle.contact_force()
                if force > 0.0:
                    kinds.append(draw.kind)
                    self._record_contact(fault, n, force)
                if fault.last == n:
                    self.plant.obstacle.park()
                continue
            kinds.append(draw.kind)
            if fault.last == n and draw.kind == "collision":
                self.plant.clear_external_forces()
        return tuple(kinds)

    def _record_contact(self, fault: _RunningFault, n: int, force: float) -> None:
        """The obstacle's record: its first contact step and the largest contact force (N) so far."""
        if fault.record < 0:
            fault.record = len(self.injected)
            self.injected.append(InjectedFault("collision", n, 1, (n + 1) * self.dt, None, force, "obstacle"))
            return
        record = self.injected[fault.record]
        self.injected[fault.record] = replace(record, steps=n - record.start_step + 1, size=max(record.size, force))

    def corrupt_readings(
        self, n: int, readings: list[float], previous: list[float]
    ) -> tuple[list[float], list[tuple[int, float]]]:
        """The sensor faults acting on the observation of step ``n``.

        Args:
            n: The step just taken.
            readings: The encoder readings (rad) of this observation, (3,).
            previous: The readings (rad) of the observation before, (3,).

        Returns:
            The readings as the faults leave them (a new list), and the offsets (joint, N m; NaN for a sensor_nan) to
            add to its measured torques, in order.
        """
        readings = list(readings)
        torque_offsets = []
        for fault in self._running:
            draw = fault.draw
            if draw.kind not in SENSOR_KINDS or fault.first > n:
                continue
            j = draw.joint
            if draw.kind == "torque_glitch" or draw.detail == "torque":
                torque_offsets.append((j, draw.size))
            elif draw.kind == "encoder_glitch":
                readings[j] += draw.size
            elif draw.kind == "encoder_stuck":
                readings[j] = previous[j]
            else:
                readings[j] = math.nan
        return readings, torque_offsets
