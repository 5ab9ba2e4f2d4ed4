"""The residual policy, ``python -m eval.residual``: its training environments, hyperparameters, training and
scores against its base controller."""
