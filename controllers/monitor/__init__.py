"""Fault detection from what a real controller sees: encoders, measured torques, its own commands, its model.

:class:`FaultMonitor` checks every observation (docs/design.md section 6, "Fault monitor"):

- **Sensor plausibility**, at the sample itself: a NaN or inf reading; an encoder step whose second difference
  asks an acceleration no drive could give (:data:`ACCELERATION_FACTOR`); an encoder that repeats its reading while
  the joint was moving several counts per sample, or while its torque beyond what rest holds moved it from rest
  (:data:`STUCK_SAMPLES`); a measured torque outside what a
  first-order current loop can do between the last torque and the held command (:data:`TORQUE_MARGIN`). Measured
  torques that stay short of the prediction, or keep falling short of what the slowest healthy loop would reach (a
  CUSUM, :data:`DRIVE_FAULT_EVIDENCE`), or whose sum over a window falls short of what any healthy loop owes the
  commands (:data:`DRIVE_FAULT_WINDOW`), are a drive that does not deliver its command.
- **External forces** (collisions): the residual of the identified model, measured torque minus the model's
  torque at the smoothed joint state (the tracking error smoothed, the reference's own derivatives added back; with
  the mass held, once known), mapped to a platform force F = J^-T r. Until the mass held is known (and while a pick or
  a place lies in the smoother's window), the residual's component along the payload regressor phi is taken off as
  far as a mass the cup can hold explains it, 0 to :data:`~delta_env.config.MAX_PAYLOAD_MASS` (an unknown mass looks
  exactly like a force along J^T (xdd + g)). On a joint near rest, what friction up to its breakaway can hold is left
  out too (:data:`REST_RATE`), and only what it can resist where the readings show the joint sliding.
- **Payload consistency** (slips and drops): the apparent mass of the last few samples against the mass held since
  the pick.

The monitor hands the controller a *clean* observation: a faulty encoder reading is replaced by the reference plus
the joint's last tracking error, a faulty torque by the current loop's prediction, so that one bad sample never
reaches the feedback, the model or an estimator. :class:`MonitoredController` runs any controller behind a
monitor, keeps what a fault corrupted out of its payload estimator and reacts to a detected fault.

A sample is one compiled call on one state record. The modules: :mod:`~controllers.monitor.tuning` (the thresholds
and reactions, each with its reason), :mod:`~controllers.monitor.events` (:class:`DetectedFault`,
:class:`ReportsFaults`), :mod:`~controllers.monitor.detector` (:class:`FaultMonitor`: the record, read as its
attributes, and the events), :mod:`~controllers.monitor.step` (the record and the step),
:mod:`~controllers.monitor.sensor_check` (the encoder and torque checks), :mod:`~controllers.monitor.model_check`
(the collision and slip checks on the model's residual), :mod:`~controllers.monitor.compiled` (their arithmetic on
three-vectors) and :mod:`~controllers.monitor.wrapper` (:class:`MonitoredController`: its reactions and the payload
estimator's rollback).
"""

from controllers.monitor.detector import FaultMonitor
from controllers.monitor.events import DetectedFault, ReportsFaults
from controllers.monitor.wrapper import MonitoredController

__all__ = [
    "DetectedFault",
    "FaultMonitor",
    "MonitoredController",
    "ReportsFaults",
]
