"""The packet format and the container file (splitrender.codec.stream): round trips, key-frame index,
byte accounting, and untrusted input (every malformed packet or file raises StreamError naming
the frame and buffer; fuzzed with hypothesis)."""

from __future__ import annotations

import dataclasses
import errno
import io
import os
import re
import struct
import zlib
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import zstandard
from hypothesis import given
from hypothesis import strategies as st
from splitrender.errors import InvalidInputError, StreamError
from splitrender.codec.stream import (
    KIND_CHANNELS,
    MAX_BUFFERS,
    MAX_CAMERAS,
    MAX_HEADER,
    MAX_INDEX,
    MAX_PAYLOAD,
    MAX_RATE,
    MAX_SIDE,
    BufferEntry,
    BufferKind,
    CameraRecord,
    Codec,
    Packet,
    StreamFile,
    StreamWriter,
    pack_packet,
    read_stream,
    stream_stats,
    unpack_packet,
    write_stream,
)


def _packet(index: int = 7, key: bool = True) -> Packet:
    eye = np.eye(4)
    cams = (CameraRecord(eye, eye * 2, 8, 4), CameraRecord(eye, eye, 4, 2))
    bufs = (
        BufferEntry(0, BufferKind.COLOR, Codec.RAW, 3, 8, 4, bytes(range(96))),
        BufferEntry(
            0,
            BufferKind.DEPTH,
            Codec.TILE,
            1,
            8,
            4,
            b"",
            (0.5, 0, 0),
            (0.25, 0, 0),
        ),
        BufferEntry(1, BufferKind.MOTION_FWD, Codec.ZERO, 3, 4, 2, b""),
        BufferEntry(1, BufferKind.SHADOW_FWD_BITS, Codec.ZSTD, 1, 4, 2, b"zz"),
        BufferEntry(0, BufferKind.PICTURE_GEOMETRY, Codec.HEVC, 1, 8, 4, b"\x01\x02\x03"),
    )
    return Packet(
        index=index, time=0.7, key=key, uncompressed=False, cameras=cams, buffers=bufs
    )


def _split(data: bytes) -> tuple[bytes, bytearray, bytes]:
    """``(fixed header, decompressed header block, payloads)`` of a packet."""
    m = struct.unpack_from("<I", data, 24)[0]
    block = zstandard.ZstdDecompressor().decompress(data[32 : 32 + m])
    return data[:32], bytearray(block), data[32 + m :]


def _join(head: bytes, block: bytes, payloads: bytes) -> bytes:
    """A packet from its parts with a consistent length and CRC (a hostile producer writes
    consistent CRCs)."""
    packed = zstandard.ZstdCompressor(write_content_size=True).compress(bytes(block))
    head = head[:24] + struct.pack("<I", len(packed))
    crc = zlib.crc32(payloads, zlib.crc32(packed, zlib.crc32(head)))
    return head + struct.pack("<I", crc) + packed + payloads


def _refresh_crc(data: bytes) -> bytes:
    """Recomputes the packet CRC."""
    crc = zlib.crc32(data[32:], zlib.crc32(data[:28]))
    return data[:28] + struct.pack("<I", crc) + data[32:]


# Offsets inside the decompressed header block of _packet(): 4-byte head, 2 cameras of 264
# bytes, then the entries (8 bytes + 8 per scale/offset pair).
_CAMS = 4
_ENTRIES = 4 + 2 * 264


def test_packet_round_trip() -> None:
    p = _packet()
    q = unpack_packet(pack_packet(p))
    assert (q.index, q.time, q.key, q.uncompressed) == (7, 0.7, True, False)
    assert np.array_equal(q.cameras[0].proj, np.eye(4) * 2)
    assert [(b.camera, b.kind, b.codec, bytes(b.payload)) for b in q.buffers] == [
        (b.camera, b.kind, b.codec, bytes(b.payload)) for b in p.buffers
    ]
    assert [(b.width, b.height) for b in q.buffers] == [
        (8, 4), (8, 4), (4, 2), (4, 2), (8, 4)
    ]
    assert q.buffers[1].scale == (0.5, 0.0, 0.0) and q.buffers[1].offset == (
        0.25,
        0.0,
        0.0,
    )
    assert q.buffers[3].name == "aux0.shadow_fwd.bits"
    assert q.buffers[4].name == "picture.geometry"


def _counted(n_cam: int, n_buf: int, camera: int | None = None, tiles: bool = False) -> Packet:
    """A packet of ``n_cam`` 1x1 cameras and ``n_buf`` empty buffers (on camera ``camera``, or
    spread over them): motion, as zeros or (``tiles``) as tiles with three scale and offset
    pairs, the most a buffer's header entry holds."""
    eye = np.eye(4)
    codec, pairs = (Codec.TILE, ((1.0,) * 3, (0.0,) * 3)) if tiles else (Codec.ZERO, ())
    return Packet(
        index=1, time=0.1, key=True, uncompressed=False,
        cameras=tuple(CameraRecord(eye, eye, 1, 1) for _ in range(n_cam)),
        buffers=tuple(
            BufferEntry(i % max(n_cam, 1) if camera is None else camera, BufferKind.MOTION_FWD,
                        codec, 3, 1, 1, b"", *pairs)
            for i in range(n_buf)
        ),
    )


def test_packets_at_the_limits_round_trip_and_one_past_is_refused(tmp_path: Path) -> None:
    # One camera and no buffer, MAX_CAMERAS cameras and MAX_BUFFERS buffers, frame indices 0
    # and MAX_INDEX, a camera MAX_SIDE wide or high, a stream at MAX_RATE: each limit itself
    # is allowed; one past it is refused by pack_packet and, written by a hostile producer
    # (consistent CRCs), by unpack_packet.
    for n_cam, n_buf in [(1, 0), (1, 1), (MAX_CAMERAS, MAX_BUFFERS)]:
        q = unpack_packet(pack_packet(_counted(n_cam, n_buf)))
        assert (len(q.cameras), len(q.buffers)) == (n_cam, n_buf)
    # The largest header block: every camera and buffer at the limits, three pairs each.
    largest = pack_packet(_counted(MAX_CAMERAS, MAX_BUFFERS, tiles=True))
    assert len(_split(largest)[1]) == MAX_HEADER
    assert len(unpack_packet(largest).buffers) == MAX_BUFFERS
    for index in (0, MAX_INDEX):
        assert unpack_packet(pack_packet(dataclasses.replace(_counted(1, 0), index=index))).index \
            == index
    eye = np.eye(4)
    for w, h in [(MAX_SIDE, 1), (1, MAX_SIDE)]:
        cam = CameraRecord(eye, eye, w, h)
        q = unpack_packet(pack_packet(dataclasses.replace(_counted(1, 0), cameras=(cam,))))
        assert (q.cameras[0].width, q.cameras[0].height) == (w, h)
    write_stream(tmp_path / "s.srs", [pack_packet(_counted(1, 0))], fps=MAX_RATE)
    assert StreamFile(tmp_path / "s.srs").fps == MAX_RATE
    for packet, message in [
        (_counted(0, 0), "frame 1: 0 cameras (1..16 allowed)"),
        (_counted(MAX_CAMERAS + 1, 1), "frame 1: 17 cameras (1..16 allowed)"),
        (_counted(1, MAX_BUFFERS + 1), "frame 1: 513 buffers (at most 512)"),
        (_counted(2, 1, camera=2), "frame 1, aux1.motion_fwd: camera 2 of 2"),
    ]:
        with pytest.raises(StreamError, match=f"^{re.escape(message)}$"):
            pack_packet(packet)
    head, block, payloads = _split(pack_packet(_counted(2, 1, camera=1)))
    for n_cam, n_buf, message in [
        (0, 1, "0 cameras in the header (1..16 allowed)"),
        (MAX_CAMERAS + 1, 1, "17 cameras in the header (1..16 allowed)"),
        (2, MAX_BUFFERS + 1, "513 buffers in the header (at most 512)"),
    ]:
        hostile = bytes(struct.pack("<BBH", n_cam, 0, n_buf) + block[4:])
        with pytest.raises(StreamError, match=f"^frame 1: {re.escape(message)}$"):
            unpack_packet(_join(head, hostile, payloads))
    entry = _ENTRIES  # two cameras before it, as in _packet()
    assert block[entry] == 1  # the buffer's camera
    hostile = block[:entry] + bytes([2]) + block[entry + 1:]
    with pytest.raises(StreamError, match=r"^frame 1, aux1\.motion_fwd: camera 2 of 2$"):
        unpack_packet(_join(head, hostile, payloads))
    # A header block of its 4-byte head alone, one camera announced: too short for it.
    with pytest.raises(StreamError, match=r"^frame 1: header block of 4 bytes is too short for "
                                          r"1 cameras$"):
        unpack_packet(_join(head, struct.pack("<BBH", 1, 0, 0), payloads))


@pytest.mark.parametrize(
    ("index", "change", "message"),
    [
        # a tile carries no payload of its own: its picture does
        (1, {"payload": b"x"}, "main.depth: a TILE buffer with a 1-byte payload"),
        # HEVC is the codec of the pictures only, TILE of the lossy buffers only
        (1, {"codec": Codec.HEVC}, "main.depth: codec HEVC is not a codec of this buffer kind"),
        (3, {"codec": Codec.TILE}, "aux0.shadow_fwd.bits: codec TILE is not a codec"),
        (4, {"codec": Codec.ZSTD}, "picture.geometry: codec ZSTD is not a codec"),
        (4, {"camera": 1}, "picture.geometry: a picture must be listed under camera 0, not 1"),
    ],
)
def test_tiles_and_pictures_keep_their_codecs(
    index: int, change: dict[str, object], message: str
) -> None:
    p = _packet()
    bufs = list(p.buffers)
    bufs[index] = dataclasses.replace(bufs[index], **change)  # type: ignore[arg-type]
    if "camera" in change:  # an aux camera of the picture's size, so only the camera differs
        p = dataclasses.replace(p, cameras=(p.cameras[0], p.cameras[0]))
        bufs[2:4] = [dataclasses.replace(b, width=8, height=4) for b in bufs[2:4]]
    # pack_packet checks sizes, not codecs: a hostile producer can write any table
    data = pack_packet(dataclasses.replace(p, buffers=tuple(bufs)))
    with pytest.raises(StreamError, match=f"frame 7, {message}"):
        unpack_packet(data)


def test_header_is_compact() -> None:
    """Version 3's fixed costs: a three-camera frame with 39 buffer entries (the server's layout:
    13 per camera, the lossy ones as payload-less tiles) and its 3 pictures spends well under
    the ~1.7 kB of version 1's plain header."""
    rng = np.random.default_rng(0)
    cams = tuple(
        CameraRecord(
            np.vstack([rng.normal(size=(3, 4)), [0, 0, 0, 1]]), np.diag([1.7, 3.0, 0, 0]),
            w, h,
        )
        for w, h in ((320, 180), (160, 90), (160, 90))
    )
    kinds = [k for k in BufferKind][:13]
    bufs = []
    for c in range(3):
        w, h = cams[c].width, cams[c].height
        for k in kinds:
            q = k in (BufferKind.DEPTH, BufferKind.MOTION_FWD, BufferKind.MOTION_BWD)
            n = 1 if k == BufferKind.DEPTH else 3
            sc = tuple(float(np.float32(v)) for v in rng.uniform(1e-4, 1e-2, 3))
            bufs.append(
                BufferEntry(
                    c, k, Codec.TILE if q else Codec.ZSTD, n if q else 1, w, h,
                    b"" if q else bytes(int(rng.integers(1, 3000))),
                    sc if q else (0.0, 0.0, 0.0), sc if q else (0.0, 0.0, 0.0),
                )
            )
    bufs += [
        BufferEntry(0, k, Codec.HEVC, 1, 320, 180, bytes(int(rng.integers(1, 30000))))
        for k in (BufferKind.PICTURE_COLOR, BufferKind.PICTURE_GEOMETRY, BufferKind.PICTURE_SHADOW)
    ]
    p = Packet(index=5, time=0.5, key=False, uncompressed=False, cameras=cams,
               buffers=tuple(bufs))
    data = pack_packet(p)
    header = len(data) - sum(len(b.payload) for b in bufs)
    assert header < 900, header
    assert stream_stats([data]).header_bytes == header


def test_scales_must_be_float32_values() -> None:
    p = _packet()
    bad = dataclasses.replace(p.buffers[1], scale=(0.1, 0.0, 0.0))
    with pytest.raises(StreamError, match="frame 7, main.depth: scale/offset"):
        pack_packet(dataclasses.replace(p, buffers=(p.buffers[0], bad)))


def test_every_truncation_raises() -> None:
    data = pack_packet(_packet())
    for n in range(len(data)):
        with pytest.raises(StreamError):
            unpack_packet(data[:n])
    with pytest.raises(StreamError, match="trailing"):
        unpack_packet(_refresh_crc(data + b"\0"))


def test_corrupted_packet_names_the_frame() -> None:
    data = bytearray(pack_packet(_packet()))
    data[-3] ^= 0x40  # inside a payload
    with pytest.raises(StreamError, match="frame 7: packet CRC mismatch"):
        unpack_packet(bytes(data))
    data = bytearray(pack_packet(_packet()))
    data[40] ^= 1  # inside the compressed header block
    with pytest.raises(StreamError, match="frame 7: packet CRC mismatch"):
        unpack_packet(bytes(data))
    head, block, payloads = _split(pack_packet(_packet()))
    with pytest.raises(StreamError, match="frame 7: the header block is not a zstd frame"):
        unpack_packet(_refresh_crc(head + bytes(block) + payloads))


def test_wrong_version_and_magic() -> None:
    data = bytearray(pack_packet(_packet()))
    data[4:6] = struct.pack("<H", 9)
    with pytest.raises(StreamError, match="frame 7: unsupported packet version 9"):
        unpack_packet(bytes(data))
    # Versions 2 (24 HEVC streams a frame) and 3 (full-size shadow colours, which a version-4
    # decoder would read wrongly: same bytes, other meaning) are refused with what to do.
    for old in (2, 3):
        data[4:6] = struct.pack("<H", old)
        with pytest.raises(
            StreamError,
            match=f"frame 7: packet format version {old} is no longer supported \\(this reader "
            "knows version 4\\); re-encode the recording with `splitrender encode`",
        ):
            unpack_packet(bytes(data))
    with pytest.raises(StreamError, match="not a splitrender packet"):
        unpack_packet(b"XXXX" + bytes(data[4:]))


def test_fields_a_writer_leaves_fixed_are_checked_by_the_reader() -> None:
    # pack_packet refuses a NaN time and writes only known flags and a zero reserved byte; a
    # hostile producer (consistent CRC) may write anything there.
    data = pack_packet(_packet())
    for offset, fmt, value, message in [
        (16, "<d", float("nan"), "time is not finite"),
        (16, "<d", float("-inf"), "time is not finite"),
        (6, "<H", 1 | 4, "unknown header flags 0x0005"),
    ]:
        bad = bytearray(data)
        struct.pack_into(fmt, bad, offset, value)
        with pytest.raises(StreamError, match=f"^frame 7: {message}"):
            unpack_packet(_refresh_crc(bytes(bad)))
    head, block, payloads = _split(data)
    block[1] = 1
    with pytest.raises(StreamError, match="^frame 7: reserved header byte is 1, expected 0"):
        unpack_packet(_join(head, block, payloads))


def test_a_frame_index_beyond_an_i64_is_a_stream_error() -> None:
    # A crafted index of 2^63 passed the parser and failed after the whole decode, as an
    # InvalidInputError of ServerFrame.index (the caller's class for the wire's fault).
    data = bytearray(pack_packet(_packet()))
    for index in (2**63, 2**64 - 1):
        data[8:16] = struct.pack("<Q", index)
        with pytest.raises(StreamError, match=f"frame {index}: the index is beyond"):
            unpack_packet(_refresh_crc(bytes(data)))
    data[8:16] = struct.pack("<Q", 2**63 - 1)
    assert unpack_packet(_refresh_crc(bytes(data))).index == 2**63 - 1


def test_packets_as_memoryviews(tmp_path: Path) -> None:
    data = pack_packet(_packet())
    # Any C-contiguous view is taken as its bytes (a 2-D one's len() counts its rows).
    rows = memoryview(np.frombuffer(data, np.uint8).reshape(1, -1))
    assert len(rows) == 1
    assert unpack_packet(memoryview(data)).index == 7
    write_stream(tmp_path / "s.srs", [memoryview(data), rows])
    assert [bytes(p) for p in read_stream(tmp_path / "s.srs")] == [data, data]
    assert stream_stats([rows]).frames == 1
    # A strided view raised a bare TypeError (decode, stats) or BufferError (write).
    strided = memoryview(bytes(b for b in data for _ in range(2)))[::2]
    assert bytes(strided) == data
    for call in (
        lambda: stream_stats([strided]),
        lambda: write_stream(tmp_path / "t.srs", [strided]),
    ):
        with pytest.raises(InvalidInputError, match="packet: expected a C-contiguous buffer"):
            call()
    assert not (tmp_path / "t.srs").exists()


def test_absurd_sizes_rejected_before_allocation() -> None:
    head, block, payloads = _split(pack_packet(_packet()))
    b = bytearray(block)
    b[_CAMS : _CAMS + 8] = struct.pack("<II", 60000, 60000)  # main camera 60000 x 60000
    with pytest.raises(StreamError, match="frame 7, main: camera size 60000x60000"):
        unpack_packet(_join(head, b, payloads))
    b = bytearray(block)
    entry1 = _ENTRIES + 8  # second entry (main.depth), after the colour entry
    b[entry1 + 4 : entry1 + 8] = struct.pack("<I", 0xFFFFFFF0)
    with pytest.raises(
        StreamError, match=rf"frame 7, main.depth: payload of {0xFFFFFFF0} bytes"
    ):
        unpack_packet(_join(head, b, payloads))
    assert MAX_PAYLOAD < 0xFFFFFFF0
    # Within MAX_PAYLOAD but beyond the bytes that remain (96 + 0 + 0 + 2 + 3 of payloads): the
    # check above must not rest on MAX_PAYLOAD alone.
    b = bytearray(block)
    b[_ENTRIES + 4 : _ENTRIES + 8] = struct.pack("<I", 1000)  # main.color, 96 bytes
    with pytest.raises(
        StreamError, match=r"^frame 7, main.color: payload of 1000 bytes but 101 bytes remain"
    ):
        unpack_packet(_join(head, b, payloads))
    # Camera counts outside 1..16, each with as many whole camera records as it claims.
    cam = block[_CAMS + 264 : _CAMS + 2 * 264]
    for n_cam in (0, 17):
        b = bytearray(block)
        b[0] = n_cam
        if n_cam:
            b[_ENTRIES:_ENTRIES] = cam * (n_cam - 2)
        with pytest.raises(StreamError, match=f"^frame 7: {n_cam} cameras in the header"):
            unpack_packet(_join(head, b, payloads))
    b = bytearray(block)
    b[2:4] = struct.pack("<H", 60000)  # buffer count
    with pytest.raises(StreamError, match="frame 7: 60000 buffers"):
        unpack_packet(_join(head, b, payloads))
    # A header block that declares more than MAX_HEADER bytes is refused before decompressing.
    huge = zstandard.ZstdCompressor(write_content_size=True).compress(bytes(MAX_HEADER + 1))
    h = head[:24] + struct.pack("<I", len(huge))
    crc = zlib.crc32(payloads, zlib.crc32(huge, zlib.crc32(h)))
    with pytest.raises(StreamError, match=f"frame 7: header block of {MAX_HEADER + 1} bytes"):
        unpack_packet(h + struct.pack("<I", crc) + huge + payloads)


def test_each_check_of_the_header_block_says_what_is_wrong() -> None:
    """The header block's own checks, each met by a packet that only it refuses (with a
    consistent block length and CRC, as a hostile producer writes them): without it, the
    block would decompress without a bound, or a short block would raise struct.error."""
    head, block, payloads = _split(pack_packet(_packet()))
    depth = _ENTRIES + 8  # main.depth's entry (TILE, one scale/offset pair after it)

    def refused(b: bytes | bytearray, message: str) -> None:
        with pytest.raises(StreamError, match=message):
            unpack_packet(_join(head, b, payloads))

    b = bytearray(block)
    b[depth + 3] = 2
    refused(b, r"^frame 7, main.depth: 2 scale/offset pairs \(expected 1\)$")
    b = bytearray(block)
    struct.pack_into("<f", b, depth + 8, float("nan"))
    refused(b, r"^frame 7, main.depth: scale/offset not finite$")
    refused(block + bytes(3), r"^frame 7: 3 trailing bytes in the header block$")
    refused(block[:3], r"^frame 7: header block of 3 bytes is too short$")
    refused(block[:_CAMS + 264 + 10],
            rf"^frame 7: header block of {_CAMS + 274} bytes is too short for 2 cameras$")
    # Every cut of the block is refused in its own words, never with another exception.
    for n in range(len(block)):
        with pytest.raises(StreamError, match="^frame 7"):
            unpack_packet(_join(head, block[:n], payloads))
    # A zstd frame that does not declare its size would decompress without a bound.
    unsized = zstandard.ZstdCompressor(write_content_size=False).compress(bytes(block))
    h = head[:24] + struct.pack("<I", len(unsized))
    crc = zlib.crc32(payloads, zlib.crc32(unsized, zlib.crc32(h)))
    with pytest.raises(StreamError, match="^frame 7: the header block does not declare its size"):
        unpack_packet(h + struct.pack("<I", crc) + unsized + payloads)
    # The block's length field: beyond the bytes after the fixed header, or zero.
    data = _join(head, block, payloads)
    rest = len(data) - 32
    for m in (rest + 1, 0):
        bad = _refresh_crc(data[:24] + struct.pack("<I", m) + data[28:])
        with pytest.raises(StreamError, match=f"^frame 7: header block of {m} bytes, but "
                                              f"{rest} bytes remain"):
            unpack_packet(bad)


def test_cameras_over_the_budget_together_are_refused_before_allocating() -> None:
    # Issue 15: each camera's size was checked but not their sum; a tiny packet of 16 cameras
    # of 8192 x 4096 whose buffers are all ZERO made the decoder ask for ~30 GB.
    from splitrender.codec.coder import StreamDecoder

    eye = np.eye(4)
    cams = tuple(CameraRecord(eye, eye, 8192, 4096) for _ in range(16))
    bufs = tuple(
        BufferEntry(c, k, Codec.ZERO, KIND_CHANNELS[k], 8192, 4096, b"")
        for c in range(16)
        for k in (BufferKind.COLOR, BufferKind.DEPTH)
    )
    data = pack_packet(Packet(0, 0.0, True, False, cams, bufs))
    assert len(data) < 1000
    with StreamDecoder(threads=1) as d, pytest.raises(
        StreamError, match="the cameras hold 536870912 pixels together"
    ):
        d.decode(data)


def test_unknown_kind_and_wrong_size() -> None:
    p = _packet()
    bad = dataclasses.replace(p.buffers[0], width=9)
    with pytest.raises(StreamError, match="frame 7, main.color: size 9x4"):
        pack_packet(dataclasses.replace(p, buffers=(bad,)))
    head, block, payloads = _split(pack_packet(p))
    block[_ENTRIES + 1] = 200  # kind of the first entry
    with pytest.raises(StreamError, match="frame 7, main.kind200: unknown kind"):
        unpack_packet(_join(head, block, payloads))


_VALID = pack_packet(_packet())


# Every integer field of _VALID's header block: (offset, struct format). The block holds
# 2 cameras, then 5 entries; the second (main.depth, a quantised TILE) carries one pair.
_BLOCK_FIELDS = [(0, "<B"), (1, "<B"), (2, "<H")] + [
    (_CAMS + 264 * c + k, "<I") for c in range(2) for k in (0, 4)
] + [
    (start + k, fmt)
    for start in (_ENTRIES, _ENTRIES + 8, _ENTRIES + 24, _ENTRIES + 32, _ENTRIES + 40)
    for k, fmt in ((0, "<B"), (1, "<B"), (2, "<B"), (3, "<B"), (4, "<I"))
]


@given(
    st.lists(
        st.tuples(
            st.sampled_from(_BLOCK_FIELDS),
            st.one_of(
                st.sampled_from([0, 1, 2, 3, 4, 15, 16, 17, 255, 256, 512, 513, 16384, 16385,
                                 1 << 25, 0xFFFF, 0xFFFFFFFF]),
                st.integers(0, 0xFFFFFFFF),
            ),
        ),
        min_size=1,
        max_size=4,
    ),
    st.integers(-40, 0),
)
def test_fuzz_header_block_fields(edits: list[tuple[tuple[int, str], int]], cut: int) -> None:
    """Structure-aware: counts, sizes, kinds, codecs and lengths of a real packet's header block
    set to edge values (and the block cut short), re-packed with a consistent block length and
    CRC so that every case reaches the block parser (random bytes stopped at the first length
    check). Either a StreamError naming the frame, or a packet within the format's limits whose
    payloads lie inside it."""
    head, block, payloads = _split(_VALID)
    for (offset, fmt), value in edits:
        struct.pack_into(fmt, block, offset, value & ((1 << (8 * struct.calcsize(fmt))) - 1))
    data = _join(head, bytes(block[: len(block) + cut] if cut else block), payloads)
    try:
        p = unpack_packet(data)
    except StreamError as e:
        assert str(e).startswith("frame 7")  # past the fixed header: the frame is known
    else:
        assert 1 <= len(p.cameras) <= 16
        assert all(c.width * c.height <= 1 << 25 for c in p.cameras)
        assert sum(len(b.payload) for b in p.buffers) <= len(data)


@given(
    st.lists(
        st.tuples(st.integers(0, len(_VALID) - 1), st.integers(0, 255)), max_size=6
    ),
    st.integers(0, len(_VALID)),
    st.booleans(),
)
def test_fuzz_mutated_packet(
    edits: list[tuple[int, int]], cut: int, fix_crc: bool
) -> None:
    data = bytearray(_VALID)
    for pos, val in edits:
        data[pos] = val
    data = data[:cut]
    if fix_crc and len(data) >= 32 and data[:4] == b"SRPK":  # the header block may still be bad
        data = bytearray(_refresh_crc(bytes(data)))
    try:
        p = unpack_packet(bytes(data))
    except StreamError as e:
        assert str(e).startswith("frame ")
    else:
        assert sum(len(b.payload) for b in p.buffers) <= len(data)


def test_container_index_and_random_access(tmp_path: Path) -> None:
    packets = [pack_packet(_packet(i, key=i % 3 == 0)) for i in range(8)]
    path = tmp_path / "s.srs"
    write_stream(path, packets, fps=10)
    f = StreamFile(path)
    assert f.key_frames == [0, 3, 6] and len(f) == 8 and f.fps == 10
    assert list(f.packets()) == packets
    assert list(read_stream(path, start=3)) == packets[3:]
    with pytest.raises(StreamError, match="frame 4 is not a key frame"):
        list(read_stream(path, start=4))


def test_a_failed_write_leaves_the_previous_stream_intact(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # Issue 15: the writer wrote in place, so a failure midway destroyed the previous file and
    # left a shorter one that still read cleanly.
    path = tmp_path / "s.srs"
    packets = [pack_packet(_packet(i)) for i in range(4)]
    write_stream(path, packets)
    good = path.read_bytes()

    with pytest.raises(RuntimeError, match="midway"):
        with StreamWriter(path, fps=10) as w:
            w.write(packets[0])
            raise RuntimeError("midway")
    assert path.read_bytes() == good

    def packets_then_fail() -> Iterator[bytes]:
        yield packets[0]
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        write_stream(path, packets_then_fail())
    with pytest.raises(StreamError):  # a bad packet midway
        write_stream(path, [packets[0], b"not a packet"])
    assert path.read_bytes() == good

    def full_disk(fd: int) -> None:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "fsync", full_disk)
    with pytest.raises(OSError, match="No space left"):
        write_stream(path, packets[:2])
    assert path.read_bytes() == good
    assert [p.name for p in tmp_path.iterdir()] == ["s.srs"]
    monkeypatch.undo()

    write_stream(path, packets[:2])  # a clean close replaces it
    assert list(read_stream(path)) == packets[:2]
    assert [p.name for p in tmp_path.iterdir()] == ["s.srs"]
    with pytest.raises(IsADirectoryError, match="got a folder"):
        StreamWriter(tmp_path)
    # The rename would replace the node itself (as root, `encode --out /dev/zero` did).
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    with pytest.raises(InvalidInputError, match="fifo: the output is not a regular file"):
        StreamWriter(fifo)
    assert fifo.is_fifo()


class _FullDisk(io.RawIOBase):
    """A file whose every write fails as on a full disk."""

    def writable(self) -> bool:
        return True

    def seekable(self) -> bool:
        return True

    def seek(self, offset: int, whence: int = 0) -> int:
        return 0

    def write(self, b: object) -> int:
        raise OSError(errno.EFBIG, "File too large")


def test_an_abort_on_a_full_disk_removes_the_temporary_file(tmp_path: Path) -> None:
    # Found by the fuzz suite (issue 15): abort() closed the file first, whose flush of the
    # buffered bytes failed again on the full disk, so the temporary file was never removed.
    path = tmp_path / "s.srs"
    write_stream(path, [pack_packet(_packet(0))])
    good = path.read_bytes()
    w = StreamWriter(path, fps=10)
    w._file.close()
    w._file = io.BufferedWriter(_FullDisk())
    w.write(pack_packet(_packet(0)))  # buffered: the failure comes with the flush
    with pytest.raises(OSError, match="File too large"):
        w.close()
    assert path.read_bytes() == good
    assert [p.name for p in tmp_path.iterdir()] == ["s.srs"]


def test_a_stream_path_that_does_not_open_is_a_stream_error(tmp_path: Path) -> None:
    # Found by the fuzz suite: a dangling link or a loop of links raised OSError.
    (tmp_path / "dangling").symlink_to(tmp_path / "nowhere")
    (tmp_path / "loop").symlink_to("loop")
    for name in ("missing", "dangling", "loop"):
        with pytest.raises(StreamError, match=f"{name}: cannot open the stream file"):
            StreamFile(tmp_path / name)


def test_a_file_that_is_not_a_stream_is_refused_by_its_magic(tmp_path: Path) -> None:
    path = tmp_path / "s.srs"
    write_stream(path, [pack_packet(_packet(i)) for i in range(2)])
    raw = path.read_bytes()
    other = tmp_path / "other.srs"
    other.write_bytes(b"SRSTREAX" + raw[8:])  # all else a valid stream's
    with pytest.raises(StreamError, match=r"^other.srs: not a splitrender stream \(b'SRSTREAX'\)"):
        StreamFile(other)


def test_packets_beyond_the_record_limit_are_refused_on_both_sides(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # MAX_PACKET (2 GiB, the record's length field) made small, so that a packet passes it.
    import splitrender.codec.stream as stream

    packets = [pack_packet(_packet(i)) for i in range(2)]
    path = tmp_path / "s.srs"
    write_stream(path, packets)
    monkeypatch.setattr(stream, "MAX_PACKET", len(packets[0]) - 1)
    with StreamWriter(tmp_path / "w.srs", 10.0) as w, pytest.raises(
        StreamError, match=f"^frame 0: packet of {len(packets[0])} bytes is too large"
    ):
        w.write(packets[0])
    with pytest.raises(StreamError, match=f"record at byte 24 claims {len(packets[0])} bytes"):
        list(read_stream(path))


def test_container_truncated_and_wrong_version(tmp_path: Path) -> None:
    packets = [pack_packet(_packet(i)) for i in range(4)]
    path = tmp_path / "s.srs"
    write_stream(path, packets)
    raw = path.read_bytes()
    cut = tmp_path / "cut.srs"
    cut.write_bytes(
        raw[: 24 + 2 * (4 + len(packets[0])) + 100]
    )  # mid third record, no index
    # Refused by its claimed length before the read (the 100 bytes after the record's start
    # hold its 4-byte length and 96 of its bytes), not by the short read after it.
    with pytest.raises(
        StreamError,
        match=f"^cut.srs: frame after frame 1: record at byte {24 + 2 * (4 + len(packets[0]))} "
        f"claims {len(packets[0])} bytes but 96 remain",
    ):
        list(read_stream(cut))
    # Cut inside the index (4 records of 4 written): every record is whole and read. The
    # scan used to take the index magic for a record length and refuse the file.
    end = raw.rindex(b"SRIX")
    for size in (end + 4, end + 10, len(raw) - 1):
        cut.write_bytes(raw[:size])
        assert list(read_stream(cut)) == packets, size
    # Not an index: a record whose length field reads "SRIX" with more bytes after it than an
    # index of that many entries takes is still a record that runs past the end.
    cut.write_bytes(raw[:end] + b"SRIX" + bytes(200))
    with pytest.raises(StreamError, match="after frame 3: record at byte"):
        list(read_stream(cut))
    # A record of zero bytes (no index, so the scan reads it): its message named no file
    # ("frame ?: packet of 0 bytes is shorter than the 32-byte header").
    cut.write_bytes(raw[:24] + struct.pack("<I", 0) + raw[24:end])
    with pytest.raises(StreamError, match="^cut.srs: frame \\?: packet of 0 bytes is shorter"):
        list(read_stream(cut))
    bad = tmp_path / "v.srs"
    bad.write_bytes(raw[:8] + struct.pack("<H", 9) + raw[10:])
    with pytest.raises(StreamError, match="unsupported stream version 9"):
        StreamFile(bad)
    for old in (2, 3):
        bad.write_bytes(raw[:8] + struct.pack("<H", old) + raw[10:])
        with pytest.raises(
            StreamError,
            match=f"v.srs: stream format version {old} is no longer supported \\(this reader "
            "knows version 4\\)",
        ):
            StreamFile(bad)
    bad.write_bytes(b"nonsense")
    with pytest.raises(StreamError):
        StreamFile(bad)
    # The file header has no CRC: its reserved fields must be 0 and its rate one the package
    # takes (1e300 failed later as the caller's argument error of stream_stats).
    for offset, fmt, value, message in [
        (10, "<H", 1, "reserved header fields are 1 and 0, expected 0"),
        (12, "<I", 7, "reserved header fields are 0 and 7, expected 0"),
        (16, "<d", 1e300, r"server rate 1e\+300 frames per second, expected a finite value in "
         r"\(0, 1000\]"),
        (16, "<d", 0.0, "server rate 0.0 frames per second"),
        (16, "<d", float("nan"), "server rate nan frames per second"),
    ]:
        end = offset + struct.calcsize(fmt)
        bad.write_bytes(raw[:offset] + struct.pack(fmt, value) + raw[end:])
        with pytest.raises(StreamError, match=f"v.srs: {message}"):
            StreamFile(bad)


def test_stream_stats() -> None:
    packets = [pack_packet(_packet(i)) for i in range(10)]
    s = stream_stats(packets, fps=10.0)
    assert s.frames == 10 and s.seconds == 1.0
    assert s.total_bytes == sum(len(p) for p in packets)
    assert s.mbps_by_buffer()["main.color"] == pytest.approx(96 * 10 * 8 / 1e6)
    assert sum(s.mbps_by_camera().values()) == pytest.approx(s.mbps_total())
    assert "main.color" in s.format()


def test_hevc_decoder_refuses_a_picture_larger_than_declared() -> None:
    """A payload whose SPS declares a larger picture than the buffer table must fail inside FFmpeg
    before the picture is allocated (`max_pixels`), not after decoding it."""
    from fractions import Fraction

    import av

    from splitrender.codec.coder import _hevc_decoder

    enc = av.CodecContext.create("libx265", "w")
    enc.width, enc.height, enc.pix_fmt = 256, 256, "yuv420p"
    enc.time_base = Fraction(1, 10)
    enc.options = {"x265-params": "log-level=none:bframes=0", "tune": "zerolatency"}
    frame = av.VideoFrame.from_ndarray(np.zeros((256, 256, 3), np.uint8), format="rgb24")
    frame = frame.reformat(format="yuv420p")
    frame.pts = 0
    data = b"".join(bytes(p) for p in [*enc.encode(frame), *enc.encode(None)])
    assert len(_hevc_decoder(256, 256).decode(av.Packet(data))) == 1
    with pytest.raises(av.error.FFmpegError):
        _hevc_decoder(100, 100).decode(av.Packet(data))


def _with_index(raw: bytes, entries: list[tuple[int, int, int]]) -> bytes:
    """``raw`` (a container file) with its index replaced by ``entries`` ``(frame, offset,
    key)``, CRC and trailer consistent (a hostile writer makes them so)."""
    (offset,) = struct.unpack_from("<Q", raw, len(raw) - 16)
    table = b"".join(struct.pack("<QQB7x", *e) for e in entries)
    index = b"SRIX" + struct.pack("<I", len(entries)) + table + struct.pack("<I", zlib.crc32(table))
    return raw[:offset] + index + struct.pack("<Q8s", offset, b"SRSTREND")


def test_an_index_that_repeats_reorders_or_skips_records_is_refused(tmp_path: Path) -> None:
    # With its CRC made consistent, an index that listed record 0 four times read back as frame
    # 0 four times, one that listed the first record of four as a stream of one frame, an empty
    # one as a stream of none, and a key flag the packet contradicts let packets(start=k) start
    # at a frame no decoder can start at.
    packets = [pack_packet(_packet(i, key=i % 2 == 0)) for i in range(4)]
    path = tmp_path / "s.srs"
    write_stream(path, packets)
    raw = path.read_bytes()
    good = [(e.frame, e.offset, int(e.key)) for e in StreamFile(path).index]
    assert _with_index(raw, good) == raw
    bad = tmp_path / "bad.srs"
    for entries, message in [
        ([good[0]] * 4, "index entry 1 \\(frame 0\\) points at byte 24, expected the records in "
         "file order from byte 24"),
        (good[::-1], "index entry 0 \\(frame 3\\) points at byte"),
        (good[1:], "index entry 0 \\(frame 1\\) points at byte"),
        (good[:1], "frame 0: its record ends at byte \\d+, the index begins at byte"),
        (good[:1] + good[2:], "frame 0: its record ends at byte \\d+, the next record begins"),
        ([], "the index lists no records, but \\d+ bytes of records precede it"),
        ([good[0], (1, good[1][1], 1), *good[2:]],
         "frame 1: the index says it is a key frame, the packet says otherwise"),
    ]:
        bad.write_bytes(_with_index(raw, entries))
        with pytest.raises(StreamError, match=f"^bad.srs: {message}"):
            list(StreamFile(bad).packets())
    # Any other change to the index (here a padding byte, which nothing else reads) fails its
    # CRC.
    (offset,) = struct.unpack_from("<Q", raw, len(raw) - 16)
    damaged = bytearray(raw)
    damaged[offset + 8 + 17] ^= 1  # entry 0's first padding byte
    bad.write_bytes(bytes(damaged))
    with pytest.raises(StreamError, match="^bad.srs: index CRC mismatch"):
        StreamFile(bad)
    # A stream of no frames is still one.
    write_stream(path, [])
    assert list(read_stream(path)) == []


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"index": -1}, "frame index -1, expected an int in 0..9223372036854775807"),
        ({"index": 1 << 63}, "frame index 9223372036854775808, expected an int in"),
        ({"time": float("nan")}, "time is not finite"),
        ({"cameras": (), "buffers": ()}, r"frame 7: 0 cameras \(1\.\.\d+ allowed\)$"),
        ({"width": 0}, "main: camera size 0x4 beyond the limits"),
        ({"width": 20000}, "main: camera size 20000x4 beyond the limits"),
        ({"view": np.full((4, 4), np.inf)}, "main: camera matrices must be finite 4x4 arrays"),
        ({"proj": np.eye(3)}, "main: camera matrices must be finite 4x4 arrays"),
    ],
)
def test_pack_packet_refuses_what_a_reader_refuses(change: dict[str, object], message: str) -> None:
    # Each was packed (and then refused by every reader) or raised struct.error.
    p = _packet()
    if "index" in change or "time" in change or "cameras" in change:
        p = dataclasses.replace(p, **change)  # type: ignore[arg-type]
    else:
        cam = dataclasses.replace(p.cameras[0], **change)  # type: ignore[arg-type]
        p = dataclasses.replace(p, cameras=(cam, *p.cameras[1:]), buffers=())
    with pytest.raises(StreamError, match=message):
        pack_packet(p)


@pytest.mark.parametrize("fps", [1e6, 0.0, float("nan"), "10"])
def test_stream_writer_refuses_a_rate_no_reader_takes(tmp_path: Path, fps: object) -> None:
    # fps=1e6 was written, and the file then refused by every reader ("server rate 1000000.0");
    # a str raised TypeError.
    with pytest.raises(InvalidInputError, match="^fps: expected a"):
        StreamWriter(tmp_path / "s.srs", fps)  # type: ignore[arg-type]
    assert list(tmp_path.iterdir()) == []


def test_a_failed_write_names_the_stream_file(tmp_path: Path) -> None:
    # On a full disk `splitrender encode` said "error: [Errno 28] No space left on device",
    # naming no file: the write into the temporary file has no name of its own.
    path = tmp_path / "s.srs"
    for at_close in (False, True):
        w = StreamWriter(path, fps=10)
        w._file.close()
        full = io.BufferedWriter(_FullDisk()) if at_close else _FullDisk()
        w._file = full  # type: ignore[assignment]
        with pytest.raises(OSError) as e:
            with w:
                w.write(pack_packet(_packet(0)))  # buffered at_close: it fails at the flush
        assert (e.value.errno, e.value.filename) == (errno.EFBIG, str(path)), at_close
        assert list(tmp_path.iterdir()) == []
