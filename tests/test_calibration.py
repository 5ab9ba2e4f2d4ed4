"""Tare calibration: payload-free episodes on a scenario's work or along given references."""

import types

import numpy as np
import pytest

from delta_env.geometry import NOMINAL_GEOMETRY
from delta_env.sensors import CONTROL_PERIOD
from eval.calibration import calibration_units, tares_from_results
from eval.design.performance import TASK_CYCLES, task_cycle
from eval.work import unit_record
from tests.conftest import NOMINAL_SETUP as SETUP


def standard_cycle(place: int):
    centre, heading = TASK_CYCLES[place]
    return task_cycle(NOMINAL_GEOMETRY, centre, heading, n_cycles=1, dt=CONTROL_PERIOD)


def test_calibration_episodes_follow_the_references_given_one_per_seed():
    references = [standard_cycle(0), standard_cycle(1)]
    units = calibration_units(["mid_f_rls"], [7, 8], 1, references=references)
    assert [(u.seed, u.masses, u.reference) for u in units] == [(7, (0.0,), references[0]), (8, (0.0,), references[1])]
    assert all(u.keep_observations and u.scenario.task.n_cycles == 1 for u in units)
    assert all(u.reference is None for u in calibration_units(["mid_f_rls"], [7, 8], 1))
    with pytest.raises(ValueError, match="2 references for 3 seeds"):
        calibration_units(["mid_f_rls"], [7, 8, 9], 1, references=references)
    with pytest.raises(ValueError, match="'pd' has no tared payload estimator"):
        calibration_units(["pd"], [7], 1)
    record = unit_record(units[1], SETUP)
    assert not record.diverged
    assert len(record.observations) == len(references[1].theta)  # the whole reference, sample for sample
    np.testing.assert_allclose(record.observations[-1]["reference_angles"], references[1].theta[-1], atol=1e-12)


def test_a_diverged_calibration_episode_gives_no_tare():
    unit = calibration_units(["mid_f_rls"], [5], 1)[0]
    diverged = types.SimpleNamespace(diverged=True, observations=[])
    with pytest.raises(RuntimeError, match="'mid_f_rls' on seed 5 diverged"):
        tares_from_results([(unit, diverged)], SETUP)


def test_a_calibration_episode_that_opened_a_loop_beyond_the_limit_gives_no_tare():
    unit = calibration_units(["mid_f_rls"], [5], 1)[0]
    opened = types.SimpleNamespace(diverged=False, max_loop_gap=2e-4, observations=[])
    with pytest.raises(RuntimeError, match=r"seed 5 opened a loop by 0\.200 mm \(limit 0\.100 mm\)"):
        tares_from_results([(unit, opened)], SETUP, max_loop_gap=1e-4)
