"""Where numba keeps the project's compiled functions: a folder of the user's cache named by a hash of the project's
sources (:func:`compile_cache_folder`), set on import, before any of them is compiled (``delta_env`` imports this
module first).

numba's own cache (``cache=True``) lives beside each module, in the package, and checks only the source file of the
function it loads, not those of the functions that function calls: a changed kernel in one module left the cached
callers in another running the old one. A folder per version of the sources compiles every changed function afresh
and writes nothing into the installed package. ``NUMBA_CACHE_DIR``, if set, wins.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

import numba

PACKAGES = ("delta_env", "controllers", "eval")
"""The packages whose sources name the folder: every one that compiles functions, or calls compiled ones."""


PROJECT_ROOT = Path(__file__).resolve().parent.parent
"""The folder that holds :data:`PACKAGES`."""


def compile_cache_folder(root: Path = PROJECT_ROOT) -> Path:
    """``$XDG_CACHE_HOME/delta-pickplace/numba/<hash>`` (``~/.cache`` without XDG_CACHE_HOME), the hash of every
    ``.py`` file of :data:`PACKAGES` under ``root`` (its path there and its bytes)."""
    digest = hashlib.sha256()
    for package in PACKAGES:
        for path in sorted((root / package).rglob("*.py")):
            digest.update(path.relative_to(root).as_posix().encode())
            digest.update(path.read_bytes())
    base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return base / "delta-pickplace" / "numba" / digest.hexdigest()[:16]


def use_compile_cache() -> None:
    """Point numba's cache at :func:`compile_cache_folder`, unless ``NUMBA_CACHE_DIR`` names one."""
    if not os.environ.get("NUMBA_CACHE_DIR"):
        folder = str(compile_cache_folder())
        os.environ["NUMBA_CACHE_DIR"] = folder  # worker processes, which import numba afresh
        numba.config.CACHE_DIR = folder  # this process, whose numba may have read the environment already


use_compile_cache()
