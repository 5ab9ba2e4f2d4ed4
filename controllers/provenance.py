"""What every run folder records about how it was made: the command and the package versions."""

from __future__ import annotations

import platform
import shlex
import sys
from collections.abc import Sequence
from importlib import metadata

RUN_PACKAGES = ("numpy", "scipy", "mujoco", "gymnasium", "filterpy", "matplotlib", "stable-baselines3", "torch")
"""Packages whose versions decide a run's numbers."""


def package_versions(packages: Sequence[str] = RUN_PACKAGES) -> dict[str, str]:
    """Python's and each package's version ("not installed" when absent)."""
    versions = {"python": platform.python_version()}
    for package in packages:
        try:
            versions[package] = metadata.version(package)
        except metadata.PackageNotFoundError:
            versions[package] = "not installed"
    return versions


def command_line(module: str, argv: Sequence[str] | None = None) -> str:
    """The shell command ``python -m module args`` that reproduces this run (argv defaults to sys.argv[1:])."""
    return shlex.join(["python", "-m", module, *(sys.argv[1:] if argv is None else argv)])
