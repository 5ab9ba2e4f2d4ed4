"""The package's metadata: a console command for every command line, each answering ``--help``, and the license."""

import importlib
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
SCRIPTS = PROJECT["scripts"]
COMMAND_LINES = {
    "delta-eval": "eval",
    "delta-identify": "eval.identification",
    "delta-train-residual": "eval.residual",
    "delta-sweep": "eval.sweep",
    "delta-rate": "eval.rate",
    "delta-faults": "eval.faults",
    "delta-fault-soak": "eval.faults.soak",
    "delta-design": "eval.design",
    "delta-compare": "eval.compare",
}
"""Each console command and the ``python -m`` module it stands for."""


def test_every_command_line_has_a_console_command() -> None:
    assert set(SCRIPTS) == set(COMMAND_LINES)


@pytest.mark.parametrize("command", sorted(COMMAND_LINES))
def test_console_command_answers_help(command: str, capsys: pytest.CaptureFixture[str]) -> None:
    """The entry point's function is the module's ``main`` (that of its ``__main__`` for a package) and prints its
    usage under ``--help``, exiting 0."""
    module_name, function_name = SCRIPTS[command].split(":")
    assert module_name in (COMMAND_LINES[command], f"{COMMAND_LINES[command]}.__main__")
    main = getattr(importlib.import_module(module_name), function_name)
    with pytest.raises(SystemExit) as exit_info:
        main(["--help"])
    assert exit_info.value.code == 0
    assert capsys.readouterr().out.startswith(f"usage: python -m {COMMAND_LINES[command]} ")


def test_license_is_an_spdx_expression_with_its_file() -> None:
    assert PROJECT["license"] == "MIT"
    assert PROJECT["license-files"] == ["LICENSE"]
    text = (ROOT / "LICENSE").read_text()
    assert text.startswith("MIT License\n")
    assert "Copyright (c) 2026 delta-pick-place contributors" in text
