"""Thin command lines: each resolves its parsed arguments into one frozen configuration, leaves the parser's namespace
as parsed, passes the configuration down and records it in the run's manifest as it was built."""

from __future__ import annotations

import copy
import dataclasses
import importlib
import json
from pathlib import Path
from typing import Any

import pytest

from delta_env.scenario import preset
from eval.run_folder import MANIFEST, configuration_record, json_ready

RESOLVED = [
    # module, argv, a field that resolving changes from its parsed value
    ("eval.comparison.__main__", ["--controllers", "pd", "--episodes", "2"], "cycles"),
    ("eval.rate.__main__", ["--quick"], "episodes"),
    ("eval.sweep.__main__", ["--episodes", "2"], "out"),
    ("eval.identification.__main__", ["--quick"], "trajectories"),
    ("eval.identification.__main__", ["--log", "a.csv", "b.csv", "--robot", "r.toml"], "log"),
    ("eval.design.__main__", ["--quick", "--screw-settings", "7"], "population"),
    ("eval.compare", ["a", "b", "--metrics", "tracking_rms_mm"], "metrics"),
    ("eval.residual.__main__", ["--mix", "nominal", "--hyperparams", "gamma:0.9"], "cycles"),
    ("eval.faults.__main__", ["--kinds", "slip,collision", "--reactions", "slow,stop"], "reactions"),
    ("eval.faults.soak", ["--conditions", "6g,3g,6g"], "conditions"),
]


def command_line_module(name: str) -> Any:
    if name == "eval.residual.__main__":
        pytest.importorskip("stable_baselines3", reason="needs the rl extra (stable-baselines3)")
    return importlib.import_module(name)


@pytest.mark.parametrize(("module", "argv", "resolved"), RESOLVED)
def test_each_command_line_resolves_a_frozen_configuration_and_leaves_the_namespace_as_parsed(
    module: str, argv: list[str], resolved: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("DELTA_RUNS_DIR", str(tmp_path))
    cli = command_line_module(module)
    parser = cli.argument_parser()
    arguments = parser.parse_args(argv)
    parsed = copy.deepcopy(vars(arguments))
    config = cli.resolve(arguments) if module == "eval.compare" else cli.resolve(arguments, parser)
    assert vars(arguments) == parsed, "the parser's namespace is left as it parsed the command line"
    assert getattr(config, resolved) != parsed[resolved], f"{resolved} is resolved into the configuration"
    assert dataclasses.is_dataclass(config)
    with pytest.raises(dataclasses.FrozenInstanceError):
        setattr(config, resolved, parsed[resolved])
    assert cli.parse_args(argv) == config, "parse_args is the parser and resolve, nothing more"


RECORDED = [
    # module, the function the main hands its configuration to ([module:]name), argv; the manifest's entry holding
    # the configuration
    ("eval.comparison.__main__", "compare", ["--controllers", "pd", "--episodes", "2"], "arguments"),
    ("eval.rate.__main__", "rate", ["--quick"], "arguments"),
    ("eval.sweep.__main__", "sweep", ["--episodes", "2"], "arguments"),
    ("eval.identification.__main__", "identify_into", ["--quick"], None),
    ("eval.design.__main__", "study", ["--quick", "--no-verify"], "arguments"),
    ("eval.faults.__main__", "campaign", ["--kinds", "slip", "--episodes", "1"], None),
    (
        "eval.residual.__main__",
        "eval.residual.training:_train",
        ["--cycles", "1", "--hyperparams", "gamma:0.9"],
        "arguments",
    ),
]


@pytest.mark.parametrize(("module", "work", "argv", "entry"), RECORDED)
def test_each_command_line_records_its_configuration_as_built_and_hands_it_down(
    module: str, work: str, argv: list[str], entry: str | None, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("DELTA_RUNS_DIR", str(tmp_path / "runs"))
    cli = command_line_module(module)
    handed = []

    def record(config: Any, run: Any, *rest: Any) -> str:
        handed.append((config, run.folder))
        return ""

    home, _, name = work.rpartition(":")
    monkeypatch.setattr(importlib.import_module(home) if home else cli, name, record)
    out = tmp_path / "run"
    assert cli.main([*argv, "--out", str(out)]) == 0
    ((config, folder),) = handed
    assert folder == out
    manifest = json.loads((out / MANIFEST).read_text())
    assert manifest["status"] == "finished"
    recorded = manifest["config"] if entry is None else manifest["config"][entry]
    assert recorded == json.loads(json.dumps(json_ready(configuration_record(config))))


@dataclasses.dataclass(frozen=True)
class _Settings:
    limit: float


@dataclasses.dataclass(frozen=True)
class _Config:
    scenario: Any
    mixture: tuple[Any, ...]
    settings: _Settings
    empty: tuple[Any, ...]
    out: Path | None


def test_the_record_names_the_scenarios_and_tables_a_settings_record() -> None:
    nominal, worn = preset("nominal"), preset("worn")
    config = _Config(nominal, (nominal, worn), _Settings(2.5), (), Path("run"))
    assert configuration_record(config) == {
        "scenario": "nominal",
        "mixture": ["nominal", "worn"],
        "settings": {"limit": 2.5},
        "empty": (),
        "out": Path("run"),
    }
