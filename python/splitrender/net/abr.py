"""Adaptive bit-rate for the live server: the encoder's target from the client's reports.

The client reports, a few times a second, the rate it received over its last window and the
queueing delay its frames met (how much later than the least-delayed frame they completed;
:class:`~splitrender.net.protocol.RateReport`). A link that narrows below the stream's rate
builds a queue at once, long before loss, so the queue is the signal:

- queue above ``high_ms``: the link is full; the target drops to ``backoff`` times the rate that
  got through (what the link carries now), at once;
- queue below ``low_ms``: there is room; the target climbs by ``climb`` per report (multiplicative,
  so it takes a few seconds to double: probing, not jumping back into a queue);
- in between: hold.

The target stays in ``[min_bps, max_bps]`` (``--min-bitrate``, ``--bitrate``). This is the
delay-based part of GCC (Carlucci et al. 2016) without its Kalman filter: enough for a
seeded relay's sharp changes, and easy to read."""

from __future__ import annotations

import math
from dataclasses import dataclass

from splitrender.errors import InvalidInputError

__all__ = ["RateController"]


@dataclass
class RateController:
    """The target (bits per second) between ``min_bps`` and ``max_bps``; starts at the top."""

    max_bps: float
    min_bps: float
    high_ms: float = 60.0
    low_ms: float = 20.0
    backoff: float = 0.85
    climb: float = 1.08

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

    def update(self, receive_bps: float, queue_ms: float) -> float:
        """The new target after one report."""
        if queue_ms > self.high_ms and receive_bps > 0:
            self.target_bps = min(self.target_bps, self.backoff * receive_bps)
        elif queue_ms < self.low_ms:
            self.target_bps *= self.climb
        self.target_bps = min(max(self.target_bps, self.min_bps), self.max_bps)
        return self.target_bps
