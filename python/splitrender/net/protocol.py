"""The live protocol between ``splitrender serve`` and ``splitrender connect`` (docs/protocol.md):
the messages as bytes and back, pure functions with every length and count checked before
anything is allocated.

Three channels of one QUIC connection carry them (ALPN :data:`ALPN`):

- the **control stream** (the client's first bidirectional stream): :class:`Hello` (client),
  :class:`Welcome` (server), then :class:`KeyRequest` (client) as needed, each framed as
  ``u16 length ‖ message`` (:func:`frame_control`, :class:`ControlReader`);
- **datagrams** (client → server, loss-tolerant, newest wins): :class:`PoseSample` and
  :class:`RateReport`;
- one **unidirectional stream per server frame** (server → client): a :class:`FrameHeader`
  followed by the stream-format packet (docs/stream-format.md), so that a late frame never
  blocks the next and a stale one can be given up alone.

A refusal is not a message: the server closes the connection with one of the ``CLOSE_*`` codes
and a one-line reason phrase, and keeps nothing of the session.

Every decoder raises :class:`~splitrender.errors.ProtocolError` (and nothing else) for bytes it
cannot accept, naming the field and what was expected; the peers count and drop those.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import TypeVar

import numpy as np
import numpy.typing as npt

from splitrender.errors import ProtocolError
from splitrender.types import MAX_SIDE, MAX_SPAN

__all__ = [
    "ALPN",
    "CLOSE_BAD_HELLO",
    "CLOSE_BUSY",
    "CLOSE_BYE",
    "CLOSE_DISPLAY",
    "CLOSE_SERVER_ERROR",
    "CLOSE_SHUTDOWN",
    "CLOSE_TEXT",
    "CLOSE_TOKEN",
    "CLOSE_VERSION",
    "MAX_CONTROL",
    "MAX_DATAGRAM",
    "MAX_FPS",
    "MAX_FRAME_PAYLOAD",
    "MAX_SPAN",
    "MAX_TOKEN",
    "MIN_DISPLAY_FPS",
    "MIN_SERVER_FPS",
    "PROTOCOL_VERSION",
    "SCENE_DIGEST_BYTES",
    "ControlReader",
    "FrameHeader",
    "Hello",
    "KeyRequest",
    "PoseSample",
    "RateReport",
    "Welcome",
    "decode_control",
    "decode_datagram",
    "fingerprint_hex",
    "frame_control",
    "hello_version",
    "normalise_fingerprint",
    "pose_problem",
    "printable",
    "unsupported_version",
]

#: The version this code speaks; a hello of any other is refused (:data:`CLOSE_VERSION`).
PROTOCOL_VERSION = 4
#: QUIC's application protocol name (TLS ALPN); a peer without it fails the handshake.
ALPN = "splitrender-live/1"
#: Four bytes that open a :class:`Hello`, so that a stray peer is refused as such.
HELLO_MAGIC = b"SRLV"

#: Largest control message body (after its u16 length): a hello with the longest token is 84 B,
#: a welcome with the longest scene name 457 B.
MAX_CONTROL = 1024
#: Largest datagram either side accepts (a pose is 109 B, a report 43 B).
MAX_DATAGRAM = 256
#: Longest token, in bytes (UTF-8).
MAX_TOKEN = 64
#: The range of a hello's display rate and of a welcome's server rate (frames per second).
MIN_DISPLAY_FPS = 1.0
MIN_SERVER_FPS = 0.1
MAX_FPS = 1000.0
#: Largest stream-format packet behind a frame header: 64 MiB, far above a 2560x1440 frame at
#: the paper's rates (about 0.5 MB) and small enough that a lying header cannot exhaust memory.
MAX_FRAME_PAYLOAD = 64 << 20
#: Largest coordinate of a pose's position (scene units): far beyond any scene, and the
#: renderer's arithmetic stays finite.
MAX_POSITION = 1e6
#: Longest scene name in a welcome, in bytes (UTF-8).
MAX_SCENE_NAME = 255
#: Size of a welcome's scene digest (SHA-256, :meth:`splitrender.scene.Scene.digest`).
SCENE_DIGEST_BYTES = 32

# Connection close codes (QUIC application error codes) of a refusal or an ending.
CLOSE_BYE = 0  #: the session ended normally
CLOSE_VERSION = 1  #: the hello's protocol version is not :data:`PROTOCOL_VERSION`
CLOSE_TOKEN = 2  #: the hello's token is wrong
CLOSE_BAD_HELLO = 3  #: the control stream did not start with a well-formed hello
CLOSE_BUSY = 4  #: the server already serves a session
CLOSE_DISPLAY = 5  #: the display size is not the one the server renders
CLOSE_SERVER_ERROR = 6  #: the server failed to render or encode; the session ends
CLOSE_SHUTDOWN = 7  #: the server is shutting down (Ctrl-C, SIGTERM); the session ends
#: What each close code says when its reason phrase is empty (a peer's own words come first).
CLOSE_TEXT: Mapping[int, str] = {
    CLOSE_BYE: "session over",
    CLOSE_VERSION: "protocol version not supported",
    CLOSE_TOKEN: "wrong token",
    CLOSE_BAD_HELLO: "bad hello",
    CLOSE_BUSY: "busy",
    CLOSE_DISPLAY: "display size not served",
    CLOSE_SERVER_ERROR: "server error",
    CLOSE_SHUTDOWN: "server shutting down",
}

# Message types (the first byte of every message).
T_HELLO = 0x01
T_WELCOME = 0x02
T_KEY_REQUEST = 0x03
T_POSE = 0x10
T_REPORT = 0x11
T_FRAME = 0x20

_F64 = npt.NDArray[np.float64]

_HELLO = struct.Struct("<B4sHB")  # type, magic, version, token length; token; then _HELLO_TAIL
_HELLO_TAIL = struct.Struct("<HHd")  # display width, height (0 = the server's), f_c
_WELCOME = struct.Struct("<BHddHHHdd16d32sB")  # ..., scene digest, name length; the name
_WELCOME_VERSION = struct.Struct("<BH")  # type, version: read before the rest
_KEY_REQUEST = struct.Struct("<BqB")
_POSE = struct.Struct("<BId12d")
_REPORT = struct.Struct("<BIddffIIHf")
_FRAME = struct.Struct("<BqqBddddffIB")

#: Key request reasons.
KEY_LOST = 1  #: a frame was given up (lost, reset, or too late to wait for)
KEY_UNDECODABLE = 2  #: a frame did not decode (the decoder restarts at a key frame)
KEY_START = 3  #: the client has no key frame yet


def _finite(where: str, v: float, lo: float = -math.inf, hi: float = math.inf) -> float:
    if not (math.isfinite(v) and lo <= v <= hi):
        raise ProtocolError(f"{where}: expected a finite number in [{lo:g}, {hi:g}], got {v!r}")
    return float(v)


def _expect(where: str, data: bytes | memoryview, size: int, exact: bool = True) -> None:
    n = len(data)
    if n < size or (exact and n != size):
        raise ProtocolError(
            f"{where}: expected {'' if exact else 'at least '}{size} bytes, got {n}"
        )


def _type(where: str, data: bytes | memoryview, expected: int) -> None:
    if not data:
        raise ProtocolError(f"{where}: empty message")
    if data[0] != expected:
        raise ProtocolError(f"{where}: expected message type {expected:#04x}, got {data[0]:#04x}")


def _text(where: str, raw: bytes | memoryview) -> str:
    try:
        return bytes(raw).decode("utf-8")
    except UnicodeDecodeError:
        raise ProtocolError(f"{where}: expected UTF-8 text") from None


# -- control stream ------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Hello:
    """The client's first message: protocol ``version``, the session ``token``, the display size
    (``0 x 0``: whatever the server renders) and the display rate ``f_c``."""

    token: str
    width: int = 0
    height: int = 0
    display_fps: float = 120.0
    version: int = PROTOCOL_VERSION

    def encode(self) -> bytes:
        token = self.token.encode("utf-8")
        if len(token) > MAX_TOKEN:
            raise ProtocolError(f"hello.token: at most {MAX_TOKEN} bytes, got {len(token)}")
        for name, v in (("width", self.width), ("height", self.height)):
            if not 0 <= v <= MAX_SIDE:
                raise ProtocolError(f"hello.{name}: expected 0..{MAX_SIDE}, got {v}")
        _finite("hello.display_fps", self.display_fps, MIN_DISPLAY_FPS, MAX_FPS)
        return (
            _HELLO.pack(T_HELLO, HELLO_MAGIC, self.version, len(token))
            + token
            + _HELLO_TAIL.pack(self.width, self.height, self.display_fps)
        )

    @classmethod
    def decode(cls, data: bytes | memoryview) -> Hello:
        """The hello in ``data``. A wrong version is reported before anything after it is read,
        so that a newer client learns the version it met, not a parse error."""
        _type("hello", data, T_HELLO)
        _expect("hello", data, _HELLO.size, exact=False)
        _, magic, version, n = _HELLO.unpack_from(data, 0)
        if magic != HELLO_MAGIC:
            raise ProtocolError(f"hello: expected magic {HELLO_MAGIC!r}, got {bytes(magic)!r}")
        if version != PROTOCOL_VERSION:
            raise ProtocolError(f"hello: {unsupported_version(version)}")
        if n > MAX_TOKEN:
            raise ProtocolError(f"hello.token: at most {MAX_TOKEN} bytes, got {n}")
        _expect("hello", data, _HELLO.size + n + _HELLO_TAIL.size)
        token = _text("hello.token", data[_HELLO.size : _HELLO.size + n])
        w, h, fc = _HELLO_TAIL.unpack_from(data, _HELLO.size + n)
        if w > MAX_SIDE or h > MAX_SIDE or (w == 0) != (h == 0):
            raise ProtocolError(
                f"hello: display size {w}x{h}: expected 0x0 or 1..{MAX_SIDE} on each side"
            )
        fc = _finite("hello.display_fps", fc, MIN_DISPLAY_FPS, MAX_FPS)
        return cls(token, w, h, fc, version)


def unsupported_version(version: int) -> str:
    """The one-line reason a hello of another ``version`` is refused with."""
    return (
        f"protocol version {version} is not supported (this server speaks version "
        f"{PROTOCOL_VERSION})"
    )


def hello_version(data: bytes | memoryview) -> int | None:
    """The protocol version a hello declares, read before anything else in it is checked
    (``None``: not even that far a hello), so that a peer of another version is refused as
    such rather than for whatever its hello's layout does differently."""
    if len(data) < _HELLO.size or data[0] != T_HELLO:
        return None
    return int(_HELLO.unpack_from(data, 0)[2])


@dataclass(frozen=True, slots=True)
class Welcome:
    """The server's answer to an accepted hello: what the client needs to display the stream
    (server rate ``f_s``, main camera size and projection, key-frame interval ``gop``, the bit
    rate range) and to compute its own poses (``scene``, the built-in scene, and ``scale``).
    Since version 4 ``scene_digest`` (32 bytes): the :meth:`~splitrender.scene.Scene.digest`
    of exactly what the server renders (variant, placed models and their files too), which a
    client compares with its own scene's before it scores against it."""

    server_fps: float
    scale: float
    width: int
    height: int
    proj: tuple[float, ...]
    gop: int
    max_mbps: float
    min_mbps: float
    scene: str
    scene_digest: bytes
    version: int = PROTOCOL_VERSION

    def encode(self) -> bytes:
        name = self.scene.encode("utf-8")
        if len(name) > MAX_SCENE_NAME:
            raise ProtocolError(f"welcome.scene: at most {MAX_SCENE_NAME} bytes, got {len(name)}")
        if not isinstance(self.scene_digest, bytes) or len(self.scene_digest) != (
            SCENE_DIGEST_BYTES
        ):
            raise ProtocolError(
                f"welcome.scene_digest: expected {SCENE_DIGEST_BYTES} bytes, got "
                f"{self.scene_digest!r:.80}"
            )
        if len(self.proj) != 16:
            raise ProtocolError(f"welcome.proj: expected 16 values, got {len(self.proj)}")
        return (
            _WELCOME.pack(
                T_WELCOME,
                self.version,
                self.server_fps,
                self.scale,
                self.width,
                self.height,
                self.gop,
                self.max_mbps,
                self.min_mbps,
                *self.proj,
                self.scene_digest,
                len(name),
            )
            + name
        )

    @classmethod
    def decode(cls, data: bytes | memoryview) -> Welcome:
        """The welcome in ``data``. Its version is read first, so that a welcome of another
        version (another layout: version 3's has no digest) is refused as such, not for its
        size."""
        _type("welcome", data, T_WELCOME)
        _expect("welcome", data, _WELCOME_VERSION.size, exact=False)
        version = _WELCOME_VERSION.unpack_from(data, 0)[1]
        if version != PROTOCOL_VERSION:
            raise ProtocolError(
                f"welcome: protocol version {version}, expected {PROTOCOL_VERSION}"
            )
        _expect("welcome", data, _WELCOME.size, exact=False)
        _, _, fs, scale, w, h, gop, hi, lo, *rest = _WELCOME.unpack_from(data, 0)
        proj, digest, n = tuple(float(v) for v in rest[:16]), bytes(rest[16]), rest[17]
        _expect("welcome", data, _WELCOME.size + n)
        fs = _finite("welcome.server_fps", fs, MIN_SERVER_FPS, MAX_FPS)
        scale = _finite("welcome.scale", scale, 1e-6, 16.0)
        if not (1 <= w <= MAX_SIDE and 1 <= h <= MAX_SIDE):
            raise ProtocolError(f"welcome: size {w}x{h}: expected 1..{MAX_SIDE} on each side")
        if gop < 1:
            raise ProtocolError(f"welcome.gop: expected >= 1, got {gop}")
        hi = _finite("welcome.max_mbps", hi, 1e-6, 1e6)
        lo = _finite("welcome.min_mbps", lo, 1e-6, hi)
        for i, v in enumerate(proj):
            _finite(f"welcome.proj[{i}]", v)
        name = _text("welcome.scene", data[_WELCOME.size :])
        return cls(fs, scale, w, h, proj, gop, hi, lo, name, digest, version)


@dataclass(frozen=True, slots=True)
class KeyRequest:
    """The client asks for a key frame: ``last`` is the ``seq`` of the last frame it decoded
    (-1: none),
    ``reason`` one of ``KEY_LOST``, ``KEY_UNDECODABLE``, ``KEY_START``."""

    last: int
    reason: int = KEY_LOST

    def encode(self) -> bytes:
        return _KEY_REQUEST.pack(T_KEY_REQUEST, self.last, self.reason)

    @classmethod
    def decode(cls, data: bytes | memoryview) -> KeyRequest:
        _type("key request", data, T_KEY_REQUEST)
        _expect("key request", data, _KEY_REQUEST.size)
        _, last, reason = _KEY_REQUEST.unpack_from(data, 0)
        if last < -1:
            raise ProtocolError(f"key request.last: expected >= -1, got {last}")
        if reason not in (KEY_LOST, KEY_UNDECODABLE, KEY_START):
            raise ProtocolError(f"key request.reason: expected 1, 2 or 3, got {reason}")
        return cls(int(last), int(reason))


def frame_control(message: bytes) -> bytes:
    """``message`` framed for the control stream: its u16 length, then itself."""
    if not 0 < len(message) <= MAX_CONTROL:
        raise ProtocolError(f"control message: expected 1..{MAX_CONTROL} bytes, got {len(message)}")
    return struct.pack("<H", len(message)) + message


_T = TypeVar("_T")


def _decode_by_type(
    data: bytes | memoryview, what: str, decoders: Mapping[int, Callable[[bytes | memoryview], _T]]
) -> _T:
    """``data`` decoded by the decoder of its first byte, the message type (``what`` names the
    kind of message in errors)."""
    if not data:
        raise ProtocolError(f"{what}: empty")
    decode = decoders.get(data[0])
    if decode is None:
        raise ProtocolError(f"{what}: unknown type {data[0]:#04x}")
    return decode(data)


_CONTROL_DECODERS: dict[int, Callable[[bytes | memoryview], Hello | Welcome | KeyRequest]] = {
    T_HELLO: Hello.decode,
    T_WELCOME: Welcome.decode,
    T_KEY_REQUEST: KeyRequest.decode,
}


def decode_control(data: bytes | memoryview) -> Hello | Welcome | KeyRequest:
    """One control message (without its length) by its type byte."""
    return _decode_by_type(data, "control message", _CONTROL_DECODERS)


class ControlReader:
    """Splits the bytes of a control stream, as they arrive in pieces, into messages.

    :meth:`feed` returns the complete messages so far (raw, for :func:`decode_control`). A
    length of 0 or over :data:`MAX_CONTROL` raises :class:`ProtocolError` before the body is
    waited for; so does more than ``max_buffer`` bytes pending (a peer that never completes)."""

    def __init__(self, max_buffer: int = 4 * MAX_CONTROL) -> None:
        self._buf = bytearray()
        self._max = max_buffer

    def feed(self, data: bytes) -> list[bytes]:
        self._buf += data
        out: list[bytes] = []
        while len(self._buf) >= 2:
            (n,) = struct.unpack_from("<H", self._buf, 0)
            if not 0 < n <= MAX_CONTROL:
                raise ProtocolError(
                    f"control stream: message length {n}, expected 1..{MAX_CONTROL}"
                )
            if len(self._buf) < 2 + n:
                break
            out.append(bytes(self._buf[2 : 2 + n]))
            del self._buf[: 2 + n]
        if len(self._buf) > self._max:
            raise ProtocolError(f"control stream: more than {self._max} bytes pending")
        return out


# -- datagrams -----------------------------------------------------------------------------------


def _pose_rows(pose: _F64) -> tuple[float, ...]:
    m = np.asarray(pose, dtype=np.float64)
    if m.shape != (4, 4):
        raise ProtocolError(f"pose: expected a 4x4 matrix, got shape {m.shape}")
    return tuple(float(v) for v in m[:3].ravel())


@dataclass(frozen=True, slots=True)
class PoseSample:
    """One pose of the client: sequence number ``seq``, its display time ``time`` (session
    seconds, the client's clock) and ``pose`` (world-from-camera, 4x4; the last row travels as
    ``0 0 0 1`` implicitly)."""

    seq: int
    time: float
    pose: _F64

    def encode(self) -> bytes:
        return _POSE.pack(T_POSE, self.seq & 0xFFFFFFFF, self.time, *_pose_rows(self.pose))

    @classmethod
    def decode(cls, data: bytes | memoryview) -> PoseSample:
        _type("pose", data, T_POSE)
        _expect("pose", data, _POSE.size)
        _, seq, t, *rows = _POSE.unpack_from(data, 0)
        t = _finite("pose.time", t, -1e9, 1e9)
        m = np.eye(4)
        m[:3] = np.asarray(rows, dtype=np.float64).reshape(3, 4)
        problem = pose_problem(m)
        if problem is not None:
            raise ProtocolError(f"pose.pose: {problem}")
        return cls(int(seq), t, m)


def pose_problem(m: _F64) -> str | None:
    """What makes the 4x4 ``m`` (its top three rows) no pose a server takes (``None``: it is
    one): non-finite values, a position beyond ±:data:`MAX_POSITION`, or a 3x3 part that is not
    a rotation (the renderer refuses anything else; orthonormal within float noise). The server
    drops such a ``POSE`` datagram (:meth:`PoseSample.decode`); a client checks its poses with
    it before it sends them."""
    if not np.isfinite(m[:3]).all() or np.abs(m[:3, 3]).max() > MAX_POSITION:
        return f"expected finite values, positions within ±{MAX_POSITION:g}"
    r = m[:3, :3]
    if np.abs(r).max() > 1.001:  # before the product below (it could overflow)
        return "the 3x3 part is not a rotation"
    if not np.allclose(r @ r.T, np.eye(3), atol=1e-4) or np.linalg.det(r) <= 0:
        return "the 3x3 part is not a rotation"
    return None


@dataclass(frozen=True, slots=True)
class RateReport:
    """The client's receive statistics for adaptive bit-rate: ``receive_bps`` over its last
    window, ``queue_ms`` (how much later than the least-delayed frame the recent frames
    completed: the queue the link builds; since version 2 that of the newest frame completed
    or still arriving, and −1 when no frame came since the previous report: no news), and
    running counts. Since version 2 also the
    timeliness of the frames made usable (decoded and prepared) in the window: ``usable`` of
    them, the latest by ``late_ms`` (usable time minus ``t_k − m/f_s``, when the display
    first needed it; negative: early; 0 when ``usable`` is 0). The server plans its frames
    that much earlier (:class:`splitrender.net.abr.LeadController`)."""

    seq: int
    time: float
    receive_bps: float
    window_s: float
    queue_ms: float
    frames_received: int
    frames_lost: int
    usable: int = 0
    late_ms: float = 0.0

    def encode(self) -> bytes:
        return _REPORT.pack(
            T_REPORT,
            self.seq & 0xFFFFFFFF,
            self.time,
            self.receive_bps,
            self.window_s,
            self.queue_ms,
            self.frames_received & 0xFFFFFFFF,
            self.frames_lost & 0xFFFFFFFF,
            min(self.usable, 0xFFFF),
            self.late_ms,
        )

    @classmethod
    def decode(cls, data: bytes | memoryview) -> RateReport:
        _type("report", data, T_REPORT)
        _expect("report", data, _REPORT.size)
        _, seq, t, bps, win, q, rx, lost, usable, late = _REPORT.unpack_from(data, 0)
        return cls(
            int(seq),
            _finite("report.time", t, -1e9, 1e9),
            _finite("report.receive_bps", bps, 0.0, 1e12),
            _finite("report.window_s", win, 0.0, 3600.0),
            _finite("report.queue_ms", q, -1.0, 1e7),
            int(rx),
            int(lost),
            int(usable),
            _finite("report.late_ms", late, -1e7, 1e7),
        )


_DATAGRAM_DECODERS: dict[int, Callable[[bytes | memoryview], PoseSample | RateReport]] = {
    T_POSE: PoseSample.decode,
    T_REPORT: RateReport.decode,
}


def decode_datagram(data: bytes | memoryview) -> PoseSample | RateReport:
    """A client datagram by its type byte (anything over :data:`MAX_DATAGRAM` is refused
    first)."""
    if len(data) > MAX_DATAGRAM:
        raise ProtocolError(f"datagram: {len(data)} bytes, at most {MAX_DATAGRAM}")
    return _decode_by_type(data, "datagram", _DATAGRAM_DECODERS)


# -- frame streams -------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class FrameHeader:
    """What precedes a server frame's packet on its stream: ``index`` (the frame's time is
    ``index / f_s``), ``seq`` (its place in the encoded sequence, which is the index in the
    packet: the decoder needs consecutive ``seq`` or a key frame, while ``index`` skips the
    frames the server could not render in time) and ``key``, so that the client can order
    and give up frames without parsing the packet; ``pose_time`` (the
    display time of the newest pose the server had when it predicted: pose-to-display latency
    is measured from it), ``predicted_time`` (the time the pose was predicted for), ``sent``
    (when the server sent the frame; since version 2 on the client's display clock as the
    server estimates it from the poses, early by the least one-way delay of a pose: the client
    measures queueing from its variation), the encoder's ``target_bps`` (since version 2 the
    one the frame was encoded at, not a newer one still waiting for a key frame), the server's
    ``render_ms``/``encode_ms``, the packet's ``size`` and (since version 3) ``span``: the
    server-frame periods the frame's motion spans (``1..MAX_SPAN``; above 1 when the server
    cannot keep ``f_s`` and renders every ``span``-th frame, :attr:`ServerFrame.span`)."""

    index: int
    seq: int
    key: bool
    pose_time: float
    predicted_time: float
    sent: float
    target_bps: float
    render_ms: float
    encode_ms: float
    size: int
    span: int = 1

    SIZE = _FRAME.size

    def encode(self) -> bytes:
        return _FRAME.pack(
            T_FRAME,
            self.index,
            self.seq,
            int(self.key),
            self.pose_time,
            self.predicted_time,
            self.sent,
            self.target_bps,
            self.render_ms,
            self.encode_ms,
            self.size,
            self.span,
        )

    @classmethod
    def decode(cls, data: bytes | memoryview) -> FrameHeader:
        """The header at the start of ``data`` (the packet may follow)."""
        _type("frame header", data, T_FRAME)
        _expect("frame header", data, _FRAME.size, exact=False)
        _, index, seq, key, pt, tt, sent, bps, rms, ems, size, span = _FRAME.unpack_from(data, 0)
        if index < 0 or seq < 0:
            raise ProtocolError(f"frame header: index {index}, seq {seq}: expected >= 0")
        if key not in (0, 1):
            raise ProtocolError(f"frame header.key: expected 0 or 1, got {key}")
        if not 0 < size <= MAX_FRAME_PAYLOAD:
            raise ProtocolError(
                f"frame header.size: expected 1..{MAX_FRAME_PAYLOAD} bytes, got {size}"
            )
        if not 1 <= span <= MAX_SPAN:
            raise ProtocolError(f"frame header.span: expected 1..{MAX_SPAN}, got {span}")
        return cls(
            int(index),
            int(seq),
            bool(key),
            _finite("frame header.pose_time", pt, -1e9, 1e9),
            _finite("frame header.predicted_time", tt, -1e9, 1e9),
            _finite("frame header.sent", sent, -1e9, 1e9),  # times, as pose_time's
            _finite("frame header.target_bps", bps, 0.0, 1e12),
            _finite("frame header.render_ms", rms, 0.0, 1e9),
            _finite("frame header.encode_ms", ems, 0.0, 1e9),
            int(size),
            int(span),
        )


# -- certificate pinning -------------------------------------------------------------------------


def printable(text: str, limit: int = 200) -> str:
    """A peer's text (a close's reason phrase) fit for one line of a terminal: control
    characters (a line break, an escape sequence) as Python writes them in a string literal,
    and at most ``limit`` characters. Printed raw, a server's reason could add lines that read
    as the command's own, or drive the terminal."""
    out = "".join(c if c.isprintable() else repr(c)[1:-1] for c in text[:limit])
    return out + ("..." if len(text) > limit else "")


def fingerprint_hex(der: bytes) -> str:
    """The SHA-256 of a DER certificate as colon-separated upper-case hex (how it is printed)."""
    import hashlib

    return ":".join(f"{b:02X}" for b in hashlib.sha256(der).digest())


def normalise_fingerprint(text: str) -> str:
    """A fingerprint as given by a user (colons and case ignored) as 64 lower-case hex digits.

    Raises:
        ProtocolError: when it is not 32 bytes of hex.
    """
    h = text.replace(":", "").strip().lower()
    if len(h) != 64 or any(c not in "0123456789abcdef" for c in h):
        raise ProtocolError(
            f"fingerprint: expected the SHA-256 of the certificate as 64 hex digits (colons "
            f"allowed), got {text!r}"
        )
    return h
