"""What the controller sees of the robot, and when: the sample period and the sensor models."""

from __future__ import annotations

import math

from delta_env.validation import require_in

CONTROL_PERIOD = 1e-3
"""Sample period of the encoders, the torque sensing and the controller (s): a 1 kHz loop."""

ENCODER_BITS = 17
"""Resolution of the absolute joint encoders (bits per revolution)."""


def encoder_resolution(bits: int) -> float:
    """Step (rad) of an absolute encoder with ``bits`` bits per revolution: 2 pi / 2^bits."""
    return 2.0 * math.pi / 2**bits


ENCODER_RESOLUTION = encoder_resolution(ENCODER_BITS)
"""Step of the joint encoders (rad)."""

ENCODER_NOISE_STD = ENCODER_RESOLUTION / math.sqrt(12.0)
"""Standard deviation of the quantization error, uniform over one step (rad)."""

PHYSICS_TIMESTEP = CONTROL_PERIOD / 2
"""Default physics timestep h of the plant (s), :attr:`PlantConfig.timestep <delta_env.config.PlantConfig>`:
two MuJoCo steps per control period, which holds the kinematic loops closed (docs/design.md section 4)."""


def control_substeps(timestep: float) -> int:
    """Physics steps of ``timestep`` (s) per control period, else ``ValueError`` if it does not divide the period.

    The one check of the timestep against :data:`CONTROL_PERIOD`: the env applies it to its model and
    :class:`~delta_env.config.PlantConfig` (so a scenario file) to its ``timestep``. "Divides" is within the
    tolerance of ``numpy.isclose`` (1e-8 s + 1e-5 of the period).
    """
    n_substeps = round(CONTROL_PERIOD / timestep)
    if not abs(n_substeps * timestep - CONTROL_PERIOD) <= 1e-8 + 1e-5 * CONTROL_PERIOD:
        raise ValueError(
            f"the physics timestep {timestep} s must divide the control period {CONTROL_PERIOD} s "
            f"(timestep = {CONTROL_PERIOD} s / n for an integer n >= 1)"
        )
    return n_substeps


MEASURED_TORQUE_DELAY = PHYSICS_TIMESTEP
"""Age of a measured motor torque relative to the encoder sample it comes with (s): one physics step h.

The reading is the actuator force that MuJoCo held over the last physics step [t - h, t]. MuJoCo's
semi-implicit Euler step turns that force into the velocity change of the step, and the positions then
carry it as their central second difference at the step's start t - h: the torque belongs to the state
one physics step before the encoder sample. The within-period shape of the drive's current loop moves
the best fit by a fraction of h (to about 0.45 ms with the default 1 ms lag); tested against the
simulator in ``tests/test_sensors.py``.
"""


def require_torque_age(value: float) -> float:
    """``value``, the age (s) of a measured torque against its encoder sample, as a float if it lies in
    (0, :data:`CONTROL_PERIOD`] (a reading taken within the period it is read in), else ValueError naming it."""
    return require_in("torque_delay", value, 0.0, CONTROL_PERIOD, unit="s", low_open=True)


def rate_window(encoder_bits: int | None, timestep: float) -> float:
    """The window (s) whose mean rate the observed joint rate is: ``joint_velocities`` of the observation.

    With an encoder it is the backward difference of two readings, the mean over one control period. Without one
    (exact angles) it is MuJoCo's velocity after the last physics step, and the semi-implicit step moves the
    angles by exactly timestep times it: the mean over one physics step.

    Args:
        encoder_bits: The encoder's resolution (bits per revolution), or None for exact angles.
        timestep: The plant's physics step (s), in (0, CONTROL_PERIOD].
    """
    if not (math.isfinite(timestep) and 0.0 < timestep <= CONTROL_PERIOD):
        raise ValueError(f"timestep must lie in (0, {CONTROL_PERIOD}] s, got {timestep}")
    return timestep if encoder_bits is None else CONTROL_PERIOD
