"""``python -m eval.design``: the second paper's design study, verified in closed loop.

1. Figures of the nominal robot (workspace, torque on the 3.8 kg standard cycles, pick rate, speed).
2. NSGA-II over (ra, rb, l1, l2) (workspace, peak torque and pick rate) on ``--search-seeds`` seeds from
   ``--seed`` and a GA on the paper-style weighted cost on the first, in processes; every archive merged into one front
   (:mod:`eval.design.front`).
3. Designs chosen from the merged front (compromise, paper targets, low torque, large workspace, the weighted-cost
   optimum: each only where its figures bear the name out, each design named once),
   their drives by the full planner, and their tolerance and sensitivity (:mod:`eval.design.robustness`).
4. Reconfiguration by the pitch-screw linkage (:mod:`eval.design.mechanism`) for three task profiles, of the
   nominal robot and of the compromise design.
5. Closed-loop verification (unless ``--no-verify``): nominal and chosen designs on their own plants,
   identified, with PD, MId+F+R+RLS+PD and the oracle.
6. The run folder (``--out``, default ``<runs root>/design/<UTC time>``): ``config.json`` (the manifest of
   :mod:`eval.run_folder`: resolved configuration, command, status, times), ``pareto.csv``, ``designs.csv``,
   ``convergence.csv`` (per optimizer, seed and generation), ``robustness.csv``, ``reconfiguration.csv``,
   ``verification.csv``, ``torque_changes.csv``, ``summary.md``, the figures of :mod:`eval.design.report`,
   ``convergence.png``, ``robustness.png`` and the figures of :mod:`eval.design.profiles` (motion and torques
   over the nominal robot's worst cycle), ``explorer.html`` (:mod:`eval.design.explorer`: the interactive
   front) and a geometry file ``design-<name>.toml`` per chosen design (``--geometry`` of the other command
   lines, format of :mod:`delta_env.scenario`); the summary is printed.

Usage: python -m eval.design [--seed 0] [--search-seeds 3] [--population 40] [--generations 25]
                             [--screw-settings 21] [--mass-samples 24] [--quick] [--no-verify] [--out DIR]
                             [--runs-dir DIR]
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from delta_env import catalogue, collisions, cylinder, scaling, workspace
from delta_env.config import RATED_PAYLOAD, PlantRealism
from delta_env.geometry import NOMINAL_GEOMETRY
from delta_env.scaling import GRIPPER_MASS
from delta_env.scenario import save_geometry
from delta_env.trajectories import WORKING_HEIGHT
from eval import calibration
from eval.console import CommandParser, command_main, progress_bar
from eval.design import (
    codesign,
    drive_modes,
    drive_rate,
    explorer,
    front,
    mechanism,
    optimize,
    performance,
    profiles,
    reconfigure,
    report,
    robustness,
    stiffness,
    verify,
)
from eval.identification import excitation
from eval.identification import run as identification
from eval.run_folder import (
    Run,
    add_force_argument,
    add_runs_dir_argument,
    command_run_folder,
    configuration_record,
    package_versions,
    write_csv,
)
from eval.scenario_args import add_workers_argument, check_episode_seeds, check_ranges

QUICK = {
    "population": 12,
    "generations": 3,
    "search_seeds": 2,
    "episodes": 1,
    "verified_designs": 1,
    "screw_settings": 5,
    "mass_samples": 6,
}
"""Settings of ``--quick`` (tests and smoke runs)."""


@dataclasses.dataclass(frozen=True)
class DesignConfig:
    """The resolved configuration of a design study (``python -m eval.design``), recorded as it is in the run's
    manifest (``arguments``, beside the study's fixed settings: :func:`_resolved_config`).

    Attributes:
        seed: Seed of the optimizers' first search and of the episodes.
        search_seeds: Seeds of each optimizer, from ``seed``.
        population: Population of NSGA-II and the GA.
        generations: Generations of each optimizer.
        episodes: Verification episodes per controller.
        verified_designs: Chosen designs verified besides the nominal.
        screw_settings: Settings of the reconfiguration's grid over the screw stroke.
        mass_samples: Robots drawn by the mass sensitivity of each chosen design.
        quick: A small run (:data:`QUICK` where not given); pick rates by the optimizer's cheap path.
        no_verify: Skip the closed-loop verification.
        workers: Processes.
        out: ``--out``, or None.
        force: Write into an existing, non-empty ``out``.
        runs_dir: ``--runs-dir``, or None.
    """

    seed: int
    search_seeds: int
    population: int
    generations: int
    episodes: int
    verified_designs: int
    screw_settings: int
    mass_samples: int
    quick: bool
    no_verify: bool
    workers: int
    out: Path | None
    force: bool
    runs_dir: Path | None


def argument_parser() -> CommandParser:
    """The parser of the command line."""
    parser = CommandParser(
        prog="python -m eval.design", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--seed", type=int, default=0, help="seed of the optimizers and episodes (default 0)")
    parser.add_argument(
        "--search-seeds",
        type=int,
        default=front.SEARCH_SEEDS,
        help=f"seeds of each optimizer, from --seed (default {front.SEARCH_SEEDS})",
    )
    parser.add_argument("--population", type=int, default=40, help="population of NSGA-II and the GA (default 40)")
    parser.add_argument("--generations", type=int, default=25, help="generations of each optimizer (default 25)")
    parser.add_argument("--episodes", type=int, default=2, help="verification episodes per controller (default 2)")
    parser.add_argument(
        "--verified-designs", type=int, default=5, help="chosen designs verified besides the nominal (default 5)"
    )
    parser.add_argument(
        "--screw-settings",
        type=int,
        default=reconfigure.GRID_SETTINGS,
        help=f"settings of the reconfiguration's grid over the screw stroke (default {reconfigure.GRID_SETTINGS})",
    )
    parser.add_argument(
        "--mass-samples",
        type=int,
        default=robustness.MASS_SAMPLES,
        help=f"robots drawn by the mass sensitivity of each chosen design (default {robustness.MASS_SAMPLES})",
    )
    parser.add_argument(
        "--quick",
        action="store_true",
        help=f"a small run for tests: {QUICK}, unless given explicitly; pick rates by the optimizer's cheap path",
    )
    parser.add_argument("--no-verify", action="store_true", help="skip the closed-loop verification")
    add_workers_argument(
        parser,
        help="processes of the searches and of each design's identification, tare and episodes (default: up to 2)",
    )
    parser.add_argument("--out", type=Path, default=None, help="run folder (default <runs root>/design/<UTC time>)")
    add_force_argument(parser)
    add_runs_dir_argument(parser)
    return parser


def resolve(arguments: argparse.Namespace, parser: argparse.ArgumentParser) -> DesignConfig:
    """The configuration of the parsed command line ``arguments`` (left as they are): ``--quick``'s settings where
    not given; a value out of range is a parser error."""
    quick = {}
    if arguments.quick:  # only the settings left at their defaults: an explicit --population etc. wins over --quick
        quick = {key: value for key, value in QUICK.items() if getattr(arguments, key) == parser.get_default(key)}
    config = DesignConfig(**{**vars(arguments), **quick})
    minimums = {
        "seed": 0,
        "search_seeds": 1,
        "population": 4,
        "generations": 1,
        "episodes": 1,
        "verified_designs": 1,
        "workers": 1,
        "screw_settings": 3,
        "mass_samples": 2,
    }
    check_ranges(parser, config, minimums)
    check_episode_seeds(parser, config)
    return config


def parse_args(argv: Sequence[str] | None) -> DesignConfig:
    """The resolved configuration of the command line ``argv`` (None: ``sys.argv[1:]``); a bad value is a parser
    error."""
    parser = argument_parser()
    return resolve(parser.parse_args(argv), parser)


def _distinct(designs: dict[str, performance.Performance]) -> dict[str, performance.Performance]:
    """Designs with distinct geometries, the first name kept."""
    seen, kept = set(), {}
    for name, design in designs.items():
        if design.geometry not in seen:
            seen.add(design.geometry)
            kept[name] = design
    return kept


def _resolved_config(config: DesignConfig, fixed_ra: dict[str, float | None] | None = None) -> dict[str, object]:
    """The run's arguments and every setting of the study, for ``config.json``."""
    drive = PlantRealism()
    return {
        "arguments": configuration_record(config),
        "bounds": dataclasses.asdict(optimize.DEFAULT_BOUNDS),
        "criteria": dataclasses.asdict(workspace.DEXTEROUS),
        "task": {
            "payload_kg": performance.PAYLOAD,
            "cycle_acceleration_m_s2": performance.CYCLE_ACCELERATION,
            "band_m": performance.TASK_BAND,
            "radius_m": performance.TASK_RADIUS,
            "cycles": performance.TASK_CYCLES,
            "joint_speed_limit_rad_s": performance.JOINT_SPEED_LIMIT,
        },
        "scaling": {
            "rule": f"m1 ~ l1^{scaling.UPPER_ARM_MASS_EXPONENT}, m2 ~ l2^{scaling.FOREARM_MASS_EXPONENT} (links as "
            "stiff as the nominal ones), m0 = gripper + plate ~ rb^2",
            "gripper_kg": GRIPPER_MASS,
        },
        "drive": {
            "rule": "each design's own catalogue motor and planetary ratio (most picks/min at the rated payload), "
            "armature = rotor inertia x ratio^2; friction of the plant's nominal drive",
            "viscous_n_m_s_rad": drive.viscous,
            "coulomb_n_m": drive.coulomb,
            "motors": {name: dataclasses.asdict(motor) for name, motor in catalogue.MOTORS.items()},
            "gear_ratios": catalogue.GEAR_RATIOS,
            "stage_efficiency": catalogue.STAGE_EFFICIENCY,
            "light_payload_kg": codesign.LIGHT_PAYLOAD,
            "torque_share": drive_rate.TORQUE_SHARE,
        },
        "weights": optimize.WEIGHTS,
        "robustness": {
            "length_tolerance_m": robustness.LENGTH_TOLERANCE,
            "length_samples": robustness.LENGTH_SAMPLES,
            "mass_tolerance": robustness.MASS_TOLERANCE,
            "mass_samples": config.mass_samples,
        },
        "reconfiguration": {
            "linkage": {
                "screw_lead_m": mechanism.SCREW_LEAD,
                "thread_length_m": mechanism.THREAD_LENGTH,
                "nut_length_m": mechanism.NUT_LENGTH,
                "rocker_length_m": mechanism.ROCKER_LENGTH,
                "coupler_length_m": mechanism.COUPLER_LENGTH,
                "coupler_angle_rad": mechanism.COUPLER_ANGLE,
            },
            "grid_settings": config.screw_settings,
            "travel_tolerance_m": reconfigure.TRAVEL_TOLERANCE,
            "profiles": [dataclasses.asdict(p) for p in reconfigure.PROFILES],
            "fixed_ra_m": fixed_ra,  # None where no setting serves every profile (JSON has no NaN)
        },
        "verification": {
            "identification_trajectories": identification.DEFAULT_TRAJECTORIES,
            "identification_duration_s": excitation.DEFAULT_DURATION,
            "validation_duration_s": excitation.VALIDATION_DURATION,
            "calibration_episodes": calibration.DEFAULT_CALIBRATION_EPISODES,
            "episode_cycles": verify.EPISODE_CYCLES,
            "loop_gap_limit_m": verify.LOOP_GAP_LIMIT,
        },
        "pymoo_version": package_versions(("pymoo",))["pymoo"],
    }


@command_main("python -m eval.design")
def main(argv: Sequence[str] | None = None) -> int:
    started = time.perf_counter()
    config = parse_args(argv)
    with command_run_folder("design", "eval.design", argv, config, _resolved_config(config)) as run:
        study(config, run, started)
    return 0


def study(config: DesignConfig, run: Run, started: float) -> None:
    """The design study of ``config`` (:func:`parse_args`) into ``run``'s folder, its summary printed; ``started`` is
    the :func:`time.perf_counter` time at the start of the command."""
    out = run.folder
    seconds = {}

    nominal = performance.evaluate(NOMINAL_GEOMETRY)
    if not nominal.feasible:
        raise RuntimeError(f"the nominal robot does not meet the study's own constraints: {nominal.reason}")
    seeds = list(range(config.seed, config.seed + config.search_seeds))
    with progress_bar(len(seeds) + 1, "NSGA-II on every seed, the GA", "run") as bar:
        searches = front.search(
            nominal, config.population, config.generations, seeds, workers=config.workers, progress=bar
        )
    pareto = searches.result
    seconds["optimization"] = time.perf_counter() - started

    roles = optimize.design_roles(pareto, nominal)
    chosen = {name: pareto.archive.performance[i] for name, i in optimize.choose_designs(roles).items()}
    designs = {"nominal": nominal, **chosen}
    if not config.quick:  # the reported designs' drives by the full planner (the optimizer used the cheap path)
        designs = {n: performance.evaluate(p.geometry, masses=p.masses, exact_drive=True) for n, p in designs.items()}
    front_designs = [pareto.archive.performance[i] for i in pareto.front]
    sensitivity = {
        name: robustness.analyse(p, seed=config.seed, mass_samples=config.mass_samples)
        for name, p in _distinct(designs).items()
    }
    seconds["robustness"] = time.perf_counter() - started - seconds["optimization"]

    reachable = {name: workspace.reachable_volume_estimate(p.geometry, seed=config.seed) for name, p in designs.items()}
    region = performance.task_region_points()
    frequency = {  # lowest over the conveyors' region, rated payload (eval.design.stiffness: an upper bound)
        name: float(np.min(stiffness.first_natural_frequency(p.geometry, region, RATED_PAYLOAD, p.masses)))
        for name, p in designs.items()
    }
    mode_maps = {name: drive_modes.design_mode_map(p) for name, p in designs.items()}
    clearance = {  # over the cylinder's surface and the conveyors' region: the plant's links never touch there
        name: collisions.smallest_clearances(p.geometry, np.vstack((p.cylinder.surface_points(), region)))
        for name, p in designs.items()
    }
    reconfigured = {
        name: reconfigure.study(designs[name].geometry, grid_settings=config.screw_settings)
        for name in ("nominal", "compromise")
    }
    seconds["reconfiguration"] = time.perf_counter() - started - sum(seconds.values())

    verifications: list[verify.Verification] = []
    if not config.no_verify:
        verified = dict(list(_distinct(designs).items())[: 1 + config.verified_designs])
        for name, design in progress_bar(desc="closed-loop verification", unit="design", iterable=verified.items()):
            verifications.append(
                verify.verify_design(name, design, seed=config.seed, episodes=config.episodes, workers=config.workers)
            )
        seconds["verification"] = time.perf_counter() - started - sum(seconds.values())

    write_csv(out / "pareto.csv", [report.performance_row(p) for p in front_designs])
    write_csv(
        out / "designs.csv",
        [
            {
                "design": n,
                **report.performance_row(p),
                "reachable_volume_m3": reachable[n][0],
                "reachable_volume_error_m3": reachable[n][1],
                "first_natural_frequency_hz": frequency[n],
                **drive_modes.drive_mode_columns(mode_maps[n]),
                "arm_clearance_m": clearance[n][0],
                "base_clearance_m": clearance[n][1],
            }
            for n, p in designs.items()
        ],
    )
    write_csv(out / "convergence.csv", pareto.convergence)
    write_csv(out / "robustness.csv", robustness.rows(sensitivity))
    write_csv(
        out / "reconfiguration.csv",
        [
            {
                "design": name,
                "profile": o.profile.name,
                "objective": o.profile.objective,
                "travel_m": travel,
                "ra": ra,
                "motor_rise_m": float(study.linkage.height_offset(travel)),
                "value": value,
            }
            for name, study in reconfigured.items()
            for o, values in zip(study.outcomes, study.values, strict=True)
            for travel, ra, value in zip(study.travel, study.settings, values, strict=True)
        ],
    )
    if verifications:
        write_csv(out / "verification.csv", report.verification_rows(verifications))
        write_csv(
            out / "torque_changes.csv",
            [
                {
                    **dataclasses.asdict(change),
                    "model_ratio_holds": change.ratio_holds(change.model),
                    "model_change_holds": change.change_holds(change.model),
                    "identified_ratio_holds": change.ratio_holds(change.identified),
                    "identified_change_holds": change.change_holds(change.identified),
                }
                for change in report.torque_changes(verifications)
            ],
        )
    for name, design in designs.items():
        if name != "nominal":
            save_geometry(design.geometry, out / report.design_file_name(name), report.design_record(name, design))
    front.plot_convergence(searches, nominal, out / "convergence.png")
    robustness.plot(sensitivity, out / "robustness.png")
    report.plot_pareto(front_designs, nominal, {n: p for n, p in designs.items() if n != "nominal"}, out / "pareto.png")
    map_designs = {"nominal": NOMINAL_GEOMETRY, "compromise": chosen["compromise"].geometry}
    report.plot_maps(map_designs, "horizontal", out / "maps_horizontal.png")
    report.plot_maps(map_designs, "vertical", out / "maps_vertical.png")
    for name, study in reconfigured.items():
        suffix = "" if name == "nominal" else f"-{report.file_slug(name)}"
        report.plot_reconfiguration(study, out / f"reconfiguration{suffix}.png")
    # Figures 3-6 of the paper and the explorer page: every design on the nominal robot's worst task cycle
    profile_cycle = profiles.worst_cycle(nominal)
    profiles.plot_profiles({n: profiles.design_profile(p, profile_cycle) for n, p in _distinct(designs).items()}, out)
    explorer.write_explorer(front_designs, designs, out / "explorer.html", cycle=profile_cycle)
    seconds["total"] = time.perf_counter() - started

    lines = [
        f"# Design study: NSGA-II and GA, population {config.population}, {config.generations} generations, "
        f"seeds {seeds[0]}-{seeds[-1]}",
        "",
        "Objectives relative to the nominal robot. Reachable volume: Monte Carlo over the points with the motor "
        "range and ball-joint cone (no dexterity threshold), ± its standard error. Workspace: the data-sheet "
        "cylinder, the largest dexterous vertical cylinder (1/cond(J) >= "
        f"{workspace.DEXTEROUS_CONDITIONING}, motor range {workspace.THETA_RANGE} rad, ball-joint cone "
        f"{workspace.MAX_FOREARM_TILT:.3f} rad) standing on the belt and reaching "
        f"{cylinder.REQUIRED_TOP - WORKING_HEIGHT:.3f} m above it (the lift and the product clearance); both "
        "conveyor zones must be dexterous. Peak torque: the "
        f"{performance.PAYLOAD} kg 25/305/25 mm cycles at 3 g in five places of the conveyor region (rod-forearm "
        "model, masses scaled with the lengths, the same motors' friction on every design). Picks/min: the "
        "25/305/25 mm standard cycle at the centre, time-optimal within the design's own drive (the catalogue motor "
        "and planetary ratio that give it the most picks/min at the rated payload, its rotor inertia reflected), "
        "at the rated and a light payload (eval.design.codesign). "
        "Speed at 30 rad/s: the platform speed reachable in "
        "every direction over the conveyor region at that joint speed.",
        "",
        report.summary_table(designs, designs["nominal"], reachable),
        "",
        *([report.roles_sentence(roles), ""] if report.roles_sentence(roles) else []),
        report.clearance_sentence(clearance),
        "",
        "Every design chosen from the front of all runs merged (NSGA-II on every seed and the GA): none is "
        "dominated by any design evaluated (on the optimizer's figures; the table's pick rates are the full "
        "planner's). " + front.convergence_text(searches, nominal),
        "",
        f"## Tolerance and sensitivity: lengths ±{1e3 * robustness.LENGTH_TOLERANCE:.1f} mm, masses "
        f"±{100 * robustness.MASS_TOLERANCE:.0f} %",
        "",
        f"Position error: {robustness.LENGTH_SAMPLES} robots, each of the 12 lengths (ra, rb, l1, l2 of each chain) "
        "uniform in its band, commanded by the drawn lengths' inverse kinematics at points filling the workspace "
        f"cylinder. Masses: {config.mass_samples} robots, m1, m2, m0 each uniform in its band; last column: each "
        f"mass alone +{100 * robustness.MASS_TOLERANCE:.0f} %. Mean ± std [5 %, 95 %]:",
        "",
        robustness.table(sensitivity),
        "",
        "## First mode of the compliant drives over the task region",
        "",
        "Each design's drive behind the data-sheet gearhead (SP+ 140) scaled to its peak torque, at the damping "
        "ratio of the data sheet's drive (an assumption: eval.design.drive_modes); the two-mass model "
        "(docs/design.md section 4) on the design's links over the task disc at the band's two heights, empty and "
        f"at {RATED_PAYLOAD:g} kg. Stiffer is higher: what the servo and a shaped move must live with.",
        "",
        *drive_modes.drive_mode_table(designs, mode_maps),
        "",
    ]
    for name, study in reconfigured.items():
        stroke = study.linkage.stroke
        lines += [
            "",
            f"## Reconfiguration of the {name} design by its pitch screws: ra {study.settings[0]:.3f} to "
            f"{study.settings[-1]:.3f} m over the {1e3 * stroke:.0f} mm stroke ({study.linkage.turns:.0f} turns)",
            "",
            report.reconfiguration_table(study),
        ]
    if verifications:
        table, checks = report.verification_table(verifications)
        lines += [
            "",
            f"## Closed-loop verification: each design's own plant, {config.episodes} episode(s) of "
            f"{verify.EPISODE_CYCLES} standard cycles with {performance.PAYLOAD} kg per controller",
            "",
            table,
            "",
            "Torque change against nominal (plant: oracle controller, the torque the plant needs). The 5 % "
            "criterion read two ways: the ratio design / nominal within 5 % of the predicted ratio, and the "
            "change within 5 % of the predicted change's own size:",
            "",
            *checks,
        ]
    lines += ["", f"Run folder: {out} ({seconds['total']:.0f} s)"]
    summary = "\n".join(lines)
    (out / "summary.md").write_text(summary + "\n")

    fixed_ra = {n: s.fixed_ra if math.isfinite(s.fixed_ra) else None for n, s in reconfigured.items()}
    run.record(config=_resolved_config(config, fixed_ra), seconds=seconds)
    print(summary)


if __name__ == "__main__":
    sys.exit(main())
