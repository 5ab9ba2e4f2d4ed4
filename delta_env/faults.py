"""Faults injected into an episode: what a scenario may ask for and the truth of what happened (docs/design.md)."""

from __future__ import annotations

from dataclasses import dataclass

FAULT_KINDS = ("slip", "encoder_glitch", "encoder_stuck", "sensor_nan", "torque_glitch", "collision", "drive_fault")
"""The kinds of fault an episode may carry; detectors report the same names."""


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
            drive keeps (drive_fault), the object's mass in kg (slip); NaN where a kind has none.
        detail: What else identifies it, e.g. ``"encoder"``/``"torque"`` (sensor_nan), ``"platform"``/``"arm"``/
            ``"obstacle"`` (collision).
    """

    kind: str
    start_step: int
    steps: int
    start_s: float
    joint: int | None = None
    size: float = float("nan")
    detail: str = ""
