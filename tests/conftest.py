"""Shared test set-up: headless rendering through EGL unless the caller chose a backend, and fixtures.

Fixtures are named after what they build (``workzone_points``, ``workzone_angles``, ``opengl_context``).
"""

import os

os.environ.setdefault("MUJOCO_GL", "egl")

from collections.abc import Callable

import mujoco
import numpy as np
import pytest

from delta_env import NOMINAL_GEOMETRY, kinematics


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
