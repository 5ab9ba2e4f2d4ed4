"""Drive logs: the table a robot's logger records, read onto the control period (docs/design.md section 7).

A log is a table, CSV (a header row, then one row per sample) or Parquet, with the columns

- ``time_s``: the sample's time (s), strictly increasing; any origin;
- ``theta_1``, ``theta_2``, ``theta_3``: encoder angles (rad), the sign and zero of docs/design.md section 1
  (0 is the upper arm horizontal, positive turns the arm down);
- ``torque_1``, ``torque_2``, ``torque_3``: measured motor torques at the joint (N m), each read with the
  angles of its row;
- ``command_1``, ``command_2``, ``command_3`` (optional, all three or none): the torque commanded with the
  row's sample (N m), held until the next one; the last row's may be empty (no command follows the log);
- ``motor_angle_1``, ``motor_angle_2``, ``motor_angle_3`` (optional, all three or none): a compliant drive's
  motor-side angle (rad), the motor shaft's over the gear ratio, where ``theta_j`` is read elsewhere or to say
  which side it is; without them a compliant drive's motor side is ``theta_j`` (its encoder sits on the motor);
- ``load_angle_1``, ``load_angle_2``, ``load_angle_3`` (optional, all three or none): a compliant drive's
  load-side angle (rad), an encoder on the arm behind the gearhead (docs/design.md section 4, "Compliant drives").

Other columns are ignored. Timestamps may be irregular: the samples are resampled onto the grid
``time_s[0] + k * period`` (:data:`~delta_env.sensors.CONTROL_PERIOD` by default) up to the last sample, angles
and torques by linear interpolation, commands by zero-order hold (a drive holds its command). A log on that grid
to the last bit (as :func:`write_log` writes it) comes back unchanged. A step between two samples longer than
:data:`MAX_LOG_GAP` is refused (a straight line across it would be a made-up motion), as are non-increasing times
and missing or non-finite values: each error names the file, the column and the row. Split a log at a gap into
two files.

A ROS 2 bag (MCAP or sqlite3, :mod:`controllers.identification.bags`) is a log too: its ``JointState`` messages
become these columns and go through the same checks and resampling.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from controllers.drive import identify_lag
from delta_env.sensors import CONTROL_PERIOD, MEASURED_TORQUE_DELAY

TIME_COLUMN = "time_s"
"""Sample time (s)."""

ANGLE_COLUMNS = ("theta_1", "theta_2", "theta_3")
"""Encoder angles (rad)."""

TORQUE_COLUMNS = ("torque_1", "torque_2", "torque_3")
"""Measured motor torques (N m)."""

COMMAND_COLUMNS = ("command_1", "command_2", "command_3")
"""Commanded motor torques (N m), optional."""

MOTOR_ANGLE_COLUMNS = ("motor_angle_1", "motor_angle_2", "motor_angle_3")
"""A compliant drive's motor-side angles at the joint's scale (rad), optional."""

LOAD_ANGLE_COLUMNS = ("load_angle_1", "load_angle_2", "load_angle_3")
"""A compliant drive's load-side (arm) angles (rad), optional."""

OPTIONAL_ANGLE_COLUMNS = {"motor_angles": MOTOR_ANGLE_COLUMNS, "load_angles": LOAD_ANGLE_COLUMNS}
"""The optional angle columns by the :class:`DriveLog` field that holds them."""

LOG_COLUMNS = (
    TIME_COLUMN,
    *ANGLE_COLUMNS,
    *TORQUE_COLUMNS,
    *COMMAND_COLUMNS,
    *MOTOR_ANGLE_COLUMNS,
    *LOAD_ANGLE_COLUMNS,
)
"""Every column of a log, in the order a log is written."""

TABLE_SUFFIXES = (".csv", ".parquet")
"""File name endings of the two table formats."""

BAG_SUFFIXES = (".mcap", ".db3")
"""File name endings of the storage files of ROS 2 bags, MCAP and sqlite3 (a rosbag2 folder is a bag too)."""

LOG_SUFFIXES = (*TABLE_SUFFIXES, *BAG_SUFFIXES)
"""File name endings of every log format."""

MAX_LOG_GAP = 0.005
"""Longest step between two samples of a log (s), 5 control periods. Across it linear interpolation of the
angles errs by about acceleration x gap^2 / 8: 0.4 mrad (8 encoder steps) at 100 rad/s^2 over 5 ms."""

OTHER_SEPARATORS = (";", "\t", "|")
"""Column separators of other CSV dialects, named in the error when a header holds no log column but one of
them."""

_GRID_TOLERANCE = 1e-9
"""Slack (s) of the zero-order hold: a command logged this close after a grid instant counts as held there."""


class LogFileError(ValueError):
    """A log that cannot be used; the message names the file and the problem."""


@dataclass(frozen=True, eq=False)
class DriveLog:
    """A drive log on a uniform grid: what identification reads of a robot.

    Attributes:
        angles: Encoder angles (rad), ``(N, 3)``, N >= 2.
        torques: Measured motor torques (N m), ``(N, 3)``; reading k comes with angle sample k.
        commands: Commanded torques (N m), ``(N - 1, 3)``: command k, sent with sample k, is held until sample
            k + 1; None when the log has none.
        dt: Sample period (s).
        motor_angles: A compliant drive's motor-side angles (rad), ``(N, 3)``, or None: not logged apart (then
            ``angles`` are the motor side's).
        load_angles: A compliant drive's load-side (arm) angles (rad), ``(N, 3)``, or None: not logged.
    """

    angles: NDArray[np.float64]
    torques: NDArray[np.float64]
    commands: NDArray[np.float64] | None
    dt: float = CONTROL_PERIOD
    motor_angles: NDArray[np.float64] | None = field(default=None, kw_only=True)
    load_angles: NDArray[np.float64] | None = field(default=None, kw_only=True)

    def __post_init__(self) -> None:
        shape = np.shape(self.angles)
        if len(shape) != 2 or shape[1] != 3 or shape[0] < 2:
            raise ValueError(f"angles must have shape (N >= 2, 3), got {shape}")
        if np.shape(self.torques) != shape:
            raise ValueError(f"torques must have the shape of angles {shape}, got {np.shape(self.torques)}")
        if self.commands is not None and np.shape(self.commands) != (shape[0] - 1, 3):
            raise ValueError(f"commands must have shape ({shape[0] - 1}, 3), got {np.shape(self.commands)}")
        if not (math.isfinite(self.dt) and self.dt > 0.0):
            raise ValueError(f"dt must be a finite number > 0 s, got {self.dt!r}")
        for name in OPTIONAL_ANGLE_COLUMNS:
            values = getattr(self, name)
            if values is not None and np.shape(values) != shape:
                raise ValueError(f"{name} must have the shape of angles {shape}, got {np.shape(values)}")

    @property
    def motor_side_angles(self) -> NDArray[np.float64]:
        """The motor-side angles (rad), ``(N, 3)``: ``motor_angles`` if logged, else ``angles``."""
        return self.angles if self.motor_angles is None else self.motor_angles

    def __len__(self) -> int:
        return len(self.angles)

    def drive_lag(self, torque_delay: float = MEASURED_TORQUE_DELAY) -> NDArray[np.float64] | None:
        """The drive lag (s) per joint fitted to the commands and the torques reported after them
        (:func:`controllers.drive.identify_lag`), each reading ``torque_delay`` (s) older than the instant after its
        command; None without commands."""
        if self.commands is None:
            return None
        return identify_lag(self.commands, self.torques[1:], self.dt, sample_delay=torque_delay)


def write_table_log(log: DriveLog, path: Path, start: float = 0.0) -> Path:
    """Write ``log`` as a CSV or Parquet file (by the ending of ``path``); sample k at ``start + k dt`` (s).

    The CSV holds every number exactly (shortest round-trip decimal); the last row's commands are empty
    (Parquet: null). Parent folders are created. Any log file by its ending:
    :func:`controllers.identification.write_log`.

    Returns:
        The path written.
    """
    time = start + np.arange(len(log)) * log.dt
    columns = {TIME_COLUMN: time}
    columns |= {name: log.angles[:, j] for j, name in enumerate(ANGLE_COLUMNS)}
    columns |= {name: log.torques[:, j] for j, name in enumerate(TORQUE_COLUMNS)}
    if log.commands is not None:
        held = np.vstack([log.commands, np.full((1, 3), np.nan)])
        columns |= {name: held[:, j] for j, name in enumerate(COMMAND_COLUMNS)}
    for field_name, names in OPTIONAL_ANGLE_COLUMNS.items():
        values = getattr(log, field_name)
        if values is not None:
            columns |= {name: values[:, j] for j, name in enumerate(names)}
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix == ".csv":
        with path.open("w", newline="") as file:
            writer = csv.writer(file)
            writer.writerow(columns)
            for row in zip(*(column.tolist() for column in columns.values()), strict=True):
                writer.writerow(["" if math.isnan(value) else repr(value) for value in row])
    else:
        import pyarrow as pa
        import pyarrow.parquet as pq

        table = pa.table({name: pa.array(values, mask=np.isnan(values)) for name, values in columns.items()})
        pq.write_table(table, path)
    return path


def read_table_log(path: Path, period: float | None = CONTROL_PERIOD) -> DriveLog:
    """The CSV or Parquet log at ``path`` (format in the module docstring), resampled onto ``period`` (s; None: the
    log's own, :func:`resample_log`). Any log file by its ending: :func:`controllers.identification.read_log`.

    Raises:
        LogFileError: for a missing or unreadable file, a missing column, a value that is not a finite number,
            non-increasing times or a gap longer than :data:`MAX_LOG_GAP`; the message names the file, the
            column and the row.
    """
    require_log_suffix(path)
    if not path.is_file():
        raise LogFileError(f"log {path}: no such file")
    columns = _read_csv(path) if path.suffix == ".csv" else _read_parquet(path)
    try:
        return resample_log(columns, period)
    except ValueError as error:
        raise LogFileError(f"log {path}: {error}") from None


def resample_log(columns: dict[str, ArrayLike], period: float | None = CONTROL_PERIOD) -> DriveLog:
    """A log's columns (name -> values) checked and resampled onto ``period`` (s; None: the log's own, the median
    step of its times, for a trace sampled faster than the control period); errors count data rows from 1.

    Raises:
        ValueError: naming the column and the row (module docstring).
    """
    if period is not None and not (math.isfinite(period) and 0.0 < period <= MAX_LOG_GAP):
        raise ValueError(f"period must lie in (0, {MAX_LOG_GAP:g}] s, got {period!r}")
    required = (TIME_COLUMN, *ANGLE_COLUMNS, *TORQUE_COLUMNS)
    missing = [name for name in required if name not in columns]
    commands_present = [name for name in COMMAND_COLUMNS if name in columns]
    if missing:
        raise ValueError(
            f"missing column(s) {', '.join(missing)}; a log needs {', '.join(required)} "
            f"(and optionally {', '.join(COMMAND_COLUMNS)})"
        )
    optional_present = []
    for group in (COMMAND_COLUMNS, *OPTIONAL_ANGLE_COLUMNS.values()):
        present = [name for name in group if name in columns]
        if present and len(present) < len(group):
            absent = [name for name in group if name not in columns]
            raise ValueError(f"has {', '.join(present)} but not {', '.join(absent)}: give all three or none")
        optional_present += present
    values = {name: np.asarray(columns[name], dtype=float) for name in (*required, *optional_present)}
    rows = len(values[TIME_COLUMN])
    if rows < 2:
        raise ValueError(f"needs at least 2 rows, has {rows}")
    for name, column in values.items():
        checked = column[:-1] if name in COMMAND_COLUMNS else column  # the last command may be empty
        bad = np.flatnonzero(~np.isfinite(checked))
        if bad.size:
            raise ValueError(f"column {name} is not a finite number at data row {bad[0] + 1}: {float(column[bad[0]])}")
    time = values[TIME_COLUMN]
    steps = np.diff(time)
    if np.any(steps <= 0.0):
        row = int(np.flatnonzero(steps <= 0.0)[0]) + 1  # the data row (from 1) whose successor is not later
        raise ValueError(
            f"time_s must increase strictly: data row {row + 1} has {float(time[row])!r} s after "
            f"{float(time[row - 1])!r} s"
        )
    if np.any(steps > MAX_LOG_GAP):
        row = int(np.flatnonzero(steps > MAX_LOG_GAP)[0]) + 1
        raise ValueError(
            f"a gap of {1e3 * steps[row - 1]:.4g} ms from data row {row} ({float(time[row - 1])!r} s) to {row + 1} "
            f"({float(time[row])!r} s); steps may be at most {1e3 * MAX_LOG_GAP:g} ms: split the log at the gap into "
            "two files"
        )
    if period is None:
        period = float(np.median(steps))
    # 1e-6 periods of slack: a log on the grid keeps its last sample despite rounding of its times
    grid = time[0] + np.arange(math.floor((time[-1] - time[0]) / period + 1e-6) + 1) * period
    angles = np.column_stack([np.interp(grid, time, values[name]) for name in ANGLE_COLUMNS])
    torques = np.column_stack([np.interp(grid, time, values[name]) for name in TORQUE_COLUMNS])
    commands = None
    if commands_present:
        held = np.searchsorted(time, grid[:-1] + _GRID_TOLERANCE, side="right") - 1
        commands = np.column_stack([values[name][held] for name in COMMAND_COLUMNS])
    optional_angles = {
        field_name: np.column_stack([np.interp(grid, time, values[name]) for name in names])
        for field_name, names in OPTIONAL_ANGLE_COLUMNS.items()
        if names[0] in values
    }
    try:
        return DriveLog(angles, torques, commands, period, **optional_angles)
    except ValueError as error:
        raise ValueError(f"spans {time[-1] - time[0]:g} s, too short for one {period:g} s period ({error})") from None


def require_log_suffix(path: Path) -> None:
    """A :class:`LogFileError` unless ``path`` ends in one of :data:`LOG_SUFFIXES`."""
    if path.suffix not in LOG_SUFFIXES:
        raise LogFileError(
            f"log {path}: the file name must end in {', '.join(LOG_SUFFIXES[:-1])} or {LOG_SUFFIXES[-1]} "
            "(or name a rosbag2 folder)"
        )


def _read_csv(path: Path) -> dict[str, NDArray[np.float64]]:
    """The numeric columns of a CSV log; an empty cell is refused (:func:`_refuse_empty`) but in the last row's
    commands, where it is NaN."""
    with path.open(newline="") as file:
        reader = csv.reader(file)
        header = next(reader, None)
        if header is None:
            raise LogFileError(f"log {path}: empty file, needs a header row of column names")
        header = [name.strip() for name in header]
        wanted = {name: index for index, name in enumerate(header) if name in LOG_COLUMNS}
        separator = next((mark for mark in OTHER_SEPARATORS if not wanted and mark in ",".join(header)), None)
        if separator is not None:
            raise LogFileError(
                f"log {path}: no column of a log in the header {','.join(header)!r}; its columns seem separated by "
                f"{separator!r}, a log's are separated by commas"
            )
        table: dict[str, list[float]] = {name: [] for name in wanted}
        empty: dict[str, list[int]] = {name: [] for name in wanted}
        for number, row in enumerate(reader, start=1):
            where = f"data row {number} (line {number + 1})"
            if len(row) != len(header):
                raise LogFileError(f"log {path}: {where} has {len(row)} cells, the header has {len(header)}")
            for name, index in wanted.items():
                cell = row[index].strip()
                if not cell:
                    empty[name].append(number)
                try:
                    table[name].append(float(cell) if cell else math.nan)
                except ValueError:
                    raise LogFileError(f"log {path}: column {name} at {where} is not a number: {cell!r}") from None
    _refuse_empty(path, empty, len(next(iter(table.values()), [])), lambda row: f"data row {row} (line {row + 1})")
    return {name: np.array(values) for name, values in table.items()}


def _refuse_empty(path: Path, empty: dict[str, list[int]], rows: int, where: Callable[[int], str]) -> None:
    """A :class:`LogFileError` naming the first empty cell (``empty``: its data rows, from 1, per column) but the
    last row's commands, which may be empty; ``rows`` is the number of data rows, ``where`` names a row."""
    for name, numbers in empty.items():
        allowed = {rows} if name in COMMAND_COLUMNS else set()
        refused = [number for number in numbers if number not in allowed]
        if refused:
            rule = "only the last row's commands may be empty" if name in COMMAND_COLUMNS else "it needs a number"
            raise LogFileError(f"log {path}: column {name} at {where(refused[0])} is empty; {rule}")


def _read_parquet(path: Path) -> dict[str, NDArray[np.float64]]:
    """The numeric columns of a Parquet log; a null is NaN."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    try:
        table = pq.read_table(path)
    except (pa.ArrowException, OSError) as error:
        raise LogFileError(f"log {path}: not a readable Parquet file ({error})") from None
    columns = {}
    empty: dict[str, list[int]] = {}
    for name in table.column_names:
        if name in LOG_COLUMNS:
            column = table.column(name)
            if not (pa.types.is_floating(column.type) or pa.types.is_integer(column.type)):
                raise LogFileError(f"log {path}: column {name} must hold numbers, has type {column.type}")
            columns[name] = column.to_numpy(zero_copy_only=False).astype(float)
            empty[name] = (np.flatnonzero(column.is_null().to_numpy(zero_copy_only=False)) + 1).tolist()
    _refuse_empty(path, empty, table.num_rows, lambda row: f"data row {row} (null)")
    return columns
