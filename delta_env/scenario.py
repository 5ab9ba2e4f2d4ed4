"""Scenarios: one value that says everything about the robot and the work it does.

A :class:`Scenario` has three parts:

- ``plant``: the robot, a :class:`~delta_env.config.PlantConfig` (geometry, true masses, drive effects and
  sensors). Its content hash is the robot's identity (:attr:`Scenario.robot_identity`).
- ``condition``: how the drive differs today from the robot as identified (wear: more friction, a slower
  current loop). A condition changes the physics the episode runs on, not which robot it is.
- ``task``: the work (:class:`PickPlaceTask`): cycle kind, where it starts, cycles per episode, peak acceleration,
  payload range and per-episode domain randomization.

Identity rule. ``robot_identity`` hashes the ``plant`` part only. Conditions (wear), payloads and domain
randomization are left out, so ``worn``, ``heavy`` and ``randomized`` are the nominal robot under other
conditions and reuse its identification, as a real cell is identified once and then runs under changing
conditions. A new geometry, new true masses or new drive or sensor hardware is a new robot. The drive's limits
(``plant.drive``) came later than the identities: they enter the hashes only when they differ from the default
drive, so that the robots that existed before (their cached identifications and the shipped residual policy)
keep their identities, while a robot with another drive gets a new one. Likewise a task's timing fields enter the
content hash only when its moves are planned (``task.timing`` not ``"fixed"``).

Files are TOML: human-readable with comments, a standard-library reader (``tomllib``, Python >= 3.11), no
implicit typing surprises (YAML reads ``no`` as False and ``1e-3`` as a string), and nested tables map one
to one onto the nested dataclasses. A file may give any subset of the fields; the others take the defaults
of the dataclasses, which are today's default environment. TOML has no null: optional fields take the
string ``"none"``. Unknown keys are errors, so a typo never falls back to a default silently.

Faults (:class:`~delta_env.faults.FaultSpec`, drawn per episode; ``task.faults`` enters the content hash only when
it is not empty) are an array of tables; each gives a kind and any of its ranges, the rest take the kind's
defaults::

    [[task.faults]]
    kind = "collision"
    probability = 0.5              # half of the episodes
    target = "arm"                 # on an upper arm at its elbow
    size = [200.0, 800.0]          # N
    carry_fraction = [0.3, 0.7]    # of a random carry (or: start = [1.0, 2.0], s from the reset)

    [[task.faults]]
    kind = "encoder_glitch"
    joint = 2

Named presets ship as package data next to this module (``delta_env/scenarios/<name>.toml``).

Geometry files (``--geometry FILE`` of the command lines, written by the design study) are TOML with one
table of the four lengths in metres; other top-level tables (e.g. the design's objectives) are ignored::

    [geometry]
    ra = 0.20   # base radius (m)
    rb = 0.05   # platform radius (m)
    l1 = 0.37   # upper arm (m)
    l2 = 0.95   # forearm (m)

:func:`load_geometry` and :func:`save_geometry` are the one reader and writer of that format.

A robot file (``--robot FILE`` of ``python -m eval.identification --log``, written by its ``--save-logs``) is a geometry
file with a second table, the datasheet masses of the analytical model in kg (:class:`DeltaMasses`)::

    [masses]
    m1 = 2.0    # upper arm
    m2 = 0.2    # half of one forearm pair
    m0 = 0.8    # platform with the gripper

It is all a parameter file identified from logs knows of the robot: its identity is the content hash of the two
tables (:func:`datasheet_identity`), and a scenario whose plant has these lengths and masses (``--geometry FILE``
with a robot file takes both) is that robot. :func:`load_robot` and :func:`save_robot` read and write it.
"""

from __future__ import annotations

import dataclasses
import functools
import os
from dataclasses import dataclass, field, replace
from importlib import resources
from pathlib import Path
from typing import Any, Literal

import tomli_w

from delta_env.config import MAX_PAYLOAD_MASS, PlantConfig, RandomizationRanges
from delta_env.cycles import DEFAULT_LIFT_FRACTION, STANDARD_LIFT, MoveProfile, require_start
from delta_env.drive import DriveLimits
from delta_env.faults import FAULT_REACTIONS, FaultSpec
from delta_env.geometry import GRAVITY, DeltaGeometry, DeltaMasses
from delta_env.records import content_hash, from_table, read_toml, to_table
from delta_env.release import (
    DEFAULT_AIR_ACTIVATION,
    DEFAULT_IN_POSITION_TIME,
    DEFAULT_IN_POSITION_WINDOW,
    DEFAULT_SETTLE_TIMEOUT,
    ReleaseSettings,
)
from delta_env.sensors import CONTROL_PERIOD
from delta_env.timing import DEFAULT_TORQUE_SHARE
from delta_env.trajectories import require_peak_acceleration
from delta_env.validation import require_count, require_in, require_interval


@dataclass(frozen=True)
class Condition:
    """How the drive differs from the robot as identified; not part of the robot's identity.

    Attributes:
        friction_scale: Multiplier of the plant's viscous and Coulomb friction (dimensionless); the
            Stribeck excess is a fraction of Coulomb and scales with it. 1 keeps the plant's friction.
        actuator_lag: Current-loop time constant (s) replacing the plant's, or None to keep it.
    """

    friction_scale: float = 1.0
    actuator_lag: float | None = None

    def __post_init__(self) -> None:
        require_in("friction_scale", self.friction_scale, 0.0, 10.0, low_open=True)
        if self.actuator_lag is not None:
            require_in("actuator_lag", self.actuator_lag, 0.0, 0.1, unit="s")

    def apply(self, plant: PlantConfig) -> PlantConfig:
        """The plant as it runs under this condition."""
        realism = plant.realism
        worn = replace(
            realism,
            viscous=realism.viscous * self.friction_scale,
            coulomb=realism.coulomb * self.friction_scale,
            actuator_lag=realism.actuator_lag if self.actuator_lag is None else self.actuator_lag,
        )
        return replace(plant, realism=worn)


TIMINGS = ("fixed", "worst_case", "declared", "online")
"""The names of the ways a task's moves may be timed (:attr:`PickPlaceTask.timing`)."""


def require_timing(timing: str) -> str:
    """``timing`` if it is one of :data:`TIMINGS`, else ValueError."""
    if timing not in TIMINGS:
        raise ValueError(f"timing must be one of {list(TIMINGS)}, got {timing!r}")
    return timing


RELEASE_FIELDS = tuple(item.name for item in dataclasses.fields(ReleaseSettings))
"""The task's fields that say when the gripper switches (:class:`~delta_env.release.ReleaseSettings`)."""


@dataclass(frozen=True)
class PickPlaceTask:
    """The work of one episode (the task arguments of ``DeltaPickPlaceEnv``).

    Attributes:
        cycle: ``"conveyor"`` (random pick and place points on two conveyor zones) or ``"standard"`` (the
            25/305/25 mm cycle).
        n_cycles: Pick-and-place cycles per episode.
        start: ``"place"`` (the episode starts at rest at a place point, where a previous object was released, and
            arches empty to the first pick point: a window of continuous work) or ``"pick"`` (it starts at rest at
            the first pick point).
        peak_acceleration: Peak Cartesian acceleration of the reference (m/s^2), in (0, MAX_PEAK_ACCELERATION = 30 g].
        payload_mass_range: Object masses (kg) are drawn per pick from U[low, high]; low = high fixes them.
        domain_randomization: Per-episode perturbation of the plant, or None (off).
        timing: How moves are timed: ``"fixed"`` at ``peak_acceleration``, or by the time-optimal planner on the
            identified model within the drive's envelope (:mod:`controllers.timing`): ``"worst_case"`` (every
            carry for the heaviest object of ``payload_mass_range``), ``"declared"`` (each carry for its object's
            true mass: a per-object payload schedule, the reference), ``"online"`` (a carry starts timed for the
            heaviest object and is retimed once the payload estimate has settled). A planned timing needs the
            identified model, so the env then needs a ``timing`` object (the evaluation builds it).
        torque_share: Share of the drive's envelope (after the planner's margin) a planned timing may use, in
            (0, 1]: the margin for tracking (:data:`delta_env.timing.DEFAULT_TORQUE_SHARE`).
        jerk_limited: Whether a planned timing's laws are averaged over one period of the drives' first mode
            (:class:`controllers.shaping.JerkLimitedTiming`, built by the evaluation from the drives the controllers
            know): the path acceleration ramps instead of stepping. Only with a planned ``timing``.
        faults: Faults injected into the episodes (:class:`~delta_env.faults.FaultSpec`), drawn per episode;
            none by default.
        release: When the gripper switches at each pick and place point: ``"in_position"`` (the reference holds at
            rest until the cell judges the platform in position from its encoders, then the air activation runs
            and the gripper switches at its end) or ``"timed"`` (mid-way through a 0.1 s dwell, the old cell's;
            the next four fields are then unused). :class:`~delta_env.release.ReleaseSettings` checks them.
        in_position_window: Distance (m) of the measured platform from the reference within which it is in position.
        in_position_time: Time (s) the window must hold, in consecutive control samples.
        air_activation: Rest (s) from the in-position signal to the attach or detach, whole control periods.
        settle_timeout: Longest wait (s) for the in-position signal after the arrival; the gripper then acts anyway.
        fault_reaction: What the monitored controllers (:mod:`controllers.monitor`) ask of the cell after detecting a
            collision, a slip or a drive fault: ``"continue"``, ``"slow"`` (half the reference's speed) or
            ``"stop"`` (a controlled stop at rest on the path, which ends the episode unless the cell resumes first:
            full speed returns once a collision is over; a slip or a drive fault lasts).
    """

    cycle: Literal["conveyor", "standard"] = "conveyor"
    n_cycles: int = 3
    start: Literal["place", "pick"] = "place"
    peak_acceleration: float = 3.0 * GRAVITY
    payload_mass_range: tuple[float, float] = (0.0, 4.0)
    domain_randomization: RandomizationRanges | None = None
    timing: Literal["fixed", "worst_case", "declared", "online"] = "fixed"
    torque_share: float = DEFAULT_TORQUE_SHARE
    jerk_limited: bool = False
    faults: tuple[FaultSpec, ...] = ()
    fault_reaction: Literal["continue", "slow", "stop"] = "continue"
    release: Literal["in_position", "timed"] = "in_position"
    in_position_window: float = DEFAULT_IN_POSITION_WINDOW
    in_position_time: float = DEFAULT_IN_POSITION_TIME
    air_activation: float = DEFAULT_AIR_ACTIVATION
    settle_timeout: float = DEFAULT_SETTLE_TIMEOUT

    def __post_init__(self) -> None:
        self.release_settings  # noqa: B018 - checks the release's fields (once: the settings are kept)
        if not isinstance(self.faults, tuple) or not all(isinstance(f, FaultSpec) for f in self.faults):
            raise ValueError(f"faults must be a tuple of FaultSpec, got {self.faults!r}")
        require_timing(self.timing)
        if self.jerk_limited and self.timing == "fixed":
            raise ValueError("jerk_limited smooths a planned timing's laws; the 'fixed' timing plans none")
        if self.fault_reaction not in FAULT_REACTIONS:
            raise ValueError(f"fault_reaction must be one of {list(FAULT_REACTIONS)}, got {self.fault_reaction!r}")
        require_in("torque_share", self.torque_share, 0.0, 1.0, unit="of the envelope", low_open=True)
        if self.cycle not in ("conveyor", "standard"):
            raise ValueError(f"cycle must be 'conveyor' or 'standard', got {self.cycle!r}")
        require_count("n_cycles", self.n_cycles)
        require_start(self.start)
        require_peak_acceleration(self.peak_acceleration)
        require_interval("payload_mass_range", self.payload_mass_range, 0.0, MAX_PAYLOAD_MASS, unit="kg")
        if self.domain_randomization is not None and not isinstance(self.domain_randomization, RandomizationRanges):
            raise ValueError(
                f"domain_randomization must be RandomizationRanges or None, got {type(self.domain_randomization)}"
            )

    @functools.cached_property
    def move_profile(self) -> MoveProfile:
        """The moves' shared timing and shape on the control period, from the task's fields (checked as it is made)."""
        acceleration, dwell = float(self.peak_acceleration), self.release_settings.dwell
        return MoveProfile(acceleration, STANDARD_LIFT, DEFAULT_LIFT_FRACTION, dwell, CONTROL_PERIOD, self.release)

    @functools.cached_property
    def release_settings(self) -> ReleaseSettings:
        """The release's fields as :class:`~delta_env.release.ReleaseSettings` (checked there, as the task is made)."""
        return ReleaseSettings(**{name: getattr(self, name) for name in RELEASE_FIELDS})


@dataclass(frozen=True)
class Scenario:
    """Everything about the robot and the work; see the module docstring for the three parts.

    Attributes:
        name: Short name (a preset's name, or the file's).
        description: One line for people; not part of any hash.
        plant: The robot as identified.
        condition: Wear on top of the plant.
        task: The work.
    """

    name: str = "custom"
    description: str = ""
    plant: PlantConfig = field(default_factory=PlantConfig)
    condition: Condition = field(default_factory=Condition)
    task: PickPlaceTask = field(default_factory=PickPlaceTask)

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name.strip():
            raise ValueError(f"name must be a non-empty string, got {self.name!r}")
        if not isinstance(self.description, str):
            raise ValueError(f"description must be a string, got {self.description!r}")
        for part, kind in (("plant", PlantConfig), ("condition", Condition), ("task", PickPlaceTask)):
            if not isinstance(getattr(self, part), kind):
                raise ValueError(f"{part} must be a {kind.__name__}, got {type(getattr(self, part)).__name__}")
        self.effective_plant  # noqa: B018 - the worn plant must itself be valid (e.g. Coulomb <= torque limit)

    @property
    def effective_plant(self) -> PlantConfig:
        """The plant the episodes run on: ``plant`` under ``condition``."""
        try:
            return self.condition.apply(self.plant)
        except ValueError as error:
            raise ValueError(f"condition: the worn plant is invalid: {error}") from None

    @property
    def robot_identity(self) -> str:
        """Content hash (16 hex digits) of the ``plant`` part: the robot, whatever its condition and task."""
        return plant_identity(self.plant)

    @property
    def content_hash(self) -> str:
        """Content hash (16 hex digits) of plant, condition and task: what decides an episode's physics."""
        parts = {"plant": _plant_table(self.plant), "condition": to_table(self.condition)}
        return content_hash(parts | {"task": _task_table(self.task)})

    def to_toml(self) -> str:
        """Every field, resolved, as TOML text (what :meth:`from_toml` reads back to an equal value)."""
        return tomli_w.dumps(to_table(self))

    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write :meth:`to_toml` to ``path`` (parent folders created); returns the path."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(self.to_toml())
        return path

    @classmethod
    def from_toml(cls, text: str, source: str = "<string>") -> Scenario:
        """Parse and validate TOML text; ``source`` names it in errors.

        Raises:
            ValueError: for invalid TOML, an unknown key or an invalid field, naming the field.
        """
        return cls._from_document(read_toml(text, f"scenario {source}"), source)

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> Scenario:
        """Read a scenario file; a file without ``name`` is named after its stem."""
        path = Path(path)
        document = read_toml(path.read_text(), f"scenario {path}")
        return cls._from_document({"name": path.stem, **document}, str(path))

    @classmethod
    def _from_document(cls, document: dict[str, Any], source: str) -> Scenario:
        try:
            return from_table(cls, document, "")
        except ValueError as error:
            raise ValueError(f"scenario {source}: {error}") from None


def plant_identity(plant: PlantConfig) -> str:
    """Content hash (16 hex digits) of a plant: the identity of the robot it builds.

    Raises:
        ValueError: if ``plant`` is not a PlantConfig.
    """
    if not isinstance(plant, PlantConfig):
        raise ValueError(f"plant must be a PlantConfig, got {type(plant).__name__}")
    return content_hash(_plant_table(plant))


def _plant_table(plant: PlantConfig) -> dict[str, Any]:
    """The table of ``plant`` that its hashes cover: without ``drive`` when it is the default drive, without
    ``collisions`` when they are off and without ``realism.compliance`` when the drives are rigid (all came later;
    earlier robots keep their hashes)."""
    table = to_table(plant)
    if plant.drive == DriveLimits():
        del table["drive"]
    if not plant.collisions:
        del table["collisions"]
    if plant.realism.compliance is None:
        del table["realism"]["compliance"]
    return table


def _task_table(task: PickPlaceTask) -> dict[str, Any]:
    """The table of ``task`` that the content hash covers: without the timing fields while the moves are timed
    fixed (they came later; earlier scenarios keep their hashes, and the share does nothing then) and without
    ``jerk_limited`` while it is False (it came later too), without ``faults`` when there are none and
    ``fault_reaction`` when it is ``"continue"``, and without the release's
    fields when it is ``"timed"`` (likewise: a timed scenario is the one before the in-position release existed), and
    without the domain randomization's gearhead fractions while they are 0 (they came later too)."""
    table = to_table(task)
    ranges = task.domain_randomization
    if ranges is not None and not ranges.draws_gearhead:
        del table["domain_randomization"]["stiffness_fraction"], table["domain_randomization"]["damping_fraction"]
    if task.timing == "fixed":
        del table["timing"], table["torque_share"]
    if not task.jerk_limited:
        del table["jerk_limited"]
    if not task.faults:
        del table["faults"]
    if task.fault_reaction == "continue":
        del table["fault_reaction"]
    if task.release == "timed":
        for name in RELEASE_FIELDS:
            del table[name]
    return table


def with_geometry(scenario: Scenario, geometry: DeltaGeometry, masses: DeltaMasses | None = None) -> Scenario:
    """``scenario`` on a robot of other lengths: a new robot (new identity), same condition and task.

    Args:
        scenario: The scenario.
        geometry: The robot's lengths (m).
        masses: The robot's masses (kg); None keeps the scenario's.
    """
    plant = replace(scenario.plant, geometry=geometry, masses=scenario.plant.masses if masses is None else masses)
    return replace(scenario, plant=plant)


def load_geometry(path: str | os.PathLike[str]) -> DeltaGeometry:
    """The ``[geometry]`` table (ra, rb, l1, l2 in m) of a geometry file (format in the module docstring).

    Raises:
        ValueError: for a missing file, invalid TOML, a missing ``[geometry]`` table, an unknown key or an
            invalid length, naming the file and the field.
    """
    return _read_part(Path(path), "geometry file", DeltaGeometry, "geometry", "ra, rb, l1, l2 (m)")


def load_masses(path: str | os.PathLike[str]) -> DeltaMasses | None:
    """The ``[masses]`` table (m1, m2, m0 in kg) of a robot file, or None when the file has none.

    Raises:
        ValueError: for a missing file, invalid TOML, an unknown key or an invalid mass, naming the file and the
            field.
    """
    path = Path(path)
    if "masses" not in _read_file(path, "robot file"):
        return None
    return _read_part(path, "robot file", DeltaMasses, "masses", "m1, m2, m0 (kg)")


def load_robot(path: str | os.PathLike[str]) -> tuple[DeltaGeometry, DeltaMasses]:
    """The lengths (m) and datasheet masses (kg) of a robot file (format in the module docstring).

    Raises:
        ValueError: as :func:`load_geometry`, or for a missing ``[masses]`` table.
    """
    path = Path(path)
    geometry = _read_part(path, "robot file", DeltaGeometry, "geometry", "ra, rb, l1, l2 (m)")
    return geometry, _read_part(path, "robot file", DeltaMasses, "masses", "m1, m2, m0 (kg)")


def save_robot(geometry: DeltaGeometry, masses: DeltaMasses, path: str | os.PathLike[str]) -> Path:
    """Write a robot file of ``geometry`` (m) and ``masses`` (kg) (parent folders created); returns the path."""
    return save_geometry(geometry, path, {"masses": to_table(masses)})


def datasheet_identity(geometry: DeltaGeometry, masses: DeltaMasses) -> str:
    """Content hash (16 hex digits) of a robot file's lengths and datasheet masses: the identity of a robot known
    only by them (identified from its logs)."""
    return content_hash({"geometry": to_table(geometry), "masses": to_table(masses)})


def _read_file(path: Path, kind: str) -> dict[str, Any]:
    if not path.is_file():
        raise ValueError(f"{kind} {path}: no such file")
    return read_toml(path.read_text(), f"{kind} {path}")


def _read_part(path: Path, kind: str, cls: type, name: str, keys: str) -> Any:
    """The table ``name`` of a TOML file as dataclass ``cls`` with every field given; ValueError naming the file."""
    table = _read_file(path, kind).get(name)
    if not isinstance(table, dict):
        raise ValueError(f"{kind} {path}: needs a [{name}] table with {keys}")
    missing = [item.name for item in dataclasses.fields(cls) if item.name not in table]
    if missing:
        raise ValueError(f"{kind} {path}: [{name}] misses {', '.join(missing)}")
    try:
        return from_table(cls, table, name)
    except ValueError as error:
        raise ValueError(f"{kind} {path}: {error}") from None


def save_geometry(geometry: DeltaGeometry, path: str | os.PathLike[str], extra: dict[str, Any] | None = None) -> Path:
    """Write ``geometry`` as a geometry file (parent folders created); returns the path.

    Args:
        geometry: The lengths (m).
        path: The file.
        extra: Other top-level tables to record beside ``[geometry]`` (e.g. the design's objectives);
            readers ignore them.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(geometry_toml(geometry, extra))
    return path


def geometry_toml(geometry: DeltaGeometry, extra: dict[str, Any] | None = None) -> str:
    """The text of the geometry file of ``geometry`` (:func:`save_geometry`), ``extra`` tables first."""
    return tomli_w.dumps({**(extra or {}), "geometry": to_table(geometry)})


def preset_names() -> list[str]:
    """Names of the presets shipped with the package, sorted."""
    return sorted(entry.name[: -len(".toml")] for entry in _preset_dir().iterdir() if entry.name.endswith(".toml"))


def preset(name: str) -> Scenario:
    """The shipped preset ``name``.

    Raises:
        ValueError: for an unknown name, listing the presets.
    """
    entry = _preset_dir() / f"{name}.toml"
    if not entry.is_file():
        raise ValueError(f"unknown scenario preset {name!r}; presets: {', '.join(preset_names())}")
    return Scenario.from_toml(entry.read_text(), f"preset {name!r}")


def resolve_scenario(spec: str | os.PathLike[str] | Scenario) -> Scenario:
    """A Scenario from a preset name, a TOML file path or a Scenario (returned as is).

    A string is a preset name if one ships by that name, otherwise a file path.

    Raises:
        ValueError: if ``spec`` is neither a preset nor an existing file (the message lists the presets),
            or if the file is invalid.
    """
    if isinstance(spec, Scenario):
        return spec
    if isinstance(spec, str) and spec in preset_names():
        return preset(spec)
    if isinstance(spec, str | os.PathLike):
        path = Path(spec)
        if path.is_file():
            return Scenario.load(path)
    raise ValueError(
        f"scenario must be a preset name ({', '.join(preset_names())}), a TOML file or a Scenario; got {spec!r}"
        + (" (no such file)" if isinstance(spec, str | os.PathLike) else "")
    )


def _preset_dir() -> Any:
    return resources.files("delta_env") / "scenarios"
