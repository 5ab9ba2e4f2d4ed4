"""What runs the compliance excitation on a compliant plant, and the plant's first mode measured by a frequency
response (docs/design.md section 7, "Compliant drives").

The frequency response (:func:`measure_first_mode`) is a test bench's: the rotors driven about a pose, the
motor-side angles read, the modes found where the response peaks; it judges the model's two-mass modes
(:func:`controllers.compliance.first_mode`) against the plant's.

The excitation holds the robot at rest poses (a soft joint PD on the motor encoders plus MKH's gravity torque, stiff
enough to hold, soft enough that the gearhead mode leaves it stable) and adds a random-phase multisine torque per
drive (:func:`delta_env.excitation.multisine_torques`); the drive's trace records the motor-side encoders, the
load-side encoders where the drives have them and the measured torques at the physics step
(:class:`~controllers.identification.DriveLog`, with ``load_angles`` or without).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from controllers.compliance import DriveCompliance, first_mode_map, joint_space_inertia
from controllers.dynamics import DeltaDynamics
from controllers.identification import ComplianceFit, DriveLog, fit_compliance
from controllers.identification.compliance import FIT_BAND_TOP, SETTLE_PERIODS, fit_motor_side_compliance
from delta_env import kinematics
from delta_env.config import RATED_PAYLOAD, PlantConfig, PlantRealism
from delta_env.env import DIVERGENCE_LOOP_GAP, encoder_steps
from delta_env.excitation import MULTISINE_BAND, MULTISINE_PERIOD, multisine_torques
from delta_env.geometry import DeltaGeometry, DeltaMasses
from delta_env.plant import DeltaPlant
from delta_env.sensors import CONTROL_PERIOD
from delta_env.trajectories import WORKING_HEIGHT
from eval.identification.excitation import robot_model
from eval.processes import run_jobs

COMPLIANCE_POSES = ((0.0, 0.0, WORKING_HEIGHT), (0.3, -0.15, -1.0), (-0.2, 0.35, -0.8))
"""Platform positions (m) where the compliance excitation holds the robot: the work zone's centre, low and off
centre, high and off centre (the first mode moves with the pose)."""

HOLD_KP = 3000.0
"""Stiffness (N m/rad) of the hold's joint PD on the motor encoders: the PD that the default gearhead's mode leaves
stable (docs/measurements.md, "Compliant drives")."""

HOLD_KD = 30.0
"""Damping (N m s/rad) of the hold's joint PD."""

EXCITATION_RMS = 20.0
"""RMS multisine torque per drive (N m): the gearheads deflect by about 1e-4 rad, 20 steps of a 20-bit load encoder."""

EXCITATION_PERIODS = 8
"""Periods recorded per pose after the settling ones (:data:`~controllers.identification.compliance.SETTLE_PERIODS`)."""


@dataclass(frozen=True)
class ComplianceExcitationSpec:
    """One compliance excitation run.

    Attributes:
        seed: Seeds the multisine's phases and the env's reset (its torque noise).
        pose: Platform position (m) held.
        periods: Periods of the multisine, the settling one included.
        rms: RMS multisine torque per drive (N m).
        period: The multisine's period (s).
        band: Its band (Hz).
    """

    seed: int
    pose: tuple[float, float, float] = COMPLIANCE_POSES[0]
    periods: int = SETTLE_PERIODS + EXCITATION_PERIODS
    rms: float = EXCITATION_RMS
    period: float = MULTISINE_PERIOD
    band: tuple[float, float] = MULTISINE_BAND


def run_compliance_excitation(spec: ComplianceExcitationSpec, plant: PlantConfig) -> DriveLog:
    """Hold ``spec.pose`` on the compliant ``plant`` and drive a multisine through its drives; the drive's trace.

    The hold runs at the control period on the motor encoders (quantized, their rate by backward difference, as the
    env's observations give them); the trace records at every physics step, as a servo drive's trace records at its
    current loop's rate: the motor-side and load-side angles quantized by their encoders, the torque the drive
    delivered over the step with the plant's torque noise (one physics step older than the angles it comes with, as
    the env's measured torque), the command held. At the 1 kHz control period a backlash's impacts on a stiff
    gearhead alias into the fitted band (docs/measurements.md, "Compliant drives").

    Returns:
        The trace, a :class:`~controllers.identification.DriveLog` at the plant's physics step with
        ``motor_angles``, and ``load_angles`` where the drives have a load-side encoder.

    Raises:
        ValueError: if the plant has no compliant drives.
        RuntimeError: if the plant diverges.
    """
    compliance = plant.realism.compliance
    if compliance is None:
        raise ValueError("the compliance excitation needs compliant drives (PlantRealism.compliance)")
    load_side = compliance.load_encoder_bits is not None
    motor_step, load_step = encoder_steps(plant.realism)
    theta = kinematics.inverse(plant.geometry, np.asarray(spec.pose, dtype=float))
    samples_per_period = round(spec.period / CONTROL_PERIOD)
    substeps = round(CONTROL_PERIOD / plant.timestep)
    rng = np.random.default_rng(spec.seed)
    excitation = multisine_torques(rng, spec.rms, spec.period, spec.band)
    gravity = robot_model(plant).inverse_dynamics(theta, np.zeros(3), np.zeros(3))
    simulated = DeltaPlant(plant)
    simulated.reset(theta)

    def read(values: tuple[float, float, float], step: float | None) -> NDArray[np.float64]:
        angles = np.array(values)
        return angles if step is None else np.round(angles / step) * step

    rows = spec.periods * samples_per_period * substeps
    motor, load, torque, command = (np.empty((rows, 3)) for _ in range(4))
    previous = read(simulated.rotor_angle_values(), motor_step)
    row = 0
    for step in range(spec.periods * samples_per_period):
        angle = read(simulated.rotor_angle_values(), motor_step)
        rate, previous = (angle - previous) / CONTROL_PERIOD, angle
        action = gravity + HOLD_KP * (theta - angle) - HOLD_KD * rate + excitation[step % samples_per_period]
        for _ in range(substeps):
            simulated.step(action, 1)
            motor[row] = read(simulated.rotor_angle_values(), motor_step)
            if load_side:
                load[row] = read(simulated.joint_angle_values(), load_step)
            torque[row] = simulated.data.actuator_force + rng.normal(0.0, plant.realism.torque_noise_std, 3)
            command[row] = action
            row += 1
        if not simulated.loop_gap() <= DIVERGENCE_LOOP_GAP:
            raise RuntimeError(f"the plant diverged at step {step + 1} of compliance excitation seed {spec.seed}")
    # command k is the one sent with sample k and held until sample k + 1: the action of the step after row k
    return DriveLog(
        motor, torque, command[1:], plant.timestep, motor_angles=motor, load_angles=load if load_side else None
    )


RESPONSE_BAND = (100.0, 450.0)
"""Band (Hz) of the frequency response's multisine: around every gearhead mode (205 to 260 Hz for the SP+ 140,
times sqrt of a stiffness scale), above the hold's loop."""

RESPONSE_PERIOD = 1.0
"""Period (s) of the frequency response's multisine: its lines 1 Hz apart, a fifth of the modes' half-power
bandwidth (2 zeta f, 16 Hz at zeta = 0.035)."""

RESPONSE_SETTLE = 0.5
"""Time (s) before the recorded period: thirteen time constants of the hold's slowest pole (about 37 ms), so the
start's transient leaks no more than 1e-5 of itself into the lines."""

RESPONSE_RMS = 5.0
"""RMS multisine torque per drive (N m)."""

RESPONSE_HOLD_KP = 300.0
"""Stiffness (N m/rad) of the weak PD that keeps the pose during the response (critically damped near 4 Hz); it
shifts the modes by about kp / (2 k) J_a / (J_m + J_a), 0.05 % of the SP+ 140's, and is part of the measured
torque, not of the response."""

RESPONSE_HOLD_KD = 20.0
"""Damping (N m s/rad) of that PD."""


@dataclass(frozen=True)
class MeasuredMode:
    """A mode read off the plant's motor-side frequency response.

    Attributes:
        frequency_hz: Where the largest singular value of the response matrix peaks, the lowest peak (Hz).
        damping_ratio: Half its half-power bandwidth over the peak's frequency (dimensionless); where two modes lie
            within that bandwidth (the lateral pair at home), their joint width.
        frequencies_hz: The response's lines (Hz), ``(L,)``.
        gain: The largest singular value of the response matrix d phi / d tau (rad/(N m)) on each line, ``(L,)``.
    """

    frequency_hz: float
    damping_ratio: float
    frequencies_hz: NDArray[np.float64]
    gain: NDArray[np.float64]


def _response_plant(plant: PlantConfig) -> PlantConfig:
    """``plant`` with its gearheads and arm armature and nothing else of its drives (no friction, lag, noise): the
    linear system whose modes the two-mass model describes."""
    compliance = plant.realism.compliance
    if compliance is None:
        raise ValueError("the frequency response needs a plant with compliant drives (PlantRealism.compliance)")
    realism = replace(PlantRealism.off(), compliance=compliance, armature=plant.realism.armature)
    return replace(plant, realism=realism, payload_body=True)


def measure_first_mode(
    plant: PlantConfig, pose: tuple[float, float, float], payload: float = 0.0, seed: int = 0
) -> MeasuredMode:
    """The plant's first mode about ``pose`` (platform position, m) carrying ``payload`` (kg), from its
    frequency response.

    Without gravity (whose stiffness is negligible against the gearheads') and without the drives' friction, three
    runs drive the rotors with independent random-phase multisines in :data:`RESPONSE_BAND` at every physics step,
    a weak PD on the motor angles keeping the pose; after :data:`RESPONSE_SETTLE`, one period of the applied torques
    U and the motor-side angles Y of the three runs gives the 3 x 3 response H = Y U^-1 on each line. The first mode
    is the lowest peak of H's largest singular value that reaches a third of its highest (parabola through the
    peak's three lines in log gain).

    Raises:
        ValueError: if the plant has no compliant drives or the response has no peak in the band.
    """
    config = _response_plant(plant)
    simulated = DeltaPlant(config)
    simulated.model.opt.gravity[:] = 0.0
    dt = config.timestep
    theta = kinematics.inverse(config.geometry, np.asarray(pose, dtype=float))
    rng = np.random.default_rng(seed)
    samples = round(RESPONSE_PERIOD / dt)
    settle = round(RESPONSE_SETTLE / dt)
    inputs, outputs = [], []
    for _ in range(3):
        excitation = multisine_torques(rng, RESPONSE_RMS, RESPONSE_PERIOD, RESPONSE_BAND, dt)
        simulated.reset(theta)
        if payload > 0.0:
            simulated.place_payload(simulated.suction_cup_position(), payload)
            simulated.attach_payload()
        applied, angles = np.empty((samples, 3)), np.empty((samples, 3))
        for n in range(settle + samples):
            angle = np.array(simulated.rotor_angle_values())
            torque = (
                RESPONSE_HOLD_KP * (theta - angle)
                - RESPONSE_HOLD_KD * np.array(simulated.rotor_velocity_values())
                + excitation[n % samples]
            )
            if n >= settle:
                applied[n - settle], angles[n - settle] = torque, angle
            simulated.step(torque, 1)
        inputs.append(np.fft.rfft(applied, axis=0))
        outputs.append(np.fft.rfft(angles, axis=0))
    frequencies = np.fft.rfftfreq(samples, dt)
    lines = np.flatnonzero((frequencies >= RESPONSE_BAND[0]) & (frequencies <= RESPONSE_BAND[1]))
    u = np.stack(inputs, axis=-1)[lines]  # (L, joint, run)
    y = np.stack(outputs, axis=-1)[lines]
    response = y @ np.linalg.inv(u)
    gain = np.linalg.svd(response, compute_uv=False)[:, 0]
    return _first_peak(frequencies[lines], gain)


def _first_peak(frequencies: NDArray[np.float64], gain: NDArray[np.float64]) -> MeasuredMode:
    """The lowest peak of ``gain`` reaching a third of its highest, with its half-power damping ratio."""
    interior = np.flatnonzero((gain[1:-1] > gain[:-2]) & (gain[1:-1] >= gain[2:])) + 1
    peaks = interior[gain[interior] >= gain.max() / 3.0]
    if peaks.size == 0:
        raise ValueError(f"the response has no peak between {frequencies[0]:g} and {frequencies[-1]:g} Hz")
    peak = int(peaks[0])
    left, middle, right = np.log(gain[peak - 1 : peak + 2])
    offset = 0.5 * (left - right) / (left - 2.0 * middle + right)
    spacing = frequencies[1] - frequencies[0]
    frequency = float(frequencies[peak] + offset * spacing)
    half_power = math.exp(middle - 0.25 * (left - right) * offset) / math.sqrt(2.0)
    lower, upper = gain[peak::-1] < half_power, gain[peak:] < half_power
    if not (lower.any() and upper.any()):
        raise ValueError(
            f"the peak at {frequency:g} Hz does not fall to half power on both sides between {frequencies[0]:g} and "
            f"{frequencies[-1]:g} Hz: its damping ratio cannot be read"
        )
    below = peak - int(np.argmax(lower))
    above = peak + int(np.argmax(upper))

    def crossing(first: int, second: int) -> float:
        """Where the gain crosses half power between two adjacent lines (Hz), linearly."""
        fraction = (half_power - gain[first]) / (gain[second] - gain[first])
        return float(frequencies[first] + fraction * (frequencies[second] - frequencies[first]))

    bandwidth = crossing(above - 1, above) - crossing(below, below + 1)
    return MeasuredMode(frequency, bandwidth / (2.0 * frequency), frequencies, gain)


MAP_HEIGHTS = (-0.8, -0.9, -1.0)
"""Platform heights (m) of the first-mode map's grid: the workspace's upper part, the conveyors, below them."""

MAP_RADII = (0.0, 0.3, 0.6)
"""Distances (m) from the base axis of the map's grid, up to the workspace's 0.7 m rim."""

MAP_AZIMUTHS = 12
"""Azimuths of the map's grid per ring (every 30 degrees: the three-fold symmetry and its mirror lines twice)."""

MAP_PAYLOADS = (0.0, 1.0, 2.0, RATED_PAYLOAD)
"""Payloads (kg) of the map: empty to rated."""


@dataclass(frozen=True, eq=False)
class ModeMap:
    """The model's first mode over a grid of poses and payloads.

    Attributes:
        points: Platform positions (m), ``(N, 3)``.
        payloads: Payloads (kg), ``(P,)``.
        frequency_hz: Natural frequency of the first mode (Hz), ``(N, P)``.
        damping_ratio: Its damping ratio, ``(N, P)``.
        source: Where the drives' compliance comes from (identified, data sheet, scaled gearhead).
    """

    points: NDArray[np.float64]
    payloads: NDArray[np.float64]
    frequency_hz: NDArray[np.float64]
    damping_ratio: NDArray[np.float64]
    source: str

    def summary(self) -> dict[str, object]:
        """JSON-ready extremes per payload: the lowest and highest first mode (Hz) with its point and damping."""
        rows = {}
        for p, payload in enumerate(self.payloads):
            low, high = int(np.argmin(self.frequency_hz[:, p])), int(np.argmax(self.frequency_hz[:, p]))
            rows[f"{payload:g} kg"] = {
                "lowest_hz": float(self.frequency_hz[low, p]),
                "lowest_at_m": self.points[low].tolist(),
                "highest_hz": float(self.frequency_hz[high, p]),
                "highest_at_m": self.points[high].tolist(),
                "damping_ratio_range": [float(self.damping_ratio[:, p].min()), float(self.damping_ratio[:, p].max())],
            }
        return {"source": self.source, "points": len(self.points), "payloads_kg": rows}


def workspace_grid(
    heights: tuple[float, ...] = MAP_HEIGHTS, radii: tuple[float, ...] = MAP_RADII, azimuths: int = MAP_AZIMUTHS
) -> NDArray[np.float64]:
    """Platform positions (m) on rings about the base axis, ``(n, 3)``: one point on the axis per height."""
    points = []
    for height in heights:
        for radius in radii:
            angles = [0.0] if radius == 0.0 else np.linspace(0.0, 2.0 * math.pi, azimuths, endpoint=False)
            points += [(radius * math.cos(a), radius * math.sin(a), height) for a in angles]
    return np.array(points)


def mode_map(
    dynamics: DeltaDynamics,
    compliance: DriveCompliance,
    points: NDArray[np.float64],
    payloads: tuple[float, ...] = MAP_PAYLOADS,
    source: str = "",
) -> ModeMap:
    """The first mode of the two-mass model at ``points`` (m, reachable) and ``payloads`` (kg)."""
    theta = kinematics.inverse(dynamics.geometry, points)
    frequency, damping = first_mode_map(dynamics, compliance, theta, payloads)
    return ModeMap(np.asarray(points, dtype=float), np.asarray(payloads, dtype=float), frequency, damping, source)


def mode_map_lines(modes: ModeMap) -> list[str]:
    """Markdown: per height and radius the first mode's range over the azimuths (Hz) per payload, and its damping."""
    header = " | ".join(f"{payload:g} kg (Hz)" for payload in modes.payloads)
    lines = [
        f"| z (m) | r (m) | {header} | damping ratio |",
        "|---|---|" + "---|" * len(modes.payloads) + "---|",
    ]
    radius = np.round(np.hypot(modes.points[:, 0], modes.points[:, 1]), 6)
    height = np.round(modes.points[:, 2], 6)
    for z in sorted(set(height.tolist()), reverse=True):
        for r in sorted(set(radius[height == z].tolist())):
            ring = (height == z) & (radius == r)
            cells = []
            for p in range(len(modes.payloads)):
                values = modes.frequency_hz[ring, p]
                low, high = f"{values.min():.1f}", f"{values.max():.1f}"
                cells.append(low if low == high else f"{low} to {high}")
            damping = modes.damping_ratio[ring]
            lines.append(f"| {z:.2f} | {r:.2f} | {' | '.join(cells)} | {damping.min():.3f} to {damping.max():.3f} |")
    return lines


_EXCITATION_METHOD = (
    "per compliance excitation pose: a joint PD (kp {kp:g} N m/rad, kd {kd:g} N m s/rad) on the motor encoders plus "
    "MKH's gravity torque holds the pose, a random-phase multisine ({low:g} to {high:g} Hz, {rms:g} N m RMS per "
    "drive, period {period:g} s) drives the rotors, the drive's trace recorded at the physics step; after {settle} "
    "period(s), "
)
"""What both fits' provenance says of the excitation."""

COMPLIANCE_METHOD = _EXCITATION_METHOD + (
    "per joint least squares of the motor "
    "side's tau = J_m phi_ddot + f_v phi_dot + f_c sign(phi_dot) + k (phi - theta - dead band) + c (phi_dot - "
    "theta_dot) + b on the periods' mean (the dead band and the friction's sign: the mean of each period's), rates "
    "from the DFT (lines up to {top:g} Hz), torques {delay:g} s older than their angles, the backlash searched; "
    "standard errors from the spread of the fits to single periods"
)
"""How the compliance was identified (the provenance's ``compliance.method``)."""

MOTOR_SIDE_METHOD = _EXCITATION_METHOD + (
    "from the motor side alone (no load-side encoder): per DFT line up to {top:g} Hz of the periods' mean, "
    "tau = (-w^2 J_m + i w f_v) phi + f_c S(sign phi_dot) - w^2 G (G - w^2 s M)^-1 s M phi with G = k + i w c and M "
    "the datasheet model's arm-side joint inertia (rod forearms) at each pose, k, c and the scale s by nonlinear "
    "least squares (J_m, f_v, f_c linear inside), torques {delay:g} s older than their angles; the backlash not "
    "identified (taken as 0); standard errors from the spread of the fits to single periods"
)
"""How the compliance was identified without a load-side encoder (the provenance's ``compliance.method``)."""


def arm_inertia(geometry: DeltaGeometry, masses: DeltaMasses, theta: NDArray[np.float64]) -> NDArray[np.float64]:
    """The arm-side joint inertia (kg m^2), ``(3, 3)``, at the joint angles ``theta`` (rad) of the datasheet model of
    ``geometry`` (m) and ``masses`` (kg) with rod forearms (the rotor not in it: its rho1 is 1): what the motor-side fit
    scales (docs/design.md section 7, "From the motor side alone")."""
    return joint_space_inertia(DeltaDynamics.of_robot(geometry, masses, forearm_rods=True), theta)


def pose_arm_inertia(plant: PlantConfig, pose: tuple[float, float, float]) -> NDArray[np.float64]:
    """:func:`arm_inertia` of the robot ``plant`` builds at the platform position ``pose`` (m)."""
    return arm_inertia(plant.geometry, plant.masses, kinematics.inverse(plant.geometry, np.asarray(pose, dtype=float)))


def identify_compliance(
    plant: PlantConfig, seed: int, workers: int = 1
) -> tuple[ComplianceFit, tuple[DriveLog, ...], dict]:
    """Run the compliance excitation at :data:`COMPLIANCE_POSES` on ``plant`` (``workers`` processes of the one
    executor, :func:`eval.processes.run_jobs`) and fit its drives: with the load-side angles where the drives have a
    load-side encoder (:func:`~controllers.identification.fit_compliance`), else from the motor side alone on the
    datasheet model's arm (:func:`~controllers.identification.compliance.fit_motor_side_compliance`,
    :func:`pose_arm_inertia`).

    Returns:
        The fit, the logs and the provenance (method, poses, seeds, the fit's summary).

    Raises:
        ValueError: without compliant drives.
    """
    seeds = [int(s) for s in np.random.SeedSequence([seed, 36]).generate_state(len(COMPLIANCE_POSES))]
    specs = [ComplianceExcitationSpec(seed=s, pose=pose) for s, pose in zip(seeds, COMPLIANCE_POSES, strict=True)]
    logs = tuple(run_jobs(functools.partial(run_compliance_excitation, plant=plant), specs, workers=workers))
    if all(log.load_angles is not None for log in logs):
        fit, method = fit_compliance(logs, torque_delay=plant.timestep), COMPLIANCE_METHOD
    else:
        inertias = [pose_arm_inertia(plant, spec.pose) for spec in specs]
        fit = fit_motor_side_compliance(logs, inertias, torque_delay=plant.timestep)
        method = MOTOR_SIDE_METHOD
    spec = specs[0]
    method = method.format(
        kp=HOLD_KP,
        kd=HOLD_KD,
        low=spec.band[0],
        high=spec.band[1],
        rms=spec.rms,
        period=spec.period,
        settle=SETTLE_PERIODS,
        top=FIT_BAND_TOP,
        delay=plant.timestep,
    )
    provenance = {
        "method": method,
        "poses_m": [list(pose) for pose in COMPLIANCE_POSES],
        "seeds": seeds,
        "fit": fit.summary(),
    }
    return fit, logs, provenance
