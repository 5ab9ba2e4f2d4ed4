"""Online payload mass estimation for the feedforward controllers (the paper's section 5, docs/design.md section 6).

The payload enters the identified model linearly, tau(mp) = tau0 + mp phi with tau0 = tau_model(mp = 0) and
phi = J^T (xdd + g e_z) (``DeltaDynamics.torque_and_payload_regressor``), so each control step gives three
equations in the one unknown mp,

    y = tau_measured - tau0 = phi mp + e,

solved by recursive least squares with forgetting (:class:`~controllers.estimation.PayloadRLS`, filterpy's
fading-memory Kalman filter). What biases the estimate on this plant, and what is done about it:

- **Friction near zero speed.** At rest the Coulomb friction is a constraint force anywhere in [-fc_i, fc_i]
  and the plant adds a Stribeck excess near zero speed, while the model predicts fc_i sign(thd_i) (0 at rest);
  while a joint starts or stops, its friction is not the model's either. With phi_i of a few N m/kg at rest
  (gravity alone), 4 N m of unknown friction is a kilogram of error. Each joint's equation is therefore
  weighted by a standard deviation that grows as |thd_i| falls (:func:`residual_std`): the nominal residual
  plus the static friction band fc_i, fading as exp(-(thd_i / v_w)^2) with v_w = 1 rad/s
  (:data:`FRICTION_VELOCITY`). That error is one constant per stop, not white noise, so its variance is
  inflated by the samples of a dwell: a whole stop counts as one equation, instead of outweighing the
  moving samples of the carry that follows it. Weighting is done by whitening
  (dividing phi_i and y_i by sigma_i), which is exactly RLS with R = diag(sigma_i^2) per update.
- **Torque timing.** A measured torque is ``delta_env.sensors.MEASURED_TORQUE_DELAY`` older than the
  encoder sample it comes with; every regressor below evaluates the model at the joint state interpolated
  linearly back to that instant, between the sample and the one before.
- **Joint states.** With ``regressor="smoothed"`` (the default) tau0 and phi are evaluated on the
  fixed-lag Kalman smoother's estimate of sample k - L (:class:`~controllers.estimation.JointStateSmoother`,
  L = 5 ms) and compared with the torque measured with that sample. The smoother runs on the tracking error
  theta - theta_ref, and the reference's exact derivatives at sample k - L are added back: what the reference
  describes needs no smoothing, and where its jerk steps (the start of a lift, 1e4 rad/s^3 at 6 g) the smoother
  follows only the robot's departure from it. ``regressor="filtered"`` uses the
  causal Kalman filter (:class:`~controllers.estimation.JointStateFilter`) instead, which estimates angle
  and rate without lag but the acceleration about 3 ms late (:func:`acceleration_lag`): the model is
  evaluated at (theta_{k-D}, theta_dot_{k-D}, theta_ddot_k), D = that lag in samples, with the torque of
  sample k - D. That alignment is exact for a constant jerk only; where the jerk changes, the filter's
  acceleration error has another shape, which biases light payload estimates by several percent for
  100 ms and more in the middle of a carry; the smoother has no such bias within its model.
  ``regressor="reference"`` evaluates tau0 and phi on the reference instead: no lag and no noise, but it
  silently assumes the robot is where the reference is, so the tracking transient right after a pick (the
  payload not yet fed forward) biases the estimate when it matters most; ``python -m eval`` runs both.
- **Model error along phi (the tare).** The model should have the forearm pairs as rods (MId+F+R,
  ``DeltaDynamics(forearm_rods=True)``): MId+F lumps each pair into two point masses, more inertia than two
  rods, so even at the plant's exact states it needs -0.1 kg of payload to match the plant with an empty
  gripper, and how much depends on the path (+0.3 kg in the first 30 ms of a lift). With MId+F+R the tare
  is 0.00 to -0.03 kg. Like a scale, the estimator is tared all the same: the apparent
  payload with nothing picked that the corrections fitted on the empty moves leave (a few grams) is measured
  on payload-free pick cycles (:func:`tare_from_observations`) and subtracted from the estimate; the
  feedforward keeps the apparent mass, which is what the model needs.
- **Gripper events.** The controller knows when the gripper closes and opens (``observation["gripper"]``).
  A pick is an abrupt change of mp that forgetting tracks slowly, so the covariance is reset there. While
  the gripper is open no object is carried: mp = 0 is known, so on release the estimate goes back to 0
  (the apparent mass to the tare; the object is gone) and the RLS does not run until the next pick (the
  suction cup belongs to m0).
- **At rest.** While every joint is slower than :data:`REST_RATE` (the dwell in which the gripper closes),
  static friction holds an unknown share of the load and the equation is not used: the estimate starts
  from the prior when the lift begins, instead of jumping on friction before it.
- **Masses and friction of the robot at hand.** A robot's masses and friction are not exactly the identified
  ones (domain randomization: +-10 % and +-30 %). A platform-mass error (m0, and the platform's share 3 m2 of
  the forearms) is exactly a payload error; an arm-mass error adds d_arm (I thdd + G), whose gravity part
  resembles phi at rest; a friction error is odd in the rate, so it biases the carry and the empty move back
  with opposite signs. The empty moves (mp = 0 known) fit all three by weighted least squares with priors
  (:class:`ModelCorrections`, :data:`MASS_CORRECTION_STD`, :data:`FRICTION_SCALE_STD`) and the carries'
  equations have them removed. On a carry dm and mp are the same column, so nothing in it tells them apart:
  a carry is corrected only if an empty move came before it in the episode (the env's default start, at a
  place point, gives every carry one; with ``start="pick"`` the first carry has none) or the robot's earlier
  empty moves seed the fit (:class:`EmptyMoveSums`, its calibration episodes). From one empty move the fitted
  platform mass is uncertain (it is collinear with the arm-mass scale there) and carries about 8 g of torque
  noise into the carry; the seeded sums of the same robot remove that.
- Torque ripple (1 N m, fast in position) and the measured-torque noise are zero-mean over a carry and go
  into the nominal residual standard deviation.

The modules: :mod:`~controllers.payload.tuning` (the settings and the weighting), :mod:`~controllers.payload.equation`
(the compiled payload equation and empty-move fit), :mod:`~controllers.payload.regressors` (the joint states the
equation is formed at, one class each), :mod:`~controllers.payload.fit` (:class:`CorrectionFit`, the fit of the
model's corrections), :mod:`~controllers.payload.checkpoints` (:class:`CheckpointRing`),
:mod:`~controllers.payload.estimator` (:class:`PayloadEstimator`, which composes them with the
:class:`~controllers.estimation.PayloadRLS`) and :mod:`~controllers.payload.tare`.
"""

from controllers.payload.checkpoints import CheckpointRing
from controllers.payload.estimator import PayloadEstimator
from controllers.payload.fit import CorrectionFit, EmptyMoveSums, ModelCorrections
from controllers.payload.regressors import acceleration_lag
from controllers.payload.tare import Tare, tare_from_observations
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

__all__ = [
    "CONSISTENT_SAMPLES",
    "DROP_VARIANCE",
    "FRICTION_CORRELATION_SAMPLES",
    "FRICTION_SCALE_STD",
    "FRICTION_VELOCITY",
    "INNOVATION_GATE",
    "MASS_CORRECTION_STD",
    "PICK_PRIOR_VARIANCE",
    "RESIDUAL_STD",
    "REST_RATE",
    "CheckpointRing",
    "CorrectionFit",
    "EmptyMoveSums",
    "ModelCorrections",
    "PayloadEstimator",
    "Tare",
    "acceleration_lag",
    "residual_std",
    "tare_from_observations",
]
