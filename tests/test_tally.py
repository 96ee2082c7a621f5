"""Tally: a run's measurements in bounded memory, exact while few, then within its stated
relative error; and the real-time report built on it."""

from __future__ import annotations

import math
import tracemalloc

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from splitrender.tally import (
    BINS_PER_OCTAVE,
    MAX_EXPONENT,
    MIN_EXPONENT,
    RELATIVE_ERROR,
    Tally,
)

QS = (0.0, 1.0, 25.0, 50.0, 90.0, 95.0, 99.0, 100.0)


def test_up_to_its_exact_count_a_tally_gives_numpys_percentiles() -> None:
    values = np.random.default_rng(3).lognormal(1.0, 0.8, 500).tolist()
    t = Tally(exact=500)
    for v in values:
        t.add(v)
    assert t.exact and len(t) == 500
    for q in QS:
        assert t.percentile(q) == float(np.percentile(values, q))
    assert t.count_above(5.0) == sum(v > 5.0 for v in values)
    # "exceed": a value equal to x is not counted (5.0 is none of them, so >= passed above).
    assert t.count_above(values[7]) == sum(v > values[7] for v in values)
    assert (t.min, t.max) == (min(values), max(values))


@settings(max_examples=200, deadline=None)
@given(
    st.lists(st.floats(1e-6, 1e12), min_size=1, max_size=300),
    st.sampled_from(QS),
    st.booleans(),
)
def test_beyond_it_percentiles_are_within_the_stated_relative_error(
    values: list[float], q: float, negative: bool
) -> None:
    # Values of one sign (either) within the histogram's exponents: each rank's value is its
    # bin's middle, within half a bin; the interpolation between two ranks keeps that bound.
    if negative:
        values = [-v for v in values]
    t = Tally(exact=0)
    for v in values:
        t.add(v)
    assert not t.exact
    exact = float(np.percentile(values, q))
    got = t.percentile(q)
    assert got is not None
    assert abs(got - exact) <= RELATIVE_ERROR * abs(exact) * (1 + 1e-12)
    assert t.min is not None and t.max is not None and t.min <= got <= t.max  # as numpy's is
    assert (t.min, t.max) == (min(values), max(values))
    assert t.percentile(0) == min(values) and t.percentile(100) == max(values)


def test_a_tally_that_forgets_its_values_keeps_its_summary_within_the_relative_error() -> None:
    values = np.random.default_rng(5).lognormal(2.0, 0.5, 2000).tolist()
    t = Tally()
    for v in values:
        t.add(v)
    assert t.exact
    t.forget_values()
    assert not t.exact and len(t) == 2000 and (t.min, t.max) == (min(values), max(values))
    for q in QS:
        exact = float(np.percentile(values, q))
        got = t.percentile(q)
        assert got is not None and abs(got - exact) <= RELATIVE_ERROR * exact * (1 + 1e-12)
    t.add(1.0)  # and counts on
    assert len(t) == 2001 and t.min == 1.0


def test_beyond_it_counts_above_a_value_are_exact_but_for_the_values_own_bin() -> None:
    values = np.random.default_rng(5).uniform(1.0, 20.0, 5000).tolist()
    t = Tally(exact=100)
    for v in values:
        t.add(v)
    for x in (0.5, 3.0, 7.25, 19.0, 25.0):
        true = sum(v > x for v in values)
        near = sum(abs(v - x) <= 2 * RELATIVE_ERROR * x for v in values)
        assert abs(t.count_above(x) - true) <= near


def test_a_tally_of_any_values_holds_a_bounded_number_of_bins() -> None:
    # A peer's numbers (a server's render times in its frame headers) spread over every
    # exponent a float has: the bins stay within the histogram's range.
    t = Tally(exact=0)
    for e in range(-1074, 1024):
        for sign in (1.0, -1.0):
            t.add(sign * math.ldexp(1.0, e))
            t.add(sign * math.ldexp(1.7, e) if e < 1023 else sign * math.ldexp(1.0, e))
    t.add(0.0)
    bound = 2 * (MAX_EXPONENT - MIN_EXPONENT + 1) * BINS_PER_OCTAVE + 1
    assert len(t._bins) <= bound
    assert t.min == -math.ldexp(1.0, 1023) and t.max == math.ldexp(1.0, 1023)
    assert len(t) == 4 * 2098 + 1


def test_non_finite_values_are_counted_apart() -> None:
    t = Tally()
    for v in (1.0, math.nan, math.inf, -math.inf, 3.0):
        t.add(v)
    assert len(t) == 2 and t.non_finite == 3 and t.median() == 2.0
    assert Tally().median() is None and Tally().max is None


def _frame(n: int, render_ms: float, cpu_ms: float, mode: str) -> object:
    from splitrender.client.realtime import DisplayFrame

    period = 1 / 120
    tick = n * period
    return DisplayFrame(
        index=n, time=tick, start=tick + 1e-4, done=tick + 1e-4 + render_ms / 1e3,
        deadline=tick + period, mode=mode, older=0, newer=1, alpha=0.5,
        server_age_ms=50.0 + n % 7, prepared=n % 3 != 0, refresh=tick, cpu_ms=cpu_ms,
        divisor=1 + n % 2)


def test_a_report_keeping_few_frames_sums_up_every_frame() -> None:
    from splitrender.client.realtime import RealtimeReport

    rng = np.random.default_rng(11)
    few, every = RealtimeReport(120.0, keep_frames=50), RealtimeReport(120.0, keep_frames=None)
    for n in range(3000):
        mode = ("interpolate", "extrapolate", "hold")[n % 3]
        render = float(rng.uniform(1.0, 12.0))
        f = _frame(n, render, render * float(rng.uniform(1.0, 2.5)), mode)
        few.add(f)  # type: ignore[arg-type]
        every.add(f)  # type: ignore[arg-type]
    assert len(few.frames) == 50 and len(every.frames) == 3000
    assert [f.index for f in few.frames] == list(range(2950, 3000))
    assert few.summary() == every.summary()
    s = few.summary()
    assert s["frames"] == 3000 and few.frame_count == 3000
    misses = [f for f in every.frames if not f.met]
    assert s["deadline_misses"] == len(misses) > 0
    assert sum(s["deadline_misses_by_cause"].values()) == len(misses)
    renders = [f.render_ms for f in every.frames]
    assert s["frame_ms_p99"] == pytest.approx(np.percentile(renders, 99))


def test_a_reports_memory_does_not_grow_with_the_run() -> None:
    # Past Tally's exact count every frame adds to counters and histogram bins only. (Every
    # frame of one mode, and missed: each of the report's tallies has seen that many.)
    from splitrender.client.realtime import RealtimeReport
    from splitrender.tally import EXACT

    report = RealtimeReport(120.0, keep_frames=100)
    frames = [_frame(n, 9.0 + (n % 97) / 10, 4.0 + (n % 89) / 10, "interpolate")
              for n in range(200)]
    for n in range(EXACT + 1):
        report.add(frames[n % 200])  # type: ignore[arg-type]
    tracemalloc.start()
    try:
        before = tracemalloc.get_traced_memory()[0]
        for n in range(EXACT):
            report.add(frames[n % 200])  # type: ignore[arg-type]
        grown = tracemalloc.get_traced_memory()[0] - before
    finally:
        tracemalloc.stop()
    assert report.frame_count == 2 * EXACT + 1
    assert grown < 64 * 1024, f"{grown} bytes for {EXACT} frames"
