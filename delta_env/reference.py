"""The env's reference: the path an episode follows and its gripper events, planned at reset, retimed by an online
timing during carries, time-scaled by a speed override and held at rest at a pick or place point until the platform
is in position (docs/design.md section 5, "Timing", "Speed override", "Release")."""

from __future__ import annotations

import dataclasses
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from delta_env.cycles import MoveProfile, plan_conveyor_cycles, plan_standard_cycle
from delta_env.geometry import DeltaGeometry
from delta_env.override import SpeedOverride, override_speed
from delta_env.release import ReleaseSettings
from delta_env.timed_cycles import TimedCycles
from delta_env.timing import MoveTiming
from delta_env.trajectories import REST_SPEED, Trajectory, arrivals


class EpisodeReference:
    """The reference of a :class:`~delta_env.env.DeltaPickPlaceEnv`'s episodes, from its plan to its last change.

    The env calls :meth:`plan` in its reset, :meth:`retime` after each step's physics while :attr:`retimes_online`,
    :meth:`override_speed` from its own, and :meth:`hold` while it waits for the platform to be in position
    (:class:`~delta_env.release.InPositionRelease`); after a change that lengthens :attr:`trajectory`, its sensors
    must cover the new samples. Steps are the env's control steps: sample k of the reference is step k's.

    Args:
        geometry: The robot's geometry, on which the cycles are planned.
        n_cycles: Pick-and-place cycles per episode.
        cycle: ``"conveyor"`` (random points) or ``"standard"`` (the 25/305/25 mm cycle).
        start: ``"place"`` or ``"pick"``: where an episode starts at rest.
        profile: The moves' shared timing and shape (the peak acceleration of a fixed timing, the dwells), checked
            where it was made (the scenario's task: :attr:`~delta_env.scenario.PickPlaceTask.move_profile`).
        release: Where the gripper switches in the dwells and how the cell judges the platform in position.

    Attributes:
        trajectory: The reference followed from now on (1 kHz samples); None before the first plan.
        events: The gripper events ahead: sample -> (``"pick"`` or ``"place"``, cycle).
        gates: With the in-position release, the arrival of each event -> the event: the planned dwell, one air
            activation, before it, or the first sample of its rest run if later (a reference of shorter dwells;
            :func:`~delta_env.trajectories.arrivals`); after a speed override, the first sample of its rest run.
            Empty with the timed release and for a reference given to :meth:`plan`.
        retimes_online: Whether :meth:`retime` may change the carries: an online timing, until an override.
        speed_override: The last rate asked of :meth:`override_speed` (1.0 without one).
    """

    def __init__(
        self,
        geometry: DeltaGeometry,
        n_cycles: int,
        cycle: Literal["conveyor", "standard"],
        start: Literal["place", "pick"],
        profile: MoveProfile,
        release: ReleaseSettings,
    ) -> None:
        self.geometry = geometry
        self.release = release
        self.n_cycles = n_cycles
        self.cycle = cycle
        self.start = start
        self.profile = profile
        self.trajectory: Trajectory | None = None
        self.events: dict[int, tuple[str, int]] = {}
        self.gates: dict[int, tuple[str, int]] = {}
        self.retimes_online = False
        self.speed_override = 1.0
        self._timing: MoveTiming | None = None
        self._timed: TimedCycles | None = None  # the timed pieces of the reference, with a timing
        self._carry_starts: dict[int, tuple[int, int]] = {}  # sample -> (piece, its first sample) of each carry
        self._carry: tuple[int, int] | None = None  # the carry move under way: (piece, its first sample)
        self._override: SpeedOverride | None = None  # the reference's time scaling, once override_speed is called
        self._given = False  # whether the reference was given to plan rather than planned

    def plan(
        self,
        rng: np.random.Generator,
        masses: NDArray[np.float64],
        timing: MoveTiming | None,
        reference: Trajectory | None,
    ) -> Trajectory:
        """Plan an episode's reference, drawing its points from ``rng``, and follow it from sample 0.

        Args:
            rng: The episode's generator (conveyor points).
            masses: The objects' masses (kg), one per cycle, declared to ``timing``.
            timing: Times every move, or None for the profile's fixed peak acceleration.
            reference: A path to follow instead of the cycles (``timing`` then unused), as given: it is never held
                for the in-position signal. Or None.
        """
        timing = timing if reference is None else None
        if reference is not None:
            planned = reference
        elif self.cycle == "conveyor":
            planned = plan_conveyor_cycles(
                self.geometry, rng, self.n_cycles, self.profile, self.start, timing=timing, declared_masses=masses
            )
        else:
            planned = plan_standard_cycle(
                self.geometry, self.profile, self.n_cycles, self.start, timing=timing, declared_masses=masses
            )
        self._timing = timing
        self._given = reference is not None  # followed as given: no waits for the in-position signal
        self._timed = planned if isinstance(planned, TimedCycles) else None
        self.retimes_online = self._timed is not None and timing.retimes_online
        self._carry = None
        self._override = None
        self.speed_override = 1.0
        return self._follow(planned)

    def _follow(self, planned: Trajectory | TimedCycles) -> Trajectory:
        """Follow ``planned`` (sampled, or timed pieces) from now on: the reference, its gripper events, its carries."""
        trajectory = planned.trajectory() if isinstance(planned, TimedCycles) else planned
        self.trajectory = trajectory
        self.events = {int(i): ("pick", c) for c, i in enumerate(trajectory.pick_indices)}
        self.events.update({int(i): ("place", c) for c, i in enumerate(trajectory.place_indices)})
        self.gates = {}
        if self.release.in_position and self.events and not self._given:
            samples = list(self.events)
            air = round(self.release.air_activation / trajectory.dt)
            rests = arrivals(trajectory.xyz_dot, samples).tolist()
            # an override stretches the dwells: their rest runs hold the arrivals
            gates = (
                rests if self._override is not None else [max(i - air, r) for i, r in zip(samples, rests, strict=True)]
            )
            # (an event on the first sample of its rest run has no wait before it)
            self.gates = {g: e for g, i, e in zip(gates, samples, self.events.values(), strict=True) if g < i}
        self._carry_starts = {}
        if isinstance(planned, TimedCycles):
            self._find_carries(planned)
        return trajectory

    def _find_carries(self, timed: TimedCycles) -> None:
        """Where each carry of ``timed`` starts (:meth:`retime`)."""
        self._carry_starts = {}
        for index, (start, piece) in enumerate(zip(timed.starts(), timed.pieces, strict=True)):
            if piece.carry is not None:
                self._carry_starts[start] = (index, start)

    def hold(self, k: int, samples: int = 1) -> None:
        """Hold the reference at rest at its sample ``k`` (a rest sample, before the event it waits for) for
        ``samples`` more samples: samples at the rest point follow it (with timed pieces, from the dwell's first
        sample on if ``k`` is still in the move's end at rest), and everything after them comes that much later
        (events, arrivals, carries; the timed pieces and a speed override's path time likewise, so that a later
        retime or override keeps the hold)."""
        if self._timed is not None:
            self._timed, k = self._timed.held(k, samples)
            self._find_carries(self._timed)
        current = self.trajectory
        after = slice(k + 1, None)
        # the new samples are copies of the next one, at rest too: sample k may be a move's last, a rounding off the
        # point, which the timed pieces rebuild differently
        source = min(k + 1, len(current) - 1)

        def held(values: NDArray, at: int = source) -> NDArray:
            copies = np.broadcast_to(values[at], (samples, *values.shape[1:]))
            return np.concatenate((values[: k + 1], copies, values[after]))

        def later(indices: NDArray[np.int64]) -> NDArray[np.int64]:
            return np.where(indices > k, indices + samples, indices)

        trajectory = Trajectory(
            current.dt,
            *(held(getattr(current, name)) for name in ("xyz", "xyz_dot", "xyz_ddot", "theta", "theta_dot")),
            held(current.theta_ddot),
            held(current.gripper, k),  # (sample k + 1 may be the event's)
            later(current.pick_indices),
            later(current.place_indices),
        )
        self.trajectory = trajectory
        self.events = {(i + samples if i > k else i): event for i, event in self.events.items()}
        self.gates = {(i + samples if i > k else i): event for i, event in self.gates.items()}
        if self._override is not None:
            o = self._override
            self._override = SpeedOverride(
                o.nominal, trajectory, held(o.path_time), held(o.path_rate), held(o.path_acceleration), o.rate, o.limits
            )

    def retime(self, k: int) -> bool:
        """Let the online timing retime the carry under way at sample ``k`` (:meth:`MoveTiming.retime`); returns
        whether it did (a new :attr:`trajectory`)."""
        if k in self._carry_starts:
            self._carry = self._carry_starts[k]
        if self._carry is None:
            return False
        piece_index, start = self._carry
        piece = self._timed.pieces[piece_index]
        if k >= start + piece.samples - 1:
            self._carry = None
            return False
        law = self._timing.retime(piece.shape, piece.law, k - start)
        if law is None:
            return False
        self._timed = self._timed.with_law(piece_index, law, followed=k - start + 1)
        self._follow(self._timed)
        self._carry = (piece_index, start)
        return True

    def override_speed(self, k: int, rate: float) -> None:
        """Run the rest of the reference from sample ``k`` at ``rate`` (in [0, 1]) times the planned speed, 0 a stop
        (:func:`delta_env.override.override_speed`); online retiming ends. With the in-position release, an event
        that the override moved onto the first sample of the next move (it sits on the dwell's last sample, where the
        move starts) goes back to the last sample at rest."""
        self._override = override_speed(self.trajectory if self._override is None else self._override, k, rate)
        if self.release.in_position:
            self._override = dataclasses.replace(self._override, trajectory=_events_at_rest(self._override.trajectory))
        self._timed = None
        self.retimes_online = False
        self._carry = None
        self._follow(self._override.trajectory)
        self.speed_override = rate

    def planned_pick(self, cycle: int) -> NDArray[np.float64]:
        """The pick point (m) of ``cycle`` as planned, before any override (a stop may have dropped the pick)."""
        planned = self.trajectory if self._override is None else self._override.nominal
        return planned.xyz[planned.pick_indices[cycle]]


def _events_at_rest(trajectory: Trajectory) -> Trajectory:
    """``trajectory`` with each gripper event on a moving sample moved back to the last sample at rest before it."""
    moving = np.linalg.norm(trajectory.xyz_dot, axis=1) > REST_SPEED

    def at_rest(indices: NDArray[np.int64]) -> list[int]:
        rest = []
        for index in indices.tolist():
            while index > 0 and moving[index]:
                index -= 1
            rest.append(index)
        return rest

    picks, places = at_rest(trajectory.pick_indices), at_rest(trajectory.place_indices)
    if picks == trajectory.pick_indices.tolist() and places == trajectory.place_indices.tolist():
        return trajectory
    gripper = np.zeros(len(trajectory), dtype=bool)
    for cycle, pick in enumerate(picks):
        gripper[pick : places[cycle] if cycle < len(places) else len(gripper)] = True
    return dataclasses.replace(trajectory, gripper=gripper, pick_indices=picks, place_indices=places)
