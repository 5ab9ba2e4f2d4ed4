"""Published pick rates of an industrial Delta robot, set beside the simulated data sheet (:mod:`eval.rate.__main__`).

The one home of these figures: ABB's IRB 360 FlexPicker, product specification 3HAC079010-001, "Cycle 1" (the
25/305/25 mm standard cycle: 25 mm up, 305 mm across, 25 mm down and back, with 35 ms of air activation at each
end). The robots differ from ours in ways the table cannot show (see :data:`DIFFERENCES`).
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["ABB_IRB_360", "DIFFERENCES", "PublishedRate", "PublishedSheet"]


@dataclass(frozen=True)
class PublishedRate:
    """One row of a maker's data sheet.

    Attributes:
        robot: The robot's type designation (``"IRB 360-8/1130"``: rated payload 8 kg, 1130 mm reach).
        payload: Payload (kg).
        picks_per_min: Picks per minute on the sheet's cycle.
    """

    robot: str
    payload: float
    picks_per_min: float


@dataclass(frozen=True)
class PublishedSheet:
    """A maker's pick rates on a standard cycle.

    Attributes:
        maker: The robot maker.
        source: The document the figures come from.
        cycle: The document's name for the cycle.
        lift: Height of the cycle's lift and of its set-down (m).
        travel: Horizontal distance between pick and place (m).
        air_activation: Time the gripper's air takes to grip or release at each end of the cycle (s).
        repeatability: Position repeatability of the robots (m; ISO 9283 RP, the spread of repeated positioning).
        rows: The published rows.
    """

    maker: str
    source: str
    cycle: str
    lift: float
    travel: float
    air_activation: float
    repeatability: float
    rows: tuple[PublishedRate, ...]

    @property
    def robots(self) -> tuple[str, ...]:
        """The robots of :attr:`rows`, in first-seen order."""
        return tuple(dict.fromkeys(row.robot for row in self.rows))


ABB_IRB_360 = PublishedSheet(
    maker="ABB",
    source="ABB IRB 360 product specification 3HAC079010-001",
    cycle="Cycle 1",
    lift=0.025,
    travel=0.305,
    air_activation=0.035,
    repeatability=0.1e-3,
    rows=(
        PublishedRate("IRB 360-3/1130", 0.1, 150.0),
        PublishedRate("IRB 360-8/1130", 1.0, 160.0),
        PublishedRate("IRB 360-8/1130", 4.0, 140.0),
        PublishedRate("IRB 360-8/1130", 8.0, 100.0),
    ),
)
"""ABB's IRB 360 on Cycle 1, as its product specification publishes them."""

DIFFERENCES = (
    "ABB's robots turn the object 90 degrees about a fourth axis during Cycle 1; ours is a 3-DOF Delta that only "
    "translates",
    "our drive and geometry are a representative servo drive and arm lengths (the scenario's), not ABB's",
    "ABB states repeatability (ISO 9283: the spread of repeated positioning); we score the place error at release "
    "(the distance from the place point when the gripper opens, in simulation), which also counts any bias",
)
"""What differs between :data:`ABB_IRB_360` and the simulated data sheet, one clause each."""
