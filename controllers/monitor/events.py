"""What a fault monitor reports: the detected faults and the capability of reporting them."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol, runtime_checkable


@dataclass(frozen=True)
class DetectedFault:
    """One fault a monitor detected.

    Attributes:
        kind: One of :data:`delta_env.faults.FAULT_KINDS`: what the monitor believes happened.
        time_s: Time (s) from the reset of the observation on which it was detected.
        joint: Joint 0..2 it concerns, or None.
        magnitude: What the monitor measured, in the unit of its kind: the estimated external force (N) for a
            collision, the implausible jump (rad) or torque (N m) of a sensor, the mass (kg) lost in a slip, the
            torque shortfall (N m) of a drive fault; NaN where none applies.
    """

    kind: str
    time_s: float
    joint: int | None = None
    magnitude: float = float("nan")


@runtime_checkable
class ReportsFaults(Protocol):
    """A controller that detects faults: the capability the evaluation records beside the injected truth."""

    @property
    def detected_faults(self) -> Sequence[DetectedFault]:
        """The faults detected since the last reset, in time order."""
        ...
