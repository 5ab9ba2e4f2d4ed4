"""What the controller sees of the robot, and when: the sample period and the sensor models."""

from __future__ import annotations

import math

CONTROL_PERIOD = 1e-3
"""Sample period of the encoders, the torque sensing and the controller (s): a 1 kHz loop."""

ENCODER_BITS = 17
"""Resolution of the absolute joint encoders (bits per revolution)."""

ENCODER_RESOLUTION = 2.0 * math.pi / 2**ENCODER_BITS
"""Step of the joint encoders (rad)."""

ENCODER_NOISE_STD = ENCODER_RESOLUTION / math.sqrt(12.0)
"""Standard deviation of the quantization error, uniform over one step (rad)."""

MEASURED_TORQUE_DELAY = 0.25e-3
"""Age of a measured motor torque relative to the encoder sample it comes with (s).

The reading is the actuator force that MuJoCo held constant over the last physics step [t - h, t]
(h = 0.5 ms); the state that step's acceleration belongs to lies at its centre, h / 2 before t.
"""
