"""A seeded UDP impairment relay (``splitrender relay``): what ``tc netem`` does, for a kernel
without it, on 127.0.0.1 only.

The relay listens on ``listen`` and forwards every datagram to ``target``; the answers go back
to the last client address seen (one client at a time, as a QUIC connection is). Each direction
applies, per datagram and in this order: loss (probability ``loss``), a bandwidth cap (the
datagram leaves the link's queue ``8 · size / rate`` seconds after the one before it; a queue
longer than ``queue_ms`` drops it, as a router's drop-tail does), and a one-way delay of
``delay_ms`` plus a jitter drawn uniformly in ``±jitter_ms`` (never below 0; datagrams may be
reordered by it, as on a real path). The bandwidth can change during a run: a schedule of
``(seconds, Mb/s)`` steps counted from the first datagram of a client (the session's start,
not the relay's: a client may connect any time after the relay starts), or
:meth:`Relay.set_bandwidth`.

Every random draw comes from one ``random.Random(seed)`` per direction, so that a given
sequence of datagrams meets the same fate in every run with the same seed.
"""

from __future__ import annotations

import asyncio
import ipaddress
import math
import random
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

from splitrender.errors import InvalidInputError

__all__ = ["Impairment", "Relay", "RelayStats", "check_loopback"]


def check_loopback(host: str, what: str) -> str:
    """``host`` when it is a loopback address (the relay never reaches further)."""
    try:
        ok = host == "localhost" or ipaddress.ip_address(host).is_loopback
    except ValueError:
        ok = False
    if not ok:
        raise InvalidInputError(f"{what}: the relay stays on loopback (127.0.0.1), got {host!r}")
    return host


@dataclass(frozen=True)
class Impairment:
    """One direction's impairments (all zero: a plain forwarder). ``bandwidth_mbps`` 0 means
    no cap; ``schedule`` holds ``(seconds, mbps)`` steps applied after the first datagram
    from a client."""

    delay_ms: float = 0.0
    jitter_ms: float = 0.0
    loss: float = 0.0
    bandwidth_mbps: float = 0.0
    queue_ms: float = 500.0
    schedule: tuple[tuple[float, float], ...] = ()

    def __post_init__(self) -> None:
        for name in ("delay_ms", "jitter_ms", "bandwidth_mbps", "queue_ms"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise InvalidInputError(f"{name}: expected a finite number >= 0, got {v!r}")
        if not (0.0 <= self.loss < 1.0):
            raise InvalidInputError(f"loss: expected a fraction in [0, 1), got {self.loss!r}")
        for t, mbps in self.schedule:
            if not (math.isfinite(t) and t >= 0 and math.isfinite(mbps) and mbps >= 0):
                raise InvalidInputError(
                    f"bandwidth schedule: expected SECONDS:MBPS >= 0, got {t!r}:{mbps!r}"
                )


@dataclass
class RelayStats:
    """Datagrams per direction: forwarded, lost (drawn), dropped by the full queue."""

    forwarded: dict[str, int] = field(default_factory=lambda: {"up": 0, "down": 0})
    lost: dict[str, int] = field(default_factory=lambda: {"up": 0, "down": 0})
    queue_drops: dict[str, int] = field(default_factory=lambda: {"up": 0, "down": 0})


class _Direction:
    def __init__(self, imp: Impairment, seed: int) -> None:
        self.imp = imp
        self.rng = random.Random(seed)
        self.rate_bps = imp.bandwidth_mbps * 1e6
        self.link_free = 0.0  # when the bandwidth-capped link is next free (loop time)

    def fate(self, size: int, now: float) -> float | None:
        """Seconds from now at which the datagram arrives (``None``: lost or dropped)."""
        imp = self.imp
        # Always draw both numbers, so that the draws do not depend on the outcome.
        lost = self.rng.random() < imp.loss
        jitter = (2 * self.rng.random() - 1) * imp.jitter_ms
        if lost:
            return None
        depart = now
        if self.rate_bps > 0:
            start = max(now, self.link_free)
            if (start - now) * 1e3 > imp.queue_ms:
                return -1.0  # queue full: drop-tail
            depart = start + 8 * size / self.rate_bps
            self.link_free = depart
        return depart - now + max(0.0, imp.delay_ms + jitter) / 1e3


class Relay(asyncio.DatagramProtocol):
    """The relay: ``await relay.start()`` binds ``listen`` (port 0: any; :attr:`port` says
    which), ``relay.close()`` ends it. ``up`` is client → server, ``down`` server → client."""

    def __init__(
        self,
        target: tuple[str, int],
        up: Impairment,
        down: Impairment,
        seed: int = 0,
        listen: tuple[str, int] = ("127.0.0.1", 0),
        on_step: Callable[[str, float, float], None] | None = None,
    ) -> None:
        self.target = (check_loopback(target[0], "target"), target[1])
        self.listen = (check_loopback(listen[0], "listen"), listen[1])
        # A relay that forwards to itself: one datagram went round 186,000 times in 1.5 s.
        same = {"localhost": "127.0.0.1"}
        if listen[1] == target[1] and same.get(listen[0], listen[0]) == same.get(
            target[0], target[0]
        ):
            raise InvalidInputError(
                f"listen and target: both {target[0]}:{target[1]}; the relay would forward "
                "to itself (expected another port)"
            )
        # Two streams of draws from one seed: the directions do not disturb each other.
        self._dirs = {"up": _Direction(up, seed * 2 + 1), "down": _Direction(down, seed * 2 + 2)}
        self.stats = RelayStats()
        #: Called as ``on_step(direction, mbps, when)`` as a scheduled step is applied
        #: (``when``: the event loop's clock, ``time.monotonic()``, shared by every process
        #: on the machine: a test aligns the step with a session's clock by it).
        self.on_step = on_step
        self._client: tuple[str, int] | None = None
        self._down: _Upstream | None = None
        self._transport: asyncio.DatagramTransport | None = None
        self._tasks: list[asyncio.Task[None]] = []
        self.port = 0

    async def start(self) -> None:
        loop = asyncio.get_running_loop()
        transport, _ = await loop.create_datagram_endpoint(lambda: self, local_addr=self.listen)
        self._transport = transport
        self.port = int(transport.get_extra_info("sockname")[1])
        up, _ = await loop.create_datagram_endpoint(
            lambda: _Upstream(self), remote_addr=self.target
        )
        self._up_transport = up

    async def _steps(self, name: str, schedule: Sequence[tuple[float, float]]) -> None:
        loop = asyncio.get_running_loop()
        t0 = loop.time()
        for t, mbps in sorted(schedule):
            await asyncio.sleep(max(0.0, t0 + t - loop.time()))
            self.set_bandwidth(name, mbps)
            if self.on_step is not None:
                self.on_step(name, mbps, loop.time())

    def set_bandwidth(self, direction: str, mbps: float) -> None:
        """The cap of ``direction`` (``"up"``/``"down"``) from now on (0: none)."""
        self._dirs[direction].rate_bps = mbps * 1e6

    def close(self) -> None:
        for t in self._tasks:
            t.cancel()
        if self._transport is not None:
            self._transport.close()
        if getattr(self, "_up_transport", None) is not None:
            self._up_transport.close()

    def _forward(self, direction: str, data: bytes) -> None:
        loop = asyncio.get_running_loop()
        after = self._dirs[direction].fate(len(data), loop.time())
        if after is None:
            self.stats.lost[direction] += 1
            return
        if after < 0:
            self.stats.queue_drops[direction] += 1
            return
        loop.call_later(after, self._deliver, direction, data)

    def _deliver(self, direction: str, data: bytes) -> None:
        self.stats.forwarded[direction] += 1
        if direction == "up":
            self._up_transport.sendto(data)
        elif self._client is not None and self._transport is not None:
            self._transport.sendto(data, self._client)

    # asyncio.DatagramProtocol: datagrams from the client
    def datagram_received(self, data: bytes, addr: tuple[str | Any, int]) -> None:
        if self._client is None:
            # The first datagram of a client: the bandwidth schedules start now.
            for name, d in self._dirs.items():
                if d.imp.schedule:
                    self._tasks.append(
                        asyncio.ensure_future(self._steps(name, d.imp.schedule))
                    )
        self._client = (addr[0], addr[1])
        self._forward("up", data)


class _Upstream(asyncio.DatagramProtocol):
    def __init__(self, relay: Relay) -> None:
        self.relay = relay

    def datagram_received(self, data: bytes, addr: tuple[str | Any, int]) -> None:
        self.relay._forward("down", data)
