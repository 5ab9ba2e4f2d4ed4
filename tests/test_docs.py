"""The documentation: the site builds with warnings as errors, the API reference covers every public name, and the
README is a guide whose Quick start runs as printed and whose links lead somewhere."""

import contextlib
import html
import importlib
import io
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
README = ROOT / "README.md"
PUBLIC_PACKAGES = ("delta_env", "controllers", "eval")
MAX_README_LINES = 400
"""Issue 35: the README is a guide of at most about 400 lines; the reference lives in docs/."""


def readme_code(section: str, language: str) -> str:
    """The ``language`` code blocks under the README's ``## section`` heading, in order, as one program."""
    text = README.read_text()
    match = re.search(rf"^## {re.escape(section)}\n(.*?)(?=^## |\Z)", text, flags=re.S | re.M)
    assert match, f"README has no section {section!r}"
    blocks = re.findall(rf"^```{language}\n(.*?)^```", match.group(1), flags=re.S | re.M)
    assert blocks, f"README section {section!r} has no {language} block"
    return "".join(blocks)


def public_anchors(package: str) -> set[str]:
    """The HTML ids of the API reference's entries of ``package.__all__``: ``package.name``, or for ``eval`` (whose
    names load from their home modules on first use) ``home_module.name``."""
    module = importlib.import_module(package)
    if package != "eval":
        return {f"{package}.{name}" for name in module.__all__}
    return {f"{getattr(module, name).__module__}.{name}" for name in module.__all__}


def only_readme(page: Path) -> bool:
    """Whether a page of the site is its home page or holds nothing but its title and sections of the README."""
    lines = [line for line in page.read_text().splitlines()[1:] if line.strip() and not line.startswith("#")]
    return page.name == "index.md" or all(line.startswith('--8<-- "README.md:') for line in lines)


@pytest.fixture(scope="module")
def site(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The site built as `make docs` builds it (``mkdocs build --strict``), into a temporary folder."""
    site_dir = tmp_path_factory.mktemp("site")
    built = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(site_dir)],
        cwd=ROOT,
        env={**os.environ, "NO_MKDOCS_2_WARNING": "1"},
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert built.returncode == 0, f"mkdocs build --strict failed:\n{built.stderr[-3000:]}"
    return site_dir


@pytest.mark.parametrize("package", PUBLIC_PACKAGES)
def test_api_reference_has_every_public_name(site: Path, package: str) -> None:
    page = (site / "api" / package / "index.html").read_text()
    ids = set(re.findall(r'id="([^"]+)"', page))
    missing = sorted(public_anchors(package) - ids)
    assert not missing, f"docs/api/{package}.md documents none of {missing}"
    roles = re.findall(r":[a-z]+:<code>[^<]*</code>", page)
    assert not roles, f"Sphinx roles printed as text (scripts/docs_sphinx_roles.py): {roles[:5]}"


def test_site_includes_the_readme_sections(site: Path) -> None:
    """The README's marked sections appear on the site's pages, resolved (no snippet marker left)."""
    pages = {
        "index.html": "run_episode(env, PDController()",
        "guide/your-controller/index.html": "ControllerEntry",
        "guide/identification/index.html": "time_s",
        "guide/run-folders/index.html": "DELTA_RUNS_DIR",
        "guide/evaluation/index.html": "Oracle+PD (bound)",
        "guide/pick-rate/index.html": "IRB 360-8/1130",
    }
    for page, text in pages.items():
        page_text = html.unescape(re.sub(r"<[^>]+>", "", (site / page).read_text()))
        assert text in page_text, f"{page} lacks {text!r}"
        assert "--8<--" not in page_text, f"{page} holds an unresolved snippet marker"


def test_readme_is_a_guide_that_links_the_docs() -> None:
    text = README.read_text()
    lines = text.count("\n")
    assert lines <= MAX_README_LINES, f"README.md has {lines} lines, more than {MAX_README_LINES}"
    targets = [target for target in re.findall(r"\]\(([^)#\s]+)[^)]*\)", text) if "://" not in target]
    broken = [target for target in targets if not (ROOT / target).exists()]
    assert not broken, f"README.md links to missing files: {broken}"
    unlinked = sorted(
        str(page.relative_to(ROOT))
        for page in (ROOT / "docs").rglob("*.md")
        if "api" not in page.parts and not only_readme(page) and str(page.relative_to(ROOT)) not in targets
    )
    assert not unlinked, f"README.md's Documentation section does not link {unlinked}"


def test_readme_quick_start_runs() -> None:
    """The Quick start, executed as printed: PD tracks the 3.8 kg and 0.5 kg carries at 5.7 mm RMS."""
    output = io.StringIO()
    with contextlib.redirect_stdout(output):
        exec(readme_code("Quick start", "python"), {"__name__": "readme_quick_start"})
    printed = re.fullmatch(r"RMS tracking error (\d+\.\d\d) mm\n", output.getvalue())
    assert printed, f"the Quick start printed {output.getvalue()!r}"
    assert 4.0 < float(printed.group(1)) < 8.0
