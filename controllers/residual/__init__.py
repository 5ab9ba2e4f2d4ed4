"""Residual policy on top of a model-based controller (docs/design.md section 6).

A base controller (by default the shipped policy's: MId+F+R feedforward leading the identified drive lag + the
servo layer, with the payload RLS) runs at 1 kHz; a learned
policy adds ``residual_limit * a`` with ``a`` in [-1, 1]^3, chosen every ``action_period`` control
steps and held in between (100 Hz by default).

- :class:`DeltaResidualEnv` (``DeltaPickPlaceResidual-v0``, a ``gym.Wrapper`` of ``DeltaPickPlace-v0``):
  the environment the policy is trained in.
- :class:`ResidualController`: the same loop as a :class:`~controllers.base.Controller`, running from
  observations only (the evaluation's "residual" row).
- :func:`load_residual_controller`: a saved policy (by default the shipped
  ``controllers/policies/residual_sac.zip``) as a Controller; :func:`save_residual_policy` writes a policy
  with the settings and the base controller it was trained with.

Both the env and the controller build the policy's observation with one :class:`ResidualFeatures`,
so that a policy sees exactly the same numbers in training and in evaluation.
"""

from controllers.residual.config import ResidualConfig
from controllers.residual.controller import PolicyFunction, ResidualController
from controllers.residual.env import DeltaResidualEnv
from controllers.residual.features import FEATURE_VERSION, ResidualFeatures
from controllers.residual.policy_file import (
    ALGORITHMS,
    DEFAULT_POLICY_PATH,
    PolicyBase,
    PolicySettings,
    ResidualPolicy,
    algorithm_class,
    load_residual_controller,
    load_residual_policy,
    read_policy_metadata,
    read_policy_settings,
    residual_controller,
    save_residual_policy,
    shipped_base_setup,
)

__all__ = [
    "ALGORITHMS",
    "DEFAULT_POLICY_PATH",
    "FEATURE_VERSION",
    "DeltaResidualEnv",
    "PolicyBase",
    "PolicyFunction",
    "PolicySettings",
    "ResidualConfig",
    "ResidualController",
    "ResidualFeatures",
    "ResidualPolicy",
    "algorithm_class",
    "load_residual_controller",
    "load_residual_policy",
    "read_policy_metadata",
    "read_policy_settings",
    "residual_controller",
    "save_residual_policy",
    "shipped_base_setup",
]
