"""A MuJoCo Delta robot that picks and places payloads of unknown mass.

``import delta_env`` registers ``DeltaPickPlace-v0`` with Gymnasium. The package is the simulated robot
and its task: geometry and kinematics, the plant (:class:`DeltaPlant`, built with ``mujoco.MjSpec``),
its sensors, reference trajectories and the environment.
"""

import gymnasium as gym

from delta_env import compile_cache  # noqa: F401 - first: sets numba's cache folder before anything compiles
from delta_env.config import (
    MAX_PAYLOAD_MASS,
    GearheadCompliance,
    PhysicalParameters,
    PlantConfig,
    PlantRealism,
    RandomizationRanges,
)
from delta_env.cycles import conveyor_cycles, standard_cycle
from delta_env.env import DeltaPickPlaceEnv, RewardWeights
from delta_env.excitation import excitation_trajectory
from delta_env.geometry import (
    GRAVITY,
    NOMINAL_GEOMETRY,
    NOMINAL_MASSES,
    TORQUE_LIMIT,
    DeltaGeometry,
    DeltaMasses,
)
from delta_env.plant import DeltaPlant
from delta_env.release import ReleaseSettings
from delta_env.scene import build_mjcf, build_model
from delta_env.sensors import CONTROL_PERIOD, MEASURED_TORQUE_DELAY
from delta_env.trajectories import Trajectory, concatenate

__all__ = [
    "CONTROL_PERIOD",
    "GRAVITY",
    "MAX_PAYLOAD_MASS",
    "MEASURED_TORQUE_DELAY",
    "NOMINAL_GEOMETRY",
    "NOMINAL_MASSES",
    "TORQUE_LIMIT",
    "DeltaGeometry",
    "DeltaMasses",
    "DeltaPickPlaceEnv",
    "DeltaPlant",
    "GearheadCompliance",
    "PhysicalParameters",
    "PlantConfig",
    "PlantRealism",
    "RandomizationRanges",
    "ReleaseSettings",
    "RewardWeights",
    "Trajectory",
    "build_mjcf",
    "build_model",
    "concatenate",
    "conveyor_cycles",
    "excitation_trajectory",
    "standard_cycle",
]

# The episode ends with its reference trajectory (truncated), so no TimeLimit is needed.
gym.register(id="DeltaPickPlace-v0", entry_point="delta_env.env:DeltaPickPlaceEnv")
