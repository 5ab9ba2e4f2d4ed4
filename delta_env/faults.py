"""Faults injected into an episode: what a scenario may ask for and the truth of what happened (docs/design.md)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np

from delta_env.validation import require_count, require_in, require_instance, require_interval

FAULT_KINDS = ("slip", "encoder_glitch", "encoder_stuck", "sensor_nan", "torque_glitch", "collision", "drive_fault")
"""The kinds of fault an episode may carry; detectors report the same names."""

SENSOR_KINDS = ("encoder_glitch", "encoder_stuck", "sensor_nan", "torque_glitch")
"""The kinds that corrupt a reading rather than the robot: the plant never notices them."""

FAULT_REACTIONS = ("continue", "slow", "stop")
"""What a cell may do after a detected collision, slip or drive fault: carry on, slow to half the reference's speed,
or stop at rest on the path (:attr:`delta_env.scenario.PickPlaceTask.fault_reaction`,
:meth:`delta_env.env.DeltaPickPlaceEnv.override_speed`)."""


@dataclass(frozen=True)
class InjectedFault:
    """The truth of one fault that happened in an episode (never shown to a controller).

    Attributes:
        kind: One of :data:`FAULT_KINDS`.
        start_step: Control step at whose end the fault first acts: the first observation it affects is the one
            ``env.step`` returns at that step (step n returns observation n + 1).
        steps: Control steps it lasts (>= 1); a slip lasts to the end of its carry.
        start_s: Time of that first affected observation (s) from the reset: ``(start_step + 1) * dt``.
        joint: Joint 0..2 it acts on, or None (slip, a collision on the platform or with the obstacle).
        size: Its size, in the unit of its kind: rad (encoder_glitch), N m (torque_glitch), N (collision, the
            force's magnitude; for the obstacle the largest contact force), the fraction of the peak torque the
            drive keeps (drive_fault, whatever its spec's ``relative_to``), the object's mass in kg (slip); NaN where
            a kind has none.
        detail: What else identifies it, e.g. ``"encoder"``/``"torque"`` (sensor_nan), ``"platform"``/``"arm"``/
            ``"obstacle"`` (collision), ``"command"``/``"peak"`` (drive_fault: what its drawn fraction was of).
        withheld: For a drive_fault, the most torque (N m) it withheld from the command (within the envelope) on any
            step it acted: 0 if every command stayed within what the drive kept, so that the fault changed nothing
            and nothing could observe it (:func:`is_latent`); NaN for the other kinds.
    """

    kind: str
    start_step: int
    steps: int
    start_s: float
    joint: int | None = None
    size: float = float("nan")
    detail: str = ""
    withheld: float = float("nan")


def is_latent(fault: InjectedFault) -> bool:
    """Whether an injected fault changed nothing the robot did: a drive fault that never withheld any torque (every
    command it met stayed within what the drive kept). Nothing can detect it, so a scorer does not count it."""
    return fault.kind == "drive_fault" and fault.withheld == 0.0


JOINT_KINDS = ("encoder_glitch", "encoder_stuck", "sensor_nan", "torque_glitch", "drive_fault")
"""The kinds that act on one joint (a collision does too when its target is ``"arm"``)."""

FAULT_DEFAULTS: dict[str, tuple[tuple[float, float] | None, tuple[float, float] | None]] = {
    "slip": (None, None),
    "encoder_glitch": ((0.005, 0.05), (0.001, 0.001)),
    "encoder_stuck": (None, (0.005, 0.05)),
    "sensor_nan": (None, (0.001, 0.001)),
    "torque_glitch": ((20.0, 200.0), (0.001, 0.001)),
    "collision": ((150.0, 1000.0), (0.02, 0.05)),
    "drive_fault": ((0.0, 0.5), (0.02, 0.1)),
}
"""Per kind, the default ``size`` and ``duration`` ranges of a :class:`FaultSpec` (None: the kind has none)."""

DEFAULT_CARRY_FRACTION = (0.2, 0.8)
"""Where in a carry a fault starts when its spec gives no ``start``: a fraction of the carry (pick to place)."""

_SIGNED_KINDS = ("encoder_glitch", "torque_glitch")
_SIZE_UNITS = {"encoder_glitch": "rad", "torque_glitch": "N m", "collision": "N"}


@dataclass(frozen=True)
class FaultSpec:
    """A fault a scenario may inject: its kind and the ranges each episode draws it from (uniformly).

    Every range is a pair ``(min, max)``; ``min == max`` fixes the value. Fields a kind does not use must stay
    None; those it uses and are left at None take the kind's default (``FAULT_DEFAULTS``):

    | kind | ``size`` (default) | ``duration`` (default, s) | other fields |
    |---|---|---|---|
    | ``slip`` | none | none: to the end of the carry | needs ``carry_fraction`` |
    | ``encoder_glitch`` | offset of the reading, rad, sign drawn (0.005, 0.05) | (0.001, 0.001) | ``joint`` |
    | ``encoder_stuck`` | none | (0.005, 0.05) | ``joint`` |
    | ``sensor_nan`` | none | (0.001, 0.001) | ``joint``, ``sensor`` (``"encoder"``) |
    | ``torque_glitch`` | offset of the measured torque, N m, sign drawn (20, 200) | (0.001, 0.001) | ``joint`` |
    | ``collision`` | force, N (150, 1000); none for the obstacle | (0.02, 0.05) | ``target``, ``joint`` (arm) |
    | ``drive_fault`` | fraction the drive keeps, in [0, 1) (0, 0.5) | (0.02, 0.1) | ``joint``, ``relative_to`` |

    A fault lasts ``max(1, round(duration / dt))`` control steps (dt = 1 ms). For the obstacle, ``duration`` is how
    long it stays in the path after the platform reaches it.

    A ``drive_fault`` limits its joint's torque to ``size`` times the magnitude of the joint's command at the
    fault's onset (``relative_to="command"``, the default) or times the drive's peak torque (``"peak"``). The first
    sizes the fault on what the motion needs there, so the command exceeds what is left from the first step on and
    the fault is observable at any speed and load; a fraction of the peak torque is often more than a carry at
    3 g needs, and then the fault changes nothing (:func:`is_latent`). Either way the record's ``size`` is the
    fraction of the peak torque kept.

    Attributes:
        kind: One of :data:`FAULT_KINDS`.
        probability: Chance in [0, 1] that an episode gets this fault.
        carry_fraction: The fault starts at a fraction, drawn from this range in [0, 1], of a carry (pick to place)
            drawn uniformly from the episode's carries; an episode without a carry gets no such fault. Default
            :data:`DEFAULT_CARRY_FRACTION` when ``start`` is None.
        start: Or the time (s from the reset) it starts at, drawn from this range; exactly one of the two is set.
        joint: Joint 0..2 of a joint kind, or None to draw it uniformly.
        size: Range of its size (table), or None for the kind's default.
        duration: Range of its duration (s), or None for the kind's default.
        sensor: ``"encoder"`` or ``"torque"``: the reading a ``sensor_nan`` makes NaN (default ``"encoder"``).
        target: What a ``collision`` hits: ``"platform"`` (a force on the platform, its direction uniform on the
            sphere), ``"arm"`` (the same on the upper arm of ``joint``, at its elbow) or ``"obstacle"`` (a body in
            the path that the platform runs into; default ``"platform"``).
        relative_to: What a ``drive_fault``'s size is a fraction of: ``"command"`` (the joint's command at its
            onset; default) or ``"peak"`` (the drive's peak torque).
    """

    kind: str
    probability: float = 1.0
    carry_fraction: tuple[float, float] | None = None
    start: tuple[float, float] | None = None
    joint: int | None = None
    size: tuple[float, float] | None = None
    duration: tuple[float, float] | None = None
    sensor: Literal["encoder", "torque"] | None = None
    target: Literal["platform", "arm", "obstacle"] | None = None
    relative_to: Literal["command", "peak"] | None = None

    def __post_init__(self) -> None:
        kind = self.kind
        if kind not in FAULT_KINDS:
            raise ValueError(f"kind must be one of {list(FAULT_KINDS)}, got {kind!r}")
        require_in("probability", self.probability, 0.0, 1.0)
        if self.start is not None and self.carry_fraction is not None:
            raise ValueError(f"give carry_fraction or start, not both; got {self.carry_fraction!r} and {self.start!r}")
        if kind == "slip" and self.start is not None:
            raise ValueError(f"a slip happens during a carry: give carry_fraction, not start={self.start!r}")
        if self.start is not None:
            self._set("start", require_interval("start", self.start, 0.0, unit="s"))
        else:
            fraction = DEFAULT_CARRY_FRACTION if self.carry_fraction is None else self.carry_fraction
            self._set("carry_fraction", require_interval("carry_fraction", fraction, 0.0, 1.0))
        self._check_choice("sensor", ("encoder", "torque"), kind == "sensor_nan")
        self._check_choice("target", ("platform", "arm", "obstacle"), kind == "collision")
        self._check_choice("relative_to", ("command", "peak"), kind == "drive_fault")
        if self.joint is not None:
            if kind not in JOINT_KINDS and self.target != "arm":
                raise ValueError(f"joint is for {list(JOINT_KINDS)} and an arm collision, not {kind!r}")
            require_count("joint", self.joint, 0, 2)
        size, duration = FAULT_DEFAULTS[kind]
        if self.target == "obstacle":
            size = None
        self._check_range("size", size, _SIZE_UNITS.get(kind, ""))
        self._check_range("duration", duration, "s")
        if kind == "drive_fault" and self.size[1] >= 1.0:
            raise ValueError(f"size of a drive_fault (the torque it keeps) must lie in [0, 1), got {self.size!r}")

    def _set(self, name: str, value: object) -> None:
        object.__setattr__(self, name, value)

    def _check_choice(self, name: str, allowed: tuple[str, ...], used: bool) -> None:
        """A field of one kind: its default there (the first allowed), None elsewhere."""
        value = getattr(self, name)
        if not used:
            if value is not None:
                raise ValueError(f"{name} is not used by kind {self.kind!r}: leave it out, got {value!r}")
        elif value is None:
            self._set(name, allowed[0])
        elif value not in allowed:
            raise ValueError(f"{name} must be one of {list(allowed)}, got {value!r}")

    def _check_range(self, name: str, default: tuple[float, float] | None, unit: str) -> None:
        """A range the kind uses (``default`` not None): checked, or its default; else it must be None."""
        value = getattr(self, name)
        if default is None:
            if value is not None:
                where = f"kind {self.kind!r}" + (f" with target {self.target!r}" if self.target else "")
                raise ValueError(f"{name} is not used by {where}: leave it out, got {value!r}")
            return
        self._set(name, require_interval(name, default if value is None else value, 0.0, unit=unit))

    def draw(self, rng: np.random.Generator, n_carries: int) -> FaultDraw | None:
        """This fault in one episode of ``n_carries`` carries, or None if it does not happen.

        Always takes the same ten numbers from ``rng``, whatever the outcome, so that one spec's draws never
        shift another's.
        """
        occur, when, carry, joint, size, sign, duration = rng.random(7).tolist()
        direction = rng.normal(size=3)
        if occur >= self.probability or (self.start is None and n_carries == 0):
            return None
        low, high = self.start if self.start is not None else self.carry_fraction
        if self.kind in JOINT_KINDS or self.target == "arm":
            joint_index = min(int(joint * 3), 2) if self.joint is None else self.joint
        else:
            joint_index = None
        magnitude = _uniform(self.size, size)
        if self.kind in _SIGNED_KINDS and sign < 0.5:
            magnitude = -magnitude
        seconds = _uniform(self.duration, duration)
        unit = tuple((direction / np.linalg.norm(direction)).tolist()) if self.kind == "collision" else None
        return FaultDraw(
            kind=self.kind,
            carry=None if self.start is not None else min(int(carry * n_carries), n_carries - 1),
            when=low + when * (high - low),
            joint=joint_index,
            size=magnitude,
            duration=seconds,
            direction=unit,
            detail=self.sensor or self.target or self.relative_to or "",
        )


def require_fault_specs(faults: Sequence[FaultSpec]) -> tuple[FaultSpec, ...]:
    """``faults`` as a tuple if it is a sequence of :class:`FaultSpec` with at most one obstacle collision (the scene
    has one obstacle), else ``ValueError``."""
    if isinstance(faults, FaultSpec | str):
        raise ValueError(f"faults must be a sequence of FaultSpec (e.g. [FaultSpec('slip')]), got {faults!r}")
    faults = tuple(faults)
    obstacles = sum(getattr(spec, "target", None) == "obstacle" for spec in faults)
    if obstacles > 1:
        raise ValueError(f"the scene has one obstacle: at most one obstacle collision fault, got {obstacles}")
    for index, spec in enumerate(faults):
        require_instance(f"faults[{index}]", spec, FaultSpec)
    return faults


def _uniform(bounds: tuple[float, float] | None, u: float) -> float:
    """The point at fraction ``u`` of ``bounds``, NaN without bounds."""
    return math.nan if bounds is None else bounds[0] + u * (bounds[1] - bounds[0])


@dataclass(frozen=True)
class FaultDraw:
    """One fault drawn for an episode, before its step is known (internal to the env).

    Attributes:
        kind: One of :data:`FAULT_KINDS`.
        carry: The carry (by pick order) it happens in, or None when it is timed from the reset.
        when: The fraction of that carry, or the time (s) from the reset.
        joint: Joint 0..2, or None.
        size: Signed size in its kind's unit (:class:`InjectedFault`), NaN where it has none.
        duration: Duration (s), NaN for a slip.
        direction: Unit vector of a collision's force, or None.
        detail: ``sensor`` of a sensor_nan, ``target`` of a collision, ``relative_to`` of a drive_fault, else ``""``.
    """

    kind: str
    carry: int | None
    when: float
    joint: int | None
    size: float
    duration: float
    direction: tuple[float, float, float] | None
    detail: str
