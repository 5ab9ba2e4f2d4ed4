"""The payload box and the suction weld that carries it on the platform (part of :class:`~delta_env.plant.DeltaPlant`).

:class:`SuctionPayload` caches the payload's ids once and owns every read and write of its MuJoCo state; the plant
tells it where the platform is and moves, and keeps the model constants up to date after :meth:`SuctionPayload.set_box`.
"""

from __future__ import annotations

import mujoco
import numpy as np
from numpy.typing import NDArray

from delta_env.config import MIN_PAYLOAD_MASS


def quat_to_matrix(quat: NDArray[np.float64]) -> NDArray[np.float64]:
    """Rotation matrix (3, 3) of a unit quaternion (w, x, y, z)."""
    matrix = np.empty(9)
    mujoco.mju_quat2Mat(matrix, quat)
    return matrix.reshape(3, 3)


def _quat_multiply(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    result = np.empty(4)
    mujoco.mju_mulQuat(result, a, b)
    return result


class SuctionPayload:
    """The free payload body ``payload`` and the weld equality ``suction`` of a plant's model.

    Args:
        model: The plant's ``mujoco.MjModel``, built with a payload body.
        data: The plant's ``mujoco.MjData``.
    """

    def __init__(self, model: mujoco.MjModel, data: mujoco.MjData) -> None:
        self.model, self.data = model, data
        self.body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "payload")
        """Body id of the payload."""
        self._qpos = int(model.jnt_qposadr[model.body_jntadr[self.body]])
        self._dof = int(model.jnt_dofadr[model.body_jntadr[self.body]])
        self._geom = int(model.body_geomadr[self.body])
        self._suction = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_EQUALITY, "suction")

    @property
    def attached(self) -> bool:
        """True while the suction weld holds the payload."""
        return bool(self.data.eq_active[self._suction])

    @property
    def mass(self) -> float:
        """Simulated payload mass (kg)."""
        return float(self.model.body_mass[self.body])

    def position(self) -> NDArray[np.float64]:
        """Centre of the box (m), shape (3,), from qpos; current."""
        return self.data.qpos[self._qpos : self._qpos + 3].copy()

    def set_box(self, mass: float, size: NDArray[np.float64]) -> None:
        """Give the box a mass (kg, simulated as at least MIN_PAYLOAD_MASS) and edge lengths ``size`` (m), (3,), with
        the homogeneous inertia of that box, and make gravity compensation float it. The caller refreshes the model
        constants derived from masses (``mj_setConst``)."""
        model = self.model
        simulated_mass = max(float(mass), MIN_PAYLOAD_MASS)
        model.body_mass[self.body] = simulated_mass
        squares = size**2
        model.body_inertia[self.body] = simulated_mass / 12.0 * (squares.sum() - squares)
        model.geom_size[self._geom] = size / 2.0
        model.geom_rbound[self._geom] = float(np.linalg.norm(size / 2.0))
        model.body_gravcomp[self.body] = 1.0

    def put_at_rest(self, position: NDArray[np.float64]) -> None:
        """Put the box's centre at ``position`` (m), (3,), level and at rest."""
        self.data.qpos[self._qpos : self._qpos + 7] = [*position, 1.0, 0.0, 0.0, 0.0]
        self.data.qvel[self._dof : self._dof + 6] = 0.0

    def attach(self, platform_position: NDArray[np.float64], platform_quat: NDArray[np.float64]) -> None:
        """Activate the suction weld at the current pose relative to the platform (position in m, unit quaternion);
        gravity compensation off. The caller then gives the payload the platform's velocity (:meth:`match_velocity`).
        """
        payload_position = self.data.qpos[self._qpos : self._qpos + 3]
        payload_quat = self.data.qpos[self._qpos + 3 : self._qpos + 7]
        relative_position = quat_to_matrix(platform_quat).T @ (payload_position - platform_position)
        relative_quat = _quat_multiply(platform_quat * np.array([1.0, -1.0, -1.0, -1.0]), payload_quat)
        eq_data = self.model.eq_data[self._suction]
        eq_data[0:3] = 0.0  # anchor: the payload's origin, in the payload frame
        eq_data[3:6] = relative_position  # where that anchor sits in the platform frame
        eq_data[6:10] = relative_quat
        self.data.eq_active[self._suction] = 1
        self.model.body_gravcomp[self.body] = 0.0

    def release(self) -> None:
        """Deactivate the suction weld; the payload stops and floats where it is (gravity compensation on)."""
        self.data.eq_active[self._suction] = 0
        self.model.body_gravcomp[self.body] = 1.0
        self.data.qvel[self._dof : self._dof + 6] = 0.0

    def follow(self, platform_position: NDArray[np.float64], platform_quat: NDArray[np.float64]) -> None:
        """Put the attached payload where the weld holds it on a platform at this pose (m, unit quaternion)."""
        eq_data = self.model.eq_data[self._suction]
        position = platform_position + quat_to_matrix(platform_quat) @ eq_data[3:6]
        quat = _quat_multiply(platform_quat, eq_data[6:10])
        self.data.qpos[self._qpos : self._qpos + 7] = [*position, *quat]

    def match_velocity(
        self, platform_position: NDArray[np.float64], linear: NDArray[np.float64], angular: NDArray[np.float64]
    ) -> None:
        """Give the payload the rigid-body velocity at its position of a platform at ``platform_position`` (m) moving
        at ``linear`` (m/s) and ``angular`` (rad/s, world frame)."""
        qpos, qvel = self.data.qpos, self.data.qvel
        payload_position = qpos[self._qpos : self._qpos + 3]
        payload_quat = qpos[self._qpos + 3 : self._qpos + 7]
        qvel[self._dof : self._dof + 3] = linear + np.cross(angular, payload_position - platform_position)
        qvel[self._dof + 3 : self._dof + 6] = quat_to_matrix(payload_quat).T @ angular
