"""Controllers of the Delta robot: the algorithms, never the experiments (docs/design.md section 6).

A controller sees only the env's observation and nominal or identified parameters (the oracle bound
excepted). ``import controllers`` registers ``DeltaPickPlaceResidual-v0`` (the residual-policy env) with
Gymnasium; SB3 and torch are imported only when a policy is loaded or trained.
"""

import gymnasium as gym

from controllers.base import DEFAULT_KD, DEFAULT_KP, Controller, Observation, PDController
from controllers.compliance import (
    DriveCompliance,
    DriveMode,
    TwoMassLinearization,
    drive_modes,
    first_mode,
    first_mode_map,
    static_deflection,
)
from controllers.dynamics import DeltaDynamics, ModelParameters
from controllers.estimation import JointStateFilter, JointStateSmoother, PayloadRLS, smooth_joint_motion
from controllers.feedforward import FeedforwardController, LagCompensatedController, OracleController, model_controller
from controllers.payload import EmptyMoveSums, ModelCorrections, PayloadEstimator, Tare, tare_from_observations
from controllers.registry import (
    CONTROLLER_LABELS,
    ESTIMATOR_REGRESSORS,
    ControllerEntry,
    ControllerSetup,
    build_controller,
    controller_entry,
)
from controllers.servo import JointServo, ResonanceNotch, ServoGains, servo_gains
from controllers.shaping import ShapedController, Shaper, zv_shaper, zvd_shaper

__all__ = [
    "CONTROLLER_LABELS",
    "DEFAULT_KD",
    "DEFAULT_KP",
    "ESTIMATOR_REGRESSORS",
    "Controller",
    "ControllerEntry",
    "ControllerSetup",
    "DeltaDynamics",
    "DriveCompliance",
    "DriveMode",
    "EmptyMoveSums",
    "FeedforwardController",
    "JointServo",
    "JointStateFilter",
    "JointStateSmoother",
    "LagCompensatedController",
    "ModelCorrections",
    "ModelParameters",
    "Observation",
    "OracleController",
    "PDController",
    "PayloadEstimator",
    "PayloadRLS",
    "ResonanceNotch",
    "ServoGains",
    "ShapedController",
    "Shaper",
    "Tare",
    "TwoMassLinearization",
    "build_controller",
    "controller_entry",
    "drive_modes",
    "first_mode",
    "first_mode_map",
    "model_controller",
    "servo_gains",
    "smooth_joint_motion",
    "static_deflection",
    "tare_from_observations",
    "zv_shaper",
    "zvd_shaper",
]

# The env wraps DeltaPickPlace-v0 with a base controller; its module is imported when the env is made.
gym.register(id="DeltaPickPlaceResidual-v0", entry_point="controllers.residual.env:DeltaResidualEnv")
