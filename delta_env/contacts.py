"""The plant's contacts (parts of :class:`~delta_env.plant.DeltaPlant`): the obstacle of collision faults, and the
robot's self-contacts when its collision geometry is on (``PlantConfig.collisions``).
"""

from __future__ import annotations

import math

import mujoco
import numpy as np
from numpy.typing import NDArray

from delta_env.robot import ROBOT_CONTACT_BIT
from delta_env.scene import OBSTACLE_PARKED, OBSTACLE_RADIUS


class Obstacle:
    """The obstacle sphere of collision faults (a mocap body, :func:`delta_env.scene.build_model` with
    ``obstacle=True``): where it is put in the platform's way and the force it meets there; ``mj_resetData``
    parks it.

    Attributes:
        body: Its body id (not domain-randomized).
    """

    def __init__(self, model: mujoco.MjModel, data: mujoco.MjData) -> None:
        self._model, self._data = model, data
        self.body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "obstacle")
        self._geom = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "obstacle")
        if self.body < 0 or self._geom < 0:
            raise ValueError("the model has no obstacle: build it with obstacle=True")
        disc = model.geom_size[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "platform_disc")]
        self._disc_radius, self._disc_half_height = float(disc[0]), float(disc[1])

    def place(self, point: NDArray[np.float64], direction: NDArray[np.float64]) -> None:
        """Put the sphere where the platform disc touches it when its centre E0 is at ``point`` (m) moving along
        ``direction`` (any length > 0): at the disc's extent in that direction plus the sphere's radius."""
        unit = np.asarray(direction, dtype=float) / np.linalg.norm(direction)
        reach = self._disc_radius * math.hypot(unit[0], unit[1]) + self._disc_half_height * abs(unit[2])
        self._move(np.asarray(point) + (reach + OBSTACLE_RADIUS) * unit)

    def park(self) -> None:
        """Move the sphere back out of the way."""
        self._move(np.array(OBSTACLE_PARKED))

    def _move(self, position: NDArray[np.float64]) -> None:
        self._data.mocap_pos[self._model.body_mocapid[self.body]] = position

    def contact_force(self) -> float:
        """Normal force (N) between the sphere and the platform at the last physics step; 0 without contact."""
        force, total = np.zeros(6), 0.0
        for index in range(self._data.ncon):
            contact = self._data.contact[index]
            if self._geom in (contact.geom1, contact.geom2):
                mujoco.mj_contactForce(self._model, self._data, index, force)
                total += force.item(0)
        return total


class RobotContacts:
    """Robot self-contacts (both geoms with :data:`delta_env.robot.ROBOT_CONTACT_BIT`) seen since the last
    :meth:`clear`: each pair of geom names with its deepest penetration (m)."""

    def __init__(self, model: mujoco.MjModel, data: mujoco.MjData) -> None:
        self._model, self._data = model, data
        self._deepest: dict[tuple[str, str], float] = {}

    def record(self) -> None:
        """Add the contacts of the last physics step."""
        contype = self._model.geom_contype
        for index in range(self._data.ncon):
            contact = self._data.contact[index]
            if contype[contact.geom1] & contype[contact.geom2] & ROBOT_CONTACT_BIT:
                pair = tuple(sorted(self._model.geom(g).name for g in (contact.geom1, contact.geom2)))
                self._deepest[pair] = max(self._deepest.get(pair, 0.0), -float(contact.dist))

    def clear(self) -> None:
        """Forget every contact seen."""
        self._deepest = {}

    def seen(self) -> dict[tuple[str, str], float]:
        """The contacts seen (a copy): geom-name pair -> deepest penetration (m)."""
        return dict(self._deepest)
