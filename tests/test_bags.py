"""ROS 2 bags as drive logs: the round trip, the joint names, the clocks, the command topic, the errors, the
identification from bags against the one from CSV logs of the same runs, and ``python -m eval.identification
--quick``."""

import json

import numpy as np
import pytest
from numpy.testing import assert_allclose

from controllers.identification import LogFileError, load_result, read_log, resample_log, write_log
from controllers.identification.bags import JOINT_COMMANDS_TOPIC, JOINT_STATE_TYPE, BagTopics, read_bag, ros2_typestore
from eval.identification import __main__ as cli
from eval.identification.parameter_files import identification_root, parameter_path
from eval.identification.run import identify_logs
from tests.test_logs import random_log

COMMANDS = BagTopics(commands=JOINT_COMMANDS_TOPIC)


def write_messages(path, topics: dict[str, list[dict]], *, folder: bool = False) -> None:
    """A bag as another robot's recorder might write it: per topic, JointState messages given as dicts with
    ``stamp`` (header, ns), ``receive`` (ns, default the stamp), ``name``, ``position``, ``effort``; a topic whose
    list is empty has no messages. ``folder``: the rosbag2 folder itself, else its storage file at ``path``."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    store = ros2_typestore()
    state, header, time = (
        store.types[name] for name in (JOINT_STATE_TYPE, "std_msgs/msg/Header", "builtin_interfaces/msg/Time")
    )
    bag = path if folder else path.parent / f"{path.stem}_bag"
    plugin = StoragePlugin.MCAP if path.suffix == ".mcap" or folder else StoragePlugin.SQLITE3
    with Writer(bag, version=9, storage_plugin=plugin) as writer:
        connections = {topic: writer.add_connection(topic, JOINT_STATE_TYPE, typestore=store) for topic in topics}
        stream = sorted(
            (
                (message.get("receive", message["stamp"]), topic, message)
                for topic, messages in topics.items()
                for message in messages
            ),
            key=lambda item: item[0],
        )
        for receive, topic, message in stream:
            stamp = header(stamp=time(sec=message["stamp"] // 10**9, nanosec=message["stamp"] % 10**9), frame_id="")
            data = state(
                header=stamp,
                name=list(message["name"]),
                position=np.asarray(message.get("position", []), dtype=float),
                velocity=np.zeros(0),
                effort=np.asarray(message.get("effort", []), dtype=float),
            )
            writer.write(connections[topic], receive, store.serialize_cdr(data, JOINT_STATE_TYPE))
    if not folder:
        (bag / f"{bag.name}{path.suffix}").replace(path)


def joint_states(times_ns, angles, torques, names=("joint_1", "joint_2", "joint_3")) -> list[dict]:
    return [
        {"stamp": int(t), "name": names, "position": a, "effort": e}
        for t, a, e in zip(times_ns, angles, torques, strict=True)
    ]


@pytest.mark.parametrize("suffix", [".mcap", ".db3"])
@pytest.mark.parametrize("commands", [True, False], ids=["commands", "no-commands"])
def test_a_bag_reads_back_exactly_as_its_csv_does(tmp_path, suffix, commands) -> None:
    log = random_log(commands=commands)
    start = 1.7e9  # a Unix time: the stamps keep whole nanoseconds, the log comes back bit for bit
    bag = read_bag(write_log(log, tmp_path / f"log{suffix}", start=start), COMMANDS if commands else None)
    csv = read_log(write_log(log, tmp_path / "log.csv", start=start))
    for back in (bag.log, csv):
        np.testing.assert_array_equal(back.angles, log.angles)
        np.testing.assert_array_equal(back.torques, log.torques)
    if commands:
        np.testing.assert_array_equal(bag.log.commands, log.commands)
    else:
        assert bag.log.commands is None
    assert (bag.joint_names, bag.clock) == (("joint_1", "joint_2", "joint_3"), "header stamps")
    # without --command-topic a bag's commands are not read
    assert read_log(tmp_path / f"log{suffix}").commands is None


def test_joint_names_pick_the_three_joints_from_a_message_with_more_in_any_order(tmp_path) -> None:
    log = random_log(commands=False)
    names = ("gripper", "arm_3", "arm_1", "arm_2")
    # the message's joints: the gripper (position 9, effort -9), then joints 3, 1, 2
    position = np.column_stack([np.full(len(log), 9.0), log.angles[:, 2], log.angles[:, 0], log.angles[:, 1]])
    effort = np.column_stack([np.full(len(log), -9.0), log.torques[:, 2], log.torques[:, 0], log.torques[:, 1]])
    times = 5 * 10**9 + np.arange(len(log)) * 10**6
    path = tmp_path / "robot.mcap"
    write_messages(path, {"/arm/joint_states": joint_states(times, position, effort, names)})
    topics = BagTopics("/arm/joint_states", ("arm_1", "arm_2", "arm_3"))
    bag = read_bag(path, topics)
    np.testing.assert_array_equal(bag.log.angles, log.angles)
    np.testing.assert_array_equal(bag.log.torques, log.torques)
    default = read_bag(path, BagTopics("/arm/joint_states"))  # the first three names, in order
    assert default.joint_names == ("gripper", "arm_3", "arm_1")
    np.testing.assert_array_equal(default.log.angles[:, 1:], log.angles[:, [2, 0]])
    with pytest.raises(LogFileError) as error:
        read_bag(path, BagTopics("/arm/joint_states", ("arm_1", "arm_2", "wrist")))
    message = str(error.value)
    assert "no joint named 'wrist'" in message and "'gripper', 'arm_3', 'arm_1', 'arm_2'" in message


@pytest.fixture
def jittered(tmp_path) -> dict:
    rng = np.random.default_rng(2)
    # a recorder at 1 kHz with +-0.3 ms jitter and one message lost (a 2 ms step)
    times = np.delete(3 * 10**9 + np.arange(300) * 10**6 + rng.integers(-300_000, 300_000, 300), 150)
    signal = np.sin(20.0 * times / 1e9)
    angles = np.column_stack([signal, 2 * signal, 3 * signal])
    return {"times": times, "angles": angles, "torques": 10.0 * angles, "folder": tmp_path}


def test_jittered_stamps_are_resampled_as_a_csv_log_with_those_times_is(jittered) -> None:
    times, angles, torques = jittered["times"], jittered["angles"], jittered["torques"]
    path = jittered["folder"] / "jitter.db3"
    write_messages(path, {"/joint_states": joint_states(times, angles, torques)})
    columns = {"time_s": (times - times[0]) / 1e9}
    columns |= {f"theta_{j + 1}": angles[:, j] for j in range(3)}
    columns |= {f"torque_{j + 1}": torques[:, j] for j in range(3)}
    expected = resample_log(columns)
    log = read_log(path)
    assert len(log) == len(expected) > 290
    assert_allclose(log.angles, expected.angles, rtol=0, atol=1e-12)
    assert_allclose(log.torques, expected.torques, rtol=0, atol=1e-11)


def test_zero_header_stamps_take_the_bags_receive_times(jittered, caplog) -> None:
    times, angles, torques = jittered["times"], jittered["angles"], jittered["torques"]
    stamped, unstamped = jittered["folder"] / "stamped.mcap", jittered["folder"] / "unstamped.mcap"
    write_messages(stamped, {"/joint_states": joint_states(times, angles, torques)})
    messages = [
        message | {"stamp": 0, "receive": int(t)}
        for message, t in zip(joint_states(times, angles, torques), times, strict=True)
    ]
    write_messages(unstamped, {"/joint_states": messages})
    header, receive = read_bag(stamped), read_bag(unstamped)
    assert (header.clock, receive.clock) == ("header stamps", "receive times")
    np.testing.assert_array_equal(receive.log.angles, header.log.angles)
    assert "the header stamps of ['/joint_states'] are zero" in caplog.text


def test_commands_are_held_from_their_own_topic_within_its_span(tmp_path) -> None:
    log = random_log(rows=80)
    times = 10**9 + np.arange(len(log)) * 10**6
    states = joint_states(times, log.angles, log.torques)
    # the recorder subscribed to the commands 10 ms late; each command comes 0.2 ms after its joint state
    commands = [
        {"stamp": int(t) + 200_000, "name": ("joint_1", "joint_2", "joint_3"), "effort": c}
        for t, c in zip(times[10:-1], log.commands[10:], strict=True)
    ]
    path = tmp_path / "late.mcap"
    write_messages(path, {"/joint_states": states, "/cmd": commands})
    back = read_bag(path, BagTopics(commands="/cmd")).log
    # the joint states before the first command's period are left out; row k holds the last command stamped
    # before joint state k + 1, the one sent after sample k
    np.testing.assert_array_equal(back.angles, log.angles[10:])
    np.testing.assert_array_equal(back.commands, log.commands[10:])
    # a gap of 8 ms in the commands is refused, naming the joint state
    gap = [c for c in commands if not 40 * 10**6 < c["stamp"] - 10**9 < 48 * 10**6]
    path = tmp_path / "gap.mcap"
    write_messages(path, {"/joint_states": states, "/cmd": gap})
    with pytest.raises(LogFileError, match=r"/cmd: no command in the 5\.8 ms before /joint_states message 46"):
        read_bag(path, BagTopics(commands="/cmd"))


def test_a_rosbag2_folder_is_a_log_too(tmp_path) -> None:
    log = random_log(commands=False)
    folder = tmp_path / "rosbag2_2026_11_28"
    write_messages(
        folder, {"/joint_states": joint_states(np.arange(len(log)) * 10**6 + 1, log.angles, log.torques)}, folder=True
    )
    assert (folder / "metadata.yaml").is_file()
    np.testing.assert_array_equal(read_log(folder).angles, log.angles)


@pytest.mark.parametrize(
    ("topics", "message"),
    [
        ({}, "no topic /joint_states; the bag has no topics"),
        ({"/joint_states": []}, "topic /joint_states has no messages"),
        (
            {"/js": [{"stamp": 1, "name": "abc", "position": [0, 0, 0], "effort": [0, 0, 0]}]},
            "no topic /joint_states; the bag has /js (sensor_msgs/msg/JointState, 1 messages)",
        ),
        (
            {"/joint_states": [{"stamp": 1, "name": "ab", "position": [0, 0], "effort": [0, 0]}]},
            "message 1 names 2 joints (a, b), needs 3",
        ),
        (
            {"/joint_states": [{"stamp": 1, "name": "abc", "position": [0, 0, 0]}]},
            "message 1 has 0 efforts (torques) for 3 joints",
        ),
        (
            {"/joint_states": [{"stamp": 1, "name": "abc", "position": [0, 0, 0], "effort": [0, 0, 0]}]},
            "position, effort of a, b, c): needs at least 2 rows, has 1",
        ),
        (
            {
                "/joint_states": [
                    {"stamp": s, "name": "abc", "position": [0, 0, 0], "effort": [0, 0, 0]}
                    for s in (10**6, 2 * 10**6, 9 * 10**6)
                ]
            },
            "topic /joint_states (theta_j, torque_j: position, effort of a, b, c): a gap of 7 ms from data row 2",
        ),
    ],
    ids=["empty-bag", "no-messages", "other-topic", "two-joints", "no-effort", "one-message", "gap"],
)
def test_bad_bags_are_refused_naming_the_bag_topic_and_message(tmp_path, topics, message) -> None:
    path = tmp_path / "bad.mcap"
    write_messages(path, topics)
    with pytest.raises(LogFileError) as error:
        read_log(path)
    assert str(error.value).startswith(f"log {path}: ") and message in str(error.value)


def test_unreadable_bags_are_refused(tmp_path) -> None:
    garbage = tmp_path / "garbage.db3"
    garbage.write_bytes(b"not a bag")
    with pytest.raises(LogFileError, match="not a readable ROS 2 bag"):
        read_log(garbage)
    with pytest.raises(LogFileError, match=r"metadata\.yaml"):
        read_log(tmp_path)  # a folder without metadata.yaml
    with pytest.raises(LogFileError, match="no such file or folder"):
        read_log(tmp_path / "missing.mcap")
    with pytest.raises(LogFileError, match=r"must end in \.csv, \.parquet, \.mcap or \.db3"):
        read_log(tmp_path / "log.txt")


@pytest.fixture(scope="module")
def bag_runs(tmp_path_factory) -> dict:
    """A short simulated identification with ``--save-logs DIR --log-format mcap``, then the identification from
    those bags alone (``--log *.mcap --command-topic /joint_commands --robot``): both run folders and the bags."""
    root = tmp_path_factory.mktemp("bags")
    logs = root / "logs"
    short = ["--trajectories", "2", "--duration", "2.5", "--validation-duration", "2.5", "--seed", "3"]
    quiet = ["--no-progress", "--workers", "1"]
    cli.main(
        [*short, *quiet, "--no-install", "--out", str(root / "sim"), "--save-logs", str(logs), "--log-format", "mcap"]
    )
    files = sorted(logs.glob("*.mcap"))
    robot = ["--robot", str(logs / "robot.toml")]
    bags = ["--command-topic", JOINT_COMMANDS_TOPIC]
    cli.main(["--log", *map(str, files), *robot, *bags, *quiet, "--out", str(root / "frombags")])
    return {"root": root, "logs": logs, "files": files}


def test_runs_saved_as_bags_identify_to_the_parameters_of_their_csv_logs(bag_runs, tmp_path) -> None:
    root, files = bag_runs["root"], bag_runs["files"]
    assert [path.name for path in files] == ["excitation_01.mcap", "excitation_02.mcap", "validation.mcap"]
    # the same runs as CSV logs (what --log-format csv writes) and as sqlite3 bags
    csv = [write_log(read_log(path, topics=COMMANDS), tmp_path / path.with_suffix(".csv").name) for path in files]
    from_csv = identify_logs(csv, bag_runs["logs"] / "robot.toml").result
    simulated, from_bags = (load_result(root / name / "parameters.json") for name in ("sim", "frombags"))
    for name in ("mid", "mid_f", "mid_f_rods", "paper_mid", "paper_mid_f", "drive_lag", "standard_errors"):
        assert getattr(from_bags, name) == getattr(from_csv, name) == getattr(simulated, name), name
    assert from_bags.provenance["torque_error_validation"] == from_csv.provenance["torque_error_validation"]
    read = from_bags.provenance["validation_log"]["bag"]
    assert read == {
        "topic": "/joint_states",
        "joint_names": ["joint_1", "joint_2", "joint_3"],
        "command_topic": JOINT_COMMANDS_TOPIC,
        "clock": "header stamps",
    }
    config = json.loads((root / "frombags" / "config.json").read_text())["config"]
    assert (config["topic"], config["command_topic"]) == ("/joint_states", JOINT_COMMANDS_TOPIC)


def test_sqlite3_bags_of_the_runs_give_the_mcap_bags_logs(bag_runs, tmp_path) -> None:
    for path in bag_runs["files"]:
        mcap = read_log(path, topics=COMMANDS)
        sqlite3 = read_log(write_log(mcap, tmp_path / path.with_suffix(".db3").name), topics=COMMANDS)
        for name in ("angles", "torques", "commands"):
            np.testing.assert_array_equal(getattr(sqlite3, name), getattr(mcap, name))


def test_bag_errors_on_the_command_line_are_messages(bag_runs, tmp_path, capsys) -> None:
    files, robot = [str(path) for path in bag_runs["files"]], ["--robot", str(bag_runs["logs"] / "robot.toml")]
    out = ["--out", str(tmp_path / "run")]
    assert cli.main(["--log", *files, *robot, "--topic", "/arm/joint_states", *out]) == 2
    error = capsys.readouterr().err
    assert (
        "error: log " in error
        and "no topic /arm/joint_states; the bag has /joint_commands (sensor_msgs/msg/JointState" in error
    )
    assert cli.main(["--log", *files, *robot, "--joint-names", "joint_1,joint_2,elbow", *out]) == 2
    assert "no joint named 'elbow'; its joints are 'joint_1', 'joint_2', 'joint_3'" in capsys.readouterr().err
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize(
    ("arguments", "message"),
    [
        (["--topic", "/js"], "--topic say what to read from ROS 2 bags; no --log file is a bag"),
        (["--log", "a.csv", "b.csv", "--robot", "r.toml", "--command-topic", "/c"], "--command-topic say what to read"),
        (
            ["--log", "a.mcap", "b.mcap", "--robot", "r.toml", "--joint-names", "a,b"],
            "must be three distinct joint names a,b,c",
        ),
        (
            ["--log", "a.mcap", "b.mcap", "--robot", "r.toml", "--joint-names", "a,b,a"],
            "must be three distinct joint names",
        ),
        (["--log-format", "rosbag1"], "argument --log-format: invalid choice: 'rosbag1'"),
        (["--quick", "--parameters", "p.json"], "--quick writes its rough parameters to the run folder only"),
        (["--log", "a.csv", "b.csv", "--robot", "r.toml", "--quick"], "--quick is for a simulation"),
    ],
)
def test_bad_bag_and_quick_command_lines_are_parser_errors(capsys, arguments, message) -> None:
    with pytest.raises(SystemExit) as exit_code:
        cli.parse_args(arguments)
    assert exit_code.value.code == 2
    assert message in capsys.readouterr().err


def test_quick_settings_yield_to_explicit_ones() -> None:
    quick = cli.parse_args(["--quick"])
    settings = (quick.trajectories, quick.duration, quick.validation_duration, quick.workers, quick.no_install)
    assert settings == (3, 3.0, 3.0, 1, True)
    assert cli.parse_args(["--quick", "--duration", "5"]).duration == 5.0


def test_a_quick_identification_never_replaces_the_robots_parameter_file(tmp_path, monkeypatch, capsys) -> None:
    monkeypatch.setattr(cli, "QUICK", {"trajectories": 1, "duration": 2.0, "validation_duration": 2.0, "workers": 1})
    runs = tmp_path / "runs"
    cached = parameter_path(cli.parse_args(["--runs-dir", str(runs)]).scenario.plant, identification_root(runs))
    cached.parent.mkdir(parents=True)
    cached.write_text("the default identification")
    cli.main(["--quick", "--runs-dir", str(runs), "--out", str(tmp_path / "run"), "--no-progress"])
    assert cached.read_text() == "the default identification"
    assert load_result(tmp_path / "run" / "parameters.json").provenance["samples"]["validation"] > 0
    output = capsys.readouterr().out
    assert output.startswith("Quick identification (--quick): 1 excitation trajectory of 2 s")
    assert "A quick run (--quick)" in (tmp_path / "run" / "report.md").read_text()
    config = json.loads((tmp_path / "run" / "config.json").read_text())["config"]
    assert (config["quick"], config["trajectories"], config["no_install"]) == (True, 1, True)
