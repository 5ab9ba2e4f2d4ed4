"""Process pools for the experiments, safe next to torch.

This module imports nothing of the project at its top, so that a command line can start the worker server
(:func:`start_worker_server`) before it imports the experiments.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import signal
import threading
from collections.abc import Callable, Iterator, Sequence
from multiprocessing.context import BaseContext
from multiprocessing.pool import Pool
from typing import Any, TypeVar

_Item = TypeVar("_Item")
_Output = TypeVar("_Output")

DEFAULT_WORKERS = min(2, os.cpu_count() or 1)
"""Worker processes of a command line unless ``--workers`` says otherwise: up to 2."""

WORKER_MODULES = ("eval.worker_start",)
"""Modules the forkserver imports once before it forks any worker (:mod:`eval.worker_start`: what every worker of the
experiments needs, and numba's compiler context loaded): a fork inherits them instead of importing them again. None
of them imports torch; a worker that runs a residual policy whose actor is not SAC's plain MLP imports it itself
(:func:`controllers.residual.load_residual_policy`)."""


def ignore_interrupts() -> None:
    """The initializer of every worker process: Ctrl-C (SIGINT, sent to the whole process group) is the parent's to
    handle, which stops its workers as it leaves; a worker that raised ``KeyboardInterrupt`` itself would print its
    own traceback, and a ``multiprocessing.Pool`` would wait for the task it lost."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


@contextlib.contextmanager
def holding_interrupts() -> Iterator[None]:
    """Hold Ctrl-C (SIGINT) back while workers start, and deliver it on leaving (to the handler in place before): a
    worker forked while its parent unwinds would find the parent's pipes and semaphores gone and print a traceback.
    Only in the main thread, where Python runs its signal handlers; elsewhere nothing is held."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    held: list[int] = []
    previous = signal.signal(signal.SIGINT, lambda signum, frame: held.append(signum))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
        if held:
            signal.raise_signal(signal.SIGINT)


def start_pool(stack: contextlib.ExitStack, workers: int) -> Pool:
    """A pool of ``workers`` processes (:func:`pool_context`, Ctrl-C left to this process: :func:`ignore_interrupts`)
    entered on ``stack``, started with Ctrl-C held back (:func:`holding_interrupts`): one that came meanwhile is raised
    once the pool is on the stack, which terminates it."""
    with holding_interrupts():
        return stack.enter_context(pool_context().Pool(workers, ignore_interrupts))


def runs_a_pool(argv: Sequence[str]) -> bool:
    """Whether a command line with the arguments ``argv`` will start a pool: it does not ask for help and its
    ``--workers`` (the last one given, else :data:`DEFAULT_WORKERS`) is above 1. Read before the parser exists,
    so a malformed value says False and the parser reports it."""
    if "-h" in argv or "--help" in argv:
        return False
    workers = str(DEFAULT_WORKERS)
    for index, argument in enumerate(argv):
        if argument == "--workers" and index + 1 < len(argv):
            workers = argv[index + 1]
        elif argument.startswith("--workers="):
            workers = argument.removeprefix("--workers=")
    return workers.isdigit() and int(workers) > 1


def start_worker_server() -> None:
    """Start the forkserver of :func:`pool_context` now, in the background: it imports :data:`WORKER_MODULES` (about
    as long as a command line's own imports) while the caller imports its own, instead of after them when the
    first pool starts. Nothing happens where the start method is spawn."""
    context = pool_context()
    if context.get_start_method() == "forkserver":
        from multiprocessing import forkserver

        forkserver.ensure_running()


def pool_context() -> BaseContext:
    """forkserver where available (with :data:`WORKER_MODULES` preloaded), else spawn; never fork.

    A forked child of a process that has loaded torch (the residual policy, the training CLI) can deadlock
    in torch's thread pool. Forkserver and spawn children start clean and import what their work needs.
    """
    methods = multiprocessing.get_all_start_methods()
    if "forkserver" not in methods:
        return multiprocessing.get_context("spawn")
    context = multiprocessing.get_context("forkserver")
    context.set_forkserver_preload(list(WORKER_MODULES))  # takes effect when the forkserver starts
    return context


@contextlib.contextmanager
def process_pool(workers: int) -> Iterator[Pool | None]:
    """A pool of ``workers`` processes for several :func:`parallel_map` calls in a row; None for one worker.

    One pool for dependent batches of work (the tare episodes, then the episodes that need the tares)
    starts its workers once.
    """
    from delta_env.validation import require_count  # not at the top: see the module's docstring

    require_count("workers", workers)
    if workers == 1:
        yield None
        return
    with contextlib.ExitStack() as stack:
        yield start_pool(stack, workers)


def parallel_imap(function: Callable[[_Item], _Output], items: Sequence[_Item], pool: Pool | None) -> Iterator[_Output]:
    """``function(item)`` for each of ``items``, in order, as the caller asks for them.

    On ``pool`` every item is queued at once, so the workers keep busy while the caller works on the first
    results, and work given to the pool afterwards queues behind these items (no barrier between dependent
    batches); without a pool, each item runs in this process when its result is asked for.
    """
    return map(function, items) if pool is None else pool.imap(function, items)


def parallel_map(
    function: Callable[[_Item], _Output],
    items: Sequence[_Item],
    workers: int,
    progress: Any = None,
    pool: Pool | None = None,
) -> list[_Output]:
    """``[function(item) for item in items]`` in order, on ``workers`` processes (in this one if 1).

    Args:
        function: A picklable function of one item.
        items: The work.
        workers: Processes, >= 1; ignored when ``pool`` is given.
        progress: A tqdm bar advanced once per finished item, or None.
        pool: A running pool of :func:`process_pool` to use instead of a new one.
    """
    from delta_env.validation import require_count  # not at the top: see the module's docstring

    require_count("workers", workers)
    results = []
    with contextlib.ExitStack() as stack:
        if pool is not None and len(items) > 1:
            outputs = pool.imap(function, items)
        elif workers == 1 or len(items) <= 1 or pool is not None:
            outputs = map(function, items)
        else:
            outputs = start_pool(stack, min(workers, len(items))).imap(function, items)
        for output in outputs:
            results.append(output)
            if progress is not None:
                progress.update()
    return results
