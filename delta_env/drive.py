"""The drive's current loop as a 1 kHz controller sees it: a first-order lag under a zero-order hold.

The plant's actuator (``dyntype="filterexact"``) integrates T dtau/dt = u - tau exactly over each physics
step h: tau_{j+1} = a tau_j + (1 - a) u_j with a = exp(-h / T), and the force that acts during step j is
tau_j, the state before the update. A command u_k held over the n = period / h steps of a control period
therefore gives, at the control instants t_k = k * period,

    tau_{k+1} = p tau_k + (1 - p) u_k,    p = a^n = exp(-period / T),

which depends on the period only. Its exact inverse is u_k = (tau*_{k+1} - p tau_k) / (1 - p): the command
that brings the drive's output to tau*_{k+1} at the next control instant. Inside the period the output
is the exponential between the two instants, tau(t_k + j h) = a^j tau_k + (1 - a^j) u_k.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from delta_env.sensors import CONTROL_PERIOD

MAX_TIME_CONSTANT = 0.1
"""Largest lag time constant (s) accepted, as for the plant's ``actuator_lag``."""


class SampledLag:
    """The first-order drive lag sampled at the control instants, per joint, and its exact inverse.

    The object keeps the drive output it predicts at the current control instant, so :meth:`command`
    can be called once per period with the output wanted at the next one.

    Args:
        time_constant: Lag T (s) of each joint, a scalar or shape (3,), each in [0, 0.1]; 0 is a direct
            torque source (the command acts at once).
        period: Control period (s) over which each command is held, in (0, 0.1].
    """

    def __init__(self, time_constant: ArrayLike, period: float = CONTROL_PERIOD) -> None:
        time_constant = np.broadcast_to(np.asarray(time_constant, dtype=float), (3,)).copy()
        if not np.all(np.isfinite(time_constant) & (time_constant >= 0.0) & (time_constant <= MAX_TIME_CONSTANT)):
            raise ValueError(f"time_constant must lie in [0, {MAX_TIME_CONSTANT}] s, got {time_constant.tolist()}")
        if not (math.isfinite(period) and 0.0 < period <= 0.1):
            raise ValueError(f"period must lie in (0, 0.1] s, got {period}")
        self.time_constant = time_constant
        self.period = float(period)
        with np.errstate(divide="ignore"):
            self.pole = np.where(time_constant > 0.0, np.exp(-self.period / np.maximum(time_constant, 1e-300)), 0.0)
        self._gain = 1.0 / (1.0 - self.pole)
        self.output = np.zeros(3)

    def reset(self, output: ArrayLike = 0.0) -> None:
        """Set the drive output (N m) at the current instant: 0 after the plant's reset."""
        self.output = np.broadcast_to(np.asarray(output, dtype=float), (3,)).copy()

    def command(self, target: ArrayLike) -> NDArray[np.float64]:
        """The command (N m, shape (3,)) whose lagged output equals ``target`` at the next control instant.

        Advances the predicted output to ``target``, so the next call continues from there.
        """
        target = np.asarray(target, dtype=float)
        command = (target - self.pole * self.output) * self._gain
        self.output = target.copy()
        return command

    def advance(self, command: ArrayLike) -> NDArray[np.float64]:
        """Hold ``command`` (N m) over one period; returns the drive output at the next instant."""
        self.output = self.pole * self.output + (1.0 - self.pole) * np.asarray(command, dtype=float)
        return self.output.copy()
