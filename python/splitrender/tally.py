"""The measurements of a long run in bounded memory: :class:`Tally`.

A live session or a headset's display loop runs for hours: per-frame lists of render times,
ages and targets grew with it (120 display frames a second: gigabytes a day). A :class:`Tally`
keeps one quantity's count, minimum and maximum exactly, its values exactly up to
:data:`EXACT` of them (the percentiles are numpy's then, ``method="linear"``), and a histogram
of every value in bins :data:`BINS_PER_OCTAVE` to the octave, from which the percentiles come
beyond that, within :data:`RELATIVE_ERROR` of the value. The histogram has at most a bin per
occupied bin width between ``2**MIN_EXPONENT`` and ``2**MAX_EXPONENT`` (values beyond those
share the end bins; the exact minimum and maximum stay), whatever the values.
"""

from __future__ import annotations

import math
from array import array

import numpy as np

__all__ = ["BINS_PER_OCTAVE", "EXACT", "RELATIVE_ERROR", "Tally"]

#: Values a :class:`Tally` keeps one by one (about 9 minutes of display frames at 120 Hz,
#: 1.8 hours of server frames at 10 FPS): 512 KiB of doubles.
EXACT = 65536

#: Histogram bins per octave (factor of two) of the absolute value: a bin spans 1/512 of the
#: octave's lower end at most, so its middle is within :data:`RELATIVE_ERROR` of each value in it.
BINS_PER_OCTAVE = 512

#: The most a percentile from the histogram differs from the exact one, relative to it (half a
#: bin; plus the interpolation between two neighbouring ranks, which stays between them).
RELATIVE_ERROR = 1.0 / (2 * BINS_PER_OCTAVE)

#: Smallest and largest binary exponents the histogram tells apart (about 1e-9 to 1.8e19: times
#: in ms, rates in Mb/s and sizes in bytes fit); a hostile peer's values cannot spread it over
#: more than ``(MAX_EXPONENT - MIN_EXPONENT) * BINS_PER_OCTAVE`` bins a sign.
MIN_EXPONENT = -30
MAX_EXPONENT = 64


def _key(x: float) -> int:
    """The bin of ``x``: keys sort as their values do (0 for zero, negative for negative)."""
    if x == 0.0:
        return 0
    m, e = math.frexp(abs(x))  # |x| = m * 2**e, 0.5 <= m < 1
    if e < MIN_EXPONENT:
        m, e = 0.5, MIN_EXPONENT
    elif e > MAX_EXPONENT:
        m, e = 1.0 - 1e-16, MAX_EXPONENT
    k = 1 + (e - MIN_EXPONENT) * BINS_PER_OCTAVE + int((m - 0.5) * 2 * BINS_PER_OCTAVE)
    return k if x > 0 else -k


def _middle(k: int) -> float:
    """The middle of bin ``k`` (:func:`_key`)."""
    if k == 0:
        return 0.0
    e, sub = divmod(abs(k) - 1, BINS_PER_OCTAVE)
    m = 0.5 + (sub + 0.5) / (2 * BINS_PER_OCTAVE)
    v = math.ldexp(m, e + MIN_EXPONENT)
    return v if k > 0 else -v


class Tally:
    """One quantity's measurements over a run (a frame's render time, a server frame's decode
    time), in memory bounded whatever the run's length. Non-finite values are not measurements:
    :meth:`add` counts them in :attr:`non_finite` and leaves the rest alone.

    ``exact`` (default :data:`EXACT`): how many values to keep one by one; up to that many the
    percentiles are exact, beyond within :data:`RELATIVE_ERROR`."""

    __slots__ = ("_bins", "_exact", "_values", "count", "max", "min", "non_finite")

    def __init__(self, exact: int = EXACT) -> None:
        self._exact = exact
        self._values: array[float] | None = array("d")  # None once more than `exact` came
        self._bins: dict[int, int] = {}
        self.count = 0
        self.non_finite = 0
        self.min: float | None = None
        self.max: float | None = None

    def add(self, x: float) -> None:
        x = float(x)
        if not math.isfinite(x):
            self.non_finite += 1
            return
        self.count += 1
        self.min = x if self.min is None else min(self.min, x)
        self.max = x if self.max is None else max(self.max, x)
        k = _key(x)
        self._bins[k] = self._bins.get(k, 0) + 1
        if self._values is not None:
            if len(self._values) < self._exact:
                self._values.append(x)
            else:
                self._values = None

    def __len__(self) -> int:
        return self.count

    def forget_values(self) -> None:
        """Drops the values kept one by one (up to 512 KiB): from then on the percentiles
        come from the histogram, within :data:`RELATIVE_ERROR`, as past :data:`EXACT` values.
        For a tally kept for its summary after its run ended."""
        self._values = None

    @property
    def exact(self) -> bool:
        """Whether every value is kept (the percentiles are exact)."""
        return self._values is not None

    def percentile(self, q: float) -> float | None:
        """The ``q``-th percentile (0-100) as numpy's ``method="linear"`` gives it (exact while
        :attr:`exact`, else within :data:`RELATIVE_ERROR`); ``None`` without values."""
        if self.count == 0:
            return None
        if self._values is not None:
            return float(np.percentile(self._values, q))
        assert self.min is not None and self.max is not None
        pos = q / 100.0 * (self.count - 1)
        lo = math.floor(pos)
        a = self._ranked(lo)
        b = a if lo == pos else self._ranked(lo + 1)
        return a + (pos - lo) * (b - a)

    def median(self) -> float | None:
        return self.percentile(50.0)

    def count_above(self, x: float) -> int:
        """How many values exceed ``x`` (exact while :attr:`exact`; beyond, the values in
        ``x``'s own bin count when the bin's middle exceeds ``x``)."""
        if self._values is not None:
            return sum(v > x for v in self._values)
        kx = _key(x)
        return sum(
            c for k, c in self._bins.items() if k > kx or (k == kx and _middle(k) > x)
        )

    def _ranked(self, r: int) -> float:
        """The ``r``-th smallest value (from 0) as its bin's middle, within the exact range."""
        assert self.min is not None and self.max is not None
        if r <= 0:
            return self.min
        if r >= self.count - 1:
            return self.max
        seen = 0
        for k in sorted(self._bins):
            seen += self._bins[k]
            if seen > r:
                return min(max(_middle(k), self.min), self.max)
        return self.max  # unreachable: the bins hold `count` values
