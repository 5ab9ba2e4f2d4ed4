"""Payload-adaptive timing of pick-and-place moves (docs/design.md section 9): how a cell decides how fast to move.

A :class:`PayloadTiming` implements :class:`delta_env.timing.MoveTiming` with the time-optimal planner of
:mod:`controllers.timing` on the identified model, within a share of the drive's envelope (the task's torque
share, the margin for tracking). Every move also keeps the drive's thermal rating: by the model, the RMS torque
of each joint over the move and the dwell that follows it (holding the move's end point) stays below the rated
torque less :data:`THERMAL_MARGIN`; a move that would exceed it is planned within a smaller share of the envelope
(bisection), which cools better than waiting. Empty moves are timed for the empty gripper; carries by mode:

- ``"worst_case"``: every carry for the task's heaviest object, as an industrial controller does when its
  objects are not weighed (or its payload not declared): the best a cell can do without knowing the mass;
- ``"declared"``: each carry for its object's true mass, as a per-object payload schedule would give: the
  reference a payload estimate can at best reach, not a controller;
- ``"online"``: a carry starts on the plan for the heaviest object; once the payload estimator (the
  controller's RLS) has settled, the rest of the carry continues on a plan for the estimate plus its
  uncertainty and a margin, from the state the carry has reached (the past is kept, the continuation is C2):
  at once if one was precomputed with the carry's plan (:data:`PRECOMPUTED_TAKEOVERS`), else after the planner's
  time (:data:`PLANNING_LATENCY`). It may replan again as the estimate tightens, by at least
  :data:`REPLAN_STEP`.
"""

from __future__ import annotations

import functools
import math
import weakref
from collections.abc import Callable
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from controllers.base import Controller, Observation
from controllers.dynamics import DeltaDynamics, ModelParameters
from controllers.payload import PayloadEstimator
from controllers.timing import TimeOptimalPlanner
from delta_env.cycles import DEFAULT_DWELL
from delta_env.drive import DriveLimits
from delta_env.geometry import DeltaGeometry, DeltaMasses
from delta_env.timing import DEFAULT_TORQUE_SHARE, TimeLaw
from delta_env.trajectories import Segment
from delta_env.validation import require_in, require_instance

Mode = Literal["worst_case", "declared", "online"]

MODES: tuple[Mode, ...] = ("worst_case", "declared", "online")
"""The planned timings, as :attr:`delta_env.scenario.PickPlaceTask.timing` names them."""

SETTLED_STD = 0.5
"""The estimate counts as settled once its standard deviation (kg) is below this."""

ESTIMATE_SIGMAS = 1.0
"""A retimed carry is planned for the estimate plus this many of its standard deviations (and the margin)."""

ESTIMATE_MARGIN = 0.05
"""Mass (kg) added to the estimate's upper bound when a carry is retimed: the estimate's model error, which its
variance does not describe (the tare's spread and the lift-off transient are tens of grams)."""

REPLAN_STEP = 0.05
"""A carry is replanned only for a mass at least this much (kg) lighter than its current plan."""

PLANNING_LATENCY = 0.015
"""Time (s) from the estimate that asks for a new plan to the sample the new plan takes over from: longer than a
replan takes on one core (:data:`controllers.timing.REPLAN_GRID_INTERVALS`; docs/measurements.md, "Pick rate"),
so the carry keeps its law that long and the online rate is what a cell whose planner runs beside the 1 kHz loop
would get."""

PRECOMPUTED_TAKEOVERS = (0.015, 0.02, 0.025, 0.03, 0.04)
"""Times (s) into a carry from which an online timing precomputes, while it plans the carry, continuations for
:data:`PRECOMPUTED_PAYLOADS`: an estimate that settles before one of them switches at no planning latency."""

PRECOMPUTED_PAYLOADS = (0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 3.5)
"""Payloads (kg) of the precomputed continuations (below the heaviest object only)."""

MAX_CACHED_PLANS = 512
"""Laws kept per planner (the oldest go first): declared timings of random objects rarely repeat."""

THERMAL_MARGIN = 0.05
"""Share of the rated torque held back by the thermal check of every move (model error)."""

THERMAL_BISECTIONS = 6
"""Bisection steps of the share of the envelope that keeps a move within the thermal rating (2 % resolution)."""


class PayloadTiming:
    """Times every move with a :class:`TimeOptimalPlanner`, carries by ``mode`` (the module docstring).

    Args:
        planner: The time-optimal planner on the identified model within the drive's envelope.
        mode: ``"worst_case"``, ``"declared"`` or ``"online"``.
        max_payload: The heaviest object of the task (kg), >= 0.
        estimator: The payload estimator whose estimate retimes carries (``"online"`` only; the controller's own).
        dwell: Rest (s) after every move, part of its thermal budget (the task's dwell).
        torque_share: Share of the planner's envelope (after its margin) that moves may use, in (0, 1]: the
            margin for tracking (:data:`DEFAULT_TORQUE_SHARE`).
    """

    def __init__(
        self,
        planner: TimeOptimalPlanner,
        mode: Mode,
        max_payload: float,
        estimator: PayloadEstimator | None = None,
        dwell: float = DEFAULT_DWELL,
        torque_share: float = DEFAULT_TORQUE_SHARE,
    ) -> None:
        if mode not in MODES:
            raise ValueError(f"mode must be one of {list(MODES)}, got {mode!r}")
        require_instance("planner", planner, TimeOptimalPlanner)
        self.max_payload = require_in("max_payload", max_payload, 0.0, unit="kg")
        if mode == "online" and estimator is None:
            raise ValueError("online timing needs the payload estimator whose estimate retimes the carries")
        self.planner = planner
        self.mode = mode
        self.estimator = estimator
        self.dwell = require_in("dwell", dwell, 0.0, unit="s")
        self.torque_share = require_in("torque_share", torque_share, 0.0, 1.0, low_open=True)
        self.retimes_online = mode == "online"
        self._law: TimeLaw | None = None  # the carry law last returned by retime, and the mass it is planned for
        self._law_mass = math.inf

    def _plan(self, shape: Segment, payload: float) -> TimeLaw:
        """The planner's law for ``shape`` and ``payload`` (kg), planned once per planner, shape, mass, dwell and
        share (a cell repeats its moves: the standard cycle has two shapes)."""
        key = (shape.start.tobytes(), shape.end.tobytes(), shape.lift_height, shape.lift_fraction, payload)
        key += (self.dwell, self.torque_share)
        plans = _PLANS.setdefault(self.planner, {})
        if len(plans) >= MAX_CACHED_PLANS:
            del plans[next(iter(plans))]
        if key not in plans:
            law = self._within_rating(lambda scale: self.planner.plan(shape, payload, scale), shape, payload)
            if law is None:
                raise ValueError(
                    f"no share of the envelope keeps a move with {payload} kg within the drive's rated torque "
                    f"{self.planner.drive.rated_torque} N m (less {100 * THERMAL_MARGIN:.0f} %)"
                )
            plans[key] = law
        return plans[key]

    def thermal_ratio(self, shape: Segment, law: TimeLaw, payload: float) -> float:
        """Largest joint RMS torque over the move and the dwell after it, over the rated torque less the margin.

        By the planner's model with ``payload`` (kg) throughout; the dwell holds the last sample's (static) torque.
        """
        torque, _ = self.planner.model_torque(shape, law, payload)
        squared = np.sum(torque[:-1] ** 2, axis=0) * law.dt + self.dwell * torque[-1] ** 2
        rms = np.sqrt(squared / (law.duration + self.dwell))
        return float(np.max(rms)) / ((1.0 - THERMAL_MARGIN) * self.planner.drive.rated_torque)

    def _within_rating(self, planned: Callable[[float], TimeLaw], shape: Segment, payload: float) -> TimeLaw | None:
        """``planned(1)`` if it is within the thermal rating, else ``planned(scale)`` with the largest share of the
        envelope that is (bisection over :data:`THERMAL_BISECTIONS` steps; the squared torque falls with it), or
        None if no share is: a continuation from a moving state may be unable to stop within a small share."""
        law = planned(self.torque_share)
        if self.thermal_ratio(shape, law, payload) <= 1.0:
            return law
        low, high, best = 0.0, self.torque_share, None
        for _ in range(THERMAL_BISECTIONS):
            scale = 0.5 * (low + high)
            try:
                candidate = planned(scale)
            except ValueError:  # too small a share to stop from where the move is
                low = scale
                continue
            if self.thermal_ratio(shape, candidate, payload) <= 1.0:
                low, best = scale, candidate
            else:
                high = scale
        return best

    def carry(self, shape: Segment, declared_mass: float) -> TimeLaw:
        """The law of a carry: for its declared mass (kg) in ``"declared"`` mode, else for the heaviest object.

        ``"online"`` also precomputes its continuations (:data:`PRECOMPUTED_TAKEOVERS`), once per carry shape.
        """
        law = self._plan(shape, declared_mass if self.mode == "declared" else self.max_payload)
        if self.retimes_online and law not in _CONTINUATIONS:
            _CONTINUATIONS[law] = self._continuations(shape, law)
        return law

    def _continuations(self, shape: Segment, law: TimeLaw) -> list[tuple[int, float, TimeLaw]]:
        """(takeover sample, payload, law) of ``law``'s continuations for lighter objects, earliest first."""
        table = []
        for takeover in sorted({round(t / law.dt) for t in PRECOMPUTED_TAKEOVERS}):
            for payload in (p for p in PRECOMPUTED_PAYLOADS if p <= self.max_payload - REPLAN_STEP):
                continued = self._continued(shape, law, takeover, payload)
                if continued is not None:
                    table.append((takeover, payload, continued))
        return table

    def _continued(self, shape: Segment, law: TimeLaw, takeover: int, payload: float) -> TimeLaw | None:
        """``law`` continued from sample ``takeover`` for ``payload`` (kg) within the rating, if shorter."""
        if takeover >= len(law) - 1:
            return None
        try:
            continued = self._within_rating(
                lambda scale: self.planner.replan(shape, law, takeover, payload, scale), shape, payload
            )
        except ValueError:  # no continuation from there within the share
            return None
        return continued if continued is not None and len(continued) < len(law) else None

    def empty(self, shape: Segment) -> TimeLaw:
        """The law of an empty move: for the empty gripper."""
        return self._plan(shape, 0.0)

    def retime(self, shape: Segment, law: TimeLaw, index: int) -> TimeLaw | None:
        """``"online"``: the rest of the carry replanned for the settled estimate, or None to keep ``law``.

        The new law takes over :data:`PLANNING_LATENCY` after ``index`` and must be shorter than ``law``; a
        non-finite estimate or variance (a sensor fault) never retimes.
        """
        if not self.retimes_online:
            return None
        if index == 0 or law is not self._law:  # a new carry runs on the heaviest object's plan
            self._law, self._law_mass = law, self.max_payload
        mass, variance = self.estimator.mass, self.estimator.rls.variance
        if not (math.isfinite(mass) and math.isfinite(variance) and 0.0 <= variance <= SETTLED_STD**2):
            return None
        payload = min(self.max_payload, max(0.0, mass + ESTIMATE_SIGMAS * math.sqrt(variance) + ESTIMATE_MARGIN))
        if payload > self._law_mass - REPLAN_STEP:
            return None
        takeover = index + round(PLANNING_LATENCY / law.dt)
        # A precomputed continuation that takes over before a new plan could, for the lightest payload that covers
        # the estimate; else a new plan.
        ready = [
            (start, mass_, continued)
            for start, mass_, continued in _CONTINUATIONS.get(law, ())
            if index <= start < takeover and payload <= mass_ < self._law_mass - REPLAN_STEP
        ]
        if ready:
            _, self._law_mass, retimed = min(ready, key=lambda entry: (entry[0], entry[1]))
        else:
            self._law_mass = payload  # tried: the estimate has to fall by another step before the next try
            retimed = self._continued(shape, law, takeover, payload)
        if retimed is None:
            return None
        self._law = retimed
        return retimed


_CONTINUATIONS: weakref.WeakKeyDictionary[TimeLaw, list[tuple[int, float, TimeLaw]]] = weakref.WeakKeyDictionary()
"""Precomputed continuations of online carries' laws (:meth:`PayloadTiming._continuations`)."""

_PLANS: weakref.WeakKeyDictionary[TimeOptimalPlanner, dict[tuple, TimeLaw]] = weakref.WeakKeyDictionary()
"""Laws already planned, per planner (at most :data:`MAX_CACHED_PLANS` each)."""


@functools.cache
def shared_planner(
    geometry: DeltaGeometry,
    masses: DeltaMasses,
    parameters: ModelParameters,
    drive: DriveLimits,
    drive_lag: float | tuple[float, float, float],
) -> TimeOptimalPlanner:
    """One :class:`TimeOptimalPlanner` per process for the MId+F+R model of this robot (identified ``parameters``)
    and drive, so that the laws it plans are reused across episodes."""
    dynamics = DeltaDynamics.of_robot(geometry, masses, parameters, forearm_rods=True)
    return TimeOptimalPlanner(dynamics, drive, drive_lag)


class EstimatingController:
    """A controller run beside a payload estimator of its own: the cell's estimate, which an online timing reads
    whatever the control law (e.g. PD, or a user's controller without an estimator).

    Args:
        controller: The control law; its commands are returned unchanged.
        estimator: Updated with every observation before the controller is called.
    """

    def __init__(self, controller: Controller, estimator: PayloadEstimator) -> None:
        self.controller = controller
        self.estimator = estimator
        self.name = controller.name

    @property
    def payload_estimate(self) -> float:
        """The estimator's mass (kg) at the last call."""
        return self.estimator.mass

    def reset(self) -> None:
        self.controller.reset()
        self.estimator.reset()

    def __call__(self, observation: Observation) -> NDArray[np.float64]:
        self.estimator.update(observation)
        return self.controller(observation)
