"""The architecture: imports run only eval -> controllers -> delta_env, and controllers hold no experiments."""

import ast
import pkgutil
import types
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
LAYERS = ("delta_env", "controllers", "eval")
"""Packages from the lowest to the highest: a package may import only itself and those before it."""

EXPERIMENT_MODULES = ("argparse", "matplotlib", "stable_baselines3", "torch", "tqdm")
"""What ``controllers`` must not import at module level or in functions: command lines, figures, training
loops and progress bars belong to ``eval`` (SB3 and torch are loaded lazily by the policy file and the actor only)."""

LAZY_ALLOWED = {
    ("controllers/residual/policy_file.py", "stable_baselines3"),
    ("controllers/residual/policy_file.py", "torch"),
    ("controllers/residual/actor.py", "stable_baselines3"),
    ("controllers/residual/actor.py", "torch"),
}
"""(module, import) pairs allowed when deferred: loading a saved policy needs SB3, running its network torch,
taking the actor's layers from a loaded model both."""


def _type_checking_only(node: ast.AST) -> bool:
    return isinstance(node, ast.If) and isinstance(node.test, ast.Name) and node.test.id == "TYPE_CHECKING"


def imported_modules(path: Path) -> list[tuple[str, bool]]:
    """Every module ``path`` imports (absolute names), with whether it is deferred: inside a function or an
    ``if TYPE_CHECKING:`` block, so not run when the module is imported."""
    tree = ast.parse(path.read_text(), filename=str(path))
    found = []

    def visit(node: ast.AST, in_function: bool) -> None:
        for child in ast.iter_child_nodes(node):
            inside = in_function or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef))
            inside = inside or _type_checking_only(child)
            if isinstance(child, ast.Import):
                found.extend((alias.name, inside) for alias in child.names)
            elif isinstance(child, ast.ImportFrom) and child.level == 0 and child.module:
                found.append((child.module, inside))
            visit(child, inside)

    visit(tree, False)
    return found


def modules_of(package: str) -> list[Path]:
    return sorted((ROOT / package).rglob("*.py"))


@pytest.mark.parametrize("package", LAYERS)
def test_every_package_imports_only_itself_and_the_layers_below(package: str) -> None:
    forbidden = LAYERS[LAYERS.index(package) + 1 :]
    offenders = [
        f"{path.relative_to(ROOT)} imports {name}"
        for path in modules_of(package)
        for name, _ in imported_modules(path)
        if name.split(".")[0] in forbidden
    ]
    assert modules_of(package), f"no modules found in {package}"
    assert offenders == []


def test_controllers_hold_algorithms_not_experiments() -> None:
    offenders = []
    for path in modules_of("controllers"):
        relative = path.relative_to(ROOT).as_posix()
        for name, in_function in imported_modules(path):
            top = name.split(".")[0]
            if top in EXPERIMENT_MODULES and not (in_function and (relative, top) in LAZY_ALLOWED):
                offenders.append(f"{relative} imports {name}")
    assert offenders == []


ENGINE_MODULES = ("eval/engine.py", "eval/work.py", "eval/processes.py", "eval/calibration.py")
"""The experiment engine: what it knows before the episodes, the work unit and its runner, the executor, the tare."""


def test_eval_imports_its_own_modules_at_the_top() -> None:
    # a deferred import inside eval hides a dependency that runs back up (the engine calling into a command)
    offenders = [
        f"{path.relative_to(ROOT)} imports {name} in a function"
        for path in modules_of("eval")
        for name, deferred in imported_modules(path)
        if deferred and name.split(".")[0] == "eval"
    ]
    assert offenders == []


def test_the_engine_imports_no_command_built_on_it() -> None:
    # the sweep, the comparison and the other experiments sit on top of the engine, never below it
    offenders = [
        f"{module} imports {name}"
        for module in ENGINE_MODULES
        for name, _ in imported_modules(ROOT / module)
        if name.startswith(
            (
                "eval.sweep",
                "eval.comparison.run",
                "eval.rate.__main__",
                "eval.design",
                "eval.residual.scoring",
                "eval.comparison.__main__",
            )
        )
    ]
    assert offenders == []


def test_the_scan_sees_imports_everywhere(tmp_path: Path) -> None:
    module = tmp_path / "sample.py"
    module.write_text(
        "import a.b\nfrom c import d\n\ndef f():\n    from eval import x\n\nclass K:\n    import e\n"
        "if TYPE_CHECKING:\n    import torch\n"
    )
    expected = [("a.b", False), ("c", False), ("eval", True), ("e", False), ("torch", True)]
    assert imported_modules(module) == expected


def test_the_eval_package_exports_functions_not_its_modules() -> None:
    # The names load on first use (python -m eval starts its worker server first); importing a submodule binds its
    # name on the package, so no export may share a submodule's name.
    import eval

    submodules = {module.name for module in pkgutil.iter_modules(eval.__path__)}
    assert submodules.isdisjoint(eval.__all__)
    for name in eval.__all__:
        value = getattr(eval, name)
        assert callable(value) and not isinstance(value, types.ModuleType), name
        assert value.__name__ == name and name in dir(eval)
