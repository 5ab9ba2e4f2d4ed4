"""The one closed-loop episode runner of every experiment, and what it records (docs/design.md section 8).

An episode is a seeded ``DeltaPickPlaceEnv`` run of a :class:`~controllers.base.Controller`: the same seed
gives every controller the same path, the same objects and the same sensor noise. :func:`run_episode`
runs the comparison's episodes, the tare calibrations, the residual policy's scores and the
identification's excitation runs. The runner reads the truth (``info`` and the plant's joint state) to
score the run; the controller sees only the observations.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from controllers.base import Controller, EstimatesPayload, Observation, Privileged, ShapesReference
from controllers.dynamics import DeltaDynamics
from controllers.identification import TRIM_SAMPLES, motion_at_torque_samples
from controllers.monitor import DetectedFault, MonitoredController, ReportsFaults
from controllers.payload_timing import EstimatingController
from delta_env import kinematics
from delta_env.env import DeltaPickPlaceEnv
from delta_env.faults import InjectedFault
from delta_env.release import Settle
from delta_env.sensors import CONTROL_PERIOD
from delta_env.trajectories import Trajectory
from eval import metrics
from eval.fault_scores import EpisodeFaults, fault_metrics, match_faults


@dataclass
class EpisodeRecord:
    """One episode, step by step (N steps), with the truth the evaluator scores it by.

    Attributes:
        tracking_error: Cartesian tracking error (m), ``(N,)``, from the reference the controller follows (the env's,
            or the one it shapes from it: :class:`~controllers.base.ShapesReference`); NaN after a divergence.
        torque: Motor torque that acted (N m), ``(N, 3)``.
        command: Command the drive held over each step (N m), ``(N, 3)``: the action within the torque limit.
        joint_velocity: True joint rates (rad/s), ``(N, 3)``.
        joint_error: True joint angle minus the reference the controller follows (rad), ``(N, 3)``.
        payload_mass: True carried mass (kg) at each observation, ``(N + 1,)``, from the reset on.
        payload_estimate: The controller's payload estimate used at each step (kg), ``(N,)``: the one it
            formed from observation n.
        measured_torque: Observed (noisy) motor torque (N m), ``(N + 1, 3)``, from the reset on.
        encoder_angles: Observed joint angles (rad), ``(N + 1, 3)``, from the reset on.
        pick_indices: Steps at which the gripper closes.
        place_indices: Steps at which it opens.
        masses: Mass of each object (kg).
        diverged: True if the simulation diverged (the episode ended early).
        saturated_steps: Steps whose command the drive clipped (its peak torque or its torque-speed envelope).
        max_loop_gap: Largest loop-closure gap of the plant over the steps (m); inf if it was not finite.
        platform_position: True platform position at the end of each step (m), ``(N, 3)``; NaN after a
            divergence. Step n ends at reference sample n + 1.
        reference: The reference the episode followed (samples ``0 .. N`` and on, if it ended early).
        peak_torque: The drive's peak torque (N m).
        rated_torque: The drive's rated continuous torque (N m).
        observations: The observations from the reset on, if recorded.
        speed_exceeded_steps: Steps after which some joint was beyond the drive's maximum speed.
        thermal_exceeded: True if some joint's RMS torque over a full thermal window exceeded the drive's rated
            torque.
        speed_override: The last speed override a monitored controller's reaction asked the cell for (1: none).
        stopped: True if the episode ended at rest after a stop (``info["stopped"]``).
        injected_faults: The truth of the faults injected into the episode (``env.injected_faults`` at its end),
            in the order they started.
        detected_faults: The faults the controller detected (its ``detected_faults`` at the episode's end, if it
            :class:`~controllers.monitor.ReportsFaults`; else none), in time order. :mod:`eval.fault_scores` matches
            them to the injected ones.
        robot_contacts: Pairs of robot links (or a link and the base) that touched during the episode, each with its
            deepest penetration (m): ``plant.robot_contacts`` at its end, empty unless the plant was built with
            ``PlantConfig.collisions``.
        settles: The waits for the in-position signal at the pick and place points (``env.settles`` at its end;
            none with the timed release), in order.
    """

    tracking_error: NDArray[np.float64]
    torque: NDArray[np.float64]
    command: NDArray[np.float64]
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
    max_loop_gap: float
    platform_position: NDArray[np.float64]
    reference: Trajectory
    peak_torque: float
    rated_torque: float
    observations: list[Observation] | None = None
    speed_exceeded_steps: int = 0
    thermal_exceeded: bool = False
    speed_override: float = 1.0
    stopped: bool = False
    injected_faults: list[InjectedFault] = field(default_factory=list)
    detected_faults: list[DetectedFault] = field(default_factory=list)
    robot_contacts: dict[tuple[str, str], float] = field(default_factory=dict)
    settles: list[Settle] = field(default_factory=list)

    def metrics(self) -> dict[str, Any]:
        """Scalar metrics of the episode (see :mod:`eval.metrics` for the definitions), and its faults'
        (:data:`eval.fault_scores.FAULT_METRICS`: ``faults_injected``, ``faults_detected``, ...)."""
        rms, peak = metrics.tracking_metrics(self.tracking_error)
        torque_rms, torque_peak = metrics.torque_metrics(self.torque)
        joint_rms = 1e3 * float(np.sqrt(np.mean(self.joint_error**2)))
        reference = self.reference
        cycle_times = metrics.cycle_times(reference.xyz_dot, self.pick_indices, reference.dt)
        place_errors = self.place_errors()
        # Step n ends at reference sample n + 1: the path is searched around that sample.
        steps = len(self.platform_position)
        deviation_rms, deviation_max = metrics.path_deviation(
            self.platform_position, reference.xyz, np.arange(1, steps + 1)
        )
        peak_ratio, rms_ratio = metrics.torque_ratios(self.torque, self.peak_torque, self.rated_torque)
        settle_mean, settle_max, settle_timeouts = metrics.settle_metrics(
            [settle.settle_time for settle in self.settles], [settle.timed_out for settle in self.settles]
        )
        residual = self.residual_vibrations()
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
            "speed_exceeded_steps": self.speed_exceeded_steps,
            "thermal_exceeded": self.thermal_exceeded,
            "speed_override": self.speed_override,
            "stopped": self.stopped,
            "picks_per_min": metrics.picks_per_min(reference.xyz_dot, self.pick_indices, reference.dt),
            "cycle_time_mean_s": float(np.mean(cycle_times)) if cycle_times.size else math.nan,
            "cycle_time_max_s": float(np.max(cycle_times)) if cycle_times.size else math.nan,
            "place_error_mean_mm": float(np.mean(place_errors)) if place_errors.size else math.nan,
            "place_error_max_mm": float(np.max(place_errors)) if place_errors.size else math.nan,
            "settle_time_mean_ms": settle_mean,
            "settle_time_max_ms": settle_max,
            "settle_timeouts": settle_timeouts,
            "residual_vibration_mean_um": float(np.mean(residual)) if residual.size else math.nan,
            "residual_vibration_max_um": float(np.max(residual)) if residual.size else math.nan,
            "path_deviation_rms_mm": deviation_rms,
            "path_deviation_max_mm": deviation_max,
            "envelope_violations": metrics.envelope_violations(self.saturated_steps, self.speed_exceeded_steps),
            "peak_torque_ratio": peak_ratio,
            "rms_torque_ratio": rms_ratio,
            "thermal_margin": 1.0 - rms_ratio,
            **fault_metrics(self.faults()),
        }

    def faults(self) -> EpisodeFaults:
        """The episode's detections matched to its injected faults (:func:`eval.fault_scores.match_faults`)."""
        return match_faults(self.injected_faults, self.detected_faults)

    def place_errors(self) -> NDArray[np.float64]:
        """Distance (mm) of the platform from the place point when the gripper opened, per object released before
        the episode ended: the gripper opens as step ``place_indices[k] - 1`` ends, at that reference sample."""
        released = self.place_indices[(self.place_indices >= 1) & (self.place_indices <= len(self.platform_position))]
        errors = metrics.place_errors(self.platform_position[released - 1], self.reference.xyz[released])
        return errors[np.isfinite(errors)]  # a release on the step that diverged is no placement

    def residual_vibrations(self) -> NDArray[np.float64]:
        """The residual vibration at each place the cell waited at (um): the peak to peak of the platform's true
        position over :data:`eval.metrics.RESIDUAL_WINDOW` from the cell's in-position signal (or its time-out), the
        start of the air activation, cut at the release; a place whose window holds no sample before the episode
        ended, or a non-finite position, is left out."""
        dt = self.reference.dt
        window = round(metrics.RESIDUAL_WINDOW / dt)
        steps = len(self.platform_position)
        vibrations = []
        for settle in self.settles:
            if settle.kind != "place" or settle.cycle >= len(self.place_indices):
                continue
            start = settle.arrival_step + round(settle.settle_time / dt)  # reference sample s: as step s - 1 ends
            end = min(start + window, int(self.place_indices[settle.cycle]), steps + 1)
            if end > start:
                vibrations.append(1e6 * metrics.peak_to_peak(self.platform_position[start - 1 : end - 1]))
        values = np.array(vibrations, dtype=float)
        return values[np.isfinite(values)]

    def model_torques(
        self, dynamics: DeltaDynamics, tare: float = 0.0, trim: int = TRIM_SAMPLES
    ) -> dict[str, NDArray[np.float64]]:
        """Measured torques and the model's torques at the motion recorded, for the paper's Table 2.

        The motion is the RTS-smoothed encoder record (offline, as the paper's recorded data) at the instants
        the torques were measured (:func:`controllers.identification.motion_at_torque_samples`), as in the
        identification; ``trim`` samples are dropped at each end, where the smoother sees one side only.

        Args:
            dynamics: The model (MId+F+R).
            tare: The estimator's tare (kg), for the ``"apparent"`` torque.
            trim: Samples dropped at each end.

        Returns:
            ``"measured"``, ``"mp_0"`` (tau0), ``"mp_hat"`` (tau0 + m_hat phi, the estimate of the object
            held, 0 with an empty gripper), ``"apparent"`` (with the tare added, as fed forward), each
            ``(M, 3)`` N m, and ``"time"`` (s), ``"estimate"`` and ``"mass"`` (kg), each ``(M,)``.
        """
        motion = motion_at_torque_samples(self.encoder_angles, CONTROL_PERIOD)
        kept = slice(trim, len(self.encoder_angles) - trim)
        # Estimate used with observation k is payload_estimate[k]; the last observation has none.
        estimate = np.append(self.payload_estimate, self.payload_estimate[-1])[kept]
        states = [x[kept] for x in motion]
        tau0, phi = dynamics.inverse_dynamics(*states), dynamics.payload_regressor(*states)
        return {
            "time": np.arange(len(self.encoder_angles))[kept] * CONTROL_PERIOD,
            "measured": self.measured_torque[kept],
            "mp_0": tau0,
            "mp_hat": tau0 + estimate[:, None] * phi,
            "apparent": tau0 + (estimate + tare)[:, None] * phi,
            "estimate": estimate,
            "mass": self.payload_mass[kept],
        }

    def carries(self) -> list[metrics.CarryMetrics]:
        """Payload metrics of each completed carry whose object did not slip (an injected slip)."""
        # a stop may leave the last pick without its place; a carry whose object slipped weighs nothing known
        carried = min(len(self.pick_indices), len(self.place_indices))
        picks, places, masses = self.pick_indices[:carried], self.place_indices[:carried], self.masses[:carried]
        slips = [fault.start_step for fault in self.injected_faults if fault.kind == "slip"]
        intact = np.array(
            [not any(pick <= slip < place for slip in slips) for pick, place in zip(picks, places, strict=True)],
            dtype=bool,
        )
        done = (places <= len(self.payload_estimate)) & intact
        return metrics.carry_metrics(self.payload_estimate, picks[done], places[done], masses[done], CONTROL_PERIOD)


def run_episode(
    env: DeltaPickPlaceEnv,
    controller: Controller,
    seed: int,
    payload_masses: Sequence[float] | None = None,
    *,
    reference: Trajectory | None = None,
    keep_observations: bool = False,
    after_step: Callable[[int], None] | None = None,
) -> EpisodeRecord:
    """Run one seeded episode to its end (or divergence) and record it.

    Args:
        env: The environment (not wrapped: the evaluator reads the plant's true joint state).
        controller: Called with each observation; reset here.
        seed: Episode seed.
        payload_masses: Override of the drawn object masses (kg), one per cycle.
        reference: A reference to follow instead of the env's pick-and-place cycles (e.g. an excitation).
        keep_observations: Keep every observation (for the tare calibration).
        after_step: Called with 0 after the reset and with n after step n: a view of the episode that reads ``env``
            and changes nothing (:func:`eval.comparison.video.record_episode` renders its frames).
    """
    options: dict[str, Any] = {}
    if payload_masses is not None:
        options["payload_masses"] = list(payload_masses)
    if reference is not None:
        options["reference"] = reference
    observation, info = env.reset(seed=seed, options=options or None)
    # the oracle's privilege and a monitor's reactions, also when an online timing runs the cell's estimator beside it
    wrappers = []  # the wrappers around the controller proper: a fault monitor, the cell's estimator beside it
    privileged = controller
    while isinstance(privileged, MonitoredController | EstimatingController):
        wrappers.append(privileged)
        privileged = privileged.controller
    inner = next((wrapper for wrapper in wrappers if isinstance(wrapper, MonitoredController)), controller)
    knows_reference = isinstance(privileged, Privileged)
    shaping = privileged if isinstance(privileged, ShapesReference) else None
    if knows_reference:
        privileged.set_payload_masses(info["payload_masses"])
        privileged.set_physical_parameters(env.plant.parameters)
        privileged.set_reference(env.trajectory)
    followed = env.trajectory
    controller.reset()
    plant = env.plant
    estimates_payload = isinstance(controller, EstimatesPayload)
    reacts, speed = isinstance(inner, MonitoredController), 1.0
    # Gathered step by step as Python values (the 1 kHz loop) and stacked once the episode is over; each step's
    # truth is taken at its end, against the reference of that instant (the new observation's).
    tracking: list[float] = []
    loop_gaps: list[float] = []
    estimates: list[float] = []
    torque: list[float] = []  # three floats per step, as are the next four
    command: list[float] = []
    platform: list[float] = []
    true_angles: list[float] = []
    true_velocities: list[float] = []
    reference_angles: list[NDArray[np.float64]] = []  # the reference the controller follows, at each step's end
    saturated, speed_exceeded, thermal_exceeded = 0, 0, False
    mass, measured, angles = [0.0], [observation["joint_torques"]], [observation["joint_angles"]]
    observations = [observation] if keep_observations else None
    if after_step is not None:
        after_step(0)
    while True:
        action = controller(observation)
        if estimates_payload:
            estimates.append(controller.payload_estimate)
        if reacts and inner.requested_speed != speed:
            speed = inner.requested_speed  # a monitored controller's reaction to a fault: the cell's override
            env.override_speed(speed)
        observation, _, terminated, truncated, info = env.step(action)
        if knows_reference and env.trajectory is not followed:  # retimed or overridden: the new reference ahead
            followed = env.trajectory
            privileged.set_reference(followed)
        tracking.append(info["tracking_error"])
        loop_gaps.append(info["loop_gap"])
        torque.extend(info["applied_torque"].tolist())
        command.extend(info["torque_command"].tolist())
        platform.extend(info["platform_position"].tolist())
        true_angles.extend(plant.joint_angle_values())
        true_velocities.extend(plant.joint_velocity_values())
        reference_angles.append(
            observation["reference_angles"] if shaping is None else shaping.followed_reference(observation)
        )
        mass.append(info["payload_mass"])
        saturated += info["torque_saturated"]
        speed_exceeded += info["speed_exceeded"]
        thermal_exceeded = thermal_exceeded or info["thermal_exceeded"]
        measured.append(observation["joint_torques"])
        angles.append(observation["joint_angles"])
        if keep_observations:
            observations.append(observation)
        if after_step is not None:
            after_step(len(tracking))
        if terminated or truncated:
            break
    diverged = info["diverged"]
    platform_position = _rows(platform)
    if diverged:
        platform_position[-1] = math.nan  # the state the simulation diverged to is no position
    gaps = np.array(loop_gaps)
    trajectory = env.trajectory
    drive = env.plant_config.drive
    followed = np.array(reference_angles)
    tracking_error = np.array(tracking)
    if shaping is not None:  # judged against the reference it follows, on the geometry the env's is planned on
        tracking_error = np.linalg.norm(
            platform_position - kinematics.forward(env.plant_config.geometry, followed), axis=1
        )
    return EpisodeRecord(
        tracking_error=tracking_error,
        torque=_rows(torque),
        command=_rows(command),
        joint_velocity=_rows(true_velocities),
        joint_error=_rows(true_angles) - followed,
        payload_mass=np.array(mass),
        payload_estimate=np.array(estimates, dtype=float) if estimates_payload else np.zeros(len(tracking)),
        measured_torque=np.array(measured),
        encoder_angles=np.array(angles),
        pick_indices=np.asarray(trajectory.pick_indices),
        place_indices=np.asarray(trajectory.place_indices),
        masses=np.asarray(env.payload_masses, dtype=float),
        diverged=diverged,
        saturated_steps=saturated,
        max_loop_gap=float(gaps.max()) if np.isfinite(gaps).all() else math.inf,
        platform_position=platform_position,
        reference=trajectory,
        peak_torque=drive.peak_torque,
        rated_torque=drive.rated_torque,
        observations=observations,
        speed_exceeded_steps=speed_exceeded,
        thermal_exceeded=thermal_exceeded,
        speed_override=speed,
        stopped=bool(info["stopped"]),
        injected_faults=list(env.injected_faults),
        detected_faults=list(inner.detected_faults) if isinstance(inner, ReportsFaults) else [],
        robot_contacts=plant.robot_contacts,
        settles=list(env.settles),
    )


def _rows(values: list[float]) -> NDArray[np.float64]:
    """Three floats per step, appended in order, as an ``(N, 3)`` array."""
    return np.array(values).reshape(-1, 3)
