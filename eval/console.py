"""How every command line talks to its user: one-line errors, one-line interruptions, progress bars and counts.

:func:`command_main` wraps a command line's ``main(argv)``: a usage error (:data:`USAGE_ERRORS`: a value it cannot
use, a parameter file or a log it cannot read) raised anywhere in the run is printed as one line,
``<prog>: error: <message>``, and exits with code 2, as argparse's own errors do; Ctrl-C (or SIGTERM) prints
``<prog>: interrupted`` and exits with 130 (143). The run folder records either outcome in its manifest
(:func:`eval.run_folder.run_folder`) and the line names it. Every other exception is a bug and keeps its traceback.

:func:`progress_bar` is the progress bar of every long run: tqdm on a terminal, plain lines (no carriage returns,
one every :data:`PLAIN_PROGRESS_INTERVAL_S`) in a log file or a pipe. :func:`plural` counts things in words.
"""

from __future__ import annotations

import argparse
import functools
import re
import signal
import sys
from collections.abc import Callable, Sequence
from typing import IO, Any, NoReturn

from controllers.identification import LogFileError, ParameterFileError
from eval import _interrupted_while_starting


class CommandParser(argparse.ArgumentParser):
    """The argument parser of every command line: a usage error is one line, ``<prog>: error: <message>``, with exit
    code 2 (argparse's own parser prints its whole usage first)."""

    def error(self, message: str) -> NoReturn:
        self.exit(USAGE_EXIT_CODE, f"{self.prog}: error: {_one_line(message)} (--help lists the options)\n")


def resolved_arguments(arguments: argparse.Namespace, **values: Any) -> argparse.Namespace:
    """A new namespace: ``arguments`` with ``values`` resolved in (new names last), the parser's own left as it
    parsed the command line."""
    return argparse.Namespace(**{**vars(arguments), **values})


class Terminated(KeyboardInterrupt):
    """SIGTERM received inside :func:`eval.run_folder.run_folder` (a job scheduler, ``kill``, a container stopping):
    raised where the run is, so that it unwinds like a Ctrl-C and its manifest records it."""


class UsageError(ValueError):
    """A value given to a command line that it cannot use: the message names the option, the value and what is
    allowed. :func:`command_main` prints it as one line and exits with code 2."""


USAGE_ERRORS: tuple[type[Exception], ...] = (UsageError, ParameterFileError, LogFileError)
"""The errors :func:`command_main` reports as a user's mistake (one line, exit code 2) rather than as a bug."""

USAGE_EXIT_CODE = 2
"""Exit code of a usage error, as argparse's."""

PLAIN_PROGRESS_INTERVAL_S = 30.0
"""Seconds between two lines of a progress bar whose output is not a terminal."""

Main = Callable[[Sequence[str] | None], int]
"""A command line's ``main``: its arguments (None: ``sys.argv[1:]``) to its exit code."""


def _one_line(text: str) -> str:
    """``text`` with its line breaks as spaces."""
    return " ".join(text.split())


def _run_folder_note(error: BaseException) -> str:
    """`` (run folder ...)`` when ``error`` left a run folder behind (:func:`eval.run_folder.run_folder` notes it),
    else empty."""
    notes = [note for note in getattr(error, "__notes__", ()) if note.startswith("run folder ")]
    return f" ({notes[-1]})" if notes else ""


def command_main(prog: str) -> Callable[[Main], Main]:
    """Decorate a command line's ``main(argv) -> int`` so that a usage error or an interruption ends it with one line
    on stderr and a ``SystemExit``: code 2 for :data:`USAGE_ERRORS`, 128 + the signal's number for Ctrl-C (130) or
    SIGTERM (143).

    Args:
        prog: The command as the user types it (``python -m eval``), the start of each line.
    """

    def decorate(main: Main) -> Main:
        @functools.wraps(main)
        def run(argv: Sequence[str] | None = None) -> int:
            if signal.getsignal(signal.SIGINT) is _interrupted_while_starting:  # the package's, while importing
                signal.signal(signal.SIGINT, signal.default_int_handler)
            try:
                return main(argv)
            except USAGE_ERRORS as error:
                print(f"{prog}: error: {_one_line(str(error))}{_run_folder_note(error)}", file=sys.stderr)
                raise SystemExit(USAGE_EXIT_CODE) from None
            except KeyboardInterrupt as error:
                signum = signal.SIGTERM if isinstance(error, Terminated) else signal.SIGINT
                what = "terminated" if signum == signal.SIGTERM else "interrupted"
                print(f"{prog}: {what}{_run_folder_note(error)}", file=sys.stderr)
                raise SystemExit(128 + signum) from None

        return run

    return decorate


def plural(count: int, noun: str, nouns: str | None = None) -> str:
    """``count`` and ``noun``, the plural ``nouns`` (default ``noun + "s"``) unless ``count`` is 1: "1 episode",
    "3 episodes"."""
    return f"{count} {noun if count == 1 else (nouns or noun + 's')}"


_CURSOR_CONTROL = re.compile(r"\r|\x1b\[[0-9;]*[A-Za-z]")
"""What tqdm writes to redraw a bar in place: carriage returns and the cursor moves of nested bars."""


class _PlainLines:
    """A stream for tqdm that writes each of its updates as a line of its own (no carriage returns, no cursor
    moves, no padding)."""

    def __init__(self, stream: IO[str]) -> None:
        self.stream = stream

    def write(self, text: str) -> None:
        line = _CURSOR_CONTROL.sub("", text).rstrip()
        if line:
            self.stream.write(line + "\n")

    def flush(self) -> None:
        self.stream.flush()


def progress_bar(
    total: int | float | None = None, desc: str | None = None, unit: str = "it", *, disable: bool = False, **kwargs: Any
) -> Any:
    """A tqdm progress bar on stderr: redrawn in place on a terminal; elsewhere (a log file, a pipe) a plain line at
    most every :data:`PLAIN_PROGRESS_INTERVAL_S` and one at the end.

    Args:
        total: Items (None: unknown).
        desc: What is counted, before the bar.
        unit: Name of one item.
        disable: Show nothing.
        **kwargs: Other arguments of ``tqdm``.
    """
    from tqdm import tqdm

    stream = sys.stderr
    if not disable and not stream.isatty():
        kwargs = {"file": _PlainLines(stream), "mininterval": PLAIN_PROGRESS_INTERVAL_S, "ascii": True, **kwargs}
        kwargs.setdefault("ncols", 100)
    return tqdm(total=total, desc=desc, unit=unit, disable=disable, **kwargs)
