"""Any drive log file by its ending: a table (CSV or Parquet, :mod:`controllers.identification.logs`) or a ROS 2 bag
(MCAP, sqlite3 or a rosbag2 folder, :mod:`controllers.identification.bags`), the same :class:`DriveLog` either way."""

from __future__ import annotations

import os
from pathlib import Path

from controllers.identification.bags import BagTopics, read_bag, write_bag
from controllers.identification.logs import (
    BAG_SUFFIXES,
    DriveLog,
    read_table_log,
    require_log_suffix,
    write_table_log,
)
from delta_env.sensors import CONTROL_PERIOD


def write_log(log: DriveLog, path: str | os.PathLike[str], start: float = 0.0) -> Path:
    """Write ``log`` as a CSV, Parquet, MCAP or sqlite3 file (by the ending of ``path``: ``.csv``, ``.parquet``,
    ``.mcap``, ``.db3``); sample k at ``start + k dt`` (s). Parent folders are created.

    Returns:
        The path written.
    """
    path = Path(path)
    require_log_suffix(path)
    if path.suffix in BAG_SUFFIXES:
        return write_bag(log, path, start)
    return write_table_log(log, path, start)


def read_log(path: str | os.PathLike[str], period: float = CONTROL_PERIOD, topics: BagTopics | None = None) -> DriveLog:
    """The log at ``path`` (a table, or a ROS 2 bag read as ``topics`` say), resampled onto ``period`` (s).

    Raises:
        LogFileError: for a missing or unreadable file, a missing column, a value that is not a finite number,
            non-increasing times or a gap longer than the largest allowed; the message names the file, the column
            and the row.
    """
    path = Path(path)
    if path.is_dir() or path.suffix in BAG_SUFFIXES:
        return read_bag(path, topics, period).log
    return read_table_log(path, period)
