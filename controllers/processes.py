"""Process pools that are safe next to torch (identification, evaluation)."""

from __future__ import annotations

import multiprocessing
from multiprocessing.context import BaseContext


def pool_context() -> BaseContext:
    """forkserver where available, else spawn; never fork.

    A forked child of a process that has loaded torch (the residual policy, the training CLI) can deadlock
    in torch's thread pool. Forkserver and spawn children start clean and import what their work needs.
    """
    methods = multiprocessing.get_all_start_methods()
    return multiprocessing.get_context("forkserver" if "forkserver" in methods else "spawn")
