"""The "real robot": the compiled MuJoCo Delta and the only code that touches its state (docs/design.md section 4).

:class:`DeltaPlant` builds the model of a :class:`~delta_env.config.PlantConfig` (:mod:`delta_env.scene`),
caches every id and address once, assembles closed-loop states, steps the 1 kHz hot path, handles the
payload, applies external forces and domain randomization; its parts are the loop closures
(:mod:`delta_env.loops`), the suction payload (:mod:`delta_env.suction`) and the contacts
(:mod:`delta_env.contacts`).
"""

from __future__ import annotations

import logging
from dataclasses import replace

import mujoco
import numpy as np
from numpy.typing import ArrayLike, NDArray

from delta_env import kernels
from delta_env.config import (
    DEFAULT_PAYLOAD_SIZE,
    MAX_PAYLOAD_MASS,
    SUCTION_CUP_OFFSET,
    PhysicalParameters,
    PlantConfig,
    PlantRealism,
    RandomizationRanges,
)
from delta_env.contacts import Obstacle, RobotContacts
from delta_env.loops import LoopClosures
from delta_env.robot import CHAIN_LABELS, ROD_LABELS, forearm_home_tilt
from delta_env.scene import build_model
from delta_env.suction import SuctionPayload, quat_to_matrix
from delta_env.validation import require_in, require_joint_vector

_LOG = logging.getLogger(__name__)


def _log_mujoco_warning(message: str) -> None:
    """MuJoCo's warnings (an unstable simulation, which the env also flags in ``info``) to this module's logger:
    MuJoCo's default prints them and appends them to ``MUJOCO_LOG.TXT`` in the working directory."""
    _LOG.warning("MuJoCo: %s", message.strip())


if mujoco.get_mju_user_warning() is None:  # a handler installed before is kept: the hook is process-wide
    mujoco.set_mju_user_warning(_log_mujoco_warning)

_IDENTITY_QUATERNION = np.array([1.0, 0.0, 0.0, 0.0])


class DeltaPlant:
    """MuJoCo model and data of the Delta, with named access and the 1 kHz stepping hot path.

    Every id and address is cached once here (dm_control style); the env and the oracle read and write
    MuJoCo state only through this class. Freshness of the measurements after :meth:`step`:

    - ``joint_angles``, ``joint_velocities``, ``platform_position``, ``payload_position`` and the float forms
      ``joint_angle_values``, ``joint_velocity_values``, ``platform_point`` read qpos/qvel: always current.
    - ``loop_gap`` reads ``site_xpos``, which ``mj_step`` computes before integrating: after
      :meth:`step` it is one physics step (``timestep``) stale unless ``refresh=True``.

    Attributes:
        config: The configuration the model was built from.
        model: ``mujoco.MjModel``.
        data: ``mujoco.MjData``.
    """

    def __init__(self, config: PlantConfig | None = None, obstacle: bool = False) -> None:
        self.config = PlantConfig() if config is None else config
        if not isinstance(self.config, PlantConfig):
            raise ValueError(f"config must be a PlantConfig, got {type(self.config).__name__}")
        self.model = build_model(self.config, obstacle)
        self.data = mujoco.MjData(self.model)
        self._scratch = mujoco.MjData(self.model)  # mj_setConst overwrites the state of the data it gets
        model, data = self.model, self.data

        def ident(kind: mujoco.mjtObj, name: str) -> int:
            return mujoco.mj_name2id(model, kind, name)

        joint, body = mujoco.mjtObj.mjOBJ_JOINT, mujoco.mjtObj.mjOBJ_BODY
        motor_joints = [ident(joint, f"motor_{label}") for label in CHAIN_LABELS]
        self._motor_qpos = model.jnt_qposadr[motor_joints].copy()
        self._motor_dofs = model.jnt_dofadr[motor_joints].copy()
        # The joints the drives turn: the rotors of compliant drives, else the arms' own (motor) joints.
        self._compliant = self.config.realism.compliance is not None
        rotor_joints = [ident(joint, f"rotor_{label}") for label in CHAIN_LABELS] if self._compliant else motor_joints
        self._rotor_qpos = model.jnt_qposadr[rotor_joints].copy()
        self._rotor_dofs = model.jnt_dofadr[rotor_joints].copy()
        self._drive_dofs = np.union1d(self._motor_dofs, self._rotor_dofs)
        self._gearheads = (
            np.array([ident(mujoco.mjtObj.mjOBJ_TENDON, f"gearhead_{label}") for label in CHAIN_LABELS])
            if self._compliant
            else np.zeros(0, dtype=int)
        )
        self._platform_body = ident(body, "platform")
        self._arm_bodies = [ident(body, f"upper_arm_{label}") for label in CHAIN_LABELS]
        self.obstacle = Obstacle(model, data) if obstacle else None
        """The obstacle of collision faults; None unless built with ``obstacle=True``."""
        first_platform_joint = model.body_jntadr[self._platform_body]
        self._platform_qpos = int(model.jnt_qposadr[first_platform_joint])
        self._platform_dof = int(model.jnt_dofadr[first_platform_joint])
        self._platform_free = self.config.variant == "realistic"
        # Ideal: slides measure the displacement from the body's home position.
        home = tuple(model.body_pos[self._platform_body].tolist())
        self._platform_offset = (0.0, 0.0, 0.0) if self._platform_free else home

        rods = ("",) if self.config.variant == "ideal" else ROD_LABELS
        self.loops = LoopClosures(model, data, rods)
        """The loop-closure constraints (Jacobian, its rate term, the gap)."""
        self._elbow_qpos = np.array(
            [
                [model.jnt_qposadr[ident(joint, f"elbow_{label}{rod}_{axis}")] for axis in ("pitch", "roll")]
                for label in CHAIN_LABELS
                for rod in rods
            ]
        )
        self._elbow_chains = np.repeat(np.arange(3), len(rods))  # the chain of each rod of _elbow_qpos
        self._tilt = forearm_home_tilt(self.config.geometry)

        # Degrees of freedom of the robot (the payload's free joint excluded), split into motors and the
        # passive ones that assemble() solves for.
        self._payload = SuctionPayload(model, data) if self.config.payload_body else None
        payload_body = -1 if self._payload is None else self._payload.body
        robot_dofs = np.array([dof for dof in range(model.nv) if model.dof_bodyid[dof] != payload_body])
        self._passive_dofs = np.setdiff1d(robot_dofs, self._drive_dofs)
        if self.loops.n_rows != len(self._passive_dofs):
            raise RuntimeError(f"model has {self.loops.n_rows} loop rows for {len(self._passive_dofs)} passive dofs")

        # Domain-randomizable parameters: the nominal ones come from the config.
        others = (payload_body, -1 if self.obstacle is None else self.obstacle.body)
        self._robot_bodies = np.array([b for b in range(1, model.nbody) if b not in others])
        self._has_lag = self.config.realism.actuator_lag > 0.0
        self._parameters = self.nominal_parameters
        self._set_disturbance_coefficients(self.config.realism)

        # Robot self-contacts seen since the last reset, tracked only with the collision geometry on.
        self._contacts = RobotContacts(model, data) if self.config.collisions else None

        # Views into mjData for the hot path (the buffers never move), and its addresses as Python ints.
        self._qpos, self._qvel = data.qpos, data.qvel
        self._motor_qpos_items = tuple(self._motor_qpos.tolist())
        self._motor_dof_items = tuple(self._motor_dofs.tolist())
        self._rotor_qpos_items = tuple(self._rotor_qpos.tolist())
        self._rotor_dof_items = tuple(self._rotor_dofs.tolist())
        self._ctrl, self._qfrc_applied = data.ctrl, data.qfrc_applied
        self.reset()

    # --------------------------------------------------------------------------------------------
    # State
    # --------------------------------------------------------------------------------------------

    @property
    def motor_dofs(self) -> NDArray[np.int_]:
        """Addresses of the three motor joints (the arms' joints at the motor axes) in qvel (a copy), shape (3,)."""
        return self._motor_dofs.copy()

    @property
    def rotor_dofs(self) -> NDArray[np.int_]:
        """Addresses in qvel of the joints the drives turn (a copy), shape (3,): the rotors of compliant drives, else
        the motor joints themselves."""
        return self._rotor_dofs.copy()

    @property
    def compliant(self) -> bool:
        """True if the drives are compliant (``config.realism.compliance``): rotor and arm are two joints."""
        return self._compliant

    def reset(self, theta: ArrayLike | None = None) -> None:
        """Reset the data (time 0, no forces), detach and float the payload, and assemble at ``theta``.

        Args:
            theta: Motor angles (rad), shape (3,); home (arms horizontal) when None.
        """
        mujoco.mj_resetData(self.model, self.data)
        if self._contacts is not None:
            self._contacts.clear()
        if self._payload is not None:
            self.model.body_gravcomp[self._payload.body] = 1.0
        self.assemble(np.zeros(3) if theta is None else theta)

    def assemble(self, theta: ArrayLike, theta_dot: ArrayLike | None = None) -> None:
        """Put the robot at motor angles ``theta`` with every loop closed, moving at ``theta_dot``.

        Positions are analytic (:meth:`assembly_coordinates`), so the loops close to round-off; velocities
        solve J_c qvel = 0 with the motor rates fixed. The rotors of compliant drives take the arms' angles and rates
        (the gearheads undeflected). A carried payload follows the platform rigidly; a
        free one is left where it is. Actuator states are zeroed and ``mj_forward`` brings every derived
        quantity up to date.

        Args:
            theta: Motor angles (rad), shape (3,).
            theta_dot: Motor rates (rad/s), shape (3,); zero when None.

        Raises:
            ValueError: if the angles are not finite or the forearms cannot reach a common point.
        """
        theta = require_joint_vector("theta", theta)
        theta_dot = np.zeros(3) if theta_dot is None else require_joint_vector("theta_dot", theta_dot)
        platform, elbows = self.assembly_coordinates(theta)
        self._assemble(theta, theta_dot, platform, elbows)

    def assembly_coordinates(self, theta: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Platform position (m) and elbow (pitch, roll) angles (rad) that close every loop at ``theta``.

        Vectorized over a leading batch shape: ``theta`` (..., 3) gives (..., 3) and (..., 3 chains, 2).
        The platform is the forward kinematics; both rods of a parallelogram are parallel to x - J'_i
        (:func:`delta_env.kernels.assembly`).

        Raises:
            ValueError: if the forearms cannot reach a common point, or one would lie along its motor axis.
        """
        theta = np.asarray(theta, dtype=float)
        rows = np.ascontiguousarray(theta.reshape(-1, 3))
        platform, elbows = np.empty(rows.shape), np.empty((len(rows), 3, 2))
        g = self.config.geometry
        status, row = kernels.assembly(rows, g.r, g.l1, g.l2, self._tilt, platform, elbows)
        if status != kernels.VALID:
            raise ValueError(f"{kernels.INVALID_STATE[status]} at theta={rows[row].tolist()}")
        return platform.reshape(theta.shape), elbows.reshape((*theta.shape, 2))

    def _assemble(self, theta: NDArray, theta_dot: NDArray, platform: NDArray, elbows: NDArray) -> None:
        """Write a configuration from :meth:`assembly_coordinates`, solve the velocities and run ``mj_forward``
        (no checks)."""
        model, data = self.model, self.data
        jac = self.configure(theta, platform, elbows)
        data.qvel[self._motor_dofs] = theta_dot
        if self._compliant:
            data.qpos[self._rotor_qpos] = theta
            data.qvel[self._rotor_dofs] = theta_dot
        data.qvel[self._passive_dofs] = np.linalg.solve(
            jac[:, self._passive_dofs], -jac[:, self._motor_dofs] @ theta_dot
        )
        if self.payload_attached:
            self._payload_follows_velocity()
        if model.na:
            data.act[:] = 0.0
        mujoco.mj_forward(model, data)

    def configure(self, theta: NDArray, platform: NDArray, elbows: NDArray) -> NDArray[np.float64]:
        """Write the positions of a closed configuration and run the position stages ``mj_kinematics`` and
        ``mj_comPos``; qvel is left as it was, a carried payload follows the platform. No checks.

        Args:
            theta: Motor angles (rad), shape (3,).
            platform: Platform position (m), shape (3,), and elbows: elbow (pitch, roll) angles (rad), shape
                (3, 2), as :meth:`assembly_coordinates` gives them for ``theta``.

        Returns:
            The loop Jacobian at the new configuration (the buffer of :meth:`LoopClosures.jacobian`): what the
            velocities that close the loops solve with (:meth:`assemble`, and the inverse dynamics oracle, which
            writes qvel and qacc itself and lets ``mj_inverse`` recompute the rest).
        """
        qpos = self._qpos
        qpos[self._motor_qpos] = theta
        if self._platform_free:
            qpos[self._platform_qpos : self._platform_qpos + 3] = platform
            qpos[self._platform_qpos + 3 : self._platform_qpos + 7] = _IDENTITY_QUATERNION
        else:
            np.subtract(platform, self._platform_offset, out=qpos[self._platform_qpos : self._platform_qpos + 3])
        qpos[self._elbow_qpos] = elbows[self._elbow_chains]
        if self.payload_attached:
            self._payload.follow(*self._platform_pose())
        mujoco.mj_kinematics(self.model, self.data)
        mujoco.mj_comPos(self.model, self.data)
        return self.loops.jacobian()

    def joint_angles(self) -> NDArray[np.float64]:
        """Motor angles theta (rad), shape (3,): the arms' angles at the motor axes (the load side of a compliant
        drive); current."""
        return np.array(self.joint_angle_values())

    def joint_velocities(self) -> NDArray[np.float64]:
        """Motor rates theta_dot (rad/s), shape (3,); current."""
        return np.array(self.joint_velocity_values())

    def platform_position(self) -> NDArray[np.float64]:
        """Platform centre E0 (m), shape (3,), from qpos; current."""
        return np.array(self.platform_point())

    def joint_angle_values(self) -> tuple[float, float, float]:
        """Motor angles theta (rad) as three floats (the 1 kHz hot path's scalar math); current."""
        qpos, (a0, a1, a2) = self._qpos, self._motor_qpos_items
        return qpos.item(a0), qpos.item(a1), qpos.item(a2)

    def joint_velocity_values(self) -> tuple[float, float, float]:
        """Motor rates theta_dot (rad/s) as three floats; current."""
        qvel, (d0, d1, d2) = self._qvel, self._motor_dof_items
        return qvel.item(d0), qvel.item(d1), qvel.item(d2)

    def rotor_angle_values(self) -> tuple[float, float, float]:
        """The drives' motor-side angles (rad) as three floats: a compliant drive's rotor angle at the joint's scale
        (its shaft's angle over the gear ratio), else the arm's angle; current."""
        qpos, (a0, a1, a2) = self._qpos, self._rotor_qpos_items
        return qpos.item(a0), qpos.item(a1), qpos.item(a2)

    def rotor_velocity_values(self) -> tuple[float, float, float]:
        """The drives' motor-side rates (rad/s, at the joint's scale) as three floats; current."""
        qvel, (d0, d1, d2) = self._qvel, self._rotor_dof_items
        return qvel.item(d0), qvel.item(d1), qvel.item(d2)

    def platform_point(self) -> tuple[float, float, float]:
        """Platform centre E0 (m) as three floats, from qpos; current."""
        qpos, address, (o0, o1, o2) = self._qpos, self._platform_qpos, self._platform_offset
        return qpos.item(address) + o0, qpos.item(address + 1) + o1, qpos.item(address + 2) + o2

    def loop_gap(self, refresh: bool = False) -> float:
        """Largest distance (m) between the two points of any loop-closure connect.

        Args:
            refresh: Recompute the kinematics first (``mj_kinematics``). Without it
                the value is that of ``site_xpos``: after :meth:`step`, the state one physics step ago.
        """
        if refresh:
            mujoco.mj_kinematics(self.model, self.data)
        return self.loops.gap()

    # --------------------------------------------------------------------------------------------
    # Stepping (1 kHz hot path)
    # --------------------------------------------------------------------------------------------

    def motor_disturbance(self, theta: ArrayLike, theta_dot: ArrayLike) -> NDArray[np.float64]:
        """Stribeck excess and torque ripple (N m) on the driven joints (:attr:`rotor_dofs`) at angles ``theta``
        (rad) and rates ``theta_dot`` (rad/s), each ``(..., 3)``: :func:`delta_env.kernels.motor_disturbance`."""
        theta, theta_dot = np.broadcast_arrays(np.asarray(theta, dtype=float), np.asarray(theta_dot, dtype=float))
        torque = np.empty(theta.shape)
        kernels.motor_disturbances(
            self._disturbance_bytes,
            np.ascontiguousarray(theta.reshape(-1, 3)),
            np.ascontiguousarray(theta_dot.reshape(-1, 3)),
            torque.reshape(-1, 3),
        )
        return torque

    @property
    def disturbance_coefficients(self) -> NDArray:
        """The constants of :meth:`motor_disturbance` (a copy), a one-element :data:`delta_env.kernels.DISTURBANCE`
        array."""
        return self._disturbance.copy()

    def step(self, torque_command: NDArray[np.float64], n_substeps: int) -> None:
        """Command motor torques (N m, shape (3,)) and advance ``n_substeps`` physics steps.

        MuJoCo clips the command to the drive's peak torque and passes it through the current-loop lag, if any.
        Stribeck excess and ripple (:meth:`motor_disturbance`) are computed once from the state at the call
        and held over the substeps (zero-order hold, like a drive's 1 kHz torque update); this method owns
        ``qfrc_applied`` on the driven dofs (:attr:`rotor_dofs`). No input validation: this is the 1 kHz hot path.
        """
        self._ctrl[...] = torque_command
        if self._has_disturbance:
            kernels.apply_motor_disturbance(
                self._disturbance_bytes, self._qpos, self._qvel, self._rotor_qpos, self._rotor_dofs, self._qfrc_applied
            )
        mujoco.mj_step(self.model, self.data, n_substeps)
        if self._contacts is not None and self.data.ncon:
            self._contacts.record()

    @property
    def robot_contacts(self) -> dict[tuple[str, str], float]:
        """Robot self-contacts since the last :meth:`reset`, checked after every :meth:`step` (a copy): each pair of
        geom names with its deepest penetration (m). Always empty unless the plant was built with
        ``PlantConfig.collisions``; a touch shorter than one control step can pass unseen."""
        return {} if self._contacts is None else self._contacts.seen()

    # --------------------------------------------------------------------------------------------
    # Payload
    # --------------------------------------------------------------------------------------------

    def _required_payload(self) -> SuctionPayload:
        if self._payload is None:
            raise RuntimeError("this plant was built with payload_body=False")
        return self._payload

    @property
    def payload_attached(self) -> bool:
        """True while the suction weld holds the payload (False without a payload body)."""
        return self._payload is not None and self._payload.attached

    @property
    def payload_mass(self) -> float:
        """Simulated payload mass (kg); at least MIN_PAYLOAD_MASS."""
        return self._required_payload().mass

    def payload_position(self) -> NDArray[np.float64]:
        """Centre of the payload box (m), shape (3,), from qpos; current."""
        return self._required_payload().position()

    def suction_cup_position(self) -> NDArray[np.float64]:
        """Suction cup face (m), SUCTION_CUP_OFFSET below E0 (the platform stays level), shape (3,)."""
        return self.platform_position() - np.array([0.0, 0.0, SUCTION_CUP_OFFSET])

    def place_payload(self, position: ArrayLike, mass: float, size: ArrayLike = DEFAULT_PAYLOAD_SIZE) -> None:
        """Teleport the (released) payload to ``position`` at rest, with a new mass and box size.

        The box gets the homogeneous inertia of its size; gravity compensation makes it float there.

        Args:
            position: Centre of the box (m), shape (3,).
            mass: Payload mass (kg) in [0, MAX_PAYLOAD_MASS]; simulated as at least MIN_PAYLOAD_MASS.
            size: Edge lengths of the box (m), shape (3,), each in (0, 1].

        Raises:
            ValueError: for a bad position, mass or size. RuntimeError: while the payload is attached.
        """
        payload = self._required_payload()
        if payload.attached:
            raise RuntimeError("release the payload before placing it")
        position = require_joint_vector("position", position)
        mass = require_in("mass", mass, 0.0, MAX_PAYLOAD_MASS, unit="kg")
        size = require_joint_vector("size", size, 0.0, 1.0, unit="m", low_open=True)
        payload.set_box(mass, size)
        self._set_const()
        payload.put_at_rest(position)
        mujoco.mj_forward(self.model, self.data)

    def attach_payload(self) -> None:
        """Activate the suction weld at the current relative pose; gravity compensation off.

        The payload takes the platform's velocity (a suction pick is a short impulse the weld would
        otherwise deliver in one constraint time constant).
        """
        self._required_payload().attach(*self._platform_pose())
        self._payload_follows_velocity()

    def release_payload(self) -> None:
        """Deactivate the suction weld; the payload stops and floats where it is (gravcomp on)."""
        self._required_payload().release()

    def _platform_pose(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        if self._platform_free:
            quat = self._qpos[self._platform_qpos + 3 : self._platform_qpos + 7].copy()
            return self.platform_position(), quat / np.linalg.norm(quat)
        return self.platform_position(), np.array([1.0, 0.0, 0.0, 0.0])

    def _payload_follows_velocity(self) -> None:
        """Give the payload the rigid-body velocity of the platform at its position."""
        platform_position, platform_quat = self._platform_pose()
        linear = self._qvel[self._platform_dof : self._platform_dof + 3]
        if self._platform_free:
            angular = quat_to_matrix(platform_quat) @ self._qvel[self._platform_dof + 3 : self._platform_dof + 6]
        else:
            angular = np.zeros(3)
        self._payload.match_velocity(platform_position, linear, angular)

    # --------------------------------------------------------------------------------------------
    # External forces (fault injection; the obstacle is :attr:`obstacle`); mj_resetData clears them
    # --------------------------------------------------------------------------------------------

    def apply_external_force(self, force: NDArray[np.float64], joint: int | None = None) -> None:
        """Push with ``force`` (N, world frame, shape (3,)) on the platform at its centre E0 (``joint`` None) or on
        the upper arm of ``joint`` at its elbow, until :meth:`clear_external_forces`.

        Written to ``xfrc_applied`` at the body's centre of mass, with the torque of the force's lever arm from the
        body's pose at the last physics step (call it again each control step while the arm turns).
        """
        data = self.data
        body = self._platform_body if joint is None else self._arm_bodies[joint]
        point = data.xpos[body].copy()
        if joint is not None:  # the elbow: the arm's x axis at l1
            point += self.config.geometry.l1 * data.xmat[body].reshape(3, 3)[:, 0]
        data.xfrc_applied[body, :3] = force
        data.xfrc_applied[body, 3:] = np.cross(point - data.xipos[body], force)

    def clear_external_forces(self) -> None:
        """Remove every force of :meth:`apply_external_force`."""
        self.data.xfrc_applied[:] = 0.0

    # --------------------------------------------------------------------------------------------
    # Domain randomization: every per-episode model edit happens here
    # --------------------------------------------------------------------------------------------

    @property
    def nominal_parameters(self) -> PhysicalParameters:
        """The parameters of ``config`` (what :meth:`restore_nominal` sets)."""
        return PhysicalParameters(masses=self.config.masses, actuator_lag=self.config.realism.actuator_lag)

    @property
    def parameters(self) -> PhysicalParameters:
        """The parameters the model currently has."""
        return self._parameters

    def set_physical_parameters(self, parameters: PhysicalParameters) -> None:
        """Edit masses, friction, lag and a compliant drive's gearheads of the model in place (the state is kept).

        The new inertial properties come from compiling the model of the modified config, so they are
        exactly what :func:`~delta_env.scene.build_model` would give; derived constants are refreshed with
        ``mj_setConst``. It compiles a model: call it between episodes.

        Raises:
            ValueError: for a lag on a plant built without one (or the reverse), or gearhead scales on a rigid one.
        """
        if not isinstance(parameters, PhysicalParameters):
            raise ValueError(f"parameters must be PhysicalParameters, got {type(parameters).__name__}")
        if parameters.scales_gearhead and not self._compliant:
            raise ValueError(
                "this plant's drives are rigid: stiffness_scale and damping_scale must be (1, 1, 1), got "
                f"{parameters.stiffness_scale} and {parameters.damping_scale}"
            )
        if (parameters.actuator_lag > 0.0) != self._has_lag:
            raise ValueError(
                f"actuator_lag must be {'> 0' if self._has_lag else '0'} for this plant "
                f"(built with actuator_lag={self.config.realism.actuator_lag}), got {parameters.actuator_lag}"
            )
        nominal = self.config.realism
        scale = np.asarray(parameters.friction_scale)
        compliance = nominal.compliance
        if compliance is not None:
            compliance = replace(
                compliance,
                stiffness_scale=tuple(
                    float(v) for v in np.multiply(compliance.stiffness_scale, parameters.stiffness_scale)
                ),
                damping_scale=tuple(float(v) for v in np.multiply(compliance.damping_scale, parameters.damping_scale)),
            )
        realism = replace(
            nominal,
            viscous_scale=tuple(float(v) for v in np.asarray(nominal.viscous_scale) * scale),
            coulomb_scale=tuple(float(v) for v in np.asarray(nominal.coulomb_scale) * scale),
            actuator_lag=parameters.actuator_lag,
            compliance=compliance,
        )
        edited = build_model(replace(self.config, masses=parameters.masses, realism=realism))
        model, bodies = self.model, self._robot_bodies
        for name in ("body_mass", "body_inertia", "body_ipos", "body_iquat"):
            getattr(model, name)[bodies] = getattr(edited, name)[bodies]
        for name in ("dof_damping", "dof_frictionloss", "dof_armature"):
            getattr(model, name)[self._drive_dofs] = getattr(edited, name)[self._drive_dofs]
        for name in ("tendon_stiffness", "tendon_damping"):
            getattr(model, name)[self._gearheads] = getattr(edited, name)[self._gearheads]
        model.actuator_dynprm[:] = edited.actuator_dynprm
        self._set_const()
        self._set_disturbance_coefficients(realism)
        self._parameters = parameters

    def randomize(self, rng: np.random.Generator, ranges: RandomizationRanges | None = None) -> PhysicalParameters:
        """Draw and set new physical parameters (docs/design.md section 4 ranges by default); returns them."""
        ranges = RandomizationRanges() if ranges is None else ranges
        if ranges.actuator_lag is not None and not self._has_lag:
            raise ValueError("this plant has no actuator lag to randomize: use actuator_lag=None")
        if ranges.draws_gearhead and not self._compliant:
            raise ValueError(
                "this plant's drives are rigid, with no gearhead to randomize: use stiffness_fraction=0 and "
                f"damping_fraction=0, got {ranges.stiffness_fraction} and {ranges.damping_fraction}"
            )
        parameters = ranges.draw(rng, self.config.masses, self.config.realism.actuator_lag)
        self.set_physical_parameters(parameters)
        return parameters

    def restore_nominal(self) -> None:
        """Undo :meth:`randomize`: the parameters of ``config`` again."""
        self.set_physical_parameters(self.nominal_parameters)

    def _set_const(self) -> None:
        """Refresh the model constants derived from masses (mass matrix of simple bodies, constraint
        softness through body_invweight0) after an edit."""
        mujoco.mj_setConst(self.model, self._scratch)
        # mj_setConst derives flg_gravcomp from body_gravcomp, which is 0 while the payload is carried.
        self.model.flg_gravcomp = self.config.payload_body

    def _set_disturbance_coefficients(self, realism: PlantRealism) -> None:
        disturbance = self._disturbance = np.zeros(1, kernels.DISTURBANCE)
        self._disturbance_bytes = disturbance.view(np.uint8)
        disturbance["stribeck_gain"] = realism.stribeck_excess * realism.coulomb_per_joint
        disturbance["inverse_stribeck_velocity"] = 1.0 / realism.stribeck_velocity
        disturbance["ripple_amplitude"] = realism.ripple_amplitude
        disturbance["ripple_periods"] = float(realism.ripple_periods)
        self._has_disturbance = bool(np.any(disturbance["stribeck_gain"] > 0.0) or realism.ripple_amplitude > 0.0)
