"""The fault monitor's detector: checks each observation and returns it clean (the package docstring names the
checks; docs/design.md section 6, "Fault monitor"). Its state is one record, its step one compiled call
(:mod:`controllers.monitor.step`)."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from controllers.base import Observation
from controllers.dynamics import DeltaDynamics
from controllers.estimation import SMOOTHER_LAG, SMOOTHER_WINDOW, JointStateSmoother
from controllers.monitor.compiled import correction_terms
from controllers.monitor.events import DetectedFault
from controllers.monitor.model_check import (
    acceleration_step_response,
    lagged_step_weights,
    samples_to_show,
    torque_step_response,
)
from controllers.monitor.sensor_check import ANGLES_REPLACED, RATES_REPLACED, TORQUES_REPLACED
from controllers.monitor.step import BAD_SHAPE, DETECTED, MONITOR, monitor_step
from controllers.monitor.tuning import (
    ACCELERATION_FACTOR,
    BREAKAWAY_FACTOR,
    INITIAL_RESIDUAL_STD,
    MONITOR_JERK_STD,
    PLANT_STEP_LAG,
    PUSH_SHOWN_SHARE,
    SLOWEST_LAG_FACTOR,
    STUCK_COUNTS,
)
from controllers.payload import ModelCorrections
from delta_env.faults import FAULT_KINDS
from delta_env.sensors import CONTROL_PERIOD, MEASURED_TORQUE_DELAY, require_torque_age
from delta_env.validation import require_in, require_positive

SETTINGS = ("corrections", "charged_coulomb", "breakaway")
"""The fields of the monitor's record that a reset keeps: what :meth:`FaultMonitor.set_corrections` set."""

NO_COMMAND = np.zeros(3)
"""What :func:`~controllers.monitor.step.monitor_step` is given for the command at a sample without one."""


def loop_response(lags: Sequence[float], age: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(hold, keep) per joint of a first-order current loop of time constant ``lags`` (s; 0 for none) over one
    control period whose torque reading is ``age`` periods old: the reading lags the command's change by that much,
    so the loop ran that long towards the command held before, then the rest of the period towards the one held
    since (:func:`~controllers.monitor.compiled.loop_output`).
    hold = exp(-(1 - age) T / lag), keep = exp(-T / lag)."""
    hold = [math.exp(-(1.0 - age) * CONTROL_PERIOD / lag) if lag > 0 else 0.0 for lag in lags]
    keep = [math.exp(-CONTROL_PERIOD / lag) if lag > 0 else 0.0 for lag in lags]
    return np.array(hold), np.array(keep)


class FaultMonitor:
    """Checks each observation for faults and returns it cleaned; see :mod:`controllers.monitor`.

    Everything it remembers is one :data:`~controllers.monitor.step.MONITOR` record, which each sample's one
    compiled call (:func:`~controllers.monitor.step.monitor_step`) updates; its attributes read that record.

    Args:
        dynamics: The identified model (MId+F+R), for the residual and the payload regressor.
        peak_torque: The drive's peak torque (N m).
        drive_lag: The identified current-loop time constant per joint (s), for the torque prediction; None
            uses 1 ms.
        encoder_step: Encoder resolution (rad); None for ideal encoders.
        torque_delay: How much older (s) a torque reading is than its encoder sample: the plant's physics step
            (:data:`~delta_env.sensors.MEASURED_TORQUE_DELAY` by default), for the current loop's prediction and the
            model checks' state at the torque's instant.
        drive_backlash: Whether the drives' gearheads have backlash (as identified): inside the band a rotor, which
            the encoders read, turns against its own inertia alone, beyond the rigid model's bounds of its
            acceleration, so the stuck check does not take a turning joint's repeats against those bounds
            (docs/design.md section 6, "Encoders", case (c)).

    Attributes:
        events: The faults detected since the reset, in time order.
        lag: Readings between a sample and the model's checks at it (the smoother's lag).
    """

    def __init__(
        self,
        dynamics: DeltaDynamics,
        peak_torque: float,
        *,
        drive_lag: Sequence[float] | None = None,
        encoder_step: float | None = None,
        torque_delay: float = MEASURED_TORQUE_DELAY,
        drive_backlash: bool = False,
    ) -> None:
        require_positive("peak_torque", peak_torque, unit="N m")
        require_torque_age(torque_delay)
        age = torque_delay / CONTROL_PERIOD
        lags = (1e-3,) * 3 if drive_lag is None else tuple(drive_lag)
        for lag in lags:
            require_in("drive_lag", lag, 0.0, 0.1, unit="s")
        self.dynamics = dynamics
        self.peak_torque = float(peak_torque)
        step = 0.0 if encoder_step is None else float(encoder_step)
        self.encoder_step = step
        self.lag = SMOOTHER_LAG
        self._state_bytes = np.zeros(1, dtype=MONITOR).view(np.uint8)
        state = self._state_bytes.view(MONITOR)
        self._field = {name: state[name] for name in MONITOR.names}
        """Each field of the record as an array of one element: a view into the record."""
        # the record at a reset: its constants, and the state of an episode's start
        initial = np.zeros(1, dtype=MONITOR)
        arm_inertia = dynamics.parameters.rho1 * dynamics.inertia
        initial["jump_bound"] = ACCELERATION_FACTOR * peak_torque / arm_inertia * CONTROL_PERIOD**2 + 2.0 * step
        initial["stuck_step"] = max(STUCK_COUNTS * step, 1e-9)
        initial["turn_check"] = not drive_backlash
        initial["loop_response"] = loop_response(lags, age)
        initial["slowest_response"] = loop_response([SLOWEST_LAG_FACTOR * lag for lag in lags], age)
        initial["peak_torque"] = self.peak_torque
        smoother = JointStateSmoother(lag=SMOOTHER_LAG, jerk_std=MONITOR_JERK_STD)
        initial["weights"] = smoother.weights
        response = acceleration_step_response(smoother)
        initial["squared_response"] = response**2
        initial["torque_age"] = age
        initial["torque_response"] = torque_step_response(smoother, age)
        initial["acceleration_response"] = response
        initial["step_weights"] = lagged_step_weights(response, PLANT_STEP_LAG)
        initial["onset_samples"] = samples_to_show(response, PUSH_SHOWN_SHARE)
        initial["static_friction"] = dynamics.parameters.coulomb
        initial["reference_before"] = math.nan
        initial["half_count"] = max(0.5 * step, 1e-9)
        initial["sample"] = initial["quiet_until"] = initial["held_since"] = initial["empty_since"] = -1
        initial["held_glitch"] = math.nan
        initial["gripper_changed"] = -SMOOTHER_WINDOW
        initial["scatter"] = INITIAL_RESIDUAL_STD**2
        self._initial = initial
        self.events: list[DetectedFault] = []
        self.reset()
        self.set_corrections(None)

    def reset(self) -> None:
        """Start an episode: no history, no events (the corrections stay)."""
        self.events = []
        for name in MONITOR.names:
            if name not in SETTINGS:
                self._field[name][:] = self._initial[name]

    def _read(self, name: str) -> bool | int | float:
        return self._field[name].item(0)

    @property
    def faulty(self) -> bool:
        """Whether this sample's reading (any joint, encoder or torque) was replaced."""
        return self._read("faulty")

    @property
    def suspect(self) -> bool:
        """Whether an encoder repeats a reading it should not, not yet called stuck (kept out of the checks)."""
        return self._read("suspect")

    @property
    def resynced(self) -> bool:
        """Whether the clean readings stepped back onto an encoder on this sample."""
        return self._read("resynced")

    @property
    def quiet_samples(self) -> int:
        """Readings from this one that the model's equations leave out (0 after a lone replaced reading)."""
        return self._read("quiet_samples")

    @property
    def collision(self) -> bool:
        """Whether an external force is being detected now."""
        return self._read("collision")

    @property
    def slipped(self) -> bool:
        """Whether a slip was detected on this sample."""
        return self._read("slipped")

    @property
    def force(self) -> NDArray[np.float64]:
        """The last estimate of the external force on the platform (N), (3,): while the gripper holds, without its
        part along the payload regressor that a mass the cup can hold explains until the mass held is known."""
        return self._field["force"][0].copy()

    @property
    def collision_samples(self) -> int:
        """Checked samples since the collision evidence began to grow (0 while there is none)."""
        return self._read("collision_samples")

    @property
    def onset_samples(self) -> int:
        """Samples a step of the residual takes, from its first reading, to show in the checked state
        (:data:`~controllers.monitor.tuning.PUSH_SHOWN_SHARE` of it): how long a force's onset may lie under the
        collision check's reference unseen."""
        return self._read("onset_samples")

    @property
    def held_mass(self) -> float | None:
        """The mass (kg) the payload-consistency check believes held, once
        :data:`~controllers.monitor.tuning.SLIP_SETTLE` after the pick has passed and it is known to
        :data:`~controllers.monitor.tuning.HELD_MASS_STD` (0 after a slip); None otherwise."""
        return self._read("held_mass") if self._read("held_known") else None

    def set_corrections(self, corrections: ModelCorrections | None) -> None:
        """Take the model's corrections to this robot (fitted by a payload estimator on its empty moves) into the
        residual from now on; None uses the identified model as it is."""
        dynamics = self.dynamics
        coulomb = dynamics.parameters.coulomb
        self._field["corrections"][0] = correction_terms(
            corrections, dynamics.inertia, dynamics.gravity_amplitude, dynamics.parameters.viscous, coulomb
        )
        # the Coulomb friction the residual charges (the corrections scale the model's friction by 1 + s_i), and
        # the breakaway friction a joint at rest may hold
        scale = 1.0 if corrections is None else 1.0 + np.asarray(corrections.friction_scale, dtype=float)
        charged_coulomb = np.array(coulomb) * scale
        self._field["charged_coulomb"][0] = charged_coulomb
        self._field["breakaway"][0] = BREAKAWAY_FACTOR * np.maximum(charged_coulomb, 0.0)

    def update(
        self, observation: Observation, command: NDArray[np.float64] | None, feedforward_mass: float = 0.0
    ) -> dict[str, NDArray[np.float64]]:
        """Check one observation given the command (N m) sent after the previous one (None at the first) and the
        payload mass (kg) its feedforward held (the controller's estimate; 0 for a controller without one); return
        the clean observation (a new dict; unchanged entries shared)."""
        angles = np.asarray(observation["joint_angles"], dtype=float)
        rates = np.asarray(observation["joint_velocities"], dtype=float)
        torques = np.asarray(observation["joint_torques"], dtype=float)
        self._field["feedforward_mass"][0] = feedforward_mass
        result = monitor_step(
            self._state_bytes,
            self.dynamics.model_constants,
            angles,
            rates,
            torques,
            observation["reference_angles"],
            observation["reference_velocities"],
            observation["reference_accelerations"],
            NO_COMMAND if command is None else np.asarray(command, dtype=float),
            command is not None,
            observation["gripper"].item(0) > 0.5,
            np.asarray(observation["load_angles"], dtype=float) if "load_angles" in observation else angles,
            "load_angles" in observation,
        )
        if result == BAD_SHAPE:
            shapes = {key: np.shape(observation[key]) for key in observation if key != "gripper"}
            raise ValueError(
                f"the readings, references and command must be 3-vectors, got {shapes} and command {command!r}"
            )
        clean = dict(observation)
        if result:
            if result & DETECTED:
                self._take_events()
            rows = self._field["clean"][0]
            if result & ANGLES_REPLACED:
                angles = rows[0].copy()
            if result & RATES_REPLACED:
                rates = rows[1].copy()
            if result & TORQUES_REPLACED:
                torques = rows[2].copy()
        clean["joint_angles"], clean["joint_velocities"], clean["joint_torques"] = angles, rates, torques
        return clean

    def _take_events(self) -> None:
        """Append this sample's detections, as the record holds them, to :attr:`events`."""
        time_s, count = self._read("sample") * CONTROL_PERIOD, self._read("event_count")
        for kind, joint, magnitude in zip(
            self._field["event_kind"][0][:count].tolist(),
            self._field["event_joint"][0][:count].tolist(),
            self._field["event_magnitude"][0][:count].tolist(),
            strict=True,
        ):
            self.events.append(DetectedFault(FAULT_KINDS[kind], time_s, None if joint < 0 else joint, magnitude))
