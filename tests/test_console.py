"""How the command lines talk to a user: a bad value is one line and exit code 2 with no run folder left running, an
interruption is one line, the robot's cached identification holds the default settings only, summaries are short
and end with the run folder, and progress off a terminal is plain lines."""

from __future__ import annotations

import importlib
import io
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

from controllers.identification import ParameterFileError, save_result
from delta_env.scenario import preset, with_geometry
from eval.comparison import __main__ as eval_cli
from eval.console import UsageError, command_main, plural, progress_bar
from eval.identification import __main__ as identify
from eval.identification import parameter_files
from eval.processes import holding_interrupts, run_jobs
from eval.run_folder import MANIFEST, RUNS_DIR_VARIABLE, Terminated
from tests.test_robot_identity import DESIGN, fake_result
from tests.test_run_folder import script


def simulated_provenance(trajectories: int, duration: float, validation: float, seed: int = 0) -> dict[str, Any]:
    """What a simulated identification of these settings records of its trajectories."""
    return {
        "seed": seed,
        "trajectories": [{"seed": 100 + n, "duration": duration} for n in range(trajectories)],
        "validation_trajectory": {"seed": 99, "duration": validation},
    }


def usage_error(main: Any, argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    """The one line ``main(argv)`` printed on stderr as it exited with code 2."""
    with pytest.raises(SystemExit) as exit:
        main(argv)
    assert exit.value.code == 2
    printed = capsys.readouterr().err
    lines = printed.strip().splitlines()
    assert len(lines) == 1 or lines[0].startswith("usage:"), lines  # argparse prints its usage first
    assert "Traceback" not in printed and ": error: " in lines[-1]
    return lines[-1]


@pytest.fixture
def runs(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """The runs root of the test (empty), as $DELTA_RUNS_DIR."""
    monkeypatch.setenv(RUNS_DIR_VARIABLE, str(tmp_path / "runs"))
    return tmp_path / "runs"


def run_folders(runs: Path) -> list[Path]:
    """Every run folder under ``runs`` (a folder holding a manifest)."""
    return sorted(path.parent for path in runs.glob(f"**/{MANIFEST}")) if runs.exists() else []


def test_command_main_turns_usage_errors_and_interruptions_into_one_line(capsys) -> None:
    def raising(error: BaseException) -> Any:
        @command_main("python -m tool")
        def main(argv: list[str] | None = None) -> int:
            raise error

        return main

    cases = [
        (
            UsageError("--x 3: must lie in [0, 1]\nsee --help"),
            2,
            "python -m tool: error: --x 3: must lie in [0, 1] see --help",
        ),
        (ParameterFileError("p.json: not valid JSON"), 2, "python -m tool: error: p.json: not valid JSON"),
        (KeyboardInterrupt(), 130, "python -m tool: interrupted"),
        (Terminated("SIGTERM"), 143, "python -m tool: terminated"),
    ]
    for error, code, line in cases:
        with pytest.raises(SystemExit) as exit:
            raising(error)([])
        assert exit.value.code == code
        assert capsys.readouterr().err == line + "\n"
    with pytest.raises(RuntimeError, match="a bug"):  # anything else is a bug and keeps its traceback
        raising(RuntimeError("a bug"))([])


def test_score_only_of_a_missing_file_is_a_usage_error_leaving_no_run_folder(runs, capsys) -> None:
    train_residual = pytest.importorskip("eval.residual.__main__", reason="needs the rl extra (stable-baselines3)")
    line = usage_error(train_residual.main, ["--score-only", "nofile.zip"], capsys)
    assert line.startswith("python -m eval.residual: error: ") and "--score-only nofile.zip" in line
    assert "not found" in line and run_folders(runs) == []


def test_bad_parameter_files_are_usage_errors_before_any_run_folder(runs, tmp_path, capsys) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text("x = 1\n")
    line = usage_error(eval_cli.main, ["--parameters", str(bad)], capsys)
    assert f"argument --parameters: {bad}: not valid JSON" in line
    # A file that does not exist is an error, not an identification written there.
    missing = tmp_path / "nofile.json"
    line = usage_error(eval_cli.main, ["--parameters", str(missing)], capsys)
    assert f"{missing}: no such parameter file" in line and "leave --parameters out" in line
    assert not missing.exists()
    # Another robot's file: the message names both robots, on one line.
    design = with_geometry(preset("nominal"), DESIGN)
    other = tmp_path / "design.json"
    save_result(fake_result(design.plant), other)
    line = usage_error(eval_cli.main, ["--parameters", str(other)], capsys)
    assert line.startswith("python -m eval: error: --parameters: ")
    assert design.robot_identity in line and preset("nominal").robot_identity in line
    assert run_folders(runs) == []


def test_a_policy_trained_on_rigid_drives_is_left_out_on_compliant_ones(capsys) -> None:
    """The shipped policy's base knows no drive compliance (no notch, no deflection feedforward), whose loop rings on
    compliant drives: like a policy of another geometry it is left out of the default rows, and asked for, refused."""
    config = eval_cli.parse_args(["--scenario", "compliant"])
    assert "residual" not in config.controllers and "was trained on another robot" in config.left_out
    assert "residual" in eval_cli.parse_args([]).controllers
    line = usage_error(eval_cli.parse_args, ["--scenario", "compliant", "--controllers", "residual"], capsys)
    assert "rigid drives, not on this scenario's" in line and "compliant drives" in line


def test_an_out_folder_that_cannot_be_made_is_a_usage_error(runs, tmp_path, capsys) -> None:
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    out = blocker / "run"
    line = usage_error(eval_cli.main, ["--out", str(out), "--controllers", "pd"], capsys)
    assert (
        line
        == f"python -m eval: error: --out: cannot create the folder {out} (Not a directory); choose a writable place"
    )
    assert not out.exists() and run_folders(runs) == []


def test_an_existing_out_folder_is_refused_unless_force(runs, tmp_path, capsys, monkeypatch) -> None:
    out = tmp_path / "done"
    out.mkdir()
    (out / "summary.md").write_text("an earlier run\n")
    compared = []
    monkeypatch.setattr(eval_cli, "compare", lambda args, run, started: compared.append(run.folder))
    line = usage_error(eval_cli.main, ["--out", str(out), "--controllers", "pd"], capsys)
    assert f"--out {out}: the folder exists and is not empty" in line and "--force" in line
    assert sorted(path.name for path in out.iterdir()) == ["summary.md"] and compared == []
    assert eval_cli.main(["--out", str(out), "--controllers", "pd", "--force"]) == 0
    assert compared == [out] and json.loads((out / MANIFEST).read_text())["status"] == "finished"
    empty = tmp_path / "empty"
    empty.mkdir()
    assert eval_cli.main(["--out", str(empty), "--controllers", "pd"]) == 0  # an empty folder is no earlier run


def test_ctrl_c_prints_one_line_and_the_manifest_says_interrupted(runs, capsys, monkeypatch) -> None:
    def interrupted(args: Any, run: Any, started: float) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(eval_cli, "compare", interrupted)
    with pytest.raises(SystemExit) as exit:
        eval_cli.main(["--controllers", "pd"])
    (folder,) = run_folders(runs)
    assert exit.value.code == 130
    assert capsys.readouterr().err == f"python -m eval: interrupted (run folder {folder}, marked interrupted)\n"
    assert json.loads((folder / MANIFEST).read_text())["status"] == "interrupted"


def test_a_usage_error_inside_the_run_marks_its_folder_failed_and_names_it(runs, capsys, monkeypatch) -> None:
    def failing(args: Any, run: Any, started: float) -> None:
        raise ParameterFileError("p.json: records robot 'x'")

    monkeypatch.setattr(eval_cli, "compare", failing)
    line = usage_error(eval_cli.main, ["--controllers", "pd"], capsys)
    (folder,) = run_folders(runs)
    assert line == f"python -m eval: error: p.json: records robot 'x' (run folder {folder}, marked failed)"
    assert json.loads((folder / MANIFEST).read_text())["status"] == "failed"


def test_the_robots_cache_refuses_an_identification_of_other_settings(tmp_path) -> None:
    plant = preset("nominal").plant
    defaults = parameter_files.DEFAULT_SETTINGS
    path = parameter_files.parameter_path(plant, tmp_path)
    short = fake_result(plant, **simulated_provenance(3, 3.0, defaults["validation_duration_s"]))
    save_result(short, path)
    with pytest.raises(ParameterFileError) as error:
        parameter_files.identify_robot(plant, tmp_path)
    message = str(error.value)
    assert str(path) in message and "--trajectories 3 --duration 3 --validation-duration 10 --seed 0" in message
    assert "not the defaults --trajectories 12 --duration 8 --validation-duration 10 --seed 0" in message
    # Given by the user, the same file is read as it is.
    assert parameter_files.robot_identification(plant, path, tmp_path)[1] == short
    # The defaults' identification is the robot's; one that does not record its settings is taken as it is.
    trajectories, duration, validation = (defaults[k] for k in ("trajectories", "duration_s", "validation_duration_s"))
    default = fake_result(plant, **simulated_provenance(trajectories, duration, validation))
    assert parameter_files.identification_settings(default) == defaults
    for result in (default, fake_result(plant)):
        save_result(result, path)
        assert parameter_files.identify_robot(plant, tmp_path) == result


def test_eval_identify_installs_only_the_default_settings_as_the_robots_identification(tmp_path, capsys) -> None:
    runs = ["--runs-dir", str(tmp_path)]
    own = parameter_files.parameter_path(preset("nominal").plant, tmp_path / "identification")
    assert identify.parse_args(runs).parameters == own
    assert identify.parse_args([*runs, "--trajectories", "3", "--duration", "3"]).parameters is None
    assert identify.parse_args([*runs, "--seed", "1"]).parameters is None
    chosen = tmp_path / "short.json"
    assert identify.parse_args([*runs, "--trajectories", "3", "--parameters", str(chosen)]).parameters == chosen
    line = usage_error(identify.parse_args, [*runs, "--trajectories", "3", "--parameters", str(own)], capsys)
    assert f"--parameters {own} is the robot's own identification" in line and "--trajectories 3" in line


def test_a_short_identification_does_not_replace_the_robots_own(tmp_path, capsys) -> None:
    out = tmp_path / "run"
    quick = ["--trajectories", "1", "--duration", "1", "--validation-duration", "1", "--workers", "1"]
    assert identify.main([*quick, "--runs-dir", str(tmp_path), "--out", str(out), "--no-progress"]) == 0
    assert (out / "parameters.json").is_file()
    assert not parameter_files.parameter_path(preset("nominal").plant, tmp_path / "identification").exists()
    last = capsys.readouterr().out.strip().splitlines()[-1]
    assert f"Wrote {out}/" in last and "not installed as the robot's identification" in last


def test_progress_off_a_terminal_is_plain_lines(monkeypatch) -> None:
    stream = io.StringIO()
    monkeypatch.setattr("sys.stderr", stream)
    with progress_bar(3, "episodes", "ep", mininterval=0.0, miniters=1) as bar:
        for _ in range(3):
            bar.update()
    text = stream.getvalue()
    assert "\r" not in text and "\x1b" not in text
    lines = text.splitlines()
    assert lines[0].startswith("episodes:   0%") and lines[-1].startswith("episodes: 100%")
    assert "3/3" in lines[-1] and all(line.strip() for line in lines)
    stream.truncate(0)
    with progress_bar(3, "hidden", disable=True) as bar:
        bar.update(3)
    assert stream.getvalue() == ""


def test_plurals() -> None:
    assert [plural(n, "episode") for n in (0, 1, 2)] == ["0 episodes", "1 episode", "2 episodes"]
    assert plural(1, "scenario") == "1 scenario" and plural(2, "process", "processes") == "2 processes"


def test_plan_times_help_does_not_run_the_benchmark(capsys) -> None:
    with pytest.raises(SystemExit) as exit:
        script("plan_times").main(["--help"])
    assert exit.value.code == 0
    printed = capsys.readouterr().out
    assert printed.startswith("usage: python scripts/plan_times.py") and "margin" not in printed


def test_train_residual_help_shows_its_options_first_each_with_help(capsys) -> None:
    train_residual = pytest.importorskip("eval.residual.__main__", reason="needs the rl extra (stable-baselines3)")
    with pytest.raises(SystemExit):
        train_residual.parse_args(["--help"])
    printed = capsys.readouterr().out
    assert printed.index("options:") < printed.index("Seeds:")  # the module's details come after the options
    assert len(printed[: printed.index("options:")].splitlines()) < 30  # the usage lines and a one-line description
    for option in ("--algo", "--reward-scale", "--torch-threads"):
        start = printed.index(f"  {option}", printed.index("options:"))
        entry = printed[start : printed.index("\n  -", start + 1)]
        assert len(entry.split()) > 4, entry  # the option, its value and a sentence of help


def interrupts_ignored(_: int) -> bool:
    """Whether this process ignores Ctrl-C (run in a pool's worker)."""
    return signal.getsignal(signal.SIGINT) == signal.SIG_IGN


def test_workers_leave_ctrl_c_to_the_command_line_which_holds_it_while_they_start() -> None:
    assert run_jobs(interrupts_ignored, [0, 1], workers=2) == [True, True]
    assert not interrupts_ignored(0)
    reached = False
    with pytest.raises(KeyboardInterrupt), holding_interrupts():
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(0.05)  # held: not raised here
        reached = True
    assert reached


@pytest.mark.slow
def test_ctrl_c_on_a_running_comparison_with_workers_prints_one_line(parameter_file, tmp_path) -> None:
    """SIGINT to the whole process group (what Ctrl-C in a terminal sends), the workers of the pool included."""
    out = tmp_path / "run"
    command = [sys.executable, "-m", "eval", "--episodes", "4", "--controllers", "pd,mid_f_rls", "--workers", "2"]
    command += ["--parameters", str(parameter_file), "--out", str(out), "--runs-dir", str(tmp_path / "runs")]
    environment = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    process = subprocess.Popen(
        command, stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True, start_new_session=True, env=environment
    )
    try:
        deadline = time.monotonic() + 120.0
        while not (out / MANIFEST).exists() and time.monotonic() < deadline:
            time.sleep(0.2)
        time.sleep(3.0)  # the tare episodes under way in the workers
        os.killpg(process.pid, signal.SIGINT)
        _, errors = process.communicate(timeout=60)
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
    assert process.returncode == 130, errors
    assert "Traceback" not in errors and "KeyboardInterrupt" not in errors, errors
    assert errors.strip().splitlines()[-1] == f"python -m eval: interrupted (run folder {out}, marked interrupted)"
    assert json.loads((out / MANIFEST).read_text())["status"] == "interrupted"


@pytest.mark.parametrize("delay", [0.3, 1.0])
def test_ctrl_c_while_a_command_starts_prints_one_line(tmp_path, delay: float) -> None:
    """SIGINT while ``python -m eval.identification`` still imports its modules (or, later, runs): one line, exit code
    130, no traceback and no run folder left running."""
    out = tmp_path / "run"
    command = [sys.executable, "-m", "eval.identification", "--quick", "--out", str(out), "--runs-dir", str(tmp_path)]
    process = subprocess.Popen(command, stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True)
    try:
        time.sleep(delay)
        process.send_signal(signal.SIGINT)
        _, errors = process.communicate(timeout=60)
    finally:
        if process.poll() is None:
            process.kill()
    assert process.returncode == 130, errors
    assert "Traceback" not in errors and "KeyboardInterrupt" not in errors, errors
    assert len(errors.strip().splitlines()) == 1 and "interrupted" in errors, errors
    assert not (out / MANIFEST).exists() or json.loads((out / MANIFEST).read_text())["status"] == "interrupted"


@pytest.mark.parametrize(
    ("module", "argv", "message"),
    [
        ("eval.comparison.__main__", ["--episodes", "0"], "--episodes must be an integer >= 1, got 0"),
        ("eval.rate.__main__", ["--planners", "fastest"], "--planners"),
        ("eval.compare", ["--metrics"], "--metrics"),
    ],
)
def test_a_parser_error_is_one_line_without_the_usage(module: str, argv: list[str], message: str, capsys) -> None:
    main = importlib.import_module(module).main
    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    assert exit_info.value.code == 2
    (line,) = capsys.readouterr().err.splitlines()
    assert line.startswith("python -m eval") and ": error: " in line and message in line
    assert line.endswith("(--help lists the options)")
