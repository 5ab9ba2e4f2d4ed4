"""Controllers: the fast single-sample model, PD + feedforward, payload RLS on the plant, and no truth access."""

import dataclasses
import inspect
from collections.abc import Iterator, Mapping

import numpy as np
import pytest
from filterpy.kalman import KalmanFilter
from numpy.testing import assert_allclose, assert_array_equal

from controllers.base import PDController
from controllers.dynamics import DeltaDynamics, ModelParameters
from controllers.feedforward import FeedforwardController
from controllers.payload import (
    FRICTION_SCALE_STD,
    MASS_CORRECTION_STD,
    PICK_PRIOR_VARIANCE,
    EmptyMoveSums,
    PayloadEstimator,
    residual_std,
    tare_from_observations,
)
from controllers.registry import (
    CONTROLLER_LABELS,
    ESTIMATOR_REGRESSORS,
    ControllerSetup,
    build_controller,
    estimation_model,
)
from delta_env import NOMINAL_MASSES, DeltaGeometry, DeltaMasses
from delta_env.config import PlantConfig, PlantRealism, RandomizationRanges
from delta_env.env import DeltaPickPlaceEnv
from delta_env.geometry import GRAVITY
from delta_env.scenario import PickPlaceTask, Scenario, preset
from delta_env.sensors import CONTROL_PERIOD, MEASURED_TORQUE_DELAY
from eval.calibration import Calibration, calibrate_tares, calibrated_setup
from eval.episodes import EpisodeRecord, run_episode


@pytest.mark.parametrize("forearm_rods", [False, True])
def test_single_sample_model_equals_the_batched_model(
    random_joint_states, model_parameters: ModelParameters | None, forearm_rods: bool
) -> None:
    model = DeltaDynamics.nominal(model_parameters, forearm_rods=forearm_rods)
    theta, theta_dot, theta_ddot = random_joint_states(300, seed=11)
    theta_dot[:10, 1] = 0.0  # sign(0) = 0 in both paths
    tau0 = model.inverse_dynamics(theta, theta_dot, theta_ddot)
    phi = model.payload_regressor(theta, theta_dot, theta_ddot)
    for n in range(len(theta)):
        fast_tau0, fast_phi = model.torque_and_payload_regressor(theta[n], theta_dot[n], theta_ddot[n])
        assert_allclose(fast_tau0, tau0[n], rtol=0.0, atol=1e-9)
        assert_allclose(fast_phi, phi[n], rtol=0.0, atol=1e-9)


@pytest.mark.parametrize(
    ("l2", "theta", "message"),
    [
        (0.95, [np.nan, 0.0, 0.0], "finite"),
        (0.95, [0.0, 0.0], "3 values"),
        (0.4, [0.0, 0.0, 0.0], "no real solution"),  # forearms too short to meet
    ],
)
def test_single_sample_model_rejects_bad_states(l2: float, theta: list[float], message: str) -> None:
    masses = NOMINAL_MASSES
    model = DeltaDynamics(DeltaGeometry(l2=l2), m1=masses.m1, m2=masses.m2, m0=masses.m0)
    with pytest.raises(ValueError, match=message):
        model.torque_and_payload_regressor(theta, np.zeros(3), np.zeros(3))


# ------------------------------------------------------------------------------------------------
# Controllers on the plant

EPISODE_SEED, CALIBRATION_SEED = 3, 1003
RLS_KEYS = sorted(ESTIMATOR_REGRESSORS)


@pytest.fixture(scope="module")
def tared_setup(controller_setup: ControllerSetup) -> ControllerSetup:
    """The setup with each RLS controller's tare from one payload-free calibration episode of three cycles (one
    carry's apparent payload varies by about 10 g from carry to carry)."""
    tares = calibrate_tares(RLS_KEYS, controller_setup, [CALIBRATION_SEED], n_cycles=3).tares
    return dataclasses.replace(controller_setup, tares=tares)


@pytest.fixture(scope="module")
def records(tared_setup: ControllerSetup) -> dict[str, EpisodeRecord]:
    """Every controller on the same seeded one-cycle episode carrying 3 kg."""
    env = DeltaPickPlaceEnv(n_cycles=1)
    return {
        key: run_episode(env, build_controller(key, tared_setup, env), EPISODE_SEED, [3.0]) for key in CONTROLLER_LABELS
    }


RECORDED_TRACKING_RMS_MM = {
    "pd": 5.36,
    "mkh": 0.527,
    "mid": 0.342,
    "mid_f": 0.320,
    "mid_f_r": 0.341,
    "mid_f_rls": 0.105,
    "mid_f_rls_ref": 0.0869,
    "mid_f_rls_lag": 0.0834,
    "oracle": 0.0072,
    "residual": 0.0442,
}
"""Tracking RMS (mm) of each controller on the episode of :func:`records` (seed 3, one cycle, 3 kg).

The model rows and the bound run the servo layer (the default). On seeds 4-6 every row lies within 33 % of these (the
RLS rows' carries are short, and one stop more or less in position moves them), so :data:`TRACKING_RMS_RTOL` holds a
change that redraws the episode and fails a regression of 1.4 times or more. The bands around PD, the model rows
and the bound do not overlap, so they hold the ranking too (feedforward beats PD, nothing beats the bound). Update a
row, with its README table, when it improves."""

TRACKING_RMS_RTOL = 0.35


@pytest.mark.parametrize("key", list(CONTROLLER_LABELS))
def test_each_controller_tracks_a_seeded_episode(key: str, records: dict[str, EpisodeRecord]) -> None:
    record = records[key]
    assert not record.diverged and record.saturated_steps == 0
    rms = record.metrics()["tracking_rms_mm"]
    assert rms == pytest.approx(RECORDED_TRACKING_RMS_MM[key], rel=TRACKING_RMS_RTOL)


@pytest.mark.parametrize(
    ("variant", "masses", "deadline_ms"),
    [
        # Measured: 33 and 54 ms, end errors -0.17 and +0.89 %.
        ("realistic", (3.8, 1.0), 90.0),
        # MKH is exact on the ideal plant: no tare, no friction. Measured: 19 and 28 ms, +0.045 and +0.066 %.
        ("ideal", (2.0, 0.5), 45.0),
    ],
)
def test_rls_converges_to_the_true_payload_on_the_plant(
    tared_setup: ControllerSetup, variant: str, masses: tuple[float, ...], deadline_ms: float
) -> None:
    if variant == "ideal":
        env = DeltaPickPlaceEnv(plant=PlantConfig.ideal(), n_cycles=len(masses))
        dynamics = DeltaDynamics.nominal()
        estimator, tolerance = PayloadEstimator(dynamics), 0.001
    else:
        env = DeltaPickPlaceEnv(n_cycles=len(masses))
        dynamics = estimation_model(tared_setup)
        estimator, tolerance = PayloadEstimator(dynamics, tare=tared_setup.tares["mid_f_rls"]), 0.015
    controller = FeedforwardController("MId+F+RLS", dynamics, estimator=estimator)
    record = run_episode(env, controller, seed=8, payload_masses=masses)
    carries = record.carries()
    assert [carry.mass for carry in carries] == list(masses)
    for carry in carries:
        assert abs(carry.end_error_percent) < 100.0 * tolerance
        assert carry.settling_time_ms <= deadline_ms
    empty = record.payload_mass[:-1] == 0.0
    assert np.all(record.payload_estimate[empty] == 0.0), "0 kg with the gripper open"


def test_half_kilogram_objects_settle_within_150_ms(tared_setup: ControllerSetup) -> None:
    """0.5 kg, the lightest object the settling target covers (+-5 % is 25 g), on 20 seeded one-cycle episodes:
    every end-of-carry estimate within +-5 % and at least 18 of 20 within it by 150 ms after the pick. Measured:
    23 of 24 seeds (0-23); the estimate from one empty move carries about 8 g of torque noise through the fitted
    platform mass, so a rare carry settles late (seed 8: 192 ms)."""
    env = DeltaPickPlaceEnv(n_cycles=1)
    controller = build_controller("mid_f_rls", tared_setup, env)
    carries = [run_episode(env, controller, seed=seed, payload_masses=[0.5]).carries()[0] for seed in range(20)]
    end_errors = np.array([carry.end_error_percent for carry in carries])
    settling = np.array([carry.settling_time_ms for carry in carries])
    assert np.all(np.abs(end_errors) < 5.0), end_errors
    assert np.count_nonzero(settling <= 150.0) >= 18, settling


def test_whitened_rls_is_rls_with_per_joint_noise(random_joint_states, controller_setup) -> None:
    # Dividing row i by sigma_i is the weighted least squares with R = diag(sigma_i^2), here through filterpy.
    dynamics = DeltaDynamics.nominal(controller_setup.mid_f)
    estimator = PayloadEstimator(dynamics, regressor="reference", rest_rate=0.0)  # every sample used
    estimator.reset()
    theta, theta_dot, theta_ddot = random_joint_states(200, seed=4)
    theta_dot[::3] *= 0.01  # slow samples, where the friction band weighs in
    torques = np.random.default_rng(5).normal(0.0, 20.0, theta.shape)
    reference = KalmanFilter(dim_x=1, dim_z=3)
    reference.x, reference.P, reference.Q = np.zeros(1), np.array([[PICK_PRIOR_VARIANCE]]), np.zeros((1, 1))
    reference.alpha = 1.0 / np.sqrt(0.999)
    previous = None
    for n in range(len(theta)):
        observation = {
            "reference_angles": theta[n],
            "reference_velocities": theta_dot[n],
            "reference_accelerations": theta_ddot[n],
            "joint_torques": torques[n],
            "gripper": np.ones(1),
        }
        mass = estimator.update(observation)
        current = (*dynamics.torque_and_payload_regressor(theta[n], theta_dot[n], theta_ddot[n]), theta_dot[n])
        # The model is taken at the torque's instant, MEASURED_TORQUE_DELAY back towards the previous reference.
        earlier = current if previous is None else previous
        age = MEASURED_TORQUE_DELAY / CONTROL_PERIOD
        tau0, phi, rate = ((1.0 - age) * b + age * a for a, b in zip(earlier, current, strict=True))
        previous = current
        reference.predict()
        reference.update(
            torques[n] - tau0, R=np.diag(residual_std(rate, controller_setup.mid_f.coulomb) ** 2), H=phi[:, None]
        )
        assert mass == pytest.approx(float(reference.x[0]), rel=1e-9, abs=1e-12)


# ------------------------------------------------------------------------------------------------
# No controller reads the plant's truth

DOCUMENTED_KEYS = frozenset(DeltaPickPlaceEnv(n_cycles=1).observation_space.spaces)
FORBIDDEN_TYPES = ("Env", "DeltaPlant", "PlantConfig", "Oracle", "MjModel", "MjData")


class WatchedObservation(Mapping):
    """An observation that only yields the documented keys and records which ones are read."""

    def __init__(self, observation: Mapping, reads: set[str]) -> None:
        self._observation = observation
        self._reads = reads

    def __getitem__(self, key: str) -> np.ndarray:
        if key not in DOCUMENTED_KEYS:
            raise KeyError(f"{key!r} is not a documented observation key")
        self._reads.add(key)
        return self._observation[key]

    def __iter__(self) -> Iterator[str]:
        return iter(self._observation)

    def __len__(self) -> int:
        return len(self._observation)


@pytest.fixture(scope="module")
def recorded_observations() -> list:
    """The observations of a seeded one-cycle episode carrying 3.8 kg under PD."""
    env = DeltaPickPlaceEnv(n_cycles=1)
    return run_episode(env, PDController(), EPISODE_SEED, [3.8], keep_observations=True).observations


@pytest.mark.parametrize("constructor", [PDController, FeedforwardController, PayloadEstimator, DeltaDynamics])
def test_controller_constructors_take_no_env_or_plant(constructor: type) -> None:
    for parameter in inspect.signature(constructor).parameters.values():
        annotation = str(parameter.annotation)
        assert not any(name in annotation for name in FORBIDDEN_TYPES), f"{constructor.__name__}({parameter})"


@pytest.mark.parametrize("key", [key for key in CONTROLLER_LABELS if key != "oracle"])
def test_actions_depend_on_the_observations_only(controller_setup, key: str, recorded_observations: list) -> None:
    # The same observations, replayed while a live plant in this process carries another hidden payload,
    # give bit-identical actions: the controller has no way to the truth but the observation.
    reads: set[str] = set()
    actions = []
    for hidden_payload in (0.0, 4.0):
        env = DeltaPickPlaceEnv(n_cycles=1)
        env.reset(seed=EPISODE_SEED, options={"payload_masses": [hidden_payload]})
        controller = build_controller(key, controller_setup)  # no env
        controller.reset()
        episode, live = [], True
        for observation in recorded_observations[:-1]:
            episode.append(controller(WatchedObservation(observation, reads)))
            if live:  # the open-loop plant may end its episode (diverge) first: it is only a distraction
                *_, terminated, truncated, _ = env.step(episode[-1])
                live = not (terminated or truncated)
        actions.append(np.array(episode))
    assert_array_equal(actions[0], actions[1])
    assert {"reference_angles", "joint_angles"} <= reads <= DOCUMENTED_KEYS
    if key in ESTIMATOR_REGRESSORS:
        assert {"joint_torques", "gripper"} <= reads


def test_oracle_is_a_labelled_bound_that_must_be_told_the_truth(controller_setup) -> None:
    env = DeltaPickPlaceEnv(n_cycles=1)
    oracle = build_controller("oracle", controller_setup, env)
    assert "bound" in oracle.name and "bound" in CONTROLLER_LABELS["oracle"]
    observation, _ = env.reset(seed=EPISODE_SEED)
    oracle.reset()
    with pytest.raises(RuntimeError, match="set_payload_masses"):
        for _ in env.trajectory.time:
            observation, *_ = env.step(oracle(observation))


def test_lag_compensated_row_tracks_better_than_its_base_and_needs_the_lag(
    controller_setup: ControllerSetup, records: dict[str, EpisodeRecord]
) -> None:
    rms = {name: record.metrics()["tracking_rms_mm"] for name, record in records.items()}
    # Leading the 1 ms drive lag: measured 0.078 -> 0.063 mm (-19 %) on this 3 kg episode behind the servo layer
    # (0.40 -> 0.29 mm behind the paper's PD); half the gain fails.
    assert rms["mid_f_rls_lag"] < 0.9 * rms["mid_f_rls"]
    with pytest.raises(ValueError, match="drive lag"):
        build_controller("mid_f_rls_lag", dataclasses.replace(controller_setup, drive_lag=None))


def test_friction_scale_fitted_on_the_empty_moves_removes_the_friction_bias_of_light_estimates(
    tared_setup: ControllerSetup,
) -> None:
    """A robot whose friction is 30 % above the identified one (known truth): the empty moves find the scale
    error, and the 0.3 kg objects carried after them are estimated within 25 g, where the estimator that trusts
    the identified friction is biased by it."""
    realism = dataclasses.replace(PlantRealism(), viscous_scale=(1.3, 1.3, 1.3), coulomb_scale=(1.3, 1.3, 1.3))
    # the cell of the paper (timed release), where the 25 g were measured: with the in-position release the second
    # carry ends 27 g off (the pick comes at the end of the rest, and the carry's motion at once)
    env = DeltaPickPlaceEnv(plant=PlantConfig(realism=realism), n_cycles=3, release="timed")
    dynamics = estimation_model(tared_setup)
    end_errors = {}
    for prior in (None, FRICTION_SCALE_STD):
        estimator = PayloadEstimator(
            dynamics, tare=tared_setup.tares["mid_f_rls"], friction_scale_std=prior, mass_correction_std=None
        )
        record = run_episode(env, FeedforwardController("RLS", dynamics, estimator=estimator), 8, [0.3, 0.3, 0.3])
        end_errors[prior] = np.array([carry.end_estimate - carry.mass for carry in record.carries()])
        if prior is not None:
            # The viscous part dominates the friction of a 3 g move; the prior pulls the fit slightly towards 0.
            kappa = estimator.friction_scale_error
            assert np.all((kappa > 0.15) & (kappa < 0.4)), kappa
    assert np.all(np.abs(end_errors[FRICTION_SCALE_STD]) <= 0.025), end_errors
    assert np.max(np.abs(end_errors[None])) > 2.0 * np.max(np.abs(end_errors[FRICTION_SCALE_STD])), end_errors


def test_mass_and_friction_errors_fitted_on_the_empty_moves_leave_light_estimates_unbiased(
    tared_setup: ControllerSetup,
) -> None:
    """A robot whose masses m1, m2, m0 are all 10 % and whose friction is 30 % above the identified ones (known
    truth): the empty moves find the platform-mass error dm = 0.1 (m0 + 3 m2) = 0.14 kg, the arms' (10 %) and the
    friction scale errors; the 0.3 kg objects carried after them are estimated within
    25 g. Fitting the friction alone leaves dm, which is exactly a payload error, in the estimate."""
    nominal = PlantRealism()  # its joints' friction differs from joint to joint; the identified model knows that
    realism = dataclasses.replace(
        nominal,
        viscous_scale=tuple(1.3 * scale for scale in nominal.viscous_scale),
        coulomb_scale=tuple(1.3 * scale for scale in nominal.coulomb_scale),
    )
    masses = DeltaMasses(m1=1.1 * NOMINAL_MASSES.m1, m2=1.1 * NOMINAL_MASSES.m2, m0=1.1 * NOMINAL_MASSES.m0)
    env = DeltaPickPlaceEnv(plant=PlantConfig(masses=masses, realism=realism), n_cycles=3)
    dynamics = estimation_model(tared_setup)
    end_errors = {}
    for mass_prior in (None, MASS_CORRECTION_STD):
        estimator = PayloadEstimator(dynamics, tare=tared_setup.tares["mid_f_rls"], mass_correction_std=mass_prior)
        record = run_episode(env, FeedforwardController("RLS", dynamics, estimator=estimator), 8, [0.3, 0.3, 0.3])
        # Every carry follows an empty move: the episode starts at a place point (start="place").
        end_errors[mass_prior] = np.array([carry.end_estimate - carry.mass for carry in record.carries()])
        if mass_prior is not None:
            corrections = estimator.corrections
            assert 0.10 < corrections.platform_mass < 0.18, corrections
            assert 0.05 < corrections.arm_mass_scale < 0.15, corrections
            assert np.all((corrections.friction_scale > 0.15) & (corrections.friction_scale < 0.4)), corrections
    assert np.all(np.abs(end_errors[MASS_CORRECTION_STD]) <= 0.025), end_errors
    assert np.all(end_errors[None] > 0.08), end_errors  # dm = 0.14 kg, less the tare's share of it


def test_first_carry_needs_the_empty_move_before_it_on_a_robot_heavier_than_its_model(
    tared_setup: ControllerSetup,
) -> None:
    """Masses m1, m2, m0 10 % above the identified ones (known truth: a platform-mass error of 0.14 kg, the same
    column as the payload on a carry). Starting at a place point, the empty move to the first pick fits it and the
    first 0.3 kg object is estimated within 25 g; starting at the pick point, nothing tells the two apart on the
    first carry and its estimate holds most of the 0.14 kg."""
    masses = DeltaMasses(m1=1.1 * NOMINAL_MASSES.m1, m2=1.1 * NOMINAL_MASSES.m2, m0=1.1 * NOMINAL_MASSES.m0)
    first_errors = {}
    for start in ("place", "pick"):
        env = DeltaPickPlaceEnv(plant=PlantConfig(masses=masses), n_cycles=1, start=start)
        record = run_episode(env, build_controller("mid_f_rls", tared_setup, env), 8, [0.3])
        (carry,) = record.carries()
        first_errors[start] = carry.end_estimate - carry.mass
    assert abs(first_errors["place"]) <= 0.025, first_errors
    assert first_errors["pick"] > 0.08, first_errors


def test_a_robots_earlier_empty_moves_correct_a_carry_that_follows_none(controller_setup: ControllerSetup) -> None:
    """The robot 10 % heavier than its model again, its episodes starting at the pick point: no empty move comes
    before the carry, yet with the sums of its own calibration episodes' empty moves seeded, the 0.3 kg object
    is estimated within 25 g (without them: off by the platform-mass error, about +0.19 kg)."""
    masses = DeltaMasses(m1=1.1 * NOMINAL_MASSES.m1, m2=1.1 * NOMINAL_MASSES.m2, m0=1.1 * NOMINAL_MASSES.m0)
    plant = PlantConfig(masses=masses)
    scenario = Scenario(plant=plant, task=PickPlaceTask(start="pick"))
    seeds = [CALIBRATION_SEED, CALIBRATION_SEED + 1]
    calibration = calibrate_tares(["mid_f_rls"], controller_setup, seeds, 3, scenario=scenario)
    seeded = calibrated_setup(controller_setup, calibration, scenario)
    assert set(seeded.empty_moves) == {"mid_f_rls"}
    env = DeltaPickPlaceEnv(plant=plant, n_cycles=1, start="pick")
    errors = {}
    for name, setup in (("seeded", seeded), ("tared only", dataclasses.replace(seeded, empty_moves={}))):
        (carry,) = run_episode(env, build_controller("mid_f_rls", setup, env), 8, [0.3]).carries()
        errors[name] = carry.end_estimate - carry.mass
    assert abs(errors["seeded"]) <= 0.025, errors
    assert errors["tared only"] > 0.1, errors


def test_empty_move_sums_are_only_for_the_robot_they_were_measured_on(controller_setup: ControllerSetup) -> None:
    """Under domain randomization every episode is another robot: the calibration's sums are dropped; a robot
    under a condition (worn) is the same robot and keeps them. Bad sums and an estimator that fits nothing are
    refused, and taring needs an unseeded estimator."""
    sums = EmptyMoveSums(np.eye(5), np.zeros(5))
    calibration = Calibration({"mid_f_rls": 0.01}, {"mid_f_rls": 0.002}, {"mid_f_rls": sums})
    for name, kept in (("nominal", True), ("worn", True), ("randomized", False)):
        setup = calibrated_setup(controller_setup, calibration, preset(name))
        assert setup.tares == {"mid_f_rls": 0.01}
        assert (set(setup.empty_moves) == {"mid_f_rls"}) is kept, name
    dynamics = DeltaDynamics.nominal(controller_setup.mid_f_rods, forearm_rods=True)
    fresh = PayloadEstimator(dynamics, regressor="reference", empty_moves=EmptyMoveSums(2.0 * np.eye(5), np.ones(5)))
    assert_allclose(fresh.corrections.friction_scale, 1.0 / (2.0 + FRICTION_SCALE_STD**-2))  # seeded before a reset
    with pytest.raises(ValueError, match=r"\(5, 5\) and \(5,\) sums, got shapes \(4, 4\)"):
        PayloadEstimator(dynamics, empty_moves=EmptyMoveSums(np.eye(4), np.zeros(4)))
    with pytest.raises(ValueError, match="symmetric"):
        PayloadEstimator(dynamics, empty_moves=EmptyMoveSums(np.triu(np.ones((5, 5))), np.zeros(5)))
    with pytest.raises(ValueError, match="fits none"):
        PayloadEstimator(dynamics, empty_moves=sums, friction_scale_std=None, mass_correction_std=None)
    with pytest.raises(ValueError, match="without seeded empty moves"):
        tare_from_observations(PayloadEstimator(dynamics, regressor="reference", empty_moves=sums), [])


def test_light_object_estimate_does_not_overshoot_at_lift_off(tared_setup: ControllerSetup) -> None:
    """While the joints rest in the pick dwell, static friction holds part of the load: those samples are not
    used, and a 0.17 kg object's estimate stays within 0.2 kg above its mass over the whole carry (it reached
    1.3 kg before the lift when they were)."""
    env = DeltaPickPlaceEnv(n_cycles=2)
    controller = build_controller("mid_f_rls", tared_setup)
    record = run_episode(env, controller, 3, [0.17, 0.17])
    for pick, place in zip(record.pick_indices, record.place_indices, strict=True):
        assert np.max(record.payload_estimate[pick:place]) <= 0.17 + 0.2
    assert all(abs(carry.end_estimate - 0.17) <= 0.025 for carry in record.carries())


@pytest.mark.parametrize(("servo", "overshoot_limit"), [("pd", 0.2), ("servo", 0.35)])
def test_light_object_estimate_does_not_overshoot_at_a_fast_lift_off(
    tared_setup: ControllerSetup, servo: str, overshoot_limit: float
) -> None:
    """At 6 g the lift starts with a jerk step of about 1e4 rad/s^3; the fixed-lag smoother's acceleration must
    follow it, or the unexplained inertia reads as mass. On robots drawn as in the ``randomized`` preset, 50 g
    objects stay within 0.2 kg above their mass over the whole carry behind the paper's PD (with a model stiff
    enough for 3 g, 1000 rad/s^3, most of them overshot by 0.2-0.3 kg in the first 10 ms of the lift). The servo
    layer makes the arm follow the jerk step more sharply than the smoother does: measured up to 0.30 kg
    (docs/design.md section 6, "Known cost")."""
    env = DeltaPickPlaceEnv(n_cycles=3, peak_acceleration=6.0 * GRAVITY, domain_randomization=RandomizationRanges())
    controller = build_controller("mid_f_rls", dataclasses.replace(tared_setup, servo=servo))
    for seed in (11, 12):
        record = run_episode(env, controller, seed, [0.05, 0.05, 0.05])
        carries = record.carries()
        overshoots = [carry.peak_estimate - carry.mass for carry in carries]
        assert len(overshoots) == 3 and max(overshoots) <= overshoot_limit, overshoots
        assert all(abs(carry.end_error_kg) <= 0.025 for carry in carries), [carry.end_error_kg for carry in carries]


def test_tare_takes_a_carry_with_a_stop_inside_as_one_carry(controller_setup: ControllerSetup) -> None:
    """The tare's spread is over carries, gripper closing to gripper closing: a stop of every joint within a
    carry gives no equations but does not split the carry in two."""
    dynamics = DeltaDynamics.nominal(controller_setup.mid_f_rods, forearm_rods=True)
    estimator = PayloadEstimator(dynamics, regressor="reference", friction_scale_std=None, mass_correction_std=None)
    angles, accelerations = np.array([0.4, 0.3, 0.5]), np.array([5.0, -3.0, 4.0])

    def sample(rate: float, closed: bool, mass: float) -> dict[str, np.ndarray]:
        rates = np.full(3, rate)
        tau0, phi = dynamics.torque_and_payload_regressor(angles, rates, accelerations)
        return {
            "reference_angles": angles,
            "reference_velocities": rates,
            "reference_accelerations": accelerations,
            "joint_torques": tau0 + mass * phi,
            "gripper": np.array([float(closed)]),
        }

    def carry(mass: float) -> list[dict[str, np.ndarray]]:
        moving, resting = [sample(2.0, True, mass)] * 50, [sample(0.0, True, mass)] * 30
        return [sample(2.0, False, 0.0)] * 20 + moving + resting + moving

    tare, spread, _ = tare_from_observations(estimator, [carry(0.1) + carry(0.3)])
    assert tare == pytest.approx(0.2, abs=0.005)
    assert spread == pytest.approx(np.std([0.1, 0.3], ddof=1), abs=0.005)  # four half-carries: 0.115


def test_tare_counts_only_the_carries_after_an_empty_move_when_the_estimator_fits_corrections(
    controller_setup: ControllerSetup,
) -> None:
    """An episode's first carry comes before any empty move: its apparent payload holds the plant's own errors,
    which the estimator has not fitted yet, so it is left out of the tare, unless no carry follows an empty move
    or the estimator fits nothing."""
    dynamics = DeltaDynamics.nominal(controller_setup.mid_f_rods, forearm_rods=True)
    angles, rates, accelerations = np.array([0.4, 0.3, 0.5]), np.full(3, 2.0), np.array([5.0, -3.0, 4.0])
    tau0, phi = dynamics.torque_and_payload_regressor(angles, rates, accelerations)

    def samples(count: int, closed: bool, mass: float) -> list[dict[str, np.ndarray]]:
        sample = {
            "reference_angles": angles,
            "reference_velocities": rates,
            "reference_accelerations": accelerations,
            "joint_torques": tau0 + mass * phi,
            "gripper": np.array([float(closed)]),
        }
        return [sample] * count

    first_carry_only = samples(50, True, 0.4)
    episode = [*first_carry_only, *samples(30, False, 0.0), *samples(50, True, 0.1)]
    fitting = PayloadEstimator(dynamics, regressor="reference")
    trusting = PayloadEstimator(dynamics, regressor="reference", friction_scale_std=None, mass_correction_std=None)
    assert fitting.fits_corrections and not trusting.fits_corrections
    tare = tare_from_observations(fitting, [episode])
    assert tare.mass == pytest.approx(0.1, abs=1e-9)
    assert fitting.empty_move_samples == 30
    # The sums of the 30 empty samples (mp = 0): as many again for two episodes.
    assert tare.empty_moves.information[0, 0] > 0.0
    assert_allclose(tare.empty_moves.information, fitting.empty_move_sums.information, rtol=1e-12)
    twice = tare_from_observations(fitting, [episode, episode]).empty_moves
    assert_allclose(twice.information, 2.0 * tare.empty_moves.information, rtol=1e-12)
    assert_allclose(twice.moment, 2.0 * tare.empty_moves.moment, rtol=1e-12, atol=1e-12)
    assert tare_from_observations(trusting, [episode])[0] == pytest.approx(0.25, abs=1e-9)
    assert tare_from_observations(fitting, [first_carry_only])[0] == pytest.approx(0.4, abs=1e-9)


def test_friction_scale_fit_gives_a_joint_at_exact_rest_no_coulomb_friction(controller_setup: ControllerSetup) -> None:
    """The model's friction is fc sign(thd), 0 at thd = 0: a torque error of a resting joint on an empty move is
    not read as a friction scale error, while the moving joints' errors are."""
    dynamics = DeltaDynamics.nominal(controller_setup.mid_f_rods, forearm_rods=True)
    estimator = PayloadEstimator(dynamics, regressor="reference")
    angles, rates, accelerations = np.array([0.4, 0.3, 0.5]), np.array([0.0, 2.0, -2.0]), np.zeros(3)
    tau0, _ = dynamics.torque_and_payload_regressor(angles, rates, accelerations)
    observation = {
        "reference_angles": angles,
        "reference_velocities": rates,
        "reference_accelerations": accelerations,
        "joint_torques": tau0 + 1.0,  # 1 N m the model does not explain on every joint
        "gripper": np.array([0.0]),
    }
    for _ in range(50):
        assert estimator.measurement(observation) is None  # gripper open: only the friction fit
    kappa = estimator.friction_scale_error
    assert kappa[0] == 0.0
    assert kappa[1] > 0.01 and kappa[2] < -0.01  # 1 N m along +f and along -f


def test_reading_the_corrections_does_not_change_the_feedforward(controller_setup: ControllerSetup) -> None:
    """The feedforward's platform-mass correction is the one solved at the last carry's start: reading
    :attr:`PayloadEstimator.corrections` during an empty move reports the fit so far without moving it."""
    dynamics = DeltaDynamics.nominal(controller_setup.mid_f_rods, forearm_rods=True)
    angles, rates, accelerations = np.array([0.4, 0.3, 0.5]), np.full(3, 2.0), np.array([5.0, -3.0, 4.0])
    tau0, phi = dynamics.torque_and_payload_regressor(angles, rates, accelerations)

    def sample(closed: bool, torque: np.ndarray) -> dict[str, np.ndarray]:
        return {
            "reference_angles": angles,
            "reference_velocities": rates,
            "reference_accelerations": accelerations,
            "joint_torques": torque,
            "gripper": np.array([float(closed)]),
        }

    read, unread = (PayloadEstimator(dynamics, regressor="reference") for _ in range(2))
    for estimator in (read, unread):
        estimator.reset()
    # A carry, an empty move whose torques say the platform is 0.1 kg heavier than the model, a second carry.
    episode = [sample(True, tau0 + 0.5 * phi)] * 20 + [sample(False, tau0 + 0.1 * phi)] * 40
    episode += [sample(True, tau0 + 0.6 * phi)] * 20
    for observation in episode:
        masses = [estimator.update(observation) for estimator in (read, unread)]
        platform_mass = read.corrections.platform_mass
        assert masses[0] == masses[1], "reading the corrections changed the feedforward"
        if observation["gripper"][0] == 0.0:
            assert platform_mass > 0.0  # the fit so far is reported
    assert read.corrections.platform_mass == pytest.approx(unread.corrections.platform_mass)
    assert read.apparent_mass == unread.apparent_mass
