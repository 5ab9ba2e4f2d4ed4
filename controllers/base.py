"""The controller protocol and the PD joint controller.

A controller sees only the environment's observation (measured joints, the reference, the gripper
state) and nominal parameters; it never reads the plant's truth (the oracle row excepted).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import TYPE_CHECKING, Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from delta_env.validation import require_in

if TYPE_CHECKING:
    from controllers.payload import PayloadEstimator
    from delta_env.config import PhysicalParameters
    from delta_env.trajectories import Trajectory

Observation = Mapping[str, NDArray[np.float64]]
"""The env's observation dict (see ``delta_env.env.DeltaPickPlaceEnv``)."""

DEFAULT_KP = 3000.0
"""Proportional gain (N m/rad) of every controller's joint PD feedback."""

DEFAULT_KD = 60.0
"""Derivative gain (N m s/rad) of every controller's joint PD feedback."""


@runtime_checkable
class Controller(Protocol):
    """A torque controller called once per control step (1 kHz)."""

    name: str

    def reset(self) -> None:
        """Forget all state; called at the start of every episode."""

    def __call__(self, observation: Observation) -> NDArray[np.float64]:
        """Motor torques (N m), shape (3,), for this control step."""


@runtime_checkable
class JointFeedback(Protocol):
    """The feedback part of a controller: the joint servo (:class:`PDController` or
    :class:`controllers.servo.JointServo`), called once per control step."""

    def reset(self) -> None:
        """Forget all state (an integral); called at the start of every episode."""

    def feedback(self, observation: Observation) -> NDArray[np.float64]:
        """The feedback torque (N m), shape (3,), for this control step."""


@runtime_checkable
class EstimatesPayload(Protocol):
    """A controller that estimates the mass it carries: the experiments score and plot its estimate."""

    @property
    def payload_estimate(self) -> float:
        """The payload estimate (kg) used at the last call."""
        ...


def payload_estimate_reader(controller: Controller) -> Callable[[], float]:
    """A function of no arguments giving the controller's payload estimate (kg) at the last call, or 0 if it does not
    estimate the payload (:class:`EstimatesPayload`). The protocol is checked here, once: a runtime protocol check
    costs microseconds, too much for every step at 1 kHz."""
    if isinstance(controller, EstimatesPayload):
        return lambda: float(controller.payload_estimate)
    return lambda: 0.0


@runtime_checkable
class PayloadEstimating(Protocol):
    """A controller that runs a payload estimator the cell reaches: the fault monitor keeps faulty samples out of it,
    an online timing reads it, the tare calibration rebuilds it untared. A registry entry declares it
    (``ControllerEntry.has_estimator``), and building the entry checks the declaration against the controller."""

    @property
    def estimator(self) -> PayloadEstimator | None:
        """Its payload estimator; None when this instance runs none (a model row without the RLS, a wrapper around a
        controller without one)."""
        ...


def payload_estimator_of(controller: Controller) -> PayloadEstimator | None:
    """The payload estimator ``controller`` runs (:class:`PayloadEstimating`), or None."""
    return controller.estimator if isinstance(controller, PayloadEstimating) else None


@runtime_checkable
class Privileged(Protocol):
    """A controller that knows the plant's truth (the oracle bound): the episode runner tells it after each reset,
    and gives it the reference ahead."""

    def set_payload_masses(self, masses: Sequence[float]) -> None:
        """The true masses (kg) of the episode's objects, in pick order."""

    def set_physical_parameters(self, parameters: PhysicalParameters) -> None:
        """The plant's true (e.g. randomized) masses, friction and lag."""

    def set_reference(self, trajectory: Trajectory) -> None:
        """The reference the env follows (``env.trajectory``), ahead of the observation's sample: after each reset
        and whenever the env replaces it (an online retiming, a speed override)."""


@runtime_checkable
class ShapesReference(Protocol):
    """A controller that follows its own reference shaped from the env's (an input shaper,
    :class:`controllers.shaping.ShapedController`): the experiments judge its tracking against that reference."""

    def followed_reference(self, observation: Observation) -> NDArray[np.float64]:
        """The reference angles (rad), shape (3,), it will follow when called with ``observation`` (the next one),
        computed as that call will compute them; nothing is kept."""


class PDController:
    """Joint PD feedback: tau = Kp (th_ref - th) + Kd (thd_ref - thd).

    Args:
        kp: Proportional gain (N m/rad), per joint or scalar.
        kd: Derivative gain (N m s/rad), per joint or scalar.
    """

    name = "PD"

    def __init__(self, kp: float = DEFAULT_KP, kd: float = DEFAULT_KD) -> None:
        self.kp = require_in("kp", kp, 0.0, unit="N m/rad")
        self.kd = require_in("kd", kd, 0.0, unit="N m s/rad")

    def reset(self) -> None:
        """PD has no state."""

    def feedback(self, observation: Observation) -> NDArray[np.float64]:
        """The PD torque (N m), (3,)."""
        # Per joint in Python floats: at three values, cheaper than four NumPy operations.
        kp, kd = self.kp, self.kd
        r1, r2, r3 = observation["reference_angles"].tolist()
        a1, a2, a3 = observation["joint_angles"].tolist()
        v1, v2, v3 = observation["reference_velocities"].tolist()
        w1, w2, w3 = observation["joint_velocities"].tolist()
        return np.array(
            (kp * (r1 - a1) + kd * (v1 - w1), kp * (r2 - a2) + kd * (v2 - w2), kp * (r3 - a3) + kd * (v3 - w3))
        )

    def __call__(self, observation: Observation) -> NDArray[np.float64]:
        return self.feedback(observation)
