"""Shared test set-up: headless rendering through EGL unless the caller chose a backend, and fixtures.

Fixtures are named after what they build (``workzone_points``, ``workzone_angles``, ``opengl_context``).
"""

import os
import subprocess
import sys

os.environ.setdefault("MUJOCO_GL", "egl")

from collections.abc import Callable
from pathlib import Path
from typing import NamedTuple

import mujoco
import numpy as np
import pytest

from controllers.base import PDController
from controllers.dynamics import ModelParameters
from controllers.registry import ControllerSetup
from delta_env import NOMINAL_GEOMETRY, DeltaPickPlaceEnv, kinematics
from eval.identification.parameter_files import load_or_identify

# ---------------------------------------------------------------------------------------------
# Order of the test files

LONGEST_FILES = ("test_design.py", "test_residual.py", "test_controllers.py", "test_engine.py")
"""The test files that take longest, collected first so that
``make test``'s pytest-xdist workers (``--dist loadfile --no-loadscope-reorder``: whole files, in this order) start
on them and finish together. By default xdist starts with the files of most tests, and the worker that got
``test_design.py`` last still ran it long after the other had finished."""


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Collect :data:`LONGEST_FILES` first, in their order; every other file keeps its place."""
    rank = {name: n for n, name in enumerate(LONGEST_FILES)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))


# ---------------------------------------------------------------------------------------------
# Fixtures of the controllers and eval tests


IDENTIFIED_EXAMPLE = ModelParameters(rho1=1.35, rho2=1.12, viscous=(2.0, 2.4, 1.7), coulomb=(4.0, 3.4, 4.6))
"""Identified-looking parameters far enough from MKH that every term of the identified model matters."""


def _random_joint_states(n: int | tuple[int, ...], seed: int = 0) -> tuple[np.ndarray, ...]:
    """Angles (rad) in the work zone, rates (rad/s) and accelerations (rad/s^2) of pick cycles."""
    shape = (n,) if isinstance(n, int) else n
    rng = np.random.default_rng(seed)
    theta = rng.uniform(-0.4, 1.0, (*shape, 3))
    return theta, rng.normal(0.0, 3.0, theta.shape), rng.normal(0.0, 100.0, theta.shape)


def _joint_min_jerk_move(
    theta_start: np.ndarray, theta_end: np.ndarray, duration: float, dt: float
) -> tuple[np.ndarray, ...]:
    """A rest-to-rest minimum-jerk move in joint space: angles, rates, accelerations, ``(N, 3)``."""
    s = np.arange(round(duration / dt) + 1)[:, None] * dt / duration
    delta = np.asarray(theta_end) - np.asarray(theta_start)
    theta = theta_start + delta * (10 * s**3 - 15 * s**4 + 6 * s**5)
    theta_dot = delta * (30 * s**2 - 60 * s**3 + 30 * s**4) / duration
    theta_ddot = delta * (60 * s - 180 * s**2 + 120 * s**3) / duration**2
    return theta, theta_dot, theta_ddot


@pytest.fixture(scope="session")
def identified_parameters() -> ModelParameters:
    """:data:`IDENTIFIED_EXAMPLE`."""
    return IDENTIFIED_EXAMPLE


@pytest.fixture(params=[None, IDENTIFIED_EXAMPLE], ids=["MKH", "identified"])
def model_parameters(request: pytest.FixtureRequest) -> ModelParameters | None:
    """Each parameter set a model is tested with: None (plain MKH) and :data:`IDENTIFIED_EXAMPLE`."""
    return request.param


@pytest.fixture(scope="session")
def random_joint_states() -> Callable[..., tuple[np.ndarray, ...]]:
    """``random_joint_states(n, seed=0)``: random joint angles, rates and accelerations, ``(n, 3)`` each."""
    return _random_joint_states


@pytest.fixture(scope="session")
def joint_min_jerk_move() -> Callable[..., tuple[np.ndarray, ...]]:
    """``joint_min_jerk_move(theta_start, theta_end, duration, dt)``: a rest-to-rest minimum-jerk move."""
    return _joint_min_jerk_move


class Step(NamedTuple):
    """One env step: the action sent, and the observation, info and reward it returned."""

    action: np.ndarray
    observation: dict[str, np.ndarray]
    info: dict
    reward: float


def pd_episode(
    env: DeltaPickPlaceEnv, seed: int, options: dict | None = None, max_steps: int | None = None
) -> list[Step]:
    """Every step of a PD episode of ``env`` from ``reset(seed=seed, options=options)``, to the episode's end or
    ``max_steps``."""
    observation, _ = env.reset(seed=seed, options=options)
    controller, steps = PDController(), []
    while max_steps is None or len(steps) < max_steps:
        action = controller(observation)
        observation, reward, terminated, truncated, info = env.step(action)
        steps.append(Step(action, observation, info, reward))
        if terminated or truncated:
            break
    return steps


def run_python(code: str) -> str:
    """Run ``code`` in a fresh interpreter on this checkout (a clean ``sys.modules``); its standard output. Fails the
    test with the standard error when it exits with an error."""
    environment = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parent.parent)}
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=environment, check=False)
    assert done.returncode == 0, done.stderr
    return done.stdout


NOMINAL_SETUP = ControllerSetup(
    mid=ModelParameters(rho1=1.80, rho2=0.936),
    mid_f=ModelParameters(rho1=1.76, rho2=0.877, viscous=(1.97, 2.41, 1.73), coulomb=(4.07, 3.35, 4.46)),
    mid_f_rods=ModelParameters(rho1=1.95, rho2=0.951, viscous=(2.01, 2.41, 1.71), coulomb=(3.98, 3.38, 4.59)),
    drive_lag=(0.001, 0.001, 0.001),
)
"""The parameters identified on the default realistic plant (``python -m eval.identification``, seed 0), rounded:
the tests do not wait a minute for the identification."""


@pytest.fixture(scope="session")
def controller_setup() -> ControllerSetup:
    """:data:`NOMINAL_SETUP`."""
    return NOMINAL_SETUP


# ---------------------------------------------------------------------------------------------


@pytest.fixture(scope="session")
def parameter_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A parameter file of the nominal robot from a tiny identification (one short trajectory): fast, not
    accurate."""
    path = tmp_path_factory.mktemp("identification") / "parameters.json"
    load_or_identify(path, n_trajectories=1, duration=2.0, validation_duration=2.0, progress=False, workers=1)
    return path


@pytest.fixture(scope="session")
def workzone_points() -> Callable[[int, int], np.ndarray]:
    """``points(n, seed)``: n random platform positions (m), (n, 3), in the work zone around z = -0.9 m.

    Uniform over a disc of radius 0.45 m, heights in [-1.1, -0.75] m: well inside the workspace. ``seed``
    may be a ``numpy.random.Generator``, whose stream then continues.
    """

    def points(n: int, seed: int | np.random.Generator) -> np.ndarray:
        rng = np.random.default_rng(seed)
        radius, azimuth = 0.45 * np.sqrt(rng.uniform(size=n)), rng.uniform(0.0, 2.0 * np.pi, n)
        return np.stack((radius * np.cos(azimuth), radius * np.sin(azimuth), rng.uniform(-1.1, -0.75, n)), -1)

    return points


@pytest.fixture(scope="session")
def workzone_angles(workzone_points: Callable[[int, int], np.ndarray]) -> Callable[[int, int], np.ndarray]:
    """``angles(n, seed)``: motor angles (rad), (n, 3), of :func:`workzone_points` on the nominal geometry."""

    def angles(n: int, seed: int | np.random.Generator) -> np.ndarray:
        return kinematics.inverse(NOMINAL_GEOMETRY, workzone_points(n, seed))

    return angles


@pytest.fixture(scope="session")
def opengl_context() -> None:
    """Skip the test where no OpenGL context can be made (no EGL / OSMesa / display on the machine)."""
    model = mujoco.MjModel.from_xml_string("<mujoco><worldbody><geom size='0.1'/></worldbody></mujoco>")
    try:
        with mujoco.Renderer(model, 8, 8) as renderer:
            renderer.render()
    except Exception as error:  # the backends fail with ImportError, RuntimeError, AttributeError, FatalError
        pytest.skip(f"no OpenGL context for MUJOCO_GL={os.environ.get('MUJOCO_GL')!r}: {error}")
