"""When the gripper switches: at a fixed time mid-dwell, or once the cell judges the platform in position
(docs/design.md section 5, "Release").

A real cell switches the suction cup's air only once its axes report "in position", then waits for the air to act
(ABB's IRB 360 data sheet counts 35 ms of air activation at each end of its cycle). With ``release="in_position"``
the reference arrives at each pick and place point and holds there at rest; every control step the cell judges
the platform from what it measures only: the encoder angles (the load encoders' where the arms have them:
compliant drives' motor encoders read the rotors, a gearhead's deflection away from the arms) through the forward
kinematics of its own model of the robot (the declared geometry the reference is planned on), never the
simulator's truth. The platform is *in
position* once that position has stayed within ``in_position_window`` of the reference for ``in_position_time``
(a number of consecutive samples, as a drive's positioning window with its monitoring time). Then the air
activation runs (``air_activation``, the planned rest after the arrival): the object attaches or detaches at its
end, and the next move departs on the same sample. A platform that is not in position ``settle_timeout`` after the
arrival is released anyway, and the event is flagged. ``release="timed"`` is the old cell: a ``DEFAULT_DWELL``
rest with the gripper switching in its middle, whatever the error.

Why consecutive samples and no speed condition: the speed a drive would test comes from the same encoders, whose
17-bit count is about 17 um at the platform, so their backward difference over 1 ms reads 0 or at least 17 mm/s;
a speed window would only ask that no count changed. Holding the position window for N samples bounds the mean
speed over them by 2 * window / ((N - 1) dt) (50 mm/s by default) and rejects a platform that only passes
through the window.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal, Protocol

from delta_env import kernels
from delta_env.cycles import DEFAULT_DWELL, require_release
from delta_env.geometry import DeltaGeometry
from delta_env.sensors import CONTROL_PERIOD
from delta_env.validation import require_in

if TYPE_CHECKING:
    from delta_env.trajectories import Trajectory


class HeldReference(Protocol):
    """What the in-position release needs of the env's reference (:class:`delta_env.reference.EpisodeReference`):
    its samples, its gripper events and the arrivals that gate them, and holding it at rest."""

    trajectory: Trajectory
    events: dict[int, tuple[str, int]]
    gates: dict[int, tuple[str, int]]

    def hold(self, k: int, samples: int = 1) -> None:
        """Hold the reference at rest at its sample ``k`` for ``samples`` more samples."""


DEFAULT_IN_POSITION_WINDOW = 5e-5
"""Distance (m) within which the measured platform must stay of the reference to be in position: 0.05 mm."""

DEFAULT_IN_POSITION_TIME = 0.003
"""Time (s) the window must hold, in consecutive control samples (3 ms: 3 samples), before the cell judges the
platform in position."""

DEFAULT_AIR_ACTIVATION = 0.035
"""Time (s) the suction cup's air takes to act, from the in-position signal to the attach or detach: the 35 ms
that ABB's IRB 360 data sheet counts at each end of its "Cycle 1"."""

DEFAULT_SETTLE_TIMEOUT = 0.065
"""Longest wait (s) for the in-position signal after the reference's arrival; the gripper then acts anyway. With
the air activation, a platform that never settles dwells 0.1 s, the timed release's dwell: a servo that leaves
a friction band (the fixed joint PD's, up to 0.7 mm) runs the old cycle time, and one that settles runs faster."""

MAX_WINDOW = 0.01
"""Largest in-position window (m)."""

MAX_RELEASE_TIME = 10.0
"""Largest in-position time, air activation and settle time-out (s)."""


@dataclass(frozen=True)
class ReleaseSettings:
    """How and when the gripper switches at each pick and place point (module docstring).

    Attributes:
        release: ``"in_position"`` (the default) or ``"timed"`` (the old cell: a ``DEFAULT_DWELL`` rest, the gripper
            switching mid-dwell; the other fields are then unused).
        in_position_window: Distance (m) of the measured platform from the reference within which it may be in
            position, in (0, MAX_WINDOW].
        in_position_time: Time (s) the window must hold (rounded to whole control samples, at least one), in
            [CONTROL_PERIOD, MAX_RELEASE_TIME].
        air_activation: Rest (s) from the in-position signal to the attach or detach, a whole number of control
            samples in [2 CONTROL_PERIOD, MAX_RELEASE_TIME].
        settle_timeout: Longest wait (s) for the in-position signal after the arrival (rounded to whole control
            samples), in [0, MAX_RELEASE_TIME]; 0 releases after the air activation whatever the error.
    """

    release: Literal["in_position", "timed"] = "in_position"
    in_position_window: float = DEFAULT_IN_POSITION_WINDOW
    in_position_time: float = DEFAULT_IN_POSITION_TIME
    air_activation: float = DEFAULT_AIR_ACTIVATION
    settle_timeout: float = DEFAULT_SETTLE_TIMEOUT

    def __post_init__(self) -> None:
        require_release(self.release)
        require_in("in_position_window", self.in_position_window, 0.0, MAX_WINDOW, unit="m", low_open=True)
        require_in("in_position_time", self.in_position_time, CONTROL_PERIOD, MAX_RELEASE_TIME, unit="s")
        air = require_in("air_activation", self.air_activation, 2 * CONTROL_PERIOD, MAX_RELEASE_TIME, unit="s")
        if not math.isclose(round(air / CONTROL_PERIOD) * CONTROL_PERIOD, air, abs_tol=1e-9):
            raise ValueError(
                f"air_activation must be a whole number of control periods ({CONTROL_PERIOD} s), got {air!r} s"
            )
        require_in("settle_timeout", self.settle_timeout, 0.0, MAX_RELEASE_TIME, unit="s")

    @property
    def in_position(self) -> bool:
        """Whether the gripper waits for the in-position signal."""
        return self.release == "in_position"

    @property
    def dwell(self) -> float:
        """The planned rest (s) at each pick and place point: the air activation, or the timed ``DEFAULT_DWELL``."""
        return self.air_activation if self.in_position else DEFAULT_DWELL


@dataclass(frozen=True)
class Settle:
    """One wait for the in-position signal, from the reference's arrival at a pick or place point.

    Attributes:
        kind: ``"pick"`` or ``"place"``.
        cycle: The cycle whose object is picked or placed.
        arrival_step: The step (reference sample) at which the reference arrived at rest.
        settle_time: From the arrival to the in-position signal (s); the time-out for a wait that timed out.
        timed_out: True if the platform was not in position by the time-out (the gripper acted anyway).
    """

    kind: str
    cycle: int
    arrival_step: int
    settle_time: float
    timed_out: bool


class InPositionRelease:
    """The cell's in-position signal and its waits at the pick and place points.

    The cell judges the platform from the encoder angles through the forward kinematics of ``geometry``
    (:meth:`judge`); with ``settings.in_position``, once the reference arrives at rest at a point whose gripper event
    lies ahead, :meth:`step` holds the reference there, a sample a step, until the signal or the time-out.

    Args:
        settings: The release's settings.
        geometry: The cell's model of the robot (the declared geometry the reference is planned on).

    Attributes:
        settles: The waits of the episode that have ended, in order.
    """

    def __init__(self, settings: ReleaseSettings, geometry: DeltaGeometry) -> None:
        self.settings = settings
        self._r, self._l1, self._l2 = geometry.r, geometry.l1, geometry.l2
        self._window_squared = settings.in_position_window**2
        self._samples = max(1, round(settings.in_position_time / CONTROL_PERIOD))
        self._timeout_samples = round(settings.settle_timeout / CONTROL_PERIOD)
        self.reset()

    def reset(self) -> None:
        """Forget the last episode: no samples within the window, no wait under way, no waits ended."""
        self.settles: list[Settle] = []
        self._done: set[tuple[str, int]] = set()  # the events whose wait has ended
        self._inside = 0  # consecutive samples within the window, up to the last judged
        self._waiting: tuple[str, int, int] | None = None  # (kind, cycle, arrival step) of the wait under way

    def judge(self, angles: list[float], target: list[float]) -> bool:
        """Judge one sample: whether the platform measured at encoder ``angles`` (rad) has been within the window of
        ``target`` (m) for the last ``in_position_time``. Never reads the plant: a NaN or an unreachable reading
        is out of the window."""
        status, x, y, z = kernels.platform_position(*angles, self._r, self._l1, self._l2)
        tx, ty, tz = target
        inside = status == kernels.VALID and (x - tx) ** 2 + (y - ty) ** 2 + (z - tz) ** 2 <= self._window_squared
        self._inside = self._inside + 1 if inside else 0
        return self._inside >= self._samples

    def step(self, k: int, angles: list[float], reference: HeldReference) -> tuple[bool, Settle | None]:
        """With the in-position release, judge sample ``k`` of ``reference`` at encoder ``angles`` (rad) from
        ``in_position_time`` before an arrival on, and while waiting for the in-position signal hold the reference
        one more sample at rest (:meth:`HeldReference.hold`). The timed release judges nothing.

        Returns:
            The in-position signal (False where nothing is judged), and the wait that ended on this step (the signal
            or the time-out), if any.
        """
        if not self.settings.in_position:
            return False, None
        gates = reference.gates
        if self._waiting is None:
            if gates.get(k) in self._done:
                return False, None  # an override moved the arrival of an event already waited for
            if k not in gates:
                # judged only over the samples that can count at the next arrival
                armed = any(k + ahead in gates for ahead in range(1, self._samples))
                if not armed:
                    self._inside = 0
                    return False, None
                return self.judge(angles, reference.trajectory.xyz[k].tolist()), None
            self._waiting = (*gates[k], k)
        in_position = self.judge(angles, reference.trajectory.xyz[k].tolist())
        kind, cycle, arrival = self._waiting
        if (kind, cycle) not in reference.events.values():
            self._waiting = None  # a stop dropped the event waited for
            return in_position, None
        waited = k - arrival
        if in_position or waited >= self._timeout_samples:
            self._waiting = None
            settle = Settle(kind, cycle, arrival, waited * CONTROL_PERIOD, not in_position)
            self.settles.append(settle)
            self._done.add((kind, cycle))
            return in_position, settle
        reference.hold(k)
        return in_position, None
