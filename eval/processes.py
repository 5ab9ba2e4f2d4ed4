"""Process pools for the experiments, safe next to torch."""

from __future__ import annotations

import contextlib
import multiprocessing
from collections.abc import Callable, Sequence
from multiprocessing.context import BaseContext
from typing import Any, TypeVar

from delta_env.validation import require_count

_Item = TypeVar("_Item")
_Output = TypeVar("_Output")


def pool_context() -> BaseContext:
    """forkserver where available, else spawn; never fork.

    A forked child of a process that has loaded torch (the residual policy, the training CLI) can deadlock
    in torch's thread pool. Forkserver and spawn children start clean and import what their work needs.
    """
    methods = multiprocessing.get_all_start_methods()
    return multiprocessing.get_context("forkserver" if "forkserver" in methods else "spawn")


def parallel_map(
    function: Callable[[_Item], _Output], items: Sequence[_Item], workers: int, progress: Any = None
) -> list[_Output]:
    """``[function(item) for item in items]`` in order, on ``workers`` processes (in this one if 1).

    Args:
        function: A picklable function of one item.
        items: The work.
        workers: Processes, >= 1.
        progress: A tqdm bar advanced once per finished item, or None.
    """
    require_count("workers", workers)
    results = []
    with contextlib.ExitStack() as stack:
        if workers == 1 or len(items) <= 1:
            outputs = map(function, items)
        else:
            outputs = stack.enter_context(pool_context().Pool(min(workers, len(items)))).imap(function, items)
        for output in outputs:
            results.append(output)
            if progress is not None:
                progress.update()
    return results
