"""Pick-and-place cycles timed by a :class:`~delta_env.timing.MoveTiming` (:class:`TimedCycles`): the fixed timing's
stations, shapes, dwells and gripper events (:mod:`delta_env.cycles`), every move timed by its own law, so that a
move can be retimed while it runs and a dwell held longer (docs/design.md section 5, "Timing")."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal

import numpy as np

from delta_env.geometry import DeltaGeometry
from delta_env.kinematics import cartesian_to_joint
from delta_env.limits import WORKSPACE_LIMITS, WorkspaceLimits, require_admissible
from delta_env.timing import MoveTiming, TimeLaw, move_samples
from delta_env.trajectories import Segment, Trajectory

if TYPE_CHECKING:
    from delta_env.cycles import MoveProfile


def require_stations(
    geometry: DeltaGeometry,
    picks: np.ndarray,
    places: np.ndarray,
    origin: np.ndarray | None,
    lift_height: float,
    limits: WorkspaceLimits,
) -> None:
    """Raise ValueError unless every station (m) and the point ``lift_height`` (m) above it is admissible."""
    lifted = np.array([0.0, 0.0, lift_height])
    stations = [("pick point", picks), ("place point", places)]
    if origin is not None:
        stations.append(("starting point", origin[None, :]))
    for name, points in stations:
        require_admissible(geometry, points, limits, name)
        require_admissible(geometry, points + lifted, limits, f"lifted {name}")


@dataclass(frozen=True)
class TimedPiece:
    """One piece of timed cycles: a dwell (``law`` None, ``samples`` at rest) or a move timed by ``law``.

    Attributes:
        shape: The move's shape (its ``duration`` unused), or for a dwell a line from the point to itself.
        samples: Samples of the piece including both ends (a dwell of d seconds has d / dt + 1).
        law: The move's time law, or None for a dwell.
        carry: The cycle whose object the move carries, or None (empty move or dwell).
    """

    shape: Segment
    samples: int
    law: TimeLaw | None = None
    carry: int | None = None


@dataclass(frozen=True)
class TimedCycles:
    """Pick-and-place cycles whose moves are timed by a :class:`~delta_env.timing.MoveTiming`.

    The same stations, shapes, dwells and gripper events (mid-dwell, or at the dwell's end) as the fixed timing;
    every piece starts and ends on a sample, so a move's law can be replaced while it runs (:meth:`with_law`) and
    the reference before the change stays as it was, and a dwell can be held longer (:meth:`held`).

    Attributes:
        geometry: Robot geometry.
        dt: Sample period (s).
        pieces: Dwells and moves in order.
        limits: Region and singularity margins every sample must respect.
        release: ``"timed"`` (the gripper switches on a dwell's middle sample) or ``"in_position"`` (on its last).
    """

    geometry: DeltaGeometry
    dt: float
    pieces: tuple[TimedPiece, ...]
    limits: WorkspaceLimits = WORKSPACE_LIMITS
    release: Literal["in_position", "timed"] = "timed"

    @classmethod
    def plan(
        cls,
        geometry: DeltaGeometry,
        picks: np.ndarray,
        places: np.ndarray,
        profile: MoveProfile,
        limits: WorkspaceLimits,
        origin: np.ndarray | None,
        timing: MoveTiming,
        declared_masses: Sequence[float] | None,
    ) -> TimedCycles:
        """The pieces of the fixed timing's path through ``picks`` and ``places`` (m; from ``origin`` if given, as in
        :mod:`delta_env.cycles`) with every move timed by ``timing``, ``declared_masses`` (kg) one per cycle."""
        n_cycles = len(places)
        if declared_masses is None or len(declared_masses) != n_cycles:
            got = None if declared_masses is None else len(declared_masses)
            raise ValueError(f"a timing needs one declared mass per cycle ({n_cycles}), got {got}")
        require_stations(geometry, picks, places, origin, profile.lift_height, limits)
        dwell_samples = round(profile.dwell / profile.dt)
        halved = profile.release == "timed"  # the gripper switches on the dwell's middle sample
        if (halved and dwell_samples % 2) or not math.isclose(dwell_samples * profile.dt, profile.dwell, abs_tol=1e-9):
            raise ValueError(
                f"with a timing the dwell must be {'an even' if halved else 'a whole'} number of sample periods "
                f"({profile.dt} s), got {profile.dwell} s"
            )

        def dwell(point: np.ndarray, samples: int) -> TimedPiece:
            return TimedPiece(Segment.line(point, point, samples * profile.dt), samples + 1)

        def move(start: np.ndarray, end: np.ndarray, carry: int | None) -> TimedPiece:
            shape = Segment(start, end, 1.0, profile.lift_height, profile.lift_fraction)
            law = timing.empty(shape) if carry is None else timing.carry(shape, float(declared_masses[carry]))
            return TimedPiece(shape, len(law), law, carry)

        pieces: list[TimedPiece] = []
        if origin is not None:
            # the rest of the dwell in which the previous object was released
            pieces += [dwell(origin, dwell_samples // 2)] if halved else []
            pieces += [move(origin, picks[0], None)]
        for cycle, (pick, place, next_pick) in enumerate(zip(picks[:-1], places, picks[1:], strict=True)):
            pieces += [dwell(pick, dwell_samples), move(pick, place, cycle)]
            pieces += [dwell(place, dwell_samples), move(place, next_pick, None)]
        return cls(geometry, profile.dt, tuple(pieces), limits, profile.release)

    def starts(self) -> list[int]:
        """The sample at which each piece starts."""
        return np.concatenate(([0], np.cumsum([piece.samples - 1 for piece in self.pieces])))[:-1].tolist()

    def with_law(self, index: int, law: TimeLaw, followed: int = 0) -> TimedCycles:
        """The same cycles with piece ``index`` (a move) timed by ``law``, which must repeat the first ``followed``
        samples of its present law (those the robot has followed already)."""
        piece = self.pieces[index]
        if piece.law is None:
            raise ValueError(f"piece {index} is a dwell, not a move")
        for name in ("tau", "tau_dot", "tau_ddot"):
            past = getattr(piece.law, name)[:followed]
            if len(law) < followed or not np.array_equal(getattr(law, name)[:followed], past):
                raise ValueError(f"a retimed law must repeat the {followed} samples already followed ({name} differs)")
        pieces = list(self.pieces)
        pieces[index] = TimedPiece(piece.shape, len(law), law, piece.carry)
        return TimedCycles(self.geometry, self.dt, tuple(pieces), self.limits, self.release)

    def held(self, sample: int, extra: int) -> tuple[TimedCycles, int]:
        """The same cycles with the first dwell that ends at or after ``sample`` ``extra`` samples longer, and the
        sample after which its :meth:`trajectory` has the ``extra`` more samples at the dwell's point: ``sample``
        itself in that dwell, or the dwell's first when ``sample`` is still in the move's end at rest (a time law may
        reach its end a few samples early).

        Raises:
            ValueError: no dwell ends at or after ``sample``.
        """
        for index, (start, piece) in enumerate(zip(self.starts(), self.pieces, strict=True)):
            if piece.law is None and start + piece.samples - 1 >= sample:
                pieces = list(self.pieces)
                pieces[index] = TimedPiece(piece.shape, piece.samples + extra)
                return TimedCycles(self.geometry, self.dt, tuple(pieces), self.limits, self.release), max(sample, start)
        raise ValueError(f"no dwell of the timed cycles ends at or after sample {sample}")

    def trajectory(self) -> Trajectory:
        """The sampled reference: joint references by exact inverse kinematics, gripper events mid-dwell or on the
        dwell's last sample."""
        starts = self.starts()
        parts = []
        for piece in self.pieces:
            if piece.law is None:
                rest = np.zeros((piece.samples, 3))
                parts.append((rest + piece.shape.start, rest, rest))
            else:
                parts.append(move_samples(piece.shape, piece.law))
        xyz, xyz_dot, xyz_ddot = (
            np.concatenate([part[k][1 if i else 0 :] for i, part in enumerate(parts)]) for k in range(3)
        )
        require_admissible(self.geometry, xyz, self.limits, "path point")
        theta, theta_dot, theta_ddot = cartesian_to_joint(self.geometry, xyz, xyz_dot, xyz_ddot)
        # A carry's object is picked in the dwell before it and released in the one after: in their middle, or on
        # their last sample (the carry's first, the next move's first).
        carries = [index for index, piece in enumerate(self.pieces) if piece.carry is not None]
        halved = self.release == "timed"

        def switch(index: int) -> int:
            return starts[index] + ((self.pieces[index].samples - 1) // 2 if halved else self.pieces[index].samples - 1)

        picks = [switch(i - 1) for i in carries]
        places = [switch(i + 1) for i in carries]
        gripper = np.zeros(len(xyz), dtype=bool)
        for pick, place in zip(picks, places, strict=True):
            gripper[pick:place] = True
        return Trajectory(self.dt, xyz, xyz_dot, xyz_ddot, theta, theta_dot, theta_ddot, gripper, picks, places)
