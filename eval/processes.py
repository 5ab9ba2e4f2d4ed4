"""The experiments' one executor (:func:`run_jobs`): a picklable function mapped over items on a local process pool,
safe next to torch, or on Ray.

Every parallel run of the project goes through it: the episodes of the experiment engine (:func:`eval.work.run_grid`:
the comparison, the tare calibration, the sweep, the pick-rate study, the residual scores, the design verification),
the identification's excitation runs and log smoothing (:mod:`eval.identification.run`,
:mod:`eval.identification.excitation`), the design front's optimizer runs (:mod:`eval.design.front`) and the videos
(:mod:`eval.comparison.video`).

Backends:

- ``local``: a process pool of ``workers`` processes on this machine (forkserver or spawn, never fork: torch may be
  loaded; :func:`pool_context`), or this process itself when ``workers`` is 1 or there is one item. At most
  ``workers`` items are in flight, so when a worker dies (the pool breaks) the items it may have held are known and
  resubmitted on a new pool, up to ``max_attempts`` times each.
- ``ray``: Ray tasks; Ray resubmits a task whose worker died (``max_retries``). Without an address Ray starts in this
  process with ``workers`` CPUs; with one (``auto`` or ``ray://host:port``) it joins the cluster and ships this
  checkout's packages to it (``runtime_env`` ``py_modules``).

This module imports nothing of the project at its top, so that a command line can start the worker server
(:func:`start_worker_server`) before it imports the experiments.
"""

from __future__ import annotations

import concurrent.futures
import contextlib
import multiprocessing
import os
import signal
import threading
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures.process import BrokenProcessPool
from multiprocessing.context import BaseContext
from pathlib import Path
from typing import Any, TypeVar

_Item = TypeVar("_Item")
_Output = TypeVar("_Output")

DEFAULT_WORKERS = min(2, os.cpu_count() or 1)
"""Worker processes of a command line unless ``--workers`` says otherwise: up to 2."""

BACKENDS = ("local", "ray")
"""Where :func:`run_jobs` runs: a local process pool, or Ray."""

DEFAULT_MAX_ATTEMPTS = 3
"""Runs of an item whose worker died before it is given up (:func:`run_jobs`'s ``on_lost``)."""

PROJECT_PACKAGES = ("controllers", "delta_env", "eval")
"""The project's packages, shipped to a Ray cluster that :func:`run_jobs` joins."""

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


OnResult = Callable[[int, Any], None]
"""Told the index of an item and its output, as each finishes."""
OnLost = Callable[[int, str], Any]
"""Told the index of an item whose worker died too often and why; returns the output recorded in its place (or
raises)."""


def run_jobs(
    function: Callable[[_Item], _Output],
    items: Sequence[_Item],
    *,
    backend: str = "local",
    workers: int = 1,
    address: str | None = None,
    progress: Any = None,
    on_result: OnResult | None = None,
    on_lost: OnLost | None = None,
    max_attempts: int = DEFAULT_MAX_ATTEMPTS,
    ray_folders: Sequence[str] = (),
    keep: bool = True,
) -> list[_Output] | None:
    """``[function(item) for item in items]``, in the order of ``items``, on ``backend`` (see the module's docstring).

    Args:
        function: A picklable function of one item (any callable when it runs in this process).
        items: The work, each picklable.
        backend: One of :data:`BACKENDS`.
        workers: Local processes (this process if 1), or the CPUs of a Ray started here; >= 1.
        address: Ray cluster to join (``"auto"``, ``"ray://host:port"``; ``ray`` only).
        progress: A tqdm bar advanced once per finished item, or None.
        on_result: Called with each item's index and output as it finishes, in the order they finish (a long run
            writes them as they come, so an interruption loses only the items still running).
        on_lost: Gives the output of an item whose worker died ``max_attempts`` times; None raises a RuntimeError.
        max_attempts: Runs of an item whose worker died, >= 1.
        ray_folders: More package folders to ship to a joined Ray cluster (a user's controllers).
        keep: Return the outputs; False keeps none of them and returns None (a long run that hands each to
            ``on_result`` holds no more than the items in flight).

    Raises:
        ValueError: for an unknown backend, an address without Ray, or workers or max_attempts below 1.
        The error of ``function`` on an item, as it raised it.
    """
    from delta_env.validation import require_count  # not at the top: see the module's docstring

    if backend not in BACKENDS:
        raise ValueError(f"backend must be one of {BACKENDS}, got {backend!r}")
    if address is not None and backend != "ray":
        raise ValueError(f"address is for the ray backend only, got {address!r} with {backend!r}")
    require_count("workers", workers)
    require_count("max_attempts", max_attempts)
    outputs: list[Any] | None = [None] * len(items) if keep else None

    def finished(index: int, output: Any) -> None:
        if outputs is not None:
            outputs[index] = output
        if on_result is not None:
            on_result(index, output)
        if progress is not None:
            progress.update()

    def lost(index: int, error: str) -> None:
        if on_lost is None:
            raise RuntimeError(f"item {index} of {len(items)} was not run: {error}")
        finished(index, on_lost(index, error))

    if not items:  # nothing to run: no pool, and Ray is not needed
        return outputs
    if backend == "ray":
        _run_ray(function, items, workers, address, max_attempts, ray_folders, finished, lost)
    elif workers == 1 or len(items) <= 1:
        for index, item in enumerate(items):
            finished(index, function(item))
    else:
        _run_local(function, items, min(workers, len(items)), max_attempts, finished, lost)
    return outputs


def _run_local(
    function: Callable[[Any], Any],
    items: Sequence[Any],
    workers: int,
    max_attempts: int,
    finished: OnResult,
    lost: Callable[[int, str], None],
) -> None:
    """Run ``items`` on a local pool of ``workers`` processes, at most ``workers`` in flight, in any order."""
    queue = list(reversed(range(len(items))))
    attempts = [0] * len(items)

    def retry_or_lose(index: int) -> None:
        if attempts[index] < max_attempts:
            queue.append(index)
        else:
            lost(index, f"its worker died on each of its {attempts[index]} attempts")

    while queue:
        with concurrent.futures.ProcessPoolExecutor(
            workers, mp_context=pool_context(), initializer=ignore_interrupts
        ) as pool:
            running: dict[concurrent.futures.Future, int] = {}
            broken = False
            try:
                while (queue or running) and not broken:
                    with holding_interrupts():  # a submit may start a worker
                        while queue and len(running) < workers:
                            index = queue.pop()
                            attempts[index] += 1
                            running[pool.submit(function, items[index])] = index
                    done, _ = concurrent.futures.wait(running, return_when=concurrent.futures.FIRST_COMPLETED)
                    for future in done:
                        index = running.pop(future)
                        try:
                            output = future.result()
                        except BrokenProcessPool:
                            broken = True
                            retry_or_lose(index)
                        else:
                            finished(index, output)
            except BaseException:
                # Ctrl-C, SIGTERM or an error: stop the work under way, which the executor would wait for
                # (it has no public way to stop its workers before Python 3.14's terminate_workers).
                for process in list(pool._processes.values()):
                    process.terminate()
                pool.shutdown(wait=False, cancel_futures=True)
                raise
            if broken:  # the other items in flight died with the pool, unless they had finished
                for future, index in running.items():
                    died = future.cancelled() or not future.done() or isinstance(future.exception(), BrokenProcessPool)
                    if died:
                        retry_or_lose(index)
                    else:
                        finished(index, future.result())  # an item's own error is raised, not retried


def _run_ray(
    function: Callable[[Any], Any],
    items: Sequence[Any],
    workers: int,
    address: str | None,
    max_attempts: int,
    ray_folders: Sequence[str],
    finished: OnResult,
    lost: Callable[[int, str], None],
) -> None:
    """Run ``items`` as Ray tasks, in any order: on a Ray started here with ``workers`` CPUs, or on the cluster at
    ``address``."""
    ray = import_ray()
    started_here = not ray.is_initialized()
    if started_here:
        # ray.init installs its own SIGTERM handler (sys.exit); the run folder's records the run as interrupted
        handler = signal.getsignal(signal.SIGTERM)
        if address is None:
            # "local": a new instance even when the machine runs (or ran) another cluster.
            ray.init(address="local", num_cpus=workers, include_dashboard=False, log_to_driver=False)
        else:
            root = Path(__file__).resolve().parents[1]
            folders = [str(root / package) for package in PROJECT_PACKAGES] + list(ray_folders)
            ray.init(address=address, runtime_env={"py_modules": folders}, log_to_driver=False)
        if handler is not None and threading.current_thread() is threading.main_thread():
            signal.signal(signal.SIGTERM, handler)
    try:
        # a Ray task is a plain function: the mapped one (a partial, say) goes to the cluster once, as an argument
        remote = ray.remote(num_cpus=1, max_retries=max_attempts - 1)(_apply)
        function_ref = ray.put(function)
        window = 4 * max(1, int(ray.cluster_resources().get("CPU", workers)))
        queue = list(reversed(range(len(items))))
        running: dict[Any, int] = {}
        while queue or running:
            while queue and len(running) < window:
                index = queue.pop()
                running[remote.remote(function_ref, items[index])] = index
            done, _ = ray.wait(list(running), num_returns=1)
            for ref in done:
                index = running.pop(ref)
                try:
                    output = ray.get(ref)
                except ray.exceptions.RayTaskError:  # the function raised: the caller's error
                    raise
                except ray.exceptions.RayError as error:  # the worker died max_attempts times, or Ray failed
                    lost(index, f"{type(error).__name__}: {error}")
                else:
                    finished(index, output)
    finally:
        if started_here:
            ray.shutdown()


def _apply(function: Callable[[Any], Any], item: Any) -> Any:
    """``function(item)``: the Ray task of :func:`run_jobs`."""
    return function(item)


def import_ray() -> Any:
    """The ``ray`` module, or an ImportError naming the extra that installs it."""
    try:
        import ray
    except ImportError:
        raise ImportError(
            "--backend ray needs Ray: install the 'distributed' extra (pip install '.[distributed]')"
        ) from None
    return ray
