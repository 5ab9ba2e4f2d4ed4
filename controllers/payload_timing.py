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
- ``"online"``: a carry starts on a plan for the heaviest object within the envelope but hotter than its rating
  (:data:`START_SHARE`: the thermal budget is an average, which the rest of the carry settles). Before the carry
  runs, with its plan, the cell precomputes that plan's rated continuations (once per carry shape): from each of
  its takeovers on (:data:`TAKEOVER_SCALES` of the time at which the estimator's deviation, predicted along the
  plan, falls within :data:`REPLAN_STEP`), for each of :data:`PRECOMPUTED_PAYLOADS`, from the state the carry reaches
  there (the past is kept, the continuation is C2), within the rating and braking no harder than that payload's
  rated law (:meth:`PayloadTiming._braking`). Once the payload estimator (the controller's RLS) has settled, the
  carry switches, once and at no planning latency, to the table's continuation for the lightest payload that
  covers the estimate plus its uncertainty and a margin, unless waiting for a later takeover is free or buys a
  shorter law (:meth:`PayloadTiming.retime`). Nothing is planned while a carry runs: a rated continuation bisects
  its share, about 100 ms of a core, most of a carry. A carry still on its start at the last takeover continues
  on the precomputed rated plan for the heaviest object.
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
from delta_env import kinematics
from delta_env.cycles import DEFAULT_DWELL
from delta_env.drive import DriveLimits
from delta_env.geometry import DeltaGeometry, DeltaMasses
from delta_env.timing import DEFAULT_TORQUE_SHARE, TimeLaw, move_samples
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
"""A carry is continued only for a mass at least this much (kg) lighter than the heaviest object."""

START_SHARE = 0.6
"""Share of the task's torque share on which an online carry starts, planned for the heaviest object: within the
envelope whatever the object, but too hot for the thermal rating on its own, so that the first samples, before the
estimate settles, are not slowed by a budget that the whole move and its dwell share (every carry law on the whole
envelope is thermally limited: about 0.4 to 0.6 of it). Its rated continuations reach about the declared timing
(docs/measurements.md, "Pick rate")."""

TAKEOVER_SCALES = (1.0, 1.125, 1.25, 1.375, 1.5, 1.75)
"""Times into an online carry from which it precomputes, with its plan, continuations for
:data:`PRECOMPUTED_PAYLOADS` (the only samples at which a carry switches), as multiples of the carry's settle
time (:meth:`PayloadTiming.settle_time`): the first sample at which the estimator's predicted standard deviation
along the carry's start law is within :data:`REPLAN_STEP`. The estimate overshoots over the lift's first
milliseconds (on the nominal robot by 6 to 16 %, until about 22 ms), a bias its deviation does not describe, so a heavy
object waits for a later takeover (:meth:`PayloadTiming.retime`). The last is the fallback: a carry still on its
unrated start there continues on the precomputed rated plan for the heaviest object. On the nominal robot (settle
time 17 ms) they are 17 to 30 ms (docs/design.md section 9)."""

PRECOMPUTED_PAYLOADS = tuple(round(REPLAN_STEP * step, 2) for step in range(1, 80))
"""Payloads (kg) of the precomputed continuations, :data:`REPLAN_STEP` apart, 0.05 to 3.95 kg (below the heaviest
object by :data:`REPLAN_STEP` only; the heaviest object's own at the last takeover, :data:`TAKEOVER_SCALES`): a
carry's bound rounds up to the next one, about half a millisecond per step. A 0.1 kg grid costs half the table's
CPU and about 0.25 ms per carry (docs/measurements.md)."""

BRAKING_PAYLOADS = (0.0, 0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 3.5, 4.0)
"""Payloads (kg) whose rated laws' shares of the envelope give, by linear interpolation (and with the heaviest
object's), the share within which a continuation brakes (:meth:`PayloadTiming._braking`)."""

MAX_CACHED_PLANS = 512
"""Laws and braking shares kept per planner (the oldest go first): declared timings of random objects rarely
repeat."""

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
        min_payload: The lightest object of the task (kg), in [0, ``max_payload``]: an online carry starts hot
            (:data:`START_SHARE`) only if its object may be lighter than the heaviest by a :data:`REPLAN_STEP`.
    """

    def __init__(
        self,
        planner: TimeOptimalPlanner,
        mode: Mode,
        max_payload: float,
        estimator: PayloadEstimator | None = None,
        dwell: float = DEFAULT_DWELL,
        torque_share: float = DEFAULT_TORQUE_SHARE,
        min_payload: float = 0.0,
    ) -> None:
        if mode not in MODES:
            raise ValueError(f"mode must be one of {list(MODES)}, got {mode!r}")
        require_instance("planner", planner, TimeOptimalPlanner)
        self.max_payload = require_in("max_payload", max_payload, 0.0, unit="kg")
        self.min_payload = require_in("min_payload", min_payload, 0.0, self.max_payload, unit="kg")
        if mode == "online" and estimator is None:
            raise ValueError("online timing needs the payload estimator whose estimate retimes the carries")
        self.planner = planner
        self.mode = mode
        self.estimator = estimator
        self.dwell = require_in("dwell", dwell, 0.0, unit="s")
        self.torque_share = require_in("torque_share", torque_share, 0.0, 1.0, low_open=True)
        self.retimes_online = mode == "online"

    def _plan(self, shape: Segment, payload: float) -> TimeLaw:
        """The planner's law for ``shape`` and ``payload`` (kg), planned once per planner, shape, mass, dwell and
        share (a cell repeats its moves: the standard cycle has two shapes)."""
        key = (shape.start.tobytes(), shape.end.tobytes(), shape.lift_height, shape.lift_fraction, payload)
        key += (self.dwell, self.torque_share)
        plans = _PLANS.setdefault(self.planner, {})
        if len(plans) >= MAX_CACHED_PLANS:
            del plans[next(iter(plans))]
        if key not in plans:
            rated = self._within_rating(lambda scale: self.planner.plan(shape, payload, scale), shape, payload)
            if rated is None:
                raise ValueError(
                    f"no share of the envelope keeps a move with {payload} kg within the drive's rated torque "
                    f"{self.planner.drive.rated_torque} N m (less {100 * THERMAL_MARGIN:.0f} %)"
                )
            law, share = rated
            plans[key] = law
            _RATED_SHARES[law] = share
        return plans[key]

    def thermal_ratio(self, shape: Segment, law: TimeLaw, payload: float) -> float:
        """Largest joint RMS torque over the move and the dwell after it, over the rated torque less the margin.

        By the planner's model with ``payload`` (kg) throughout; the dwell holds the last sample's (static) torque.
        """
        torque, _ = self.planner.model_torque(shape, law, payload)
        squared = np.sum(torque[:-1] ** 2, axis=0) * law.dt + self.dwell * torque[-1] ** 2
        rms = np.sqrt(squared / (law.duration + self.dwell))
        return float(np.max(rms)) / ((1.0 - THERMAL_MARGIN) * self.planner.drive.rated_torque)

    def _within_rating(
        self, planned: Callable[[float], TimeLaw], shape: Segment, payload: float
    ) -> tuple[TimeLaw, float] | None:
        """(``planned(share)``, share) with the task's share if that law is within the thermal rating, else with the
        largest share of the envelope that is (bisection over :data:`THERMAL_BISECTIONS` steps; the squared torque
        falls with it), or None if no share is: a continuation from a moving state may be unable to stop within a
        small share."""
        law = planned(self.torque_share)
        if self.thermal_ratio(shape, law, payload) <= 1.0:
            return law, self.torque_share
        low, high, best = 0.0, self.torque_share, None
        for _ in range(THERMAL_BISECTIONS):
            scale = 0.5 * (low + high)
            try:
                candidate = planned(scale)
            except ValueError:  # too small a share to stop from where the move is
                low = scale
                continue
            if self.thermal_ratio(shape, candidate, payload) <= 1.0:
                low, best = scale, (candidate, scale)
            else:
                high = scale
        return best

    def carry(self, shape: Segment, declared_mass: float) -> TimeLaw:
        """The law of a carry: for its declared mass (kg) in ``"declared"`` mode, else for the heaviest object.

        ``"online"`` starts hot (:meth:`_start`) if lighter objects may come: with objects of one mass the rated
        worst case is the declared timing, and a hot start would only move heat to the end of the carry, where the
        platform then settles worse. It also precomputes the start's continuations (:meth:`takeovers`), once per carry
        shape.
        """
        rated = self._plan(shape, declared_mass if self.mode == "declared" else self.max_payload)
        if not self.retimes_online:
            return rated
        key = (shape.start.tobytes(), shape.end.tobytes(), shape.lift_height, shape.lift_fraction, self.max_payload)
        key += (self.dwell, self.torque_share, "start")
        plans = _PLANS.setdefault(self.planner, {})
        if self.min_payload > self.max_payload - REPLAN_STEP:
            law = rated
        elif key in plans:
            law = plans[key]
        else:
            law = plans[key] = self._start(shape, rated)
        if law not in _CONTINUATIONS:
            _CONTINUATIONS[law] = self._continuations(shape, law, len(rated))
        return law

    def _start(self, shape: Segment, rated: TimeLaw) -> TimeLaw:
        """The start law of an online carry (:data:`START_SHARE`) if its rated continuation for the heaviest object
        from its last takeover exists, else ``rated`` (the heaviest object's rated law)."""
        try:
            start = self.planner.plan(shape, self.max_payload, START_SHARE * self.torque_share)
        except ValueError:
            return rated
        if len(start) >= len(rated):
            return rated
        takeovers = self.takeovers(shape, start)
        if not takeovers or self._continued(shape, start, takeovers[-1], self.max_payload, math.inf) is None:
            return rated
        if self.thermal_ratio(shape, start, self.max_payload) > 1.0:
            _UNRATED_STARTS.add(start)
        return start

    def _continuations(self, shape: Segment, law: TimeLaw, rated_samples: int) -> list[tuple[int, float, TimeLaw]]:
        """(takeover sample, payload, law) of ``law``'s rated continuations, earliest first: for lighter objects
        if shorter than ``rated_samples`` (the heaviest object's rated law), and, for a start law over the rating,
        the heaviest object's own from the last takeover (:meth:`takeovers`)."""
        table = []
        takeovers = self.takeovers(shape, law)
        for takeover in takeovers:
            for payload in (p for p in PRECOMPUTED_PAYLOADS if p <= self.max_payload - REPLAN_STEP):
                continued = self._continued(shape, law, takeover, payload, rated_samples)
                if continued is not None:
                    table.append((takeover, payload, continued))
        if law in _UNRATED_STARTS:
            fallback = takeovers[-1]
            table.append(
                (fallback, self.max_payload, self._continued(shape, law, fallback, self.max_payload, math.inf))
            )
        return table

    def settle_time(self, shape: Segment, law: TimeLaw) -> int:
        """The sample of a carry of ``shape`` timed by ``law`` at which the payload estimate is predicted to be within
        :data:`REPLAN_STEP` (one standard deviation), or ``len(law)`` if it never is.

        The estimator's variance depends only on the regressor along the carry and its own noise model, not on the
        readings (:meth:`~controllers.payload.PayloadEstimator.predicted_variance`): known once the carry is
        planned, for this robot and this carry shape."""
        x, velocity, acceleration = move_samples(shape, law)
        theta, theta_dot, theta_ddot = kinematics.cartesian_to_joint(
            self.planner.dynamics.geometry, x, velocity, acceleration
        )
        settled = self.estimator.predicted_variance(theta, theta_dot, theta_ddot) <= REPLAN_STEP**2
        return int(np.argmax(settled)) if settled.any() else len(law)

    def takeovers(self, shape: Segment, law: TimeLaw) -> tuple[int, ...]:
        """The samples of an online carry's start ``law`` from which its continuations are precomputed: the
        :data:`TAKEOVER_SCALES` of its :meth:`settle_time`, those before the law's last sample; the last is the
        fallback. Derived once per law."""
        if law not in _TAKEOVERS:
            settle = self.settle_time(shape, law)
            samples = sorted({round(scale * settle) for scale in TAKEOVER_SCALES})
            _TAKEOVERS[law] = tuple(sample for sample in samples if sample < len(law) - 1)
        return _TAKEOVERS[law]

    def _continued(
        self, shape: Segment, law: TimeLaw, takeover: int, payload: float, within: float | None = None
    ) -> TimeLaw | None:
        """``law`` continued from sample ``takeover`` for ``payload`` (kg) within the rating, if shorter than
        ``within`` samples (default: ``law``'s)."""
        within = len(law) if within is None else within
        if takeover >= len(law) - 1:
            return None
        braking_from, rated_share = self._braking(shape, payload)

        def planned(scale: float) -> TimeLaw:
            return self.planner.replan(shape, law, takeover, payload, scale, (braking_from, min(scale, rated_share)))

        try:
            continued = self._within_rating(planned, shape, payload)
        except ValueError:  # no continuation from there within the share
            return None
        return continued[0] if continued is not None and len(continued[0]) < within else None

    def _braking(self, shape: Segment, payload: float) -> tuple[float, float]:
        """(tau, share): where a carry of ``shape`` brakes, from the point at which the heaviest object's rated law
        runs fastest on, and the share of the envelope the rated laws brake with at ``payload`` (kg): linear between
        those of :data:`BRAKING_PAYLOADS` (and the heaviest object's), each rated law's thermal share.

        A continuation brakes within that share (:meth:`_continued`): the heat its carry saved while it ran slower
        than the rated law goes into the rest of the move, not into the braking, whose deceleration sets the
        platform's settle at the place (docs/design.md section 9)."""
        key = (shape.start.tobytes(), shape.end.tobytes(), shape.lift_height, shape.lift_fraction, self.max_payload)
        key += (self.dwell, self.torque_share)
        brakings = _BRAKINGS.setdefault(self.planner, {})
        if len(brakings) >= MAX_CACHED_PLANS:
            del brakings[next(iter(brakings))]
        if key not in brakings:
            heaviest = self._plan(shape, self.max_payload)
            _, velocity, _ = move_samples(shape, heaviest)
            fastest = float(heaviest.tau[int(np.argmax(np.linalg.norm(velocity, axis=1)))])
            payloads = sorted({p for p in BRAKING_PAYLOADS if p < self.max_payload} | {self.max_payload})
            shares = [_RATED_SHARES[self._plan(shape, p)] for p in payloads]
            brakings[key] = (fastest, tuple(payloads), tuple(shares))
        fastest, payloads, shares = brakings[key]
        return fastest, float(np.interp(payload, payloads, shares))

    def empty(self, shape: Segment) -> TimeLaw:
        """The law of an empty move: for the empty gripper."""
        return self._plan(shape, 0.0)

    def precomputed(self, law: TimeLaw) -> list[tuple[int, float, TimeLaw]]:
        """(takeover sample, payload, law) of the continuations precomputed with the carry law ``law`` (earliest
        first; none for a continuation, or for a timing that does not retime): all that :meth:`retime` may return."""
        return _CONTINUATIONS.get(law, []) if self.retimes_online else []

    def retime(self, shape: Segment, law: TimeLaw, index: int) -> TimeLaw | None:
        """``"online"``: the carry's precomputed continuation from sample ``index`` for the settled estimate, or None
        to keep ``law``.

        Nothing is planned while the carry runs: only a carry on its start law switches, once, to one of the
        continuations precomputed with that law (:meth:`_continuations`), at one of their takeover samples, for the
        lightest payload that covers the estimate's bound. It waits for the next takeover if that one's law for the
        same payload is no longer (for free: the estimate overshoots after the settle time), or for a later one
        whose law for the estimate itself (its bound once the deviation has shrunk) is shorter. A carry still on its
        unrated start at its last takeover (:meth:`takeovers`) takes the heaviest object's rated continuation,
        whatever the estimate (a non-finite one included).
        """
        if not self.retimes_online:
            return None
        table = self.precomputed(law)
        here = [(mass_, continued) for start, mass_, continued in table if start == index]
        if not here:
            return None
        fallback = next((continued for mass_, continued in here if mass_ == self.max_payload), None)
        mass, variance = self.estimator.mass, self.estimator.rls.variance
        if not (math.isfinite(mass) and math.isfinite(variance) and 0.0 <= variance <= SETTLED_STD**2):
            return fallback
        lighter = [(mass_, continued) for mass_, continued in here if mass_ <= self.max_payload - REPLAN_STEP]
        bound = mass + ESTIMATE_SIGMAS * math.sqrt(variance) + ESTIMATE_MARGIN
        covering = [entry for entry in lighter if entry[0] >= bound]
        if not covering:
            return fallback
        payload, now = min(covering, key=lambda entry: entry[0])
        later = [(start, mass_, len(continued)) for start, mass_, continued in table if start > index]
        following = min((start for start, _, _ in later), default=None)
        # waiting is free if the next takeover's law for the same payload is no longer (the estimate overshoots
        # over the lift's first milliseconds, then falls); worth it if a later law for the estimate itself is shorter
        free = any(start == following and mass_ == payload and samples <= len(now) for start, mass_, samples in later)
        expected = mass + ESTIMATE_MARGIN
        shorter = any(expected <= mass_ < payload and samples < len(now) for _, mass_, samples in later)
        return None if free or shorter else now


_CONTINUATIONS: weakref.WeakKeyDictionary[TimeLaw, list[tuple[int, float, TimeLaw]]] = weakref.WeakKeyDictionary()
"""Precomputed continuations of online carries' laws (:meth:`PayloadTiming._continuations`)."""

_TAKEOVERS: weakref.WeakKeyDictionary[TimeLaw, tuple[int, ...]] = weakref.WeakKeyDictionary()
"""The takeover samples of online carries' start laws (:meth:`PayloadTiming.takeovers`)."""

_RATED_SHARES: weakref.WeakKeyDictionary[TimeLaw, float] = weakref.WeakKeyDictionary()
"""The share of the envelope each rated law was planned within (:meth:`PayloadTiming._within_rating`)."""

_BRAKINGS: weakref.WeakKeyDictionary[TimeOptimalPlanner, dict[tuple, tuple[float, tuple, tuple]]] = (
    weakref.WeakKeyDictionary()
)
"""Per planner and carry shape: where carries brake and the rated laws' shares (:meth:`PayloadTiming._braking`)."""

_UNRATED_STARTS: weakref.WeakSet[TimeLaw] = weakref.WeakSet()
"""Start laws of online carries over the thermal rating (:meth:`PayloadTiming._start`)."""

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
