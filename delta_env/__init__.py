"""A MuJoCo Delta robot that picks and places payloads of unknown mass."""

from delta_env.geometry import NOMINAL_GEOMETRY, NOMINAL_MASSES, DeltaGeometry, DeltaMasses

__all__ = ["NOMINAL_GEOMETRY", "NOMINAL_MASSES", "DeltaGeometry", "DeltaMasses"]
