"""Tolerance and sensitivity of a design: how far its figures move when the built robot is not the drawn one.

- **Length tolerances -> position error.** Each chain's base radius, platform radius, upper arm and forearm is
  made to within +-:data:`LENGTH_TOLERANCE` (12 independent errors, uniform in the band, a Monte Carlo of
  :data:`LENGTH_SAMPLES` robots). The controller keeps the drawn (nominal) lengths: to reach a point p it sets
  the motors to the nominal inverse kinematics theta(p), and the built robot's platform goes to the forward
  kinematics of its true lengths at theta, the lower intersection of three spheres of radius l2_i about the
  elbows J'_i = (ra_i - rb_i + l1_i cos theta_i) u_i - l1_i sin theta_i z. The position error is the distance
  between the two, at points filling the design's workspace cylinder (:func:`cylinder_points`); per robot its
  RMS and its maximum over the points.
- **Masses -> torque and speed.** Arm, forearm and platform masses each off by a factor uniform in
  1 +- :data:`MASS_TOLERANCE` (:data:`MASS_SAMPLES` robots), the design re-evaluated
  (:func:`eval.design.performance.evaluate`): peak torque and :data:`SPEED_FIGURE`; and each mass alone at
  +:data:`MASS_TOLERANCE`, the one-at-a-time sensitivity.

Every figure is reported as its nominal value, mean, standard deviation, 5 and 95 % quantiles and extremes over
the samples (:class:`Spread`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from numpy.typing import NDArray

from delta_env import kinematics
from delta_env.cylinder import Cylinder
from delta_env.geometry import CHAIN_COS, CHAIN_SIN, DeltaGeometry, DeltaMasses
from delta_env.validation import require_count, require_in
from eval.design.performance import Performance, evaluate
from eval.metrics import markdown_table

LENGTH_TOLERANCE = 1e-4
"""Manufacturing tolerance (m) of every length of every chain: +-0.1 mm, a machined part's general tolerance."""

LENGTH_SAMPLES = 400
"""Robots of the length Monte Carlo: its means within 2 % and 95 % quantiles within 5 % of their limit (one
standard deviation over seeds; docs/measurements.md)."""

MASS_TOLERANCE = 0.10
"""Relative uncertainty of each mass (m1, m2, m0): +-10 %."""

MASS_SAMPLES = 24
"""Robots of the mass Monte Carlo, each a full evaluation of the design: enough for mean and spread, while its
5-95 % range is only indicative (the 2nd and 23rd of 24 samples)."""

SPEED_FIGURE = ("picks_per_min", "picks/min at the rated payload", "1/min")
"""The speed objective whose sensitivity is reported: the :class:`~eval.design.performance.Performance` field,
its label and its unit (the one place to change when the study's speed objective changes)."""

LENGTH_NAMES = ("ra", "rb", "l1", "l2")
"""Order of the lengths in an error array ``(..., 4, 3 chains)``."""

MASS_NAMES = ("m1", "m2", "m0")
"""Order of the masses in a factor array ``(..., 3)``."""

_CHAIN_DIRECTIONS = np.stack((CHAIN_COS, CHAIN_SIN, (0.0, 0.0, 0.0)), axis=-1)  # u_i, (3 chains, 3 xyz)


@dataclass(frozen=True)
class Spread:
    """A figure over Monte Carlo samples: its nominal value and the samples' statistics (same unit)."""

    nominal: float
    mean: float
    std: float
    p5: float
    p95: float
    low: float
    high: float

    @classmethod
    def of(cls, nominal: float, samples: NDArray[np.float64]) -> Spread:
        """The statistics of ``samples`` (any shape) beside ``nominal``."""
        p5, p95 = np.percentile(samples, (5.0, 95.0))
        return cls(
            nominal,
            float(np.mean(samples)),
            float(np.std(samples)),
            float(p5),
            float(p95),
            float(np.min(samples)),
            float(np.max(samples)),
        )


def sphere_intersection(centres: NDArray[np.float64], radii: NDArray[np.float64]) -> NDArray[np.float64]:
    """The lower intersection (m) of three spheres: ``centres`` ``(..., 3 spheres, 3 xyz)``, ``radii`` ``(..., 3)``.

    Trilateration in the frame of the centres; of its two points the one below their plane (the plane's normal
    turned down), the forward kinematics' branch (:func:`delta_env.kinematics.forward`).

    Raises:
        ValueError: if some three spheres have no common point.
    """
    first, second, third = centres[..., 0, :], centres[..., 1, :], centres[..., 2, :]
    r1, r2, r3 = radii[..., 0], radii[..., 1], radii[..., 2]
    d = np.linalg.norm(second - first, axis=-1)
    ex = (second - first) / d[..., None]
    i = np.sum(ex * (third - first), axis=-1)
    across = third - first - i[..., None] * ex
    j = np.linalg.norm(across, axis=-1)
    ey = across / j[..., None]
    ez = np.cross(ex, ey)
    down = np.where(ez[..., 2:3] > 0.0, -ez, ez)
    x = (r1**2 - r2**2 + d**2) / (2.0 * d)
    y = (r1**2 - r3**2 + i**2 + j**2) / (2.0 * j) - i * x / j
    height_sq = r1**2 - x**2 - y**2
    if np.any(height_sq < 0.0):
        raise ValueError(f"three spheres have no common point (depth^2 down to {height_sq.min():.3g} m^2)")
    return first + x[..., None] * ex + y[..., None] * ey + np.sqrt(height_sq)[..., None] * down


def built_positions(geometry: DeltaGeometry, errors: NDArray[np.float64], theta: NDArray[np.float64]) -> NDArray:
    """Platform positions (m) of robots built with length ``errors`` at motor angles ``theta``.

    Args:
        geometry: The drawn lengths (m).
        errors: Each robot's errors (m) of ``ra, rb, l1, l2`` (:data:`LENGTH_NAMES`) per chain, ``(n, 4, 3)``.
        theta: Motor angles (rad), ``(m, 3)``.

    Returns:
        ``(n, m, 3)``.
    """
    ra, rb, l1, l2 = (np.array(getattr(geometry, name)) + errors[:, k, None, :] for k, name in enumerate(LENGTH_NAMES))
    radial = ra - rb + l1 * np.cos(theta)  # (n, m, 3 chains)
    centres = radial[..., None] * _CHAIN_DIRECTIONS
    centres[..., 2] = -l1 * np.sin(theta)
    return sphere_intersection(centres, np.broadcast_to(l2, radial.shape))


def position_errors(geometry: DeltaGeometry, points: NDArray[np.float64], errors: NDArray[np.float64]) -> NDArray:
    """Distance (m) from each of ``points`` ``(m, 3)`` to where each robot built with ``errors`` ``(n, 4, 3)`` goes
    when commanded there with the drawn lengths' inverse kinematics, ``(n, m)``."""
    theta = kinematics.inverse(geometry, points)
    return np.linalg.norm(built_positions(geometry, errors, theta) - points, axis=-1)


def cylinder_points(cylinder: Cylinder, rings: int = 4, azimuths: int = 12, heights: int = 3) -> NDArray:
    """Points (m) filling ``cylinder``: its axis and ``rings`` rings out to its rim of ``azimuths`` points, at
    ``heights`` heights from its bottom to its top, ``(n, 3)``."""
    radius = cylinder.diameter / 2.0
    phi = np.linspace(0.0, 2.0 * math.pi, azimuths, endpoint=False)
    disc = [(0.0, 0.0)] + [
        (r * math.cos(p), r * math.sin(p)) for r in np.linspace(0, radius, rings + 1)[1:] for p in phi
    ]
    return np.array([(x, y, z) for z in np.linspace(cylinder.bottom, cylinder.top, heights) for x, y in disc])


def length_errors(tolerance: float, samples: int, rng: np.random.Generator) -> NDArray[np.float64]:
    """``samples`` robots' length errors (m), each uniform in +-``tolerance``, ``(samples, 4, 3)``."""
    return rng.uniform(-tolerance, tolerance, size=(samples, len(LENGTH_NAMES), 3))


@dataclass(frozen=True)
class Robustness:
    """One design's tolerance and sensitivity figures.

    Attributes:
        rms_error: RMS position error over the workspace points per robot (m).
        max_error: Largest position error over the points per robot (m).
        peak_torque: Peak torque over the mass samples (N m).
        speed: :data:`SPEED_FIGURE` over the mass samples.
        torque_change: Relative change of the peak torque with each mass alone at +:data:`MASS_TOLERANCE`, by name.
        speed_change: The same for the speed figure.
    """

    rms_error: Spread
    max_error: Spread
    peak_torque: Spread
    speed: Spread
    torque_change: dict[str, float]
    speed_change: dict[str, float]


def speed_figure(performance: Performance) -> float:
    """The design's :data:`SPEED_FIGURE`."""
    return float(getattr(performance, SPEED_FIGURE[0]))


def with_masses(performance: Performance, factors: Sequence[float]) -> Performance:
    """The design re-evaluated with its masses m1, m2, m0 multiplied by ``factors``, on its own drive, its pick
    rate by the optimizer's cheap path (the full planner for each of a design's 27 variants took minutes)."""
    m = performance.masses
    masses = DeltaMasses(*(getattr(m, name) * float(f) for name, f in zip(MASS_NAMES, factors, strict=True)))
    drive = performance.drive
    drives = None if drive is None or drive.option is None else (drive.option,)
    return evaluate(performance.geometry, masses=masses, drives=drives)


def analyse(
    performance: Performance,
    *,
    seed: int = 0,
    length_tolerance: float = LENGTH_TOLERANCE,
    length_samples: int = LENGTH_SAMPLES,
    mass_tolerance: float = MASS_TOLERANCE,
    mass_samples: int = MASS_SAMPLES,
) -> Robustness:
    """The tolerance and sensitivity figures of a design with a workspace cylinder (module docstring).

    Raises:
        ValueError: for a design without a cylinder, a tolerance outside [0, 1 mm] or [0, 50 %], or < 1 sample.
    """
    require_in("length_tolerance", length_tolerance, 0.0, 1e-3, unit="m")
    require_in("mass_tolerance", mass_tolerance, 0.0, 0.5)
    require_count("length_samples", length_samples)
    require_count("mass_samples", mass_samples)
    if performance.cylinder is None:
        raise ValueError(f"design {performance.geometry} has no workspace cylinder to measure position errors in")
    rng = np.random.default_rng(seed)
    errors = position_errors(
        performance.geometry,
        cylinder_points(performance.cylinder),
        length_errors(length_tolerance, length_samples, rng),
    )
    factors = rng.uniform(1.0 - mass_tolerance, 1.0 + mass_tolerance, size=(mass_samples, len(MASS_NAMES)))
    varied = [with_masses(performance, f) for f in factors]
    alone = {
        name: with_masses(performance, 1.0 + mass_tolerance * (np.arange(len(MASS_NAMES)) == k))
        for k, name in enumerate(MASS_NAMES)
    }
    reference = with_masses(performance, np.ones(len(MASS_NAMES)))  # the speed figure by the variants' method
    torque, speed = reference.peak_torque_nm, speed_figure(reference)
    return Robustness(
        rms_error=Spread.of(0.0, np.sqrt(np.mean(errors**2, axis=1))),
        max_error=Spread.of(0.0, np.max(errors, axis=1)),
        peak_torque=Spread.of(torque, np.array([p.peak_torque_nm for p in varied])),
        speed=Spread.of(speed, np.array([speed_figure(p) for p in varied])),
        torque_change={name: p.peak_torque_nm / torque - 1.0 for name, p in alone.items()},
        speed_change={name: speed_figure(p) / speed - 1.0 for name, p in alone.items()},
    )


FIGURES = (
    ("rms_error", "position error RMS", "mm", 1e3),
    ("max_error", "position error max", "mm", 1e3),
    ("peak_torque", "peak torque", "N m", 1.0),
    ("speed", SPEED_FIGURE[1], SPEED_FIGURE[2], 1.0),
)
"""(attribute of :class:`Robustness`, label, unit, scale from SI) of each reported figure."""


def rows(results: Mapping[str, Robustness]) -> list[dict[str, Any]]:
    """CSV rows: one per design and figure, its spread and, for the mass figures, its relative change with each
    mass alone +:data:`MASS_TOLERANCE` (``change_with_<mass>_up``)."""
    table = []
    for design, result in results.items():
        for attribute, label, unit, scale in FIGURES:
            spread: Spread = getattr(result, attribute)
            row = {"design": design, "figure": label, "unit": unit}
            row.update({key: scale * value for key, value in vars(spread).items()})
            changes = {"peak_torque": result.torque_change, "speed": result.speed_change}.get(attribute, {})
            row.update({f"change_with_{name}_up": v for name, v in changes.items()})
            table.append(row)
    return table


def table(results: Mapping[str, Robustness]) -> str:
    """Markdown table of the summary: mean ± std and the 5-95 % range of each figure, by design."""
    step = f"+{100 * MASS_TOLERANCE:.0f} %"
    header = ["Design", *(f"{label} ({unit})" for _, label, unit, _ in FIGURES), f"peak torque, m1, m2, m0 {step}"]
    body = []
    for design, result in results.items():
        cells = []
        for attribute, _, _, scale in FIGURES:
            s: Spread = getattr(result, attribute)
            cells.append(f"{scale * s.mean:.4g} ± {scale * s.std:.2g} [{scale * s.p5:.4g}, {scale * s.p95:.4g}]")
        changes = ", ".join(f"{100 * result.torque_change[name]:+.1f} %" for name in MASS_NAMES)
        body.append([design, *cells, changes])
    return markdown_table(header, body)


def plot(results: Mapping[str, Robustness], path: Path) -> None:
    """Each figure by design: nominal (star), mean ± std (thick) and the 5-95 % range (thin)."""
    figure, axes = plt.subplots(1, len(FIGURES), figsize=(4 * len(FIGURES), 4.2))
    names = list(results)
    positions = np.arange(len(names))
    for axis, (attribute, label, unit, scale) in zip(axes, FIGURES, strict=True):
        spreads = [getattr(results[n], attribute) for n in names]
        mean = scale * np.array([s.mean for s in spreads])
        axis.errorbar(positions, mean, yerr=scale * np.array([s.std for s in spreads]), fmt="o", lw=3, capsize=0)
        low = mean - scale * np.array([s.p5 for s in spreads])
        high = scale * np.array([s.p95 for s in spreads]) - mean
        axis.errorbar(positions, mean, yerr=(low, high), fmt="none", lw=1, capsize=4, color="k")
        if attribute not in ("rms_error", "max_error"):
            axis.plot(positions, scale * np.array([s.nominal for s in spreads]), "*", color="red", ms=9)
        axis.set_xticks(positions, names, rotation=30, ha="right", fontsize=8)
        axis.set(ylabel=f"{label} ({unit})")
        axis.grid(alpha=0.3)
    figure.suptitle(
        f"Lengths ±{1e3 * LENGTH_TOLERANCE:.1f} mm -> position error; masses ±{100 * MASS_TOLERANCE:.0f} % -> "
        "torque and speed (mean ± std, 5-95 %; star: as designed)"
    )
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)
