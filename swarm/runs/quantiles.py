"""Percentiles of a long series of durations in constant memory, for the processes' summaries.

A process that keeps every tick's duration grows by its count: 100 per second per agent, an
hour's flight 360,000 floats per agent and eight times that in the world. :class:`Quantiles`
counts values in log-spaced bins instead, so a percentile comes back within half a bin's ratio
of the exact one (about 1.2 % at 100 bins per decade); the count, the smallest and the largest
are exact.
"""

from __future__ import annotations

import math

import numpy as np

from swarm.errors import InputError


class Quantiles:
    """Counts of values in ``per_decade`` log-spaced bins per decade from ``lo`` to ``hi`` (a
    value below ``lo``, zero or negative included, counts in the lowest bin; above ``hi``, in the
    highest). :meth:`percentile` gives a bin's geometric centre, clipped to the exact range."""

    def __init__(self, lo: float = 1e-7, hi: float = 1e3, per_decade: int = 100) -> None:
        if not (0.0 < lo < hi) or per_decade < 1:
            raise InputError(f"Quantiles: need 0 < lo < hi and per_decade >= 1, got {lo}, {hi}, {per_decade}")
        self.lo, self.per_decade = lo, per_decade
        self._log_lo = math.log10(lo)
        self._n_bins = math.ceil((math.log10(hi) - self._log_lo) * per_decade) + 1
        self._counts = np.zeros(self._n_bins, dtype=np.int64)
        self.count = 0
        self.min = math.inf
        self.max = -math.inf

    def add(self, x: float) -> None:
        """Count one value (not finite: refused)."""
        if not math.isfinite(x):
            raise InputError(f"Quantiles.add: {x!r} is not finite")
        i = int((math.log10(x) - self._log_lo) * self.per_decade) if x > self.lo else 0
        self._counts[min(i, self._n_bins - 1)] += 1
        self.count += 1
        self.min = min(self.min, x)
        self.max = max(self.max, x)

    def merge(self, other: Quantiles) -> None:
        """Add ``other``'s counts (built with the same bins)."""
        if (other.lo, other.per_decade, other._n_bins) != (self.lo, self.per_decade, self._n_bins):
            raise InputError("Quantiles.merge: the bins differ")
        self._counts += other._counts
        self.count += other.count
        self.min, self.max = min(self.min, other.min), max(self.max, other.max)

    def percentile(self, q: float) -> float | None:
        """The ``q``-th percentile (0-100) within half a bin's ratio; None with no value."""
        if not self.count:
            return None
        if not 0.0 <= q <= 100.0:
            raise InputError(f"Quantiles.percentile: q must be in [0, 100], got {q}")
        rank = max(1, math.ceil(q / 100.0 * self.count))
        i = int(np.searchsorted(np.cumsum(self._counts), rank))
        centre = 10.0 ** (self._log_lo + (i + 0.5) / self.per_decade)
        return min(max(centre, self.min), self.max)
