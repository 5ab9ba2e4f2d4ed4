"""The tare of a payload estimator: what payload-free pick cycles tell it (docs/design.md section 6)."""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import NamedTuple

import numpy as np

from controllers.base import Observation
from controllers.payload.equation import PARAMETERS
from controllers.payload.estimator import PayloadEstimator
from controllers.payload.fit import EmptyMoveSums


class Tare(NamedTuple):
    """What payload-free pick cycles tell a payload estimator (:func:`tare_from_observations`).

    Attributes:
        mass: Apparent payload of the empty gripper on carries (kg), the tare.
        spread: Standard deviation of the same estimate carry by carry (kg); NaN from one carry.
        empty_moves: The sums of the cycles' empty moves (:class:`EmptyMoveSums`).
    """

    mass: float
    spread: float
    empty_moves: EmptyMoveSums


def tare_from_observations(estimator: PayloadEstimator, episodes: Iterable[Iterable[Observation]]) -> Tare:
    """The apparent payload of an empty gripper (kg): weighted least squares over payload-free carries.

    Taring, as on a scale: pick cycles are run with nothing to pick (the gripper still closes and opens,
    mp = 0 is known), and the mass that the model needs along phi over the carry phases, beyond what the
    estimator fits on the empty moves of the same episode (:class:`ModelCorrections`), is its error there.
    The estimate is the weighted least squares of the RLS without forgetting or prior, over all carries at once.

    Only the carries that follow an empty move count, if there are any: before the first, nothing is fitted, and
    the apparent payload of a first carry also holds the calibration plant's own mass and friction errors (on a
    randomized plant, tens of grams that the next plant does not share). Episodes that start at their pick point
    with one cycle have no such carry; their first carries are used then.

    Args:
        estimator: Gives the payload equations, with the corrections it fits on each episode's empty moves
            removed (its tare does not enter them); reset here before each episode.
        episodes: Observation sequences of payload-free pick-and-place episodes.

    Returns:
        The tare (kg), the standard deviation (kg) of the same estimate carry by carry (the model error along phi
        changes with the path, so this, not the torque noise, is its uncertainty) and the sums of the episodes'
        empty moves, which the estimator fitted (:class:`Tare`).
    """
    # (sum of phi.y, sum of phi.phi) over one carry, weighted, and whether an empty move was fitted before it; a
    # carry runs from a closing of the gripper to the next (moments are also None while every joint rests, which
    # does not end a carry).
    carries: list[tuple[float, float, bool]] = []
    if estimator.fit.seed is not None:
        raise ValueError("taring needs an estimator without seeded empty moves: it sums the episodes' own")
    empty_information, empty_moment = np.zeros((PARAMETERS, PARAMETERS)), np.zeros(PARAMETERS)
    for episode in episodes:
        estimator.reset()
        holding = False
        for observation in episode:
            closed = observation["gripper"].item(0) > 0.5
            if closed and not holding:
                carries.append((0.0, 0.0, estimator.empty_move_samples > 0))
            holding = closed
            moments = estimator.measurement(observation)
            if moments is None:
                continue
            information, moment = moments
            carry_moment, carry_information, corrected = carries[-1]
            carries[-1] = (carry_moment + moment, carry_information + information, corrected)
        sums = estimator.empty_move_sums
        empty_information += sums.information
        empty_moment += sums.moment
    carries = [carry for carry in carries if carry[1] > 0.0]
    if not carries:
        raise ValueError("no carry phase in the calibration episodes: the gripper never closed while moving")
    if estimator.fits_corrections and any(corrected for *_, corrected in carries):
        carries = [carry for carry in carries if carry[2]]
    moments, informations, _ = np.array(carries).T
    per_carry = moments / informations
    spread = float(np.std(per_carry, ddof=1)) if len(carries) > 1 else math.nan
    return Tare(float(moments.sum() / informations.sum()), spread, EmptyMoveSums(empty_information, empty_moment))
