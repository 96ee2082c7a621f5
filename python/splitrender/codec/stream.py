"""The splitrender stream: a versioned packet per server frame and a container file of packets.

Everything here treats its input as untrusted: every count and size read from the wire is checked
against a fixed limit *and* against the bytes that remain before anything is allocated, both CRCs
are verified, and every failure is a :class:`~splitrender.errors.StreamError` whose message names
the frame and, where there is one, the buffer (``"frame 12, main.depth: ..."``). The codecs that
fill and read the payloads live in :mod:`splitrender.codec.coder`. The format is also described in
``docs/stream-format.md``.

Packet (version 4), all integers little-endian::

    offset  size  field
    0       4     magic b"SRPK"
    4       2     version (u16) = 4
    6       2     flags (u16): bit 0 key frame (every HEVC picture starts with an IDR and its
                  parameter sets, so decoding may start here), bit 1 uncompressed; others 0
    8       8     frame index (u64)
    16      8     time in seconds (f64, finite)
    24      4     M: length of the compressed header block (u32, 1..MAX_HEADER_ZSTD)
    28      4     CRC32 of the whole packet but these four bytes (bytes 0..28, then 32..end)
    32      M     the header block as one zstd frame that declares its content size
                  (at most MAX_HEADER bytes), laid out as:
                    u8 C cameras (1..MAX_CAMERAS; camera 0 is the main camera, camera i >= 1
                    auxiliary camera i-1), u8 reserved = 0, u16 B entries (0..MAX_BUFFERS);
                    C x camera record (264 bytes): u32 width, u32 height (1..MAX_SIDE),
                    f64[16] view, f64[16] proj (row-major, column-vector convention, finite);
                    B x entry (8 + 8*P bytes): u8 camera, u8 kind (BufferKind), u8 codec
                    (Codec), u8 P (the number of (scale, offset) pairs: the channels of a
                    quantised TILE buffer, else 0), u32 payload length,
                    P x (f32 scale, f32 offset): per channel, value = code * scale + offset
                    (finite); every buffer has its camera's size
    32+M    ...   payloads, back to back, in table order; the packet ends exactly after the
                  last payload

Version 3 (issue 13): the lossy buffers of every camera are tiles (codec ``TILE``, no payload)
of at most three HEVC pictures per packet, the ``PICTURE_*`` entries (codec ``HEVC``, listed
under camera 0): colour, geometry (depth and motion) and shadow colours. Where each tile lies is
a function of the camera sizes alone (``coder._layout``). Version 2 sent one HEVC stream per
buffer and camera (24 a frame), which took three times as long to decode; version-2 packets and
files are refused with a message that says to re-encode. Version 1 spent ~1.7 kB per frame on a
plain header; since version 2 the header block is zstd-compressed, the scales are the float32
values they are and one CRC covers the whole packet: about 0.6 kB per frame for three cameras
(docs/stream-format.md).

Version 4 keeps version 3's bytes and changes what the shadow picture holds: the shadow colours
at half size per axis (as motion), and the geometry and shadow pictures coded without HEVC's
in-loop filters; together about a quarter less decoding per server frame. Version-3 packets
would decode to wrong shadow colours, so they are refused like version 2 (``coder`` and
docs/stream-format.md, "Why version 4").

Container file (version 4; it holds version-4 packets)::

    b"SRSTREAM", u16 version = 4, u16 reserved, u32 reserved, f64 server fps   (24 bytes)
    records: u32 packet length, packet bytes                                     (repeated)
    index:   b"SRIX", u32 N, N x (u64 frame index, u64 record offset, u8 key, 7 x pad),
             u32 CRC32 of the N entries
    trailer: u64 index offset, b"SRSTREND"                                       (16 bytes)

The index lets a reader start at any key frame without scanning; a file without a valid trailer
(a writer that did not finish, a truncated copy) is still read sequentially, and a record that
runs past the end of the file raises :class:`StreamError`. A file cut inside its index ends its
records where the index begins. The index lists every record in file order, each where the one
before it ends, with its packet's frame and key flag; any other index is refused.
"""

from __future__ import annotations

import enum
import errno
import math
import numbers
import os
import struct
import zlib
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO

import numpy as np
import numpy.typing as npt
import zstandard

from splitrender.errors import InvalidInputError, StreamError
from splitrender.files import AtomicWriter, open_regular, open_temporary
from splitrender.types import (  # argument checks
    ITERABLE,
    MAX_INDEX,
    MAX_RATE,
    PATH,
    buffers,
    check_buffer,
    check_float,
    check_int,
    checked,
    floats,
    ints,
    optional,
)


__all__ = [
    "MAX_BUFFERS",
    "MAX_CAMERAS",
    "MAX_HEADER",
    "MAX_PAYLOAD",
    "MAX_PIXELS",
    "MAX_SIDE",
    "PACKET_VERSION",
    "STREAM_VERSION",
    "BufferEntry",
    "BufferKind",
    "CameraRecord",
    "Codec",
    "IndexEntry",
    "Packet",
    "StreamFile",
    "StreamStats",
    "StreamWriter",
    "buffer_name",
    "camera_name",
    "pack_packet",
    "read_stream",
    "stream_stats",
    "unpack_packet",
    "without_file_name",
    "write_stream",
]

PACKET_VERSION = 4
STREAM_VERSION = 4

#: Largest image side (as ``splitrender.types.MAX_SIDE``).
MAX_SIDE = 16384
#: Largest number of pixels of one camera (8192 x 4096); bounds every decoded allocation.
MAX_PIXELS = 1 << 25
MAX_CAMERAS = 16
MAX_BUFFERS = 512
#: Largest payload of one buffer (a raw float32 x 3 image of MAX_PIXELS pixels).
MAX_PAYLOAD = MAX_PIXELS * 12
#: Largest packet a container record may hold.
MAX_PACKET = 1 << 31

_MAGIC = b"SRPK"
_FIXED = struct.Struct("<4sHHQdII")  # 32 bytes
_BLOCK_HEAD = struct.Struct("<BBH")  # 4 bytes
_CAMERA = struct.Struct("<II16d16d")  # 264 bytes
_ENTRY = struct.Struct("<BBBBI")  # 8 bytes, then P x _PARAM
_PARAM = struct.Struct("<ff")
#: Largest header block (decompressed): every camera and buffer at the limits, 3 pairs each.
MAX_HEADER = _BLOCK_HEAD.size + MAX_CAMERAS * _CAMERA.size + MAX_BUFFERS * (
    _ENTRY.size + 3 * _PARAM.size
)
#: Largest compressed header block accepted (zstd never needs more than this for MAX_HEADER).
MAX_HEADER_ZSTD = MAX_HEADER + 1024
_HEADER_LEVEL = 19
FLAG_KEY = 1
FLAG_UNCOMPRESSED = 2
_KNOWN_FLAGS = FLAG_KEY | FLAG_UNCOMPRESSED

_FILE_MAGIC = b"SRSTREAM"
_FILE_HEADER = struct.Struct("<8sHHId")  # 24 bytes
_RECORD = struct.Struct("<I")
_INDEX_MAGIC = b"SRIX"
_INDEX_HEAD = struct.Struct("<4sI")
_INDEX_ENTRY = struct.Struct("<QQB7x")  # 24 bytes
_TRAILER = struct.Struct("<Q8s")
_TRAILER_MAGIC = b"SRSTREND"


class BufferKind(enum.IntEnum):
    """What a buffer holds. The ``*_STATIC`` and ``*_INVALID`` kinds are lossless one-bit masks
    that travel beside a lossy depth or motion buffer: pixels whose motion is exactly zero, and
    pixels whose value is NaN or infinite (DESIGN.md: invalid)."""

    COLOR = 0
    DEPTH = 1
    MOTION_FWD = 2
    MOTION_BWD = 3
    SHADOW_FWD_BITS = 4
    SHADOW_FWD_MIN = 5
    SHADOW_FWD_MAX = 6
    SHADOW_BWD_BITS = 7
    SHADOW_BWD_MIN = 8
    SHADOW_BWD_MAX = 9
    DEPTH_INVALID = 10
    MOTION_FWD_STATIC = 11
    MOTION_BWD_STATIC = 12
    MOTION_FWD_INVALID = 13
    MOTION_BWD_INVALID = 14
    # Version 3: one HEVC picture per group holds the tiles of every camera (camera 0's entry).
    PICTURE_COLOR = 15
    PICTURE_GEOMETRY = 16
    PICTURE_SHADOW = 17


#: Channels of each kind (masks and bitfields count as one channel).
KIND_CHANNELS: dict[BufferKind, int] = {
    BufferKind.COLOR: 3,
    BufferKind.DEPTH: 1,
    BufferKind.MOTION_FWD: 3,
    BufferKind.MOTION_BWD: 3,
    BufferKind.SHADOW_FWD_BITS: 1,
    BufferKind.SHADOW_FWD_MIN: 3,
    BufferKind.SHADOW_FWD_MAX: 3,
    BufferKind.SHADOW_BWD_BITS: 1,
    BufferKind.SHADOW_BWD_MIN: 3,
    BufferKind.SHADOW_BWD_MAX: 3,
    BufferKind.DEPTH_INVALID: 1,
    BufferKind.MOTION_FWD_STATIC: 1,
    BufferKind.MOTION_BWD_STATIC: 1,
    BufferKind.MOTION_FWD_INVALID: 1,
    BufferKind.MOTION_BWD_INVALID: 1,
    BufferKind.PICTURE_COLOR: 1,
    BufferKind.PICTURE_GEOMETRY: 1,
    BufferKind.PICTURE_SHADOW: 1,
}

_KIND_NAMES: dict[BufferKind, str] = {
    BufferKind.COLOR: "color",
    BufferKind.DEPTH: "depth",
    BufferKind.MOTION_FWD: "motion_fwd",
    BufferKind.MOTION_BWD: "motion_bwd",
    BufferKind.SHADOW_FWD_BITS: "shadow_fwd.bits",
    BufferKind.SHADOW_FWD_MIN: "shadow_fwd.s_min",
    BufferKind.SHADOW_FWD_MAX: "shadow_fwd.s_max",
    BufferKind.SHADOW_BWD_BITS: "shadow_bwd.bits",
    BufferKind.SHADOW_BWD_MIN: "shadow_bwd.s_min",
    BufferKind.SHADOW_BWD_MAX: "shadow_bwd.s_max",
    BufferKind.DEPTH_INVALID: "depth.invalid",
    BufferKind.MOTION_FWD_STATIC: "motion_fwd.static",
    BufferKind.MOTION_BWD_STATIC: "motion_bwd.static",
    BufferKind.MOTION_FWD_INVALID: "motion_fwd.invalid",
    BufferKind.MOTION_BWD_INVALID: "motion_bwd.invalid",
    BufferKind.PICTURE_COLOR: "color",
    BufferKind.PICTURE_GEOMETRY: "geometry",
    BufferKind.PICTURE_SHADOW: "shadow",
}

#: The HEVC pictures (since version 3) and the buffer kinds whose tiles each one holds.
PICTURE_KINDS: dict[BufferKind, tuple[BufferKind, ...]] = {
    BufferKind.PICTURE_COLOR: (BufferKind.COLOR,),
    BufferKind.PICTURE_GEOMETRY: (
        BufferKind.DEPTH,
        BufferKind.MOTION_FWD,
        BufferKind.MOTION_BWD,
    ),
    BufferKind.PICTURE_SHADOW: (
        BufferKind.SHADOW_FWD_MIN,
        BufferKind.SHADOW_FWD_MAX,
        BufferKind.SHADOW_BWD_MIN,
        BufferKind.SHADOW_BWD_MAX,
    ),
}
#: The picture that holds the tile of each lossy kind.
TILE_PICTURE: dict[BufferKind, BufferKind] = {
    k: pic for pic, kinds in PICTURE_KINDS.items() for k in kinds
}


_QUANTISED = (BufferKind.DEPTH, BufferKind.MOTION_FWD, BufferKind.MOTION_BWD)


class Codec(enum.IntEnum):
    """How a payload is coded.

    - ``RAW``: the array's bytes, C order, little-endian (uint8 colour, float32 depth/motion,
      uint32 bitfields, uint8 masks one byte per pixel).
    - ``HEVC``: one HEVC access unit of a picture's stream (only the ``PICTURE_*`` kinds).
    - ``TILE``: no payload; the buffer is a tile of its picture (:data:`TILE_PICTURE`) in the
      same packet (8-bit colour; 12-bit depth/motion codes, ``value = code * scale + offset``
      per channel).
    - ``ZSTD``: a zstd frame (shadow bitfields of the non-zero pixels, or a bit-packed mask).
    - ``ZERO``: no payload; every value is zero (a mask: no pixel set).
    """

    RAW = 0
    HEVC = 1
    ZSTD = 2
    ZERO = 3
    TILE = 4


def camera_name(camera: int) -> str:
    """``"main"`` for camera 0, ``"aux{i}"`` for camera ``i + 1``."""
    return "main" if camera == 0 else f"aux{camera - 1}"


def buffer_name(camera: int, kind: int) -> str:
    """``"main.depth"``, ``"aux1.shadow_fwd.bits"``, ..., ``"picture.geometry"`` (a picture
    belongs to no one camera)."""
    try:
        bk = BufferKind(kind)
    except ValueError:
        return f"{camera_name(camera)}.kind{kind}"
    if bk in PICTURE_KINDS:
        return f"picture.{_KIND_NAMES[bk]}"
    return f"{camera_name(camera)}.{_KIND_NAMES[bk]}"


@dataclass(frozen=True, slots=True, eq=False)
class CameraRecord:
    """A camera of a packet: its matrices (``float64[4, 4]``) and image size."""

    view: npt.NDArray[np.float64]
    proj: npt.NDArray[np.float64]
    width: int
    height: int


@dataclass(frozen=True, slots=True, eq=False)
class BufferEntry:
    """One buffer of a packet: its table entry and payload."""

    camera: int
    kind: BufferKind
    codec: Codec
    channels: int
    width: int
    height: int
    payload: bytes | memoryview
    scale: tuple[float, float, float] = (0.0, 0.0, 0.0)
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)

    @property
    def name(self) -> str:
        return buffer_name(self.camera, self.kind)


@dataclass(frozen=True, slots=True, eq=False)
class Packet:
    """One server frame on the wire."""

    index: int
    time: float
    key: bool
    uncompressed: bool
    cameras: tuple[CameraRecord, ...]
    buffers: tuple[BufferEntry, ...]
    version: int = PACKET_VERSION


def _where(index: int | None, name: str | None = None) -> str:
    frame = "frame ?" if index is None else f"frame {index}"
    return frame if name is None else f"{frame}, {name}"


def _n_params(b: BufferEntry) -> int:
    """The (scale, offset) pairs an entry carries: its channels for quantised tiles."""
    return b.channels if b.codec == Codec.TILE and b.kind in _QUANTISED else 0


def _integral(v: object) -> bool:
    return isinstance(v, numbers.Integral) and not isinstance(v, bool)


def _f32(v: float) -> bool:
    return math.isfinite(v) and float(np.float32(v)) == v


def pack_packet(packet: Packet) -> bytes:
    """The bytes of ``packet`` (format in the module docstring).

    # Errors
    :class:`StreamError` when a field does not fit the format's limits (whatever
    :func:`unpack_packet` would refuse): a frame index beyond ``0..2^63 - 1``, a time that is not
    finite, camera and buffer counts, a camera size beyond the limits or matrices that are not
    finite 4x4 arrays, a payload over :data:`MAX_PAYLOAD`, a buffer whose size is not its
    camera's, or a scale or offset that is not a finite float32 value."""
    where = _where(packet.index)
    # What unpack_packet refuses is refused here too, as the StreamError a writer expects (an
    # index of 2^63 or a NaN time was packed and then refused by every reader; an index of -1
    # or a 3x3 matrix raised struct.error).
    if not (_integral(packet.index) and 0 <= packet.index <= MAX_INDEX):
        raise StreamError(f"{where}: frame index {packet.index!r}, expected an int in "
                          f"0..{MAX_INDEX} (2^63 - 1)")
    if not math.isfinite(packet.time):
        raise StreamError(f"{where}: time is not finite ({packet.time})")
    if not 1 <= len(packet.cameras) <= MAX_CAMERAS:
        raise StreamError(
            f"{where}: {len(packet.cameras)} cameras (1..{MAX_CAMERAS} allowed)"
        )
    if len(packet.buffers) > MAX_BUFFERS:
        raise StreamError(
            f"{where}: {len(packet.buffers)} buffers (at most {MAX_BUFFERS})"
        )
    flags = (FLAG_KEY if packet.key else 0) | (
        FLAG_UNCOMPRESSED if packet.uncompressed else 0
    )
    block = bytearray(_BLOCK_HEAD.pack(len(packet.cameras), 0, len(packet.buffers)))
    for i, c in enumerate(packet.cameras):
        cwhere = f"{where}, {camera_name(i)}"
        w, h = c.width, c.height
        if not (
            _integral(w) and _integral(h)
            and 1 <= w <= MAX_SIDE and 1 <= h <= MAX_SIDE and w * h <= MAX_PIXELS
        ):
            raise StreamError(
                f"{cwhere}: camera size {w}x{h} beyond the limits (side 1..{MAX_SIDE}, "
                f"pixels <= {MAX_PIXELS})"
            )
        mats = [np.asarray(m, np.float64) for m in (c.view, c.proj)]
        if any(m.shape != (4, 4) for m in mats) or not all(np.isfinite(m).all() for m in mats):
            raise StreamError(f"{cwhere}: camera matrices must be finite 4x4 arrays")
        block += _CAMERA.pack(w, h, *mats[0].ravel(), *mats[1].ravel())
    for b in packet.buffers:
        bwhere = _where(packet.index, b.name)
        if len(b.payload) > MAX_PAYLOAD:
            raise StreamError(
                f"{bwhere}: payload of {len(b.payload)} bytes exceeds {MAX_PAYLOAD}"
            )
        if not 0 <= b.camera < len(packet.cameras):
            raise StreamError(f"{bwhere}: camera {b.camera} of {len(packet.cameras)}")
        cam = packet.cameras[b.camera]
        if (b.width, b.height) != (cam.width, cam.height):
            raise StreamError(
                f"{bwhere}: size {b.width}x{b.height} differs from the camera's "
                f"{cam.width}x{cam.height}"
            )
        n_par = _n_params(b)
        block += _ENTRY.pack(b.camera, int(b.kind), int(b.codec), n_par, len(b.payload))
        for i in range(n_par):
            if not (_f32(b.scale[i]) and _f32(b.offset[i])):
                raise StreamError(
                    f"{bwhere}: scale/offset ({b.scale[i]}, {b.offset[i]}) are not finite "
                    "float32 values"
                )
            block += _PARAM.pack(b.scale[i], b.offset[i])
    packed = _zstd_header().compress(bytes(block))
    head = _FIXED.pack(
        _MAGIC, PACKET_VERSION, flags, packet.index, packet.time, len(packed), 0
    )
    payloads = [bytes(b.payload) for b in packet.buffers]
    crc = zlib.crc32(head[:28])
    for part in (packed, *payloads):
        crc = zlib.crc32(part, crc)
    return b"".join([head[:28], struct.pack("<I", crc), packed, *payloads])


def _zstd_header() -> zstandard.ZstdCompressor:
    return zstandard.ZstdCompressor(
        level=_HEADER_LEVEL, write_content_size=True, write_checksum=False
    )


def peek_header(data: bytes | memoryview) -> tuple[int, bool]:
    """``(frame index, key)`` of a packet from its fixed header alone (no CRC check).

    # Errors
    :class:`StreamError` when the bytes do not start with a version-4 packet header (an older
    version: a message that says to re-encode), or its index is beyond
    :data:`~splitrender.types.MAX_INDEX`."""
    if len(data) < _FIXED.size:
        raise StreamError(
            f"frame ?: packet of {len(data)} bytes is shorter than the {_FIXED.size}-byte header"
        )
    magic, version, flags, index, *_ = _FIXED.unpack_from(data, 0)
    if magic != _MAGIC:
        raise StreamError(f"frame ?: not a splitrender packet (magic {bytes(magic)!r})")
    if version != PACKET_VERSION:
        raise StreamError(f"frame {index}: {_version_message('packet', version)}")
    if index > MAX_INDEX:
        raise StreamError(f"frame {index}: the index is beyond {MAX_INDEX} (2^63 - 1)")
    return int(index), bool(flags & FLAG_KEY)


def _version_message(what: str, version: int) -> str:
    """Why a packet or file of another version is refused, and what to do about it."""
    if 1 <= version < PACKET_VERSION:
        return (
            f"{what} format version {version} is no longer supported (this reader knows "
            f"version {PACKET_VERSION}); re-encode the recording with `splitrender encode`"
        )
    return f"unsupported {what} version {version} (this reader knows {PACKET_VERSION})"


def _header_block(where: str, packed: memoryview) -> bytes:
    """The decompressed header block, its declared size checked against :data:`MAX_HEADER`
    before anything is allocated."""
    try:
        size = zstandard.frame_content_size(packed)
    except zstandard.ZstdError:
        raise StreamError(f"{where}: the header block is not a zstd frame") from None
    if size < 0:
        raise StreamError(f"{where}: the header block does not declare its size")
    if size > MAX_HEADER:
        raise StreamError(
            f"{where}: header block of {size} bytes (at most {MAX_HEADER})"
        )
    try:
        block = zstandard.ZstdDecompressor().decompress(packed, max_output_size=size)
    except zstandard.ZstdError as e:
        raise StreamError(f"{where}: the header block does not decompress: {e}") from None
    if len(block) != size:
        raise StreamError(
            f"{where}: the header block holds {len(block)} bytes, declared {size}"
        )
    return block


def unpack_packet(data: bytes | memoryview) -> Packet:
    """Parses and verifies one packet; payloads are views into ``data``.

    # Errors
    :class:`StreamError` naming the frame (and buffer) for: a short or over-long packet, wrong
    magic or version, unknown flags, a CRC mismatch, a header block that does not decompress or
    declares more than :data:`MAX_HEADER` bytes, counts or sizes beyond the limits or beyond the
    bytes that remain, non-finite matrices, scales or time."""
    mv = memoryview(data).cast("B")
    index, _ = peek_header(mv)
    _, _, flags, _, time, m, crc = _FIXED.unpack_from(mv, 0)
    where = _where(index)
    if flags & ~_KNOWN_FLAGS:
        raise StreamError(f"{where}: unknown header flags 0x{flags:04x}")
    if not 1 <= m <= min(MAX_HEADER_ZSTD, len(mv) - _FIXED.size):
        raise StreamError(
            f"{where}: header block of {m} bytes, but {len(mv) - _FIXED.size} bytes remain "
            f"(limit {MAX_HEADER_ZSTD})"
        )
    want = zlib.crc32(mv[_FIXED.size :], zlib.crc32(mv[:28]))
    if want != crc:
        raise StreamError(
            f"{where}: packet CRC mismatch (stored {crc:08x}, computed {want:08x})"
        )
    if not math.isfinite(time):
        raise StreamError(f"{where}: time is not finite ({time})")
    block = _header_block(where, mv[_FIXED.size : _FIXED.size + m])
    if len(block) < _BLOCK_HEAD.size:
        raise StreamError(f"{where}: header block of {len(block)} bytes is too short")
    n_cam, reserved, n_buf = _BLOCK_HEAD.unpack_from(block, 0)
    if reserved != 0:
        raise StreamError(f"{where}: reserved header byte is {reserved}, expected 0")
    if not 1 <= n_cam <= MAX_CAMERAS:
        raise StreamError(
            f"{where}: {n_cam} cameras in the header (1..{MAX_CAMERAS} allowed)"
        )
    if n_buf > MAX_BUFFERS:
        raise StreamError(
            f"{where}: {n_buf} buffers in the header (at most {MAX_BUFFERS})"
        )
    pos = _BLOCK_HEAD.size
    if pos + n_cam * _CAMERA.size > len(block):
        raise StreamError(
            f"{where}: header block of {len(block)} bytes is too short for {n_cam} cameras"
        )
    cameras = []
    for i in range(n_cam):
        vals = _CAMERA.unpack_from(block, pos)
        pos += _CAMERA.size
        w, h = vals[0], vals[1]
        if not (1 <= w <= MAX_SIDE and 1 <= h <= MAX_SIDE and w * h <= MAX_PIXELS):
            raise StreamError(
                f"{where}, {camera_name(i)}: camera size {w}x{h} beyond the limits "
                f"(side <= {MAX_SIDE}, pixels <= {MAX_PIXELS})"
            )
        mat = np.array(vals[2:], dtype=np.float64)
        if not np.isfinite(mat).all():
            raise StreamError(
                f"{where}, {camera_name(i)}: camera matrices are not finite"
            )
        cameras.append(CameraRecord(mat[:16].reshape(4, 4), mat[16:].reshape(4, 4), w, h))
    buffers = []
    at = _FIXED.size + m
    for i in range(n_buf):
        if pos + _ENTRY.size > len(block):
            raise StreamError(
                f"{where}: header block of {len(block)} bytes ends inside buffer entry {i} "
                f"of {n_buf}"
            )
        cam, kind, codec, n_par, length = _ENTRY.unpack_from(block, pos)
        pos += _ENTRY.size
        bwhere = _where(index, buffer_name(cam, kind))
        if cam >= n_cam:
            raise StreamError(f"{bwhere}: camera {cam} of {n_cam}")
        try:
            k = BufferKind(kind)
            c = Codec(codec)
        except ValueError:
            raise StreamError(
                f"{bwhere}: unknown kind {kind} or codec {codec}"
            ) from None
        ch = KIND_CHANNELS[k]
        if (c == Codec.HEVC) != (k in PICTURE_KINDS) or (
            c == Codec.TILE and k not in TILE_PICTURE
        ):
            raise StreamError(
                f"{bwhere}: codec {c.name} is not a codec of this buffer kind (HEVC: only the "
                "pictures; TILE: only colour, depth, motion and shadow colours)"
            )
        if k in PICTURE_KINDS and cam != 0:
            raise StreamError(f"{bwhere}: a picture must be listed under camera 0, not {cam}")
        want_par = ch if c == Codec.TILE and k in _QUANTISED else 0
        if n_par != want_par:
            raise StreamError(
                f"{bwhere}: {n_par} scale/offset pairs (expected {want_par})"
            )
        if pos + n_par * _PARAM.size > len(block):
            raise StreamError(f"{bwhere}: the header block ends inside its scale/offset pairs")
        pairs = [_PARAM.unpack_from(block, pos + j * _PARAM.size) for j in range(n_par)]
        pos += n_par * _PARAM.size
        if not all(math.isfinite(x) for pr in pairs for x in pr):
            raise StreamError(f"{bwhere}: scale/offset not finite")
        if length > MAX_PAYLOAD or length > len(mv) - at:
            raise StreamError(
                f"{bwhere}: payload of {length} bytes but {len(mv) - at} bytes remain "
                f"(limit {MAX_PAYLOAD})"
            )
        if c in (Codec.ZERO, Codec.TILE) and length != 0:
            raise StreamError(f"{bwhere}: a {c.name} buffer with a {length}-byte payload")
        scale = tuple(float(pr[0]) for pr in pairs) + (0.0,) * (3 - n_par)
        offset = tuple(float(pr[1]) for pr in pairs) + (0.0,) * (3 - n_par)
        w, h = cameras[cam].width, cameras[cam].height
        buffers.append(
            BufferEntry(cam, k, c, ch, w, h, mv[at : at + length], scale, offset)
        )
        at += length
    if pos != len(block):
        raise StreamError(
            f"{where}: {len(block) - pos} trailing bytes in the header block"
        )
    if at != len(mv):
        raise StreamError(
            f"{where}: {len(mv) - at} trailing bytes after the last payload"
        )
    return Packet(
        index=index,
        time=time,
        key=bool(flags & FLAG_KEY),
        uncompressed=bool(flags & FLAG_UNCOMPRESSED),
        cameras=tuple(cameras),
        buffers=tuple(buffers),
    )


# --------------------------------------------------------------------------------------------
# Container


@dataclass(frozen=True, slots=True)
class IndexEntry:
    """Where a frame's record lies in a container file."""

    frame: int
    offset: int
    key: bool


class StreamWriter(AtomicWriter):
    """Writes packets to a container file, then the key-frame index on :meth:`close`.

    Use as a context manager. The packets go to a temporary file beside ``path``
    (:func:`~splitrender.files.temporary_beside`); only a clean close writes the index, flushes
    and syncs the file and renames it over ``path``. An exception inside the ``with`` (or from a
    write, a full disk included) calls :meth:`abort` instead: the temporary file is removed and
    ``path`` is as it was, so a failed write never leaves a stream that reads as complete with
    fewer frames, nor destroys the previous one."""

    @checked(path=PATH, fps=floats(positive=True, hi=MAX_RATE))
    def __init__(self, path: str | os.PathLike[str], fps: float = 10.0) -> None:
        # The rate StreamFile reads back: 1e6 was written, and the file then refused by every
        # reader ("server rate 1000000.0 frames per second").
        self.path = Path(path)
        if self.path.is_dir():  # found now, not by the rename after all the frames
            raise IsADirectoryError(
                errno.EISDIR, "expected a file name for the stream, got a folder", str(path)
            )
        if self.path.exists() and not self.path.is_file():
            # The rename would replace the node itself: run as root, `encode --out /dev/zero`
            # replaced the device with a regular file (found by the fuzz suite, issue 15).
            raise InvalidInputError(
                f"{path}: the output is not a regular file (a device, FIFO or socket); "
                "expected a regular file or a new name"
            )
        self._tmp, self._file = open_temporary(self.path)  # closed by close() or abort()
        self._index: list[IndexEntry] = []
        self.fps = fps
        try:
            self._file.write(_FILE_HEADER.pack(_FILE_MAGIC, STREAM_VERSION, 0, 0, fps))
        except BaseException:
            self.abort()
            raise

    def write(self, packet: bytes) -> None:
        """Appends one packet (as :func:`pack_packet` or ``StreamEncoder.encode`` made it)."""
        if self._file.closed:
            raise ValueError(f"{self.path}: the stream writer is closed")
        packet = check_buffer("packet", packet)
        frame, key = peek_header(packet)
        if len(packet) > MAX_PACKET:
            raise StreamError(
                f"frame {frame}: packet of {len(packet)} bytes is too large"
            )
        try:
            self._index.append(IndexEntry(frame, self._file.tell(), key))
            self._file.write(_RECORD.pack(len(packet)))
            self._file.write(packet)
        except OSError as e:
            raise self._named(e) from None

    def _named(self, e: OSError) -> OSError:
        """``e`` naming :attr:`path` where it names no file: a write into the temporary file
        failed with "[Errno 28] No space left on device", which named no file at all."""
        if e.filename is not None or e.errno is None:
            return e
        return type(e)(e.errno, e.strerror, str(self.path))

    def close(self) -> None:
        """Writes the index and trailer and replaces ``path`` with the finished file (a second
        call does nothing). On a failure the temporary file is removed and ``path`` is kept."""
        if self._file.closed:
            return
        try:
            offset = self._file.tell()
            entries = b"".join(
                _INDEX_ENTRY.pack(e.frame, e.offset, e.key) for e in self._index
            )
            self._file.write(_INDEX_HEAD.pack(_INDEX_MAGIC, len(self._index)))
            self._file.write(entries)
            self._file.write(struct.pack("<I", zlib.crc32(entries)))
            self._file.write(_TRAILER.pack(offset, _TRAILER_MAGIC))
            self._file.flush()
            # One file, written once: the sync is cheap, and without it a crash soon after the
            # rename could leave an empty file where the previous good one was.
            os.fsync(self._file.fileno())
            self._file.close()
            os.replace(self._tmp, self.path)
        except OSError as e:
            self.abort()
            raise self._named(e) from None
        except BaseException:
            self.abort()
            raise

    def abort(self) -> None:
        """Drops what was written: closes and removes the temporary file; ``path`` is left as
        it was. Does nothing after :meth:`close` has replaced ``path``."""
        try:
            if not self._file.closed:
                # Closing flushes the buffer, which fails again on a full disk; the bytes are
                # dropped anyway, and that error must neither keep the file nor replace the
                # one being handled.
                self._file.close()
        except OSError:
            pass
        finally:
            self._tmp.unlink(missing_ok=True)


@checked(path=PATH, packets=ITERABLE, fps=floats(positive=True, hi=MAX_RATE))
def write_stream(
    path: str | os.PathLike[str], packets: Iterable[bytes], fps: float = 10.0
) -> None:
    """Writes ``packets`` to a container file at ``path`` with its key-frame index, atomically
    (:class:`StreamWriter`): if ``packets`` or a write raises, ``path`` is as it was."""
    with StreamWriter(path, fps) as w:
        for p in packets:
            w.write(p)


class StreamFile:
    """A container file opened for reading.

    ``index`` lists every record (from the file's index, or from a sequential scan when the file
    has none); :meth:`packets` yields packet bytes from the start or from a key frame.

    # Errors
    :class:`StreamError` for a file that is not a stream, has an unknown version, or whose index
    or records are truncated or inconsistent."""

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = os.fspath(path)
        self._name = os.path.basename(self.path)
        # Only a regular file: open() of a FIFO blocked forever (issue 15).
        with self._open() as f:
            self._size = os.fstat(f.fileno()).st_size
            head = f.read(_FILE_HEADER.size)
            if len(head) < _FILE_HEADER.size:
                raise StreamError(
                    f"{self._name}: file of {self._size} bytes has no header"
                )
            magic, version, reserved16, reserved32, fps = _FILE_HEADER.unpack(head)
            if magic != _FILE_MAGIC:
                raise StreamError(
                    f"{self._name}: not a splitrender stream ({bytes(magic)!r})"
                )
            if version != STREAM_VERSION:
                raise StreamError(f"{self._name}: {_version_message('stream', version)}")
            # The file header has no CRC: what a writer leaves zero is checked to be, and the
            # rate to be one the package takes (1e300 passed here and failed later, as the
            # caller's argument error of stream_stats).
            if reserved16 or reserved32:
                raise StreamError(f"{self._name}: reserved header fields are {reserved16} and "
                                  f"{reserved32}, expected 0 (a damaged file?)")
            if not (math.isfinite(fps) and 0 < fps <= MAX_RATE):
                raise StreamError(f"{self._name}: server rate {fps!r} frames per second, "
                                  f"expected a finite value in (0, {MAX_RATE:g}]")
            self.fps = float(fps)
            self._end = self._size
            self._end, self.index = self._read_index(f)

    def _open(self) -> BinaryIO:
        """The file, opened by :func:`~splitrender.files.open_regular`; a path that cannot be
        opened (missing, a dangling link or a loop of links, no permission) is a
        :class:`StreamError` too, as every other reader's (found by the fuzz suite)."""
        try:
            return open_regular(self.path, "stream file", StreamError)
        except OSError as e:
            raise StreamError(
                f"{self.path}: cannot open the stream file: {e.strerror or e}"
            ) from None

    def _read_index(self, f: BinaryIO) -> tuple[int, list[IndexEntry]]:
        """``(end of records, index)``; falls back to a scan of the record lengths."""
        if self._size >= _FILE_HEADER.size + _INDEX_HEAD.size + 4 + _TRAILER.size:
            f.seek(self._size - _TRAILER.size)
            offset, magic = _TRAILER.unpack(f.read(_TRAILER.size))
            if magic == _TRAILER_MAGIC:
                return offset, self._parse_index(f, offset)
        return self._scan(f)

    def _parse_index(self, f: BinaryIO, offset: int) -> list[IndexEntry]:
        room = self._size - _TRAILER.size - offset
        if not _FILE_HEADER.size <= offset or room < _INDEX_HEAD.size + 4:
            raise StreamError(f"{self._name}: index offset {offset} outside the file")
        f.seek(offset)
        magic, n = _INDEX_HEAD.unpack(f.read(_INDEX_HEAD.size))
        if (
            magic != _INDEX_MAGIC
            or n * _INDEX_ENTRY.size + _INDEX_HEAD.size + 4 != room
        ):
            raise StreamError(
                f"{self._name}: corrupt index ({n} entries in {room} bytes)"
            )
        raw = f.read(n * _INDEX_ENTRY.size)
        (crc,) = struct.unpack("<I", f.read(4))
        if zlib.crc32(raw) != crc:
            raise StreamError(f"{self._name}: index CRC mismatch")
        out: list[IndexEntry] = []
        for i in range(n):
            frame, off, key = _INDEX_ENTRY.unpack_from(raw, i * _INDEX_ENTRY.size)
            if not _FILE_HEADER.size <= off <= offset - _RECORD.size:
                raise StreamError(
                    f"{self._name}: index entry for frame {frame} points outside"
                )
            # The writer lists every record, in file order, from the first: an index that
            # repeats, reorders or skips records (its CRC made consistent) read back as
            # another stream, frame 0 four times or one frame of four (records are checked to
            # follow each other as they are read).
            first = not out and off != _FILE_HEADER.size
            if first or (out and off <= out[-1].offset):
                raise StreamError(
                    f"{self._name}: index entry {i} (frame {frame}) points at byte {off}, "
                    "expected the records in file order from byte "
                    f"{_FILE_HEADER.size} (a damaged index?)"
                )
            out.append(IndexEntry(frame, off, bool(key)))
        if not out and offset != _FILE_HEADER.size:
            raise StreamError(
                f"{self._name}: the index lists no records, but {offset - _FILE_HEADER.size} "
                "bytes of records precede it (a damaged index?)"
            )
        return out

    def _scan(self, f: BinaryIO) -> tuple[int, list[IndexEntry]]:
        """``(end of the last whole record, index)`` from the record lengths."""
        out: list[IndexEntry] = []
        pos = _FILE_HEADER.size
        while pos < self._size:
            index_size = _INDEX_HEAD.size + len(out) * _INDEX_ENTRY.size + 4 + _TRAILER.size
            # The records end where an index of as many entries begins: a file cut inside its
            # index (a writer stopped while closing it, a truncated copy) holds every record
            # whole. Read as a record length, the magic claimed 1.48 GB and the file was
            # refused. Only the bytes where such an index could begin are looked at.
            f.seek(pos)
            if self._size - pos < index_size and f.read(len(_INDEX_MAGIC)) == _INDEX_MAGIC:
                break
            f.seek(pos)
            packet, n = self._read_record(
                f, pos, out[-1].frame if out else None, peek=True
            )
            frame, key = self._peek(packet)
            out.append(IndexEntry(frame, pos, key))
            pos += _RECORD.size + n
        return pos, out

    def _peek(self, packet: bytes) -> tuple[int, bool]:
        """:func:`peek_header` of a record's packet, its errors naming this file (a record of
        zero bytes was "frame ?: packet of 0 bytes ...", which named no file)."""
        try:
            return peek_header(packet)
        except StreamError as e:
            raise StreamError(f"{self._name}: {e}") from None

    def _read_record(
        self, f: BinaryIO, pos: int, prev: int | None, *, peek: bool = False
    ) -> tuple[bytes, int]:
        """``(bytes, record length)``: the packet (only its fixed header with ``peek``)."""
        after = "the start" if prev is None else f"frame {prev}"
        head = f.read(_RECORD.size)
        if len(head) < _RECORD.size:
            raise StreamError(
                f"{self._name}: frame after {after}: record at byte {pos} is truncated"
            )
        (n,) = _RECORD.unpack(head)
        remain = self._end - pos - _RECORD.size
        if n > MAX_PACKET or n > remain:
            raise StreamError(
                f"{self._name}: frame after {after}: record at byte {pos} claims {n} bytes but "
                f"{remain} remain (truncated file?)"
            )
        want = min(n, _FIXED.size) if peek else n
        data = f.read(want)
        if len(data) < want:
            raise StreamError(f"{self._name}: frame after {after}: record is truncated")
        return data, n

    @property
    def key_frames(self) -> list[int]:
        """Frame indices at which decoding may start."""
        return [e.frame for e in self.index if e.key]

    def __len__(self) -> int:
        return len(self.index)

    def packets(self, start: int | None = None) -> Iterator[bytes]:
        """Packet bytes in file order, from the first record or from key frame ``start``.

        # Errors
        :class:`StreamError` when ``start`` is not a key frame of the file, or a record is
        truncated."""
        first = 0
        if start is not None:
            hits = [i for i, e in enumerate(self.index) if e.frame == start and e.key]
            if not hits:
                raise StreamError(
                    f"{self._name}: frame {start} is not a key frame (key frames: "
                    f"{self.key_frames[:20]})"
                )
            first = hits[0]
        with self._open() as f:
            prev = self.index[first - 1].frame if first > 0 else None
            entries = self.index[first:]
            for i, e in enumerate(entries):
                f.seek(e.offset)
                data, n = self._read_record(f, e.offset, prev)
                frame, key = self._peek(data)
                if frame != e.frame:
                    raise StreamError(
                        f"{self._name}: frame {e.frame}: the record holds frame {frame}"
                    )
                if key != e.key:
                    # packets(start=k) would start at a packet that cannot be decoded first.
                    raise StreamError(
                        f"{self._name}: frame {frame}: the index says it is "
                        f"{'' if e.key else 'not '}a key frame, the packet says otherwise"
                    )
                end = e.offset + _RECORD.size + n
                nxt = entries[i + 1].offset if i + 1 < len(entries) else self._end
                if nxt != end:
                    what = "the next record" if i + 1 < len(entries) else "the index"
                    raise StreamError(
                        f"{self._name}: frame {frame}: its record ends at byte {end}, "
                        f"{what} begins at byte {nxt} (a damaged index?)"
                    )
                prev = frame
                yield data


@checked(path=PATH, start=optional(ints(0, (1 << 31) - 1)))
def read_stream(
    path: str | os.PathLike[str], start: int | None = None
) -> Iterator[bytes]:
    """The packets of the container file at ``path``, from the start or from key frame
    ``start`` (see :class:`StreamFile`)."""
    yield from StreamFile(path).packets(start)


def without_file_name(message: str, path: str | os.PathLike[str]) -> str:
    """``message`` of a :class:`StreamError` about the file at ``path`` without the name
    :class:`StreamFile` gives the file (its base name, or its path where it cannot open it):
    for a caller that names the file its own way (an option and the path as given, a cache
    entry)."""
    full = os.fspath(path)
    for name in (full, os.path.basename(full)):
        if message.startswith(f"{name}: "):
            return message[len(name) + 2:]
    return message


# --------------------------------------------------------------------------------------------
# Byte accounting


@dataclass
class StreamStats:
    """Bytes per buffer over a run of packets, and the rates they make at ``fps``.

    Buffer keys are names such as ``"picture.color"`` or ``"aux0.shadow_fwd.bits"`` (tiles are not
    listed: their bits are in their picture's); the packet headers, camera records and tables are
    counted as ``"header"``."""

    fps: float
    frames: int = 0
    bytes_by_buffer: dict[str, int] = field(default_factory=dict)
    header_bytes: int = 0

    def __post_init__(self) -> None:
        self.fps = check_float("StreamStats.fps", self.fps, positive=True, hi=MAX_RATE)
        for name in ("frames", "header_bytes"):
            setattr(self, name, check_int(f"StreamStats.{name}", getattr(self, name), 0, 1 << 62))
        if not isinstance(self.bytes_by_buffer, dict) or not all(
            isinstance(k, str) for k in self.bytes_by_buffer
        ):
            raise InvalidInputError(
                "StreamStats.bytes_by_buffer: expected a dict of buffer names to byte counts, "
                f"got {type(self.bytes_by_buffer).__name__}"
            )
        for k, v in self.bytes_by_buffer.items():
            check_int(f"StreamStats.bytes_by_buffer[{k!r}]", v, 0, 1 << 62)

    @checked(packet=buffers(Packet))
    def add(self, packet: bytes | memoryview | Packet) -> None:
        p = packet if isinstance(packet, Packet) else unpack_packet(packet)
        self.frames += 1
        payload = 0
        for b in p.buffers:
            if b.codec == Codec.TILE:
                continue  # no bytes of its own: they are in its picture's
            self.bytes_by_buffer[b.name] = self.bytes_by_buffer.get(b.name, 0) + len(
                b.payload
            )
            payload += len(b.payload)
        size = len(packet) if not isinstance(packet, Packet) else len(pack_packet(p))
        self.header_bytes += size - payload

    @property
    def seconds(self) -> float:
        return self.frames / self.fps

    def _mbps(self, n: int) -> float:
        return n * 8 / 1e6 / self.seconds if self.frames else 0.0

    @property
    def total_bytes(self) -> int:
        return sum(self.bytes_by_buffer.values()) + self.header_bytes

    def mbps_by_buffer(self) -> dict[str, float]:
        """Mb/s of each buffer."""
        return {k: self._mbps(v) for k, v in sorted(self.bytes_by_buffer.items())}

    def mbps_by_camera(self) -> dict[str, float]:
        """Mb/s of each camera (all its buffers), plus ``"header"``."""
        out: dict[str, int] = {}
        for k, v in self.bytes_by_buffer.items():
            cam = k.split(".", 1)[0]
            out[cam] = out.get(cam, 0) + v
        res = {k: self._mbps(v) for k, v in sorted(out.items())}
        res["header"] = self._mbps(self.header_bytes)
        return res

    def mbps_total(self) -> float:
        """Mb/s of the whole stream (payloads and headers)."""
        return self._mbps(self.total_bytes)

    def format(self) -> str:
        """A plain-text table of the rates."""
        lines = [
            f"{self.frames} frames at {self.fps:g} FPS: {self.mbps_total():.3f} Mb/s total"
        ]
        for k, v in self.mbps_by_camera().items():
            lines.append(f"  {k:<8} {v:9.3f} Mb/s")
        for k, v in self.mbps_by_buffer().items():
            lines.append(f"    {k:<22} {v:9.3f} Mb/s")
        return "\n".join(lines)


@checked(packets=ITERABLE, fps=floats(positive=True, hi=MAX_RATE))
def stream_stats(
    packets: Iterable[bytes | memoryview | Packet], fps: float = 10.0
) -> StreamStats:
    """The :class:`StreamStats` of ``packets`` at ``fps`` server frames per second."""
    s = StreamStats(fps=fps)
    for p in packets:
        s.add(p)
    return s
