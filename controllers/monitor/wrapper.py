"""A controller behind a fault monitor: what it keeps from the payload estimator, and how it reacts to a detected
fault (docs/design.md section 6, "Fault monitor")."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from controllers.base import Controller, Observation, payload_estimate_reader, payload_estimator_of
from controllers.monitor.detector import FaultMonitor
from controllers.monitor.events import DetectedFault
from controllers.monitor.tuning import REACTING_KINDS, ROLLBACK_SAMPLES, SENSOR_QUIET, SLOW_RATE
from controllers.payload import PayloadEstimator
from delta_env.faults import FAULT_REACTIONS


class MonitoredController:
    """Any controller behind a :class:`FaultMonitor`: it sees clean observations only, its payload estimator leaves
    out the equations that lean on drifting replacements or a collision and forgets the object on a slip, and a
    detected fault may ask the cell to slow down or stop. A collision is a transient: once it is over (the model
    agrees with the measurements again) and no lasting fault (a slip, a drive fault) was found since the reaction,
    the controller asks for full speed again, also after a stop that has not yet ended the episode.

    Args:
        controller: The controller to protect.
        monitor: Its monitor.
        reaction: One of :data:`FAULT_REACTIONS`.
        corrections_fit: A payload estimator run beside the controller only to fit the model's corrections to this
            robot on the empty moves, which the monitor's residual takes at each pick; None for the controller's own
            estimator (when it forms its equations at the measured state) or none.

    Attributes:
        estimator: The inner controller's payload estimator (:class:`~controllers.base.PayloadEstimating`), or None.
        requested_speed: The speed override (a fraction of the reference's speed) the controller asks the cell for:
            1 until a reaction asks for less, and again once a collision it answered is over.
    """

    def __init__(
        self,
        controller: Controller,
        monitor: FaultMonitor,
        reaction: Literal["continue", "slow", "stop"] = "continue",
        corrections_fit: PayloadEstimator | None = None,
    ) -> None:
        if reaction not in FAULT_REACTIONS:
            raise ValueError(f"reaction must be one of {list(FAULT_REACTIONS)}, got {reaction!r}")
        self.controller = controller
        self.monitor = monitor
        self.reaction = reaction
        self.name = controller.name
        estimator = payload_estimator_of(controller)  # a user's own kind of estimator is not the monitor's to gate
        self.estimator: PayloadEstimator | None = estimator if isinstance(estimator, PayloadEstimator) else None
        self.requested_speed = 1.0
        self._lasting = False
        """Whether a reaction answered a lasting fault (a slip, a drive fault), which full speed never follows."""
        self._estimate = payload_estimate_reader(controller)
        self._command: NDArray[np.float64] | None = None
        self._holding = False
        self._checkpoints = monitor.lag + ROLLBACK_SAMPLES
        self._corrections_fit = corrections_fit
        own = self.estimator if self.estimator is not None and self.estimator.measures_state else None
        self._corrections_source = own if corrections_fit is None else corrections_fit
        self._guarded = [e for e in (self.estimator, corrections_fit) if e is not None]
        """The estimators whose equations the monitor's findings gate: the controller's, the corrections' fit."""
        for estimator in self._guarded:
            estimator.keep_checkpoints(self._checkpoints)

    @property
    def detected_faults(self) -> Sequence[DetectedFault]:
        return self.monitor.events

    @property
    def payload_estimate(self) -> float:
        """The inner controller's payload estimate (kg) at the last call; 0 if it does not estimate the payload."""
        return self._estimate()

    def reset(self) -> None:
        self.controller.reset()
        self.monitor.reset()
        if self._corrections_fit is not None:
            self._corrections_fit.reset()
        self.requested_speed = 1.0
        self._lasting = False
        self._command = None
        self._holding = False
        self.monitor.set_corrections(None)

    def __call__(self, observation: Observation) -> NDArray[np.float64]:
        monitor = self.monitor
        seen = len(monitor.events)
        source = self._corrections_source
        holding = observation["gripper"].item(0) > 0.5
        if holding and not self._holding and source is not None and source.fits_corrections:
            monitor.set_corrections(source.corrections)  # what the empty moves so far say of this robot
        self._holding = holding
        clean = monitor.update(observation, self._command, self._estimate())
        new = monitor.events[seen:]
        collided = any(event.kind == "collision" for event in new)
        for estimator in self._guarded:
            if collided:
                # the collision's first samples entered before it was detected, from the first reading of its onset
                # on: undo them
                onset = monitor.collision_samples + monitor.onset_samples
                undo = min(self._checkpoints, monitor.lag - estimator.delay + onset + 1)
                if undo > 0:
                    estimator.rollback(undo)
                # and the servo's recovery follows it, which an estimator that forms its equations at the reference
                # reads as payload: the carry's equations stay out until they agree with the estimate again
                estimator.hold_out()
            if monitor.quiet_samples:
                estimator.skip(monitor.quiet_samples)
            if monitor.collision:
                estimator.skip(SENSOR_QUIET)
            if monitor.slipped:
                estimator.drop_object()
        if self.reaction != "continue":
            reacting = [event.kind for event in new if event.kind in REACTING_KINDS]
            if reacting:
                self.requested_speed = min(self.requested_speed, SLOW_RATE if self.reaction == "slow" else 0.0)
                self._lasting = self._lasting or any(kind != "collision" for kind in reacting)
            elif self.requested_speed < 1.0 and not self._lasting and not monitor.collision:
                self.requested_speed = 1.0  # the push is over
        if self._corrections_fit is not None:
            self._corrections_fit.update(clean)
        self._command = np.asarray(self.controller(clean), dtype=float)
        return self._command
