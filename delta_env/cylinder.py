"""The data-sheet workspace of a Delta geometry: the largest admissible vertical cylinder above the belt.

A robot's data sheet states its working range as an axis-centred cylinder, diameter x height, in which
every point is admissible (:func:`delta_env.workspace.admissible` with the given
:class:`~delta_env.workspace.Criteria`: inverse kinematics, motor range, conditioning, ball-joint cone
and whatever else the criteria check). For a pick-and-place cell it stands on the conveyor surface
(``belt``): its bottom is the belt, so depth below the belt earns nothing and the robot reaches the belt
everywhere in it, and its top must reach ``lift + clearance`` above the belt, the lifted gripper plus room
for the product. It lies in the
admissible stretch of the axis through that top (:func:`largest_cylinder` is the same search for any
required top and floor).

The search (docs/design-study.md section 9):

- **Disc radius at a height** (:func:`disc_radii`): rings of :data:`RING_AZIMUTHS` points over the
  symmetry sector [0, pi/3], every :data:`RING_STEP` from the axis outward, until a ring has an
  inadmissible point; the first exit of each failing ray is then bracketed down to :data:`RADIUS_TOLERANCE`
  (eight sections a round), and the azimuth of the smallest exit refined by :data:`AZIMUTH_ROUNDS` rounds
  of rays at half the previous spacing either side. So the whole disc is checked, not only its rim: near the top of the
  workspace the admissible set is not star-shaped around the axis (rays leave it and enter it again).
- **Heights**: a grid of :data:`HEIGHT_STEP` over the axis stretch, the best (bottom, top) pair on it,
  then rounds that halve the grid intervals next to the limiting heights (the top, the bottom, the height
  of the smallest disc and any near-smallest local minimum), down to
  :data:`HEIGHT_TOLERANCE`.

The geometry is symmetric under rotations by 2 pi / 3 and the mirrors through the chains' planes, so the
sector [0, pi/3] holds every direction; criteria must keep that symmetry.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

from delta_env.cycles import STANDARD_LIFT
from delta_env.geometry import DeltaGeometry
from delta_env.trajectories import WORKING_HEIGHT
from delta_env.validation import require_count, require_in
from delta_env.workspace import DEXTEROUS, Criteria, admissible, admissible_constants, admissible_point, reach_bounds

PRODUCT_CLEARANCE = 0.075
"""Default room (m) the cylinder must have above the lifted gripper: a product up to 75 mm tall."""

REQUIRED_TOP = WORKING_HEIGHT + STANDARD_LIFT + PRODUCT_CLEARANCE
"""Default height (m) the data-sheet cylinder's top must reach: 100 mm above the belt."""

RING_STEP = 0.03
"""Spacing (m) of the rings checked from the axis outward; an inadmissible pocket inside the disc thinner
than this could go unseen."""

RING_AZIMUTHS = 7
"""Points per ring over the symmetry sector [0, pi/3] (every 10 deg)."""

RADIUS_TOLERANCE = 1e-4
"""Bisection tolerance (m) of a ray's exit radius and of the axis stretch's ends."""

AZIMUTH_ROUNDS = 2
"""Rounds refining the azimuth of the smallest exit by the rays halfway to its neighbours (10 deg -> 2.5 deg
between the tested rays); the exit radius is smooth there (most often a minimum on a mirror plane)."""

HEIGHT_STEP = 0.025
"""Spacing (m) of the first height grid."""

HEIGHT_TOLERANCE = 5e-4
"""Grid intervals next to a limiting height are halved until they are shorter than this (m)."""

NEAR_MINIMUM = 0.05
"""Local minima of the disc radius within this share of the cylinder's radius are refined too: a dip
between grid heights can hide a smaller disc."""

AXIS_STEP = 0.005
"""Spacing (m) of the axis samples that find the admissible stretch above the belt."""

_SECTOR = math.pi / 3.0
_SECTIONS = 8  # points per bracket and round of _boundary: three bits a call
_RING_BLOCK = 8  # rings per vectorized call: most discs fail within two or three blocks
_MAX_HEIGHT_ROUNDS = 10  # halving 25 mm reaches HEIGHT_TOLERANCE in six


@dataclass(frozen=True)
class Cylinder:
    """A vertical cylinder on the base z axis (m).

    Attributes:
        diameter: Diameter (m).
        height: Height (m).
        top: Height of its top face (m).
    """

    diameter: float
    height: float
    top: float

    @property
    def bottom(self) -> float:
        """Height of its bottom face (m)."""
        return self.top - self.height

    @property
    def volume(self) -> float:
        """Volume (m^3)."""
        return math.pi * self.diameter**2 / 4.0 * self.height

    def surface_points(self, azimuths: int = 36, levels: int = 5) -> NDArray[np.float64]:
        """Points (m) on its surface, ``(n, 3)``: the rim at ``levels`` heights from the bottom to the top, and
        rings at a third and two thirds of the radius and the centre on the two faces, ``azimuths`` per ring."""
        require_count("azimuths", azimuths)
        require_count("levels", levels, minimum=2)
        phi = np.linspace(0.0, 2.0 * math.pi, azimuths, endpoint=False)
        radius = self.diameter / 2.0
        rings = [(radius, z) for z in np.linspace(self.bottom, self.top, levels)]
        rings += [(share * radius, z) for share in (1.0 / 3.0, 2.0 / 3.0) for z in (self.bottom, self.top)]
        points = [np.column_stack((r * np.cos(phi), r * np.sin(phi), np.full(azimuths, z))) for r, z in rings]
        return np.vstack([*points, [[0.0, 0.0, self.bottom], [0.0, 0.0, self.top]]])


def _boundary(
    geometry: DeltaGeometry,
    criteria: Criteria,
    origin: NDArray[np.float64],
    direction: NDArray[np.float64],
    good: NDArray[np.float64],
    bad: NDArray[np.float64],
) -> NDArray[np.float64]:
    """First exit along lines origin + t direction between ``good`` (admissible) and ``bad`` (not).

    Vectorized over the leading axes of ``origin`` and ``direction`` (``(..., 3)``) and of ``good`` and
    ``bad`` (``(...)``). Each round tests :data:`_SECTIONS` - 1 points between the two and keeps the
    stretch before the first inadmissible one, so the first exit is found (not just any) down to pockets
    of a :data:`_SECTIONS`-th of the bracket; returns the admissible side, within
    :data:`RADIUS_TOLERANCE` of the exit. The rounds run in compiled code (:func:`_bisect_exits`).
    """
    good, bad = np.array(good, dtype=float), np.array(bad, dtype=float)
    shape = np.broadcast_shapes(good.shape, bad.shape, origin.shape[:-1], direction.shape[:-1])
    lines = [np.ascontiguousarray(np.broadcast_to(a, (*shape, 3)).reshape(-1, 3)) for a in (origin, direction)]
    ends = [np.broadcast_to(a, shape).reshape(-1).copy() for a in (good, bad)]
    return _bisect_exits(*lines, *ends, admissible_constants(geometry, criteria)).reshape(shape)


@numba.njit(cache=True)
def _bisect_exits(
    origin: NDArray[np.float64],
    direction: NDArray[np.float64],
    good: NDArray[np.float64],
    bad: NDArray[np.float64],
    constants: NDArray[np.float64],
) -> NDArray[np.float64]:
    """:func:`_boundary`'s rounds on lines ``(n, 3)`` and brackets ``(n,)`` (``good`` and ``bad`` updated in place
    and returned) with :func:`~delta_env.workspace.admissible_constants`: every bracket is divided again while any
    is longer than :data:`RADIUS_TOLERANCE`, as the batched rounds did."""
    fractions = np.arange(1, _SECTIONS + 1) / _SECTIONS  # the last one is ``bad`` itself
    theta, rows = np.empty(3), np.empty((3, 3))
    t = np.empty(_SECTIONS)
    while good.size > 0 and np.max(np.abs(bad - good)) > RADIUS_TOLERANCE:
        for line in range(good.size):
            first = _SECTIONS - 1
            for section in range(_SECTIONS):
                t[section] = good[line] + (bad[line] - good[line]) * fractions[section]
            for section in range(_SECTIONS - 1):
                x = origin[line, 0] + t[section] * direction[line, 0]
                y = origin[line, 1] + t[section] * direction[line, 1]
                z = origin[line, 2] + t[section] * direction[line, 2]
                if not admissible_point(x, y, z, constants, theta, rows):
                    first = section
                    break
            bad[line] = t[first]
            if first > 0:
                good[line] = t[first - 1]
    return good


def _axis_points(heights: NDArray[np.float64]) -> NDArray[np.float64]:
    return np.column_stack((np.zeros((heights.size, 2)), heights))


def _ray_directions(phi: NDArray[np.float64]) -> NDArray[np.float64]:
    return np.stack((np.cos(phi), np.sin(phi), np.zeros_like(phi)), axis=-1)


def disc_radii(geometry: DeltaGeometry, heights: ArrayLike, criteria: Criteria = DEXTEROUS) -> NDArray[np.float64]:
    """Radius (m) of the largest admissible axis-centred disc at each height (m), ``(K,)``.

    -inf where the axis point itself is not admissible (module docstring: rings, bisection of the first
    exits, azimuth refinement).
    """
    heights = np.asarray(heights, dtype=float).reshape(-1)
    if not np.all(np.isfinite(heights)):
        raise ValueError(f"heights must be finite (m), got {heights!r}")
    radii = np.full(heights.size, -np.inf)
    on_axis = np.flatnonzero(admissible(geometry, _axis_points(heights), criteria))
    if on_axis.size == 0:
        return radii
    z = heights[on_axis]
    reach = reach_bounds(geometry, criteria.theta_range)[0]
    rings = RING_STEP * np.arange(1, math.ceil(reach / RING_STEP) + 2)  # the last ring lies beyond the reach
    phi = np.linspace(0.0, _SECTOR, RING_AZIMUTHS)
    directions = _ray_directions(phi)
    first_bad = np.zeros(z.size, dtype=int)  # index of the first ring with an inadmissible point
    failing = np.zeros((z.size, RING_AZIMUTHS), dtype=bool)  # its inadmissible azimuths
    pending = np.arange(z.size)
    for start in range(0, rings.size, _RING_BLOCK):
        block = rings[start : start + _RING_BLOCK]
        points = block[None, :, None, None] * directions[None, None] + _axis_points(z[pending])[:, None, None]
        inside = admissible(geometry, points, criteria)  # (P, B, A)
        bad_ring = ~np.all(inside, axis=-1)
        hit = np.any(bad_ring, axis=-1)
        ring = np.argmax(bad_ring, axis=-1)[hit]
        first_bad[pending[hit]] = start + ring
        failing[pending[hit]] = ~inside[hit, ring]
        pending = pending[~hit]
        if pending.size == 0:
            break
    last_good = np.where(first_bad > 0, rings[np.maximum(first_bad - 1, 0)], 0.0)  # every ring up to it holds
    height_of, azimuth_of = np.nonzero(failing)
    exits = _boundary(
        geometry,
        criteria,
        _axis_points(z[height_of]),
        directions[azimuth_of],
        last_good[height_of],
        rings[first_bad[height_of]],
    )
    radius = np.full(z.size, np.inf)
    np.minimum.at(radius, height_of, exits)
    smallest = exits == radius[height_of]
    best_phi = np.empty(z.size)
    best_phi[height_of[smallest]] = phi[azimuth_of[smallest]]
    # an exit smallest on a mirror plane (0 or pi/3) is a local minimum there: the exit radius is even about it
    refine = np.flatnonzero((best_phi > 0.0) & (best_phi < _SECTOR))
    spacing, offsets = _SECTOR / (RING_AZIMUTHS - 1), np.array([-0.5, 0.5])
    for _ in range(AZIMUTH_ROUNDS if refine.size else 0):
        # rays between the best one and its neighbours, folded into the sector by the mirrors at 0 and pi/3
        candidates = _SECTOR - np.abs(_SECTOR - np.abs(best_phi[refine, None] + spacing * offsets))
        found = _boundary(
            geometry,
            criteria,
            _axis_points(z[refine])[:, None],
            _ray_directions(candidates),
            np.broadcast_to(last_good[refine, None], candidates.shape),
            np.broadcast_to(radius[refine, None], candidates.shape),
        )
        column = np.argmin(found, axis=1)
        smaller = found[np.arange(refine.size), column]
        better = smaller < radius[refine] - RADIUS_TOLERANCE
        radius[refine[better]] = smaller[better]
        best_phi[refine[better]] = candidates[np.flatnonzero(better), column[better]]
        spacing /= 2.0
    radii[on_axis] = radius
    return radii


def axis_stretch(
    geometry: DeltaGeometry, through: float, criteria: Criteria = DEXTEROUS, floor: float = -math.inf
) -> tuple[float, float] | None:
    """(bottom, top) in m of the admissible stretch of the z axis through height ``through`` (m), cut at
    ``floor`` (m); None if ``through`` is not admissible. Axis samples every :data:`AXIS_STEP`, the ends
    bisected."""
    through = require_in("through", through, unit="m")
    if math.isnan(floor):
        raise ValueError(f"floor must be a height (m) or -inf, got {floor!r}")
    _, z_min, z_max = reach_bounds(geometry, criteria.theta_range)
    low = max(floor, z_min)
    if not low <= through <= z_max:
        return None
    below, above = np.arange(through, low, -AXIS_STEP)[::-1], np.arange(through, z_max, AXIS_STEP)[1:]
    samples = np.concatenate(([low], below, above, [z_max]))
    inside = admissible(geometry, _axis_points(samples), criteria)
    index = below.size  # ``through``
    if not inside[index]:
        return None
    outside = np.flatnonzero(~inside)
    first = int(outside[outside < index].max(initial=-1)) + 1
    last = int(outside[outside > index].min(initial=samples.size)) - 1
    ends = np.array([samples[first], samples[last]])
    beyond = np.array([samples[first - 1] if first > 0 else ends[0], samples[min(last + 1, samples.size - 1)]])
    bottom, top = _boundary(geometry, criteria, np.zeros(3), np.array([0.0, 0.0, 1.0]), ends, beyond)
    return float(bottom), float(top)


def _best_pair(
    heights: NDArray[np.float64], radii: NDArray[np.float64], required_top: float, standing: bool
) -> tuple[int, int, float] | None:
    """(bottom index, top index, radius) of the largest cylinder on the grid whose top reaches
    ``required_top`` (whose bottom is the grid's first height if ``standing``); None if none has a volume."""
    count = heights.size
    below = np.tril(np.ones((count, count), dtype=bool), -1)
    running = np.minimum.accumulate(np.where(below, np.inf, np.maximum(radii, 0.0)), axis=1)
    volume = math.pi * running**2 * (heights[None, :] - heights[:, None])
    volume[below | (heights[None, :] < required_top - 1e-12)] = 0.0
    if standing:
        volume[1:] = 0.0
    bottom, top = np.unravel_index(int(np.argmax(volume)), volume.shape)
    if volume[bottom, top] <= 0.0:
        return None
    return int(bottom), int(top), float(running[bottom, top])


def _refinement(heights: NDArray[np.float64], radii: NDArray[np.float64], pair: tuple[int, int, float]) -> list[float]:
    """New heights (m): midpoints of the grid intervals next to the limiting heights of ``pair``."""
    bottom, top, radius = pair
    span = np.maximum(radii[bottom : top + 1], 0.0)
    limiting = bottom + int(np.argmin(span))
    intervals = {(bottom - 1, bottom), (top - 1, top), (top, top + 1)}
    intervals |= {(limiting - 1, limiting), (limiting, limiting + 1)}
    for node in range(bottom + 1, top):  # near-smallest local minima: a dip between grid heights
        neighbours = (radii[node - 1], radii[node + 1])
        # a minimum below at least one neighbour: on a plateau (a constraint that does not depend on the height, such
        # as the parallelogram skew's prism) every node would tie with its neighbours and the grid double each round
        dip = min(neighbours) >= radii[node] and max(neighbours) > radii[node]
        if dip and radii[node] <= (1.0 + NEAR_MINIMUM) * radius:
            intervals |= {(node - 1, node), (node, node + 1)}
    new: list[float] = []
    for low, high in intervals:
        if low >= 0 and high < heights.size and heights[high] - heights[low] > HEIGHT_TOLERANCE:
            new.append(float(heights[low] + heights[high]) / 2.0)
    return new


def largest_cylinder(
    geometry: DeltaGeometry,
    criteria: Criteria = DEXTEROUS,
    *,
    required_top: float,
    floor: float = -math.inf,
    standing: bool = False,
) -> Cylinder | None:
    """The largest-volume admissible vertical cylinder on the z axis whose top reaches ``required_top`` (m)
    and whose bottom stays at or above ``floor`` (m), at ``floor`` if ``standing``, in the axis stretch
    through ``required_top`` (module docstring: disc radii on a height grid refined at the limiting
    heights); None if that axis point is not admissible, or if ``standing`` and the stretch does not reach
    down to ``floor``."""
    stretch = axis_stretch(geometry, required_top, criteria, floor)
    if stretch is None or (standing and stretch[0] > floor):
        return None
    bottom, top = stretch
    heights = np.union1d(np.arange(bottom, top, HEIGHT_STEP), [required_top, top])
    radii = disc_radii(geometry, heights, criteria)
    pair = _best_pair(heights, radii, required_top, standing)
    for _ in range(_MAX_HEIGHT_ROUNDS):
        if pair is None:
            return None
        new = _refinement(heights, radii, pair)
        if not new:
            break
        order = np.argsort(np.concatenate((heights, new)), kind="stable")
        heights = np.concatenate((heights, new))[order]
        radii = np.concatenate((radii, disc_radii(geometry, new, criteria)))[order]
        pair = _best_pair(heights, radii, required_top, standing)
    if pair is None:
        return None
    low, high, radius = pair
    return Cylinder(diameter=2.0 * radius, height=float(heights[high] - heights[low]), top=float(heights[high]))


def data_sheet_cylinder(
    geometry: DeltaGeometry,
    criteria: Criteria = DEXTEROUS,
    *,
    belt: float = WORKING_HEIGHT,
    lift: float = STANDARD_LIFT,
    clearance: float = PRODUCT_CLEARANCE,
) -> Cylinder | None:
    """The data-sheet workspace: the largest admissible vertical cylinder on the z axis standing on the belt
    whose top reaches ``belt + lift + clearance`` (module docstring).

    Args:
        geometry: Robot geometry.
        criteria: What makes a point admissible.
        belt: Height of the conveyor surface (m): the cylinder's bottom.
        lift: Lift of the gripper above the belt (m), >= 0.
        clearance: Room the cylinder must have above the lift (m), >= 0.

    Returns:
        The cylinder, or None when the axis is not admissible from the belt up to the required top.
    """
    belt = require_in("belt", belt, unit="m")
    required_top = belt + require_in("lift", lift, 0.0, unit="m") + require_in("clearance", clearance, 0.0, unit="m")
    return largest_cylinder(geometry, criteria, required_top=required_top, floor=belt, standing=True)
