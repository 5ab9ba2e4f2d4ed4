"""Payload-adaptive timing: worst-case, declared and online carries, the thermal rating, and python -m eval.rate."""

from __future__ import annotations

import csv
import dataclasses
import itertools
import math
from pathlib import Path

import numpy as np
import pytest

from controllers.dynamics import DeltaDynamics
from controllers.feedforward import OracleController
from controllers.payload import PayloadEstimator
from controllers.payload_timing import (
    ESTIMATE_MARGIN,
    ESTIMATE_SIGMAS,
    PRECOMPUTED_PAYLOADS,
    REPLAN_STEP,
    SETTLED_STD,
    TAKEOVER_SCALES,
    EstimatingController,
    PayloadTiming,
)
from controllers.registry import build_controller
from controllers.timing import TimeOptimalPlanner
from delta_env.config import RATED_PAYLOAD, PlantConfig
from delta_env.cycles import STANDARD_LIFT, STANDARD_TRAVEL
from delta_env.drive import DriveLimits
from delta_env.env import DeltaPickPlaceEnv
from delta_env.scenario import PickPlaceTask, Scenario
from delta_env.timing import TimeLaw, move_samples
from delta_env.trajectories import WORKING_HEIGHT, Segment
from eval.episodes import run_episode
from eval.rate.__main__ import main
from eval.rate.study import MIXED, rate_scenario
from eval.work import timed, timed_controller

CARRY = Segment(
    np.array([0.0, -0.5 * STANDARD_TRAVEL, WORKING_HEIGHT]),
    np.array([0.0, 0.5 * STANDARD_TRAVEL, WORKING_HEIGHT]),
    1.0,
    STANDARD_LIFT,
    0.3,
)
"""The 25/305/25 mm carry of the standard cycle."""


@pytest.fixture(scope="module")
def planner(controller_setup) -> TimeOptimalPlanner:
    dynamics = DeltaDynamics.nominal(controller_setup.mid_f_rods, forearm_rods=True)
    return TimeOptimalPlanner(dynamics, DriveLimits(), controller_setup.drive_lag)


class FakeRLS:
    variance = 4.0


class FakeEstimator:
    """An estimator whose estimate and variance the test sets; its predicted variance along a carry, which places the
    takeovers, is a real estimator's on the planner's model."""

    def __init__(self, planner: TimeOptimalPlanner) -> None:
        self.mass = 0.0
        self.rls = FakeRLS()
        self.predicted_variance = PayloadEstimator(planner.dynamics).predicted_variance


def switches(timing: PayloadTiming, law: TimeLaw) -> list[tuple[int, TimeLaw]]:
    """(sample, law) of every switch of a carry started on ``law``, asked at every sample as the env asks: the law
    it follows is the last one returned."""
    followed, taken = law, []
    for index in range(len(law) - 1):
        retimed = timing.retime(CARRY, followed, index)
        if retimed is not None:
            followed = retimed
            taken.append((index, retimed))
    return taken


def test_worst_case_and_declared_carries_and_empty_moves(planner: TimeOptimalPlanner) -> None:
    worst = PayloadTiming(planner, "worst_case", RATED_PAYLOAD, torque_share=0.5)
    declared = PayloadTiming(planner, "declared", RATED_PAYLOAD, torque_share=0.5)
    assert not worst.retimes_online and worst.retime(CARRY, worst.carry(CARRY, 0.5), 10) is None
    heavy, light, empty = worst.carry(CARRY, 0.5), declared.carry(CARRY, 0.5), declared.empty(CARRY)
    assert len(heavy) == len(declared.carry(CARRY, RATED_PAYLOAD))  # worst case ignores the declared mass
    assert len(empty) < len(light) < len(heavy)
    assert worst.carry(CARRY, 0.5) is heavy  # a recurring move is planned once


def test_a_smaller_share_of_the_envelope_is_slower_and_uses_less_torque(planner: TimeOptimalPlanner) -> None:
    fast = PayloadTiming(planner, "declared", RATED_PAYLOAD, torque_share=1.0).carry(CARRY, 2.0)
    slow = PayloadTiming(planner, "declared", RATED_PAYLOAD, torque_share=0.3).carry(CARRY, 2.0)
    assert len(slow) > 1.2 * len(fast)
    peak = [np.max(np.abs(planner.model_torque(CARRY, law, 2.0)[0])) for law in (fast, slow)]
    assert peak[1] < 0.6 * peak[0]


def test_every_move_keeps_the_thermal_rating(controller_setup) -> None:
    # A drive rated at a fifth of its peak: the time-optimal carry alone would overheat it.
    drive = DriveLimits(rated_torque=80.0)
    dynamics = DeltaDynamics.nominal(controller_setup.mid_f_rods, forearm_rods=True)
    hot = TimeOptimalPlanner(dynamics, drive, controller_setup.drive_lag)
    timing = PayloadTiming(hot, "declared", RATED_PAYLOAD, torque_share=1.0)
    unlimited = hot.plan(CARRY, RATED_PAYLOAD)
    assert timing.thermal_ratio(CARRY, unlimited, RATED_PAYLOAD) > 1.2
    law = timing.carry(CARRY, RATED_PAYLOAD)
    ratio = timing.thermal_ratio(CARRY, law, RATED_PAYLOAD)
    # within the rating, and close to it: the bisection finds the largest share (2 % resolution)
    assert 0.85 < ratio <= 1.0
    assert len(law) > len(unlimited)


def test_online_retimes_a_carry_once_the_estimate_has_settled(planner: TimeOptimalPlanner) -> None:
    estimator = FakeEstimator(planner)
    timing = PayloadTiming(planner, "online", RATED_PAYLOAD, estimator, torque_share=0.5)
    law = timing.carry(CARRY, 0.5)
    assert len(law) == len(PayloadTiming(planner, "worst_case", RATED_PAYLOAD, torque_share=0.5).carry(CARRY, 0.5))
    estimator.mass, estimator.rls.variance = 0.5, (2.0 * SETTLED_STD) ** 2
    assert timing.retime(CARRY, law, 20) is None  # not settled yet
    # settled: the continuation for the lightest grid payload above the estimate's bound takes over at the first
    # takeover whose successor's law for that payload is longer (waiting for that one would cost a sample)
    std = 0.001
    estimator.mass, estimator.rls.variance = 0.5, std**2
    planned = min(p for p in PRECOMPUTED_PAYLOADS if p >= 0.5 + ESTIMATE_SIGMAS * std + ESTIMATE_MARGIN)
    lengths = {start: len(continued) for start, mass, continued in timing.precomputed(law) if mass == planned}
    takeovers = sorted(lengths)
    switch = next(start for start, after in itertools.pairwise(takeovers) if lengths[after] > lengths[start])
    assert all(timing.retime(CARRY, law, start) is None for start in takeovers[: takeovers.index(switch)])
    first = timing.retime(CARRY, law, switch)
    assert first is not None and first.payload == planned and len(first) == lengths[switch] < len(law)
    for name in ("tau", "tau_dot", "tau_ddot"):
        np.testing.assert_array_equal(getattr(first, name)[: switch + 1], getattr(law, name)[: switch + 1])
    # once switched, nothing is planned, whatever the estimate
    estimator.mass = 0.5 - 4.0 * REPLAN_STEP
    assert all(timing.retime(CARRY, first, index) is None for index in range(switch + 1, 40))


def test_online_carries_take_only_laws_of_their_precomputed_table(planner: TimeOptimalPlanner) -> None:
    estimator = FakeEstimator(planner)
    timing = PayloadTiming(planner, "online", RATED_PAYLOAD, estimator, torque_share=0.5)
    law = timing.carry(CARRY, 1.0)
    table = {id(continued): (start, mass) for start, mass, continued in timing.precomputed(law)}
    # the takeovers follow the estimator's predicted settle along the start law: the first where its deviation is
    # within REPLAN_STEP, the last the fallback
    settle = timing.settle_time(CARRY, law)
    assert 10 < settle < 40
    assert timing.takeovers(CARRY, law) == tuple(round(scale * settle) for scale in TAKEOVER_SCALES)
    assert {start for start, _ in table.values()} == set(timing.takeovers(CARRY, law))
    for mass, std in ((0.07, 0.3), (0.07, 0.02), (1.3, 0.05), (3.9, 0.01), (2.0, 0.8), (math.nan, 0.1)):
        estimator.mass, estimator.rls.variance = mass, std**2
        taken = switches(timing, law)
        # each a continuation the table held from that very sample
        assert all(table[id(retimed)][0] == index for index, retimed in taken)
        assert len(taken) <= 1  # a continuation has no table of its own: it runs to the end
        if std <= SETTLED_STD and mass + ESTIMATE_SIGMAS * std + ESTIMATE_MARGIN <= max(PRECOMPUTED_PAYLOADS):
            # a settled light object leaves the start by the latest takeover, for a payload its estimate is under
            assert taken and table[id(taken[0][1])][1] >= mass + ESTIMATE_MARGIN
            assert taken[0][0] <= timing.takeovers(CARRY, law)[-1]


def test_bad_arguments_are_refused(planner: TimeOptimalPlanner) -> None:
    with pytest.raises(ValueError, match="mode must be one of"):
        PayloadTiming(planner, "fast", RATED_PAYLOAD)
    with pytest.raises(ValueError, match="needs the payload estimator"):
        PayloadTiming(planner, "online", RATED_PAYLOAD)
    with pytest.raises(ValueError, match="torque_share must be a finite number in"):
        PayloadTiming(planner, "declared", RATED_PAYLOAD, torque_share=1.5)
    with pytest.raises(ValueError, match="max_payload"):
        PayloadTiming(planner, "declared", -1.0)
    with pytest.raises(ValueError, match="min_payload"):
        PayloadTiming(planner, "declared", 1.0, min_payload=2.0)


def test_online_timing_reads_the_controllers_estimator_or_runs_the_cells_own(controller_setup) -> None:
    scenario = Scenario(task=PickPlaceTask(cycle="standard", timing="online", n_cycles=1))
    env = DeltaPickPlaceEnv(scenario=scenario)
    model = timed_controller(env, "mid_f_rls_lag", controller_setup)
    assert not isinstance(model.controller, EstimatingController)
    assert env.timing.estimator is model.estimator and env.timing.max_payload == 4.0
    wrapped = timed_controller(env, "pd", dataclasses.replace(controller_setup, tares={"mid_f_rls": 0.07}))
    # the cell's estimator (tared as the cell's row) runs beside the PD, behind the row's fault monitor, which gates
    # it too
    assert isinstance(wrapped.controller, EstimatingController) and env.timing.estimator is wrapped.estimator
    assert wrapped.estimator.tare == 0.07
    fixed_env = DeltaPickPlaceEnv()
    timed(fixed_env, controller_setup, model.estimator)
    assert fixed_env.timing is None
    no_lag = dataclasses.replace(controller_setup, drive_lag=None)
    with pytest.raises(ValueError, match="identified drive lag"):
        timed(env, no_lag, model.estimator)
    with pytest.raises(ValueError, match="'online' timing reads a payload estimator"):
        timed(env, controller_setup)


def test_rate_scenarios_run_the_standard_cycle_with_the_payloads_of_their_row() -> None:
    fixed = rate_scenario(Scenario(), "declared", 2.0)
    assert fixed.task.cycle == "standard" and fixed.task.timing == "declared"
    assert fixed.task.payload_mass_range == (2.0, 2.0) and fixed.name.endswith("/declared/2")
    assert rate_scenario(Scenario(), "online", MIXED).task.payload_mass_range == (0.0, RATED_PAYLOAD)


@pytest.mark.slow  # the online carry's table of continuations: about 50 s of a core
def test_rate_cli_writes_the_data_sheet(parameter_file: Path, tmp_path: Path, capsys) -> None:
    out = tmp_path / "rate"
    argv = ["--episodes", "1", "--cycles", "2", "--payloads", "1", "--planners", "fixed,worst_case,declared,online"]
    argv += ["--no-fastest", "--parameters", str(parameter_file), "--out", str(out), "--workers", "1"]
    argv += ["--runs-dir", str(tmp_path / "runs")]
    assert main(argv) == 0
    printed = capsys.readouterr().out
    assert printed.startswith("# Pick rate, scenario nominal") and (out / "summary.md").read_text() == printed + ""
    with (out / "rate.csv").open(newline="") as file:
        rows = list(csv.DictReader(file))
    required = {"planner", "controller", "payload", "picks_per_min", "tracking_rms_mm", "place_error_mm"}
    assert required | {"envelope_violations"} <= set(rows[0])
    assert {(row["planner"], row["payload"]) for row in rows} == {
        (planner, load) for planner in ("fixed", "worst_case", "declared", "online") for load in ("1", MIXED)
    }
    rate = {(row["planner"], row["controller"], row["payload"]): float(row["picks_per_min"]) for row in rows}
    model, pd = "MId+F+R+RLS+lag+PD", "PD"
    # PD is scored on the model's references, and the waits for the in-position signal count: PD, whose gravity sag
    # never settles into the window, times out at every pick and place, the model row at most as often
    assert all(rate[(p, pd, load)] <= rate[(p, model, load)] for p, _, load in rate)
    # time-optimal beats the fixed 3 g timing; with objects of one mass every carry is timed for it, while on the
    # mixed stream (seed 0: 2.5 and 1.1 kg) the online estimate buys speed over timing for the 4 kg maximum
    assert rate[("worst_case", model, "1")] > 1.15 * rate[("fixed", model, "1")]
    assert rate[("online", model, "1")] == pytest.approx(rate[("worst_case", model, "1")], rel=0.01)
    worst, declared, online = (rate[(planner, model, MIXED)] for planner in ("worst_case", "declared", "online"))
    assert declared > 1.04 * worst and online - worst > 0.6 * (declared - worst)
    online = next(row for row in rows if row["planner"] == "online" and row["controller"] == model)
    assert int(online["envelope_violations"]) == 0 and math.isfinite(float(online["tracking_rms_mm"]))
    assert (out / "rate.png").stat().st_size > 10_000


def test_planned_timing_on_a_plant_that_satisfies_the_model_leaves_the_envelope_alone() -> None:
    # The ideal plant is MKH exactly (no friction, no lag): a declared timing at the whole envelope, run closed loop
    # with the plant's exact inverse dynamics, needs no command the drive clips and no speed beyond its maximum.
    plant = PlantConfig.ideal()
    masses = plant.masses
    model = DeltaDynamics(plant.geometry, m1=masses.m1, m2=masses.m2, m0=masses.m0)
    timing = PayloadTiming(TimeOptimalPlanner(model, plant.drive), "declared", RATED_PAYLOAD, torque_share=1.0)
    env = DeltaPickPlaceEnv(plant=plant, cycle="standard", n_cycles=2, timing=timing)
    record = run_episode(env, OracleController(plant), seed=0, payload_masses=[4.0, 0.5])
    assert not record.diverged and record.saturated_steps == 0 and record.speed_exceeded_steps == 0
    episode = record.metrics()
    assert episode["peak_torque_ratio"] > 0.5  # it did use the drive: far beyond a 3 g cycle's 0.2


@pytest.mark.parametrize(("mass", "variance"), [(math.nan, 0.01), (0.5, math.nan), (0.5, -1e-4), (math.inf, 0.01)])
def test_a_faulty_estimate_never_retimes(planner: TimeOptimalPlanner, mass: float, variance: float) -> None:
    estimator = FakeEstimator(planner)
    timing = PayloadTiming(planner, "online", RATED_PAYLOAD, estimator, torque_share=0.5)
    law = timing.carry(CARRY, 0.5)
    estimator.mass, estimator.rls.variance = mass, variance
    assert timing.retime(CARRY, law, 0) is None and timing.retime(CARRY, law, 20) is None


def test_every_carry_starts_afresh_on_the_heaviest_objects_plan(planner: TimeOptimalPlanner) -> None:
    estimator = FakeEstimator(planner)
    timing = PayloadTiming(planner, "online", RATED_PAYLOAD, estimator, torque_share=0.5)
    first = timing.carry(CARRY, 1.0)
    estimator.mass, estimator.rls.variance = 1.0, 0.01**2
    [(_, light)] = switches(timing, first)
    # the next carry runs the same cached plan: a 3 kg estimate is still lighter than its 4 kg, so it switches
    second = timing.carry(CARRY, 3.0)
    assert second is first
    estimator.mass = 3.0
    [(_, retimed)] = switches(timing, second)
    assert retimed.payload == min(p for p in PRECOMPUTED_PAYLOADS if p >= 3.0 + 0.01 + ESTIMATE_MARGIN)
    assert len(light) < len(retimed) < len(second)


@pytest.mark.slow
def test_on_the_whole_envelope_an_online_carry_starts_hot_and_its_continuations_keep_the_rating(
    planner: TimeOptimalPlanner,
) -> None:
    worst = PayloadTiming(planner, "worst_case", RATED_PAYLOAD, torque_share=1.0).carry(CARRY, 0.5)
    estimator = FakeEstimator(planner)
    timing = PayloadTiming(planner, "online", RATED_PAYLOAD, estimator, torque_share=1.0)
    start = timing.carry(CARRY, 0.5)
    # faster than the rated worst case, and too hot for the rating on its own with the heaviest object
    assert len(start) < 0.95 * len(worst) and timing.thermal_ratio(CARRY, start, RATED_PAYLOAD) > 1.0
    # an estimate that never settles: at the last takeover the rated continuation for the heaviest object
    fallback = timing.takeovers(CARRY, start)[-1]
    assert timing.retime(CARRY, start, fallback - 1) is None
    rated = timing.retime(CARRY, start, fallback)
    assert rated is not None and rated.payload == RATED_PAYLOAD
    assert timing.thermal_ratio(CARRY, rated, RATED_PAYLOAD) <= 1.0
    np.testing.assert_array_equal(rated.tau[: fallback + 1], start.tau[: fallback + 1])
    # a 0.5 kg object whose estimate has settled: rated for its bound, close to the declared carry
    estimator.mass, estimator.rls.variance = 0.5, 0.05**2
    [(_, retimed)] = switches(timing, start)
    assert retimed.payload >= 0.5 + 0.05 + ESTIMATE_MARGIN
    assert timing.thermal_ratio(CARRY, retimed, retimed.payload) <= 1.0
    declared = PayloadTiming(planner, "declared", RATED_PAYLOAD, torque_share=1.0).carry(CARRY, retimed.payload)
    # (a deviation that stays at 0.05 kg waits, in vain, for a shorter law to the fifth takeover: 1 to 2 ms)
    assert len(retimed) <= 1.06 * len(declared)
    # faster than the same continuation of the rated start (a task of heaviest objects only starts rated), for an
    # estimate that settles within the grid (one that stays at 0.05 kg waits in vain on both starts)
    estimator.rls.variance = 0.02**2
    [(_, settled)] = switches(timing, start)
    rated_start = PayloadTiming(
        planner, "online", RATED_PAYLOAD, estimator, torque_share=1.0, min_payload=RATED_PAYLOAD
    )
    assert rated_start.carry(CARRY, 0.5) is worst
    [(_, slower)] = switches(rated_start, worst)
    assert slower.payload == settled.payload and len(settled) < len(slower)


def peak_braking(law: TimeLaw) -> float:
    """Largest platform deceleration (m/s^2) of ``CARRY`` timed by ``law`` after its fastest sample."""
    _, velocity, acceleration = move_samples(CARRY, law)
    fastest = int(np.argmax(np.linalg.norm(velocity, axis=1)))
    return float(np.max(np.linalg.norm(acceleration[fastest:], axis=1)))


@pytest.mark.slow
def test_an_online_continuation_brakes_no_harder_than_the_rated_law_of_its_payload(
    planner: TimeOptimalPlanner,
) -> None:
    estimator = FakeEstimator(planner)
    timing = PayloadTiming(planner, "online", RATED_PAYLOAD, estimator, torque_share=1.0)
    declared = PayloadTiming(planner, "declared", RATED_PAYLOAD, torque_share=1.0)
    start = timing.carry(CARRY, 0.05)
    # settled loosely, then tightly: the precomputed continuations for their bounds
    estimator.mass, estimator.rls.variance = 0.05, 0.3**2
    [(_, loose)] = switches(timing, start)
    estimator.mass, estimator.rls.variance = 0.12, 0.01**2
    [(_, tight)] = switches(timing, start)
    assert loose.payload >= 0.05 + 0.3 + ESTIMATE_MARGIN and tight.payload == 0.2
    for law in (loose, tight):
        rated = declared.carry(CARRY, law.payload)
        assert timing.thermal_ratio(CARRY, law, law.payload) <= 1.0
        # close to the declared carry: the start's few ms more (the loose bound, which never tightens here, waits
        # for it to the last takeover)
        assert len(law) <= (1.12 if law is loose else 1.08) * len(rated)
        # the cool start's heat saved goes into the travel, not into the braking, whose deceleration the
        # platform's settle at the place follows: the rated law's, where a continuation at one share brakes
        # 4 to 14 % harder (docs/measurements.md)
        assert peak_braking(law) <= 1.02 * peak_braking(rated)


def test_the_predicted_deviation_along_a_carry_is_the_estimators_own(controller_setup) -> None:
    # known truth: the RLS's own variance while the model row carries 2 kg on the realistic plant; the prediction
    # knows only the carry's planned joint trajectory (its reference) and the estimator's noise model, not the
    # plant's lag behind it nor the readings
    env = DeltaPickPlaceEnv(scenario=Scenario(task=PickPlaceTask(cycle="standard", n_cycles=1)))
    controller = build_controller("mid_f_rls_lag", controller_setup)
    estimator = controller.estimator
    observation, _ = env.reset(seed=0, options={"payload_masses": [2.0]})
    controller.reset()
    holding, variances, references = [], [], []
    terminated = truncated = False
    while not (terminated or truncated):
        action = controller(observation)
        holding.append(observation["gripper"].item(0) > 0.5)
        variances.append(estimator.rls.variance)
        references.append([observation[f"reference_{name}"] for name in ("angles", "velocities", "accelerations")])
        observation, _, terminated, truncated, _ = env.step(action)
    pick = holding.index(True)
    carry = np.array(references[pick : pick + 150])
    predicted = np.sqrt(estimator.predicted_variance(carry[:, 0], carry[:, 1], carry[:, 2]))
    actual = np.sqrt(np.array(variances[pick : pick + 150]))
    assert actual[0] == pytest.approx(math.sqrt(estimator.rls.initial_variance))  # reset at the pick
    settling = (actual <= SETTLED_STD) & (actual >= 0.005)
    assert settling.sum() > 20
    # within 10 % wherever the deviation decides a switch (measured: 3 %; a 2x error fails), and the same settle time
    np.testing.assert_allclose(predicted[settling], actual[settling], rtol=0.1)
    settle = int(np.argmax(actual <= REPLAN_STEP))
    assert abs(int(np.argmax(predicted <= REPLAN_STEP)) - settle) <= max(2, 0.1 * settle)
