"""ROS 2 bags as drive logs: the joint states a ROS 2 robot records, read with ``rosbags`` (no ROS install).

A bag is an MCAP (``.mcap``) or sqlite3 (``.db3``) storage file, or the rosbag2 folder ``ros2 bag record`` writes
(``metadata.yaml`` beside its storage files). One bag is one log, as one CSV file is.

- Measured: ``sensor_msgs/msg/JointState`` on a topic (``/joint_states`` by default): ``position`` is the encoder
  angle (rad, the sign and zero of docs/design.md section 1) and ``effort`` the measured motor torque (N m) of the
  joints named; ``velocity`` is not read (the identification estimates rates from the angles, as from a CSV log).
  The three joints are ``joint_names`` in the order of joints 1, 2, 3, or by default the first message's first
  three names, in order.
- Commanded (optional): ``sensor_msgs/msg/JointState`` on a command topic, ``effort`` the commanded torque (N m)
  of the same joint names (the command message of ``topic_based_ros2_control``; a stamped, named message, unlike
  the unnamed, unstamped ``std_msgs/msg/Float64MultiArray`` of ros2_control's forward controllers). Row k of the
  log holds the last command stamped before joint state k + 1: the command sent in the period that follows
  sample k, which the drive holds until the next (so a controller may stamp it with sample k's stamp or send it
  a little later). Joint states before the first command's period or more than
  :data:`~controllers.identification.logs.MAX_LOG_GAP` after the last command are left out (a recorder
  subscribes to the topics one after another); a command held longer than that is refused.

Times are the messages' header stamps; when every stamp of a topic read is zero (a driver that leaves them
unset), the bag's receive times of both topics, one clock. The rows then go through
:func:`~controllers.identification.logs.resample_log` as a CSV log's columns do (irregular stamps resampled, gaps
refused), so a bag gives the very :class:`~controllers.identification.logs.DriveLog` the same samples give as
CSV; in its errors a data row is a message of the joint-state topic, counted from 1. :func:`write_bag` writes the
messages with the ROS 2 Jazzy type store's definitions (:data:`TYPESTORE`).
"""

from __future__ import annotations

import logging
import os
import tempfile
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from controllers.identification.logs import (
    ANGLE_COLUMNS,
    BAG_SUFFIXES,
    COMMAND_COLUMNS,
    MAX_LOG_GAP,
    TIME_COLUMN,
    TORQUE_COLUMNS,
    DriveLog,
    LogFileError,
    resample_log,
)
from delta_env.sensors import CONTROL_PERIOD

logger = logging.getLogger(__name__)

JOINT_STATE_TYPE = "sensor_msgs/msg/JointState"
"""Message type of the measured and of the commanded joint states."""

JOINT_STATES_TOPIC = "/joint_states"
"""Default topic of the measured joint states (ros2_control's joint_state_broadcaster publishes there)."""

JOINT_COMMANDS_TOPIC = "/joint_commands"
"""Topic :func:`write_bag` writes the commands on (topic_based_ros2_control's default)."""

WRITTEN_JOINT_NAMES = ("joint_1", "joint_2", "joint_3")
"""Joint names :func:`write_bag` gives joints 1, 2, 3."""

BAG_STORAGES = dict(zip(BAG_SUFFIXES, ("mcap", "sqlite3"), strict=True))
"""File ending of a bag's storage file -> rosbag2 storage plugin."""

TYPESTORE = "ROS2_JAZZY"
"""The rosbags type store (``rosbags.typesys.Stores``) of the messages: ROS 2 Jazzy, the current long-term
release; ``JointState`` and its header are the same in Humble."""

_NANOSECONDS = 1_000_000_000


@dataclass(frozen=True)
class BagTopics:
    """What to read from a bag.

    Attributes:
        joint_states: Topic of the measured joint states.
        joint_names: The JointState names of joints 1, 2, 3; None takes the first message's first three names.
        commands: Topic of the commanded torques (JointState effort); None reads no commands.
    """

    joint_states: str = JOINT_STATES_TOPIC
    joint_names: tuple[str, str, str] | None = None
    commands: str | None = None

    def __post_init__(self) -> None:
        names = self.joint_names
        if names is not None and (len(names) != 3 or len(set(names)) != 3 or not all(names)):
            raise ValueError(f"joint_names must be three distinct non-empty names, got {names!r}")
        if self.commands == self.joint_states:
            raise ValueError(f"the command topic must differ from the joint-state topic {self.joint_states!r}")


@dataclass(frozen=True, eq=False)
class BagLog:
    """A drive log read from a bag, with what was read to make it.

    Attributes:
        log: The log, as from a CSV file of the same samples.
        joint_names: The JointState names taken as joints 1, 2, 3.
        clock: ``"header stamps"`` or ``"receive times"`` (every header stamp of a topic was zero).
    """

    log: DriveLog
    joint_names: tuple[str, str, str]
    clock: str


def is_bag(path: str | os.PathLike[str]) -> bool:
    """Whether ``path`` names a bag: a rosbag2 folder or a storage file (``.mcap``, ``.db3``)."""
    path = Path(path)
    return path.is_dir() or path.suffix in BAG_SUFFIXES


@cache
def ros2_typestore() -> Any:
    """The rosbags type store of :data:`TYPESTORE` (``rosbags.typesys.store.Typestore``), made once."""
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores[TYPESTORE])


@dataclass(frozen=True, eq=False)
class _Messages:
    """The JointState messages of one topic, in bag order: stamps (ns) and the three joints' values."""

    header_ns: NDArray[np.int64]
    receive_ns: NDArray[np.int64]
    position: NDArray[np.float64]
    effort: NDArray[np.float64]


def read_bag(path: str | os.PathLike[str], topics: BagTopics | None = None, period: float = CONTROL_PERIOD) -> BagLog:
    """The drive log in the bag at ``path`` (module docstring), resampled onto ``period`` (s).

    Raises:
        LogFileError: for a missing or unreadable bag, a missing topic (the message lists the bag's topics), a
            topic of another type, an unknown joint name (the message lists the names present), a message
            without the positions or efforts of the three joints, and every error of a CSV log's values (the
            message names the topic and the message).
    """
    from rosbags.rosbag2 import Reader

    path = Path(path)
    topics = BagTopics() if topics is None else topics
    if not path.exists():
        raise LogFileError(f"log {path}: no such file or folder")
    if path.is_dir() and not (path / "metadata.yaml").is_file():
        raise LogFileError(f"log {path}: a folder but not a rosbag2 bag (it has no metadata.yaml)")
    try:
        with Reader(path) as reader:
            present = {topic: (info.msgtype, info.msgcount) for topic, info in reader.topics.items()}
            wanted = [topic for topic in (topics.joint_states, topics.commands) if topic is not None]
            for topic in wanted:
                _require_topic(path, topic, present)
            connections = [connection for connection in reader.connections if connection.topic in wanted]
            raw: dict[str, list[tuple[int, bytes]]] = {topic: [] for topic in wanted}
            for connection, receive_ns, data in reader.messages(connections=connections):
                raw[connection.topic].append((receive_ns, data))
    except LogFileError:
        raise
    except Exception as error:  # rosbags raises its own errors, sqlite3's, KeyError, struct.error, ...
        raise LogFileError(f"log {path}: not a readable ROS 2 bag ({type(error).__name__}: {error})") from None
    states, joint_names = _joint_messages(path, topics.joint_states, raw[topics.joint_states], topics.joint_names)
    commands = None
    if topics.commands is not None:
        commands, _ = _joint_messages(path, topics.commands, raw[topics.commands], joint_names, measured=False)
    by_topic = (
        {topics.joint_states: states} if commands is None else {topics.joint_states: states, topics.commands: commands}
    )
    unstamped = [topic for topic, messages in by_topic.items() if not messages.header_ns.any()]
    clock = "receive times" if unstamped else "header stamps"
    if unstamped:
        logger.warning("log %s: the header stamps of %s are zero: timing by the bag's receive times", path, unstamped)
    state_ns = states.receive_ns if unstamped else states.header_ns
    columns: dict[str, Any] = {}
    where = f"topic {topics.joint_states}"
    if commands is not None:
        command_ns = commands.receive_ns if unstamped else commands.header_ns
        kept, held_commands = _hold_commands(path, topics, state_ns, command_ns, commands.effort)
        if kept.start > 0:
            where += f" from message {kept.start + 1} (the commands' span; data row 1 is that message)"
        state_ns, position, effort = state_ns[kept], states.position[kept], states.effort[kept]
        columns |= {name: held_commands[:, j] for j, name in enumerate(COMMAND_COLUMNS)}
    else:
        position, effort = states.position, states.effort
    # Elapsed time in periods first, then in seconds: a stamp on the grid gives the grid's own float, so a bag
    # written on the grid reads back bit for bit, as a CSV log does.
    columns[TIME_COLUMN] = ((state_ns - state_ns[0]) / (period * _NANOSECONDS)) * period
    columns |= {name: position[:, j] for j, name in enumerate(ANGLE_COLUMNS)}
    columns |= {name: effort[:, j] for j, name in enumerate(TORQUE_COLUMNS)}
    try:
        log = resample_log(columns, period)
    except ValueError as error:
        joints = ", ".join(joint_names)
        raise LogFileError(f"log {path}: {where} (theta_j, torque_j: position, effort of {joints}): {error}") from None
    return BagLog(log, joint_names, clock)


def _require_topic(path: Path, topic: str, present: dict[str, tuple[str | None, int]]) -> None:
    """Refuse a topic the bag does not have, has no messages on, or has of another type than JointState."""
    listed = ", ".join(f"{name} ({kind}, {count} messages)" for name, (kind, count) in sorted(present.items()))
    if topic not in present:
        raise LogFileError(f"log {path}: no topic {topic}; the bag has {listed or 'no topics'}")
    kind, count = present[topic]
    if kind != JOINT_STATE_TYPE:
        raise LogFileError(f"log {path}: topic {topic} has type {kind}, not {JOINT_STATE_TYPE}")
    if count == 0:
        raise LogFileError(f"log {path}: topic {topic} has no messages")


def _joint_messages(
    path: Path,
    topic: str,
    raw: list[tuple[int, bytes]],
    joint_names: tuple[str, str, str] | None,
    *,
    measured: bool = True,
) -> tuple[_Messages, tuple[str, str, str]]:
    """The stamps, positions and efforts of the joints ``joint_names`` (None: the first message's first three) in
    a topic's serialized JointState messages, and the names taken; commands (not ``measured``) need no positions
    (NaN)."""
    typestore = ros2_typestore()
    header_ns = np.empty(len(raw), dtype=np.int64)
    position = np.full((len(raw), 3), np.nan)
    effort = np.full((len(raw), 3), np.nan)
    names: list[str] | None = None
    index: list[int] = []
    for number, (_, data) in enumerate(raw):
        message = typestore.deserialize_cdr(data, JOINT_STATE_TYPE)
        where = f"log {path}: topic {topic} message {number + 1}"
        if message.name != names:
            names = list(message.name)
            if joint_names is None:
                if len(names) < 3:
                    raise LogFileError(f"{where} names {len(names)} joints ({', '.join(names)}), needs 3")
                joint_names = (names[0], names[1], names[2])
            unknown = [name for name in joint_names if name not in names]
            if unknown:
                raise LogFileError(
                    f"{where}: no joint named {', '.join(map(repr, unknown))}; its joints are "
                    f"{', '.join(map(repr, names)) or 'none'} (choose three with --joint-names a,b,c)"
                )
            index = [names.index(name) for name in joint_names]
        stamp = message.header.stamp
        header_ns[number] = stamp.sec * _NANOSECONDS + stamp.nanosec
        if measured:
            if len(message.position) != len(names):
                raise LogFileError(f"{where} has {len(message.position)} positions for {len(names)} joints")
            position[number] = message.position[index]
        if len(message.effort) != len(names):
            raise LogFileError(
                f"{where} has {len(message.effort)} efforts (torques) for {len(names)} joints; "
                "the identification needs every joint's"
            )
        effort[number] = message.effort[index]
    assert joint_names is not None  # raw holds at least one message (_require_topic)
    receive_ns = np.array([stamp for stamp, _ in raw], dtype=np.int64)
    return _Messages(header_ns, receive_ns, position, effort), joint_names


def _hold_commands(
    path: Path,
    topics: BagTopics,
    state_ns: NDArray[np.int64],
    command_ns: NDArray[np.int64],
    command_effort: NDArray[np.float64],
) -> tuple[slice, NDArray[np.float64]]:
    """The joint states within the commands' span and the command each row holds, the last row's NaN (the module
    docstring's rule).

    Raises:
        LogFileError: if the command stamps do not increase, fewer than 2 joint states lie in the commands' span or
            a row's command is older than :data:`MAX_LOG_GAP` at the next joint state.
    """
    steps = np.diff(command_ns)
    if np.any(steps <= 0):
        number = int(np.flatnonzero(steps <= 0)[0]) + 2
        raise LogFileError(f"log {path}: topic {topics.commands}: message {number} is not later than the one before")
    max_age = round(MAX_LOG_GAP * _NANOSECONDS)
    # row k holds the last command stamped before joint state k + 1: the first row is the one whose successor
    # comes after the first command; rows end max_age after the last command
    first = max(0, int(np.searchsorted(state_ns, command_ns[0], side="right")) - 1)
    stop = int(np.searchsorted(state_ns, command_ns[-1] + max_age, side="right"))
    if stop - first < 2:
        raise LogFileError(
            f"log {path}: the commands on {topics.commands} span fewer than 2 messages of {topics.joint_states}"
        )
    following = state_ns[first + 1 : stop]
    held = np.searchsorted(command_ns, following, side="left") - 1
    age = following - command_ns[held]
    if np.any(age > max_age):
        row = int(np.flatnonzero(age > max_age)[0])
        raise LogFileError(
            f"log {path}: topic {topics.commands}: no command in the {age[row] / 1e6:.4g} ms before "
            f"{topics.joint_states} message {first + row + 2}; a command may be held at most "
            f"{1e3 * MAX_LOG_GAP:g} ms: split the bag at the gap"
        )
    commands = np.vstack([command_effort[held], np.full((1, 3), np.nan)])
    return slice(first, stop), commands


def write_bag(
    log: DriveLog,
    path: str | os.PathLike[str],
    start: float = 0.0,
    joint_names: tuple[str, str, str] = WRITTEN_JOINT_NAMES,
) -> Path:
    """Write ``log`` as a bag storage file (``.mcap`` or ``.db3``, by the ending of ``path``), as a ROS 2 robot
    records it: JointState on :data:`JOINT_STATES_TOPIC` (position, effort; no velocity) and, with commands,
    JointState on :data:`JOINT_COMMANDS_TOPIC` (effort), sample k stamped ``start + k dt`` (s, whole nanoseconds;
    header stamp and receive time alike), command k with sample k's stamp. An existing file is replaced; parent
    folders are created.

    Returns:
        The path written.
    """
    from rosbags.rosbag2 import StoragePlugin, Writer

    path = Path(path)
    if path.suffix not in BAG_STORAGES:
        raise LogFileError(f"bag {path}: the file name must end in {' or '.join(BAG_STORAGES)}")
    if log.motor_angles is not None or log.load_angles is not None:
        raise LogFileError(
            f"bag {path}: a bag's JointState holds one angle per joint, this log has motor- or load-side angles "
            "besides: write it as CSV or Parquet"
        )
    typestore = ros2_typestore()
    joint_state = typestore.types[JOINT_STATE_TYPE]
    header = typestore.types["std_msgs/msg/Header"]
    time = typestore.types["builtin_interfaces/msg/Time"]
    stamps = round(start * _NANOSECONDS) + np.round(np.arange(len(log)) * log.dt * _NANOSECONDS).astype(np.int64)
    names = list(joint_names)
    empty = np.zeros(0)

    def message(stamp: int, position: NDArray[np.float64], effort: NDArray[np.float64]) -> bytes:
        stamped = header(stamp=time(sec=stamp // _NANOSECONDS, nanosec=stamp % _NANOSECONDS), frame_id="")
        state = joint_state(header=stamped, name=names, position=position, velocity=empty, effort=effort)
        return typestore.serialize_cdr(state, JOINT_STATE_TYPE)

    path.parent.mkdir(parents=True, exist_ok=True)
    # rosbags writes a rosbag2 folder; the storage file alone is the bag (it holds the types and the metadata)
    with tempfile.TemporaryDirectory(dir=path.parent) as folder:
        bag = Path(folder) / path.stem
        with Writer(bag, version=9, storage_plugin=StoragePlugin[BAG_STORAGES[path.suffix].upper()]) as writer:
            measured = writer.add_connection(JOINT_STATES_TOPIC, JOINT_STATE_TYPE, typestore=typestore)
            commanded = None
            if log.commands is not None:
                commanded = writer.add_connection(JOINT_COMMANDS_TOPIC, JOINT_STATE_TYPE, typestore=typestore)
            for k, stamp in enumerate(stamps.tolist()):
                writer.write(measured, stamp, message(stamp, log.angles[k], log.torques[k]))
                if commanded is not None and k < len(log.commands):
                    writer.write(commanded, stamp, message(stamp, empty, log.commands[k]))
        (bag / f"{path.stem}{path.suffix}").replace(path)
    return path
