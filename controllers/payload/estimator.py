"""The payload estimator: the weighted payload equation of each control step (:mod:`controllers.payload.regressors`),
fused by RLS (:class:`PayloadRLS`), with the model's corrections fitted on the empty moves
(:class:`~controllers.payload.fit.CorrectionFit`) and the last updates kept to undo
(:class:`~controllers.payload.checkpoints.CheckpointRing`). The package docstring gives the physics; docs/design.md
section 6."""

from __future__ import annotations

import math
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from controllers.base import Observation
from controllers.dynamics import DeltaDynamics
from controllers.estimation import JointStateFilter, JointStateSmoother, PayloadRLS
from controllers.payload.checkpoints import CheckpointRing
from controllers.payload.equation import equation_constants
from controllers.payload.fit import CorrectionFit, EmptyMoveSums, ModelCorrections
from controllers.payload.regressors import REGRESSORS, Regressor
from controllers.payload.tuning import (
    CONSISTENT_SAMPLES,
    DROP_VARIANCE,
    FRICTION_CORRELATION_SAMPLES,
    FRICTION_SCALE_STD,
    FRICTION_VELOCITY,
    INNOVATION_GATE,
    MASS_CORRECTION_STD,
    PICK_PRIOR_VARIANCE,
    RESIDUAL_STD,
    REST_RATE,
    residual_std,
)
from delta_env.sensors import CONTROL_PERIOD, MEASURED_TORQUE_DELAY, require_torque_age
from delta_env.validation import require_in, require_positive


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
        torque_delay: How much older (s) a torque reading is than its encoder sample: the plant's physics step
            (:data:`~delta_env.sensors.MEASURED_TORQUE_DELAY` by default); the equation of a sample is formed at the
            state interpolated that far back towards the previous one.

    Attributes:
        rls: The :class:`PayloadRLS` of the apparent payload (whitened: its noise standard deviation is 1).
        fit: The :class:`~controllers.payload.fit.CorrectionFit` of the model's corrections on the empty moves.
        checkpoints: The :class:`~controllers.payload.checkpoints.CheckpointRing` that :meth:`rollback` undoes
            updates from, or None before :meth:`keep_checkpoints`.
        joint_filter: The :class:`JointStateSmoother` of the tracking error (``"smoothed"``: its weights; the
            compiled regressor keeps the window) or the :class:`JointStateFilter` of the measured joints
            (``"filtered"``); None with ``regressor="reference"``.
        delay: Control periods between the newest observation and the sample whose equation is formed: the
            smoother's lag, the filter's acceleration lag, or 0 with ``regressor="reference"``.
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
        torque_delay: float = MEASURED_TORQUE_DELAY,
    ) -> None:
        if regressor not in REGRESSORS:
            raise ValueError(f"regressor must be one of {tuple(REGRESSORS)}, got {regressor!r}")
        require_positive("nominal_std", nominal_std)
        require_positive("friction_velocity", friction_velocity)
        require_positive("correlation_samples", correlation_samples)
        require_in("tare", tare, unit="kg")
        require_in("rest_rate", rest_rate, 0.0, unit="rad/s")
        require_torque_age(torque_delay)
        friction = dynamics.parameters.coulomb if static_friction is None else tuple(static_friction)
        if len(friction) != 3 or not all(math.isfinite(f) and f >= 0.0 for f in friction):
            raise ValueError(f"static_friction must be 3 finite values >= 0 N m, got {static_friction!r}")
        self.dynamics = dynamics
        self.regressor = regressor
        self.tare = float(tare)
        # the equations' weighting, which predicted_variance repeats along a plan
        self._weighting = (np.asarray(friction, dtype=float), float(nominal_std), float(friction_velocity))
        self._weighting += (float(correlation_samples),)
        self._rest_rate = float(rest_rate)
        self.rls = PayloadRLS(
            forgetting_factor=forgetting_factor, noise_std=1.0, initial_variance=prior_variance, initial_mass=tare
        )
        self.fit = CorrectionFit(mass_correction_std, friction_scale_std, empty_moves)
        equation = equation_constants(
            dynamics,
            friction,
            float(nominal_std),
            float(friction_velocity),
            float(correlation_samples),
            rest_rate,
            torque_delay / CONTROL_PERIOD,
        )
        self._regressor: Regressor = REGRESSORS[regressor](dynamics, equation, self.fit.state)
        self._moments = self._regressor.moments
        self.joint_filter: JointStateSmoother | JointStateFilter | None = self._regressor.joint_filter
        self.delay: int = self._regressor.delay
        self.checkpoints: CheckpointRing | None = None
        self._holding = False
        self._skip = 0  # updates still to leave out (skip)
        self._held_out = False  # the carry's equations left out until they agree with the estimate (hold_out)
        self._consistent = 0  # equations in a row that did, during a hold-out

    @property
    def mass(self) -> float:
        """Estimated mass of the object held (kg): apparent mass minus tare; 0 while the gripper is open."""
        return self.rls.x - self.tare if self._holding else 0.0

    @property
    def apparent_mass(self) -> float:
        """The payload (kg) the model needs at its platform, fed forward: the RLS state (the object plus the tare)
        plus the platform-mass correction as solved at the last carry's start."""
        return self.rls.x + self.fit.platform_mass

    @property
    def corrections(self) -> ModelCorrections:
        """The model's corrections fitted so far (:attr:`CorrectionFit.corrections`)."""
        return self.fit.corrections

    @property
    def fits_corrections(self) -> bool:
        """Whether the empty moves fit any correction of the model (:class:`ModelCorrections`)."""
        return self.fit.fits

    @property
    def measures_state(self) -> bool:
        """Whether its equations (and the corrections fitted on the empty moves) are formed at the robot's measured
        state (``"smoothed"``, ``"filtered"``), not at the reference, whose fit absorbs the robot's departure from it:
        the corrections the fault monitor's residual may take."""
        return self.regressor != "reference"

    @property
    def empty_move_sums(self) -> EmptyMoveSums:
        """The fit's sums so far (:class:`EmptyMoveSums`): the seeded ones plus this episode's empty moves."""
        return self.fit.sums

    @property
    def empty_move_samples(self) -> int:
        """Samples of this episode's empty moves that entered the fit so far."""
        return self.fit.samples

    @property
    def friction_scale_error(self) -> NDArray[np.float64]:
        """Relative error kappa_i of each joint's identified friction, fitted as :attr:`corrections`, (3,)."""
        return self.fit.corrections.friction_scale

    def reset(self) -> None:
        """Start an episode: nothing held, the fit back to the seeded sums (empty without), RLS at the tare, joint
        filter restarted at the next reading."""
        self.rls.reset(self.tare)
        self.fit.restart()
        self._regressor.reset()
        self._holding = False
        self._skip = 0
        self._held_out = False
        if self.checkpoints is not None:
            self.checkpoints.forget()

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
        rls, checkpoints = self.rls, self.checkpoints
        if holding != self._holding:
            self._holding = holding
            self._held_out = False  # a hold-out ends with its carry
            if checkpoints is not None:
                checkpoints.forget()  # a rollback never crosses a pick or a release
            if holding:
                rls.reset_covariance()
            else:
                rls.reset(self.tare)  # released: the object is known to be gone
        if checkpoints is not None:
            checkpoints.save(self.fit, rls)
        moments = self._moments(observation, holding, reference_torque, reference_regressor)
        held_out = self._held_out
        if held_out and moments is not None:
            consistent = abs(rls.normalized_innovation(*moments)) <= INNOVATION_GATE
            self._consistent = self._consistent + 1 if consistent else 0
            self._held_out = self._consistent < CONSISTENT_SAMPLES
        if self._skip:
            self._skip -= 1
            checkpoints.restore_fit(self.fit)  # the sample entered neither the fit nor the RLS
        elif moments is not None and not held_out:
            rls.update_moments(*moments)
        return self.apparent_mass

    def keep_checkpoints(self, samples: int) -> None:
        """Keep the fit and RLS state of the last ``samples`` updates so that :meth:`rollback` can undo them."""
        self.checkpoints = CheckpointRing(samples, self.fit)

    def skip(self, samples: int) -> None:
        """Leave the equations of the next ``samples`` updates out of the fit and the RLS (faulty samples);
        needs :meth:`keep_checkpoints`."""
        if self.checkpoints is None:
            raise RuntimeError("skip() needs keep_checkpoints()")
        self._skip = max(self._skip, samples)

    def hold_out(self) -> None:
        """Leave the carry's equations out from the next update on until :data:`CONSISTENT_SAMPLES` of them in a
        row agree with the estimate (normalized innovation within :data:`INNOVATION_GATE`), or the carry ends: after a
        disturbance whose end the equations themselves show (a push, and the servo's recovery from it, which an
        equation formed at the reference reads as payload). Nothing while the gripper is open."""
        self._held_out = self._holding
        self._consistent = 0

    @property
    def held_out(self) -> bool:
        """Whether the carry's equations are being left out since :meth:`hold_out`."""
        return self._held_out

    def rollback(self, samples: int) -> None:
        """Undo the last ``samples`` updates' equations (samples found faulty late), as far back as the checkpoints
        kept reach within this episode and since the last pick or release."""
        if self.checkpoints is None:
            raise RuntimeError("rollback() needs keep_checkpoints()")
        self.checkpoints.rollback(samples, self.fit, self.rls)

    def drop_object(self) -> None:
        """The object is gone although the gripper still holds (a detected slip): the estimate restarts at the tare
        with the variance :data:`DROP_VARIANCE`; the equations still in the pipeline (of samples before the slip was
        found, up to :attr:`delay` ago), and those whose smoothing window straddles the slip, are left out; needs
        :meth:`keep_checkpoints`."""
        self.rls.reset(self.tare, DROP_VARIANCE)
        self._held_out = False  # the restarted estimate has nothing left to agree with
        self.skip(4 * self.delay + 1)

    def predicted_variance(self, theta: ArrayLike, theta_dot: ArrayLike, theta_ddot: ArrayLike) -> NDArray[np.float64]:
        """The variance (kg^2) of the mass that :attr:`rls` will hold after each control step of a carry along a
        planned joint trajectory, known before the carry runs.

        RLS's variance does not depend on the readings, only on each sample's information
        I_j = sum_i w_i phi_i^2 (the weights of :func:`~controllers.payload.tuning.residual_std` at the sample's
        rates, 0 with every joint at rest: :meth:`measurement`). The covariance is reset at the pick, the first
        step of the carry, and step k fuses the equation of sample k - :attr:`delay` (those before the carry are at
        rest), so P_k = (lambda / P_{k-1} + I_{k-delay})^-1 from P_{-1} = the prior variance. This assumes the
        robot is where the plan is: its lag behind the reference over the lift's first milliseconds is not in it.

        Args:
            theta: Planned joint angles (rad) of the carry's samples at the control period, ``(n, 3)``, sample 0 the
                departure (the step the gripper holds first).
            theta_dot: Their rates (rad/s), ``(n, 3)``.
            theta_ddot: Their accelerations (rad/s^2), ``(n, 3)``.

        Returns:
            P after each of the n steps (kg^2), ``(n,)``.
        """
        states = [np.asarray(values, dtype=float) for values in (theta, theta_dot, theta_ddot)]
        if any(values.ndim != 2 or values.shape[1] != 3 or values.shape != states[0].shape for values in states):
            shapes = [values.shape for values in states]
            raise ValueError(f"theta, theta_dot and theta_ddot must each be (n, 3) of one n, got shapes {shapes}")
        if not all(np.isfinite(values).all() for values in states):
            raise ValueError("theta, theta_dot and theta_ddot must be finite")
        rates = states[1]
        phi = self.dynamics.payload_regressor(*states)
        information = np.sum((phi / residual_std(rates, *self._weighting)) ** 2, axis=-1)
        information[np.all(np.abs(rates) < self._rest_rate, axis=-1)] = 0.0
        fused = np.concatenate((np.zeros(min(self.delay, len(information))), information))[: len(information)]
        variance = np.empty(len(fused))
        previous = self.rls.initial_variance
        for step, sample_information in enumerate(fused):
            # with R = 1 (whitened equations): 1 / P+ = lambda / P + I (PayloadRLS.update_moments)
            previous = 1.0 / (self.rls.forgetting_factor / previous + sample_information)
            variance[step] = previous
        return variance

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
        needs of a sample (:meth:`PayloadRLS.update_moments` with R = 1).

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
