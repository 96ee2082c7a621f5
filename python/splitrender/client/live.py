"""The live client (``splitrender connect``): a QUIC session with ``splitrender serve`` around the
real-time loop (:class:`~splitrender.client.realtime.RealtimeClient`; docs/protocol.md,
docs/live.md).

Two threads. The caller's thread runs the display loop at ``f_c`` with the client's actual pose
and sends each pose to the server (a datagram; newest wins). An asyncio thread runs the
connection: it verifies the server's certificate against the pinned fingerprint *before* the
token is sent, sends the hello, receives one stream per server frame, puts the frames back in
order (:class:`FrameOrder`) and submits them to the real-time client, and reports its receive
rate and queueing delay for adaptive bit-rate.

Lives in :mod:`splitrender.client` (not :mod:`splitrender.net`) because it drives the
real-time client, which sits above the network layer; the protocol and the server are in
:mod:`splitrender.net`.
"""

from __future__ import annotations

import asyncio
import dataclasses
import hashlib
import hmac
import math
import ssl
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt
from aioquic.asyncio.client import connect
from aioquic.asyncio.protocol import QuicConnectionProtocol
from aioquic.quic.configuration import QuicConfiguration
from aioquic.quic.events import (
    ConnectionTerminated,
    HandshakeCompleted,
    QuicEvent,
    StreamDataReceived,
    StreamReset,
)

from splitrender.client.client import Client
from splitrender.client.realtime import (
    DISPLAY_FPS,
    MAX_DIVISOR,
    DisplayFrame,
    Handover,
    RealtimeClient,
)
from splitrender.codec.coder import StreamDecoder
from splitrender.errors import InvalidInputError, ProtocolError
from splitrender.gpu import backend_for, check_backend
from splitrender.net.protocol import (
    ALPN,
    CLOSE_BYE,
    CLOSE_TEXT,
    KEY_LOST,
    KEY_START,
    KEY_UNDECODABLE,
    MAX_DATAGRAM,
    MAX_FPS,
    MAX_FRAME_PAYLOAD,
    MAX_TOKEN,
    MIN_DISPLAY_FPS,
    PROTOCOL_VERSION,
    ControlReader,
    FrameHeader,
    Hello,
    KeyRequest,
    PoseSample,
    RateReport,
    Welcome,
    decode_control,
    fingerprint_hex,
    frame_control,
    normalise_fingerprint,
    pose_problem,
    printable,
)
from splitrender.net.quic import ReceiveWindows
from splitrender.reproject import METHODS
from splitrender.tally import Tally
from splitrender.types import (
    Camera,
    ServerFrame,
    check_bool,
    check_float,
    check_int,
    check_str,
)

__all__ = ["ConnectOptions", "FrameOrder", "LiveClient"]

_F64 = npt.NDArray[np.float64]

#: Error code of a stream the client gives up on (STOP_SENDING).
STOP_STALE = 1
#: Most bytes the frames still arriving may announce together (their headers' sizes): a
#: 1280x720 frame is under 1 MB; a server that opens frames and never ends them is held to this.
MAX_ARRIVING_BYTES = 2 * MAX_FRAME_PAYLOAD
#: Seconds between two rate reports (and one per completed frame).
REPORT_INTERVAL_S = 0.1
#: The receive rate is measured over this many seconds.
RATE_WINDOW_S = 0.5
#: Seconds between two looks at the give-up timers and the report clock.
TICK_S = 0.05
#: Server frames whose record (target, arrival, when usable: ``report.json``'s
#: ``target_mbps``) and span the client keeps: the newest, an hour at 10 FPS (some 20 MB); a
#: session of any length takes bounded memory (``ConnectOptions(keep_packets=True)`` aside).
KEEP_FRAME_RECORDS = 36000
#: Streams ended or given up that the client remembers by id, to ignore what still comes on
#: them (the newest; an older one is known by being below the newest forgotten, which for a
#: frame is minutes late at this count).
KEEP_DEAD_STREAMS = 4096
#: Seconds without any packet from the server after which the connection counts as lost.
IDLE_TIMEOUT_S = 3.0
#: How long the client waits for the server's welcome after its hello (the server answers at
#: once; it closes a connection without a hello after 2 s).
WELCOME_TIMEOUT_S = 3.0
#: A server that sent no packet at all in this long before the session's end went away (a live
#: one acknowledges the poses within milliseconds), though the idle timeout that closes the
#: connection (:data:`IDLE_TIMEOUT_S`) comes only after the end.
SILENT_S = 1.0


@dataclass(frozen=True)
class ConnectOptions:
    """What ``splitrender connect`` is told. ``fingerprint``: the pinned SHA-256 of the server's
    DER certificate (64 hex digits, :func:`~splitrender.net.protocol.normalise_fingerprint`);
    ``None`` accepts any certificate (``--insecure``). ``backend``: where the display renders
    (``"wgpu"``: on the GPU, each pair uploaded by the receiving worker). ``max_divisor``: the
    most the display may divide ``display_fps`` by when its frames do not fit the refresh
    (:class:`~splitrender.client.realtime.RateGovernor`; 1 holds the rate).
    ``defer_interpolation``: a frame that could interpolate extrapolates instead where an
    interpolated frame would miss its deadline
    (:class:`~splitrender.client.realtime.ModeGovernor`; ``False``: always interpolate)."""

    host: str
    port: int
    token: str = ""
    fingerprint: str | None = None
    method: str = "ours"
    display_fps: float = DISPLAY_FPS
    connect_timeout: float = 10.0
    backend: str = "cpu"
    version: int = PROTOCOL_VERSION  # only tests send another (to see it refused)
    max_divisor: int = MAX_DIVISOR
    #: Keep every packet received, for :meth:`LiveClient.replay` (all the bytes of the session).
    keep_packets: bool = False
    defer_interpolation: bool = True

    def __post_init__(self) -> None:
        # What the hello carries, checked here: on the network thread a hello that does not
        # encode ended in a traceback and, seconds later, an idle timeout read as a refusal.
        if not isinstance(self.token, str) or len(self.token.encode()) > MAX_TOKEN:
            raise InvalidInputError(f"token: expected a str of at most {MAX_TOKEN} bytes")
        check_float("display_fps", self.display_fps, lo=MIN_DISPLAY_FPS, hi=MAX_FPS)
        # The rest failed on the network thread or later still: a port out of range inside
        # asyncio, an unknown method when the welcome came, and a fingerprint with colons or
        # capitals (as certificate tools print it) never matched the server's.
        if not check_str("host", self.host):
            raise InvalidInputError("host: expected a host name or address, got ''")
        check_int("port", self.port, 1, 65535)
        if self.fingerprint is not None:
            try:
                fingerprint = normalise_fingerprint(check_str("fingerprint", self.fingerprint))
            except ProtocolError as e:
                raise InvalidInputError(str(e)) from None
            object.__setattr__(self, "fingerprint", fingerprint)
        check_str("method", self.method, METHODS)
        # threading.Event.wait takes at most about 49 days; an hour is more than any connect.
        check_float("connect_timeout", self.connect_timeout, positive=True, hi=3600.0)
        check_backend(self.backend)
        object.__setattr__(self, "keep_packets", check_bool("keep_packets", self.keep_packets))
        check_int("version", self.version, 0, 0xFFFF)
        check_int("max_divisor", self.max_divisor, 1, 16)  # RateGovernor's range
        object.__setattr__(
            self, "defer_interpolation", check_bool("defer_interpolation", self.defer_interpolation)
        )


class FrameOrder:
    """Puts completed frames back in order for the decoder, which needs every frame after a key
    frame in sequence (the pure logic of the receive side; no network, no clock of its own).
    The order is the encoded sequence, ``FrameHeader.seq`` (the frame index skips what the
    server did not render; the sequence does not).

    :meth:`complete` takes a frame whose stream finished; :meth:`tick` is called periodically.
    Frames are handed to ``submit`` in index order. A gap followed by a key frame is skipped at
    once (the server skipped frames). A gap followed by other frames is waited for ``give_up``
    seconds (a retransmission may fill it); then the missing frames are given up (``stop`` on
    their streams, when known), the client waits for a key frame and ``request_key`` asks for
    one, repeated every ``repeat`` seconds until it comes."""

    def __init__(
        self,
        submit: Callable[[FrameHeader, bytes], None],
        request_key: Callable[[int, int], None],
        stop: Callable[[int], None],
        give_up: float,
        repeat: float = 1.0,
    ) -> None:
        self._submit, self._request_key, self._stop = submit, request_key, stop
        self.give_up, self.repeat = give_up, repeat
        self.next: int | None = None  # None: waiting for a key frame
        self.last = -1
        self.pending: dict[int, tuple[FrameHeader, bytes]] = {}
        self.in_flight: dict[int, int] = {}  # seq -> stream id (header seen)
        self._gap_since: float | None = None
        self._requested_at: float | None = None
        self.waiting_for_key = False  # after a loss (not at the start)
        self.lost = 0
        self.key_requests = 0
        self.recoveries = 0
        self.submitted = 0

    def started(self, seq: int, stream_id: int) -> None:
        self.in_flight[seq] = stream_id

    def complete(self, header: FrameHeader, payload: bytes, now: float) -> None:
        self.in_flight.pop(header.seq, None)
        if header.seq <= self.last:
            return  # older than what the decoder already has (a late retransmission)
        self.pending[header.seq] = (header, payload)
        self._flush(now)

    def undecodable(self, seq: int, now: float) -> None:
        """The decoder refused frame ``seq``: the stream is broken until a key frame."""
        if self.next is not None or not self.waiting_for_key:
            self.next = None
            self.waiting_for_key = True
            self.pending = {i: p for i, p in self.pending.items() if p[0].key}
            self._ask(seq, KEY_UNDECODABLE, now)

    def tick(self, now: float) -> None:
        self._flush(now)
        if self.next is None and self._requested_at is not None:
            if now - self._requested_at >= self.repeat:
                self._ask(self.last, KEY_LOST, now)

    def _ask(self, last: int, reason: int, now: float) -> None:
        self._requested_at = now
        self.key_requests += 1
        self._request_key(last, reason)

    def _take(self, index: int) -> None:
        header, payload = self.pending.pop(index)
        self.pending = {i: p for i, p in self.pending.items() if i > index}
        self.next, self.last = index + 1, index
        self._gap_since = None
        if header.key and self.waiting_for_key:
            self.recoveries += 1
            self.waiting_for_key = False
            self._requested_at = None
        self.submitted += 1
        self._submit(header, payload)

    def _flush(self, now: float) -> None:
        while self.pending:
            first = min(self.pending)
            if self.next is None:
                keys = [i for i, p in self.pending.items() if p[0].key]
                if keys:
                    self._take(min(keys))
                    continue
                # Nothing decodable: a non-key frame with no key before it.
                self.pending = {}
                if self._requested_at is None:
                    self.waiting_for_key = self.last >= 0
                    self._ask(self.last, KEY_START if self.last < 0 else KEY_LOST, now)
                return
            if first == self.next or (first > self.next and self.pending[first][0].key):
                self._take(first)
                continue
            if first < self.next:
                del self.pending[first]
                continue
            # A gap before a non-key frame: wait a little for the missing frames.
            if self._gap_since is None:
                self._gap_since = now
            if now - self._gap_since < self.give_up:
                return
            for i in [i for i in self.in_flight if i < first]:
                self._stop(self.in_flight.pop(i))
            self.lost += first - self.next
            self.next = None
            self.waiting_for_key = True
            self._gap_since = None
            self.pending = {i: p for i, p in self.pending.items() if p[0].key}
            self._ask(self.last, KEY_LOST, now)
            return


def _pixel_limit(welcome: Welcome) -> int:
    """The most pixels a packet of this server may declare, per camera and in all: twice its
    welcome's main camera (the rig's two half-size auxiliary cameras make 1.5 times). The
    decoder's own limit is 2^25 pixels, about a gigabyte of buffers, which a server that
    declares cameras larger than its welcome's could make the client allocate per packet."""
    return max(1, 2 * welcome.width * welcome.height)


class _TimeIndexed(StreamDecoder):
    """The stream decoder, with each frame's index taken back from its time (``round(t ·
    f_s)``): the packets are indexed by their place in the encoded sequence (consecutive, as
    the decoder checks), while the client orders frames by time (FrameHeader). ``spans``
    (by ``seq``, from the frame headers; absent: 1) give each frame its span, which the
    packet does not carry. ``welcome``: the server's, whose size bounds the pixels a packet
    may declare (:func:`_pixel_limit`)."""

    def __init__(self, welcome: Welcome, spans: dict[int, int] | None = None) -> None:
        super().__init__(max_pixels=_pixel_limit(welcome))
        self.server_fps = welcome.server_fps
        self.spans: dict[int, int] = {} if spans is None else spans

    def decode(self, data: bytes | memoryview) -> ServerFrame:
        frame = super().decode(data)
        return dataclasses.replace(
            frame,
            index=round(frame.time * self.server_fps),
            span=self.spans.get(frame.index, 1),
        )


@dataclass
class _NetStats:
    frames_completed: int = 0
    bytes_received: int = 0
    malformed_streams: int = 0
    streams_reset: int = 0
    pose_datagrams: int = 0
    reports: int = 0
    key_frames: int = 0
    decode_errors: int = 0
    last_arrival: float | None = None  # display time of the newest completed frame
    longest_gap: float = 0.0  # the longest time without a completed frame, from time 0
    # The newest frames': index, Mb/s, arrival, sent (display s), server render + encode ms,
    # bytes, span.
    targets: deque[tuple[int, float, float, float, float, int, int]] = field(
        default_factory=lambda: deque(maxlen=KEEP_FRAME_RECORDS)
    )
    server_render_ms: Tally = field(default_factory=Tally)
    server_encode_ms: Tally = field(default_factory=Tally)
    closed_at: float | None = None
    closed_reason: str | None = None
    #: Whether the connection closed other than by the client's end of the session (the
    #: server closed it, went silent for the idle timeout, or the client failed).
    closed_early: bool = False
    last_packet: float | None = None  # display time of the newest packet from the server


class _Connection(QuicConnectionProtocol):
    owner: LiveClient

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._windows = ReceiveWindows(self._quic)
        self._control_id: int | None = None
        self._control = ControlReader()
        self._bufs: dict[int, bytearray] = {}
        self._headers: dict[int, FrameHeader] = {}
        # Streams ended or given up (ids, newest last) and the highest id forgotten of them: a
        # set of every one grew by a frame stream per server frame for the session's length.
        self._dead: dict[int, None] = {}
        self._dead_below = -1
        self._declared = 0  # bytes the headers of the frames still arriving announce

    def datagram_received(self, data: bytes | str, addr: Any) -> None:
        # Any packet (acknowledgements of the poses included): whether the server is there.
        self.owner.net.last_packet = self.owner._now()
        super().datagram_received(data, addr)

    def quic_event_received(self, event: QuicEvent) -> None:
        try:
            self._event(event)
        except Exception as e:  # noqa: BLE001 - raised in asyncio's callback, it was a traceback
            # and the session went on without what failed; it ends instead, with the reason.
            reason = f"client error: {type(e).__name__}: {e}".splitlines()[0][:200]
            o = self.owner
            if o.net.closed_reason is None:
                o.net.closed_reason, o.net.closed_at = reason, o._now()
                o.net.closed_early = not o._ending
            self._quic.close(error_code=CLOSE_BYE, reason_phrase=reason)
            self.transmit()

    def _event(self, event: QuicEvent) -> None:
        o = self.owner
        self._windows.delivered(event)
        if isinstance(event, HandshakeCompleted):
            self._handshake()
        elif isinstance(event, StreamDataReceived):
            if event.stream_id == self._control_id:
                self._control_data(event.data)
            elif event.stream_id % 4 == 3:  # server-initiated unidirectional: a frame
                self._frame_data(event.stream_id, event.data, event.end_stream)
            elif not self._is_dead(event.stream_id):
                self._kill(event.stream_id)
                o.net.malformed_streams += 1
        elif isinstance(event, StreamReset):
            if event.stream_id in self._bufs or event.stream_id in self._headers:
                o.net.streams_reset += 1
            self._forget(event.stream_id)
        elif isinstance(event, ConnectionTerminated):
            o.terminated(event.error_code, event.reason_phrase)

    def _handshake(self) -> None:
        o = self.owner
        from cryptography.hazmat.primitives.serialization import Encoding

        cert = self._quic.tls._peer_certificate
        der = b"" if cert is None else cert.public_bytes(Encoding.DER)
        o.server_fingerprint = fingerprint_hex(der)
        pinned = o.options.fingerprint
        if pinned is not None and not hmac.compare_digest(
            hashlib.sha256(der).hexdigest(), pinned
        ):
            # Before the hello: the token never goes to a server that is not the pinned one.
            o.refuse(
                f"the server's certificate (SHA-256 {o.server_fingerprint}) does not match "
                "the pinned fingerprint (--fingerprint, ConnectOptions.fingerprint)"
            )
            self._quic.close(error_code=CLOSE_BYE, reason_phrase="certificate mismatch")
            self.transmit()
            return
        self._control_id = self._quic.get_next_available_stream_id()
        hello = Hello(o.options.token, 0, 0, o.options.display_fps, o.options.version)
        self._quic.send_stream_data(self._control_id, frame_control(hello.encode()))
        self.transmit()
        # Not cancelled on the welcome: _no_welcome does nothing once there is one.
        asyncio.get_running_loop().call_later(WELCOME_TIMEOUT_S, self._no_welcome)

    def _no_welcome(self) -> None:
        """A server that took the hello and said nothing: a session cannot start."""
        o = self.owner
        if o.welcome is None:
            o.refuse(f"no welcome from the server within {WELCOME_TIMEOUT_S:g} s of the hello")
            self._quic.close(error_code=CLOSE_BYE, reason_phrase="no welcome")
            self.transmit()

    def _control_data(self, data: bytes) -> None:
        o = self.owner
        try:
            for raw in self._control.feed(data):
                msg = decode_control(raw)
                if isinstance(msg, Welcome) and o.welcome is None:
                    o.welcomed(msg)
                else:
                    o.net.malformed_streams += 1
        except ProtocolError as e:
            o.net.malformed_streams += 1
            if o.welcome is None:
                o.refuse(f"bad welcome from the server: {e}")
                self._quic.close(error_code=CLOSE_BYE, reason_phrase="bad welcome")
                self.transmit()

    def _is_dead(self, sid: int) -> bool:
        return sid in self._dead or (sid <= self._dead_below and sid not in self._bufs)

    def _kill(self, sid: int) -> None:
        """What comes on stream ``sid`` from now on is ignored."""
        gone = _put_bounded(self._dead, sid, None, KEEP_DEAD_STREAMS)
        if gone is not None:
            self._dead_below = max(self._dead_below, gone)

    def _forget(self, sid: int) -> None:
        self._bufs.pop(sid, None)
        header = self._headers.pop(sid, None)
        if header is not None:
            self._declared -= header.size
        self.owner.in_progress.pop(sid, None)

    def _drop(self, sid: int) -> None:
        """A malformed frame stream: counted, forgotten, and the server told to stop it."""
        self.owner.net.malformed_streams += 1
        self._forget(sid)
        self._kill(sid)
        self._quic.stop_stream(sid, STOP_STALE)
        self.transmit()

    def _frame_data(self, sid: int, data: bytes, end: bool) -> None:
        if self._is_dead(sid):
            return
        buf = self._bufs.setdefault(sid, bytearray())
        buf += data
        header = self._headers.get(sid)
        if header is None and len(buf) >= FrameHeader.SIZE:
            try:
                header = FrameHeader.decode(bytes(buf[: FrameHeader.SIZE]))
            except ProtocolError:
                self._drop(sid)
                return
            if self._declared + header.size > MAX_ARRIVING_BYTES:
                # Frames that never end were buffered without a bound (QUIC's windows grow as
                # the client reads): at most this much is held for the frames arriving.
                self._drop(sid)
                return
            self._headers[sid] = header
            self._declared += header.size
            self.owner.order.started(header.seq, sid)
        self.owner.received(sid, len(data), header)
        if header is not None and len(buf) > FrameHeader.SIZE + header.size:
            self._drop(sid)  # more bytes than the header announced
            return
        if end:
            if header is None or len(buf) != FrameHeader.SIZE + header.size:
                self._drop(sid)  # truncated
                return
            payload = bytes(buf[FrameHeader.SIZE :])
            first = self.owner.in_progress.get(sid, [math.nan])[0]
            self._forget(sid)
            self._kill(sid)
            self.owner.frame_complete(header, payload, first)

    def stop(self, sid: int) -> None:
        if not self._is_dead(sid):
            self._forget(sid)
            self._kill(sid)
            try:
                self._quic.stop_stream(sid, STOP_STALE)
            except ValueError:
                pass  # already gone
            self.transmit()

    def send_control(self, message: bytes) -> None:
        if self._control_id is not None:
            self._quic.send_stream_data(self._control_id, frame_control(message))
            self.transmit()

    def send_datagram(self, data: bytes) -> None:
        self._quic.send_datagram_frame(data)
        self.transmit()


def _put_bounded(d: dict[int, Any], key: int, value: Any, keep: int | None) -> int | None:
    """``d[key] = value``, then the oldest entry dropped beyond ``keep`` (``None``: none);
    returns the key dropped."""
    d[key] = value
    if keep is None or len(d) <= keep:
        return None
    oldest: int = next(iter(d))
    del d[oldest]
    return oldest


def _checked_pose(motion: Callable[[float], _F64], t: float) -> _F64:
    """``motion(t)`` as a ``float64`` 4x4 world-from-camera pose, checked as the server checks
    the poses it receives (:func:`~splitrender.net.protocol.pose_problem`). A NaN pose was sent
    (the server dropped it as malformed) and then refused as ``Camera.view``, a name the caller
    never used; a scaled one was rendered here and dropped by the server without a word.

    Raises:
        InvalidInputError: naming ``motion`` and ``t``."""
    m = motion(t)
    where = f"motion({t:g})"
    try:
        a = np.asarray(m, dtype=np.float64)
    except (TypeError, ValueError):
        a = None
    if a is None or a.shape != (4, 4):
        got = type(m).__name__ if a is None else f"shape {a.shape}"
        raise InvalidInputError(
            f"{where}: expected a 4x4 world-from-camera pose matrix, got {got}"
        )
    problem = pose_problem(a)
    if problem is None and not np.array_equal(a[3], (0.0, 0.0, 0.0, 1.0)):
        problem = "expected a last row 0 0 0 1"
    if problem is not None:
        raise InvalidInputError(f"{where}: not a world-from-camera pose: {problem}")
    return a


class LiveClient:
    """``splitrender connect``: :meth:`connect` opens the session (raises
    :class:`~splitrender.errors.ProtocolError` with the server's one-line reason when refused,
    or when the certificate does not match), :meth:`run` shows ``seconds`` of display frames at
    the poses ``motion(t)`` (world-from-camera) and returns the report (:meth:`report`).
    :meth:`run` closes the session when it ends, also when it raises; a client that connected
    and does not run is closed with :meth:`close`, or used as a context manager."""

    def __init__(self, options: ConnectOptions) -> None:
        self.options = options
        self.net = _NetStats()
        self.welcome: Welcome | None = None
        self.server_fingerprint: str | None = None
        self._refusal: str | None = None
        self._ready = threading.Event()
        self._loop: asyncio.AbstractEventLoop | None = None
        self._conn: _Connection | None = None
        self._stop: asyncio.Event | None = None
        self._thread: threading.Thread | None = None
        self._t0: float | None = None
        self._pose_seq = 0
        self._bytes: deque[tuple[float, int]] = deque()  # loop time, frame stream bytes
        self._fresh: tuple[float, float] | None = None  # queue (s), rate (b/s): newest frame
        #: Frames being received: stream id -> [first byte (loop time), bytes, header.sent].
        self.in_progress: dict[int, list[float]] = {}
        self._usable: list[float] = []  # lateness (s) of the frames usable since the report
        #: Each server frame (by index) handed to the display during the run: the display
        #: time and whether ``server_frames_late`` counted it (``on_handover``); the newest
        #: :data:`KEEP_FRAME_RECORDS`.
        self.usable_at: dict[int, tuple[float, bool]] = {}
        self._ending = False  # close() was called: the session's own end
        self._any_usable = False
        self._min_delay: float | None = None
        self._reported = 0.0  # loop time of the last rate report
        self.realtime: RealtimeClient | None = None
        #: (display time, packet) of every packet handed to the decoder: :meth:`replay` feeds
        #: them to another method in the same conditions.
        self.arrivals: list[tuple[float, bytes]] = []
        #: Each frame's span (FrameHeader.span) by its seq, for the decoder (the packet does
        #: not carry it): the newest :data:`KEEP_FRAME_RECORDS` (all with ``keep_packets``,
        #: for :meth:`replay`).
        self.spans: dict[int, int] = {}
        self.order = FrameOrder(self._submit, self._request_key, self._stop_stream, 0.1)

    # -- network thread -------------------------------------------------------------------

    def _now(self) -> float:
        """Display time (session seconds) on the display's clock (0 before the display runs)."""
        return 0.0 if self._t0 is None else time.monotonic() - self._t0

    def refuse(self, reason: str) -> None:
        if self._refusal is None:
            self._refusal = reason
        self._ready.set()

    def welcomed(self, welcome: Welcome) -> None:
        self.welcome = welcome
        self.order.give_up = 1.0 / welcome.server_fps
        self.realtime = RealtimeClient(
            client=Client(
                self.options.method, server_fps=welcome.server_fps, backend=self.options.backend
            ),
            display_fps=self.options.display_fps,
            max_divisor=self.options.max_divisor,
            defer_interpolation=self.options.defer_interpolation,
            decoder=_TimeIndexed(welcome, self.spans),
            on_handover=self._handed,
        )
        self._ready.set()

    def _handed(self, h: Handover) -> None:
        """A server frame handed to the display (the display's or the worker's thread, under
        the real-time client's lock): report.json's per-frame ``usable`` and ``usable_late``
        are the real-time loop's own decisions, which ``server_frames_late`` counts."""
        _put_bounded(self.usable_at, h.index, (h.display_time, h.late), KEEP_FRAME_RECORDS)

    def terminated(self, code: int, reason: str) -> None:
        if self.welcome is None and self.server_fingerprint is None:
            # Closed before the handshake completed: nobody (or no QUIC server) answered.
            o = self.options
            said = printable(reason) or f"code {code}"
            self.refuse(f"no answer from {o.host}:{o.port} ({said}): is `splitrender serve` "
                        "running there?")
        elif self.welcome is None:
            said = printable(reason) or f"connection closed (code {code})"
            self.refuse(f"refused by the server: {said}")
        if self.net.closed_reason is None:
            # The code's own words when the peer gave none (a bare close read "code 0").
            self.net.closed_reason = reason or CLOSE_TEXT.get(code, f"code {code}")
            self.net.closed_at = self._now()
            self.net.closed_early = not self._ending
        if self._stop is not None:
            self._stop.set()

    def frame_complete(self, header: FrameHeader, payload: bytes, first: float) -> None:
        """Frame stream done: ``first``: the loop time its first bytes came (NaN: unknown)."""
        n = self.net
        arrival = self._now()
        loop_now = asyncio.get_running_loop().time()
        n.frames_completed += 1
        size = len(payload) + FrameHeader.SIZE
        n.bytes_received += size
        n.key_frames += header.key
        n.longest_gap = max(n.longest_gap, arrival - (n.last_arrival or 0.0))
        n.last_arrival = arrival
        n.targets.append((header.index, header.target_bps / 1e6, arrival, header.sent,
                          header.render_ms + header.encode_ms, size, header.span))
        _put_bounded(self.spans, header.seq, header.span,
                     None if self.options.keep_packets else KEEP_FRAME_RECORDS)
        n.server_render_ms.add(header.render_ms)
        n.server_encode_ms.add(header.encode_ms)
        # One-way delay up to a constant (the two clocks' offset): its excess over the least
        # seen is the queue the frame met (the link's and the sender's).
        delay = loop_now - header.sent
        self._min_delay = delay if self._min_delay is None else min(self._min_delay, delay)
        took = loop_now - first
        # News for the next report: this frame's queueing, and its bytes over the time they
        # took to come (when it queued, the rate of the link it queued on).
        self._fresh = (delay - self._min_delay, 8 * size / took if took > 0.02 else math.nan)
        self.order.complete(header, payload, loop_now)
        if self._t0 is not None:
            # A report per frame as well as per interval: a link that narrows shows in the
            # first frame it delays, and the server hears of it at once.
            self._report()

    def _submit(self, header: FrameHeader, payload: bytes) -> None:
        assert self.realtime is not None
        if self.options.keep_packets:  # for replay (every byte received, for the session)
            self.arrivals.append((self._now(), payload))
        fut = self.realtime.submit(payload, pose_time=header.pose_time)
        loop = asyncio.get_running_loop()
        index = header.seq

        def done(f: Any) -> None:
            if f.cancelled():  # the backlog dropped at close
                return
            try:
                if f.exception() is not None:
                    loop.call_soon_threadsafe(self._undecodable, index)
                elif f.result() is not None:
                    # Usable now (decoded and prepared): how late against when the display
                    # first needed it, t_k - m/f_s (m: its span), for the server's planning
                    # (RateReport).
                    k = int(f.result())
                    usable = self._now()
                    loop.call_soon_threadsafe(self._made_usable, k, header.span, usable)
            except RuntimeError:
                pass  # the network loop has ended: nothing left to tell the server

        fut.add_done_callback(done)

    def _made_usable(self, k: int, span: int, usable: float) -> None:
        assert self.welcome is not None and self._loop is not None
        first, self._any_usable = not self._any_usable, True
        if not first:
            # (The session's first frame is for the time it arrives: late by construction.)
            self._usable.append(usable - (k - span) / self.welcome.server_fps)

    def _undecodable(self, index: int) -> None:
        self.net.decode_errors += 1
        assert self._loop is not None
        self.order.undecodable(index, self._loop.time())

    def _request_key(self, last: int, reason: int) -> None:
        if self._conn is not None:
            self._conn.send_control(KeyRequest(last, reason).encode())

    def _stop_stream(self, sid: int) -> None:
        if self._conn is not None:
            self._conn.stop(sid)

    def received(self, sid: int, nbytes: int, header: FrameHeader | None) -> None:
        """Bytes of frame stream ``sid`` arrived (its header, once known)."""
        now = asyncio.get_running_loop().time()
        self._bytes.append((now, nbytes))
        p = self.in_progress.setdefault(sid, [now, 0.0, math.nan])
        p[1] += nbytes
        if header is not None:
            p[2] = header.sent

    def _report(self) -> None:
        loop = asyncio.get_running_loop()
        now = loop.time()
        self._reported = now
        span = RATE_WINDOW_S
        while self._bytes and self._bytes[0][0] < now - span:
            self._bytes.popleft()
        bps = 8 * sum(b for _, b in self._bytes) / span
        # The queueing delay of the newest evidence: the frame completed since the previous
        # report, else a frame still arriving (delayed at least this long so far: a link that
        # narrows shows while the first frame it holds back is on its way); neither: no news
        # (-1), the server holds its target (a report per frame keeps the news fresh).
        queue = -1.0
        rate = math.nan
        if self._fresh is not None:
            queue, rate = self._fresh
            self._fresh = None
        going = [p for p in self.in_progress.values() if math.isfinite(p[2])]
        if going and self._min_delay is not None:
            oldest = min(going, key=lambda p: p[2])
            waited = now - oldest[2] - self._min_delay
            if waited > queue:
                queue = waited
                rate = 8 * oldest[1] / (now - oldest[0]) if now - oldest[0] > 0.02 else math.nan
        if math.isfinite(rate):
            # A frame's own transfer rate, not the window's: the window counts the idle time
            # of a server that sends less than the link carries.
            bps = rate
        late, self._usable = self._usable, []
        self.net.reports += 1
        report = RateReport(
            self.net.reports, self._now(), bps, span, max(queue, 0.0) * 1e3 if queue >= 0 else -1.0,
            self.net.frames_completed, self.order.lost,
            len(late), max(late, default=0.0) * 1e3,
        )
        if self._conn is not None:
            self._conn.send_datagram(report.encode())

    def send_pose(self, t: float, pose: _F64) -> None:
        """From the display thread: the pose of display time ``t`` goes to the server."""
        loop, conn = self._loop, self._conn
        if loop is None or conn is None or self.net.closed_reason is not None:
            return
        self._pose_seq += 1
        data = PoseSample(self._pose_seq, t, pose).encode()
        self.net.pose_datagrams += 1
        try:
            loop.call_soon_threadsafe(conn.send_datagram, data)
        except RuntimeError:
            pass  # the loop has ended (connection gone): poses have nowhere to go

    async def _main(self) -> None:
        o = self.options
        self._loop = asyncio.get_running_loop()
        self._stop = asyncio.Event()
        cfg = QuicConfiguration(
            is_client=True,
            alpn_protocols=[ALPN],
            max_datagram_frame_size=MAX_DATAGRAM,
            idle_timeout=IDLE_TIMEOUT_S,
            # The certificate is checked against the pinned fingerprint once the handshake
            # completes (a self-signed one has no CA to verify against).
            verify_mode=ssl.CERT_NONE,
        )
        owner = self

        class Connection(_Connection):
            pass

        Connection.owner = owner
        try:
            async with connect(
                o.host, o.port, configuration=cfg, create_protocol=Connection,
                wait_connected=True,
            ) as conn:
                assert isinstance(conn, _Connection)
                self._conn = conn
                self._reported = self._loop.time()
                while not self._stop.is_set():
                    # Ticks every TICK_S: the give-up of a missing frame is timely.
                    now = self._loop.time()
                    self.order.tick(now)
                    if self._t0 is not None and now - self._reported >= REPORT_INTERVAL_S:
                        self._report()
                    try:
                        await asyncio.wait_for(self._stop.wait(), TICK_S)
                    except asyncio.TimeoutError:
                        pass
                conn.close(error_code=CLOSE_BYE, reason_phrase="session over")
        except (ConnectionError, OSError, asyncio.TimeoutError) as e:
            self.refuse(f"cannot connect to {o.host}:{o.port}: {e or type(e).__name__}")
        finally:
            self._conn = None
            if self.net.closed_reason is None and self.welcome is not None:
                self.net.closed_reason = "session over"
                self.net.closed_at = self._now()
            self._ready.set()

    def connect(self) -> Welcome:
        """Opens the session; returns the server's welcome.

        Raises:
            ProtocolError: refused (wrong token or version, busy, certificate mismatch; the
                reason in one line) or no answer within ``connect_timeout``.
        """
        self._thread = threading.Thread(
            target=lambda: asyncio.run(self._main()), name="splitrender-net", daemon=True
        )
        self._thread.start()
        if not self._ready.wait(self.options.connect_timeout):
            self.close()
            raise ProtocolError(
                f"no answer from {self.options.host}:{self.options.port} within "
                f"{self.options.connect_timeout:g} s"
            )
        if self._refusal is not None or self.welcome is None:
            self.close()
            raise ProtocolError(self._refusal or "connection closed before the welcome")
        return self.welcome

    def __enter__(self) -> LiveClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _connected(self, what: str) -> Welcome:
        """The welcome of the session :meth:`connect` opened (``what`` names the call)."""
        if self.welcome is None or self.realtime is None:
            raise InvalidInputError(f"LiveClient.{what}: not connected (call connect() first)")
        if self._ending and what == "run":
            raise InvalidInputError(
                f"LiveClient.{what}: the session is over (run() and close() end it; connect "
                "a new LiveClient)"
            )
        return self.welcome

    def close(self) -> None:
        """Ends the session (the connection closed, the real-time client's worker stopped
        with the packets not yet decoded dropped); waits up to 5 s for the network thread."""
        self._ending = True
        loop, stop = self._loop, self._stop
        if loop is not None and stop is not None:
            try:
                loop.call_soon_threadsafe(stop.set)
            except RuntimeError:
                pass
        if self._thread is not None:
            self._thread.join(5.0)
        if self.realtime is not None:
            # Packets not yet decoded are dropped: a server that sent faster than its rate
            # had the command decode the whole backlog after the session (minutes).
            self.realtime.close(drop_pending=True)

    def run(
        self,
        motion: Callable[[float], _F64],
        seconds: float,
        on_frame: Callable[[Any, DisplayFrame], None] | None = None,
        stereo: bool = False,
    ) -> dict[str, Any]:
        """The display loop for ``seconds`` at ``f_c`` (on this thread), sending each pose;
        then closes the session and returns :meth:`report`'s object. ``motion(t)`` is the
        world-from-camera pose at display time ``t``: a 4x4 matrix of a rotation and a position
        (the inverse of :attr:`Camera.view <splitrender.Camera.view>`), last row ``0 0 0 1``.
        The session is closed however the loop ends (an exception of ``motion`` or
        ``on_frame`` included). ``stereo``: each display frame is the two eyes of the head at
        ``motion(t)`` (:meth:`Camera.stereo <splitrender.Camera.stereo>`), ``on_frame`` gets
        ``(left, right)`` (:meth:`RealtimeClient.run`); the server is sent the head's pose.

        Raises:
            InvalidInputError: before :meth:`connect`, or for a pose ``motion`` returns that is
                not such a matrix (named with its time; the server would drop it)."""
        w = self._connected("run")
        assert self.realtime is not None
        proj = np.asarray(w.proj, dtype=np.float64).reshape(4, 4)

        def pose(t: float) -> Camera | tuple[Camera, Camera]:
            m = _checked_pose(motion, t)
            self.send_pose(t, m)
            head = Camera(np.asarray(np.linalg.inv(m), np.float64), proj, w.width, w.height)
            return head.stereo() if stereo else head

        self._t0 = time.monotonic()
        try:
            rt = self.realtime.run(pose, seconds, on_frame=on_frame, stereo=stereo)
        finally:
            # Also when the loop raised: the connection otherwise stayed open (the server
            # busy with it) and the worker's threads running while the object lived.
            self.close()
        self.summary = rt.summary()
        return self.report(seconds)

    def replay(
        self,
        method: str,
        motion: Callable[[float], _F64],
        seconds: float,
        on_frame: Callable[[Any, DisplayFrame], None] | None = None,
        stereo: bool = False,
    ) -> dict[str, Any]:
        """The session again with ``method``, offline from the network: the packets this
        session decoded, each submitted at the display time it was, at the poses ``motion``
        (the session's), through a real-time loop of its own (so what differs between two
        methods is the method, not what the network and the server did). Returns the loop's
        summary. ``stereo`` as :meth:`run`.

        Raises:
            InvalidInputError: for a client made without ``keep_packets``, before
                :meth:`connect`, or for a pose ``motion`` returns that is not one (as
                :meth:`run`)."""
        if not self.options.keep_packets:
            raise InvalidInputError(
                "replay: the packets were not kept; connect with "
                "ConnectOptions(keep_packets=True)")
        w = self._connected("replay")
        proj = np.asarray(w.proj, dtype=np.float64).reshape(4, 4)

        def pose(t: float) -> Camera | tuple[Camera, Camera]:
            view = np.asarray(np.linalg.inv(_checked_pose(motion, t)), np.float64)
            head = Camera(view, proj, w.width, w.height)
            return head.stereo() if stereo else head

        with RealtimeClient(
            client=Client(
                method, server_fps=w.server_fps, backend=backend_for(method, self.options.backend)
            ),
            display_fps=self.options.display_fps,
            max_divisor=self.options.max_divisor,
            defer_interpolation=self.options.defer_interpolation,
            decoder=_TimeIndexed(w, dict(self.spans)),
        ) as rt:
            return rt.run(
                pose, seconds, feed=self.arrivals, on_frame=on_frame, stereo=stereo
            ).summary()

    def report(self, seconds: float) -> dict[str, Any]:
        """``report.json``: the real-time loop's summary, the pose-to-display latency, the
        received rate, and what the network did (frames, key frames and requests, losses,
        recoveries, malformed streams, the outage, the encoder target per frame)."""
        s = dict(self.summary)
        n = self.net
        fs = self.welcome.server_fps if self.welcome is not None else 1.0
        longest_gap = max(n.longest_gap, seconds - (n.last_arrival or 0.0))
        gpu = None if self.realtime is None else self.realtime.client.gpu
        s.update(
            backend=self.options.backend,
            adapter=None if gpu is None else gpu.adapter,
            max_divisor=self.options.max_divisor,
            defer_interpolation=self.options.defer_interpolation,
            pose_to_display_ms_p50=s.get("server_age_ms_p50"),
            # time.monotonic() at display time 0 (the same clock in every process of the
            # machine: events elsewhere, e.g. a relay's bandwidth step, can be placed on
            # the session's timeline).
            monotonic_at_start=self._t0,
            mbps=8 * n.bytes_received / seconds / 1e6,
            network={
                "frames_completed": n.frames_completed,
                "frames_submitted": self.order.submitted,
                "frames_lost": self.order.lost,
                "key_frames": n.key_frames,
                "key_requests": self.order.key_requests,
                "key_recoveries": self.order.recoveries,
                "decode_errors": n.decode_errors,
                "malformed_streams": n.malformed_streams,
                "streams_reset": n.streams_reset,
                "pose_datagrams": n.pose_datagrams,
                "rate_reports": n.reports,
                "longest_gap_s": float(longest_gap),
                "connection_closed_at": n.closed_at,
                # None only when closing the connection took longer than close() waits (the
                # server unreachable through a collapsed link).
                "connection_closed": n.closed_reason or "still closing at the end",
                "server_render_ms_p50": n.server_render_ms.median(),
                "server_encode_ms_p50": n.server_encode_ms.median(),
                "server_fingerprint": self.server_fingerprint,
            },
            # Per frame received (the newest KEEP_FRAME_RECORDS): the encoder target, the
            # arrival (display seconds) and how late it was against when the display first
            # needed it, t_k - m/f_s (m: its span; negative: early), the measure of whether
            # frames arrive on time as the target moves; and when it became usable (decoded
            # and prepared; None: never) and whether that was late (what server_frames_late
            # counts, frame by frame).
            target_mbps=[
                {"index": i, "mbps": round(m, 6), "sent": round(sent, 4),
                 "server_ms": round(ms, 1), "bytes": size,
                 "arrival": round(t, 4),
                 "span": span,
                 "late_ms": round((t - (i - span) / fs) * 1e3, 1),
                 "usable": None if (u := self.usable_at.get(i)) is None else round(u[0], 4),
                 "usable_late": u is not None and u[1]}
                for i, m, t, sent, ms, size, span in n.targets
            ],
        )
        # The server went away before the end: the connection closed then (the idle timeout
        # comes 3 s after its last packet, so a server gone in the last 3 s closed it after
        # the end, and one gone in the last 4 s went unreported), or nothing came from it at
        # all in the last SILENT_S. From when the frames stopped.
        silent = seconds - (n.last_packet or 0.0)
        early = n.closed_early and n.closed_at is not None and n.closed_at < seconds
        if early or silent > SILENT_S:
            s["outage"] = {
                "from": n.last_arrival or 0.0,
                "reason": n.closed_reason if early else (
                    f"no packet from the server in the last {silent:.1f} s of the session"),
            }
        if math.isnan(s["mbps"]):
            s["mbps"] = 0.0
        return s
