"""Controllers of the Delta robot; ``import controllers`` registers ``DeltaPickPlaceResidual-v0``."""

import gymnasium as gym

# The residual-policy env runs a base controller inside, so it is registered here, above delta_env.
gym.register(id="DeltaPickPlaceResidual-v0", entry_point="controllers.residual:DeltaResidualEnv")
