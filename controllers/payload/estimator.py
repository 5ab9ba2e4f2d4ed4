"""The payload estimator: the weighted payload equation of each control step, fused by RLS, with the model's
corrections fitted on the empty moves (the package docstring gives the physics; docs/design.md section 6)."""

from __future__ import annotations

import math
from typing import Literal, NamedTuple

import numpy as np
from numpy.typing import NDArray

from controllers.base import Observation
from controllers.dynamics import DeltaDynamics
from controllers.estimation import JointStateFilter, JointStateSmoother, PayloadRLS
from controllers.payload.equation import (
    ARM_MASS_SCALE,
    EQUATION,
    FIT,
    FRICTION_SCALE,
    PARAMETERS,
    PLATFORM_MASS,
    solve_fit,
)
from controllers.payload.regressors import REGRESSORS, Regressor, SmoothedRegressor
from controllers.payload.smoothed import smoothed_update
from controllers.payload.tuning import (
    DROP_VARIANCE,
    FRICTION_CORRELATION_SAMPLES,
    FRICTION_SCALE_STD,
    FRICTION_VELOCITY,
    MASS_CORRECTION_STD,
    PICK_PRIOR_VARIANCE,
    RESIDUAL_STD,
    REST_RATE,
    TORQUE_AGE,
)
from delta_env.validation import require_in, require_positive


class ModelCorrections(NamedTuple):
    """Corrections of the identified model to the robot at hand, fitted on the empty moves of an episode.

    The plant's torque with an empty gripper is modelled as tau0 + dm phi + d_arm (I thdd + G) + kappa_i f_i: the
    model's, plus what mass and friction errors add (the model is linear in each; docs/design.md section 3).

    Attributes:
        platform_mass: dm (kg), the mass the model lacks at the platform: a payload-like offset along phi.
        arm_mass_scale: d_arm, the relative error of the arms' inertia I = (m1/3 + m2) l1^2 and gravity amplitude
            G = -(m1/2 + m2) g l1 together (dimensionless; :data:`MASS_CORRECTION_STD`).
        friction_scale: kappa_i, the relative error of each joint's friction fv_i thd_i + fc_i sign(thd_i), (3,).
    """

    platform_mass: float
    arm_mass_scale: float
    friction_scale: NDArray[np.float64]


class EmptyMoveSums(NamedTuple):
    """The weighted least-squares sums of a robot's empty moves, over the columns of :class:`ModelCorrections`
    (platform mass, arm-mass scale, three friction scales).

    What the robot's earlier work taught about its own mass and friction errors: seeded into the fit at every
    episode (``PayloadEstimator(empty_moves=...)``), they make its corrections as certain from the start as many
    empty moves would. Only for the robot they were measured on.

    Attributes:
        information: sum of w c c^T, (5, 5).
        moment: sum of w c y, (5,).
    """

    information: NDArray[np.float64]
    moment: NDArray[np.float64]


def _checked_sums(sums: EmptyMoveSums) -> EmptyMoveSums:
    """``sums`` as float arrays of shapes (5, 5) and (5,), finite, the information symmetric; else ValueError."""
    information = np.array(sums.information, dtype=np.float64)
    moment = np.array(sums.moment, dtype=np.float64)
    if information.shape != (PARAMETERS, PARAMETERS) or moment.shape != (PARAMETERS,):
        raise ValueError(f"empty_moves must be (5, 5) and (5,) sums, got shapes {information.shape} and {moment.shape}")
    if not (np.all(np.isfinite(information)) and np.all(np.isfinite(moment))):
        raise ValueError("empty_moves must be finite")
    if not np.allclose(information, information.T, rtol=1e-9, atol=0.0):
        raise ValueError("empty_moves.information must be symmetric (a sum of w c c^T)")
    return EmptyMoveSums(information, moment)


class PayloadEstimator:
    """Payload mass (kg) from measured joint torques, updated once per control step while the gripper holds.

    The empty moves of the episode (gripper open, mp = 0 known), added to the robot's earlier ones if seeded
    (``empty_moves``), fit the robot's own mass and friction errors (:class:`ModelCorrections`); the carries'
    equations have them removed, and their RLS state is the object's mass plus the tare, the model's remaining
    error along phi on carries (about 0.00 to -0.03 kg for MId+F+R on the nominal plant). The estimate of the
    object is the RLS state minus the tare; the feedforward uses the apparent mass, what the model needs at its
    platform: the RLS state plus the fitted platform-mass correction.

    Args:
        dynamics: The identified model (MId+F) whose torque at mp = 0 is subtracted.
        regressor: ``"smoothed"`` evaluates tau0 and phi on the :class:`JointStateSmoother` estimate of
            the measured joints; ``"filtered"`` on the :class:`JointStateFilter` estimate, aligned with its
            acceleration lag; ``"reference"`` on the reference interpolated to the torque sample (the classes of
            :data:`~controllers.payload.regressors.REGRESSORS`; the package docstring).
        tare: Apparent payload of the empty gripper on carries (kg) beyond the empty-move fit, from
            :func:`~controllers.payload.tare.tare_from_observations` on payload-free pick cycles; 0 trusts the model.
        nominal_std: Residual standard deviation while moving (N m).
        static_friction: Static friction band f_i per joint (N m); None uses the model's Coulomb friction
            fc_i (MId+F's identified values), which is what the model cannot predict at rest.
        friction_velocity: v_w (rad/s) of :func:`~controllers.payload.tuning.residual_std`.
        correlation_samples: n_c of :func:`~controllers.payload.tuning.residual_std`.
        forgetting_factor: lambda of the RLS within a carry (memory about 1 / (1 - lambda) samples).
        prior_variance: Variance of the mass (kg^2) restored at every pick.
        rest_rate: Samples with every joint slower than this (rad/s) are not used (:data:`REST_RATE`); 0 uses all.
        friction_scale_std: Prior standard deviation of each joint's friction scale error kappa_i
            (dimensionless), fitted on the empty moves and removed from the carries' equations
            (:data:`FRICTION_SCALE_STD`); None trusts the identified friction.
        mass_correction_std: Prior standard deviations of the platform-mass error (kg) and of the arms' relative
            mass error (dimensionless), fitted likewise (:data:`MASS_CORRECTION_STD`); None trusts the
            identified masses.
        empty_moves: Sums of this robot's earlier empty moves (:class:`EmptyMoveSums`, e.g. its calibration
            episodes) that seed the fit of the corrections at every episode; None starts each episode from the
            priors alone (a robot with no history). Needs a fit (a correction std not None).

    Attributes:
        rls: The :class:`PayloadRLS` of the apparent payload (whitened: its noise standard deviation is 1).
        joint_filter: The :class:`JointStateSmoother` of the tracking error (``"smoothed"``: its weights; the
            compiled step keeps the window, :mod:`controllers.payload.smoothed`) or the :class:`JointStateFilter` of
            the measured joints (``"filtered"``); None with ``regressor="reference"``.
        delay: Control periods between the newest observation and the sample whose equation is formed: the
            smoother's lag, the filter's acceleration lag, or 0 with ``regressor="reference"``.
        empty_moves: The checked seed sums (:class:`EmptyMoveSums`), or None.
    """

    def __init__(
        self,
        dynamics: DeltaDynamics,
        *,
        regressor: Literal["smoothed", "filtered", "reference"] = "smoothed",
        tare: float = 0.0,
        nominal_std: float = RESIDUAL_STD,
        static_friction: tuple[float, float, float] | None = None,
        friction_velocity: float = FRICTION_VELOCITY,
        correlation_samples: float = FRICTION_CORRELATION_SAMPLES,
        forgetting_factor: float = 0.999,
        prior_variance: float = PICK_PRIOR_VARIANCE,
        rest_rate: float = REST_RATE,
        friction_scale_std: float | None = FRICTION_SCALE_STD,
        mass_correction_std: tuple[float, float] | None = MASS_CORRECTION_STD,
        empty_moves: EmptyMoveSums | None = None,
    ) -> None:
        if regressor not in REGRESSORS:
            raise ValueError(f"regressor must be one of {tuple(REGRESSORS)}, got {regressor!r}")
        require_positive("nominal_std", nominal_std)
        require_positive("friction_velocity", friction_velocity)
        require_positive("correlation_samples", correlation_samples)
        require_in("tare", tare, unit="kg")
        require_in("rest_rate", rest_rate, 0.0, unit="rad/s")
        if friction_scale_std is not None:
            require_positive("friction_scale_std", friction_scale_std)
        if mass_correction_std is not None:
            if len(mass_correction_std) != 2:
                raise ValueError(f"mass_correction_std must be 2 values (kg, -), got {mass_correction_std!r}")
            for name, std in zip(("platform mass", "arm mass scale"), mass_correction_std, strict=True):
                require_positive(f"mass_correction_std ({name})", std)
        friction = dynamics.parameters.coulomb if static_friction is None else tuple(static_friction)
        if len(friction) != 3 or not all(math.isfinite(f) and f >= 0.0 for f in friction):
            raise ValueError(f"static_friction must be 3 finite values >= 0 N m, got {static_friction!r}")
        self.dynamics = dynamics
        self.regressor = regressor
        self.tare = float(tare)
        self.nominal_std = float(nominal_std)
        self.static_friction = tuple(float(f) for f in friction)
        self.friction_velocity = float(friction_velocity)
        self.correlation_samples = float(correlation_samples)
        self.rest_rate = float(rest_rate)
        self.rls = PayloadRLS(
            forgetting_factor=forgetting_factor, noise_std=1.0, initial_variance=prior_variance, initial_mass=tare
        )
        # Constants of the compiled payload equation; the band's standard deviation is sqrt(n_c) f_i.
        self._equation = np.zeros(1, EQUATION)
        self._equation_bytes = self._equation.view(np.uint8)
        equation = self._equation[0]
        equation["band_std"] = [math.sqrt(self.correlation_samples) * f for f in self.static_friction]
        equation["inverse_friction_velocity"] = 1.0 / self.friction_velocity
        equation["nominal_variance"] = self.nominal_std**2
        equation["viscous"], equation["coulomb"] = dynamics.parameters.viscous, dynamics.parameters.coulomb
        equation["torque_age"], equation["rest_rate"] = TORQUE_AGE, self.rest_rate
        equation["inertia"], equation["gravity"] = dynamics.inertia, dynamics.gravity_amplitude
        # Prior information of the fit's parameters (columns PLATFORM_MASS, ARM_MASS_SCALE, FRICTION_SCALE...):
        # infinite for those held at 0.
        prior = equation["prior_information"]
        prior[:FRICTION_SCALE] = math.inf if mass_correction_std is None else [std**-2 for std in mass_correction_std]
        prior[FRICTION_SCALE:] = math.inf if friction_scale_std is None else friction_scale_std**-2
        equation["fits"] = not np.all(np.isinf(prior))
        # The empty-move least squares and its solution, and views of the fields read at every step.
        self._fit = np.zeros(1, FIT)
        self._fit_bytes = self._fit.view(np.uint8)
        self._solution = self._fit["solution"][0]
        self._regressor: Regressor = REGRESSORS[regressor](dynamics, self._equation_bytes, self._fit_bytes)
        self._moments = self._regressor.moments
        # The "smoothed" regressor's compiled step takes the RLS with it (:func:`smoothed_update`).
        self._smoothed = self._regressor if isinstance(self._regressor, SmoothedRegressor) else None
        self._rls_state = self.rls.state_array
        self._rls_inverse_forgetting, self._rls_noise_variance = self.rls.inverse_forgetting, self.rls.noise_variance
        self.joint_filter: JointStateSmoother | JointStateFilter | None = self._regressor.joint_filter
        self.delay: int = self._regressor.delay
        self.empty_moves = None if empty_moves is None else _checked_sums(empty_moves)
        if self.empty_moves is not None and not self.fits_corrections:
            raise ValueError("empty_moves seed the fit of the model's corrections, but this estimator fits none")
        self._restart_fit()
        self._holding = False
        # The fit and RLS state of the last n updates (keep_checkpoints), in a ring.
        self._fit_checkpoints: NDArray | None = None
        self._fit_checkpoint_bytes = np.zeros(0, np.uint8)  # their bytes, for the compiled step
        self._rls_checkpoints = np.zeros((0, 2))
        self._checkpoint = self._checkpointed = 0  # the ring's next slot; how many of its updates a rollback may undo
        self._skip = 0

    @property
    def mass(self) -> float:
        """Estimated mass of the object held (kg): apparent mass minus tare; 0 while the gripper is open."""
        return self.rls.mass - self.tare if self._holding else 0.0

    @property
    def apparent_mass(self) -> float:
        """The payload (kg) the model needs at its platform, fed forward: the RLS state (the object plus the tare)
        plus the platform-mass correction as solved at the last carry's start."""
        return self.rls.mass + self._solution.item(PLATFORM_MASS)

    @property
    def corrections(self) -> ModelCorrections:
        """The model's corrections fitted on the seeded sums and this episode's empty moves so far (0 before any).

        Solved on a copy: the solution the carries and the feedforward use stays the one of the last carry's start.
        """
        fit = self._fit
        if fit["stale"][0]:
            fit = fit.copy()
            solve_fit(self._equation_bytes, fit.view(np.uint8))
        p = fit["solution"][0]
        return ModelCorrections(float(p[PLATFORM_MASS]), float(p[ARM_MASS_SCALE]), p[FRICTION_SCALE:].copy())

    @property
    def fits_corrections(self) -> bool:
        """Whether the empty moves fit any correction of the model (:class:`ModelCorrections`)."""
        return bool(self._equation["fits"][0])

    @property
    def empty_move_sums(self) -> EmptyMoveSums:
        """The fit's sums so far (:class:`EmptyMoveSums`): the seeded ones plus this episode's empty moves."""
        return EmptyMoveSums(self._fit["information"][0].copy(), self._fit["moment"][0].copy())

    @property
    def empty_move_samples(self) -> int:
        """Samples of this episode's empty moves that entered the fit so far."""
        return int(self._fit["samples"][0])

    @property
    def friction_scale_error(self) -> NDArray[np.float64]:
        """Relative error kappa_i of each joint's identified friction, fitted as :attr:`corrections`, (3,)."""
        return self.corrections.friction_scale

    def reset(self) -> None:
        """Start an episode: nothing held, the fit back to the seeded sums (empty without), RLS at the tare, joint
        filter restarted at the next reading."""
        self.rls.reset(self.tare)
        self._restart_fit()
        self._regressor.reset()
        self._holding = False
        self._skip = 0
        self._checkpointed = 0

    def _restart_fit(self) -> None:
        """The empty-move fit as an episode starts: the seeded sums, to be solved at the first carry, or nothing."""
        self._fit[:] = 0  # every field
        if self.empty_moves is not None:
            fit = self._fit[0]
            fit["information"], fit["moment"] = self.empty_moves.information, self.empty_moves.moment
            fit["stale"] = True

    def update(
        self,
        observation: Observation,
        reference_torque: NDArray[np.float64] | None = None,
        reference_regressor: NDArray[np.float64] | None = None,
    ) -> float:
        """Fuse one observation and return the apparent payload (kg) to feed forward (:attr:`apparent_mass`).

        Arguments as in :meth:`measurement`.
        """
        holding = observation["gripper"].item(0) > 0.5
        if holding != self._holding:
            self._holding = holding
            self._checkpointed = 0  # a rollback never crosses a pick or a release
            if holding:
                self.rls.reset_covariance()
            else:
                self.rls.reset(self.tare)  # released: the object is known to be gone
        checkpoints, slot, skip = self._fit_checkpoints, -1, self._skip > 0
        if checkpoints is not None:
            slot = self._checkpoint
            self._checkpoint = (slot + 1) % len(checkpoints)
            self._checkpointed = min(self._checkpointed + 1, len(checkpoints))
        smoothed = self._smoothed
        if smoothed is not None:  # checkpoint, equation, skip and RLS in one compiled call
            status, apparent_mass = smoothed_update(
                smoothed.state,
                smoothed.model,
                self._equation_bytes,
                self._fit_bytes,
                self._rls_state,
                self._rls_inverse_forgetting,
                self._rls_noise_variance,
                self._fit_checkpoint_bytes,
                self._rls_checkpoints,
                slot,
                skip,
                observation["joint_angles"],
                observation["reference_angles"],
                observation["reference_velocities"],
                observation["reference_accelerations"],
                observation["joint_torques"],
                holding,
            )
            smoothed.raise_invalid(status, observation)
        else:
            if checkpoints is not None:
                checkpoints[slot] = self._fit[0]
                self._rls_checkpoints[slot] = self.rls.state
            moments = self._moments(observation, holding, reference_torque, reference_regressor)
            if skip:
                self._fit[0] = checkpoints[slot]  # the sample entered neither the fit nor the RLS
            elif moments is not None:
                self.rls.update_moments(*moments)
            apparent_mass = self.apparent_mass
        if skip:
            self._skip -= 1
        return apparent_mass

    def keep_checkpoints(self, samples: int) -> None:
        """Keep the fit and RLS state of the last ``samples`` updates so that :meth:`rollback` can undo them."""
        self._fit_checkpoints = np.zeros(samples, FIT)
        self._fit_checkpoint_bytes = self._fit_checkpoints.view(np.uint8)
        self._rls_checkpoints = np.zeros((samples, 2))
        self._checkpoint = self._checkpointed = 0

    def skip(self, samples: int) -> None:
        """Leave the equations of the next ``samples`` updates out of the fit and the RLS (faulty samples);
        needs :meth:`keep_checkpoints`."""
        if self._fit_checkpoints is None:
            raise RuntimeError("skip() needs keep_checkpoints()")
        self._skip = max(self._skip, samples)

    def rollback(self, samples: int) -> None:
        """Undo the last ``samples`` updates' equations (samples found faulty late), as far back as the checkpoints
        kept reach within this episode and since the last pick or release."""
        if self._fit_checkpoints is None:
            raise RuntimeError("rollback() needs keep_checkpoints()")
        kept = len(self._fit_checkpoints)
        if not 1 <= samples <= kept:
            raise ValueError(f"samples must be in [1, {kept}] (the checkpoints kept), got {samples!r}")
        samples = min(samples, self._checkpointed)
        if samples == 0:
            return
        self._checkpointed -= samples
        slot = (self._checkpoint - samples) % kept
        self._fit[0] = self._fit_checkpoints[slot]
        self.rls.state = self._rls_checkpoints[slot]

    def drop_object(self) -> None:
        """The object is gone although the gripper still holds (a detected slip): the estimate restarts at the tare
        with the variance :data:`DROP_VARIANCE`; the equations still in the pipeline (of samples before the slip was
        found, up to :attr:`delay` ago), and those whose smoothing window straddles the slip, are left out; needs
        :meth:`keep_checkpoints`."""
        self.rls.state = (self.tare, DROP_VARIANCE)
        self.skip(4 * self.delay + 1)

    def measurement(
        self,
        observation: Observation,
        reference_torque: NDArray[np.float64] | None = None,
        reference_regressor: NDArray[np.float64] | None = None,
    ) -> tuple[float, float] | None:
        """This step's weighted payload equation as its moments, or None with the gripper open or every joint at
        rest (:data:`REST_RATE`). With the gripper open, the sample enters the fit of the model's corrections
        instead (:class:`ModelCorrections`), which are removed from the carries' equations.

        With the weights w_i = 1 / sigma_i^2 (:func:`~controllers.payload.tuning.residual_std`), the moments are
        sum_i w_i phi_i^2 ((N m/kg)^2) and sum_i w_i phi_i y_i (N^2 m^2/kg): all that RLS with R = diag(sigma_i^2)
        needs of a sample (:meth:`PayloadRLS.update_moments` with a noise standard deviation of 1).

        Call once per control step, in order (it keeps the previous reference and the joint filter).

        Args:
            observation: The env's observation; reads ``joint_torques``, ``gripper`` and, by regressor, the
                reference (``reference_angles``, ``reference_velocities``, ``reference_accelerations``) and
                ``joint_angles``: ``"smoothed"`` both, ``"reference"`` the reference, ``"filtered"`` the angles.
            reference_torque: tau0 (N m) at this step's reference, if the caller has it already
                (``regressor="reference"``, which computes it otherwise; the others do not use it).
            reference_regressor: phi (N m/kg) at this step's reference, with ``reference_torque``.
        """
        holding = observation["gripper"].item(0) > 0.5
        return self._moments(observation, holding, reference_torque, reference_regressor)
