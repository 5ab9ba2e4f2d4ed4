"""The env's reference: the path an episode follows and its gripper events, planned at reset, retimed by an online
timing during carries and time-scaled by a speed override (docs/design.md section 5, "Timing", "Speed override")."""

from __future__ import annotations

from typing import Literal

import numpy as np
from numpy.typing import NDArray

from delta_env.cycles import TimedCycles, conveyor_cycles, standard_cycle
from delta_env.geometry import DeltaGeometry
from delta_env.override import SpeedOverride, override_speed
from delta_env.timing import MoveTiming
from delta_env.trajectories import Trajectory


class EpisodeReference:
    """The reference of a :class:`~delta_env.env.DeltaPickPlaceEnv`'s episodes, from its plan to its last change.

    The env calls :meth:`plan` in its reset, :meth:`retime` after each step's physics while :attr:`retimes_online`,
    and :meth:`override_speed` from its own; after a change that lengthens :attr:`trajectory`, its sensors must
    cover the new samples. Steps are the env's control steps: sample k of the reference is step k's.

    Args:
        geometry: The robot's geometry, on which the cycles are planned.
        n_cycles: Pick-and-place cycles per episode.
        cycle: ``"conveyor"`` (random points) or ``"standard"`` (the 25/305/25 mm cycle).
        start: ``"place"`` or ``"pick"``: where an episode starts at rest.
        peak_acceleration: Peak Cartesian acceleration of a fixed timing (m/s^2).

    Attributes:
        trajectory: The reference followed from now on (1 kHz samples); None before the first plan.
        events: The gripper events ahead: sample -> (``"pick"`` or ``"place"``, cycle).
        retimes_online: Whether :meth:`retime` may change the carries: an online timing, until an override.
        speed_override: The last rate asked of :meth:`override_speed` (1.0 without one).
    """

    def __init__(
        self,
        geometry: DeltaGeometry,
        n_cycles: int,
        cycle: Literal["conveyor", "standard"],
        start: Literal["place", "pick"],
        peak_acceleration: float,
    ) -> None:
        self.geometry = geometry
        self.n_cycles = n_cycles
        self.cycle = cycle
        self.start = start
        self.peak_acceleration = peak_acceleration
        self.trajectory: Trajectory | None = None
        self.events: dict[int, tuple[str, int]] = {}
        self.retimes_online = False
        self.speed_override = 1.0
        self._timing: MoveTiming | None = None
        self._timed: TimedCycles | None = None  # the timed pieces of the reference, with a timing
        self._carry_starts: dict[int, tuple[int, int]] = {}  # sample -> (piece, its first sample) of each carry
        self._carry: tuple[int, int] | None = None  # the carry move under way: (piece, its first sample)
        self._override: SpeedOverride | None = None  # the reference's time scaling, once override_speed is called

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
            timing: Times every move, or None for the fixed ``peak_acceleration``.
            reference: A path to follow instead of the cycles (``timing`` then unused), or None.
        """
        timing = timing if reference is None else None
        if reference is not None:
            planned = reference
        elif self.cycle == "conveyor":
            planned = conveyor_cycles(
                self.geometry,
                rng,
                self.n_cycles,
                peak_acceleration=self.peak_acceleration,
                start=self.start,
                timing=timing,
                declared_masses=masses,
            )
        else:
            planned = standard_cycle(
                self.geometry,
                self.peak_acceleration,
                n_cycles=self.n_cycles,
                start=self.start,
                timing=timing,
                declared_masses=masses,
            )
        self._timing = timing
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
        self._carry_starts = {}
        if isinstance(planned, TimedCycles):
            for index, (start, piece) in enumerate(zip(planned.starts(), planned.pieces, strict=True)):
                if piece.carry is not None:
                    self._carry_starts[start] = (index, start)
        return trajectory

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
        (:func:`delta_env.override.override_speed`); online retiming ends."""
        self._override = override_speed(self.trajectory if self._override is None else self._override, k, rate)
        self._timed = None
        self.retimes_online = False
        self._carry = None
        self._follow(self._override.trajectory)
        self.speed_override = rate

    def planned_pick(self, cycle: int) -> NDArray[np.float64]:
        """The pick point (m) of ``cycle`` as planned, before any override (a stop may have dropped the pick)."""
        planned = self.trajectory if self._override is None else self._override.nominal
        return planned.xyz[planned.pick_indices[cycle]]
