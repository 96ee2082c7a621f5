"""The live server (``splitrender serve``): QUIC sessions that receive a client's poses, render
server frames at the predicted pose, encode and stream them (docs/protocol.md, docs/live.md).

One session at a time (rendering takes the machine): a second client is refused as busy. Per
session, the frame loop:

1. estimates the client's display clock from its pose datagrams (the least-delayed sample
   gives the offset between the two clocks);
2. picks the next frame ``k`` (time ``k / f_s``) that can still arrive by ``t_k − m/f_s``,
   when the client first needs it for the pair ``(k−m, k)`` (splitrender.net.model), given the
   measured render + encode time and half the round trip. ``m`` is the frame's *span*
   (:func:`choose_span`): 1 while rendering keeps ``f_s``; when it cannot, the server renders
   every ``m``-th frame with motion spanning ``m / f_s`` (the frames of a server at
   ``f_s / m``), so that consecutive frames still form pairs to interpolate, and says so. Frames
   that still cannot arrive in time (a link or a schedule that is behind) are skipped (the
   client extrapolates meanwhile: that is the method's point). The encoded sequence does not
   skip: each packet carries its place in it (``seq``) as
   its index, which the stream decoder needs consecutive, and the frame header carries ``k``
   (the client restores it: :class:`splitrender.client.live.FrameOrder`);
3. predicts the head pose at ``t_k`` (:mod:`splitrender.net.predict`), renders with the
   reference renderer (on a worker thread: the event loop keeps receiving), encodes at the
   adaptive target (:mod:`splitrender.net.abr`) and sends the frame on its own unidirectional
   stream; the stream of a frame still in flight when two newer ones are sent is reset (stale).

A hello with a wrong version or token, a malformed hello, or a second client: the connection
is closed with a ``CLOSE_*`` code and a one-line reason, and the server keeps nothing of it.
Malformed datagrams and streams of an accepted session are dropped and counted.
"""

from __future__ import annotations

import asyncio
import dataclasses
import datetime
import hmac
import math
import sys
import time
from collections import deque
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO

import numpy as np
from aioquic.asyncio.protocol import QuicConnectionProtocol
from aioquic.asyncio.server import serve
from aioquic.quic.configuration import QuicConfiguration
from aioquic.quic.events import (
    ConnectionTerminated,
    DatagramFrameReceived,
    HandshakeCompleted,
    QuicEvent,
    StopSendingReceived,
    StreamDataReceived,
    StreamReset,
)

from splitrender.codec.coder import CodecConfig, StreamEncoder
from splitrender.errors import InvalidInputError, ProtocolError
from splitrender.files import read_regular
from splitrender.net.abr import LeadController, LinkPacer, RateController
from splitrender.net.predict import make_predictor
from splitrender.net.protocol import (
    ALPN,
    CLOSE_BAD_HELLO,
    CLOSE_BUSY,
    CLOSE_DISPLAY,
    CLOSE_SERVER_ERROR,
    CLOSE_SHUTDOWN,
    CLOSE_TEXT,
    CLOSE_TOKEN,
    CLOSE_VERSION,
    PROTOCOL_VERSION,
    ControlReader,
    FrameHeader,
    Hello,
    KeyRequest,
    PoseSample,
    RateReport,
    Welcome,
    decode_control,
    decode_datagram,
    fingerprint_hex,
    frame_control,
    hello_version,
    unsupported_version,
)
from splitrender.net.quic import ReceiveWindows
from splitrender.scene.builtin import Scene
from splitrender.tally import Tally
from splitrender.types import MAX_SPAN, ServerFrame

__all__ = [
    "LiveServer",
    "ServerOptions",
    "SessionStats",
    "check_scale",
    "choose_span",
    "self_signed_certificate",
]

#: Error code of a stream reset because its frame went stale.
RESET_STALE = 1
#: The QUIC transport parameter max_datagram_frame_size: anything that fits a packet.
QUIC_MAX_DATAGRAM = 65535
#: Least time between two key frames that the adaptive bit-rate forces.
ABR_KEY_INTERVAL_S = 2.0
#: Smallest relative change of the adaptive target that is passed to the encoder.
ABR_STEP = 0.2
#: A session whose client sent no pose for this long ends, counted from when it was accepted
#: (its QUIC idle timeout is the same).
IDLE_TIMEOUT_S = 3.0
#: How far a pose's time may run ahead of the client's clock as its earlier poses gave it (the
#: offset is the largest seen, so one sample far in the future would move every later frame).
MAX_CLOCK_STEP_S = 1.0
#: How many ended sessions' statistics a server keeps (:attr:`LiveServer.sessions`).
KEPT_SESSIONS = 64
#: A connection that has sent no valid hello this long after it opened is closed.
HELLO_TIMEOUT_S = 2.0
#: Most connections that may wait for their hello at once (each holds up to its receive
#: windows, :data:`RECEIVE_WINDOW`); one more takes the place of the one that waited longest.
MAX_PENDING = 16
#: The receive windows the server grants a client (QUIC max_data; per stream, a quarter): its
#: only stream is the control stream (a hello, then a few bytes per key request), and they grow
#: as the server reads it (splitrender.net.quic), so that the memory a client can make the
#: server hold before its hello is this much.
RECEIVE_WINDOW = 64 * 1024
#: Share of a span's period that rendering + encoding a frame may take: the rest is slack for
#: one slower frame and for a client that shares the machine.
SPAN_LOAD = 0.8
#: The share under which a shorter span is taken again: lower than SPAN_LOAD, so that a render
#: time near a boundary does not switch the span back and forth (each switch costs a pair).
SPAN_LOAD_DOWN = 0.6
#: Frames in a row that must fit a shorter span before the server goes back to it (one fast
#: frame is no trend; a longer span is taken at once, since every frame late costs a pair).
SPAN_CALM = 5


def _span_for(proc_s: float, fs: float, load: float, max_span: int) -> int:
    return min(max_span, max(1, math.ceil(proc_s * fs / load - 1e-9)))


def choose_span(
    proc_s: float, fs: float, current: int, calm: int, max_span: int = MAX_SPAN
) -> tuple[int, int]:
    """The span (server-frame periods per rendered frame, :attr:`ServerFrame.span`) for a
    server whose render + encode takes ``proc_s`` seconds per frame at the rate ``fs``: the
    least ``m ≤ max_span`` with ``proc_s ≤ SPAN_LOAD · m / fs``, taken at once when it is
    longer than ``current``. A shorter one is taken only once :data:`SPAN_CALM` frames in a row
    fit it with :data:`SPAN_LOAD_DOWN`; ``calm`` is that count so far. Returns
    ``(span, calm)``."""
    up = _span_for(proc_s, fs, SPAN_LOAD, max_span)
    if up > current:
        return up, 0
    down = _span_for(proc_s, fs, SPAN_LOAD_DOWN, max_span)
    if down >= current:
        return current, 0
    if calm + 1 >= SPAN_CALM:
        return down, 0
    return current, calm + 1


@dataclass(frozen=True)
class FramePlan:
    """What the server renders next (:func:`plan_frame`): frame ``k`` (a multiple of its span),
    started at ``start`` (the loop's clock), and how many frames of the grid it skips."""

    k: int
    start: float
    skipped: int


def plan_frame(
    *,
    client_now: float,
    offset: float,
    fs: float,
    span: int,
    last: int,
    ahead: float,
    queued: float,
    after: float,
) -> FramePlan:
    """The next frame to render. Frame ``k`` is first needed at ``t_k − m/f_s`` (it closes the
    pair (k−m, k), ``m`` = ``span``) and lies on its span's grid (``k`` a multiple of ``m``: the
    time of a frame at f_s/m); the least such ``k`` after ``last`` (``-1``: none yet) that can be
    there in time. It can be there ``ahead`` seconds after it is started (render + encode +
    one-way delay + the client's reported lead), and no sooner than ``queued + after`` from
    now: the link's queue of what was sent before it (:class:`~splitrender.net.abr.LinkPacer`)
    plus what follows its send (one-way delay + lead). The first frame of a session is for
    the time it arrives at (it can be shown at once, extrapolated); every later one is for
    one span after that. ``offset``: client display time minus loop time. It starts as late
    as it can (the freshest pose): ``ahead`` before it is needed. Frames that could not
    arrive in time are skipped."""
    m = span
    sendable = max(ahead, queued + after)
    k = m * math.ceil((math.ceil((client_now + sendable) * fs - 1e-9) + m * (last >= 0)) / m)
    skipped = 0
    if last >= 0:
        following = m * (last // m + 1)  # the next frame on the grid after the last
        skipped = max(0, (k - following) // m)
        k = max(k, following)
    return FramePlan(k, (k - m) / fs - ahead - offset, skipped)


def check_scale(scene: Scene, scale: float, name: str = "scale") -> None:
    """Raises :class:`~splitrender.errors.InvalidInputError` naming ``name`` and the largest
    scale that works when the codec cannot carry ``scene``'s frames at ``scale`` (a picture
    side beyond :data:`~splitrender.codec.stream.MAX_SIDE`,
    :func:`~splitrender.codec.coder.oversized_picture`): found at the first encode, the
    server had rendered for seconds (minutes at large scales) and failed with the codec's
    words, which named neither the scale nor an option of ``serve``."""
    from splitrender.codec.coder import oversized_picture
    from splitrender.codec.stream import MAX_SIDE

    def fits(x: float) -> bool:
        return oversized_picture(scene.camera_sizes(x)) is None

    over = oversized_picture(scene.camera_sizes(scale))
    if over is None:
        return
    # The pictures grow with the scale: bisect for the largest that fits, then round it down
    # to 4 significant digits (a value to type).
    lo, hi = 1.0 / 2880, scale
    for _ in range(60):
        mid = (lo + hi) / 2
        lo, hi = (mid, hi) if fits(mid) else (lo, mid)
    digits = 10.0 ** (3 - math.floor(math.log10(lo)))
    largest = math.floor(lo * digits) / digits
    while not fits(largest) and largest > 1.0 / digits:  # a layout that is not monotone there
        largest = round(largest - 1.0 / digits, 12)
    pic, pw, ph = over
    raise InvalidInputError(
        f"{name}: expected at most {largest:g} (scale {scale:g} makes the codec's {pic} "
        f"{pw}x{ph}, beyond its {MAX_SIDE} pixels a side)"
    )


def self_signed_certificate(host: str = "localhost") -> tuple[Any, Any]:
    """A new ECDSA P-256 key and a self-signed certificate for ``host`` valid for 30 days
    (``cryptography`` objects, as :class:`QuicConfiguration` takes them)."""
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import NameOID

    key = ec.generate_private_key(ec.SECP256R1())
    name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, host)])
    now = datetime.datetime.now(datetime.timezone.utc)
    cert = (
        x509.CertificateBuilder()
        .subject_name(name)
        .issuer_name(name)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - datetime.timedelta(minutes=5))
        .not_valid_after(now + datetime.timedelta(days=30))
        .add_extension(x509.SubjectAlternativeName([x509.DNSName(host)]), critical=False)
        .sign(key, hashes.SHA256())
    )
    return cert, key


@dataclass(frozen=True)
class ServerOptions:
    """What ``splitrender serve`` is told: the scene (a built-in name or a loaded
    :class:`Scene`), ``scale``, server rate ``fps``, the bit-rate range in Mb/s (``bitrate`` is
    the top and the start), the key-frame interval ``gop`` (frames), the session ``token``, the
    pose predictor, and how many sessions to serve before returning (0: forever)."""

    scene_name: str
    scale: float = 0.0625
    fps: float = 10.0
    bitrate: float | None = None
    min_bitrate: float | None = None
    gop: int = 100
    token: str = ""
    predictor: str = "constant-velocity"
    sessions: int = 0
    encoder_threads: int = 1
    #: Fault injection for tests and demos: every ``drop_every``-th frame that is not a key
    #: frame is encoded but not sent, as if the network had lost it (0: none).
    drop_every: int = 0
    #: Longest span :func:`choose_span` may pick (1: never lower the rate; skip frames instead).
    max_span: int = MAX_SPAN
    #: QUIC address validation (RFC 9000 §8.1.2): a client's first packet is answered with a
    #: Retry carrying a token, and no connection state is made until the client returns it, so
    #: that packets from spoofed addresses, or a flood of handshakes never completed, cost the
    #: server a packet each instead of a connection's state and crypto. Costs every client a
    #: round trip more to connect (not per frame).
    retry: bool = False


@dataclass
class SessionStats:
    """What one session did (printed when it ends, and kept in :attr:`LiveServer.sessions`,
    the last :data:`KEPT_SESSIONS`)."""

    frames_sent: int = 0
    frames_skipped: int = 0
    frames_dropped: int = 0
    key_frames: int = 0
    key_requests: int = 0
    streams_reset: int = 0
    malformed_datagrams: int = 0
    malformed_streams: int = 0
    poses: int = 0
    reports: int = 0
    bytes_sent: int = 0
    # Per frame, in memory bounded whatever the session's length (Tally).
    render_ms: Tally = field(default_factory=Tally)
    encode_ms: Tally = field(default_factory=Tally)
    target_mbps: Tally = field(default_factory=Tally)
    paced_ms: Tally = field(default_factory=Tally)  # frames held for the link (LinkPacer)
    ended: str = ""

    def forget_values(self) -> None:
        """Keeps each tally's histogram only (:meth:`Tally.forget_values`): for statistics kept
        for their summaries after the session ended (each tally's values one by one would hold
        up to 512 KiB, for :data:`KEPT_SESSIONS` sessions)."""
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if isinstance(value, Tally):
                value.forget_values()

    def line(self) -> str:
        # Milliseconds whole; Mb/s to 3 significant digits (at small scales the rate is
        # hundredths of a Mb/s, which ".0f" printed as 0).
        def med(v: Tally, spec: str = ".0f") -> str:
            m = v.median()
            return "n/a" if m is None else format(m, spec)

        return (
            f"{self.frames_sent} frames sent ({self.key_frames} key, {self.frames_skipped} "
            f"skipped, {self.streams_reset} reset, {self.frames_dropped} dropped on purpose, "
            f"{len(self.paced_ms)} held for the link), render {med(self.render_ms)} ms + encode "
            f"{med(self.encode_ms)} ms per frame at {med(self.target_mbps, '.3g')} Mb/s (medians), "
            f"{self.key_requests} key requests, "
            f"{self.malformed_datagrams} malformed datagrams, {self.malformed_streams} "
            f"malformed streams; ended: {self.ended}"
        )


class _Session(QuicConnectionProtocol):
    """One client connection: hello first, then poses in and frames out."""

    server: LiveServer

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._windows = ReceiveWindows(self._quic)
        self._addr: Any = None  # the client's address, from its first datagram
        self._pending = False  # in LiveServer.waiting (until a hello is taken)
        self._hello_timer: asyncio.TimerHandle | None = None
        self._control = ControlReader()
        self._control_id: int | None = None
        self.accepted = False
        self._refused = False
        self.stats = SessionStats()
        self._task: asyncio.Task[None] | None = None
        self._predictor = make_predictor(self.server.options.predictor)
        self._offset: float | None = None  # client display time minus loop time (max seen)
        self._last_pose_at = 0.0
        self._key_wanted = False
        self._abr = self.server.rate_controller()
        self._lead = LeadController(max_s=2.0 / self.server.options.fps)
        self._pacer = LinkPacer()
        self._reported_at: float | None = None
        self._open: dict[int, tuple[int, bool]] = {}  # seq -> (stream id, key), in flight
        self._closed = asyncio.Event()

    # -- events ---------------------------------------------------------------------------

    def connection_made(self, transport: Any) -> None:
        super().connection_made(transport)
        # From the first packet: a handshake that never completes is closed by it too.
        self._hello_timer = asyncio.get_running_loop().call_later(
            HELLO_TIMEOUT_S, self._hello_deadline
        )

    def _handshake_done(self) -> None:
        """Counts the connection among those waiting for a hello; when :data:`MAX_PENDING`
        already wait, the one that has waited longest is refused as busy. Not before the
        handshake: a close sent then carries no reason (RFC 9000 §10.2.3) and the client's
        retransmitted Initial opens a new connection."""
        srv = self.server
        if self.accepted or self._refused:
            return
        if len(srv.waiting) >= MAX_PENDING:
            # The oldest, not the newest: connections that never send a hello (they need no
            # token) refused every client while they kept the places filled; a client sends
            # its hello at once, within a round trip of taking the place.
            oldest = next(iter(srv.waiting))
            oldest._refuse(CLOSE_BUSY, f"busy: {MAX_PENDING} connections are waiting for a hello")
        srv.waiting[self] = None
        self._pending = True

    def datagram_received(self, data: bytes | str, addr: Any) -> None:
        if self._addr is None:
            self._addr = addr
        super().datagram_received(data, addr)

    def _hello_deadline(self) -> None:
        self._hello_timer = None
        if not self.accepted:
            self._refuse(CLOSE_BAD_HELLO, f"no hello within {HELLO_TIMEOUT_S:g} s")

    def _not_pending(self) -> None:
        """The connection no longer waits for its hello (taken, refused or gone)."""
        if self._hello_timer is not None:
            self._hello_timer.cancel()
            self._hello_timer = None
        if self._pending:
            self._pending = False
            del self.server.waiting[self]

    def quic_event_received(self, event: QuicEvent) -> None:
        self._windows.delivered(event)
        if self._refused and not isinstance(event, ConnectionTerminated):
            return  # nothing more is read from a connection being closed
        if isinstance(event, HandshakeCompleted):
            self._handshake_done()
        elif isinstance(event, StreamDataReceived):
            self._stream_data(event)
        elif isinstance(event, DatagramFrameReceived):
            if self.accepted:
                self._datagram(event.data)
        elif isinstance(event, StreamReset):
            if event.stream_id == self._control_id:
                self._refuse(CLOSE_BAD_HELLO, "control stream reset by the client")
        elif isinstance(event, StopSendingReceived):
            # The welcome goes on the control stream: one the client stopped could not carry
            # it (aioquic raised, and the session held the server without frames).
            if event.stream_id == self._control_id:
                self._refuse(CLOSE_BAD_HELLO, "control stream stopped by the client")
        elif isinstance(event, ConnectionTerminated):
            self._terminated(event.reason_phrase or f"closed (code {event.error_code})")

    def _refuse(self, code: int, reason: str) -> None:
        """Closes the connection with ``reason`` (one line); an accepted session ends."""
        if self._refused:
            return
        self._refused = True
        self._not_pending()
        self.server.log(f"refused {self._peer()}: {reason}" if not self.accepted else reason)
        if not self.accepted:
            self.server.refused += 1
        self._quic.close(error_code=code, reason_phrase=reason)
        self.transmit()

    def _peer(self) -> str:
        # The server's socket is not connected (no peername): the address of the datagrams.
        peer = self._addr
        return f"{peer[0]}:{peer[1]}" if peer else "client"

    def _stream_data(self, event: StreamDataReceived) -> None:
        sid = event.stream_id
        if self._control_id is None and sid % 4 == 0:
            self._control_id = sid  # the client's first bidirectional stream
        if sid != self._control_id:
            # Clients open no other stream. Before a hello that is not a client of ours;
            # after it, the stream is dropped, counted and stopped being sent (one that aioquic
            # has already let go of, finished, needs nothing).
            if not self.accepted:
                self._refuse(CLOSE_BAD_HELLO, "bad hello: a stream other than the control stream")
                return
            self.stats.malformed_streams += 1
            if (sid % 4 == 0 or sid % 4 == 2) and sid in self._quic._streams:
                self._quic.stop_stream(sid, RESET_STALE)
            return
        try:
            messages = self._control.feed(event.data)
            for raw in messages:
                if self._refused:
                    break  # e.g. a second hello behind a refused one
                self._control_message(raw)
        except ProtocolError as e:
            if not self.accepted:
                self._refuse(CLOSE_BAD_HELLO, f"bad hello: {e}")
            else:
                # The control stream cannot be re-synchronised after a framing error: stop
                # reading it; frames and poses go on.
                self.stats.malformed_streams += 1
                self._control = ControlReader()
                self._control_id = -1
        if event.end_stream and not self.accepted and not self._refused:
            self._refuse(CLOSE_BAD_HELLO, "bad hello: control stream ended before a hello")

    def _control_message(self, raw: bytes) -> None:
        if not self.accepted:
            self._hello(raw)
            return
        msg = decode_control(raw)
        if isinstance(msg, KeyRequest):
            self.stats.key_requests += 1
            self._key_wanted = True
        else:
            raise ProtocolError(f"control stream: unexpected {type(msg).__name__} after hello")

    def _hello(self, raw: bytes) -> None:
        version = hello_version(raw)
        if version is not None and version != PROTOCOL_VERSION:
            self._refuse(CLOSE_VERSION, unsupported_version(version))
            return
        hello = Hello.decode(raw)
        # Constant time: the comparison must not tell how much of a guess was right.
        if not hmac.compare_digest(hello.token.encode(), self.server.options.token.encode()):
            self._refuse(CLOSE_TOKEN, "wrong token")
            return
        w, h = self.server.size
        if hello.width and (hello.width, hello.height) != (w, h):
            self._refuse(
                CLOSE_DISPLAY,
                f"display size {hello.width}x{hello.height}: this server renders {w}x{h}",
            )
            return
        if self.server.active is not None:
            self._refuse(CLOSE_BUSY, "busy: the server is serving another session")
            return
        assert self._control_id is not None
        try:
            self._quic.send_stream_data(self._control_id, frame_control(self.server.welcome()))
        except (RuntimeError, ValueError) as e:  # aioquic: a stream the client reset or ended
            self._refuse(CLOSE_BAD_HELLO, f"control stream cannot carry the welcome: {e}")
            return
        self.accepted = True
        self._not_pending()
        self._last_pose_at = asyncio.get_running_loop().time()  # IDLE_TIMEOUT_S from here
        self.server.active = self
        self.server.log(f"session from {self._peer()}: display {hello.display_fps:g} FPS")
        self.transmit()
        self._task = asyncio.ensure_future(self._frames())

    def _datagram(self, data: bytes) -> None:
        try:
            msg = decode_datagram(data)
        except ProtocolError:
            self.stats.malformed_datagrams += 1
            return
        now = asyncio.get_running_loop().time()
        if isinstance(msg, PoseSample) and not self._plausible(msg.time, now):
            self.stats.malformed_datagrams += 1
            return
        if isinstance(msg, PoseSample):
            self.stats.poses += 1
            self._predictor.add(msg.time, msg.pose)
            off = msg.time - now
            self._offset = off if self._offset is None else max(self._offset, off)
            self._last_pose_at = now
        elif isinstance(msg, RateReport):
            self.stats.reports += 1
            # The climb is per second since the previous report with news (a frame).
            dt = now - self._reported_at if self._reported_at is not None else 0.25
            if msg.queue_ms >= 0:
                self._reported_at = now
            before = self._abr.target_bps
            after = self._abr.update(msg.receive_bps, msg.queue_ms, dt)
            if abs(after - before) > ABR_STEP * before and self._offset is not None:
                # Session time: the client's display clock as estimated from its poses.
                self.server.log(
                    f"adaptive target {before / 1e6:.3g} -> {after / 1e6:.3g} Mb/s "
                    "at session time "
                    f"{now + self._offset:.2f} s (queue {msg.queue_ms:.0f} ms, receiving "
                    f"{msg.receive_bps / 1e6:.3g} Mb/s)"
                )
            self._lead.update(msg.usable, msg.late_ms)

    def _plausible(self, t: float, now: float) -> bool:
        """Whether a pose at client time ``t`` can be served: the frames it leads to have
        indices the renderer takes (``0 <= k < 2^31``, with room for a session of years), and
        it is not ahead of the client's clock as estimated so far by more than
        :data:`MAX_CLOCK_STEP_S`."""
        fs = self.server.options.fps
        if not 0.0 <= t <= (2**31 - 1) / (2 * fs):
            return False
        return self._offset is None or t - now <= self._offset + MAX_CLOCK_STEP_S

    def shut_down(self) -> None:
        """The server stops (Ctrl-C, SIGTERM): the connection is closed with
        :data:`CLOSE_SHUTDOWN`, so that the client reports the server gone rather than a
        normal end (a bare close said code 0, ``BYE``), and an accepted session's line is
        logged now (the loop ends before the close's ``ConnectionTerminated`` would come)."""
        if not self._refused:
            self._refused = True
            self._quic.close(error_code=CLOSE_SHUTDOWN,
                             reason_phrase=CLOSE_TEXT[CLOSE_SHUTDOWN])
            self.transmit()
        self._terminated(CLOSE_TEXT[CLOSE_SHUTDOWN])

    def _terminated(self, reason: str) -> None:
        self._not_pending()
        if self._task is not None:
            self._task.cancel()
        self._closed.set()
        if self.accepted and self.server.active is self:
            self.stats.ended = reason
            self.server.session_ended(self)

    # -- frames ---------------------------------------------------------------------------

    def _unacked(self, sid: int) -> bool:
        """Whether the stream still has data the client has not acknowledged (aioquic drops
        a finished stream, so a missing one is done)."""
        stream = self._quic._streams.get(sid)
        return stream is not None and not stream.sender.is_finished

    def _in_flight(self) -> int:
        """Frames sent and not yet acknowledged (the finished ones are forgotten)."""
        for done in [i for i, (sid, _) in self._open.items() if not self._unacked(sid)]:
            del self._open[done]
        return len(self._open)

    def _rtt(self) -> float:
        # aioquic keeps its RTT estimate in the loss recovery (no public accessor).
        return float(getattr(self._quic._loss, "_rtt_smoothed", 0.0) or 0.0)

    def _take_target(
        self, effective: float, key_at: float, span: int, effective_span: int
    ) -> tuple[bool, float]:
        """Passes the adaptive target, times ``span``, to the encoder: the target is the
        link's rate, and the encoder's rate control spends its target's share of one period
        per frame, while at span ``m`` one frame goes per ``m`` periods. Only steps that
        matter: the encoders take a new target at a key frame (x265 reopens, tens of ms per
        stream). A drop is taken at once with a key frame of its own (a narrowed link cannot
        wait for the next regular one); a climb at most every ABR_KEY_INTERVAL_S (a key frame
        is itself larger) and in between waits (at most that long, not for the next regular
        key frame).
        ``effective``: the target the encoders run at, set for frames of ``effective_span``
        (a new span is taken at once: until then the link's rate is off by the ratio of the
        spans); ``key_at``: the loop time of the last such key frame. Returns whether this
        frame reopens the encoders, and ``key_at``."""
        encoder = self.server.encoder
        target = self._abr.target_bps * span
        current = encoder.config.bitrate_mbps * 1e6
        if abs(target - current) > ABR_STEP * current:
            encoder.set_bitrate(target / 1e6)
        now = asyncio.get_running_loop().time()
        wanted = encoder.config.bitrate_mbps * 1e6
        # A drop goes at once (the link is narrower now, and a key frame at the lower
        # target is small); a climb waits ABR_KEY_INTERVAL_S after the last such key frame,
        # unless the span changed (a pair is broken there anyway).
        if wanted < effective or (
            wanted > effective
            and (now - key_at >= ABR_KEY_INTERVAL_S or span != effective_span)
        ):
            encoder.request_key_frame()
            return True, now
        return False, key_at

    async def _frames(self) -> None:
        srv = self.server
        opts = srv.options
        fs = opts.fps
        loop = asyncio.get_running_loop()
        encoder = srv.encoder
        proc = srv.proc_estimate
        span, calm = choose_span(proc, fs, 1, 0, opts.max_span)
        if span > 1:
            srv.log(self._span_line(span, proc))
        if encoder.config.bitrate_mbps != srv.max_mbps() * span:
            encoder.set_bitrate(srv.max_mbps() * span)  # each session starts at the top
        encoder.request_key_frame()
        last = -1
        seq = 0  # place in the encoded sequence (the packets' index: see FrameHeader)
        abr_key_at = loop.time()  # the session's first frame is a key frame
        # The target the HEVC encoders run at: a new one takes effect at a key frame.
        effective = encoder.config.bitrate_mbps * 1e6
        effective_span = span
        proc_key = 2 * proc  # a frame that reopens the encoders (measured at the first)
        recent: deque[float] = deque(maxlen=5)
        warned = False
        try:
            while True:
                # From the session's start: a client that only reports, pings or sends
                # malformed poses does not hold the server.
                if loop.time() - self._last_pose_at > IDLE_TIMEOUT_S:
                    self._quic.close(reason_phrase=f"no pose for {IDLE_TIMEOUT_S:g} s")
                    self.transmit()
                    return
                if self._offset is None:
                    await asyncio.sleep(0.01)
                    continue
                owd = self._rtt() / 2
                if self._in_flight() >= 2 + math.ceil(2 * owd * fs):
                    # The link is behind (more frames unacknowledged than a round trip holds):
                    # rendering more would only queue behind them, and a key frame the client
                    # waits for would wait longer. The frames not rendered are skipped.
                    await asyncio.sleep(0.25 / fs)
                    continue
                # Decided before the frame is planned: reopening the encoders makes this
                # frame slower (proc_key), and the plan must start it that much earlier.
                reopen, abr_key_at = self._take_target(
                    effective, abr_key_at, span, effective_span
                )
                now = loop.time()
                # What the plan leaves out (the client's decode and preparation, a capped
                # link's transfer time, scheduling noise), from the client's reports.
                after = owd + self._lead.lead_s
                m = span
                plan = plan_frame(
                    client_now=now + self._offset,
                    offset=self._offset,
                    fs=fs,
                    span=m,
                    last=last,
                    ahead=max(proc, proc_key if reopen else 0.0) + after,
                    # The frame goes out once the link has carried what was sent before it.
                    queued=self._pacer.free_at(now, self._abr.link_bps) - now,
                    after=after,
                )
                k, start = plan.k, plan.start
                # The encoded sequence goes on over a skip (the packet's index is seq, not k),
                # so a skip costs no key frame.
                if plan.skipped:
                    self.stats.frames_skipped += plan.skipped
                    if not warned:
                        srv.log(
                            f"frames arrive too late at {fs / m:g} FPS "
                            f"({proc * 1e3:.0f} ms per frame): skipping frames, the client "
                            "extrapolates"
                        )
                        warned = True
                if start > loop.time():
                    await asyncio.sleep(start - loop.time())
                    # A target that came during the wait is taken now: this frame may be
                    # slower than planned, which beats a frame the link no longer carries.
                    again, abr_key_at = self._take_target(
                        effective, abr_key_at, m, effective_span
                    )
                    reopen = reopen or again
                if self._key_wanted:
                    encoder.request_key_frame()
                    self._key_wanted = False
                pose = self._predictor.predict(k / fs)
                pose_time = self._predictor.newest_time
                assert pose is not None and pose_time is not None
                t0 = time.perf_counter()
                frame: ServerFrame = await loop.run_in_executor(
                    srv.executor, srv.render, k, pose, m
                )
                t1 = time.perf_counter()
                packet: bytes = await loop.run_in_executor(
                    srv.executor, encoder.encode, dataclasses.replace(frame, index=seq)
                )
                t2 = time.perf_counter()
                key = bool(packet[6] & 1)  # the stream format's flags: bit 0 = key frame
                if key:
                    effective, effective_span = encoder.config.bitrate_mbps * 1e6, m
                render_ms, encode_ms = (t1 - t0) * 1e3, (t2 - t1) * 1e3
                # The median of the last frames that are not key frames (a key frame restarts
                # the encoders and is no guide to the next frame's time; the median keeps one
                # slow frame from making the next ones skip).
                if not key:
                    recent.append(t2 - t0)
                    proc = float(np.median(recent))
                    span, calm = choose_span(proc, fs, span, calm, opts.max_span)
                    if span != m:
                        srv.log(self._span_line(span, proc))
                elif reopen:
                    proc_key = t2 - t0
                last = k
                seq += 1
                n = opts.drop_every
                if n and not key and (self.stats.frames_sent + self.stats.frames_dropped) % n == (
                    n - 1
                ):
                    self.stats.frames_dropped += 1  # the injected loss (ServerOptions)
                    continue
                # Held until the link has carried the frames before it (planned above; a
                # frame that took longer than planned may find the queue drained already).
                now = loop.time()
                hold = self._pacer.free_at(now, self._abr.link_bps) - now
                if hold > 0:
                    self.stats.paced_ms.add(hold * 1e3)
                    await asyncio.sleep(hold)
                self._pacer.sent(loop.time(), len(packet) + FrameHeader.SIZE, self._abr.link_bps)
                # (The link's rate the frame was encoded for: its encoder target over its span.)
                self._send(
                    k, m, seq - 1, key, pose_time, packet, render_ms, encode_ms, effective / m
                )
        except asyncio.CancelledError:
            pass
        except Exception as e:  # noqa: BLE001 - a session's failure must not end the server
            # Whatever broke (a pose the renderer refuses, an encoder error), this session ends
            # with the reason and the server serves the next one.
            reason = f"server error: {type(e).__name__}: {e}".splitlines()[0][:200]
            srv.log(reason)
            self._quic.close(error_code=CLOSE_SERVER_ERROR, reason_phrase=reason)
            self.transmit()

    def _span_line(self, span: int, proc: float) -> str:
        fs = self.server.options.fps
        if span == 1:
            return f"rendering keeps {fs:g} FPS again ({proc * 1e3:.0f} ms per frame)"
        return (
            f"rendering cannot keep {fs:g} FPS ({proc * 1e3:.0f} ms per frame): rendering one "
            f"frame in {span} ({fs / span:g} FPS, span {span}); the client interpolates those"
        )

    def _send(
        self,
        k: int,
        span: int,
        seq: int,
        key: bool,
        pose_time: float,
        packet: bytes,
        render_ms: float,
        encode_ms: float,
        target: float,
    ) -> None:
        """Sends frame ``k`` of ``span``; ``target``: the bit-rate it was encoded at (b/s)."""
        fs = self.server.options.fps
        assert self._offset is not None  # frames follow poses
        header = FrameHeader(
            k,
            seq,
            key,
            pose_time,
            k / fs,
            # On the client's display clock as estimated from its poses: early by the
            # least one-way delay of a pose.
            asyncio.get_running_loop().time() + self._offset,
            target,
            render_ms,
            encode_ms,
            len(packet),
            span,
        )
        for old in [i for i in self._open if i < seq - 2]:
            # Stale: the client no longer needs it (it will ask for a key frame). A key frame
            # is not reset: it is what a client that lost frames waits for.
            old_sid, old_key = self._open[old]
            if self._unacked(old_sid) and not old_key:
                del self._open[old]
                self._quic.reset_stream(old_sid, RESET_STALE)
                self.stats.streams_reset += 1
        sid = self._quic.get_next_available_stream_id(is_unidirectional=True)
        self._quic.send_stream_data(sid, header.encode() + packet, end_stream=True)
        self._open[seq] = (sid, key)
        self.transmit()
        s = self.stats
        s.frames_sent += 1
        s.key_frames += key
        s.bytes_sent += len(packet) + FrameHeader.SIZE
        s.render_ms.add(render_ms)
        s.encode_ms.add(encode_ms)
        s.target_mbps.add(target / 1e6)


class LiveServer:
    """``splitrender serve``: :meth:`run` serves sessions on ``host:port`` until
    ``options.sessions`` have ended (0: until cancelled). ``certificate``/``private_key``
    (``cryptography`` objects) default to a new self-signed pair; ``certificate_chain`` holds
    the intermediate certificates sent after it in the handshake, the leaf's issuer first (as
    :func:`load_certificate_chain` returns them; none for a self-signed one), which a client
    that verifies against the root CA rather than pinning needs. :attr:`fingerprint` is the
    SHA-256 of the (leaf) certificate (what a client pins). ``scene`` overrides the built-in
    scene of ``options.scene_name`` (e.g. one loaded from a JSON description); the welcome
    names its built-in scene and :attr:`scene_digest`, its :meth:`Scene.digest`, computed
    once here (from the hashes the glTF loader took of the files it read), which a client
    compares with its own scene's."""

    def __init__(
        self,
        options: ServerOptions,
        *,
        scene: Scene | None = None,
        certificate: Any = None,
        private_key: Any = None,
        certificate_chain: Sequence[Any] = (),
        log: TextIO | None = None,
    ) -> None:
        self.options = options
        self.scene = scene if scene is not None else Scene(options.scene_name)
        self.scene_digest = self.scene.digest()
        # Before the first render: at a scale the codec cannot carry, that render took seconds
        # to minutes (and gigabytes) for an encode that then failed.
        check_scale(self.scene, options.scale)
        if certificate is None:
            certificate, private_key = self_signed_certificate()
        from cryptography.hazmat.primitives.serialization import Encoding

        self.certificate, self.private_key = certificate, private_key
        self.certificate_chain = list(certificate_chain)
        self.fingerprint = fingerprint_hex(certificate.public_bytes(Encoding.DER))
        self._log = log if log is not None else sys.stderr
        self.active: _Session | None = None
        # Connections waiting for their hello, oldest first (at most MAX_PENDING).
        self.waiting: dict[_Session, None] = {}
        self.refused = 0
        # The last KEPT_SESSIONS (all of them, a server left to run with sessions=0 grew with
        # every session; each holds four Tallies, at most 2 MB), and how many ended in all.
        self.sessions: deque[SessionStats] = deque(maxlen=KEPT_SESSIONS)
        self.sessions_ended = 0
        self.port = 0
        self.executor = ThreadPoolExecutor(1, thread_name_prefix="splitrender-serve")
        self._done = asyncio.Event()
        self._ran = False
        # Two first frames: the camera the welcome describes, and the first estimate of the
        # render + encode time of a frame that is not a key frame (refined per frame; the
        # first encode opens the encoders, which is no guide).
        first = self.render(0, self.scene.client_pose(0.0))
        self.size = (first.main.camera.width, first.main.camera.height)
        self.proj = tuple(float(v) for v in first.main.camera.proj.ravel())
        # The encoder is kept across sessions (they come one at a time): a session starts it
        # again with a key frame, which costs far less than opening its x265 encoders.
        self.encoder = StreamEncoder(self.codec_config())
        self.encoder.encode(first)
        t0 = time.perf_counter()
        self.encoder.encode(self.render(1, self.scene.client_pose(1.0 / options.fps)))
        self.proc_estimate = time.perf_counter() - t0

    def log(self, message: str) -> None:
        print(f"splitrender serve: {message}", file=self._log, flush=True)

    def render(self, k: int, pose: Any, span: int = 1) -> ServerFrame:
        """Frame ``k`` (a multiple of ``span``) at ``pose``, its motion spanning ``span``
        periods: frame ``k / span`` of a server at ``f_s / span``, which has the same time."""
        fs = self.options.fps
        f = self.scene.server_frame(k // span, self.options.scale, fs / span, pose=pose)
        return dataclasses.replace(f, index=k, span=span)

    def max_mbps(self) -> float:
        if self.options.bitrate is not None:
            return self.options.bitrate
        w, h = self.scene.main_size(self.options.scale)
        return CodecConfig.scaled(w, h).bitrate_mbps

    def min_mbps(self) -> float:
        hi = self.max_mbps()
        lo = self.options.min_bitrate
        return min(hi, hi / 4 if lo is None else lo)

    def codec_config(self) -> CodecConfig:
        o = self.options
        return CodecConfig(
            bitrate_mbps=self.max_mbps(), fps=o.fps, gop=o.gop, threads=o.encoder_threads
        )

    def rate_controller(self) -> RateController:
        period_ms = 1e3 / self.options.fps
        # In frame periods (a frame's own transfer time varies with its size), but not so
        # long at a low f_s that a narrowed link goes unnoticed for most of a second.
        return RateController(
            self.max_mbps() * 1e6,
            self.min_mbps() * 1e6,
            high_ms=min(0.4 * period_ms, 150.0),
            low_ms=min(0.15 * period_ms, 50.0),
        )

    def welcome(self) -> bytes:
        o = self.options
        w, h = self.size
        return Welcome(
            o.fps, o.scale, w, h, self.proj, o.gop, self.max_mbps(), self.min_mbps(),
            self.scene.name, self.scene_digest,
        ).encode()

    def session_ended(self, session: _Session) -> None:
        self.active = None
        stats = session.stats
        self.log(f"session ended: {stats.line()}")
        stats.forget_values()
        self.sessions.append(stats)
        self.sessions_ended += 1
        if self.options.sessions and self.sessions_ended >= self.options.sessions:
            self._done.set()

    def configuration(self) -> QuicConfiguration:
        cfg = QuicConfiguration(
            is_client=False,
            alpn_protocols=[ALPN],
            # QUIC closes a connection that receives a DATAGRAM larger than this transport
            # parameter; the protocol's own limit (MAX_DATAGRAM) is checked per message
            # instead, so that an oversized one is dropped and counted, not fatal.
            max_datagram_frame_size=QUIC_MAX_DATAGRAM,
            idle_timeout=IDLE_TIMEOUT_S,
            max_data=RECEIVE_WINDOW,
            max_stream_data=RECEIVE_WINDOW // 4,
        )
        cfg.certificate = self.certificate
        cfg.private_key = self.private_key
        cfg.certificate_chain = list(self.certificate_chain)
        return cfg

    async def run(
        self, host: str = "127.0.0.1", port: int = 4433,
        ready: Callable[[LiveServer], None] | None = None,
    ) -> None:
        """Serves until ``options.sessions`` sessions have ended (or cancelled). ``ready`` is
        called once the socket is bound (:attr:`port` holds the port, useful with 0). A server
        runs once: its encoder and render thread are closed when it returns.

        Raises:
            InvalidInputError: for a server that has run before (a second run failed with
                asyncio's RuntimeError about another event loop, its encoder closed)."""
        if self._ran:
            raise InvalidInputError(
                "LiveServer.run: this server has run before (a server runs once: its encoder "
                "and render thread are closed when it returns; make a new LiveServer)"
            )
        self._ran = True
        server = self

        class Session(_Session):
            pass

        Session.server = server
        quic = await serve(host, port, configuration=self.configuration(),
                           create_protocol=Session, retry=self.options.retry)
        assert quic._transport is not None
        self.port = int(quic._transport.get_extra_info("sockname")[1])
        if ready is not None:
            ready(self)
        try:
            await self._done.wait()
        finally:
            # Ctrl-C and SIGTERM come here too (cancelled): each connection is told why it
            # ends, and an accepted session's line is logged, before the socket goes.
            for session in [*self.waiting, *([self.active] if self.active else [])]:
                session.shut_down()
            quic.close()
            self.executor.shutdown(wait=True, cancel_futures=True)
            self.encoder.close()


#: The most bytes read from a PEM file (a certificate chain is a few kB).
MAX_PEM_BYTES = 1 << 20


def load_certificate(cert: Path, key: Path | None = None) -> tuple[Any, Any]:
    """A PEM certificate and its private key from files (``--cert``/``--key``; without ``key``,
    from ``cert`` as well), as :class:`QuicConfiguration` takes them: the first two of
    :func:`load_certificate_chain` (which see for the errors), without the intermediates."""
    leaf, private, _ = load_certificate_chain(cert, key)
    return leaf, private


def load_certificate_chain(
    cert: Path, key: Path | None = None
) -> tuple[Any, Any, list[Any]]:
    """The leaf certificate, its private key and the intermediate certificates that follow
    the leaf in ``cert`` (a PEM chain, e.g. a ``fullchain.pem``: leaf first, then each
    certificate's issuer) from files (``--cert``/``--key``; without ``key``, from ``cert`` as
    well), as :class:`QuicConfiguration` takes them (``certificate``, ``private_key``,
    ``certificate_chain``: the server sends the intermediates in its handshake, which a client
    that verifies against the root CA needs).

    # Errors
    :class:`InvalidInputError` naming the file that cannot be read or holds no certificate or
    key (cryptography's own message named neither), a chain in which a certificate is not
    issued by the next one (out of order, or an unrelated certificate: a client would fail the
    handshake), and a key that is not the certificate's (a client would fail the handshake
    with no word why)."""
    from cryptography import x509
    from cryptography.exceptions import UnsupportedAlgorithm
    from cryptography.hazmat.primitives import serialization

    def read(path: Path, what: str) -> bytes:
        try:
            return read_regular(path, MAX_PEM_BYTES, what, InvalidInputError)
        except OSError as e:
            raise InvalidInputError(f"{path}: cannot read the {what}: {e.strerror or e}") from None

    cert_pem = read(cert, "certificate (PEM)")
    try:
        chain = x509.load_pem_x509_certificates(cert_pem)
    except ValueError:
        raise InvalidInputError(f"{cert}: expected a PEM certificate (-----BEGIN CERTIFICATE-----)"
                                ", found none that parses") from None
    n = len(chain)
    for i in range(n - 1):
        # By name, as a verifier builds the path (the signatures are the client's to check).
        if chain[i].issuer != chain[i + 1].subject:
            raise InvalidInputError(f"{cert}: certificate {i + 2} of {n} does not issue "
                                    f"certificate {i + 1} (expected the leaf first, then "
                                    "each certificate's issuer)")
    key_path = cert if key is None else key
    key_pem = cert_pem if key is None else read(key, "private key (PEM)")
    try:
        private = serialization.load_pem_private_key(key_pem, password=None)
    except (ValueError, TypeError, UnsupportedAlgorithm) as e:
        # TypeError: the key is encrypted (no passphrase is asked for).
        found = "an encrypted one" if isinstance(e, TypeError) else "none that parses"
        raise InvalidInputError(f"{key_path}: expected an unencrypted PEM private key "
                                f"(-----BEGIN PRIVATE KEY-----), found {found}") from None

    def spki(public: Any) -> bytes:
        return bytes(public.public_bytes(serialization.Encoding.DER,
                                         serialization.PublicFormat.SubjectPublicKeyInfo))

    if spki(private.public_key()) != spki(chain[0].public_key()):
        raise InvalidInputError(f"{key_path}: the private key is not the key of the "
                                f"certificate in {cert}")
    return chain[0], private, list(chain[1:])
