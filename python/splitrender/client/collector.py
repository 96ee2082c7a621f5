"""Python's cyclic garbage collector kept between the display's frames.

CPython collects a generation when its count passes a threshold (the youngest: 700 more
tracked objects allocated than freed), in whichever thread allocates next, holding the GIL. In
the real-time loop that is the middle of some display frame, or the worker (whose collection
then holds up the display's next Python line); and a collection of the oldest generation walks
every tracked object of the process. Traced in a 60 s run of ``splitrender bench --realtime
--scale 0.25`` (docs/realtime.md, "Garbage collection between frames"): 26 collections fell
inside display frames, one of them a full collection of 29 ms (a missed deadline and three
dropped refreshes), generation-1 collections took 1.3-1.5 ms.

:class:`FrameCollector` does what engines in collected languages do with their collector.
While the display runs, automatic collection is off and the objects that exist when it starts
are frozen (:func:`gc.freeze`: a full collection then walks only what the run made). After each
frame the display asks for the collection the automatic schedule would have made by now
(:meth:`FrameCollector.due`), and it runs where the time to the next refresh holds
:data:`MARGIN` times what that generation took the last time; where it does not, a younger
generation that fits runs instead. A generation whose count reaches :data:`OVERDUE` times its
threshold is collected even without that time, so that the memory held in garbage cycles
stays bounded when the frames never leave it. A process whose collector is disabled when the
display starts (``gc.disable()``: the application manages it) is left as it is. Displays
running at the same time in one process (two
:class:`~splitrender.client.realtime.RealtimeClient` runs, each in a thread of its own) share
the process's collector: the first to start turns automatic collection off, the last to stop
turns it back on, and each collects between its own frames.
"""

from __future__ import annotations

import gc
import threading
import time

__all__ = ["FIRST_GUESS_S", "MARGIN", "OVERDUE", "FrameCollector"]

#: What a collection of each generation is taken to cost (seconds) until one has been timed:
#: above what the trace above measured (0.07-0.4 ms, 0.6-2 ms; a full collection of the frozen
#: process the least of it), so that the first of each waits for a frame with room.
FIRST_GUESS_S = (0.0005, 0.003, 0.01)

#: A due generation is collected between frames where the time to the next refresh is at least
#: this many times what its last collection took.
MARGIN = 2.0

#: A due generation whose count has reached this many times its threshold is collected between
#: frames even where the time to the next refresh does not hold it.
OVERDUE = 10

# The process's collector is one, whatever the number of displays: how many collectors hold it
# (started, not stopped), and whether the first of them froze the process's objects.
_hold_lock = threading.Lock()
_holders = 0
_froze = False


class FrameCollector:
    """The process's garbage collector run between display frames (module docs):
    :meth:`start` before the display's clock starts, :meth:`between_frames` after each frame,
    :meth:`stop` when the display stops (also after an error). Counts what it did:
    :attr:`collections`, :attr:`forced` (of them, collected without the time) and the longest
    (:attr:`longest_s`)."""

    def __init__(self) -> None:
        #: Whether it runs the collector (from :meth:`start` to :meth:`stop`, where the
        #: process's collector was enabled).
        self.active = False
        self.collections = 0
        self.forced = 0
        self.longest_s = 0.0
        self._cost = list(FIRST_GUESS_S)

    def start(self) -> None:
        """Collects everything (off the clock: what is garbage now is not frozen), freezes
        what is left and turns automatic collection off; nothing where the process's collector
        is disabled. Where another collector of the process is active, this one joins it: the
        process is already as this would leave it."""
        global _holders, _froze
        with _hold_lock:
            if self.active:
                return
            if _holders == 0:
                if not gc.isenabled():
                    return
                gc.collect()
                # Objects the application froze are its own to unfreeze: then nothing is
                # frozen here.
                _froze = gc.get_freeze_count() == 0
                if _froze:
                    gc.freeze()
                gc.disable()
            _holders += 1
            self.active = True

    def stop(self) -> None:
        """Undoes :meth:`start`: once no collector of the process is active, the frozen
        objects back in the oldest generation, automatic collection on."""
        global _holders
        with _hold_lock:
            if not self.active:
                return
            self.active = False
            _holders -= 1
            if _holders == 0:
                if _froze:
                    gc.unfreeze()
                gc.enable()

    @staticmethod
    def due() -> int | None:
        """The generation CPython's automatic schedule would collect at the next allocation,
        or ``None``: the oldest whose count passes its threshold, once the youngest's does (a
        threshold of 0 turns the schedule, or that generation, off)."""
        return _due(gc.get_count(), gc.get_threshold())

    def between_frames(self, time_left_s: float) -> None:
        """Where a generation is :meth:`due`: collects the oldest generation up to it whose
        last collection fits :data:`MARGIN` times into ``time_left_s`` (to the next refresh);
        where none does, the oldest whose count has reached :data:`OVERDUE` times its
        threshold; else nothing.

        A younger generation stands in for a due one that does not fit: every collection of an
        older one walks it too, so it costs less, and its collection adds to the older one's
        count until that is overdue (waiting for the older one alone, nothing would be
        collected while the frames leave less than its time)."""
        if not self.active:
            return
        counts, limits = gc.get_count(), gc.get_threshold()
        due = _due(counts, limits)
        if due is None:
            return
        fits = [g for g in range(due + 1) if self._cost[g] * MARGIN <= time_left_s]
        if fits:
            g = fits[-1]
        else:
            overdue = [
                g for g in range(due + 1) if 0 < limits[g] and OVERDUE * limits[g] <= counts[g]
            ]
            if not overdue:
                return
            g = overdue[-1]
            self.forced += 1
        t = time.perf_counter()
        gc.collect(g)
        took = time.perf_counter() - t
        self._cost[g] = took
        self.collections += 1
        self.longest_s = max(self.longest_s, took)


def _due(counts: tuple[int, ...], limits: tuple[int, ...]) -> int | None:
    """:meth:`FrameCollector.due` of the collector's ``counts`` and thresholds ``limits``."""
    if limits[0] <= 0 or counts[0] <= limits[0]:
        return None
    g = 0
    for k in range(1, min(len(counts), len(limits))):
        if 0 < limits[k] < counts[k]:
            g = k
    return g
