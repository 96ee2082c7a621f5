"""The packet format and the container file (splitrender.stream): round trips, key-frame index,
byte accounting, and untrusted input (every malformed packet or file raises StreamError naming
the frame and buffer; fuzzed with hypothesis)."""

from __future__ import annotations

import dataclasses
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from splitrender.errors import StreamError
from splitrender.stream import (
    MAX_PAYLOAD,
    BufferEntry,
    BufferKind,
    CameraRecord,
    Codec,
    Packet,
    StreamFile,
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
            Codec.HEVC,
            1,
            8,
            4,
            b"\x01\x02\x03",
            (0.5, 0, 0),
            (0.25, 0, 0),
        ),
        BufferEntry(1, BufferKind.MOTION_FWD, Codec.ZERO, 3, 4, 2, b""),
        BufferEntry(1, BufferKind.SHADOW_FWD_BITS, Codec.ZSTD, 1, 4, 2, b"zz"),
    )
    return Packet(
        index=index, time=0.7, key=key, uncompressed=False, cameras=cams, buffers=bufs
    )


def _refresh_crc(data: bytes) -> bytes:
    """Recomputes the header CRC (a hostile producer writes consistent CRCs)."""
    n_cam, n_buf = data[24], struct.unpack_from("<H", data, 26)[0]
    end = 32 + 264 * n_cam
    for _ in range(n_buf):
        if end + 16 > len(data):
            break
        end += 16 + 16 * min(data[end + 3], 3)
    crc = zlib.crc32(data[32:end], zlib.crc32(data[:28]))
    return data[:28] + struct.pack("<I", crc) + data[32:]


def test_packet_round_trip() -> None:
    p = _packet()
    q = unpack_packet(pack_packet(p))
    assert (q.index, q.time, q.key, q.uncompressed) == (7, 0.7, True, False)
    assert np.array_equal(q.cameras[0].proj, np.eye(4) * 2)
    assert [(b.camera, b.kind, b.codec, bytes(b.payload)) for b in q.buffers] == [
        (b.camera, b.kind, b.codec, bytes(b.payload)) for b in p.buffers
    ]
    assert q.buffers[1].scale == (0.5, 0.0, 0.0) and q.buffers[1].offset == (
        0.25,
        0.0,
        0.0,
    )
    assert q.buffers[3].name == "aux0.shadow_fwd.bits"


def test_every_truncation_raises() -> None:
    data = pack_packet(_packet())
    for n in range(len(data)):
        with pytest.raises(StreamError):
            unpack_packet(data[:n])
    with pytest.raises(StreamError, match="trailing"):
        unpack_packet(data + b"\0")


def test_corrupted_payload_names_frame_and_buffer() -> None:
    data = bytearray(pack_packet(_packet()))
    data[-3] ^= 0x40  # inside aux0.shadow_fwd.bits's payload... or the one before
    with pytest.raises(StreamError, match=r"frame 7, (main|aux0)\.\w+"):
        unpack_packet(bytes(data))
    data = bytearray(pack_packet(_packet()))
    data[40] ^= 1  # a camera matrix: header CRC
    with pytest.raises(StreamError, match="frame 7: header CRC"):
        unpack_packet(bytes(data))


def test_wrong_version_and_magic() -> None:
    data = bytearray(pack_packet(_packet()))
    data[4:6] = struct.pack("<H", 9)
    with pytest.raises(StreamError, match="frame 7: unsupported packet version 9"):
        unpack_packet(bytes(data))
    with pytest.raises(StreamError, match="not a splitrender packet"):
        unpack_packet(b"XXXX" + bytes(data[4:]))


def test_absurd_sizes_rejected_before_allocation() -> None:
    data = bytearray(pack_packet(_packet()))
    data[32:40] = struct.pack("<II", 60000, 60000)  # main camera 60000 x 60000
    with pytest.raises(StreamError, match="frame 7, main: camera size 60000x60000"):
        unpack_packet(_refresh_crc(bytes(data)))
    # main.depth's payload length (entry 2, at 32 + 2*264 + 16 + 3*16 + 8... computed below)
    data = bytearray(pack_packet(_packet()))
    entry1 = 32 + 2 * 264 + 16  # second table entry (after the colour entry)
    data[entry1 + 8 : entry1 + 12] = struct.pack("<I", 0xFFFFFFF0)
    with pytest.raises(
        StreamError, match=rf"frame 7, main.depth: payload of {0xFFFFFFF0} bytes"
    ):
        unpack_packet(_refresh_crc(bytes(data)))
    assert MAX_PAYLOAD < 0xFFFFFFF0
    data = bytearray(pack_packet(_packet()))
    data[26:28] = struct.pack("<H", 60000)  # buffer count
    with pytest.raises(StreamError, match="frame 7: 60000 buffers"):
        unpack_packet(_refresh_crc(bytes(data)))


def test_unknown_kind_and_wrong_size() -> None:
    p = _packet()
    bad = dataclasses.replace(p.buffers[0], width=9)
    with pytest.raises(StreamError, match="frame 7, main.color: size 9x4"):
        unpack_packet(pack_packet(dataclasses.replace(p, buffers=(bad,))))
    data = bytearray(pack_packet(p))
    data[32 + 2 * 264 + 1] = 200  # kind of the first entry
    with pytest.raises(StreamError, match="frame 7, main.kind200: unknown kind"):
        unpack_packet(_refresh_crc(bytes(data)))


_VALID = pack_packet(_packet())


@given(st.binary(max_size=300))
def test_fuzz_random_bytes(data: bytes) -> None:
    try:
        unpack_packet(data)
    except StreamError:
        pass


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
    if fix_crc and len(data) >= 32 and data[:4] == b"SRPK":
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


def test_container_truncated_and_wrong_version(tmp_path: Path) -> None:
    packets = [pack_packet(_packet(i)) for i in range(4)]
    path = tmp_path / "s.srs"
    write_stream(path, packets)
    raw = path.read_bytes()
    cut = tmp_path / "cut.srs"
    cut.write_bytes(
        raw[: 24 + 2 * (4 + len(packets[0])) + 100]
    )  # mid third record, no index
    with pytest.raises(StreamError, match="after frame 1"):
        list(read_stream(cut))
    bad = tmp_path / "v.srs"
    bad.write_bytes(raw[:8] + struct.pack("<H", 2) + raw[10:])
    with pytest.raises(StreamError, match="unsupported stream version 2"):
        StreamFile(bad)
    bad.write_bytes(b"nonsense")
    with pytest.raises(StreamError):
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

    from splitrender.codec import _hevc_decoder

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
