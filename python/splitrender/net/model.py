"""The network model and the client's frame schedule (shared/DESIGN.md "Conventions" → Timing;
REFERENCE.md §2.1).

Timing. Client frame ``n`` shows time ``n / f_c``; server frame ``k`` holds time ``t_k = k / f_s``.
The server renders ahead of the client (at a predicted pose) and *sends* frame ``k`` at
``t_k − lead``, ``lead = 1 / f_s`` by default: over an ideal network ``F_{k+1}`` arrives at
``t_k``, exactly when the client first needs the pair ``(F_k, F_{k+1})`` (``α = 0``). The
:class:`NetworkModel` delays each packet (bandwidth, latency, jitter, loss) and adds
``extra_delay_frames = l`` client frames, so ``F_{k+1}`` arrives ``l`` client frames after it would
be needed. This reproduces REFERENCE.md §2.1 exactly: with ``F = f_c / f_s`` client frames per
server frame, client frame ``n = kF + b`` interpolates ``(k, k+1)`` with ``α = b/F`` for ``b ≥ l``
and extrapolates from ``F_k`` with ``α = 1 + b/F`` for ``b < l``; ``l ≥ F`` always extrapolates.

Frame choice (:func:`choose_frames`, shared by :class:`Schedule` and
:class:`splitrender.Client`), for the frames the client holds at display time ``t``:

- ``"interpolate"``: the newest held frame ``k`` with ``t_k ≤ t`` and ``k + 1`` held:
  ``α = (t − t_k) / (t_{k+1} − t_k) ∈ [0, 1)`` (``k + m`` for frames whose motion spans ``m``
  periods, :attr:`~splitrender.types.ServerFrame.span`) (bidirectional methods: ``ours``,
  ``backward_bidir``, ``forward_splat`` with ``splat_bidirectional``);
- ``"extrapolate"``: otherwise (or always, for the unidirectional methods ``ours_extrapolate``,
  ``forward_splat``, ``timewarp``) from the newest held frame ``j`` with ``t_j ≤ t`` alone,
  ``α = 1 + (t − t_j) · f_s`` (seeds/000 §3.5), while ``α ≤ MAX_ALPHA`` (3, the core's limit);
- ``"hold"``: nothing usable (before the first frame arrives, ``backward_bidir`` without a pair,
  a gap longer than the core extrapolates): the client repeats its previous output (black at the
  start), where REFERENCE.md §2.1 renders against an uninitialised image.

``α`` within ``1e-9`` of an integer is snapped to it, so ``b = 0`` with ``l = F`` is ``α = 1``
(extrapolation), not ``0.9999999999``.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from splitrender.errors import InvalidInputError
from splitrender.types import BIDIRECTIONAL_METHODS, interpolates
from splitrender.types import (  # argument checks
    BOOL,
    check_float,
    check_int,
    check_items,
    checked,
    floats,
    ints,
    items,
    optional,
    strs,
)

__all__ = [
    "BIDIRECTIONAL_METHODS",
    "MAX_ALPHA",
    "MODES",
    "TIME_EPS",
    "ClientFrameInfo",
    "FrameBuffer",
    "Link",
    "NetworkModel",
    "Schedule",
    "choose_frames",
]

#: Largest extrapolation ``α`` the core accepts (``reproj_core::MAX_ALPHA``).
MAX_ALPHA = 3.0
#: Seconds within which two times count as equal (arrival vs display time, α snapping).
TIME_EPS = 1e-9
#: The modes a client frame can be rendered in.
MODES: tuple[str, ...] = ("interpolate", "extrapolate", "hold")
_METHODS = ("ours", "ours_extrapolate", "forward_splat", "timewarp", "backward_bidir")


#: Most frames, packets or bytes a count here may name (``frame_times=10**400`` planned that
#: many frames and exhausted memory).
_MAX_COUNT = 10**7
_MAX_INT = 2**63 - 1


def _float(where: str, value: object, *, lo: float = 0.0, positive: bool = False) -> float:
    """:func:`~splitrender.types.check_float` with ``lo`` as the lower bound (``-inf``: none)."""
    return check_float(
        where, value, positive=positive, lo=None if positive or lo == -math.inf else lo
    )


def _int(where: str, value: object, lo: int = 0, hi: int = _MAX_INT) -> int:
    return check_int(where, value, lo, hi)


@dataclass(frozen=True)
class NetworkModel:
    """A one-way link from server to client, deterministic for a given ``seed``.

    Packets leave in send order through one FIFO link: a packet starts serialising when it is
    sent and the link is free, and takes ``size · 8 / (bandwidth_mbps · 10⁶)`` seconds
    (``bandwidth_mbps=None``: instantaneous). It then arrives after ``latency_ms`` plus a jitter
    drawn uniformly from ``[0, jitter_ms]`` plus ``extra_delay_frames / client_fps`` seconds
    (``l``, REFERENCE.md §2.1). Delivery is in order (one stream, as TCP or a QUIC stream): a
    packet whose jitter would make it overtake its predecessor arrives with it instead. Each
    packet is lost with probability ``loss`` (it still occupied the link); lost packets arrive
    never (``None``). Jitter and loss come from two independent generators seeded by ``seed``,
    one draw each per packet, so changing ``loss`` leaves the jitter of every packet unchanged.
    """

    bandwidth_mbps: float | None = None
    latency_ms: float = 0.0
    jitter_ms: float = 0.0
    extra_delay_frames: int = 0
    loss: float = 0.0
    seed: int = 0
    client_fps: float = 120.0

    def __post_init__(self) -> None:
        if self.bandwidth_mbps is not None:
            b = _float("NetworkModel.bandwidth_mbps", self.bandwidth_mbps, positive=True)
            object.__setattr__(self, "bandwidth_mbps", b)
        for name in ("latency_ms", "jitter_ms"):
            object.__setattr__(self, name, _float(f"NetworkModel.{name}", getattr(self, name)))
        object.__setattr__(
            self,
            "extra_delay_frames",
            _int("NetworkModel.extra_delay_frames", self.extra_delay_frames),
        )
        loss = _float("NetworkModel.loss", self.loss)
        if loss > 1.0:
            raise InvalidInputError(f"NetworkModel.loss: expected a float in [0, 1], got {loss}")
        object.__setattr__(self, "loss", loss)
        object.__setattr__(self, "seed", _int("NetworkModel.seed", self.seed))
        object.__setattr__(
            self, "client_fps", _float("NetworkModel.client_fps", self.client_fps, positive=True)
        )

    @property
    def fixed_delay(self) -> float:
        """Seconds every packet spends after serialisation, before jitter: latency plus ``l``
        client frames."""
        return self.latency_ms * 1e-3 + self.extra_delay_frames / self.client_fps

    def link(self) -> Link:
        """A fresh stateful link (packets sent one at a time, e.g. while streaming)."""
        return Link(self)

    @checked(send_times=items(floats()), sizes=optional(items(ints(0, 1 << 40))))
    def arrival_times(
        self, send_times: Sequence[float], sizes: Sequence[int] | None = None
    ) -> list[float | None]:
        """Arrival time in seconds of each packet (``None``: lost), for packets sent at
        ``send_times`` (non-decreasing) with ``sizes`` in bytes (required with a bandwidth cap).

        Raises:
            InvalidInputError: for decreasing send times, negative sizes, a length mismatch, or
                missing sizes under a bandwidth cap.
        """
        times = list(send_times)
        if sizes is None:
            if self.bandwidth_mbps is not None:
                raise InvalidInputError(
                    "sizes: expected packet sizes in bytes with a bandwidth cap, got None"
                )
            size_list = [0] * len(times)
        else:
            size_list = list(sizes)
            if len(size_list) != len(times):
                raise InvalidInputError(
                    f"sizes: expected one size per send time ({len(times)}), got {len(size_list)}"
                )
        link = self.link()
        return [link.send(t, s) for t, s in zip(times, size_list)]


def network_for(network: NetworkModel | None, client_fps: float, whose: str) -> NetworkModel:
    """``network``, or the ideal network when ``None``, checked to run at ``client_fps`` (named
    ``whose`` in the message): what :meth:`Schedule.build` and
    :func:`splitrender.client.playback.play` take.

    Raises:
        InvalidInputError: for a non-network or one at another client frame rate.
    """
    net = network if network is not None else NetworkModel(client_fps=client_fps)
    if not isinstance(net, NetworkModel):
        raise InvalidInputError(f"network: expected a NetworkModel, got {type(net).__name__}")
    if not math.isclose(net.client_fps, client_fps):
        raise InvalidInputError(
            f"network.client_fps: expected {whose} = {client_fps}, got {net.client_fps}"
        )
    return net


class Link:
    """The state of one :class:`NetworkModel` link: call :meth:`send` for each packet in send
    order."""

    __slots__ = ("_busy_until", "_jitter", "_last_arrival", "_last_send", "_loss", "model")

    def __init__(self, model: NetworkModel) -> None:
        self.model = model
        self._jitter = np.random.default_rng([model.seed, 0])
        self._loss = np.random.default_rng([model.seed, 1])
        self._busy_until = -math.inf
        self._last_arrival = -math.inf
        self._last_send = -math.inf

    def send(self, time: float, size: int = 0) -> float | None:
        """The arrival time of a packet of ``size`` bytes sent at ``time`` seconds, or ``None``
        if it is lost.

        Raises:
            InvalidInputError: for a time before the previous packet's or a negative size.
        """
        m = self.model
        t = _float("send time", time, lo=-math.inf)
        if t < self._last_send:
            raise InvalidInputError(
                f"send time: expected non-decreasing times, got {t} after {self._last_send}"
            )
        n = _int("size", size)
        self._last_send = t
        start = max(t, self._busy_until)
        done = start if m.bandwidth_mbps is None else start + n * 8.0 / (m.bandwidth_mbps * 1e6)
        self._busy_until = done
        jitter = float(self._jitter.uniform(0.0, 1.0)) * m.jitter_ms * 1e-3
        lost = float(self._loss.random()) < m.loss
        if lost:
            return None
        arrival = max(done + m.fixed_delay + jitter, self._last_arrival)
        self._last_arrival = arrival
        return arrival


@dataclass(frozen=True)
class ClientFrameInfo:
    """How one client frame was (or is to be) made.

    ``older``/``newer``: the server frame indices used (``older`` is ``None`` when
    extrapolating from ``newer`` alone; both ``None`` when holding); ``alpha``: the ``α`` passed
    to the core (``None`` when holding); ``mode``: one of :data:`MODES`; ``held``: the indices of
    the server frames the client held after receiving and before pruning."""

    time: float
    older: int | None
    newer: int | None
    alpha: float | None
    mode: str
    held: tuple[int, ...] = ()

    @property
    def frames(self) -> tuple[int, ...]:
        """The server frames used, oldest first."""
        return tuple(i for i in (self.older, self.newer) if i is not None)


def _snap(alpha: float) -> float:
    r = round(alpha)
    return float(r) if abs(alpha - r) <= TIME_EPS else alpha


def _check_method(method: object) -> str:
    if not isinstance(method, str) or method not in _METHODS:
        raise InvalidInputError(
            f"unknown method {method!r}; expected one of: {', '.join(_METHODS)}"
        )
    return method


def choose_frames(
    held: Mapping[int, float],
    time: float,
    server_fps: float = 10.0,
    method: str = "ours",
    *,
    splat_bidirectional: bool = False,
    spans: Mapping[int, int] | None = None,
    interpolate: bool = True,
) -> ClientFrameInfo:
    """The frames, ``α`` and mode for display time ``time`` given the frames ``held``
    (``index -> time``), by the rules in the module docs. ``spans`` (``index -> span``,
    absent: 1) are the periods each frame's motion spans (:attr:`ServerFrame.span`): frame
    ``k`` of span ``m`` pairs with frame ``k + m`` of the same span, and extrapolates with
    ``α = 1 + (t − t_k) · f_s / m``. ``interpolate=False``: extrapolate from frame ``k`` even
    where the pair would interpolate (the real-time loop's
    :class:`~splitrender.client.realtime.ModeGovernor`; ``backward_bidir`` then holds)."""
    method = _check_method(method)
    t = float(time)
    bidir = interpolate and interpolates(method, splat_bidirectional)
    held_ix = tuple(sorted(held))
    past = [j for j in held_ix if held[j] <= t + TIME_EPS]
    if past:
        k = past[-1]
        m = 1 if spans is None else spans.get(k, 1)
        # A pair needs the motion of both frames to reach the other: equal spans, m apart.
        if bidir and k + m in held and (spans is None or spans.get(k + m, 1) == m):
            alpha = _snap((t - held[k]) / (held[k + m] - held[k]))
            if alpha < 1.0:
                return ClientFrameInfo(t, k, k + m, max(alpha, 0.0), "interpolate", held_ix)
        if method != "backward_bidir":
            alpha = _snap(1.0 + (t - held[k]) * server_fps / m)
            if alpha <= MAX_ALPHA:
                return ClientFrameInfo(t, None, k, max(alpha, 1.0), "extrapolate", held_ix)
    return ClientFrameInfo(t, None, None, None, "hold", held_ix)


class FrameBuffer:
    """The server frames a client holds, by index (times only; the client keeps the frames).

    A frame is refused (``receive`` returns ``False``) if its index is already held (duplicate),
    older than a frame already superseded (stale), or the buffer is full (``capacity``; the
    incoming frame is refused, not an older one, because the older ones are those needed
    first). :meth:`prune` drops the frames that can no longer be used once display time has
    reached ``t``: every frame older than the newest held frame with time ``<= t`` (times are
    assumed non-decreasing)."""

    __slots__ = ("_floor", "capacity", "times")

    def __init__(self, capacity: int = 4) -> None:
        self.capacity = _int("capacity", capacity, lo=2)
        self.times: dict[int, float] = {}
        self._floor = 0

    def receive(self, index: int, time: float) -> bool:
        if index in self.times or index < self._floor or len(self.times) >= self.capacity:
            return False
        for j, tj in self.times.items():
            if (j < index) != (tj < time):
                raise InvalidInputError(
                    f"frame {index} at time {time}: expected times increasing with the index, "
                    f"but frame {j} is at {tj}"
                )
        self.times[index] = float(time)
        return True

    def prune(self, time: float) -> None:
        past = [j for j, tj in self.times.items() if tj <= time + TIME_EPS]
        if not past:
            return
        base = max(past)
        self._floor = max(self._floor, base)
        for j in [j for j in self.times if j < base]:
            del self.times[j]

    def clear(self) -> None:
        self.times.clear()
        self._floor = 0


def _frame_times(frame_times: Sequence[float] | int, server_fps: float) -> list[float]:
    if isinstance(frame_times, (int, numbers.Integral)):
        return [k / server_fps for k in range(_int("frame_times", frame_times, hi=_MAX_COUNT))]
    times = check_items("frame_times", frame_times)
    return [_float(f"frame_times[{i}]", t, lo=-math.inf) for i, t in enumerate(times)]


@dataclass
class Schedule:
    """The per-client-frame plan of a session: ``entries[n]`` for client frame ``n`` (time
    ``n / client_fps``) and ``arrivals[k]`` for server frame ``k`` (``None``: lost).

    Build with :meth:`build`; :func:`splitrender.play` follows the same plan with images.
    """

    entries: list[ClientFrameInfo]
    arrivals: list[float | None]
    client_fps: float = 120.0
    server_fps: float = 10.0
    sends: list[float] = field(default_factory=list)

    @classmethod
    @checked(
        frame_sizes=optional(items(ints(0, 1 << 40))), method=strs(), splat_bidirectional=BOOL,
        capacity=ints(2, 1 << 16),
    )
    def build(
        cls,
        frame_times: Sequence[float] | int,
        network: NetworkModel | None = None,
        *,
        client_fps: float = 120.0,
        server_fps: float = 10.0,
        n_client_frames: int | None = None,
        frame_sizes: Sequence[int] | None = None,
        lead: float | None = None,
        method: str = "ours",
        splat_bidirectional: bool = False,
        capacity: int = 4,
    ) -> Schedule:
        """The schedule for server frames at ``frame_times`` (or ``k / server_fps`` for
        ``k < frame_times`` when an int) sent ``lead`` seconds (default ``1 / server_fps``)
        ahead of their time with ``frame_sizes`` bytes through ``network`` (default: ideal), and
        ``n_client_frames`` client frames (default: up to the last server frame's time,
        exclusive).

        Raises:
            InvalidInputError: for invalid arguments (see :class:`NetworkModel`).
        """
        client_fps = _float("client_fps", client_fps, positive=True)
        server_fps = _float("server_fps", server_fps, positive=True)
        method = _check_method(method)
        net = network_for(network, client_fps, "the schedule's client_fps")
        times = _frame_times(frame_times, server_fps)
        lead_s = 1.0 / server_fps if lead is None else _float("lead", lead)
        sends = [t - lead_s for t in times]
        sizes = None if frame_sizes is None else list(frame_sizes)
        arrivals = net.arrival_times(sends, sizes)
        if n_client_frames is None:
            n_client_frames = 0 if not times else max(0, math.ceil(times[-1] * client_fps - 1e-6))
        n_client = _int("n_client_frames", n_client_frames, hi=_MAX_COUNT)
        buf = FrameBuffer(capacity)
        entries: list[ClientFrameInfo] = []
        nxt = 0
        for n in range(n_client):
            t = n / client_fps
            nxt = _deliver(buf, times, arrivals, nxt, t)
            info = choose_frames(
                buf.times, t, server_fps, method, splat_bidirectional=splat_bidirectional
            )
            buf.prune(t)
            entries.append(info)
        return cls(entries, arrivals, client_fps, server_fps, sends)

    def modes(self) -> list[str]:
        """The mode of every client frame."""
        return [e.mode for e in self.entries]

    def summary(self) -> dict[str, int]:
        """How many client frames each mode made."""
        return {m: sum(e.mode == m for e in self.entries) for m in MODES}


def _deliver(
    buf: FrameBuffer,
    times: Sequence[float],
    arrivals: Sequence[float | None],
    nxt: int,
    t: float,
) -> int:
    """Hands ``buf`` every frame from ``nxt`` on that has arrived by ``t`` (in order: the link
    never reorders); returns the next undelivered index."""
    while nxt < len(arrivals):
        a = arrivals[nxt]
        if a is not None:
            if a > t + TIME_EPS:
                break
            buf.receive(nxt, times[nxt])
        nxt += 1
    return nxt
