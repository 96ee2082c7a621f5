"""The display's garbage collection between frames (splitrender.client.collector): which
generation is due, when it is collected, and that the process's collector is left as it was.
The decisions are checked on counts and thresholds given to it (the process's own move with
every allocation); the loop's use of it in tests/test_realtime.py."""

from __future__ import annotations

import gc
from typing import Any

import pytest
from splitrender.client import collector as col
from splitrender.client.collector import FrameCollector


class FakeGc:
    """``gc.get_count``, ``gc.get_threshold`` and ``gc.collect`` of a test: the counts it
    sets, the collections asked for (a collection of ``g`` zeroes the counts up to ``g`` and
    adds one to the next, as CPython's does)."""

    def __init__(self, monkeypatch: pytest.MonkeyPatch, counts: tuple[int, int, int],
                 limits: tuple[int, int, int] = (700, 10, 10)) -> None:
        self.counts, self.limits = list(counts), limits
        self.collected: list[int] = []
        monkeypatch.setattr(gc, "get_count", lambda: tuple(self.counts))
        monkeypatch.setattr(gc, "get_threshold", lambda: self.limits)
        monkeypatch.setattr(gc, "collect", self.collect)

    def collect(self, generation: int = 2) -> int:
        self.collected.append(generation)
        for k in range(generation + 1):
            self.counts[k] = 0
        if generation + 1 < len(self.counts):
            self.counts[generation + 1] += 1
        return 0


def active() -> FrameCollector:
    """A collector as :meth:`FrameCollector.start` leaves it, without touching the process."""
    c = FrameCollector()
    c.active = True
    return c


@pytest.mark.parametrize(
    ("counts", "limits", "due"),
    [
        ((700, 50, 50), (700, 10, 10), None),  # the youngest not past its threshold: nothing
        ((701, 0, 0), (700, 10, 10), 0),
        ((701, 11, 3), (700, 10, 10), 1),
        ((701, 11, 11), (700, 10, 10), 2),
        ((701, 3, 11), (700, 10, 10), 2),  # the oldest past its threshold, as CPython's
        ((701, 11, 11), (700, 10, 0), 1),  # a threshold of 0: that generation never
        ((5000, 50, 50), (0, 10, 10), None),  # the youngest's 0: no automatic collection
    ],
)
def test_due_is_the_oldest_generation_past_its_threshold_once_the_youngest_is(
    monkeypatch, counts, limits, due
):
    FakeGc(monkeypatch, counts, limits)
    assert FrameCollector.due() == due


def test_a_due_generation_is_collected_where_the_time_holds_twice_its_last_cost(monkeypatch):
    fake = FakeGc(monkeypatch, (701, 0, 0))
    c = active()
    guess = col.FIRST_GUESS_S[0]
    c.between_frames(col.MARGIN * guess * 0.9)  # not time enough for the first guess
    assert fake.collected == [] and c.collections == 0
    c.between_frames(col.MARGIN * guess * 1.1)
    assert fake.collected == [0] and c.collections == 1 and c.forced == 0
    # Its cost is now the one measured (the fake takes microseconds), the longest kept.
    assert 0 <= c.longest_s < guess
    fake.counts[0] = 701
    c.between_frames(col.MARGIN * guess * 0.9)  # enough for what it took
    assert fake.collected == [0, 0]


def test_a_younger_generation_stands_in_for_a_due_one_that_does_not_fit(monkeypatch):
    # A full collection is due; the time holds the first guess of the middle one's, not more.
    fake = FakeGc(monkeypatch, (701, 0, 11))
    c = active()
    time_left = col.MARGIN * col.FIRST_GUESS_S[1] * 1.1
    assert col.MARGIN * col.FIRST_GUESS_S[2] > time_left
    c.between_frames(time_left)
    assert fake.collected == [1] and c.forced == 0
    # Each stand-in adds to the due generation's count: it becomes overdue, and then comes
    # even without the time (waiting for it alone, nothing would ever be collected).
    fake.counts[:] = [701, 0, col.OVERDUE * 10 - 1]
    c.between_frames(0.0)
    assert fake.collected == [1]
    fake.counts[:] = [701, 0, col.OVERDUE * 10]
    c.between_frames(0.0)
    assert fake.collected == [1, 2] and c.forced == 1


def test_an_overdue_generation_is_collected_without_the_time(monkeypatch):
    fake = FakeGc(monkeypatch, (col.OVERDUE * 700 - 1, 0, 0))
    c = active()
    c.between_frames(0.0)
    assert fake.collected == []  # due, postponed: no time and not yet overdue
    fake.counts[0] += 1
    c.between_frames(0.0)
    assert fake.collected == [0] and c.forced == 1 and c.collections == 1
    # An older generation postponed: overdue by its own count only.
    fake.counts[:] = [701, 11, 0]
    c.between_frames(0.0)
    assert fake.collected == [0]
    fake.counts[:] = [701, col.OVERDUE * 10, 0]
    c.between_frames(0.0)
    assert fake.collected == [0, 1] and c.forced == 2


@pytest.mark.parametrize(
    ("counts", "collector"),
    [
        ((700, 10, 10), active),  # none due, whatever the time
        ((10_000, 100, 100), FrameCollector),  # inactive: never started, or stopped
    ],
)
def test_nothing_is_collected_while_none_is_due_or_the_collector_is_inactive(
    monkeypatch, counts, collector
):
    fake = FakeGc(monkeypatch, counts)
    c = collector()
    c.between_frames(1.0)
    assert fake.collected == [] and c.collections == 0


@pytest.fixture
def process_gc() -> Any:
    """The process's collector as it was before the test, restored after it."""
    enabled, frozen = gc.isenabled(), gc.get_freeze_count()
    yield
    if gc.get_freeze_count() > frozen:
        gc.unfreeze()
    gc.enable() if enabled else gc.disable()


def test_start_turns_automatic_collection_off_and_stop_back_on(process_gc):
    gc.enable()
    assert gc.get_freeze_count() == 0
    c = FrameCollector()
    c.start()
    try:
        assert c.active and not gc.isenabled()
        assert gc.get_freeze_count() > 0  # what existed at the start: walked by no collection
    finally:
        c.stop()
    assert not c.active and gc.isenabled() and gc.get_freeze_count() == 0
    c.stop()  # twice: nothing more
    assert gc.isenabled()


def test_a_collector_the_application_disabled_is_left_alone(process_gc):
    gc.disable()
    c = FrameCollector()
    c.start()
    assert not c.active and not gc.isenabled() and gc.get_freeze_count() == 0
    c.stop()
    assert not gc.isenabled()


def test_objects_the_application_froze_stay_frozen(process_gc):
    gc.enable()
    gc.freeze()
    frozen = gc.get_freeze_count()
    c = FrameCollector()
    c.start()
    assert c.active and not gc.isenabled()
    c.stop()
    assert gc.isenabled() and gc.get_freeze_count() == frozen


def test_displays_at_the_same_time_share_the_process_collector(process_gc):
    # Two displays in one process: the first to stop must not turn automatic collection back
    # on under the other, and the last must, in either order.
    gc.enable()
    for order in ((0, 1), (1, 0)):
        first, second = FrameCollector(), FrameCollector()
        first.start()
        second.start()
        assert first.active and second.active and not gc.isenabled()
        assert gc.get_freeze_count() > 0
        one, last = (first, second)[order[0]], (first, second)[order[1]]
        one.stop()
        assert not one.active and last.active
        assert not gc.isenabled() and gc.get_freeze_count() > 0  # still frozen
        last.stop()
        assert gc.isenabled() and gc.get_freeze_count() == 0
