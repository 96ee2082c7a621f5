"""Adaptive bit-rate for the live server: the encoder's target from the client's reports.

The client reports, a few times a second, the rate it received over its last window and the
queueing delay its frames met (how much later than the least-delayed frame they completed;
:class:`~splitrender.net.protocol.RateReport`). A link that narrows below the stream's rate
builds a queue at once, long before loss, so the queue is the signal:

- queue above ``high_ms``: the link is full; the target drops to ``backoff`` times the rate that
  got through (what the link carries now), at once;
- queue below ``low_ms``: there is room; the target climbs by ``climb`` per second
  (multiplicative, so it takes a few seconds to double: probing, not jumping back into a
  queue), after a backoff only up to the rate that got through then, which rises slowly (and
  which a later backoff can lower but not raise);
- in between, or no frame since the previous report (``queue_ms`` < 0): hold.

The target stays in ``[min_bps, max_bps]`` (``--min-bitrate``, ``--bitrate``). This is the
delay-based part of GCC (Carlucci et al. 2016) without its Kalman filter: enough for a
seeded relay's sharp changes, and easy to read."""

from __future__ import annotations

import math
from dataclasses import dataclass

from splitrender.errors import InvalidInputError

__all__ = ["LeadController", "LinkPacer", "RateController"]


@dataclass
class RateController:
    """The target (bits per second) between ``min_bps`` and ``max_bps``; starts at the top.

    :meth:`update` takes the time since the previous report, so that the climb is per second
    whatever the report rate (the client reports per frame and every quarter second). After
    a backoff the target climbs back only up to ``backoff`` times the rate that got through
    then (``ceiling``, the link's measured capacity), and that ceiling itself rises by
    ``probe`` per second:
    climbing straight back into the queue would make frames late again at every probe."""

    max_bps: float
    min_bps: float
    high_ms: float = 60.0
    low_ms: float = 20.0
    #: Not GCC's 0.85: the stream is one frame per period, each of which must cross the link
    #: within it, and the encoder misses its target by ~15 % frame to frame (more after a
    #: change), so at 85 % of the link every larger frame delays the next ones (measured:
    #: late frames through a halved 0.4 Mb/s cap at f_s 10); at 75 % they fit.
    backoff: float = 0.75
    climb: float = 1.36  # per second (8 % per quarter second)
    probe: float = 1.03  # per second

    def __post_init__(self) -> None:
        if not (
            math.isfinite(self.max_bps)
            and math.isfinite(self.min_bps)
            and 0 < self.min_bps <= self.max_bps
        ):
            raise InvalidInputError(
                f"bit-rate range: expected 0 < min <= max, got min {self.min_bps:g}, "
                f"max {self.max_bps:g} b/s"
            )
        self.target_bps = float(self.max_bps)
        self.ceiling_bps: float | None = None

    def update(self, receive_bps: float, queue_ms: float, dt: float = 0.25) -> float:
        """The new target after one report, ``dt`` seconds after the previous one."""
        dt = min(max(dt, 0.0), 1.0)
        if queue_ms < 0:
            pass  # no frame came since the last report: no news, hold
        elif queue_ms > self.high_ms and receive_bps > 0:
            self.target_bps = min(self.target_bps, self.backoff * receive_bps)
            # The link's capacity as measured now. A later backoff never raises it: a queue
            # means the link is full, and a rate measured above the ceiling then is the
            # client reading a frame's bytes late and at once (a busy event loop), not a
            # wider link, which shows as room and is found by the probe.
            # Never below the least target: the server sends that much whatever is reported,
            # and a pacer draining at a rate near 0 (a report of 1e-300 b/s) held every frame.
            seen = max(receive_bps, self.target_bps, self.min_bps)
            self.ceiling_bps = seen if self.ceiling_bps is None else min(self.ceiling_bps, seen)
        elif queue_ms < self.low_ms:
            self.target_bps *= self.climb**dt
            if self.ceiling_bps is not None:
                self.ceiling_bps *= self.probe**dt
                self.target_bps = min(self.target_bps, self.backoff * self.ceiling_bps)
        self.target_bps = min(max(self.target_bps, self.min_bps), self.max_bps)
        return self.target_bps

    @property
    def link_bps(self) -> float | None:
        """The link's capacity as measured at the last backoff (probed upwards since), or
        ``None`` before any: until a queue shows, nothing says the link is narrower than what
        is sent."""
        return self.ceiling_bps


@dataclass
class LeadController:
    """How much earlier than planned the server starts each frame (seconds), from the client's
    reports of how late its frames became usable.

    The server plans frame ``k`` to arrive by ``t_k − m/f_s`` from its render + encode time and
    half the round trip. What that leaves out: the client's own decode and pair preparation,
    the time a frame takes to cross a capped link (its size over the rate), and the server's
    scheduling noise on a loaded machine. All of them show in one number the client measures,
    the latest frame's lateness over a report window (:class:`~splitrender.net.protocol.
    RateReport`'s ``late_ms``), so the lead follows it: up at once by the lateness plus
    ``margin_ms`` (a late frame costs the display its interpolation), down by ``decay`` of
    the excess per report (a lead is content age, so it is given back, but slowly, so that
    one lucky window does not make the next frames late). Within ``[0, max_s]``."""

    margin_ms: float = 20.0
    decay: float = 0.1
    max_s: float = 1.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.max_s) and self.max_s >= 0):
            raise InvalidInputError(f"lead: expected max_s >= 0, got {self.max_s!r}")
        self.lead_s = 0.0

    def update(self, usable: int, late_ms: float) -> float:
        """The new lead after one report (``usable`` frames in its window, the latest
        ``late_ms`` late; none: no news, the lead stays)."""
        if usable > 0 and math.isfinite(late_ms):
            excess = (late_ms + self.margin_ms) / 1e3
            self.lead_s += excess if excess > 0 else self.decay * excess
            self.lead_s = min(max(self.lead_s, 0.0), self.max_s)
        return self.lead_s


class LinkPacer:
    """The bytes the server has sent that the link has not yet carried, as a queue drained
    at the link's measured rate (:attr:`RateController.link_bps`, read at every step, so a
    narrower link found later drains what is left more slowly; unmeasured: drained at once).

    The server plans each frame to be sent no sooner than the previous ones can have crossed
    (:meth:`free_at`) and holds it until then: a frame sent right behind a larger one (the key
    frame that reopens the encoders after a drop) would queue at the bottleneck and arrive
    late, where planned with the queue it is rendered for a later time (the frame between is
    skipped) and arrives in time. The hold is before the frame's send time stamp, so the
    client's queue measure, the adaptive bit-rate's signal, sees only the link's queue."""

    def __init__(self) -> None:
        self._bits = 0.0
        self._at: float | None = None

    def _drain(self, now: float, rate_bps: float | None) -> None:
        if rate_bps is None:
            self._bits = 0.0
        elif self._at is not None and now > self._at:
            self._bits = max(0.0, self._bits - (now - self._at) * rate_bps)
        self._at = now if self._at is None else max(self._at, now)

    def free_at(self, now: float, rate_bps: float | None) -> float:
        """When (on ``now``'s clock) the link will have carried everything sent so far."""
        self._drain(now, rate_bps)
        return now + (self._bits / rate_bps if rate_bps else 0.0)

    def sent(self, now: float, size_bytes: int, rate_bps: float | None) -> None:
        """``size_bytes`` handed to the link at ``now``."""
        self._drain(now, rate_bps)
        self._bits += 8.0 * size_bytes
