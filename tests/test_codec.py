"""The codec (splitrender.codec.coder): lossless parts bit-exact, lossy parts within stated bounds, exact
zero motion on static pixels, rate control within ±10 %, random access, untrusted payloads, and
`ours` on decoded frames close to `ours` on the uncompressed ones.

Bounds are stated where they are asserted; the figures they come from are printed by
``python -m splitrender.cli.bench_codec``."""

from __future__ import annotations

import dataclasses
import weakref
from typing import Any

import numpy as np
import pytest
import splitrender as sr
from splitrender.codec.coder import _PIC_COLOR, CodecConfig, StreamDecoder, StreamEncoder
from splitrender.errors import InvalidInputError, StreamError
from splitrender.codec.stream import (
    BufferKind,
    Codec,
    pack_packet,
    stream_stats,
    unpack_packet,
)

W, H = 160, 90  # main camera; the auxiliary cameras are 80 x 45
N = 12  # frames: two GOPs of 10 would need 20; gop=6 gives key frames 0 and 6
BITRATE = (
    2.0  # Mb/s for the 160x90 rig (tiny images: fixed costs weigh more than at 720p)
)


def _cams(f: sr.ServerFrame) -> list[sr.CameraFrame]:
    return [f.main, *f.aux]


@pytest.fixture(scope="module")
def frames() -> list[sr.ServerFrame]:
    scene = sr.SyntheticScene(dynamic=True)
    return [scene.server_frame(i, i / 10, W, H) for i in range(N)]


@pytest.fixture(scope="module")
def coded(frames: list[sr.ServerFrame]) -> tuple[list[bytes], list[sr.ServerFrame]]:
    with (
        StreamEncoder(CodecConfig(bitrate_mbps=BITRATE, gop=6)) as enc,
        StreamDecoder() as dec,
    ):
        packets = [enc.encode(f) for f in frames]
        return packets, [dec.decode(p) for p in packets]


def test_decoded_frames_keep_layout(
    frames: list[sr.ServerFrame], coded: tuple[list[bytes], list[sr.ServerFrame]]
) -> None:
    _, decoded = coded
    assert len(decoded) == len(frames)
    for f, d in zip(frames, decoded):
        assert (d.index, d.time) == (f.index, f.time)
        assert len(d.aux) == len(f.aux) == 2
        for a, b in zip(_cams(f), _cams(d)):
            assert np.array_equal(a.camera.view, b.camera.view)
            assert np.array_equal(a.camera.proj, b.camera.proj)
            assert (b.camera.width, b.camera.height) == (a.camera.width, a.camera.height)
            assert b.color.shape == a.color.shape and b.depth.dtype == np.float32
            assert b.motion_fwd is not None and b.shadow_bwd is not None
            # Every buffer at its camera's size, in the layout's dtype.
            assert b.depth.shape == a.depth.shape
            for name in ("motion_fwd", "motion_bwd"):
                ma, mb = getattr(a, name), getattr(b, name)
                assert mb is not None and mb.shape == ma.shape and mb.dtype == np.float32
            for name in ("shadow_fwd", "shadow_bwd"):
                sa, sb = getattr(a, name), getattr(b, name)
                assert sb is not None
                for x in ("bits", "s_min", "s_max"):
                    assert getattr(sb, x).shape == getattr(sa, x).shape, (name, x)
                    assert getattr(sb, x).dtype == getattr(sa, x).dtype, (name, x)


def _arrays(f: sr.ServerFrame) -> list[np.ndarray]:
    """Every array of ``f``: each camera's buffers and its shadows' arrays, in field order."""
    out: list[np.ndarray] = []
    for cf in _cams(f):
        for fd in dataclasses.fields(cf):
            v = getattr(cf, fd.name)
            if isinstance(v, np.ndarray):
                out.append(v)
            elif dataclasses.is_dataclass(v):
                out += [a for g in dataclasses.fields(v)
                        if isinstance(a := getattr(v, g.name), np.ndarray)]
    return out


def test_decoded_frames_are_the_same_bytes_for_every_thread_count(
    coded: tuple[list[bytes], list[sr.ServerFrame]]
) -> None:
    # The colour picture decodes on two slice threads (wavefront rows) once the decoder has two
    # threads: FFmpeg's rows in another order must give the same pictures, key frames (0, 6)
    # and the others alike, as every other part of the decode does.
    packets, _ = coded
    runs = []
    for threads in (1, 2, 4):
        with StreamDecoder(threads=threads) as dec:
            runs.append([dec.decode(p) for p in packets])
            colour = dec._decoders[_PIC_COLOR][1]
            assert colour.thread_count == (1 if threads == 1 else 2)
    for other in runs[1:]:
        for a, b in zip(runs[0], other, strict=True):
            pairs = list(zip(_arrays(a), _arrays(b), strict=True))
            assert len(pairs) > 20
            for x, y in pairs:
                assert x.dtype == y.dtype and x.tobytes() == y.tobytes()


def test_shadow_bits_bit_exact(
    frames: list[sr.ServerFrame], coded: tuple[list[bytes], list[sr.ServerFrame]]
) -> None:
    _, decoded = coded
    for f, d in zip(frames, decoded):
        for a, b in zip(_cams(f), _cams(d)):
            for sa, sb in ((a.shadow_fwd, b.shadow_fwd), (a.shadow_bwd, b.shadow_bwd)):
                assert sa is not None and sb is not None
                assert sb.bits.dtype == np.uint32 and np.array_equal(sa.bits, sb.bits)
                # Colours are never read where the bitfield is 0: they decode to exactly 0.
                assert (
                    not sb.s_min[sb.bits == 0].any()
                    and not sb.s_max[sb.bits == 0].any()
                )


def test_shadow_bits_beyond_8_bits_survive() -> None:
    """REFERENCE.md §5 loses every bit above 8; every one of the 32 bits must survive here."""
    scene = sr.SyntheticScene(dynamic=True)
    f = scene.server_frame(0, 0.0, W, H, subframes=16)
    rng = np.random.default_rng(1)
    bits = rng.integers(0, 2**32, (H, W), dtype=np.uint64).astype(np.uint32)
    bits[rng.random((H, W)) < 0.9] = 0
    sh = f.main.shadow_fwd
    assert sh is not None
    main = dataclasses.replace(
        f.main, shadow_fwd=sr.ShadowBuffers(bits, sh.s_min, sh.s_max)
    )
    f = dataclasses.replace(f, main=main)
    # Random 32-bit values on a tenth of the pixels (~7 kB lossless) are more than a quarter of
    # this rate's frame: the encoder would leave them out (lossless_share); give them room.
    with (
        StreamEncoder(CodecConfig(bitrate_mbps=BITRATE, lossless_share=1.0)) as enc,
        StreamDecoder() as dec,
    ):
        out = dec.decode(enc.encode(f))
        assert enc.last.shadows_left_out == ()
    assert out.main.shadow_fwd is not None
    assert np.array_equal(out.main.shadow_fwd.bits, bits)


# Worst case over the 12 frames at BITRATE, measured with stream format 4 (PyAV 18.1.0,
# libx265; printed by the test with -s): colour PSNR main 30.4 / aux 29.7 / 29.7 dB; shadow
# colours on their set pixels 21.1 / 17.4 / 14.8 dB; depth mean |error| 0.043 / 0.065 / 0.065 %
# of the frame's depth range (median 0.029 / 0.030 / 0.036 %); motion mean |error| 0.091 /
# 0.081 / 0.083 % of the channel's span (worst channel). Bounds: twice the measured error (PSNR:
# 3 dB less, twice the squared error), so a codec change that doubles any buffer's error fails.
# Format 3 measured the same but for the shadow colours (35.4 / 34.8 / 30.4 dB): format 4 sends
# them at half size, and this scene's procedural texture at 160x90 is the worst case for that
# (the 2x2 block means alone give 19-28 dB here; on courtyard at 1280x720 the loss is 1-5 dB,
# and Figure 6 shows none, docs/codec-results.md).
_BOUNDS = {
    #       colour PSNR, shadow PSNR, depth mean, depth median, motion mean
    "main": (27.4, 18.1, 0.0009, 0.0006, 0.0018),
    "aux0": (26.7, 14.4, 0.0013, 0.0006, 0.0017),
    "aux1": (26.6, 11.8, 0.0013, 0.0008, 0.0017),
}


def _psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((a.astype(np.float64) - b) ** 2))
    return 99.0 if mse == 0 else 10 * np.log10(255.0**2 / mse)


def test_every_buffer_within_twice_its_measured_error(
    frames: list[sr.ServerFrame], coded: tuple[list[bytes], list[sr.ServerFrame]]
) -> None:
    """At BITRATE (2 Mb/s) for the 160x90 rig, per camera and frame: colour PSNR, shadow colour
    PSNR where the bitfield is set, depth mean and median |error| as a fraction of the frame's
    depth range, motion mean |error| per channel as a fraction of the channel's span; each
    within twice what stream format 4 achieves (``_BOUNDS``)."""
    _, decoded = coded
    worst: dict[str, list[float]] = {}
    for f, d in zip(frames, decoded):
        for name, a, b in zip(("main", "aux0", "aux1"), _cams(f), _cams(d)):
            c_psnr, s_psnr, d_mean, d_median, m_mean = _BOUNDS[name]
            got = [_psnr(a.color, b.color), 99.0]
            assert got[0] >= c_psnr, (f.index, name, "colour", got[0])
            for sa, sb in ((a.shadow_fwd, b.shadow_fwd), (a.shadow_bwd, b.shadow_bwd)):
                assert sa is not None and sb is not None
                on = sa.bits != 0
                for x in ("s_min", "s_max"):
                    p = _psnr(getattr(sa, x)[on], getattr(sb, x)[on])
                    assert p >= s_psnr, (f.index, name, x, p)
                    got[1] = min(got[1], p)
            rng = float(a.depth.max() - a.depth.min())
            err = np.abs(a.depth - b.depth) / rng
            assert err.mean() <= d_mean, (f.index, name, err.mean())
            assert np.median(err) <= d_median, (f.index, name, np.median(err))
            got += [float(err.mean()), float(np.median(err)), 0.0]
            for ma, mb in ((a.motion_fwd, b.motion_fwd), (a.motion_bwd, b.motion_bwd)):
                assert ma is not None and mb is not None
                span = np.ptp(ma.reshape(-1, 3), axis=0) + 1e-9
                merr = np.abs(ma - mb).reshape(-1, 3).mean(axis=0) / span
                assert (merr <= m_mean).all(), (f.index, name, merr)
                got[4] = max(got[4], float(merr.max()))
            prev = worst.setdefault(name, got)
            worst[name] = [min(prev[0], got[0]), min(prev[1], got[1])] + [
                max(x, y) for x, y in zip(prev[2:], got[2:])
            ]
    for name, w in worst.items():
        print(f"{name}: colour {w[0]:.1f} dB, shadow {w[1]:.1f} dB, depth mean {w[2]:.5f} "
              f"median {w[3]:.5f}, motion {w[4]:.5f}")


def test_static_motion_decodes_to_exact_zero(
    frames: list[sr.ServerFrame], coded: tuple[list[bytes], list[sr.ServerFrame]]
) -> None:
    _, decoded = coded
    for f, d in zip(frames, decoded):
        for a, b in zip(_cams(f), _cams(d)):
            for ma, mb in ((a.motion_fwd, b.motion_fwd), (a.motion_bwd, b.motion_bwd)):
                assert ma is not None and mb is not None
                static = (ma == 0).all(axis=2)
                assert static.any() and (mb[static] == 0.0).all()


def test_motion_near_the_largest_float32_encodes(recwarn: pytest.WarningsRecorder) -> None:
    # Four such values overflowed the float32 sum of the half-size mean: RuntimeWarnings, then
    # a StreamError about the scale for a frame the caller made correctly.
    scene = sr.SyntheticScene(dynamic=True)
    f = scene.server_frame(0, 0.0, W, H)
    m = f.main.motion_fwd.copy()
    m[:2, :2, 0] = 1e38
    f = dataclasses.replace(f, main=dataclasses.replace(f.main, motion_fwd=m))
    with StreamEncoder(CodecConfig(bitrate_mbps=BITRATE)) as enc, StreamDecoder() as dec:
        out = dec.decode(enc.encode(f))
    assert not [w for w in recwarn if issubclass(w.category, RuntimeWarning)]
    assert out.main.motion_fwd is not None and np.isfinite(out.main.motion_fwd).all()
    assert out.main.motion_fwd[0, 0, 0] == pytest.approx(1e38, rel=1e-3)


def test_static_scene_motion_costs_nothing() -> None:
    scene = sr.SyntheticScene(dynamic=False)
    f = scene.server_frame(0, 0.0, W, H)
    with (
        StreamEncoder(CodecConfig(bitrate_mbps=BITRATE)) as enc,
        StreamDecoder() as dec,
    ):
        packet = enc.encode(f)
        out = dec.decode(packet)
    kinds = {b.kind: b.codec for b in unpack_packet(packet).buffers if b.camera == 0}
    assert kinds[BufferKind.MOTION_FWD] == Codec.ZERO
    assert out.main.motion_fwd is not None and not out.main.motion_fwd.any()
    # Nothing at all: both directions of every camera are ZERO entries without a payload, and
    # no static-mask or invalid-mask buffer is sent beside them.
    motion = [b for b in unpack_packet(packet).buffers if b.kind.name.startswith("MOTION")]
    assert sorted((b.camera, b.kind) for b in motion) == [
        (c, k) for c in range(3) for k in (BufferKind.MOTION_FWD, BufferKind.MOTION_BWD)
    ]
    assert all(b.codec == Codec.ZERO and len(b.payload) == 0 for b in motion)
    for cf in _cams(out):
        for m in (cf.motion_fwd, cf.motion_bwd):
            assert m is not None and not m.any()


def _round_trip_main(
    f: sr.ServerFrame, depth: np.ndarray, motion: np.ndarray
) -> sr.ServerFrame:
    """``f`` with the main camera's depth and forward motion replaced, encoded and decoded."""
    main = dataclasses.replace(f.main, depth=depth, motion_fwd=motion)
    with (
        StreamEncoder(CodecConfig(bitrate_mbps=BITRATE)) as enc,
        StreamDecoder() as dec,
    ):
        return dec.decode(enc.encode(dataclasses.replace(f, main=main)))


def test_invalid_depth_and_motion_stay_invalid(frames: list[sr.ServerFrame]) -> None:
    f = frames[0]
    depth = f.main.depth.copy()
    depth[3, 4] = np.nan
    depth[5, 6] = np.inf
    motion = f.main.motion_fwd.copy()  # type: ignore[union-attr]
    motion[7, 8, 1] = np.nan
    out = _round_trip_main(f, depth, motion)
    assert np.array_equal(np.isfinite(out.main.depth), np.isfinite(depth))
    assert out.main.motion_fwd is not None
    assert np.array_equal(
        np.isfinite(out.main.motion_fwd).all(axis=2), np.isfinite(motion).all(axis=2)
    )


def test_depth_whose_range_starts_away_from_zero_keeps_its_offset(
    frames: list[sr.ServerFrame],
) -> None:
    """The synthetic scene's depth starts at 0 (its background), where the depth tile's offset
    is 0 and a decoder that dropped it, or an encoder that sent another, went unnoticed. Here
    the main camera's depth is moved to 0.5 + its range: the mean |error| as a fraction of the
    range within twice the 0.00036 measured on this frame (the main camera's bound in
    ``test_every_buffer_within_twice_its_measured_error`` is 0.0009), and the mean signed error
    (measured +0.00008) within 0.0002: an offset off by a code step (1/4095 of the range)
    fails."""
    f = frames[0]
    depth = f.main.depth + np.float32(0.5)
    assert f.main.motion_fwd is not None
    out = _round_trip_main(f, depth, f.main.motion_fwd)
    rng = float(depth.max() - depth.min())
    err = (out.main.depth.astype(np.float64) - depth) / rng
    print(f"depth at 0.5: mean |error| {np.abs(err).mean():.5f}, bias {err.mean():+.5f}")
    assert np.abs(err).mean() <= 0.0008
    assert abs(err.mean()) <= 0.0002


@pytest.mark.parametrize("tiny", [1e-45, -1e-45, 1e-40, 1e-38])
def test_denormal_depth_and_motion_ranges_round_trip_finite(
    frames: list[sr.ServerFrame], tiny: float
) -> None:
    # A span of a denormal float32 rounded the scale to 0.0: ZeroDivisionError in quantisation.
    f = frames[0]
    motion = np.zeros_like(f.main.motion_fwd)
    motion[1, 2] = np.float32(tiny)
    depth = np.full_like(f.main.depth, abs(tiny))
    depth[3, 4] = 0.0
    out = _round_trip_main(f, depth, motion)
    assert out.main.motion_fwd is not None
    assert np.isfinite(out.main.motion_fwd).all() and np.isfinite(out.main.depth).all()
    assert np.abs(out.main.motion_fwd - motion).max() <= 1e-34
    assert np.abs(out.main.depth - depth).max() <= 1e-34


def test_uncompressed_mode_round_trips_exactly(frames: list[sr.ServerFrame]) -> None:
    f = frames[3]
    depth = f.main.depth.copy()
    depth[0, 0] = np.nan
    f = dataclasses.replace(
        f, main=dataclasses.replace(f.main, depth=depth, motion_bwd=None)
    )
    with StreamEncoder(CodecConfig(uncompressed=True)) as enc, StreamDecoder() as dec:
        out = dec.decode(enc.encode(f))
    for a, b in zip(_cams(f), _cams(out)):
        assert np.array_equal(a.color, b.color)
        assert np.array_equal(a.depth, b.depth, equal_nan=True)
        for name in ("motion_fwd", "motion_bwd"):
            ma, mb = getattr(a, name), getattr(b, name)
            assert (ma is None) == (mb is None)
            if ma is not None:
                assert np.array_equal(ma, mb)
        for name in ("shadow_fwd", "shadow_bwd"):
            sa, sb = getattr(a, name), getattr(b, name)
            for x in ("bits", "s_min", "s_max"):
                assert np.array_equal(getattr(sa, x), getattr(sb, x))


def _assert_same_frame(a: sr.ServerFrame, b: sr.ServerFrame) -> None:
    for x, y in zip(_cams(a), _cams(b), strict=True):
        assert np.array_equal(x.color, y.color)
        assert np.array_equal(x.depth, y.depth, equal_nan=True)
        for d in ("fwd", "bwd"):
            mx, my = getattr(x, f"motion_{d}"), getattr(y, f"motion_{d}")
            assert np.array_equal(mx, my, equal_nan=True)
            sx, sy = getattr(x, f"shadow_{d}"), getattr(y, f"shadow_{d}")
            for f in ("bits", "s_min", "s_max"):
                assert np.array_equal(getattr(sx, f), getattr(sy, f))


def test_decoding_starts_at_any_key_frame(
    coded: tuple[list[bytes], list[sr.ServerFrame]],
) -> None:
    """A decoder started at key frame 6 gives the same frames, every buffer bit for bit, as the
    one that decoded 0..11 and kept its HEVC decoders across the key frame; so does a decoder
    that resumes at frame 6 after a packet that failed."""
    packets, decoded = coded
    assert [unpack_packet(p).key for p in packets] == [i % 6 == 0 for i in range(N)]
    with StreamDecoder() as dec:
        late = [dec.decode(p) for p in packets[6:]]
    with StreamDecoder() as dec:
        dec.decode(packets[0])
        with pytest.raises(StreamError):
            # colour and shadow decode frame 1, then its geometry fails
            dec.decode(_replace_payload(packets[1], "picture.geometry", b"\x00\x00\x01xx" * 9))
        resumed = [dec.decode(p) for p in packets[6:]]
    for a, b, c in zip(decoded[6:], late, resumed):
        _assert_same_frame(a, b)
        _assert_same_frame(a, c)
    with (
        StreamDecoder() as dec,
        pytest.raises(StreamError, match="frame 7: not a key frame"),
    ):
        dec.decode(packets[7])
    # A key frame asked for between the regular ones (the live server's): x265 is not reopened
    # there (the regular one at 6 reopened every encoder, which starts with an IDR anyway), so
    # only the forced IDR lets a decoder start at it.
    scene = sr.SyntheticScene(dynamic=True)
    src = [scene.server_frame(i, i / 10, W, H) for i in range(4)]
    with StreamEncoder(CodecConfig(bitrate_mbps=BITRATE, gop=100)) as enc:
        forced = []
        for i, f in enumerate(src):
            if i == 2:
                enc.request_key_frame()
            forced.append(enc.encode(f))
    assert [unpack_packet(p).key for p in forced] == [True, False, True, False]
    with StreamDecoder() as dec:
        whole = [dec.decode(p) for p in forced]
    with StreamDecoder() as dec:
        for a, p in zip(whole[2:], forced[2:]):
            _assert_same_frame(a, dec.decode(p))
    with StreamDecoder() as dec:
        dec.decode(packets[0])
        with pytest.raises(StreamError, match="frame 2: not a key frame"):
            dec.decode(packets[2])  # frame 1 was skipped


def _replace_payload(packet: bytes, name: str, payload: bytes) -> bytes:
    p = unpack_packet(packet)
    bufs = tuple(
        dataclasses.replace(b, payload=payload) if b.name == name else b
        for b in p.buffers
    )
    assert any(b.name == name for b in p.buffers)
    return pack_packet(dataclasses.replace(p, buffers=bufs))  # CRCs made consistent


@pytest.mark.parametrize(
    ("name", "payload", "message"),
    [
        (
            "picture.color",
            b"\x00\x00\x01garbage" * 20,
            "picture.color: HEVC payload of 200 bytes",
        ),
        ("picture.geometry", b"", "picture.geometry: HEVC payload of 0 bytes"),
        (
            "picture.shadow",
            b"\x00\x00\x01garbage" * 10,
            "picture.shadow: HEVC payload of 100 bytes",
        ),
        (
            "main.shadow_fwd.bits",
            b"not zstd at all",
            "main.shadow_fwd.bits: zstd payload",
        ),
        (
            "aux1.motion_bwd.static",
            b"\x28\xb5\x2f\xfd" + b"\xff" * 12,
            "aux1.motion_bwd.static: zstd",
        ),
    ],
)
@pytest.mark.parametrize("threads", [1, 2])
def test_undecodable_payloads_raise_stream_error(
    coded: tuple[list[bytes], list[sr.ServerFrame]],
    name: str,
    payload: bytes,
    message: str,
    threads: int,
) -> None:
    # With two threads the geometry picture's worker waits for the lossless masks that this
    # thread unpacks, and this thread decodes the shadow picture: an error in either must reach
    # the caller (not leave the worker waiting), and the decoder go on at the next key frame.
    packets, decoded = coded
    bad = _replace_payload(packets[0], name, payload)
    with StreamDecoder(threads=threads) as dec:
        with pytest.raises(StreamError, match=f"frame 0, {message}"):
            dec.decode(bad)
        again = dec.decode(packets[0])
        assert all(x.tobytes() == y.tobytes()
                   for x, y in zip(_arrays(again), _arrays(decoded[0]), strict=True))


def _zstd_frame(raw: bytes) -> bytes:
    import zstandard

    return zstandard.ZstdCompressor(write_content_size=True).compress(raw)


def _bits_payload(n: int, values: bytes, set_pixels: int = 2) -> bytes:
    """A main-camera (160x90) shadow bitfield payload: value width ``n``, the first
    ``set_pixels`` pixels set, then ``values``."""
    mask = np.zeros(W * H, bool)
    mask[:set_pixels] = True
    return _zstd_frame(bytes([n]) + np.packbits(mask).tobytes() + values)


@pytest.mark.parametrize(
    ("name", "payload", "message"),
    [
        # a mask one byte short of its 80x45 camera's 450
        ("aux1.motion_bwd.static", _zstd_frame(bytes(449)), "mask of 449 bytes, expected 450"),
        # one value byte for two set pixels
        ("main.shadow_fwd.bits", _bits_payload(1, b"\x07"),
         "shadow bitfield payload holds 1 value bytes for 2 pixels of 1 bytes"),
        # a set pixel whose bitfield is 0
        ("main.shadow_fwd.bits", _bits_payload(1, b"\x07\x00"),
         "shadow bitfield payload stores a zero for a set pixel"),
        ("main.shadow_fwd.bits", _bits_payload(5, b"\x07" * 10), "malformed shadow bitfield"),
    ],
    ids=["short_mask", "too_few_value_bytes", "zero_value", "value_width_5"],
)
def test_malformed_lossless_payloads_raise_stream_error(
    coded: tuple[list[bytes], list[sr.ServerFrame]], name: str, payload: bytes, message: str
) -> None:
    """zstd frames that decompress within their limit but do not hold what their buffer needs:
    each a StreamError naming the frame, the buffer and what is wrong."""
    packets, _ = coded
    with (
        StreamDecoder() as dec,
        pytest.raises(StreamError, match=f"^frame 0, {name}: {message}"),
    ):
        dec.decode(_replace_payload(packets[0], name, payload))


def test_packet_holds_three_pictures_and_tiles(
    coded: tuple[list[bytes], list[sr.ServerFrame]],
) -> None:
    """Since stream format 3: every lossy buffer of every camera is a payload-less tile of one of
    three HEVC pictures (version 2 sent 24 HEVC streams, whose decoding cost ~3x as long)."""
    packets, _ = coded
    for packet in packets:
        p = unpack_packet(packet)
        hevc = [b.name for b in p.buffers if b.codec == Codec.HEVC]
        assert hevc == ["picture.color", "picture.geometry", "picture.shadow"]
        tiles = [b for b in p.buffers if b.codec == Codec.TILE]
        assert len(tiles) == 3 * 8 and all(len(b.payload) == 0 for b in tiles)


def _small_hevc_picture(side: int) -> bytes:
    """One HEVC key picture of ``side`` x ``side`` pixels, 4:2:0, as libx265 codes it."""
    from fractions import Fraction

    import av

    enc = av.CodecContext.create("libx265", "w")
    enc.width, enc.height, enc.pix_fmt = side, side, "yuv420p"
    enc.time_base = Fraction(1, 10)
    enc.options = {"x265-params": "log-level=none:bframes=0", "tune": "zerolatency"}
    frame = av.VideoFrame.from_ndarray(np.zeros((side, side, 3), np.uint8), format="rgb24")
    frame = frame.reformat(format="yuv420p")
    frame.pts = 0
    return b"".join(bytes(p) for p in [*enc.encode(frame), *enc.encode(None)])


def test_an_encoder_needs_a_camera_share_per_camera(frames: list[sr.ServerFrame]) -> None:
    # Two shares for three cameras would leave a camera without a bit-rate share.
    with StreamEncoder(CodecConfig(camera_shares=(0.5, 0.5))) as enc:
        with pytest.raises(sr.InvalidInputError, match="^frame 0: 3 cameras but 2 camera shares "
                                                       "in the CodecConfig$"):
            enc.encode(frames[0])


def test_each_check_of_a_packets_buffers_says_what_is_wrong(
    frames: list[sr.ServerFrame], coded: tuple[list[bytes], list[sr.ServerFrame]],
) -> None:
    """The decoder's own checks of a packet the stream format takes (CRCs consistent, as a
    hostile producer writes them), each met by a packet only it refuses."""
    packets, _ = coded
    p = unpack_packet(packets[0])
    main = p.cameras[0]

    def refused(packet: bytes, message: str, **decoder: Any) -> None:
        with StreamDecoder(**decoder) as dec, pytest.raises(StreamError, match=message):
            dec.decode(packet)

    def replaced(name: str, **changes: Any) -> bytes:
        assert any(b.name == name for b in p.buffers)
        return pack_packet(dataclasses.replace(p, buffers=tuple(
            dataclasses.replace(b, **changes) if b.name == name else b for b in p.buffers)))

    pixels = main.width * main.height
    refused(packets[0], f"^frame 0, main: {main.width}x{main.height} exceeds the decoder's "
                        f"limit of {pixels - 1} pixels$", max_pixels=pixels - 1)
    # The limit bounds the cameras together too (the pictures hold them all): at it a packet
    # decodes, one pixel below it is refused.
    total = sum(c.width * c.height for c in p.cameras)
    refused(packets[0], f"^frame 0: the cameras hold {total} pixels together, beyond the "
                        f"decoder's limit of {total - 1}$", max_pixels=total - 1)
    with StreamDecoder(max_pixels=total) as dec:
        assert dec.decode(packets[0]).index == 0
    refused(pack_packet(dataclasses.replace(p, buffers=p.buffers + p.buffers[-1:])),
            "^frame 0, picture.shadow: buffer appears twice$")
    # A shadow colour tile whose bitfield is stored raw (the right size for it): the tile
    # is decoded with the bitfield's zstd form only.
    refused(replaced("main.shadow_fwd.bits", codec=Codec.RAW, payload=bytes(4 * pixels)),
            "^frame 0, main.shadow_fwd.s_min: a tile needs its bitfield as zstd$")
    # A shadow colour tile of a packet without the shadow picture it is a tile of.
    refused(pack_packet(dataclasses.replace(p, buffers=tuple(
        b for b in p.buffers if b.name != "picture.shadow"))),
        "^frame 0, main.shadow_fwd.s_min: a tile of picture.shadow, which the packet does "
        "not hold$")
    # A mask (one byte a pixel would be its raw form) is decoded from zstd only.
    refused(replaced("main.motion_fwd.static", codec=Codec.RAW, payload=bytes(pixels)),
            "^frame 0, main.motion_fwd.static: a mask cannot be raw$")
    # A picture smaller than the packet's cameras need decodes in FFmpeg; it is refused here.
    # (The layout's size, not a camera's: the shadow colours of every camera side by side.)
    refused(replaced("picture.shadow", payload=_small_hevc_picture(32)),
            r"^frame 0, picture.shadow: HEVC picture is 32x32 yuv420p, expected \d+x\d+ yuv")
    # A raw buffer one byte short (the uncompressed mode stores every buffer raw).
    with StreamEncoder(CodecConfig(uncompressed=True)) as enc:
        raw = unpack_packet(enc.encode(frames[0]))
    color = raw.buffers[0]
    assert color.name == "main.color" and color.codec == Codec.RAW
    short = dataclasses.replace(color, payload=bytes(color.payload)[:-1])
    refused(pack_packet(dataclasses.replace(raw, buffers=(short, *raw.buffers[1:]))),
            f"^frame 0, main.color: raw payload of {len(color.payload) - 1} bytes, expected "
            f"{len(color.payload)}$")


def test_tile_without_its_picture_raises(
    coded: tuple[list[bytes], list[sr.ServerFrame]],
) -> None:
    packets, _ = coded
    p = unpack_packet(packets[0])
    bufs = tuple(b for b in p.buffers if b.name != "picture.shadow")
    with (
        StreamDecoder() as dec,
        pytest.raises(
            StreamError,
            match="frame 0, main.shadow_fwd.s_min: a tile of picture.shadow, which the "
            "packet does not hold",
        ),
    ):
        dec.decode(pack_packet(dataclasses.replace(p, buffers=bufs)))


@pytest.mark.parametrize(
    ("side", "message"),
    [
        # (a side beyond MAX_SIDE as well: test_a_picture_longer_than_a_side_is_refused_...)
        (16384, "a 16400x16384 picture for these cameras exceeds the decoder's limit of "
         f"{4 * (1 << 25) + (1 << 16)} pixels"),
        # every side within MAX_SIDE: only the pixel bound refuses it
        (16000, "a 16016x16000 picture for these cameras exceeds the decoder's limit of "
         f"{4 * (1 << 25) + (1 << 16)} pixels"),
    ],
)
def test_picture_of_odd_cameras_refused_before_decoding(side: int, message: str) -> None:
    """Two cameras within the per-camera and total pixel limits whose shapes (16 x side and
    side x 16) would make a picture of about side x side: refused by its pixels (more than four
    times the decoder's limit) before FFmpeg allocates it, whether or not a side is too long."""
    from splitrender.codec.stream import BufferEntry, CameraRecord, Packet

    eye = np.eye(4)
    cams = (CameraRecord(eye, eye, 16, side), CameraRecord(eye, eye, side, 16))
    bufs = (
        BufferEntry(0, BufferKind.COLOR, Codec.TILE, 3, 16, side, b""),
        BufferEntry(1, BufferKind.COLOR, Codec.TILE, 3, side, 16, b""),
        BufferEntry(0, BufferKind.PICTURE_COLOR, Codec.HEVC, 1, 16, side, b"x"),
    )
    packet = pack_packet(Packet(0, 0.0, True, False, cams, bufs))
    with (
        StreamDecoder() as dec,
        pytest.raises(StreamError, match=f"^frame 0, picture.color: {message}"),
    ):
        dec.decode(packet)


def test_a_picture_longer_than_a_side_is_refused_by_both_ends() -> None:
    """Cameras two pixels tall tile into one row: a 32768-pixel geometry picture, which the
    encoder had written and the decoder then refused at every packet, naming a tile offset
    (InvalidInputError, not the stream's error). Now the encoder refuses the first frame and
    the decoder the packet, each naming the picture's size."""
    from splitrender.codec.stream import BufferEntry, CameraRecord, Packet

    frame = sr.SyntheticScene(dynamic=True).server_frame(0, 0.0, 4096, 2)
    with (
        StreamEncoder(CodecConfig(bitrate_mbps=BITRATE)) as enc,
        pytest.raises(InvalidInputError, match="picture.geometry would be 32768x32, beyond "
                      "the codec's 16384 pixels a side"),
    ):
        enc.encode(frame)
    eye = np.eye(4)
    cams = tuple(CameraRecord(eye, eye, w, h) for w, h in ((4096, 2), (2048, 1), (2048, 1)))
    bufs = (BufferEntry(0, BufferKind.PICTURE_GEOMETRY, Codec.HEVC, 1, 4096, 2, b"x"),)
    packet = pack_packet(Packet(0, 0.0, True, False, cams, bufs))
    with (
        StreamDecoder() as dec,
        pytest.raises(StreamError, match="picture.geometry: a 32768x32 picture for these "
                      "cameras; expected at most 16384 pixels a side"),
    ):
        dec.decode(packet)


@pytest.mark.parametrize("size", [(1024, 1), (1, 1024), (2048, 8)])
def test_long_thin_cameras_round_trip(size: tuple[int, int]) -> None:
    """Their pictures are 8192 pixels long and 16 short, which x265 refused to open (a side
    beyond 4208 is HEVC level 5, whose coding tree units are 32 or more): such pictures are
    made 32 short, and the frame round-trips."""
    frame = sr.SyntheticScene(dynamic=True).server_frame(0, 0.0, *size)
    with StreamEncoder(CodecConfig(bitrate_mbps=BITRATE)) as enc, StreamDecoder() as dec:
        out = dec.decode(enc.encode(frame))
    assert out.main.color.shape == frame.main.color.shape
    assert _psnr(out.main.color, frame.main.color) > 25


@pytest.mark.parametrize(
    ("sizes", "expected"),
    [
        (
            ((1280, 720), (640, 360), (640, 360)),
            (
                (1920, 720),
                # columns of 736: depth 1280; 2 aux depths and 6 main motion tiles (640x360,
                # two to a column: 4 columns of 640); 12 aux motion tiles in 320x184 slots
                # (on the 8-pixel grid: four to a column, 3 columns). At 720 (format 3) only
                # three fitted: 5120x720, 4 % more samples.
                (4800, 736),
                # format 4's half-size shadow colours: 4 main tiles of 640x360 and 8 aux
                # ones in 320x184 slots, two to a column of 368 (one at 360: 5120x360)
                (3840, 368),
            ),
        ),
        # The evaluation's 640x360 rig: the aux colour tiles (320x184 slots) stack in 368.
        (((640, 360), (320, 180), (320, 180)), ((960, 368), (2400, 384), (1920, 192))),
    ],
)
def test_picture_layout(
    sizes: tuple[tuple[int, int], ...], expected: tuple[tuple[int, int], ...]
) -> None:
    """Tiles for the server's rigs: on the 8-pixel grid, never overlapping, in the column
    height that gives the fewest samples (for 1280x720 + 2 x 640x360 the colour picture has no
    gap)."""
    from splitrender.codec.coder import _layout

    pictures = (BufferKind.PICTURE_COLOR, BufferKind.PICTURE_GEOMETRY, BufferKind.PICTURE_SHADOW)
    for pic, size in zip(pictures, expected):
        tiles, pw, ph = _layout(pic, sizes)
        assert (pw, ph) == size
        cover = np.zeros((ph, pw), np.int32)
        for t in tiles.values():
            assert t.x % 8 == 0 and t.y % 8 == 0
            cover[t.y : t.y + t.h, t.x : t.x + t.w] += 1
        assert cover.max() == 1


def test_layout_of_odd_rigs_covers_each_tile_once_in_fewest_samples() -> None:
    """Random rigs of 1-16 cameras: every tile inside its picture, on the 8-pixel grid, none
    overlapping, and the picture no larger than with columns as tall as the tallest slot
    (format 3's rule, always among the heights tried)."""
    from splitrender.codec.coder import _aligned, _layout, _place, _tiles
    from splitrender.codec.stream import PICTURE_KINDS

    rng = np.random.default_rng(4)
    for _ in range(20):
        n = int(rng.integers(1, 17))
        sizes = tuple(
            (int(rng.integers(1, 700)), int(rng.integers(1, 400))) for _ in range(n)
        )
        for pic in PICTURE_KINDS:
            tiles, pw, ph = _layout(pic, sizes)
            assert len(tiles) == len(_tiles(pic, sizes))
            cover = np.zeros((ph, pw), np.int32)
            for t in tiles.values():
                assert t.x % 8 == 0 and t.y % 8 == 0
                assert t.x + t.w <= pw and t.y + t.h <= ph
                cover[t.y : t.y + t.h, t.x : t.x + t.w] += 1
            assert cover.max() == 1
            ordered = sorted(_tiles(pic, sizes), key=lambda t: -t.h)
            low = _aligned(ordered[0].h)
            _, width = _place(ordered, low)
            assert pw * ph <= max(16, width) * max(16, low)


def test_zstd_bomb_rejected(coded: tuple[list[bytes], list[sr.ServerFrame]]) -> None:
    import zstandard

    packets, _ = coded
    bomb = zstandard.ZstdCompressor(level=3).compress(b"\0" * (1 << 24))
    bad = _replace_payload(packets[0], "main.shadow_fwd.bits", bomb)
    with (
        StreamDecoder() as dec,
        pytest.raises(StreamError, match="main.shadow_fwd.bits: zstd payload declares"),
    ):
        dec.decode(bad)


def test_a_zstd_payload_without_its_size_is_named_so(
    coded: tuple[list[bytes], list[sr.ServerFrame]],
) -> None:
    # The message said "declares -1 bytes" (zstandard's code for a size left out).
    import zstandard

    packets, _ = coded
    unsized = zstandard.ZstdCompressor(write_content_size=False).compress(b"\0" * 64)
    assert zstandard.frame_content_size(unsized) == -1
    bad = _replace_payload(packets[0], "main.shadow_fwd.bits", unsized)
    with (
        StreamDecoder() as dec,
        pytest.raises(StreamError, match="main.shadow_fwd.bits: zstd payload does not declare "
                      r"its size \(expected a frame that declares it, at most \d+ bytes\)"),
    ):
        dec.decode(bad)


def test_truncated_packet_raises(
    coded: tuple[list[bytes], list[sr.ServerFrame]],
) -> None:
    packets, _ = coded
    with StreamDecoder() as dec:
        for cut in (0, 31, 500, len(packets[0]) - 1):
            with pytest.raises(StreamError):
                dec.decode(packets[0][:cut])


def test_a_second_thread_encoding_at_once_is_refused(frames: list[sr.ServerFrame]) -> None:
    """Two frames encoded at once would drive the same x265 encoders from two threads (the
    process crashed, or hung): the second call is refused, and the first completes."""
    import threading

    entered, release = threading.Event(), threading.Event()
    with StreamEncoder(CodecConfig(bitrate_mbps=BITRATE)) as enc:
        check = enc._check_layout

        def held_check(frame: sr.ServerFrame) -> None:  # the first call waits inside encode
            entered.set()
            assert release.wait(30)
            check(frame)

        enc._check_layout = held_check  # type: ignore[method-assign]
        out: list[bytes] = []
        first = threading.Thread(target=lambda: out.append(enc.encode(frames[0])))
        first.start()
        assert entered.wait(30)
        with pytest.raises(InvalidInputError, match="encoding a frame in another thread"):
            enc.encode(frames[1])
        release.set()
        first.join(30)
        assert len(out) == 1 and out[0]
        enc._check_layout = check  # type: ignore[method-assign]
        assert enc.encode(frames[1])  # the next frame in order, on this thread


def test_layout_change_is_invalid_input(frames: list[sr.ServerFrame]) -> None:
    scene = sr.SyntheticScene(dynamic=True)
    with StreamEncoder(CodecConfig(bitrate_mbps=BITRATE)) as enc:
        enc.encode(frames[0])
        with pytest.raises(InvalidInputError, match="camera sizes"):
            enc.encode(scene.server_frame(1, 0.1, W * 2, H * 2))
    with pytest.raises(InvalidInputError):
        CodecConfig(color_share=0.9)
    with pytest.raises(InvalidInputError):
        CodecConfig(chroma="422")


@pytest.mark.parametrize(
    ("field", "value"),
    [
        # 1e300 Mb/s reached x265 as kb/s and raised OverflowError.
        ("bitrate_mbps", 1e300),
        ("bitrate_mbps", 100_001.0),
        ("fps", 1e300),
        # 1e-300 fps became a Fraction of denominator 0 for libav: ZeroDivisionError.
        ("fps", 1e-300),
        ("vbv_buffer_s", 1e300),
        ("bitrate_mbps", float("nan")),
        ("fps", True),
    ],
)
def test_codec_config_bounds(field: str, value: float) -> None:
    with pytest.raises(InvalidInputError, match=f"CodecConfig.{field}: expected a "):
        CodecConfig(**{field: value})
    assert CodecConfig(bitrate_mbps=100_000.0, fps=1000.0, vbv_buffer_s=60.0).fps == 1000.0


def test_codec_config_takes_numpy_scalars_as_floats() -> None:
    # Every other float check of the package took them; this one refused np.float32(2.0).
    cfg = CodecConfig(bitrate_mbps=np.float32(2.0), fps=np.int64(10), vbv_buffer_s=np.float64(0.5))
    assert (cfg.bitrate_mbps, cfg.fps, cfg.vbv_buffer_s) == (2.0, 10.0, 0.5)
    assert all(type(v) is float for v in (cfg.bitrate_mbps, cfg.fps, cfg.vbv_buffer_s))


def test_codec_config_takes_numpy_integers_as_ints_and_chroma_as_a_str() -> None:
    # gop=np.int64(5) stayed a numpy integer; chroma=420 said "expected '444' or '420', got 420".
    cfg = CodecConfig(gop=np.int64(5), zstd_level=np.int32(3), threads=np.uint8(2))
    assert all(type(v) is int for v in (cfg.gop, cfg.zstd_level, cfg.threads))
    assert (cfg.gop, cfg.zstd_level, cfg.threads) == (5, 3, 2)
    with pytest.raises(InvalidInputError, match="^CodecConfig.chroma: expected a str, got int"):
        CodecConfig(chroma=420)  # type: ignore[arg-type]


def test_a_frame_that_is_not_a_key_frame_keeps_the_camera_sizes() -> None:
    # A packet of other cameras after frame 1 failed as "picture.shadow: HEVC payload of 505
    # bytes did not decode (0 pictures)" (its pictures predict from pictures of another
    # layout), which named neither the cause nor the rule; at a key frame the layout may change.
    scene = sr.SyntheticScene(dynamic=True)

    def packets(w: int, h: int) -> list[bytes]:
        with StreamEncoder(CodecConfig(bitrate_mbps=0.5, gop=100)) as enc:
            return [enc.encode(scene.server_frame(i, i / 10, w, h)) for i in range(2)]

    small, other = packets(32, 18), packets(48, 28)
    follow = pack_packet(dataclasses.replace(unpack_packet(other[1]), index=2, time=0.2))
    with StreamDecoder(threads=1) as dec:
        dec.decode(small[0])
        dec.decode(small[1])
        with pytest.raises(StreamError, match=(
                "^frame 2: camera sizes 48x28, 24x14, 24x14 differ from frame 1's 32x18, "
                "16x9, 16x9; the cameras may change only at a key frame$")):
            dec.decode(follow)
        assert dec.decode(other[0]).main.color.shape == (28, 48, 3)  # a key frame
        assert dec.decode(other[1]).main.color.shape == (28, 48, 3)


def _without_shadows(f: sr.ServerFrame, cams: set[int]) -> sr.ServerFrame:
    """``f`` with the shadow bitfields of ``cams`` all zero (no moving shadows there)."""
    def strip(ci: int, cf: sr.CameraFrame) -> sr.CameraFrame:
        if ci not in cams:
            return cf
        return dataclasses.replace(cf, **{
            f"shadow_{d}": dataclasses.replace(s, bits=np.zeros_like(s.bits))
            for d in ("fwd", "bwd") if (s := getattr(cf, f"shadow_{d}")) is not None})
    main, *aux = (strip(ci, cf) for ci, cf in enumerate(_cams(f)))
    return dataclasses.replace(f, main=main, aux=tuple(aux))


def _encode(
    frames: list[sr.ServerFrame], **cfg: Any
) -> tuple[list[bytes], list[tuple[int, ...]]]:
    with StreamEncoder(CodecConfig(bitrate_mbps=BITRATE, gop=6, **cfg)) as enc:
        packets, left = [], []
        for f in frames:
            packets.append(enc.encode(f))
            left.append(enc.last.shadows_left_out)
    return packets, left


def test_shadow_bitfields_beyond_the_lossless_share_are_coded_as_no_shadows(
    frames: list[sr.ServerFrame], coded: tuple[list[bytes], list[sr.ServerFrame]]
) -> None:
    """With no room for lossless parts (``lossless_share=0``) every camera's shadow bitfields
    are left out, auxiliary cameras first, and each packet is byte for byte the packet of the
    same frame without moving shadows in those cameras; with room (the default at this rate)
    nothing is left out and the packets are those of a share of 1."""
    with_bits = [ci for ci, cf in enumerate(_cams(frames[0]))
                 if any(s is not None and s.bits.any() for s in (cf.shadow_fwd, cf.shadow_bwd))]
    assert with_bits, "the synthetic scene should have moving shadows"
    packets, left = _encode(frames, lossless_share=0.0)
    assert left[0] == tuple(sorted(with_bits, key=lambda ci: (ci == 0, -ci)))
    stripped = [_without_shadows(f, set(ls)) for f, ls in zip(frames, left)]
    assert packets == _encode(stripped, lossless_share=0.0)[0]
    with StreamDecoder() as dec:
        for p, ls in zip(packets, left):
            decoded = _cams(dec.decode(p))
            for ci in ls:
                for s in (decoded[ci].shadow_fwd, decoded[ci].shadow_bwd):
                    assert s is not None and not s.bits.any()
    default, left_default = _encode(frames)
    assert not any(left_default)
    assert default == coded[0] == _encode(frames, lossless_share=1.0)[0]


def test_the_main_cameras_bitfields_go_only_after_the_auxiliary_ones(
    frames: list[sr.ServerFrame],
) -> None:
    """Every share leaves out a prefix of (last auxiliary camera, …, main camera), and a cap
    just below the frame's lossless cost (found by bisection to ~10 bytes, less than any
    camera's bitfields here) leaves out only the last auxiliary camera's."""
    def left(share: float) -> tuple[int, ...]:
        lo = _encode(frames[:1], lossless_share=share)[1][0]
        assert lo == (2, 1, 0)[: len(lo)], (share, lo)
        return lo

    lo, hi = 0.0, 0.1
    assert left(lo) == (2, 1, 0) and left(hi) == ()
    for _ in range(8):
        mid = (lo + hi) / 2
        lo, hi = (mid, hi) if left(mid) else (lo, mid)
    assert left(lo) == (2,)


@pytest.mark.parametrize("value", [-0.1, 1.5, float("nan"), "x"])
def test_lossless_share_is_a_fraction(value: object) -> None:
    with pytest.raises(InvalidInputError, match="CodecConfig.lossless_share"):
        CodecConfig(lossless_share=value)  # type: ignore[arg-type]


@pytest.mark.slow
@pytest.mark.parametrize("paper_mbps", [20.0, 40.0, 80.0])
def test_bitrate_within_ten_percent(paper_mbps: float) -> None:
    """20 frames at 640x360 (two GOPs), the paper's 20/40/80 Mb/s scaled by pixel count
    (1.25/2.5/5 Mb/s): the whole stream, headers included, within ±10 % of the target (issue
    13's requirement) and within twice the worst error measured with stream format 4 (+1.1 %,
    -0.6 %, -2.6 %): ±5.2 %. Without the correction for the stream's shortfall so far the
    rate control gave -0.8 %, -4.7 %, -9.9 %, inside ±10 %. (Format 3: +0.7 %, -0.4 %, -2.2 %;
    format 2's 24 HEVC streams: +7.1 %, +2.9 %, -0.4 %.)"""
    w, h = 640, 360
    scene = sr.SyntheticScene(dynamic=True)
    cfg = CodecConfig.scaled(w, h, paper_mbps)
    with StreamEncoder(cfg) as enc:
        packets = [enc.encode(scene.server_frame(i, i / 10, w, h)) for i in range(20)]
    got = stream_stats(packets, cfg.fps).mbps_total()
    assert abs(got / cfg.bitrate_mbps - 1) <= 0.052, (got, cfg.bitrate_mbps)


def test_ours_on_decoded_close_to_uncompressed() -> None:
    """`ours` at client time 7/120 s between frames 0 and 1 of the dynamic scene, 320x180, at
    the default bitrate (the paper's 40 Mb/s scaled by pixel count: 0.625 Mb/s). Mean absolute
    error against ground truth (0..255), measured: uncompressed 5.94, decoded 14.88 (stream
    format 3: 16.27, format 2: 17.0); the codec's own colour error at this rate is about as large (the synthetic
    scene's fine procedural texture is hard to code at 0.2 bit per pixel). Asserted: decoded
    <= 20 and <= uncompressed + 13."""
    w, h = 320, 180
    scene = sr.SyntheticScene(dynamic=True)
    src = [scene.server_frame(i, i / 10, w, h) for i in range(2)]
    with StreamEncoder(CodecConfig.scaled(w, h)) as enc, StreamDecoder() as dec:
        dec_frames = [dec.decode(enc.encode(f)) for f in src]
    t = 7 / 120
    camera, _ = scene.rig(t, w, h)
    req = sr.ClientRequest(camera, t)
    gt = scene.ground_truth(camera, t).astype(np.float64)
    mae_raw = np.abs(sr.reproject(src[0], src[1], req, "ours") - gt).mean()
    mae_dec = np.abs(
        sr.reproject(dec_frames[0], dec_frames[1], req, "ours") - gt
    ).mean()
    print(
        f"ours MAE vs ground truth: uncompressed {mae_raw:.2f}, decoded {mae_dec:.2f}"
    )
    assert mae_dec <= 20 and mae_dec <= mae_raw + 13


# --------------------------------------------------------------------------------------------
# The dequantisation kernels the decoder calls (reproj_core::dequant)


def test_dequantised_motion_is_the_float32_formula_with_masks_applied() -> None:
    from splitrender import _native

    rng = np.random.default_rng(3)
    w, h = 7, 5  # odd sides: the last half-size code covers one column / row
    hw, hh = 4, 3
    codes = rng.integers(0, 4096, (3 * hh + 2, hw + 3), dtype=np.uint16)
    tiles = [(1, c * hh) for c in range(3)]
    scale, offset = (0.01, 0.5, 2.0), (-1.25, -3.0, 7.0)
    static = rng.random((h, w)) < 0.3
    invalid = rng.random((h, w)) < 0.2
    m = _native.dequantise_motion(codes, tiles, w, h, scale, offset, static, invalid)
    want = np.empty((h, w, 3), np.float32)
    for c, (x, y) in enumerate(tiles):
        half = codes[y : y + hh, x : x + hw].astype(np.float32) * np.float32(scale[c])
        half += np.float32(offset[c])
        want[..., c] = np.repeat(np.repeat(half, 2, 0), 2, 1)[:h, :w]
    want[static] = 0.0
    want[invalid] = np.nan
    assert np.array_equal(m, want, equal_nan=True)
    zeros = m[static & ~invalid]
    assert not np.signbit(zeros).any(), "static motion is +0.0, not -0.0"


def test_dequantisation_refuses_a_tile_outside_its_plane() -> None:
    from splitrender import _native

    codes = np.zeros((8, 8), np.uint16)
    with pytest.raises(InvalidInputError, match="motion tile 2"):
        _native.dequantise_motion(codes, [(0, 0), (0, 4), (0, 6)], 8, 8, (1, 1, 1), (0, 0, 0))
    with pytest.raises(InvalidInputError, match="depth tile"):
        _native.dequantise_depth(codes, 4, 0, 8, 8, 1.0, 0.0)
    with pytest.raises(InvalidInputError, match="invalid_mask"):
        _native.dequantise_depth(codes, 0, 0, 8, 8, 1.0, 0.0, np.zeros((4, 4), bool))
    luma, chroma = np.zeros((8, 8), np.uint8), np.zeros((4, 4), np.uint8)
    with pytest.raises(InvalidInputError, match="shadow tile"):
        _native.shadow_colour(luma, chroma, chroma, 1, 0, np.ones((8, 8), np.uint32))
    # Half size: a 9x9 camera needs 5x5 samples, which do not fit from (4, 0).
    with pytest.raises(InvalidInputError, match="shadow tile: 5x5 at"):
        _native.shadow_colour(luma, chroma, chroma, 4, 0, np.ones((9, 9), np.uint32), half=True)
    _native.shadow_colour(luma, chroma, chroma, 3, 0, np.ones((9, 9), np.uint32), half=True)


def test_half_size_shadow_colour_is_the_full_size_one_of_repeated_samples() -> None:
    """Stream format 4's shadow tiles: a pixel takes the sample of its 2x2 block, i.e. the
    conversion of planes whose every sample is repeated 2x2 (odd camera sizes included)."""
    from splitrender import _native

    rng = np.random.default_rng(9)
    luma = rng.integers(0, 256, (8, 8), np.uint8)
    chroma = [rng.integers(0, 256, (4, 4), np.uint8) for _ in range(2)]
    bits = (rng.random((5, 7)) < 0.6).astype(np.uint32)  # 5x7 camera: 3x4 samples
    half = _native.shadow_colour(luma, *chroma, 2, 4, bits, half=True)
    up = [np.repeat(np.repeat(p, 2, 0), 2, 1) for p in (luma, *chroma)]
    full = _native.shadow_colour(up[0], up[1], up[2], 4, 8, bits)
    assert np.array_equal(half, full) and (half[bits == 0] == 0).all()


def test_block_mean_is_the_mean_of_the_weighted_pixels_of_each_2x2_block() -> None:
    """The encoder's half-size motion and shadow colours (reproj_core::quant::block_mean)
    against numpy's reduction that computed them before: the same bytes, odd sides padded,
    NaN only where a weighted pixel is NaN, and float64 sums (f32 MAX four times)."""
    from splitrender import _native

    def numpy_block_mean(a: np.ndarray, weight: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        h, w = weight.shape
        hh, hw = (h + 1) // 2, (w + 1) // 2
        wp = np.zeros((2 * hh, 2 * hw), np.float32)
        wp[:h, :w] = weight
        ap = np.zeros((2 * hh, 2 * hw, a.shape[2]), np.float32)
        ap[:h, :w] = np.where(weight[..., None], a, np.float32(0))
        sums = ap.reshape(hh, 2, hw, 2, -1).sum(axis=(1, 3), dtype=np.float64)
        counts = wp.reshape(hh, 2, hw, 2).sum(axis=(1, 3))
        return (sums / np.maximum(counts, 1)[..., None]).astype(np.float32), counts > 0

    rng = np.random.default_rng(12)
    for h, w, c in ((5, 7, 3), (6, 4, 3), (1, 1, 1), (9, 2, 2)):
        a = (rng.standard_normal((h, w, c)) * 100).astype(np.float32)
        a[rng.random((h, w)) < 0.2] = np.nan
        weight = (rng.random((h, w)) < 0.6) & ~np.isnan(a).any(axis=2)
        mean, on = _native.block_mean(a, weight)
        want, want_on = numpy_block_mean(a, weight)
        assert mean.shape == ((h + 1) // 2, (w + 1) // 2, c)
        assert np.array_equal(mean, want, equal_nan=True) and np.array_equal(on, want_on)
    nan_at_0 = np.ones((2, 2, 1), np.float32)
    nan_at_0[0, 0] = np.nan
    every, not_0 = np.ones((2, 2), bool), np.array([[False, True], [True, True]])
    assert np.isnan(_native.block_mean(nan_at_0, every)[0]).all()
    assert _native.block_mean(nan_at_0, not_0)[0][0, 0, 0] == 1.0
    huge = np.full((2, 2, 1), np.finfo(np.float32).max, np.float32)
    assert _native.block_mean(huge, np.ones((2, 2), bool))[0][0, 0, 0] == huge[0, 0, 0]
    with pytest.raises(InvalidInputError, match="weight"):
        _native.block_mean(np.zeros((4, 4, 3), np.float32), np.zeros((4, 5), bool))
    with pytest.raises(InvalidInputError, match="a:"):
        _native.block_mean(np.zeros((4, 4), np.float32), np.zeros((4, 4), bool))


def test_dequantisation_writes_into_out_every_value() -> None:
    """With ``out`` each kernel returns that array, holding what it returns without one, whatever
    ``out`` held before (the decoder reuses arrays of earlier frames)."""
    from splitrender import _native

    rng = np.random.default_rng(5)
    codes = rng.integers(0, 4096, (12, 10), dtype=np.uint16)
    depth = _native.dequantise_depth(codes, 1, 2, 6, 5, 0.5, -1.0)
    out = np.full((5, 6), 123.0, np.float32)
    assert _native.dequantise_depth(codes, 1, 2, 6, 5, 0.5, -1.0, None, out) is out
    assert np.array_equal(out, depth)
    tiles, args = [(0, 0), (0, 3), (5, 0)], ((0.1, 0.2, 0.3), (-1.0, 0.0, 1.0))
    motion = _native.dequantise_motion(codes, tiles, 7, 5, *args)
    out3 = np.full((5, 7, 3), np.nan, np.float32)
    assert _native.dequantise_motion(codes, tiles, 7, 5, *args, None, None, out3) is out3
    assert np.array_equal(out3, motion)
    luma, chroma = rng.integers(0, 256, (8, 8), np.uint8), rng.integers(0, 256, (4, 4), np.uint8)
    bits = (rng.random((6, 6)) < 0.5).astype(np.uint32)
    colour = _native.shadow_colour(luma, chroma, chroma, 2, 2, bits)
    out8 = np.full((6, 6, 3), 77, np.uint8)
    assert _native.shadow_colour(luma, chroma, chroma, 2, 2, bits, out8) is out8
    assert np.array_equal(out8, colour) and (out8[bits == 0] == 0).all()


@pytest.mark.parametrize(
    ("out", "message"),
    [
        (np.zeros((5, 5), np.float32), r"out: expected float32 array of shape \(5, 6\)"),
        (np.zeros((5, 6), np.float64), "out: expected float32"),
        (np.zeros((6, 5), np.float32).T, "out: expected a C-contiguous array"),
        (np.zeros((5, 6), np.float32), None),
    ],
)
def test_dequantisation_refuses_a_bad_out(out: np.ndarray, message: str | None) -> None:
    from splitrender import _native

    codes = np.zeros((12, 10), np.uint16)
    if message is None:  # a fine one, made read-only
        out.flags.writeable = False
        message = "out: cannot borrow the array for writing"
    with pytest.raises(InvalidInputError, match=message):
        _native.dequantise_depth(codes, 1, 2, 6, 5, 0.5, -1.0, None, out)


def test_dequantisation_refuses_an_out_that_overlaps_its_input() -> None:
    from splitrender import _native

    buf = np.zeros(64, np.float32)
    codes = buf.view(np.uint16).reshape(8, 16)  # the first 64 floats' bytes
    with pytest.raises(InvalidInputError, match="out: cannot borrow"):
        _native.dequantise_depth(codes, 0, 0, 2, 2, 1.0, 0.0, None, buf[:4].reshape(2, 2))


def test_decoder_reuses_released_arrays_and_never_held_ones(
    coded: tuple[list[bytes], list[sr.ServerFrame]],
) -> None:
    """The decoder writes a frame into the arrays of an earlier frame only once nothing holds
    them: frames kept by the caller stay as they decoded (compared with the fixture's decoder,
    which holds all 12), and a released frame's arrays are taken again."""
    packets, decoded = coded
    with StreamDecoder() as dec:
        held = [dec.decode(p) for p in packets[:6]]  # all held: no reuse possible
        for a, b in zip(decoded[:6], held):
            _assert_same_frame(a, b)
        last = held[-1]
        refs = [weakref.ref(a) for a in (last.main.depth, last.aux[1].motion_fwd, last.main.color)]
        del held, last, a, b  # the loop's names hold the last frame too
        again = [dec.decode(p) for p in packets[6:]]
        for a, b in zip(decoded[6:], again):
            _assert_same_frame(a, b)
        taken = [(f.main.depth, f.aux[1].motion_fwd, f.main.color) for f in again]
        for i, r in enumerate(refs):
            assert any(t[i] is r() for t in taken), "a released frame's array was not reused"
