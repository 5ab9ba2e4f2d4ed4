"""DeltaPickPlace-v0: a Delta robot picks objects of unknown mass and places them (docs/design.md section 5)."""

from __future__ import annotations

import dataclasses
import math
import os
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Literal

import gymnasium as gym
import mujoco
import numpy as np
from gymnasium import spaces
from numpy.typing import NDArray

from delta_env.config import (
    DEFAULT_PAYLOAD_SIZE,
    MAX_PAYLOAD_MASS,
    SUCTION_CUP_OFFSET,
    PlantConfig,
    PlantRealism,
    RandomizationRanges,
)
from delta_env.drive import DriveMonitor
from delta_env.fault_injection import FaultInjector
from delta_env.faults import FaultSpec, InjectedFault, require_fault_specs
from delta_env.measurement import Sensors, observation_space
from delta_env.plant import DeltaPlant
from delta_env.reference import EpisodeReference
from delta_env.release import InPositionRelease, Settle
from delta_env.scenario import PickPlaceTask, Scenario, resolve_scenario
from delta_env.scene import RENDER_SIZE
from delta_env.sensors import CONTROL_PERIOD, control_substeps, encoder_resolution
from delta_env.timing import MoveTiming
from delta_env.trajectories import Trajectory
from delta_env.validation import require_count, require_in, require_instance, require_torques

DIVERGENCE_LOOP_GAP = 1e-3
"""Loop gap (m) beyond which the simulation counts as diverged."""


def encoder_steps(realism: PlantRealism) -> tuple[float | None, float | None]:
    """The resolutions (rad, at the joint) of the drives' encoders and of the load encoder, None where there is none.

    The drives' encoders are on the motor side: on a compliant drive (``realism.compliance``) the motor shaft's
    encoder, whose step at the joint is its own over the gear ratio. None for exact drive encoders. The load
    encoder, only a compliant drive's with ``load_encoder_bits``, reads the arm.
    """
    compliance = realism.compliance
    bits = realism.encoder_bits
    step = None if bits is None else encoder_resolution(bits)
    if compliance is None:
        return step, None
    motor_step = None if step is None else step / compliance.gear_ratio
    load_bits = compliance.load_encoder_bits
    return motor_step, None if load_bits is None else encoder_resolution(load_bits)


DEFAULT_CAMERA = {
    "distance": 2.4,
    "azimuth": 135.0,
    "elevation": -20.0,
    "lookat": np.array([0.0, 0.0, -0.55]),
}


@dataclass(frozen=True)
class RewardWeights:
    """Weights of the reward -(tracking * |e|^2 + torque * |tau|^2).

    Attributes:
        tracking: Weight per mm^2 of squared Cartesian tracking error e (mm).
        torque: Weight per (N m)^2 of squared motor torque.
    """

    tracking: float = 1.0
    torque: float = 1e-5


DISPLAY_VARIABLES = ("DISPLAY", "WAYLAND_DISPLAY")
"""Environment variables through which a window system is reached on Linux."""


def _repeats(task: PickPlaceTask, name: str, value: object) -> bool:
    """Whether ``value`` repeats ``task``'s field ``name`` (same type, equal): an override that changes nothing."""
    current = getattr(task, name)
    return type(value) is type(current) and value == current


def require_display() -> None:
    """Refuse ``render_mode="human"`` where no window can open (Linux without a display), which would otherwise end
    the process in a C assertion of GLFW.

    Raises:
        RuntimeError: naming the missing variables and the headless alternative.
    """
    if sys.platform.startswith("linux") and not any(os.environ.get(name) for name in DISPLAY_VARIABLES):
        raise RuntimeError(
            "render_mode='human' opens a window, but this machine has no display (neither DISPLAY nor "
            "WAYLAND_DISPLAY is set); render headless with render_mode='rgb_array' and MUJOCO_GL=egl (or osmesa)"
        )


class DeltaPickPlaceEnv(gym.Env[dict[str, NDArray[np.float64]], NDArray[np.float64]]):
    """A 3-DOF Delta robot in MuJoCo picks and places objects whose masses it is never told.

    A summary; docs/design.md section 5 ("Environment", "Speed override", "Faults") is the full reference: the
    drive's envelope, every ``info`` key with its unit, the starting state, timing and what each fault does.

    ## Description
    Each episode is a sequence of pick-and-place cycles along a C2 reference path (lift 25 mm,
    travel, descend 25 mm, dwell, and back to the next pick point). At each pick point a suction
    gripper (a weld) attaches a new object whose mass is drawn at random; it is released at the
    place point. By default (``release="in_position"``) the reference holds at rest at each point until the cell
    judges the platform in position from its encoders (the arms' load encoders where fitted), then the air
    activation runs (35 ms) and the gripper switches at its end (:mod:`delta_env.release`); ``release="timed"``
    switches it mid-way through a 0.1 s dwell.
    The plant is the ``realistic`` MuJoCo model by default: true parallelograms, distributed masses, armature,
    friction, torque ripple and actuator lag that no analytical model in this project knows. One step is one
    control period, :attr:`dt` = 1 ms (two 0.5 ms physics steps).

    ## Action Space
    ``Box(-peak, peak, (3,), float64)``: motor torques (N m), peak 400 N m by default (``plant.drive``), clipped
    to the drive's torque-speed envelope at each step (``info["torque_saturated"]``); NaN or inf raises ValueError.

    ## Observation Space
    A ``Dict`` of float64 arrays, all measured or known to a real drive (never the payload mass):

    | key | shape | unit | meaning |
    |---|---|---|---|
    | ``joint_angles`` | (3,) | rad | encoder angles (quantized, 17 bit by default; compliant drives: motor shaft) |
    | ``joint_velocities`` | (3,) | rad/s | encoder backward difference over one control period |
    | ``joint_torques`` | (3,) | N m | measured motor torque (actuator output plus white noise) |
    | ``reference_angles`` | (3,) | rad | reference theta of this step |
    | ``reference_velocities`` | (3,) | rad/s | reference theta_dot of this step |
    | ``reference_accelerations`` | (3,) | rad/s^2 | reference theta_ddot of this step |
    | ``gripper`` | (1,) | - | 1 while the suction gripper holds an object |
    | ``load_angles`` | (3,) | rad | load-side encoder on the arms: compliant drives with ``load_encoder_bits`` only |

    ## Rewards
    ``reward = -(w_tracking * |e|^2 + w_torque * |tau|^2)`` with e the Cartesian tracking error
    in mm and tau the commanded (saturated) torque in N m; defaults w_tracking = 1 per mm^2 and
    w_torque = 1e-5 per (N m)^2 (:class:`RewardWeights`). The terms are in ``info["reward_tracking"]``
    and ``info["reward_torque"]``.

    ## Starting State
    At rest at a place point (``start="place"``) or the first pick point (``start="pick"``), the gripper empty.
    All randomness of an episode comes from the ``seed`` of :meth:`reset`; its ``options`` are documented there.

    ## Episode End
    Truncation at the end of the reference (``n_cycles`` cycles, or a stop's hold: ``info["stopped"]``);
    termination when the simulation diverges (``info["diverged"]``, reward ``-divergence_penalty``). Stepping
    after either raises ``RuntimeError``: call :meth:`reset`.

    ## Info
    Truth for evaluation, never for controllers: ``payload_mass``, ``platform_position``, ``reference_position``,
    ``tracking_error``, ``loop_gap``, ``torque_command``, ``applied_torque``, ``cycle``, ``diverged``,
    ``torque_saturated``, ``faults``, ``reward_tracking``, ``reward_torque``, ``speed_override``, ``stopped``, the
    release's ``in_position`` (the cell's signal, from its encoders) and ``settle_timeout``, and
    the drive's limits ``torque_margin``, ``speed_margin``, ``speed_exceeded``, ``thermal_rms``,
    ``thermal_margin``, ``thermal_exceeded`` (units and meanings: docs/design.md section 5).

    ## Arguments
    | parameter | type | default | description |
    |---|---|---|---|
    | ``plant`` | PlantConfig, None | None = ``PlantConfig()`` | plant variant, realism, masses, geometry, drive |
    | ``n_cycles`` | int | 3 | pick-and-place cycles per episode, >= 1 |
    | ``cycle`` | str | ``"conveyor"`` | random conveyor points, or ``"standard"`` 25/305/25 mm |
    | ``start`` | str | ``"place"`` | at rest at a place point, then an empty move to the first pick; or ``"pick"`` |
    | ``peak_acceleration`` | float | 3 g = 29.43 | peak Cartesian acceleration of the reference (m/s^2), at most 30 g |
    | ``payload_mass_range`` | (float, float) | (0.0, 4.0) | object masses drawn from U[low, high] (kg), in [0, 20] |
    | ``domain_randomization`` | RandomizationRanges, None | None (off) | per-episode perturbation of the plant |
    | ``reward_weights`` | RewardWeights, None | None = ``RewardWeights()`` | weights of the reward terms |
    | ``divergence_penalty`` | float | 1000.0 | reward (negated) of the step on which the simulation diverges |
    | ``render_mode`` | str, None | None | ``"rgb_array"``, ``"human"`` or None |
    | ``width``, ``height`` | int | 960, 720 | render size (pixels, within the model's 1280 x 720 offscreen buffer) |
    | ``scenario`` | str, path, Scenario, None | None = ``nominal`` | preset name, scenario TOML file or value |
    | ``timing`` | MoveTiming, None | None | times every move instead of ``peak_acceleration`` (``env.timing``) |
    | ``faults`` | sequence of FaultSpec, None | None = the scenario's (none) | faults injected into the episodes |
    | ``release`` | str, None | ``"in_position"`` | gripper switches once in position, or ``"timed"`` mid-dwell |
    | ``in_position_window`` | float, None | 5e-5 | in-position window (m), in (0, 0.01] |
    | ``in_position_time`` | float, None | 0.003 | time the window must hold (s), in [0.001, 10] |
    | ``air_activation`` | float, None | 0.035 | rest from in position to the gripper's switch (s), whole ms |
    | ``settle_timeout`` | float, None | 0.065 | longest wait for in position after the arrival (s), in [0, 10] |

    The scenario (:mod:`delta_env.scenario`) supplies every argument left at None (the defaults above are the
    ``nominal`` scenario's). :meth:`override_speed` slows or stops the rest of the reference between steps. Each
    episode draws its faults (``env.faults``) from ``np_random`` after everything else; their truth is
    ``env.injected_faults`` (:class:`~delta_env.faults.InjectedFault`) and ``info["faults"]``
    (:class:`~delta_env.fault_injection.FaultInjector`). The waits for the in-position signal are ``env.settles``
    (:class:`~delta_env.release.Settle`).
    """

    metadata = {"render_modes": ["human", "rgb_array"], "render_fps": 50}  # noqa: RUF012

    def __init__(
        self,
        plant: PlantConfig | None = None,
        n_cycles: int | None = None,
        cycle: Literal["conveyor", "standard"] | None = None,
        start: Literal["place", "pick"] | None = None,
        peak_acceleration: float | None = None,
        payload_mass_range: tuple[float, float] | None = None,
        domain_randomization: RandomizationRanges | None = None,
        reward_weights: RewardWeights | None = None,
        divergence_penalty: float = 1e3,
        render_mode: str | None = None,
        width: int = RENDER_SIZE[0],
        height: int = RENDER_SIZE[1],
        scenario: str | os.PathLike[str] | Scenario | None = None,
        timing: MoveTiming | None = None,
        faults: Sequence[FaultSpec] | None = None,
        release: Literal["in_position", "timed"] | None = None,
        in_position_window: float | None = None,
        in_position_time: float | None = None,
        air_activation: float | None = None,
        settle_timeout: float | None = None,
    ) -> None:
        base = Scenario() if scenario is None else resolve_scenario(scenario)
        overrides = {
            "n_cycles": n_cycles,
            "cycle": cycle,
            "start": start,
            "peak_acceleration": peak_acceleration,
            "payload_mass_range": payload_mass_range,
            "domain_randomization": domain_randomization,
            "release": release,
            "in_position_window": in_position_window,
            "in_position_time": in_position_time,
            "air_activation": air_activation,
            "settle_timeout": settle_timeout,
        }
        plant = base.effective_plant if plant is None else plant
        # The task checks the overrides as it checks a scenario's (PickPlaceTask): one home for their ranges. The
        # scenario's own task was checked as the scenario was made: with no override that changes it, it is used as is.
        changes = {
            key: value for key, value in overrides.items() if value is not None and not _repeats(base.task, key, value)
        }
        task = dataclasses.replace(base.task, **changes) if changes else base.task
        self.release = task.release_settings
        n_cycles, cycle, start, peak_acceleration = task.n_cycles, task.cycle, task.start, task.peak_acceleration
        (low, high), domain_randomization = task.payload_mass_range, task.domain_randomization
        if plant is not None:
            require_instance("plant", plant, PlantConfig)
        if reward_weights is not None:
            require_instance("reward_weights", reward_weights, RewardWeights)
        require_in("divergence_penalty", divergence_penalty, 0.0)
        require_count("width", width)
        require_count("height", height)
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be one of {self.metadata['render_modes']} or None, got {render_mode!r}")
        if render_mode == "human":
            require_display()

        faults = require_fault_specs(base.task.faults if faults is None else faults)

        self.plant_config = plant if plant is not None else PlantConfig()
        self.plant = DeltaPlant(self.plant_config, obstacle=any(spec.target == "obstacle" for spec in faults))
        self.n_cycles = int(n_cycles)
        self.cycle = cycle
        self.start = start
        self.peak_acceleration = float(peak_acceleration)
        self.payload_mass_range = (float(low), float(high))
        self.domain_randomization = domain_randomization
        self.timing = timing
        self.task_timing = base.task.timing
        self.jerk_limited = base.task.jerk_limited
        self.torque_share = base.task.torque_share
        self.reward_weights = reward_weights if reward_weights is not None else RewardWeights()
        self.divergence_penalty = float(divergence_penalty)
        self._tracking_weight_m2 = self.reward_weights.tracking * 1e6  # the weight is per mm^2
        self._torque_weight = self.reward_weights.torque

        timestep = self.plant.model.opt.timestep
        self.n_substeps = control_substeps(timestep)
        realism = self.plant_config.realism
        encoder_step, load_encoder_step = encoder_steps(realism)
        self._sensors = Sensors(self.plant, encoder_step, realism.torque_noise_std, load_encoder_step)
        drive = self.plant_config.drive
        self._drive = DriveMonitor(drive, self.dt)
        self._faults = FaultInjector(faults, self.plant, drive.peak_torque, self.dt, self._drop_object)
        self._reference = EpisodeReference(
            self.plant_config.geometry, self.n_cycles, cycle, start, task.move_profile, self.release
        )
        # the cell judges the platform on its own model of the robot, the geometry the reference is planned on
        self._in_position = InPositionRelease(self.release, self.plant_config.geometry)

        self.action_space = spaces.Box(-drive.peak_torque, drive.peak_torque, shape=(3,), dtype=np.float64)
        self.observation_space = observation_space(load_encoder=self._sensors.load_encoder_step is not None)

        self.render_mode = render_mode
        self._renderer = None
        if render_mode is not None:
            from gymnasium.envs.mujoco.mujoco_rendering import MujocoRenderer

            self._renderer = MujocoRenderer(
                self.plant.model, self.plant.data, DEFAULT_CAMERA, width=width, height=height
            )
        self._render_every = max(1, round(1.0 / (self.metadata["render_fps"] * CONTROL_PERIOD)))

        self._episode_over = False
        self.payload_masses = np.zeros(self.n_cycles)
        self._step_index = 0
        self._cycle = 0
        self._holding = False
        self._carried_mass = 0.0  # truth: 0 while nothing is held or after a slip
        self._last_observation: dict[str, NDArray[np.float64]] | None = None
        # Views of the mjData arrays each step reads (mjData keeps its buffers for its lifetime).
        data = self.plant.data
        self._ctrl, self._actuator_force, self._warning_counts = data.ctrl, data.actuator_force, data.warning.number
        # MuJoCo's own instability flags (it resets mjData and counts a warning when the state blows up).
        self._instability_warnings = tuple(
            int(w)
            for w in (
                mujoco.mjtWarning.mjWARN_BADQACC,
                mujoco.mjtWarning.mjWARN_BADQVEL,
                mujoco.mjtWarning.mjWARN_BADQPOS,
            )
        )

    @property
    def dt(self) -> float:
        """Control period (s): the time one :meth:`step` advances, ``n_substeps`` physics timesteps."""
        return self.n_substeps * self.plant.model.opt.timestep

    @property
    def faults(self) -> tuple[FaultSpec, ...]:
        """The faults each episode may draw (the ``faults`` argument, or the scenario's)."""
        return self._faults.specs

    @property
    def injected_faults(self) -> list[InjectedFault]:
        """The truth of the faults of this episode, as they start (cleared at reset)."""
        return self._faults.injected

    @property
    def settles(self) -> list[Settle]:
        """The waits for the in-position signal of this episode that have ended, in order (cleared at reset)."""
        return self._in_position.settles

    @property
    def trajectory(self) -> Trajectory | None:
        """The reference followed from now on (1 kHz samples; :class:`~delta_env.reference.EpisodeReference`),
        None before the first reset."""
        return self._reference.trajectory

    # -- episode --------------------------------------------------------------------------------

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, NDArray[np.float64]], dict[str, Any]]:
        """Start a new episode.

        Args:
            seed: Seeds ``self.np_random``; the same seed gives the same episode.
            options: ``"payload_masses"``: the object masses (kg, each in [0, MAX_PAYLOAD_MASS]), one per pick,
                replacing the drawn ones without changing any other random draw of the episode.
                ``"reference"``: a :class:`~delta_env.trajectories.Trajectory` to follow instead of
                the generated cycles (e.g. an identification excitation without picks), as given: its gripper
                events come at their samples, never held for the in-position signal.
        """
        super().reset(seed=seed)
        options = options or {}
        unknown = set(options) - {"payload_masses", "reference"}
        if unknown:
            raise ValueError(f"unknown reset options {sorted(unknown)}; allowed: ['payload_masses', 'reference']")
        reference = options.get("reference")
        if reference is not None and not isinstance(reference, Trajectory):
            raise ValueError(f"options['reference'] must be a delta_env.trajectories.Trajectory, got {type(reference)}")
        if reference is None and self.timing is None and self.task_timing != "fixed":
            raise ValueError(
                f"the scenario times its moves {self.task_timing!r}, which needs a planner on the identified model: "
                "set env.timing (a delta_env.timing.MoveTiming, e.g. controllers.payload_timing.PayloadTiming(...))"
            )

        # Draw everything in a fixed order so that overriding the masses changes nothing else.
        n_objects = self.n_cycles if reference is None else len(reference.pick_indices)
        drawn_masses = self.np_random.uniform(*self.payload_mass_range, size=n_objects)
        self.payload_masses = self._payload_masses(options.get("payload_masses"), drawn_masses)
        trajectory = self._reference.plan(self.np_random, self.payload_masses, self.timing, reference)
        if self.domain_randomization is not None:
            self.plant.randomize(self.np_random, self.domain_randomization)

        self._step_index = 0
        self._cycle = 0
        self._holding = False
        self._carried_mass = 0.0
        self._episode_over = False
        self._drive.reset()
        self._in_position.reset()

        # A fresh mjData state (time, solver warm start, constraint states, applied forces) so that an
        # episode repeats bit for bit whatever ran before it.
        self.plant.reset(trajectory.theta[0])
        first_pick = trajectory.pick_indices[0] if n_objects else 0
        self._place_object(trajectory.xyz[first_pick], self.payload_masses[0] if n_objects else 0.0)
        self._sensors.draw_noise(self.np_random, len(trajectory), spare=self._reference.retimes_online)
        self._faults.draw(self.np_random, len(trajectory.pick_indices))
        observation = self._sensors.first_observation(trajectory, self._holding)
        self._last_observation = observation
        if self.render_mode == "human":
            self.render()
        return observation, {"payload_masses": self.payload_masses.copy()}

    def override_speed(self, rate: float) -> None:
        """Slow the rest of the reference down, or stop it at rest, as a robot controller's speed override does.

        Callable between steps (after :meth:`reset`, before the episode ends). From the current step, the path
        rate of the reference ramps, jerk-limited, from its present value to ``rate`` times the planned speed
        along the same path (:func:`delta_env.override.override_speed`, docs/design.md section 5): the reference
        stays C2, and the gripper events still ahead move with it.

        - ``0 < rate <= 1``: the rest runs at ``rate`` to the planned end (1 restores full speed).
        - ``rate == 0``: a controlled stop along the path (category 2); the reference comes to rest, holds its
          stopping point for :data:`~delta_env.override.STOP_HOLD`, and the episode then truncates with
          ``info["stopped"] = True``. Picks and places the stop never reaches are dropped: an object not yet
          picked is never picked, one held stays held.

        A second call replaces the first from its own step; rates are always fractions of the planned speed.
        Once called, an online timing no longer retimes carries. ``info["speed_override"]`` reports the last
        rate asked for (1.0 without an override).

        Raises:
            ValueError: ``rate`` is not a finite number in [0, 1].
            RuntimeError: no episode is under way.
        """
        rate = require_in("rate", rate, 0.0, 1.0)
        if self._episode_over or self.trajectory is None:
            reason = "the episode has ended" if self._episode_over else "no episode started"
            raise RuntimeError(f"override_speed() needs an episode under way: {reason}")
        self._reference.override_speed(self._step_index, rate)
        self._sensors.cover(len(self.trajectory), self.np_random)

    def _payload_masses(self, requested: Any, drawn: NDArray[np.float64]) -> NDArray[np.float64]:
        if requested is None:
            return drawn
        try:
            masses = np.asarray(requested, dtype=float)
        except (TypeError, ValueError):
            raise ValueError(
                f"options['payload_masses'] must hold numbers, the object masses in kg, one per pick ({drawn.size}), "
                f"each in [0, {MAX_PAYLOAD_MASS}], got {requested!r}"
            ) from None
        if masses.shape != drawn.shape:
            raise ValueError(
                f"options['payload_masses'] must hold one mass per pick ({drawn.size}), got shape {masses.shape}"
            )
        if not np.all((masses >= 0.0) & (masses <= MAX_PAYLOAD_MASS)):
            raise ValueError(f"payload masses must lie in [0, {MAX_PAYLOAD_MASS}] kg, got {masses.tolist()}")
        return masses.copy()

    def step(
        self, action: NDArray[np.float64]
    ) -> tuple[dict[str, NDArray[np.float64]], float, bool, bool, dict[str, Any]]:
        # This is the 1 kHz hot path: scalar math on Python floats and few NumPy calls, so that the env costs at
        # most about its own physics (measured by scripts/bench.py).
        reference = self._reference
        if self._episode_over or reference.trajectory is None:
            reason = "the episode has ended" if self._episode_over else "no episode started"
            raise RuntimeError(f"call reset() before step(): {reason}")
        torque = require_torques(action)
        # The drive's envelope at the true joint speeds at the start of the step (it measures its own motor).
        plant = self.plant
        torque, margins, saturated = self._drive.clip(torque, plant.rotor_velocity_values())
        faulty = self._faults.faulty
        if faulty:
            carrying = self._cycle if self._holding else None
            torque = self._faults.before_physics(self._step_index, torque, reference.trajectory, carrying)
        t0, t1, t2 = torque.tolist()  # what the drive holds over the step

        plant.step(torque, self.n_substeps)
        self._step_index = k = self._step_index + 1
        if reference.retimes_online and reference.retime(k):
            self._sensors.cover(len(reference.trajectory), self.np_random)
        event = reference.events.get(k)
        if event is not None:
            self._gripper_event(*event)
        trajectory = reference.trajectory

        loop_gap = plant.loop_gap()
        # The warnings count from the episode's mj_resetData; NaN fails the loop-gap comparison.
        counts, (bad_qacc, bad_qvel, bad_qpos) = self._warning_counts, self._instability_warnings
        unstable = counts.item(bad_qacc) or counts.item(bad_qvel) or counts.item(bad_qpos)
        diverged = bool(unstable) or not loop_gap <= DIVERGENCE_LOOP_GAP

        px, py, pz = platform = plant.platform_point()
        reference_position = trajectory.xyz[k]
        rx, ry, rz = reference_position.tolist()
        squared_error = (px - rx) ** 2 + (py - ry) ** 2 + (pz - rz) ** 2
        if diverged:
            observation = self._last_observation
            reward_tracking = reward_torque = 0.0
            reward = -self.divergence_penalty
        else:
            observation = self._sensors.observe(k, trajectory, self._holding, self._faults if faulty else None)
            self._last_observation = observation
            reward_tracking = -self._tracking_weight_m2 * squared_error
            reward_torque = -self._torque_weight * (t0 * t0 + t1 * t1 + t2 * t2)
            reward = reward_tracking + reward_torque

        # The cell's in-position signal, from the encoders only (the arms' where fitted); waiting for it holds the
        # reference at rest.
        in_position, settle = False, None
        if not diverged:
            in_position, settle = self._in_position.step(k, self._sensors.cell_angles, reference)
            if reference.trajectory is not trajectory:
                self._sensors.cover(len(reference.trajectory), self.np_random)
        truncated = k >= len(reference.trajectory) - 1
        self._episode_over = diverged or truncated

        applied = self._actuator_force.copy()
        # the speed after the step, the thermal RMS of the output torque over the last window
        speed_margin, speed_exceeded, thermal_rms, thermal_margin, thermal_exceeded = self._drive.report(
            k, plant.rotor_velocity_values(), applied.tolist()
        )
        info = {
            "payload_mass": self._carried_mass,
            "platform_position": np.array(platform),
            "reference_position": reference_position,
            "tracking_error": math.sqrt(squared_error) if not diverged else math.nan,
            "loop_gap": loop_gap,
            "torque_command": self._ctrl.copy(),
            "applied_torque": applied,
            "cycle": self._cycle,
            "diverged": diverged,
            "torque_saturated": saturated,
            "torque_margin": np.array(margins),
            "speed_margin": speed_margin,
            "speed_exceeded": speed_exceeded,
            "thermal_rms": thermal_rms,
            "thermal_margin": thermal_margin,
            "thermal_exceeded": thermal_exceeded,
            "reward_tracking": reward_tracking,
            "reward_torque": reward_torque,
            "speed_override": reference.speed_override,
            "stopped": truncated and reference.speed_override == 0.0,
            "in_position": in_position,
            "settle_timeout": settle is not None and settle.timed_out,
            "faults": self._faults.after_step(k - 1) if faulty else (),
        }
        if self.render_mode == "human" and k % self._render_every == 0:
            self.render()
        return observation, reward, diverged, truncated, info

    def _gripper_event(self, kind: str, cycle: int) -> None:
        if kind == "pick":
            self.plant.attach_payload()
            self._holding = True
            self._carried_mass = self.payload_masses.item(cycle)
            self._cycle = cycle
            self._faults.schedule_carry(cycle, self._step_index, self.trajectory.place_indices)
        else:
            self.plant.release_payload()
            self._holding = False
            self._carried_mass = 0.0
            if cycle + 1 < len(self.payload_masses):
                # The next object waits at the next pick point (the same body, a new mass).
                self._place_object(self._reference.planned_pick(cycle + 1), self.payload_masses[cycle + 1])

    def _place_object(self, pick_point: NDArray[np.float64], mass: float) -> None:
        """Put the object (kg) on the conveyor so its top face meets the suction cup at ``pick_point``."""
        below = SUCTION_CUP_OFFSET + 0.5 * DEFAULT_PAYLOAD_SIZE[2]
        self.plant.place_payload(pick_point - np.array([0.0, 0.0, below]), mass)

    def _drop_object(self) -> float:
        """A slip: the suction cup loses the object held (``gripper`` still reads 1); returns its mass (kg)."""
        mass = self._carried_mass
        self.plant.release_payload()
        self._carried_mass = 0.0
        return mass

    # -- rendering ------------------------------------------------------------------------------

    def render(self) -> NDArray[np.uint8] | None:
        if self._renderer is None:
            gym.logger.warn("render() called without a render_mode; pass render_mode='rgb_array' or 'human'")
            return None
        # Body poses lag the state by one physics step (0.5 ms) after mj_step: invisible in a frame.
        return self._renderer.render(self.render_mode)

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
