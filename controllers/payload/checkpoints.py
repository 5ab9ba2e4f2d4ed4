"""The payload estimator's checkpoint ring: the state before each of its last updates, so that updates found faulty
late can be undone (``PayloadEstimator.rollback``, the fault monitor's reactions)."""

from __future__ import annotations

import numpy as np

from controllers.estimation import PayloadRLS
from controllers.payload.fit import CorrectionFit


class CheckpointRing:
    """The correction fit's record and the RLS state (x, P) saved before each of the last ``size`` updates.

    Args:
        size: Updates kept, >= 1.
        fit: The fit whose record is saved (for its size).

    Attributes:
        size: Updates kept.
        reach: How many of them a rollback may still undo: the saves since the last :meth:`forget`, at most ``size``
            (less after a rollback).
    """

    def __init__(self, size: int, fit: CorrectionFit) -> None:
        if isinstance(size, bool) or not isinstance(size, int) or size < 1:
            raise ValueError(f"size must be an integer >= 1 update, got {size!r}")
        self.size = size
        self._fits = np.zeros((size, fit.state.size), np.uint8)
        self._rls = [(0.0, 0.0)] * size
        self._next = 0  # the slot of the next save
        self.reach = 0

    def save(self, fit: CorrectionFit, rls: PayloadRLS) -> None:
        """Save the state before an update into the next slot."""
        slot = self._next
        self._fits[slot] = fit.state
        self._rls[slot] = (rls.x, rls.P)
        self._next = slot + 1 if slot + 1 < self.size else 0
        if self.reach < self.size:
            self.reach += 1

    def restore_fit(self, fit: CorrectionFit) -> None:
        """Put the fit back as it was at the last save (before the update since, which is left out)."""
        fit.state[:] = self._fits[self._next - 1]

    def rollback(self, samples: int, fit: CorrectionFit, rls: PayloadRLS) -> None:
        """Restore the state of ``samples`` saves ago (1 to ``size``), or of the oldest within :attr:`reach`;
        nothing if the reach is 0."""
        if not 1 <= samples <= self.size:
            raise ValueError(f"samples must be in [1, {self.size}] (the checkpoints kept), got {samples!r}")
        samples = min(samples, self.reach)
        if samples == 0:
            return
        self.reach -= samples
        slot = (self._next - samples) % self.size
        fit.state[:] = self._fits[slot]
        rls.x, rls.P = self._rls[slot]

    def forget(self) -> None:
        """No rollback reaches behind this point (a pick, a release, a new episode)."""
        self.reach = 0
