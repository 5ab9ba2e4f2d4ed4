"""Progress of a long command on the console: a tqdm bar on a terminal, plain lines in a log file.

A bar redraws itself with carriage returns, which fill a log file; when the stream is not a terminal,
:func:`progress_bar` prints one line at every tenth of the work instead.
"""

from __future__ import annotations

import sys
from types import TracebackType
from typing import Any, TextIO

PLAIN_STEPS = 10
"""Lines a :class:`PlainProgress` prints over its whole total (one per tenth), besides its last."""


class PlainProgress:
    """Progress as plain lines: ``<desc>: <done>/<total> <unit>`` at every tenth of ``total`` and at the end.

    Args:
        total: Items of work (>= 0).
        desc: What the work is.
        unit: Name of one item.
        stream: Where the lines go.
    """

    def __init__(self, total: int, desc: str, unit: str, stream: TextIO) -> None:
        self.total, self.desc, self.unit, self.stream = total, desc, unit, stream
        self.done = 0
        self._printed = 0

    def update(self, n: int = 1) -> None:
        """``n`` more items done: a line when another tenth of the total is reached."""
        if n <= 0:
            return
        self.done += n
        step = PLAIN_STEPS * self.done // self.total if self.total else PLAIN_STEPS
        if step > self._printed:
            self._printed = step
            print(f"{self.desc}: {self.done}/{self.total} {self.unit}", file=self.stream, flush=True)

    def close(self) -> None:
        """Nothing to clear: the lines stay."""

    def __enter__(self) -> PlainProgress:
        return self

    def __exit__(
        self, kind: type[BaseException] | None, error: BaseException | None, traceback: TracebackType | None
    ) -> None:
        self.close()


def progress_bar(total: int, desc: str, unit: str, stream: TextIO | None = None) -> Any:
    """A tqdm bar of ``total`` items on ``stream`` (default standard error) if it is a terminal, else a
    :class:`PlainProgress`; both are context managers with ``update(n=1)``."""
    stream = sys.stderr if stream is None else stream
    if stream.isatty():
        from tqdm.auto import tqdm

        return tqdm(total=total, desc=desc, unit=unit, file=stream)
    return PlainProgress(total, desc, unit, stream)
