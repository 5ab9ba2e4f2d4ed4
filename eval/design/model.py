"""The design model: what every figure of the design study is judged by (docs/design-study.md).

A design is the rod-forearm model (``DeltaDynamics(..., forearm_rods=True)``) of its geometry with the masses of
:func:`delta_env.scaling.scaled_masses` and the same motors on every joint: the rotor inertia (armature) Ia,
viscous friction fv and Coulomb friction fc of the motor datasheet (:data:`DRIVE`, the plant's nominal drive
values without its per-joint scatter). In the model's terms the armature is rho1 = 1 + Ia / I, with
I = (m1/3 + m2) l1^2 the design's own arm inertia, and the friction is its (fv, fc) on every joint. Its cycles
dwell :data:`CYCLE_DWELL` at each end, carry the payload while the gripper holds and may use the design's whole
reach (:func:`path_limits`).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from controllers.dynamics import DeltaDynamics, ModelParameters
from delta_env import workspace
from delta_env.config import PlantRealism
from delta_env.geometry import DeltaGeometry, DeltaMasses
from delta_env.limits import WorkspaceLimits
from delta_env.scaling import scaled_masses
from delta_env.trajectories import Trajectory
from delta_env.validation import require_in

CYCLE_DWELL = 0.1
"""Rest at the pick and at the place point (s); process time, left out of the cycle time."""

DRIVE = PlantRealism()
"""The motor datasheet of every design: armature, viscous and Coulomb friction of the plant's nominal drive."""


def require_belt_height(belt_height: float) -> float:
    """``belt_height`` (m, base frame) as a float if it is finite and below the base (< 0), else ``ValueError``."""
    return require_in("belt_height", belt_height, -math.inf, 0.0, unit="m", high_open=True)


def design_model(
    geometry: DeltaGeometry, masses: DeltaMasses | None = None, drive: PlantRealism | None = DRIVE
) -> DeltaDynamics:
    """The rod-forearm model of a design with its scaled masses (or ``masses``) and its drives.

    Args:
        geometry: The design (m).
        masses: Its masses (kg); :func:`delta_env.scaling.scaled_masses` when None.
        drive: The motors (module docstring): ``armature``, ``viscous`` and ``coulomb`` are used, the same on
            every joint; None leaves the drives out (the links alone).
    """
    m = scaled_masses(geometry) if masses is None else masses
    links = DeltaDynamics(geometry, m1=m.m1, m2=m.m2, m0=m.m0, forearm_rods=True)
    if drive is None:
        return links
    return links.with_parameters(
        ModelParameters(
            rho1=1.0 + drive.armature / links.inertia,
            viscous=(drive.viscous,) * 3,
            coulomb=(drive.coulomb,) * 3,
        )
    )


def path_limits(geometry: DeltaGeometry, criteria: workspace.Criteria = workspace.DEXTEROUS) -> WorkspaceLimits:
    """Limits for paths of any design: its whole reach; the dexterity checks are the design study's own."""
    radius, z_min, z_max = workspace.reach_bounds(geometry, criteria.theta_range)
    return WorkspaceLimits(radius=radius, z_min=z_min, z_max=z_max, min_abs_k=1e-9, min_abs_det_a=1e-9)


def payload_profile(trajectory: Trajectory, payload: float) -> NDArray[np.float64]:
    """The carried mass (kg) at each sample: ``payload`` while the gripper holds, else 0, ``(N,)``."""
    return np.where(trajectory.gripper, payload, 0.0)
