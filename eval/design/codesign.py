"""Motor and gearbox co-design: the catalogue drive that gives a design the most picks per minute.

For a geometry, every drive of :data:`delta_env.catalogue.CATALOGUE` (a motor behind a gear ratio) is scored
at the rated payload and the fastest is chosen; the light payload's rate is that drive's. A drive's pick rate
on the standard cycle and its check against the drive are :mod:`eval.design.drive_rate`; the drives are
scored by the cheap path (:mod:`eval.design.screening`), and an exact co-design plans the best
:data:`EXACT_CANDIDATES` screened drives with the full planner and keeps the fastest.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from delta_env.catalogue import CATALOGUE, DriveOption
from delta_env.config import RATED_PAYLOAD
from delta_env.geometry import DeltaGeometry, DeltaMasses
from delta_env.trajectories import WORKING_HEIGHT
from delta_env.validation import require_count, require_in
from eval.design.drive_rate import PickRate, planned_rate
from eval.design.model import require_belt_height
from eval.design.screening import scaled_rate, screen_drives, screened_rate

LIGHT_PAYLOAD = 0.1
"""The light payload (kg) of the design figures: the lightest payload of the pick-rate data sheet."""

EXACT_CANDIDATES = 3
"""Screened drives planned with the full planner by an exact co-design."""


@dataclass(frozen=True)
class DriveChoice:
    """The chosen drive of a design and its pick rates; ``rated`` is None when no drive runs the payload.

    Attributes:
        rated: The cycle at the rated payload on the chosen drive.
        light: The cycle at the light payload on the same drive.
        considered: Drives scored.
    """

    rated: PickRate | None
    light: PickRate | None
    considered: int

    @property
    def option(self) -> DriveOption | None:
        """The chosen drive."""
        return self.rated.option if self.rated else None

    @property
    def picks_per_min(self) -> float:
        """Picks per minute at the rated payload (0 without a drive)."""
        return self.rated.picks_per_min if self.rated else 0.0

    @property
    def picks_per_min_light(self) -> float:
        """Picks per minute at the light payload (0 without a drive)."""
        return self.light.picks_per_min if self.light else 0.0


def choose_drive(
    geometry: DeltaGeometry,
    masses: DeltaMasses | None = None,
    options: Sequence[DriveOption] = CATALOGUE,
    *,
    exact: bool = False,
    candidates: int = EXACT_CANDIDATES,
    payload: float = RATED_PAYLOAD,
    light_payload: float = LIGHT_PAYLOAD,
    belt_height: float = WORKING_HEIGHT,
) -> DriveChoice:
    """The drive among ``options`` that gives ``geometry`` the most picks per minute at ``payload`` (kg), and its rate
    at ``light_payload`` (kg), on the standard cycle centred on the axis on the belt at ``belt_height`` (m, base
    frame; the data-sheet placement at the default).

    A drive whose timed cycle breaks its peak torque, RMS torque or speed
    (:class:`eval.design.drive_rate.DriveCheck`, at every sample) is refused. The cheap path (``exact`` False)
    takes the best screened drive that holds; ``exact`` plans the ``candidates`` best screened drives with the full
    planner and keeps the fastest that holds. Ties go to the earlier option (the smaller motor, the lower ratio, in
    catalogue order).

    Raises:
        ValueError: on no options, a payload out of range, ``candidates`` < 1 or a belt height not below the base.
    """
    require_in("payload", payload, 0.0, unit="kg")
    require_in("light_payload", light_payload, 0.0, unit="kg")
    require_count("candidates", candidates)
    belt_height = require_belt_height(belt_height)
    if not options:
        raise ValueError("choose_drive needs at least one drive option")
    scored = screen_drives(geometry, options, payload, masses, keep=candidates if exact else 1, belt_height=belt_height)
    rates = np.nan_to_num(scored.rates, nan=0.0)
    order = [int(i) for i in np.argsort(-rates, kind="stable") if rates[i] > 0.0]
    rated = None
    if exact:
        planned = [_planned_or_none(geometry, options[i], payload, masses, belt_height) for i in order[:candidates]]
        held = [rate for rate in planned if rate is not None and rate.check.holds]
        rated = max(held, key=lambda rate: rate.picks_per_min, default=None)
    else:
        for index in order:
            rate = scaled_rate(geometry, options[index], payload, scored.laws[index], masses, belt_height)
            if rate.check.holds:
                rated = rate
                break
    if rated is None:
        return DriveChoice(None, None, len(options))
    if exact:
        light = _planned_or_none(geometry, rated.option, light_payload, masses, belt_height)
    else:
        light = screened_rate(geometry, rated.option, light_payload, masses, belt_height)
    return DriveChoice(rated, light, len(options))


def _planned_or_none(
    geometry: DeltaGeometry, option: DriveOption, payload: float, masses: DeltaMasses | None, belt_height: float
) -> PickRate | None:
    """:func:`eval.design.drive_rate.planned_rate`, or None if the planner finds no law within the drive."""
    try:
        return planned_rate(geometry, option, payload, masses, belt_height)
    except ValueError:
        return None
