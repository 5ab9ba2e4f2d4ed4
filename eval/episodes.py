"""The controllers under evaluation and the episodes they run (DESIGN.md section 8).

Every controller is built from the nominal geometry and masses and the identified parameters only; the
oracle row is the labelled exception that knows the plant and the payloads. An episode is a seeded
``DeltaPickPlaceEnv`` run: the same seed gives every controller the same path and the same objects.
The evaluator itself reads the truth (``info`` and the plant's joint state) to score the run.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from controllers.base import Controller, Observation, PDController
from controllers.dynamics import DeltaDynamics, ModelParameters
from controllers.estimation import smooth_joint_motion
from controllers.feedforward import FeedforwardController, OracleController
from controllers.payload import PayloadEstimator
from controllers.residual import DEFAULT_POLICY_PATH, load_residual_controller
from delta_env.env import DeltaPickPlaceEnv
from delta_env.sensors import CONTROL_PERIOD
from eval import metrics

CONTROLLER_LABELS = {
    "pd": "PD",
    "mkh": "MKH+PD",
    "mid": "MId+PD",
    "mid_f": "MId+F+PD",
    "mid_f_r": "MId+F+R+PD",
    "mid_f_rls": "MId+F+R+RLS+PD",
    "mid_f_rls_ref": "MId+F+R+RLS(ref)+PD",
    "oracle": "Oracle+PD (bound)",
    "residual": "MId+F+R+RLS+PD + residual",
}
"""Controller keys of ``--controllers`` and their labels. ``+R``: the identified model with rod forearms
(``DeltaDynamics(forearm_rods=True)``, beyond the paper), which the payload estimators use. ``mid_f_rls``
estimates the payload on the Kalman-smoothed joint states (the default estimator); ``mid_f_rls_ref`` on the
reference, for comparison. The oracle knows the plant and the true payloads: an upper bound, not a
controller. ``residual`` is the learned residual policy (``controllers.residual``) on the base it was
trained on, rebuilt from the policy file; for the shipped policy that is the ``mid_f_rls`` controller with the
identified parameters and the tare of its training run."""

SMOOTHER_TRIM = 50
"""Samples dropped at each end of a smoothed record (50 ms): the RTS smoother sees one side only there."""

ESTIMATOR_REGRESSORS = {"mid_f_rls": "smoothed", "mid_f_rls_ref": "reference"}
"""The payload estimator variant of each RLS controller key."""

ESTIMATING_KEYS = (*ESTIMATOR_REGRESSORS, "residual")
"""Controllers that estimate the payload, whose carries are scored: the RLS rows (which ``python -m eval`` tares)
and the residual (its base's tare comes with the policy file)."""


@dataclass(frozen=True)
class ControllerSetup:
    """What the controllers may know besides the observation.

    Attributes:
        mid: Identified MId parameters (rho1, rho2).
        mid_f: Identified MId+F parameters (rho1, rho2, friction).
        mid_f_rods: Identified MId+F+R parameters (the model with rod forearms).
        tares: Apparent payload of the empty gripper (kg) per RLS controller key; missing keys use 0.
        pd_gains: (Kp (N m/rad), Kd (N m s/rad)) of every controller's feedback.
        residual_policy: The residual policy file of the ``residual`` row.
    """

    mid: ModelParameters
    mid_f: ModelParameters
    mid_f_rods: ModelParameters
    tares: Mapping[str, float] = field(default_factory=dict)
    pd_gains: tuple[float, float] = (3000.0, 60.0)
    residual_policy: Path = DEFAULT_POLICY_PATH


def build_controller(key: str, setup: ControllerSetup, env: DeltaPickPlaceEnv | None = None) -> Controller:
    """The controller of ``key`` (see :data:`CONTROLLER_LABELS`).

    Args:
        key: Controller key.
        setup: Identified parameters, tares and gains.
        env: Needed for the oracle only, which inverts the env's plant; never given to the others.
    """
    if key not in CONTROLLER_LABELS:
        raise ValueError(f"unknown controller {key!r}; choose from {sorted(CONTROLLER_LABELS)}")
    pd = PDController(*setup.pd_gains)
    if key == "pd":
        return pd
    if key == "residual":
        return load_residual_controller(setup.residual_policy, name=CONTROLLER_LABELS[key])
    if key == "oracle":
        if env is None:
            raise ValueError("the oracle needs the env whose plant it inverts")
        return OracleController(env.plant_config)  # its own feedback gains: see OracleController
    if key in ("mid_f_r", *ESTIMATOR_REGRESSORS):
        dynamics = estimation_model(setup)
    else:
        dynamics = DeltaDynamics.nominal({"mkh": None, "mid": setup.mid}.get(key, setup.mid_f))
    estimator = None
    if key in ESTIMATOR_REGRESSORS:
        estimator = payload_estimator(key, dynamics, setup.tares.get(key, 0.0))
    return FeedforwardController(CONTROLLER_LABELS[key], dynamics, pd=pd, estimator=estimator)


def estimation_model(setup: ControllerSetup) -> DeltaDynamics:
    """MId+F+R: the identified model with rod forearms, of the payload estimators and their feedforward."""
    return DeltaDynamics.nominal(setup.mid_f_rods, forearm_rods=True)


def payload_estimator(key: str, dynamics: DeltaDynamics, tare: float = 0.0) -> PayloadEstimator:
    """The payload estimator of the RLS controller ``key``."""
    return PayloadEstimator(dynamics, regressor=ESTIMATOR_REGRESSORS[key], tare=tare)


@dataclass
class EpisodeRecord:
    """One episode, step by step (N steps), with the truth the evaluator scores it by.

    Attributes:
        tracking_error: Cartesian tracking error (m), ``(N,)``; NaN after a divergence.
        torque: Motor torque that acted (N m), ``(N, 3)``.
        joint_velocity: True joint rates (rad/s), ``(N, 3)``.
        joint_error: True joint angle minus reference (rad), ``(N, 3)``.
        payload_mass: True carried mass (kg) at each observation, ``(N + 1,)``, from the reset on.
        payload_estimate: The controller's payload estimate used at each step (kg), ``(N,)``: the one it
            formed from observation n.
        measured_torque: Observed (noisy) motor torque (N m), ``(N + 1, 3)``, from the reset on.
        encoder_angles: Observed joint angles (rad), ``(N + 1, 3)``, from the reset on.
        pick_indices: Steps at which the gripper closes.
        place_indices: Steps at which it opens.
        masses: Mass of each object (kg).
        diverged: True if the simulation diverged (the episode ended early).
        saturated_steps: Steps whose command exceeded the torque limit.
        observations: The observations from the reset on, if recorded.
    """

    tracking_error: NDArray[np.float64]
    torque: NDArray[np.float64]
    joint_velocity: NDArray[np.float64]
    joint_error: NDArray[np.float64]
    payload_mass: NDArray[np.float64]
    payload_estimate: NDArray[np.float64]
    measured_torque: NDArray[np.float64]
    encoder_angles: NDArray[np.float64]
    pick_indices: NDArray[np.int64]
    place_indices: NDArray[np.int64]
    masses: NDArray[np.float64]
    diverged: bool
    saturated_steps: int
    observations: list[Observation] | None = None

    def metrics(self) -> dict[str, Any]:
        """Scalar metrics of the episode (see :mod:`eval.metrics` for the definitions)."""
        rms, peak = metrics.tracking_metrics(self.tracking_error)
        torque_rms, torque_peak = metrics.torque_metrics(self.torque)
        joint_rms = 1e3 * float(np.sqrt(np.mean(self.joint_error**2)))
        return {
            "tracking_rms_mm": rms,
            "tracking_max_mm": peak,
            "joint_error_rms_mrad": joint_rms,
            "torque_rms_nm": torque_rms,
            "torque_peak_nm": torque_peak,
            "energy_j": metrics.mechanical_energy(self.torque, self.joint_velocity, CONTROL_PERIOD),
            "diverged": self.diverged,
            "saturated_steps": self.saturated_steps,
            "steps": len(self.tracking_error),
        }

    def model_torques(
        self, dynamics: DeltaDynamics, tare: float = 0.0, trim: int = SMOOTHER_TRIM
    ) -> dict[str, NDArray[np.float64]]:
        """Measured torques and the model's torques at the motion recorded, for the paper's Table 2.

        The motion is the RTS-smoothed encoder record (offline, as the paper's recorded data), interpolated
        half a period back to the torque samples, which the drive takes half a period before its encoder
        sample; ``trim`` samples are dropped at each end, where the smoother sees one side only.

        Args:
            dynamics: The model (MId+F).
            tare: The estimator's tare (kg), for the ``"apparent"`` torque.
            trim: Samples dropped at each end.

        Returns:
            ``"measured"``, ``"mp_0"`` (tau0), ``"mp_hat"`` (tau0 + m_hat phi, the estimate of the object
            held, 0 with an empty gripper), ``"apparent"`` (with the tare added, as fed forward), each
            ``(M, 3)`` N m, and ``"time"`` (s), ``"estimate"`` and ``"mass"`` (kg), each ``(M,)``.
        """
        theta, theta_dot, theta_ddot = smooth_joint_motion(self.encoder_angles, CONTROL_PERIOD)
        states = [0.5 * (x[1:] + x[:-1]) for x in (theta, theta_dot, theta_ddot)]
        kept = slice(1 + trim, len(self.encoder_angles) - trim)
        # Estimate used with observation k is payload_estimate[k]; the last observation has none.
        estimate = np.append(self.payload_estimate, self.payload_estimate[-1])[kept]
        mass = self.payload_mass[kept]
        tau0 = dynamics.inverse_dynamics(*(x[kept.start - 1 : kept.stop - 1] for x in states))
        phi = dynamics.payload_regressor(*(x[kept.start - 1 : kept.stop - 1] for x in states))
        return {
            "time": np.arange(len(self.encoder_angles))[kept] * CONTROL_PERIOD,
            "measured": self.measured_torque[kept],
            "mp_0": tau0,
            "mp_hat": tau0 + estimate[:, None] * phi,
            "apparent": tau0 + (estimate + tare)[:, None] * phi,
            "estimate": estimate,
            "mass": mass,
        }

    def carries(self) -> list[metrics.CarryMetrics]:
        """Payload metrics of each completed carry."""
        done = self.place_indices <= len(self.payload_estimate)
        return metrics.carry_metrics(
            self.payload_estimate,
            self.pick_indices[done],
            self.place_indices[done],
            self.masses[done],
            CONTROL_PERIOD,
        )


def run_episode(
    env: DeltaPickPlaceEnv,
    controller: Controller,
    seed: int,
    payload_masses: Sequence[float] | None = None,
    *,
    keep_observations: bool = False,
) -> EpisodeRecord:
    """Run one seeded episode to its end (or divergence) and record it.

    Args:
        env: The environment (not wrapped: the evaluator reads the plant's true joint state).
        controller: Called with each observation; reset here.
        seed: Episode seed.
        payload_masses: Override of the drawn object masses (kg), one per cycle.
        keep_observations: Keep every observation (for the tare calibration).
    """
    options = None if payload_masses is None else {"payload_masses": list(payload_masses)}
    observation, info = env.reset(seed=seed, options=options)
    if isinstance(controller, OracleController):
        controller.set_payload_masses(info["payload_masses"])  # the oracle's privilege
        controller.set_physical_parameters(env.plant.parameters)
    controller.reset()
    plant = env.plant
    estimate = getattr(controller, "payload_estimate", None)
    steps = len(env.trajectory) - 1
    tracking = np.full(steps, math.nan)
    torque, velocity, joint_error = np.zeros((steps, 3)), np.zeros((steps, 3)), np.zeros((steps, 3))
    estimates = np.zeros(steps)
    mass, measured, angles = [0.0], [observation["joint_torques"]], [observation["joint_angles"]]
    observations = [observation] if keep_observations else None
    diverged, saturated, n = False, 0, 0
    for n in range(steps):
        action = controller(observation)
        if estimate is not None:
            estimates[n] = controller.payload_estimate
        observation, _, terminated, truncated, info = env.step(action)
        # Truth at the end of the step, against the reference of that instant (the new observation's).
        tracking[n] = info["tracking_error"]
        torque[n] = info["applied_torque"]
        velocity[n] = plant.joint_velocities()
        joint_error[n] = plant.joint_angles() - observation["reference_angles"]
        mass.append(info["payload_mass"])
        saturated += bool(info["torque_saturated"])
        measured.append(observation["joint_torques"])
        angles.append(observation["joint_angles"])
        if keep_observations:
            observations.append(observation)
        if info["diverged"]:
            diverged = True
            break
        if terminated or truncated:
            break
    length = n + 1
    trajectory = env.trajectory
    return EpisodeRecord(
        tracking_error=tracking[:length],
        torque=torque[:length],
        joint_velocity=velocity[:length],
        joint_error=joint_error[:length],
        payload_mass=np.array(mass),
        payload_estimate=estimates[:length],
        measured_torque=np.array(measured),
        encoder_angles=np.array(angles),
        pick_indices=np.asarray(trajectory.pick_indices),
        place_indices=np.asarray(trajectory.place_indices),
        masses=np.asarray(env.payload_masses, dtype=float),
        diverged=diverged,
        saturated_steps=saturated,
        observations=observations,
    )
