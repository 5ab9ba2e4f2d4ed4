"""numba's compiled functions are cached per version of the project's sources, outside the package."""

from __future__ import annotations

from pathlib import Path

import numba
import pytest

import delta_env
from delta_env.compile_cache import PACKAGES, compile_cache_folder


def _tree(root: Path, kernel: str) -> None:
    for package in PACKAGES:
        (root / package / "sub").mkdir(parents=True)
        (root / package / "__init__.py").write_text("")
    (root / "controllers" / "sub" / "kernel.py").write_text(kernel)


def test_any_changed_source_names_another_folder(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    _tree(tmp_path / "a", "x = 1\n")
    _tree(tmp_path / "b", "x = 2\n")  # a callee changed in another module
    _tree(tmp_path / "c", "x = 1\n")
    (tmp_path / "c" / "eval" / "notes.txt").write_text("not a source")
    first, changed, same = (compile_cache_folder(tmp_path / name) for name in "abc")
    assert first != changed and first == same
    assert first.parent == tmp_path / "cache" / "delta-pickplace" / "numba"


def test_the_package_compiles_into_the_users_cache_not_into_itself() -> None:
    package = Path(delta_env.__file__).resolve().parent.parent
    folder = Path(numba.config.CACHE_DIR).resolve()
    assert numba.config.CACHE_DIR and package not in folder.parents
