"""The real-time client loop: :class:`RealtimeClient`, what a headset integration runs on top of
:class:`~splitrender.client.client.Client` to show ``f_c`` frames per second (seeds/000 §3, §4.2).

Three things happen at once, and only the last is on the display path:

1. **Receive.** Server packets are handed to :meth:`RealtimeClient.submit` as they arrive and
   decoded on a worker thread (:class:`~splitrender.codec.coder.StreamDecoder`).
2. **Prepare.** On the same worker, right after decoding frame ``k``, the pair-level work of the
   method (Algorithm 2's correspondences, the auxiliary cameras' visibility in main:
   :func:`splitrender.prepare_pair`; on the GPU, ``backend="wgpu"``, the upload of the pair:
   :meth:`~splitrender.gpu.GpuReprojector.upload`) is done for the pairs the frame opens:
   ``(k − 1, k)`` to interpolate, then ``(None, k)`` to extrapolate from it. The frame becomes
   usable as soon as its first pair is prepared (the second is needed only if frame ``k + 1`` is
   late, a server period later): until then the display extrapolates from the frames it has
   (that is the method's answer to a late frame, seeds/000 §3.5), so no display frame waits for
   a decoder or pays the pair work. A pair that would be ready too late to be shown for much
   of its interval (:data:`MIN_PAIR_USE`, estimated from the last one prepared) is not
   prepared: the frame is prepared to extrapolate from and used from its own time on, so a
   worker that cannot keep up with the pairs still keeps the content fresh.
3. **Display.** :meth:`RealtimeClient.run` is driven by a monotonic clock at ``f_c``: display
   frame ``n`` starts at refresh ``n`` (clock ``t0 + n / f_c``) with the pose of its display
   time, is rendered by :meth:`Client.render` from the usable frames, and is due at the next
   refresh. A frame that finishes after it is *late* (a deadline miss); the loop then starts
   again at the first refresh not yet passed, so one slow frame never makes the following ones
   late (the refreshes in between are *dropped*: the display repeats its image). A frame that
   could interpolate its pair extrapolates from the pair's older frame instead where an
   interpolated frame would not be done by its deadline (:class:`ModeGovernor`: about 60 % of
   the cost); a display whose frames do not fit the refresh even so goes on at half the rate
   (:class:`RateGovernor`, as headset runtimes do), on time, and back to the full rate once
   its frames fit again.

Every display frame is recorded (:class:`DisplayFrame`): deadline met or missed, render time,
mode (interpolate, extrapolate, hold), the server frames used, and the age of the newest server
frame, from the time its pose was taken to the display time. :class:`RealtimeReport` sums them up
(:meth:`RealtimeReport.summary`: percentiles, misses, decode and preparation times, CPU use).
While the display runs, Python's garbage collector runs between its frames, where the time to
the next refresh holds it, not inside them (:mod:`splitrender.client.collector`).

The clock is a parameter (:class:`Clock`), so that the loop's logic (deadlines, extrapolation
while a pair is prepared, recovery after a late frame) is tested with a fake clock, and timings
are left to ``splitrender bench --realtime``.
"""

from __future__ import annotations

import itertools
import math
import os
import sys
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable, Iterator, Sequence
from concurrent.futures import Executor, Future, ThreadPoolExecutor
from concurrent.futures import wait as futures_wait
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Literal, Protocol, overload

import numpy as np
import numpy.typing as npt

import splitrender._native as _native
from splitrender.client.client import Client
from splitrender.client.collector import FrameCollector
from splitrender.errors import InvalidInputError, StreamError
from splitrender.gpu import BACKENDS, GpuDeviceLostError, GpuPair
from splitrender.machine import cpu_times, steal_share, usable_cpus
from splitrender.net.model import MODES, TIME_EPS
from splitrender.reproject import MAX_PREPARE_THREADS, prepare_pair
from splitrender.tally import Tally
from splitrender.types import Camera, ReprojectOptions, ServerFrame, interpolates
from splitrender.types import (  # argument checks
    BOOL,
    CALLABLE,
    ITERABLE,
    MAX_RATE,
    buffers,
    check_buffer,
    check_float,
    check_instance,
    checked,
    describe,
    floats,
    instances,
    ints,
    optional,
    strs,
)

if TYPE_CHECKING:
    from splitrender.codec.coder import StreamDecoder

__all__ = [
    "DISPLAY_FPS",
    "DISPLAY_PRIORITIES",
    "WORKER_PRIORITIES",
    "Clock",
    "MAX_DIVISOR",
    "MIN_PAIR_USE",
    "PREPARE_THREADS",
    "DisplayFrame",
    "Handover",
    "ModeGovernor",
    "MonotonicClock",
    "RateGovernor",
    "RealtimeClient",
    "RealtimeReport",
]

_Image = npt.NDArray[np.uint8]

#: The default display rate ``f_c`` (FPS): the headsets' 120 Hz that the method targets.
DISPLAY_FPS = 120.0


class Clock(Protocol):
    """Where the loop reads the time (seconds, monotonic) and waits."""

    def now(self) -> float: ...

    def sleep_until(self, t: float) -> None: ...


class MonotonicClock:
    """The wall clock: :func:`time.monotonic` and :func:`time.sleep`."""

    def now(self) -> float:
        return time.monotonic()

    def sleep_until(self, t: float) -> None:
        d = t - time.monotonic()
        if d > 0:
            time.sleep(d)


@dataclass(frozen=True, slots=True)
class DisplayFrame:
    """One display frame of :meth:`RealtimeClient.run`.

    ``index`` is the display refresh it started on, ``time`` its display time (content seconds,
    the time of its pose), ``start``/``done``/``deadline`` clock seconds (``deadline`` is the
    refresh after the ``divisor`` it is shown for: the next one at the full rate, the one after
    at half rate, :class:`RateGovernor`). ``server_age_ms`` is the display time minus the time
    the pose of the newest usable server frame was taken (``None`` before the first).
    ``prepared``: the pair it used was prepared off the display path (``False`` for ``hold``,
    and for a pair the display had to prepare itself). ``refresh`` is the clock time of the
    refresh it started on (``start`` is later by the wait for the display thread to run);
    ``cpu_ms`` the CPU time the display's threads (the display thread and the render threads)
    spent from ``start`` to ``done`` (``None`` where threads' CPU clocks cannot be read: off
    Linux). ``eyes``: the images it is (2 for a stereo run: its times cover both eyes).
    ``deferred``: it could have interpolated its pair but extrapolated from the pair's older
    frame, because an interpolated frame would not have been done by its deadline
    (:class:`ModeGovernor`)."""

    index: int
    time: float
    start: float
    done: float
    deadline: float
    mode: str
    older: int | None
    newer: int | None
    alpha: float | None
    server_age_ms: float | None
    prepared: bool
    divisor: int = 1
    refresh: float | None = None
    cpu_ms: float | None = None
    eyes: int = 1
    deferred: bool = False

    @property
    def render_ms(self) -> float:
        return (self.done - self.start) * 1e3

    @property
    def met(self) -> bool:
        """Whether the frame was done by its deadline."""
        return self.done <= self.deadline

    @property
    def start_delay_ms(self) -> float | None:
        """From its refresh to its start, ms (``None`` without ``refresh``)."""
        return None if self.refresh is None else (self.start - self.refresh) * 1e3


#: A missed frame that started more than this after its refresh (ms) missed because it
#: started late (:meth:`RealtimeReport.miss_causes`). Frames start 0.1–0.3 ms after their
#: refresh on the project's machine.
LATE_START_MS = 1.0

#: A missed frame whose display threads used more than this times the run's median CPU time
#: of frames of its mode missed because its work took longer (:meth:`RealtimeReport.miss_causes`).
MORE_CPU = 1.5

#: The causes :meth:`RealtimeReport.miss_causes` tells apart, in the order it tries them.
MISS_CAUSES = ("late_start", "more_cpu", "waited")


def _thread_cpu_clocks(tids: list[int]) -> list[int] | None:
    """The CPU-time clocks of the threads ``tids`` (kernel thread ids) for
    :func:`time.clock_gettime`, or ``None`` off Linux.

    Linux names a thread's CPU clock by its id: ``((~tid) << 3) | 6`` is the kernel's
    ``MAKE_THREAD_CPUCLOCK(tid, CPUCLOCK_SCHED)``, what glibc's ``pthread_getcpuclockid``
    returns. The render threads were not started by Python, so :func:`time.pthread_getcpuclockid`
    cannot name them. Reading the three clocks costs about a microsecond, and no system call
    here lets the display thread's GIL go (a read of ``/proc`` would)."""
    if not sys.platform.startswith("linux"):
        return None
    return [((~tid) << 3) | 6 for tid in tids]


def _eye_cameras(pose: Callable[[float], Any], t: float) -> tuple[Camera, ...]:
    """``pose(t)`` of a stereo run (:meth:`RealtimeClient.run`): the cameras ``(left, right)``."""
    views = pose(t)
    if (
        not isinstance(views, (tuple, list))
        or len(views) != 2
        or not all(isinstance(c, Camera) for c in views)
    ):
        got = describe(views)
        if isinstance(views, (tuple, list)):
            got = f"a {got} of {len(views)}: ({', '.join(describe(c) for c in views[:4])}"
            got += ", ...)" if len(views) > 4 else ")"
        raise InvalidInputError(
            f"pose({t:g}): with stereo=True expected a pair (left, right) of Camera, got {got}"
        )
    return tuple(views)


def _cpu_s(clocks: list[int] | None) -> float | None:
    """The CPU seconds of ``clocks`` (:func:`_thread_cpu_clocks`) together, or ``None`` where
    one cannot be read (a thread that exited)."""
    if clocks is None:
        return None
    try:
        return sum(time.clock_gettime(c) for c in clocks)
    except OSError:
        return None


#: Display frames a :class:`RealtimeReport` keeps one by one by default (over 2 minutes at
#: 120 Hz; about 400 bytes each, 7 MB): the newest; its summary covers every frame of the run
#: (:class:`~splitrender.tally.Tally`). ``RealtimeClient(keep_frames=None)`` keeps them all.
KEEP_FRAMES = 16384


@dataclass(frozen=True, slots=True)
class Handover:
    """A server frame handed to the display during :meth:`RealtimeClient.run` (its
    ``on_handover`` callback): the frame's ``index`` and ``time`` (content seconds), the
    ``display_time`` it was handed over at, and whether it was ``late``: handed over after the
    display first needed it, one pair's interval before its time (where the pair it closes
    starts), or after the run began for a frame needed before. ``late`` is the decision
    :attr:`RealtimeReport.server_frames_late` counts."""

    index: int
    time: float
    display_time: float
    late: bool


#: Refusal messages of undecodable packets a :class:`RealtimeReport` keeps (the first ones; it
#: counts them all).
KEEP_UNDECODABLE = 100


class RealtimeReport:
    """What :meth:`RealtimeClient.run` did: its display frames (:meth:`add`; the newest
    ``keep_frames`` in :attr:`frames`, default :data:`KEEP_FRAMES`, ``None``: all), the
    refreshes dropped after a late frame and those repeated at a divided rate
    (:class:`RateGovernor`), the worker's decode and preparation times (ms per server frame),
    and the wall and CPU seconds of the run (CPU: the whole process, every thread).

    A run of any length takes bounded memory: the counts, the time percentiles and
    :meth:`miss_causes` cover every frame (:class:`~splitrender.tally.Tally`: exact up to
    :data:`~splitrender.tally.EXACT` frames, then within
    :data:`~splitrender.tally.RELATIVE_ERROR`)."""

    def __init__(self, display_fps: float, keep_frames: int | None = KEEP_FRAMES) -> None:
        self.display_fps = display_fps
        #: The newest display frames (all of them with ``keep_frames=None``).
        self.frames: deque[DisplayFrame] = deque(maxlen=keep_frames)
        self.dropped = 0
        self.repeated = 0
        #: ms per server frame: its decode; its pairs' preparation; from the worker taking
        #: the packet until the frame was usable.
        self.decode_ms = Tally()
        self.prepare_ms = Tally()
        self.usable_ms = Tally()
        self.server_frames_received = 0
        self.server_frames_late = 0
        #: Server frames whose interpolation pair was not prepared because it would have been
        #: ready too late to be shown (:data:`MIN_PAIR_USE`); each became usable at its own time.
        self.pairs_skipped = 0
        #: Interpolation pairs estimated too late but prepared to measure them again
        #: (:data:`PAIR_PROBE_AFTER`).
        self.pairs_probed = 0
        self.wall_s = 0.0
        self.cpu_s = 0.0
        self.cpus = 1
        #: The share (0-1) of the machine's CPU time that the virtual machine's host took
        #: during the run (:func:`~splitrender.machine.steal_share`); ``None`` where the
        #: platform does not count it.
        self.host_steal: float | None = None
        #: Why the first :data:`KEEP_UNDECODABLE` packets that did not decode were refused
        #: (the StreamError's message), in order; :attr:`packets_undecodable` counts them all.
        self.undecodable: list[str] = []
        self.packets_undecodable = 0
        #: The warm-up before the clock started (``RealtimeClient.run(warm_up=True)``), ms.
        self.warm_up_ms: float | None = None
        #: The render times (ms) of the warm-up's frames timed for the :class:`ModeGovernor`,
        #: by the mode they were rendered in (``interpolate``, ``extrapolate``), in order;
        #: ``None`` where the warm-up did not seed it (no warm-up, or nothing to interpolate at
        #: its start).
        self.warm_up_seed_ms: dict[str, list[float]] | None = None
        #: Why the GPU device was lost during the run (:attr:`Client.gpu_lost`: the display
        #: went on on the CPU), ``None`` where it was not.
        self.gpu_lost: str | None = None
        #: How the display's threads were scheduled (:func:`_raise_display`): ``"realtime"``,
        #: ``"normal"``, or ``"normal"`` with the reason real-time scheduling was refused.
        self.display_scheduling = "normal"
        #: Images per display frame: 1, or 2 for a stereo run (``RealtimeClient.run(stereo=)``).
        self.eyes = 1
        #: Whether the display ran the garbage collector between its frames
        #: (:class:`~splitrender.client.collector.FrameCollector`; ``False`` where the
        #: application had disabled it), the collections it ran, how many of them without the
        #: time to the next refresh (overdue), and the longest (ms).
        self.gc_between_frames = False
        self.gc_collections = 0
        self.gc_forced = 0
        self.gc_ms_max = 0.0
        # Every frame's share of the summary (the frames themselves are kept only so far).
        self._count = 0
        self._misses = 0
        self._prepared = 0
        self._deferred = 0
        self._modes: dict[str, int] = dict.fromkeys(MODES, 0)
        self._divisors: dict[int, int] = {}
        self._render = Tally()
        self._cpu = Tally()
        self._ages = Tally()
        self._cpu_by_mode: dict[str, Tally] = {}
        # Missed frames by cause: started late; else, with a CPU time, by mode (compared with
        # the mode's median at the end); else waited.
        self._late_starts = 0
        self._missed_cpu: dict[str, Tally] = {}
        self._missed_waited = 0

    def add(self, frame: DisplayFrame) -> None:
        """Records a display frame."""
        self.frames.append(frame)
        self._count += 1
        self._prepared += frame.prepared
        self._deferred += frame.deferred
        self._modes[frame.mode] = self._modes.get(frame.mode, 0) + 1
        self._divisors[frame.divisor] = self._divisors.get(frame.divisor, 0) + 1
        self._render.add(frame.render_ms)
        if frame.server_age_ms is not None:
            self._ages.add(frame.server_age_ms)
        if frame.cpu_ms is not None:
            self._cpu.add(frame.cpu_ms)
            self._cpu_by_mode.setdefault(frame.mode, Tally()).add(frame.cpu_ms)
        if frame.met:
            return
        self._misses += 1
        delay = frame.start_delay_ms
        if delay is not None and delay > LATE_START_MS:
            self._late_starts += 1
        elif frame.cpu_ms is not None:
            self._missed_cpu.setdefault(frame.mode, Tally()).add(frame.cpu_ms)
        else:
            self._missed_waited += 1

    def add_undecodable(self, reason: str) -> None:
        """Records a packet that did not decode, and why."""
        self.packets_undecodable += 1
        if len(self.undecodable) < KEEP_UNDECODABLE:
            self.undecodable.append(reason)

    @property
    def frame_count(self) -> int:
        """The display frames of the run (:attr:`frames` keeps the newest)."""
        return self._count

    @property
    def deadline_misses(self) -> int:
        return self._misses

    def miss_causes(self) -> dict[str, int]:
        """The missed frames by what made them late (:data:`MISS_CAUSES`), each counted once,
        by the first that applies:

        - ``late_start``: it started more than :data:`LATE_START_MS` after its refresh (the
          display thread did not run at its refresh: its sleep overran, it waited for the
          GIL or the lock that the worker held, or the host had taken its core);
        - ``more_cpu``: its display threads used more than :data:`MORE_CPU` times the run's
          median CPU time of frames of its mode (the work itself took longer: a pair prepared
          on the display path, page faults, or a slower processor for a while);
        - ``waited``: neither; its threads were runnable but off the cores, or blocked (on
          the GIL after the native call, say), or a virtual machine's host ran something else
          on the cores meanwhile (the host's time is not told apart per frame, here or in a
          late start: the run's ``host_steal_pct`` says how much of it there was).

        Frames without a refresh or a CPU time skip the tests that need them."""
        more = 0
        for mode, missed in self._missed_cpu.items():
            median = self._cpu_by_mode[mode].median()
            assert median is not None  # the missed frame's own CPU time is among them
            more += missed.count_above(MORE_CPU * median)
        waited = self._missed_waited + sum(len(t) for t in self._missed_cpu.values()) - more
        return {"late_start": self._late_starts, "more_cpu": more, "waited": waited}

    def summary(self) -> dict[str, Any]:
        """One flat object: ``frames``, ``eyes`` (images per frame: 2 for a stereo run; the
        frame times cover both), ``deadline_misses`` (count and ``_pct``), ``dropped``,
        ``deadline_misses_by_cause`` (:meth:`miss_causes`), ``repeated`` (refreshes that
        showed a frame again because the rate was divided),
        ``full_rate_pct`` (frames at ``f_c``) and ``frames_by_divisor`` (how many at ``f_c / d``,
        keyed by ``d`` as text), ``frame_ms_p50/p95/p99/max`` (render time),
        ``frame_cpu_ms_p50/max`` (the display threads' CPU time per frame), ``modes`` (count
        per mode), ``interpolation_deferred`` (the extrapolated frames that could have interpolated,
        but an interpolated frame would have missed its deadline: :class:`ModeGovernor`),
        ``decode_ms_per_server_frame``, ``prepare_ms_per_server_frame`` (both pairs) and
        ``usable_ms_per_server_frame`` (from the worker taking the packet until the frame is usable:
        its decode and first pair; all medians), the server frames received and late,
        ``packets_undecodable`` (packets the decoder refused; :attr:`undecodable` says why),
        ``pairs_skipped`` (interpolation pairs not prepared because they would have come too late)
        and ``pairs_probed`` (such pairs prepared anyway, to measure them again),
        ``server_age_ms_p50/max``, ``achieved_fps`` (frames done by their deadline per second of the
        run) and ``cpu_utilisation`` (process CPU seconds per wall second and core, 0–1),
        ``host_steal_pct`` (the share of the machine's CPU time its host took during the run,
        :attr:`host_steal` in per cent; ``None`` where not counted),
        ``display_scheduling`` (how the display's threads were scheduled), ``warm_up_ms`` (``None``
        without a warm-up), ``warm_up_seed_ms`` (:attr:`warm_up_seed_ms`), ``gpu_lost`` (why
        the GPU device was lost, after which the display rendered on the CPU; ``None``) and the
        garbage collection between frames: ``gc_between_frames``, ``gc_collections``,
        ``gc_forced`` and ``gc_ms_max`` (:class:`~splitrender.client.collector.FrameCollector`).
        Times that have no sample are ``None``."""
        n = self._count
        misses = self._misses
        return {
            "frames": n,
            "display_fps": self.display_fps,
            "eyes": self.eyes,
            "deadline_misses": misses,
            "deadline_misses_pct": 100.0 * misses / n if n else 0.0,
            "deadline_misses_by_cause": self.miss_causes(),
            "dropped": self.dropped,
            "repeated": self.repeated,
            "full_rate_pct": 100.0 * self._divisors.get(1, 0) / n if n else 0.0,
            "frames_by_divisor": {str(d): self._divisors[d] for d in sorted(self._divisors)},
            "frame_ms_p50": self._render.percentile(50),
            "frame_ms_p95": self._render.percentile(95),
            "frame_ms_p99": self._render.percentile(99),
            "frame_ms_max": self._render.max,
            "frame_cpu_ms_p50": self._cpu.median(),
            "frame_cpu_ms_max": self._cpu.max,
            "modes": {m: self._modes.get(m, 0) for m in MODES},
            "interpolation_deferred": self._deferred,
            "prepared_pct": 100.0 * self._prepared / n if n else 0.0,
            "decode_ms_per_server_frame": self.decode_ms.median(),
            "prepare_ms_per_server_frame": self.prepare_ms.median(),
            "usable_ms_per_server_frame": self.usable_ms.median(),
            "server_frames_received": self.server_frames_received,
            "server_frames_late": self.server_frames_late,
            "pairs_skipped": self.pairs_skipped,
            "pairs_probed": self.pairs_probed,
            "packets_undecodable": self.packets_undecodable,
            "server_age_ms_p50": self._ages.median(),
            "server_age_ms_max": self._ages.max,
            "achieved_fps": (n - misses) / self.wall_s if self.wall_s > 0 else 0.0,
            "wall_s": self.wall_s,
            "cpu_utilisation": self.cpu_s / (self.wall_s * self.cpus) if self.wall_s > 0 else 0.0,
            "host_steal_pct": None if self.host_steal is None else 100.0 * self.host_steal,
            "display_scheduling": self.display_scheduling,
            "warm_up_ms": self.warm_up_ms,
            "warm_up_seed_ms": (
                None if self.warm_up_seed_ms is None
                else {m: list(t) for m, t in self.warm_up_seed_ms.items()}
            ),
            "gpu_lost": self.gpu_lost,
            "gc_between_frames": self.gc_between_frames,
            "gc_collections": self.gc_collections,
            "gc_forced": self.gc_forced,
            "gc_ms_max": self.gc_ms_max,
        }


#: The most :class:`RateGovernor` divides the display rate by, by default
#: (``RealtimeClient(max_divisor=)``): half rate.
MAX_DIVISOR = 2


class RateGovernor:
    """Which refreshes the display renders: every ``divisor``-th, each frame shown for
    ``divisor`` refreshes and due at the refresh after them (``f_c / divisor`` frames per
    second).

    Why: a display frame longer than the refresh misses nearly every deadline (at 1280×720 on
    2 cores, ~9–14 ms against 8.33 ms at 120 Hz: 75–99 % missed, 1–16 frames a second on
    time, docs/realtime.md), and each late frame shows its refresh's pose a refresh late.
    Headset runtimes answer a late application the same way: they lock it to half the refresh
    rate and fill the other refreshes themselves (Oculus's asynchronous spacewarp at 45 of
    90 Hz, SteamVR's motion smoothing). Here the client is the part that synthesises frames,
    so it halves its own rate: each frame is on time at ``f_c / 2`` and the compositor repeats
    (or re-projects) it once.

    - **Down** by one (up to ``max_divisor``) when :data:`DOWN_MISSES` of the last
      :data:`WINDOW` frames at the current divisor missed their deadline. A lone late frame
      (a page fault, another process) changes nothing.
    - **Up** by one when every frame of the last second at the current divisor (``f_c /
      divisor`` frames) finished within :data:`HEADROOM` of the deadline it would have had at
      the divisor below (an interpolated frame counted at what it would have cost
      extrapolating, where :class:`ModeGovernor` defers interpolation that does not fit). The
      headroom and the second keep it from switching back and forth at the edge.

    ``max_divisor = 1`` keeps the full rate whatever the frames cost."""

    #: Frames at one divisor over which misses are counted.
    WINDOW = 8
    #: Misses among the last :data:`WINDOW` frames that divide the rate further.
    DOWN_MISSES = 4
    #: The share of the lower divisor's deadline every frame of a second must fit in before
    #: the rate goes back up.
    HEADROOM = 0.75

    @checked(display_fps=floats(positive=True, hi=MAX_RATE), max_divisor=ints(1, 16))
    def __init__(self, display_fps: float, max_divisor: int = MAX_DIVISOR) -> None:
        self.display_fps = float(display_fps)
        self.max_divisor = max_divisor
        self.divisor = 1
        self._missed: deque[bool] = deque(maxlen=self.WINDOW)  # the last frames at this divisor
        self._fitting = 0  # frames in a row at this divisor that would fit the one below

    def update(self, frame_s: float, met: bool) -> int:
        """Records a frame at the current divisor: ``frame_s`` seconds from its refresh until
        the next frame could start, ``met`` whether it was done by its deadline. Returns the
        divisor of the next frame."""
        d = self.divisor
        self._missed.append(not met)
        fits_below = d > 1 and frame_s <= self.HEADROOM * (d - 1) / self.display_fps
        self._fitting = self._fitting + 1 if fits_below else 0
        if d < self.max_divisor and sum(self._missed) >= self.DOWN_MISSES:
            self._switch(d + 1)
        elif d > 1 and self._fitting >= math.ceil(self.display_fps / d):
            self._switch(d - 1)
        return self.divisor

    def _switch(self, divisor: int) -> None:
        self.divisor = divisor
        self._missed.clear()
        self._fitting = 0


class ModeGovernor:
    """Whether a display frame that could interpolate its pair does, or extrapolates from the
    pair's older frame instead because an interpolated frame would not be done by its deadline
    (``RealtimeClient(defer_interpolation=)``).

    Why: an interpolated frame of ``ours`` costs about 1.6 times an extrapolated one (two
    sources to carry to the display camera and search instead of one). In a slow hour of a
    shared machine the interpolated frames' slowest few pass the refresh while the
    extrapolated ones still fit (640×360 at 120 Hz on 2 cores: 0.3–1.4 % of the frames missed,
    all of them interpolated; docs/realtime.md). A missed frame shows the last image for one
    more refresh (judder), then a pose a refresh old; extrapolated, it is on time, and only
    what the newer frame would have shown (disocclusions) is filled from the older one. Headset
    runtimes make the same trade: the deadline first, then the quality of the frame.

    - The render times of the last :data:`WINDOW` frames of each mode are kept.
    - The cost of an interpolated frame is the :data:`QUANTILE` of those kept of that mode;
      with fewer than :data:`MIN_FRAMES` of them, the extrapolated frames' quantile times the
      ratio of the two modes' medians, last measured together (without a ratio yet: the
      interpolated frames' quantile when interpolation was last deferred); before any of these,
      unknown.
    - A frame interpolates when that cost is unknown or fits within :data:`HEADROOM` of the
      time left to its deadline when it starts. When it does not, the interpolated frames
      kept are let go: from then on the cost follows the extrapolated frames (which go on
      being rendered), and interpolation resumes once it fits again.

    A frame that could not interpolate anyway (no pair yet, hold) does not ask, nor one whose
    older frame's extrapolation pair was not prepared off the display path. The
    :class:`RateGovernor` halves the rate only when the frames miss even so, and goes back up
    when they would fit the faster rate extrapolating (:meth:`cheapest_s`): 120 Hz with some
    frames extrapolated is a better display than 60 Hz with all of them interpolated."""

    #: Frames of each mode whose render times are kept.
    WINDOW = 120
    #: The share of the kept frames of a mode that the cost estimate covers.
    QUANTILE = 0.95
    #: Interpolated frames needed before their own times are the estimate (three, so that the
    #: display extrapolates before :class:`RateGovernor`'s fourth miss would halve the rate).
    MIN_FRAMES = 3
    #: The share of the time left to the deadline the estimate must fit in.
    HEADROOM = 0.9

    def __init__(self) -> None:
        self._times: dict[str, deque[float]] = {
            "interpolate": deque(maxlen=self.WINDOW),
            "extrapolate": deque(maxlen=self.WINDOW),
        }
        # The interpolated over the extrapolated frames' median, last measured together; and
        # the interpolated frames' (quantile, median) when interpolation was last deferred.
        self._ratio: float | None = None
        self._deferred_at: tuple[float, float] | None = None

    def _stats(self, mode: str) -> tuple[float, float] | None:
        """The :data:`QUANTILE` and the median of the kept frames of ``mode`` (``None``: fewer
        than :data:`MIN_FRAMES`)."""
        kept = self._times[mode]
        if len(kept) < self.MIN_FRAMES:
            return None
        ordered = sorted(kept)
        n = len(ordered)
        return ordered[max(0, math.ceil(self.QUANTILE * n) - 1)], ordered[(n - 1) // 2]

    def interpolation_s(self) -> float | None:
        """The estimated render time of an interpolated frame (seconds; ``None``: unknown)."""
        return self._estimate(self._stats("interpolate"))

    def _estimate(self, own: tuple[float, float] | None) -> float | None:
        """:meth:`interpolation_s` from the interpolated frames' ``own`` :meth:`_stats`."""
        if own is not None:
            return own[0]
        other = self._stats("extrapolate")
        if other is not None and self._ratio is not None:
            return other[0] * self._ratio
        return None if self._deferred_at is None else self._deferred_at[0]

    def allows(self, time_left_s: float) -> bool:
        """Whether a frame that could interpolate, with ``time_left_s`` to its deadline, does."""
        own = self._stats("interpolate")
        cost = self._estimate(own)
        if cost is None or cost <= self.HEADROOM * time_left_s:
            return True
        if own is not None:
            self._deferred_at = own
            self._times["interpolate"].clear()
        return False

    def record(self, mode: str, render_s: float) -> None:
        """Records a display frame of ``mode`` that took ``render_s`` seconds (``hold`` frames
        are not kept)."""
        if mode not in self._times:
            return
        self._times[mode].append(render_s)
        other = self._stats("extrapolate")
        if other is None or other[1] <= 0.0:
            return
        own = self._stats("interpolate")
        if own is not None:
            self._ratio = own[1] / other[1]
        elif self._ratio is None and self._deferred_at is not None:
            self._ratio = self._deferred_at[1] / other[1]

    def cheapest_s(self, mode: str, render_s: float) -> float:
        """What a frame of ``mode`` that took ``render_s`` seconds would have taken had its
        interpolation been deferred: divided by the ratio of the modes' medians for an
        interpolated frame (when the ratio is known and above 1), else ``render_s``."""
        if mode == "interpolate" and self._ratio is not None and self._ratio > 1.0:
            return render_s / self._ratio
        return render_s


#: Submitted packets kept for :meth:`RealtimeClient.wait` before the done ones are let go.
_PRUNE_PENDING = 64
#: How the receive worker yields the cores to the display (``RealtimeClient(worker_priority=)``).
WORKER_PRIORITIES = ("idle", "low", "normal")


def _arrivals(
    feed: Iterable[tuple[float, bytes | memoryview | ServerFrame]],
) -> Iterator[tuple[float, bytes | memoryview | ServerFrame]]:
    """The items of :meth:`RealtimeClient.run`'s ``feed``, each checked as it is taken (the feed
    may be a generator of packets as they arrive, so it is not read ahead)."""
    for i, item in enumerate(feed):
        where = f"feed[{i}]"
        if not isinstance(item, (tuple, list)) or len(item) != 2:
            raise InvalidInputError(
                f"{where}: expected a pair (display time, packet), got {describe(item)}"
            )
        yield (
            check_float(f"{where}[0]", item[0]),
            check_buffer(f"{where}[1]", item[1], (ServerFrame,)),
        )


def _yield_to_display(priority: str) -> None:
    """Lowers the receive worker's scheduling priority, per thread (Linux; the decoder's and the
    preparation pool's threads it starts inherit it), so that the display thread, whose frames
    have deadlines, gets the cores first:

    - ``"idle"``: the ``SCHED_IDLE`` policy. The worker runs mostly on a core the display leaves
      idle (between its frames: about 40 % of each refresh at 640×360 here), and a display
      thread that wakes takes the core back at once; the fair scheduler can still run it for
      up to a tick before a display thread that is runnable (:func:`_raise_display`). Where
      the platform has no ``SCHED_IDLE``, as ``"low"``.
    - ``"low"``: ``nice`` 10. The scheduler still gives the worker a share of a busy core, and a
      display frame that overlaps the worker's decoding can lose part of a core for a while.
    - ``"normal"``: unchanged.

    On 2 cores, ``idle`` against ``low`` (``splitrender bench --realtime --scale 0.25``, two
    sets of three rounds alternating, docs/realtime.md): 1.7–12.9 % deadline misses against
    13.5–18.0 %, lower in every pair of rounds; frames become usable 2–4 ms later. ``idle`` can
    starve the worker only if the display never sleeps, and a display that never sleeps has
    missed its deadlines anyway. Lowering needs no privilege; where the platform cannot,
    nothing changes."""
    if priority == "normal":
        return
    tid = threading.get_native_id()
    if priority == "idle" and hasattr(os, "SCHED_IDLE"):
        try:
            os.sched_setscheduler(tid, os.SCHED_IDLE, os.sched_param(0))
            return
        except OSError:
            pass  # e.g. a sandbox that refuses the call: fall back to nice
    try:
        os.setpriority(os.PRIO_PROCESS, tid, 10)
    except (AttributeError, OSError):
        pass


#: How :meth:`RealtimeClient.run` schedules the display's threads
#: (``RealtimeClient(display_priority=)``).
DISPLAY_PRIORITIES = ("realtime", "normal")

#: The real-time priority of the display's threads: the lowest, above every normal thread and
#: below the system's own real-time threads.
_DISPLAY_RT_PRIORITY = 1

_Saved = list[tuple[int, int, int]]  # (thread id, policy, priority) to restore

#: Late display frames in a row after which :meth:`RealtimeClient.run` gives the display's
#: threads their normal policy back (0.2 s at 120 Hz): a display that cannot keep up never
#: sleeps, and at real-time priority it would leave the worker, the network and every other
#: normal thread only the kernel's small reserve.
_OVERRUN_FRAMES = 24


def _raise_display(priority: str, threads: list[int]) -> tuple[str, _Saved]:
    """Gives the display's ``threads`` (:func:`_display_threads`) the ``SCHED_RR`` policy at
    priority 1 for ``priority == "realtime"``; returns how they are now scheduled and what to
    restore (:func:`_restore`).

    Why: Linux's fair scheduler (EEVDF) does not keep a runnable normal thread ahead of a
    ``SCHED_IDLE`` one. When one of the display's threads is switched out while runnable (it
    yields while looking for work, or a thread it wakes takes its core for a moment), the
    scheduler can pick the receive worker (decoding, preparing a pair) and run it until the
    next tick, 4 ms at 250 Hz: half a refresh at 120 Hz. A ``perf sched`` trace shows a
    display thread runnable and waiting 5.3 ms while the worker ran; a ``SCHED_IDLE`` busy loop
    beside the kernel (``PERIOD_MS=8.33 time_ours ours 640``) raises the paced frame's p99 from
    4.2 to 7.2–8.7 ms, and with the display's threads at ``SCHED_RR`` to 3.7–4.0 ms
    (docs/realtime.md). A real-time thread is never preempted by a normal one, so the worker
    gets exactly the time the display leaves idle.

    Real-time scheduling needs ``CAP_SYS_NICE`` or an ``RLIMIT_RTPRIO`` of at least 1; where it
    is refused, nothing changes and the returned text says why. The display thread sleeps
    between frames, so the worker keeps the rest of each refresh; a display that never sleeps
    (frames longer than a refresh) would leave it only the kernel's reserve for normal threads
    (5 % by default), so :meth:`RealtimeClient.run` restores the normal policy after
    :data:`_OVERRUN_FRAMES` late frames in a row."""
    if priority == "normal":
        return "normal", []
    if not hasattr(os, "SCHED_RR"):
        return "normal (no real-time scheduling on this platform)", []
    saved: _Saved = []
    try:
        for tid in threads:
            old = (tid, os.sched_getscheduler(tid), os.sched_getparam(tid).sched_priority)
            os.sched_setscheduler(tid, os.SCHED_RR, os.sched_param(_DISPLAY_RT_PRIORITY))
            saved.append(old)
    except OSError as e:
        _restore(saved)
        return f"normal (real-time scheduling refused: {e.strerror or e})", []
    return "realtime", saved


def _display_threads() -> list[int]:
    """The kernel thread ids of the display's threads: the calling (display) thread and the
    threads ``reproject`` runs on (:func:`splitrender._native.render_thread_ids`, which starts
    them on its first call)."""
    return [threading.get_native_id(), *_native.render_thread_ids()]


def _restore(saved: _Saved) -> None:
    """Gives each thread of ``saved`` its policy and priority back (:func:`_raise_display`)."""
    for tid, policy, prio in reversed(saved):
        try:
            os.sched_setscheduler(tid, policy, os.sched_param(prio))
        except OSError:
            pass  # the thread has exited, or the process lost the privilege: nothing to undo


#: The threads of the worker's pair preparation by default (``RealtimeClient(prepare_threads=)``).
#: At idle priority two of them take both cores whenever the display leaves them, and on the
#: project's 2-core machine at 640×360 and 120 Hz a pair was usable 3–4 ms sooner with two; but
#: runs missed a deadline three times as often (docs/realtime.md, "The pair prepared on two
#: threads"), so the default is one.
PREPARE_THREADS = 1

#: Methods whose client frames use pair-level state that :func:`prepare_pair` can compute.
_PREPARED_METHODS = ("ours", "ours_extrapolate", "forward_splat")

#: The least part of its interval an interpolation pair must still have ahead of it, once
#: prepared, for the worker to prepare it. The pair ``(k − 1, k)`` is shown from display time
#: ``t_{k−1}`` to ``t_k``; where the worker's estimate of its preparation
#: (:meth:`RealtimeClient._pair_too_late`) leaves less than this share of that interval, the pair
#: would cost the worker its time and show in few frames or none, while the frame waited for it.
#: The frame is then prepared to extrapolate from and becomes usable at its own time ``t_k``.
MIN_PAIR_USE = 0.25

#: After this many interpolation pairs skipped in a row, the worker prepares the next one
#: anyway, to measure it again (:meth:`RealtimeClient._skip_pair`); each such pair that is
#: still too late doubles the count, up to :data:`PAIR_PROBE_MAX`. Why: the estimate is taken
#: from the last pair prepared, so once one pair is skipped no later one is measured. Its
#: scaling by the decode time follows the display's load, but not a pair that was slow by
#: itself (the first after start-up, a page-fault storm): without a new measurement, one such
#: pair would keep interpolation off for the rest of the session.
PAIR_PROBE_AFTER = 10

#: The most pairs skipped in a row between two measurements (:data:`PAIR_PROBE_AFTER`): at
#: 10 server frames per second, one pair in 8 s where pairs never fit.
PAIR_PROBE_MAX = 80

#: A prepared pair: the older frame's index (``None``: to extrapolate) and its state.
_Prepared = tuple[int | None, _native.BidirHistory | GpuPair]


@dataclass
class _Received:
    """A server frame the worker has decoded and prepared, waiting to be handed to the client
    (:meth:`RealtimeClient._release_due`), in the order received: from display time
    ``release_at`` on (``-inf``: at once)."""

    frame: ServerFrame
    states: list[_Prepared]
    release_at: float
    pose_time: float | None
    usable_ms: float


def _clock(where: str, value: object) -> Any:
    if not all(callable(getattr(value, m, None)) for m in ("now", "sleep_until")):
        raise InvalidInputError(
            f"{where}: expected a Clock (now() and sleep_until(t)), got {type(value).__name__}"
        )
    return value


def _decoder(where: str, value: object) -> Any:
    from splitrender.codec.coder import StreamDecoder  # the codec imports this module's users

    return check_instance(where, value, StreamDecoder)


class RealtimeClient:
    """The real-time client (module docs): packets in (:meth:`submit`, any thread), one frame
    per refresh out (:meth:`run`, or :meth:`render` for a caller with its own display loop).

    ``display_fps`` is ``f_c``; ``clock`` defaults to :class:`MonotonicClock`; ``client`` (else
    a new :class:`Client` of ``method``, ``options``, ``capacity`` and ``backend``) renders the
    frames. On the GPU (``backend="wgpu"``) the worker uploads each pair
    (:meth:`~splitrender.gpu.GpuReprojector.upload`) and the display makes it current with no
    copy. ``prepare_threads`` is how many threads the CPU's pair preparation uses (its own pool,
    so that it does not queue behind the display's frames; default :data:`PREPARE_THREADS`;
    ``None``: the shared pool).
    ``worker_priority`` (one of :data:`WORKER_PRIORITIES`, default ``"idle"``) is how the default
    worker thread yields the cores to the display (:func:`_yield_to_display`).
    ``display_priority`` (one of :data:`DISPLAY_PRIORITIES`, default ``"realtime"``) is how
    :meth:`run` schedules the display thread and the threads it renders on while it shows frames
    (:func:`_raise_display`; restored when it returns; the report's ``display_scheduling`` says
    what it got). ``max_divisor`` is the most :meth:`run` may divide the display rate by when
    its frames do not fit the refresh (:class:`RateGovernor`; default 2, half rate; 1 keeps
    ``f_c`` whatever the frames cost). ``defer_interpolation`` (default ``True``): a frame that
    could interpolate its pair extrapolates from the pair's older frame instead where an
    interpolated frame would not be done by its deadline (:class:`ModeGovernor`; ``False``
    interpolates whatever it costs; ``backward_bidir``, which cannot extrapolate, always
    interpolates). ``keep_frames`` is how many display frames the report
    keeps one by one (:attr:`RealtimeReport.frames`: the newest; default :data:`KEEP_FRAMES`,
    ``None``: all, memory growing with the run); its summary covers every frame either way.
    ``executor`` runs the receive side instead (it must run jobs in order; its threads keep
    their priority). The client owns the ``decoder`` and ``executor`` it is given:
    :meth:`close` closes the one and shuts the other down. ``on_handover`` is called with a
    :class:`Handover` for each server frame handed to the display during :meth:`run`, in order,
    under the client's lock, on the thread that hands it over (the display thread, or the
    worker when a frame arrives after its time): keep it short. It is called after the
    handover is complete; an exception it raises reaches :meth:`run`'s caller from the display
    thread, or from the worker the future of the packet whose receipt handed the frame over
    (and :meth:`wait`). Use as a context manager, or call :meth:`close`.

    Raises:
        InvalidInputError: for an unknown method, invalid options, a method the backend cannot
            run or a ``display_fps`` that is not a positive finite number.
        GpuUnavailableError: for ``backend="wgpu"`` without a GPU adapter.
    """

    @checked(
        display_fps=floats(positive=True, hi=MAX_RATE), clock=optional(_clock),
        client=optional(instances(Client)), capacity=ints(2, 1 << 16),
        prepare_threads=optional(ints(1, MAX_PREPARE_THREADS)), decoder=optional(_decoder),
        executor=optional(instances(Executor)), worker_priority=strs(*WORKER_PRIORITIES),
        display_priority=strs(*DISPLAY_PRIORITIES), backend=strs(*BACKENDS),
        max_divisor=ints(1, 16), defer_interpolation=BOOL,
        keep_frames=optional(ints(0, 1 << 40)), on_handover=optional(CALLABLE),
    )
    def __init__(
        self,
        method: str = "ours",
        options: ReprojectOptions | None = None,
        *,
        display_fps: float = DISPLAY_FPS,
        clock: Clock | None = None,
        client: Client | None = None,
        capacity: int = 4,
        prepare_threads: int | None = PREPARE_THREADS,
        decoder: StreamDecoder | None = None,
        executor: Executor | None = None,
        worker_priority: str = "idle",
        display_priority: str = "realtime",
        backend: str = "cpu",
        max_divisor: int = MAX_DIVISOR,
        defer_interpolation: bool = True,
        keep_frames: int | None = KEEP_FRAMES,
        on_handover: Callable[[Handover], None] | None = None,
    ) -> None:
        self.client = (
            client
            if client is not None
            else Client(method, options, capacity=capacity, backend=backend)
        )
        self.display_fps = float(display_fps)
        self.clock: Clock = clock if clock is not None else MonotonicClock()
        self.prepare_threads = prepare_threads
        self.worker_priority = worker_priority
        self.display_priority = display_priority
        self.max_divisor = max_divisor
        self.defer_interpolation = defer_interpolation
        self.keep_frames = keep_frames
        self.on_handover = on_handover
        self._decoder = decoder
        self._lock = threading.Lock()
        # One worker: packets are decoded in order (each depends on the previous one's
        # pictures) and a frame's pairs are prepared before the next frame's.
        self._worker = (
            executor
            if executor is not None
            else ThreadPoolExecutor(
                1,
                thread_name_prefix="splitrender-receive",
                initializer=_yield_to_display,
                initargs=(worker_priority,),
            )
        )
        self._closed = False
        self._queued = 0  # packets submitted and not yet being received
        self._pending: list[Future[int | None]] = []
        # submit() is called from any thread: the worker's order and _pending's are one order.
        self._submit_lock = threading.Lock()
        # The pose time of each frame the client holds (its entries go with the frames, so that
        # a client that runs for hours keeps no state per frame it has dropped).
        self._pose_time: dict[int, float] = {}
        # Received frames not yet handed to the client, oldest first (_release_due).
        self._received: list[_Received] = []
        # The clock at display time 0 while run() shows frames (None otherwise): what tells the
        # worker how much of a pair's interval is left; and the clock when that run started.
        self._origin: float | None = None
        self._run_t0 = 0.0
        # The seconds (on the clock) of the last interpolation pair prepared, and of its
        # frame's decode (None: handed over decoded).
        self._pair_cost: tuple[float, float | None] | None = None
        # Interpolation pairs skipped since the last one prepared, and how many make the worker
        # prepare the next to measure it again (PAIR_PROBE_AFTER).
        self._skipped_in_a_row = 0
        self._probe_after = PAIR_PROBE_AFTER
        self._report = RealtimeReport(self.display_fps, self.keep_frames)
        self._interpolates = interpolates(self.method, self.client.options.splat_bidirectional)
        # backward_bidir cannot extrapolate: deferring its interpolation would hold the image.
        self._defers = defer_interpolation and self.method != "backward_bidir"

    @property
    def method(self) -> str:
        return self.client.method

    def __enter__(self) -> RealtimeClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @checked(drop_pending=BOOL)
    def close(self, *, drop_pending: bool = False) -> None:
        """Stops the worker and the decoder: after the packets already submitted, or with
        ``drop_pending`` after the one being received (the others' futures are cancelled)."""
        self._closed = True
        self._worker.shutdown(wait=True, cancel_futures=drop_pending)
        if self._decoder is not None:
            self._decoder.close()

    # -- receive and prepare (worker thread) -----------------------------------------------

    @checked(packet=buffers(ServerFrame), pose_time=optional(floats()))
    def submit(
        self, packet: bytes | memoryview | ServerFrame, *, pose_time: float | None = None
    ) -> Future[int | None]:
        """Hands over a server packet (or an already decoded :class:`ServerFrame`) as it
        arrives; returns at once. The worker decodes it, prepares its pairs and then makes it
        usable (or, without its interpolation pair, :data:`MIN_PAIR_USE`, due at its own
        time); the future gives its index (``None``: the client refused it, e.g. stale). A
        packet that cannot be decoded sets the future's exception (a
        :class:`~splitrender.errors.StreamError`) and is otherwise ignored: the display goes on
        extrapolating. ``pose_time``: when the pose of this frame was taken (default: the
        frame's time minus the period it spans, when the model's server sends it).

        Raises:
            InvalidInputError: for a packet that is not bytes, a bytearray, a C-contiguous
                memoryview or a :class:`ServerFrame`, a ``pose_time`` that is not a finite
                float, or a client that was closed."""
        return self._submit(packet, pose_time)

    def _submit(
        self, packet: bytes | memoryview | ServerFrame, pose_time: float | None = None
    ) -> Future[int | None]:
        """:meth:`submit` without its argument checks, for :meth:`run`'s arrivals, which
        :func:`_arrivals` has checked."""
        self._check_open()
        with self._submit_lock:
            with self._lock:
                self._queued += 1
            fut = self._worker.submit(self._receive, packet, pose_time)
            if len(self._pending) >= _PRUNE_PENDING:
                # What wait() needs of the done ones is the first error; the rest (a failed one
                # holds its packet) went unbounded for a client that never waits (a live
                # session).
                failed = [f for f in self._pending
                          if f.done() and not f.cancelled() and f.exception() is not None]
                first = failed[0] if failed else None
                self._pending = [f for f in self._pending if not f.done() or f is first]
            self._pending.append(fut)
        return fut

    def _check_open(self) -> None:
        if self._closed:
            raise InvalidInputError("RealtimeClient: the client is closed (close() was called)")

    def wait(self, timeout: float | None = None) -> None:
        """Blocks until every packet submitted so far is usable, refused or due at its own
        time (:data:`MIN_PAIR_USE`). ``timeout``: seconds for the whole wait (default: none).

        Raises:
            StreamError: the first error of the packets waited for (those after it are left
                to the next ``wait``).
            TimeoutError: when ``timeout`` passed first; the packets not yet received are
                left to the next ``wait``."""
        deadline = None if timeout is None else time.monotonic() + timeout
        with self._submit_lock:
            pending = list(self._pending)
        waited = 0
        try:
            for fut in pending:
                left = None if deadline is None else max(0.0, deadline - time.monotonic())
                try:
                    fut.result(left)
                except TimeoutError as e:
                    # The wait's timeout leaves the packet to the next wait.
                    if fut.done() and not fut.cancelled() and fut.exception() is e:
                        waited += 1
                    raise
                except BaseException:
                    waited += 1  # its own error, raised once
                    raise
                waited += 1
        finally:
            # Each packet is waited for once (a timeout used to drop the ones not yet
            # waited for, and then each future had the whole timeout).
            gone = {id(f) for f in pending[:waited]}
            with self._submit_lock:
                self._pending = [f for f in self._pending if id(f) not in gone]

    def _decode(self, packet: bytes | memoryview) -> ServerFrame:
        if self._decoder is None:
            from splitrender.codec.coder import StreamDecoder

            self._decoder = StreamDecoder()
        return self._decoder.decode(packet)

    def _receive(
        self, packet: bytes | memoryview | ServerFrame, pose_time: float | None
    ) -> int | None:
        with self._lock:
            self._queued -= 1
        t0, c0 = time.perf_counter(), self.clock.now()
        try:
            frame = packet if isinstance(packet, ServerFrame) else self._decode(packet)
        except StreamError as e:
            # The display goes on without it (the future holds the error); the report says so.
            with self._lock:
                self._report.add_undecodable(str(e))
            raise
        t1, c1 = time.perf_counter(), self.clock.now()
        # On the run's clock, which is what the estimate of a pair's preparation is held to.
        decode_s = None if isinstance(packet, ServerFrame) else c1 - c0
        with self._lock:
            # The frame it closes a pair with (ServerFrame.span: equal spans, that far apart),
            # held or still waiting to be handed over.
            older = self._held_or_received(frame.index - frame.span)
            if older is not None and older.span != frame.span:
                older = None
            # prepare_pair only checks the camera (the pair's work does not depend on it):
            # the frame's own, checked with it. The display's last camera was used here, so
            # one the display had refused, or accepted while nothing was held (a singular
            # one gave black), failed every later frame's pair.
            camera = frame.main.camera
            spare = self.client.retired_histories()
            # Device pairs the display no longer uses: dropped below, on this thread and outside
            # the lock the display takes, so that freeing their memory costs no display frame.
            retired = self.client.retired_uploads()
            # Behind (a newer packet is already waiting): this frame is about to be superseded,
            # so it is handed over at once and the worker's time goes to catching up; a display
            # frame that still renders its pair does the pair work itself.
            behind = self._queued > 0
            prepares = self.method in _PREPARED_METHODS and not behind
            interpolates = older is not None and self._interpolates
            skip = prepares and interpolates and self._skip_pair(frame, decode_s)
        del retired
        pairs: list[ServerFrame | None] = []
        if prepares:
            # The pair that makes the frame usable first: to interpolate towards it when the
            # method does and the older frame is held, else to extrapolate from it. The
            # extrapolation pair is needed only when the next frame is late, a server period
            # from now, so it is prepared after the frame is handed over.
            pairs = [older, None] if interpolates and not skip else [None]
        first = self._prepare(pairs[:1], frame, camera, spare)
        t2 = time.perf_counter()
        with self._lock:
            if pairs and pairs[0] is not None:
                self._pair_cost = (self.clock.now() - c1, decode_s)
            if decode_s is not None:
                self._report.decode_ms.add((t1 - t0) * 1e3)
            # Without its interpolation pair the frame is used from its own time on, to
            # extrapolate from: handed over earlier, the display would interpolate towards it
            # and do the pair's work itself.
            entry = _Received(
                frame, first, frame.time if skip else -math.inf, pose_time, (t2 - t0) * 1e3
            )
            self._report.pairs_skipped += skip
            self._received.append(entry)
            handed = self._release_due(self._display_now(), own=frame.index)
            if handed.get(frame.index) is False:
                return None
            rest = pairs[1:] if self._queued == 0 else []
        later = self._prepare(rest, frame, camera, spare)
        t3 = time.perf_counter()
        with self._lock:
            if any(e is entry for e in self._received):
                entry.states.extend(later)
            else:
                self._adopt_held(frame.index, later)
            if first or later:
                self._report.prepare_ms.add((t2 - t1 + t3 - t2) * 1e3)
        return frame.index

    def _held_or_received(self, index: int) -> ServerFrame | None:
        """Frame ``index``, held by the client or received and waiting (under the lock)."""
        held = self.client.held_frame(index)
        if held is not None:
            return held
        return next((e.frame for e in self._received if e.frame.index == index), None)

    def _display_now(self) -> float:
        """The display time now while :meth:`run` shows frames, else ``-inf`` (under the
        lock)."""
        return -math.inf if self._origin is None else self.clock.now() - self._origin

    def _pair_too_late(self, frame: ServerFrame, decode_s: float | None) -> bool:
        """Whether the interpolation pair that ``frame`` closes would be ready with less than
        :data:`MIN_PAIR_USE` of its interval ahead (under the lock). The estimate is the last
        such pair's preparation, scaled by this frame's decode time against that one's: both
        run on the worker in the cycles the display leaves, so the ratio follows the display's
        load. Without an estimate, or outside :meth:`run`, the pair is prepared."""
        if self._origin is None or self._pair_cost is None:
            return False
        pair_s, decode_then = self._pair_cost
        if decode_s is not None and decode_then is not None and decode_then > 1e-3:
            pair_s *= decode_s / decode_then
        period = frame.span / self.client.server_fps
        left = self._origin + frame.time - (self.clock.now() + pair_s)
        return left < MIN_PAIR_USE * period

    def _skip_pair(self, frame: ServerFrame, decode_s: float | None) -> bool:
        """Whether the worker skips the interpolation pair that ``frame`` closes (under the
        lock): where it would be too late (:meth:`_pair_too_late`), unless
        :data:`PAIR_PROBE_AFTER` pairs were skipped in a row, when it is prepared to be
        measured again and the count doubles (up to :data:`PAIR_PROBE_MAX`). A pair that fits
        resets the count."""
        if not self._pair_too_late(frame, decode_s):
            self._skipped_in_a_row = 0
            self._probe_after = PAIR_PROBE_AFTER
            return False
        if self._skipped_in_a_row >= self._probe_after:
            self._skipped_in_a_row = 0
            self._probe_after = min(2 * self._probe_after, PAIR_PROBE_MAX)
            self._report.pairs_probed += 1
            return False
        self._skipped_in_a_row += 1
        return True

    def _release_due(
        self, display_time: float, own: int | None = None
    ) -> dict[int, bool]:
        """Hands the received frames due by ``display_time`` to the client, oldest first, and
        stops at the first that is not (under the lock). Returns whether the client accepted
        each frame handed over, by index. A frame the client rejects with an error (its time
        contradicts the frames held) is dropped as refused, unless it is ``own`` (the worker's
        current frame), whose error is raised for its future as before: a frame from the wire
        must not stop the display thread."""
        handed: dict[int, bool] = {}
        events: list[Handover] = []
        while self._received and self._received[0].release_at <= display_time + TIME_EPS:
            entry = self._received.pop(0)
            frame = entry.frame
            try:
                accepted = self.client.receive(frame)
            except InvalidInputError:
                if frame.index == own:
                    raise
                accepted = False
            handed[frame.index] = accepted
            if not accepted:
                continue
            for older_index, state in entry.states:
                self._adopt(older_index, frame.index, state)
            self._report.server_frames_received += 1
            self._report.usable_ms.add(entry.usable_ms)
            period = frame.span / self.client.server_fps
            if self._origin is not None:
                late = self._late(frame.time, period)
                self._report.server_frames_late += late
                events.append(Handover(frame.index, frame.time, self._display_now(), late))
            self._pose_time[frame.index] = (
                frame.time - period if entry.pose_time is None else entry.pose_time
            )
        if handed:
            # Once for all the frames handed over: a later one may have retired an earlier one.
            self._forget_dropped(self.client.held)
        if self.on_handover is not None:
            for event in events:
                self.on_handover(event)
        return handed

    def _forget_dropped(self, held: tuple[int, ...]) -> None:
        """Drops the pose times of the frames the client no longer holds (under the lock)."""
        if not set(self._pose_time) <= set(held):
            self._pose_time = {i: t for i, t in self._pose_time.items() if i in held}

    def _late(self, frame_time: float, period: float) -> bool:
        """Whether a frame at ``frame_time`` whose pair spans ``period`` seconds is late, handed
        over now during :meth:`run` (under the lock): after the display first needed it, one
        period before its time, when the pair it closes starts. A frame needed before the run
        began counts from the start of the run."""
        assert self._origin is not None
        needed = max(self._run_t0, self._origin + frame_time - period)
        return self.clock.now() > needed

    def _prepare(
        self,
        olders: list[ServerFrame | None],
        frame: ServerFrame,
        camera: Camera,
        spare: list[_native.BidirHistory],
    ) -> list[tuple[int | None, _native.BidirHistory | GpuPair]]:
        """The pair state of ``(older, frame)`` for each of ``olders`` (``None``: to extrapolate
        from ``frame``): on the CPU, histories taken from ``spare`` or new ones; on the GPU, the
        pair uploaded to the device."""
        out: list[tuple[int | None, _native.BidirHistory | GpuPair]] = []
        gpu = self.client.gpu
        for o in olders:
            state: _native.BidirHistory | GpuPair | None = None
            if gpu is not None:
                try:
                    state = gpu.upload(o, frame)
                except GpuDeviceLostError as e:
                    # The display goes on on the CPU (Client.lose_gpu), and so does this pair.
                    with self._lock:
                        self.client.lose_gpu(gpu.lost or str(e))
                    gpu = None
            if state is None:
                state = spare.pop() if spare else _native.BidirHistory()
                state.reset()
                prepare_pair(
                    o,
                    frame,
                    camera,
                    self.method,
                    options=self.client.options,
                    history=state,
                    threads=self.prepare_threads,
                )
            out.append((None if o is None else o.index, state))
        return out

    def _adopt(
        self, older: int | None, newer: int, state: _native.BidirHistory | GpuPair
    ) -> None:
        """Hands a prepared pair (:meth:`_prepare`) to the client (under the lock)."""
        if isinstance(state, _native.BidirHistory):
            self.client.adopt_prepared(older, newer, state)
        else:
            self.client.adopt_uploaded(older, newer, state)

    def _adopt_held(
        self, newer: int, states: list[tuple[int | None, _native.BidirHistory | GpuPair]]
    ) -> None:
        """Hands the pairs ``states`` (:meth:`_prepare`) of frame ``newer``, prepared after it
        was handed over, to the client (under the lock): only while the frame is held (else the
        history would wait in the client until its next render retires it), and only a pair not
        adopted meanwhile (the warm-up and the worker may prepare the same one: the first is
        kept)."""
        if self.client.held_frame(newer) is None:
            return
        for older, state in states:
            if not self.client.was_prepared(older, newer):
                self._adopt(older, newer, state)

    def _could_defer(self, time: float) -> bool:
        """Whether a display frame at ``time`` could interpolate and may be deferred to its
        pair's older frame, whose extrapolation pair is prepared (under the lock): one the
        display prepared itself would cost more than the interpolated frame (the worker leaves
        it out when behind)."""
        could = self.client.choose(time)
        return (
            could.mode == "interpolate"
            and could.older is not None
            and self.client.was_prepared(None, could.older)
        )

    # -- display ---------------------------------------------------------------------------

    @checked(interpolate=BOOL)
    def render(
        self, camera: Camera, time: float, *, eye: int = 0, interpolate: bool = True
    ) -> _Image:
        """The display frame at ``camera`` and display ``time`` from the frames usable now
        (:meth:`Client.render`: read-only, the eye's previous output for the next frame's
        unmatched pixels; ``interpolate`` as its); :attr:`Client.last_info` says how it was
        made.

        Raises:
            InvalidInputError: as :meth:`Client.render`, and for a client that was closed."""
        self._check_open()
        return self._render((camera,), time, eye, interpolate)[0][0]

    def _render(
        self,
        cameras: Sequence[Camera],
        time: float,
        first_eye: int = 0,
        interpolate: bool | Callable[[], bool] = True,
    ) -> tuple[list[_Image], bool, float | None, bool]:
        """:meth:`render` of each of ``cameras`` (eyes ``first_eye``, ``first_eye + 1``, …), and
        (under the same lock, so that the worker cannot change them in between) whether its pair
        was prepared, the pose time of the newest usable frame, and whether interpolation was
        deferred. ``interpolate``: as :meth:`Client.render`'s, or the :class:`ModeGovernor`'s
        question, asked only when the frame could interpolate and the extrapolation pair of the
        pair's older frame is prepared. The eyes of a stereo frame are rendered under one hold
        of the lock: the worker cannot hand a new pair over between them, so both eyes show the
        same server frames at the same α."""
        with self._lock:
            self._release_due(time)
            deferred = False
            if callable(interpolate):
                deferred = self._could_defer(time) and not interpolate()
                interpolate = not deferred
            images = [
                self.client.render(c, time, eye=first_eye + e, interpolate=interpolate)
                for e, c in enumerate(cameras)
            ]
            info = self.client.last_info
            assert info is not None
            prepared = info.newer is not None and self.client.was_prepared(info.older, info.newer)
            held = self.client.held
            self._forget_dropped(held)
            newest = self._pose_time[max(held)] if held else None
        return images, prepared, newest, deferred

    @overload
    def run(
        self,
        pose: Callable[[float], Camera],
        seconds: float,
        *,
        feed: Iterable[tuple[float, bytes | memoryview | ServerFrame]] = ...,
        start_time: float = ...,
        on_frame: Callable[[_Image, DisplayFrame], None] | None = ...,
        exclusive: bool = ...,
        warm_up: bool = ...,
        stereo: Literal[False] = ...,
    ) -> RealtimeReport: ...
    @overload
    def run(
        self,
        pose: Callable[[float], tuple[Camera, Camera]],
        seconds: float,
        *,
        feed: Iterable[tuple[float, bytes | memoryview | ServerFrame]] = ...,
        start_time: float = ...,
        on_frame: Callable[[tuple[_Image, _Image], DisplayFrame], None] | None = ...,
        exclusive: bool = ...,
        warm_up: bool = ...,
        stereo: Literal[True],
    ) -> RealtimeReport: ...
    @overload
    def run(
        self,
        pose: Callable[[float], Any],
        seconds: float,
        *,
        feed: Iterable[tuple[float, bytes | memoryview | ServerFrame]] = ...,
        start_time: float = ...,
        on_frame: Callable[[Any, DisplayFrame], None] | None = ...,
        exclusive: bool = ...,
        warm_up: bool = ...,
        stereo: bool = ...,
    ) -> RealtimeReport: ...
    @checked(pose=CALLABLE, feed=ITERABLE, start_time=floats(), on_frame=optional(CALLABLE),
             exclusive=BOOL, warm_up=BOOL, stereo=BOOL)
    def run(
        self,
        pose: Callable[[float], Any],
        seconds: float,
        *,
        feed: Iterable[tuple[float, bytes | memoryview | ServerFrame]] = (),
        start_time: float = 0.0,
        on_frame: Callable[[Any, DisplayFrame], None] | None = None,
        exclusive: bool = False,
        warm_up: bool = False,
        stereo: bool = False,
    ) -> RealtimeReport:
        """Shows ``seconds`` of display frames at ``f_c`` from display time ``start_time``:
        frame ``n`` at the camera ``pose(start_time + n / f_c)``. ``feed`` (optional) is the
        arrivals, ``(display time, packet)`` in time order: each is submitted when the clock
        reaches it (between display frames; a live client calls :meth:`submit` from its network
        thread instead). ``on_frame(image, record)`` is called after each frame (the caller's
        present; its time counts against the frame's deadline only if it runs past the next
        refresh; ``image`` is read-only, as :meth:`Client.render` returns it). Returns the
        report of the run: its display frames, and what the worker did since the previous run
        returned (or since the client was made).

        ``exclusive`` (a diagnostic; a live client cannot wait): after each arrival the display
        waits until the worker has received it (decoded and prepared, or refused) and the
        schedule of refreshes moves on by the time waited, so that no display frame shares the
        cores with the worker. The deadlines then measure the display frames alone, and no
        server frame is late.

        ``warm_up``: before the clock starts, the arrivals due by ``start_time`` are received
        (decoded and prepared, the held frames' extrapolation pairs included), the garbage
        collector's first full collection runs (below), and one frame is rendered at
        ``pose(start_time)``, off the record (with what follows, the report's
        ``warm_up_ms``), as a headset shows nothing until its first frame is in. The display's
        buffers then exist before the first recorded frame, which would otherwise pay their
        first-touch page faults (about 4 ms at 640×360 here). Where that frame could
        interpolate and interpolation may be deferred, three frames of each mode follow, timed
        for the :class:`ModeGovernor`, so that the first pair's frames extrapolate from the
        first refresh where interpolating would not fit.

        ``stereo``: a headset's display frame is two images. ``pose(t)`` returns the eyes'
        cameras ``(left, right)`` (a headset runtime gives each eye's pose and field of view;
        :meth:`Camera.stereo` makes them from a head camera), both are rendered from the same
        server frames at the same α, one after the other, and the frame's deadline holds for
        both (its render time is theirs together); ``on_frame`` gets ``(left image, right
        image)``. Each eye keeps its own previous output (eyes 0 and 1 of
        :meth:`Client.render`).

        While the frames run, Python's garbage collector is the display's: automatic
        collection is off (in every thread of the process) and each collection runs between
        two frames, where the time to the next refresh holds it
        (:class:`~splitrender.client.collector.FrameCollector`; the report's ``gc_*``). After
        the run it is as it was; a collector the application disabled is left disabled.

        Raises:
            InvalidInputError: for arguments of the wrong type, ``seconds`` shorter than one
                display frame, an item of ``feed`` that is not a pair ``(finite display time,
                packet)`` (raised when the run reaches it), a ``pose`` that with ``stereo``
                returns anything but a pair of cameras, or a client that was closed."""
        self._check_open()
        fc = self.display_fps
        valid = not isinstance(seconds, bool) and isinstance(seconds, (int, float))
        # Checked before rounding: round() of NaN or infinity raises a ValueError of its own.
        if not valid or not math.isfinite(seconds) or round(seconds * fc) < 1:
            raise InvalidInputError(
                f"seconds: expected at least one display frame at {fc:g} FPS, got {seconds!r}"
            )
        n_frames = int(round(seconds * fc))
        report = self._report
        report.eyes = 2 if stereo else 1

        def views(t: float) -> tuple[Camera, ...]:
            return _eye_cameras(pose, t) if stereo else (pose(t),)

        # Before the clock starts: the first call may start the render threads.
        threads = _display_threads()
        report.display_scheduling, saved = _raise_display(self.display_priority, threads)
        arrivals = _arrivals(feed)
        interval = sys.getswitchinterval()
        collector = FrameCollector()
        # Created here, not in _display: the warm-up seeds it.
        modes = ModeGovernor()
        try:
            if warm_up:
                arrivals = self._warm_up(report, views, arrivals, start_time, modes, collector)
            # Off the clock: its first full collection walks every object of the process (with
            # warm_up, already started before the warm-up's frames).
            collector.start()
            # Read before the clock starts: /proc/stat took 0.2-0.3 ms here, and refresh 0 is t0.
            cpu0 = time.process_time()
            times0 = cpu_times()
            t0 = self.clock.now()
            if not exclusive:
                # An exclusive run waits for the worker, so no pair is ever late there.
                with self._lock:
                    self._origin = t0 - start_time
                    self._run_t0 = t0
            # Python hands the GIL to a waiting thread only every switch interval (5 ms by
            # default): the display thread could wait that long behind the worker's Python code
            # between two native calls. 0.5 ms keeps that wait well inside a frame.
            sys.setswitchinterval(min(interval, 0.0005))
            end = self._display(
                report, t0, n_frames, views, arrivals, start_time, on_frame, exclusive, saved,
                _thread_cpu_clocks(threads), collector, modes,
            )
        finally:
            # Whatever ended the run (the warm-up's or a frame's error included).
            with self._lock:
                self._origin = None
            _restore(saved)
            sys.setswitchinterval(interval)
            report.gc_between_frames = collector.active
            collector.stop()
        report.gc_collections = collector.collections
        report.gc_forced = collector.forced
        report.gc_ms_max = collector.longest_s * 1e3
        # To the end of the last refresh, not the last frame's completion: the frames of
        # `seconds` took (n - 1) / f_c plus a frame's time, and 120 frames at 120 FPS were
        # reported as 120.9 FPS achieved.
        report.wall_s = max(self.clock.now(), end) - t0
        report.cpu_s = time.process_time() - cpu0
        report.host_steal = steal_share(times0, cpu_times())
        report.cpus = usable_cpus()  # the CPUs its threads can use, as rayon counts them
        with self._lock:
            report.gpu_lost = self.client.gpu_lost
            self._report = RealtimeReport(self.display_fps, self.keep_frames)
        return report

    def _warm_up(
        self,
        report: RealtimeReport,
        views: Callable[[float], tuple[Camera, ...]],
        arrivals: Iterator[tuple[float, bytes | memoryview | ServerFrame]],
        start_time: float,
        modes: ModeGovernor,
        collector: FrameCollector,
    ) -> Iterator[tuple[float, bytes | memoryview | ServerFrame]]:
        """The warm-up of :meth:`run` (``warm_up``); returns the arrivals not yet submitted.

        The packets due by ``start_time`` are submitted together, so the worker is behind on
        all but the last and leaves out their extrapolation pairs (:meth:`_receive`): the held
        frames' missing ones are prepared here (:meth:`_prepare_extrapolations`). Without the
        older frame's, :meth:`_render` never asks ``modes`` for the first pair's frames, which
        then interpolated however long that took: on a 2-core Intel Xeon (model 207) 19 of the
        70 misses of twelve 10 s runs at 640×360 were the first pair's frames
        (docs/realtime.md, "The first pair's frames"). Then ``modes`` is seeded
        (:meth:`_seed_modes`), so that it knows from refresh 0 on whether interpolating fits.

        ``collector`` is started after the packets are in and before the frames: its first
        full collection walks every object of the process and leaves the caches cold, which
        cost the frame right after it 0.2-2.2 ms of 6-7 ms at 640×360 here (docs/realtime.md,
        "The collection before the frames")."""
        begin = self.clock.now()
        received = []
        nxt = next(arrivals, None)
        while nxt is not None and nxt[0] <= start_time:
            received.append(self._submit(nxt[1]))
            nxt = next(arrivals, None)
        futures_wait(received)  # a packet that failed is skipped here as in the run
        self._prepare_extrapolations()
        collector.start()
        cameras = views(start_time)
        # The first frame pays the display buffers' first touches: not one to time.
        self._render(cameras, start_time)
        if self._defers and self._interpolates:
            report.warm_up_seed_ms = self._seed_modes(modes, cameras, start_time)
        report.warm_up_ms = (self.clock.now() - begin) * 1e3
        return arrivals if nxt is None else itertools.chain([nxt], arrivals)

    def _prepare_extrapolations(self) -> None:
        """Prepares the extrapolation pair ``(None, k)`` of each held frame ``k`` that lacks
        one (the worker's, off the display path: on the caller's thread, outside the lock)."""
        if self.method not in _PREPARED_METHODS:
            return
        with self._lock:
            todo = [
                frame for k in self.client.held
                if not self.client.was_prepared(None, k)
                and (frame := self.client.held_frame(k)) is not None
            ]
            spare = self.client.retired_histories()
        for frame in todo:
            states = self._prepare([None], frame, frame.main.camera, spare)
            with self._lock:
                # A live client's network thread may submit during the warm-up.
                self._adopt_held(frame.index, states)

    def _seed_modes(
        self, modes: ModeGovernor, cameras: tuple[Camera, ...], time: float
    ) -> dict[str, list[float]] | None:
        """Renders :data:`ModeGovernor.MIN_FRAMES` frames of each mode at ``cameras`` and
        ``time``, extrapolated first, and records their times in ``modes`` (enough of each for
        its own estimate and the ratio of the two); returns them (ms) by the mode they were
        rendered in (:attr:`RealtimeReport.warm_up_seed_ms`), ``None`` where it rendered none.
        Only where the frame at ``time`` could be deferred (:meth:`_could_defer`): elsewhere
        the governor is not asked for it either (:meth:`_render`). Rendered alone, with the worker
        idle, these are the cheapest the frames get; the run's own frames take their place as
        they come (the governor keeps the last :data:`ModeGovernor.WINDOW`)."""
        with self._lock:
            if not self._could_defer(time):
                return None
        timed: dict[str, list[float]] = {}
        # Interpolated last: the eyes' previous outputs are then what the run's first frame
        # would have had without the seeding.
        for interpolate in (False, True):
            for _ in range(ModeGovernor.MIN_FRAMES):
                start = self.clock.now()
                self._render(cameras, time, 0, interpolate)
                took = self.clock.now() - start
                info = self.client.last_info
                assert info is not None
                modes.record(info.mode, took)
                timed.setdefault(info.mode, []).append(took * 1e3)
        return timed

    def _display(
        self,
        report: RealtimeReport,
        t0: float,
        n_frames: int,
        views: Callable[[float], tuple[Camera, ...]],
        arrivals: Iterator[tuple[float, bytes | memoryview | ServerFrame]],
        start_time: float,
        on_frame: Callable[[Any, DisplayFrame], None] | None,
        exclusive: bool,
        raised: _Saved,
        clocks: list[int] | None,
        collector: FrameCollector,
        modes: ModeGovernor,
    ) -> float:
        """The display loop of :meth:`run` (refresh ``n`` at clock ``t0 + n / f_c``; with
        ``exclusive``, ``t0`` moves on by the time waited for the worker); returns the clock
        time its ``n_frames`` refreshes end. ``raised``: the
        threads :func:`_raise_display` raised, restored (and emptied) after
        :data:`_OVERRUN_FRAMES` late frames in a row; ``clocks``: the display threads' CPU
        clocks (:func:`_thread_cpu_clocks`), read around each frame; ``collector``: asked
        after each frame, with the time to the next frame's refresh; ``modes``: the
        :class:`ModeGovernor` (seeded by the warm-up)."""
        period = 1.0 / self.display_fps
        governor = RateGovernor(self.display_fps, self.max_divisor)
        nxt = next(arrivals, None)
        n = 0
        late_in_a_row = 0
        while n < n_frames:
            d = governor.divisor
            tick = t0 + n * period
            while nxt is not None and t0 + (nxt[0] - start_time) <= tick:
                self.clock.sleep_until(t0 + (nxt[0] - start_time))
                # Read before submitting: the worker starts at once.
                waited = self.clock.now()
                received = self._submit(nxt[1])
                nxt = next(arrivals, None)
                if exclusive:
                    # Whatever its outcome (a bad packet is skipped here as it is otherwise).
                    futures_wait([received])
                    t0 += self.clock.now() - waited
                    tick = t0 + n * period
            self.clock.sleep_until(tick)
            t = start_time + n * period
            cameras = views(t)
            start = self.clock.now()
            used = _cpu_s(clocks)
            deadline = tick + d * period
            allows = (lambda: modes.allows(deadline - start)) if self._defers else True
            images, prepared, newest, deferred = self._render(cameras, t, 0, allows)
            after = _cpu_s(clocks)
            done = self.clock.now()
            info = self.client.last_info
            assert info is not None
            record = DisplayFrame(
                index=n,
                time=t,
                start=start,
                done=done,
                deadline=deadline,
                mode=info.mode,
                older=info.older,
                newer=info.newer,
                alpha=info.alpha,
                server_age_ms=None if newest is None else (t - newest) * 1e3,
                prepared=prepared,
                divisor=d,
                refresh=tick,
                cpu_ms=None if used is None or after is None else (after - used) * 1e3,
                eyes=len(images),
                deferred=deferred,
            )
            if self._defers:  # nothing else asks the governor
                modes.record(info.mode, done - start)
            report.add(record)
            late_in_a_row = 0 if record.met else late_in_a_row + 1
            if raised and late_in_a_row >= _OVERRUN_FRAMES:
                _restore(raised)
                raised.clear()
                report.display_scheduling = (
                    f"realtime until frame {n}, then normal ({_OVERRUN_FRAMES} late frames "
                    "in a row)"
                )
            if on_frame is not None:
                on_frame(images[0] if len(images) == 1 else tuple(images), record)
            after = self.clock.now()
            frame_s = after - tick
            if self._defers:
                # At the faster rate this frame could extrapolate, were interpolating too slow.
                frame_s -= (done - start) - modes.cheapest_s(info.mode, done - start)
            governor.update(frame_s, record.met)
            # The frame is shown for its `d` refreshes; the next starts after them, or at the
            # first refresh not yet passed (a late frame drops the refreshes it overran instead
            # of making every later frame late too).
            shown = min(n + d, n_frames)
            following = max(n + d, math.ceil((after - t0) / period - 1e-9))
            report.repeated += shown - n - 1
            report.dropped += min(following, n_frames) - shown
            n = following
            if n < n_frames:
                collector.between_frames(t0 + n * period - self.clock.now())
        return t0 + n_frames * period
