"""A MuJoCo Delta robot that picks and places payloads of unknown mass.

``import delta_env`` registers ``DeltaPickPlace-v0`` with Gymnasium.
"""

import gymnasium as gym

from delta_env.geometry import NOMINAL_GEOMETRY, NOMINAL_MASSES, TORQUE_LIMIT, DeltaGeometry, DeltaMasses

__all__ = ["NOMINAL_GEOMETRY", "NOMINAL_MASSES", "TORQUE_LIMIT", "DeltaGeometry", "DeltaMasses"]

# The episode ends with its reference trajectory (truncated), so no TimeLimit is needed.
gym.register(id="DeltaPickPlace-v0", entry_point="delta_env.env:DeltaPickPlaceEnv")
# The residual-policy env runs a base controller inside; imported lazily so delta_env stays free of controllers.
gym.register(id="DeltaPickPlaceResidual-v0", entry_point="controllers.residual:DeltaResidualEnv")
