"""`splitrender encode`: a recording of a built-in scene into a stream file and back."""

from __future__ import annotations

import threading
from pathlib import Path

import numpy as np
import pytest

import splitrender as sr
from splitrender.cli import main
import splitrender.codec.encode as encode_module
from splitrender.codec.coder import (
    CodecConfig,
    DecodedStream,
    StreamDecoder,
    StreamEncoder,
    decode_packets,
)
from splitrender.codec.encode import encode_recording
from splitrender.codec.stream import StreamFile


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("rec") / "courtyard"
    return sr.write_recording(out, "courtyard", seconds=0.25, scale=0.04)


def test_encode_round_trip_gives_every_frame_in_order(recording: Path, tmp_path: Path) -> None:
    out = tmp_path / "courtyard.srs"
    seen: list[int] = []
    stats = encode_recording(recording, out, bitrate_mbps=0.5, progress=lambda d, n: seen.append(d))
    rec = sr.load_recording(recording)
    n = len(rec.server_frames)
    assert seen == list(range(1, n + 1))
    assert stats.frames == n and out.is_file()
    assert not list(tmp_path.glob("*.partial-*"))
    frames = decode_packets(list(sr.read_stream(out)))
    assert [f.index for f in frames] == [f.index for f in rec.server_frames]
    for got, want in zip(frames, rec.server_frames):
        assert got.main.color.shape == want.main.color.shape
        assert len(got.aux) == len(want.aux)
        # Lossless parts survive exactly.
        assert got.main.shadow_fwd is not None and want.main.shadow_fwd is not None
        np.testing.assert_array_equal(got.main.shadow_fwd.bits, want.main.shadow_fwd.bits)
    # Stream format 3: colour travels in the colour picture; the tiles have no bytes of their own
    assert "picture.color" in stats.mbps_by_buffer() and "main.color" not in stats.mbps_by_buffer()
    assert stats.mbps_total() > 0


def _same_frames(got: list[sr.ServerFrame], want: list[sr.ServerFrame]) -> None:
    assert [f.index for f in got] == [f.index for f in want]
    for g, w in zip(got, want):
        for gc, wc in zip([g.main, *g.aux], [w.main, *w.aux], strict=True):
            np.testing.assert_array_equal(gc.color, wc.color)
            np.testing.assert_array_equal(gc.depth, wc.depth)


def test_decoded_stream_decodes_each_frame_when_it_is_asked_for(
    recording: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    out = tmp_path / "courtyard.srs"
    encode_recording(recording, out, bitrate_mbps=0.5)
    packets = list(sr.read_stream(out))
    assert len(packets) >= 2
    whole = decode_packets(packets)
    calls: list[int] = []
    decode = StreamDecoder.decode

    def counted(self: StreamDecoder, data: bytes) -> sr.ServerFrame:
        calls.append(1)
        return decode(self, data)

    monkeypatch.setattr(StreamDecoder, "decode", counted)
    stream = DecodedStream(packets)
    assert len(stream) == len(packets) and not calls
    it = iter(stream)
    first = next(it)
    assert len(calls) == 1  # the first frame only, not the run
    _same_frames([first, *it], whole)
    assert len(calls) == len(packets)
    # Every pass decodes anew, from the key frame, to the same frames.
    _same_frames(list(stream), whole)
    assert len(calls) == 2 * len(packets)


def test_decoded_stream_refuses_what_is_not_a_packet(recording: Path, tmp_path: Path) -> None:
    with pytest.raises(sr.InvalidInputError, match=r"packets\[1\]: expected one of bytes, bytearray"):
        DecodedStream([b"", 3])  # type: ignore[list-item]
    out = tmp_path / "courtyard.srs"
    encode_recording(recording, out, bitrate_mbps=0.5)
    packets = list(sr.read_stream(out))
    broken = DecodedStream([packets[0], packets[1][: len(packets[1]) // 2]])
    it = iter(broken)
    next(it)
    with pytest.raises(sr.StreamError):
        next(it)


def test_encode_failure_leaves_no_stream(recording: Path, tmp_path: Path) -> None:
    out = tmp_path / "broken.srs"

    def boom(done: int, total: int) -> None:
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        encode_recording(recording, out, progress=boom)
    assert list(tmp_path.iterdir()) == []


def test_encode_into_a_folder_is_refused_before_encoding(recording: Path, tmp_path: Path) -> None:
    folder = tmp_path / "streams"
    (folder / "kept.txt").parent.mkdir()
    (folder / "kept.txt").write_text("mine")
    seen: list[int] = []
    with pytest.raises(sr.InvalidInputError, match=f"^{folder}: expected a file name for the "
                       "stream, got a folder$"):
        encode_recording(recording, folder, progress=lambda d, n: seen.append(d))
    assert seen == [] and [p.name for p in folder.iterdir()] == ["kept.txt"]


def test_encode_recording_ends_its_worker_threads(recording: Path, tmp_path: Path) -> None:
    # The encoder was never closed: its worker threads outlived the call until it was collected.
    def workers() -> set[threading.Thread]:
        return {t for t in threading.enumerate() if t.name.startswith("splitrender-enc")}

    before = workers()
    encode_recording(recording, tmp_path / "s.srs", bitrate_mbps=0.5)
    assert workers() - before == set()


def _mbps(path: Path) -> float:
    f = StreamFile(path)
    return sr.stream_stats(f.packets(), f.fps).mbps_total()


def test_encode_cli(recording: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The stream is encoded at --bitrate: measured over this recording's 4 frames, 0.530 Mb/s
    for 0.5 (+6 %) and 0.114 for 0.1 (+14 %), each asserted within twice that; without it
    (the paper's 40 Mb/s scaled to the main camera) 0.084 for both. The report's total is the
    stream's."""
    rates = []
    for bitrate in ("0.5", "0.1"):
        out = tmp_path / f"s{bitrate}.srs"
        assert main(["encode", str(recording), "--bitrate", bitrate, "--out", str(out)]) == 0
        text = capsys.readouterr().out
        assert "picture.color" in text
        got = _mbps(out)
        total = [line.split() for line in text.splitlines() if line.split()[:1] == ["total"]]
        assert total == [["total", f"{got:.3f}"]], text
        rates.append(got)
    assert len(list(StreamFile(out).packets())) == 4
    assert abs(rates[0] / 0.5 - 1) <= 0.12 and abs(rates[1] / 0.1 - 1) <= 0.27, rates


def test_encode_keeps_the_recordings_server_rate(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A recording at 5 server frames per second: the stream file says 5, and the encoder's
    rate control budgets its frames at 5 per second (``CodecConfig.fps``; at 10 its packets
    were about 30 % smaller), at the given target or, without one, the paper's 40 Mb/s at
    2560x1440 scaled to the main camera by pixel count."""
    rec = sr.write_recording(tmp_path / "rec5", "courtyard", seconds=0.6, scale=0.04, fs=5.0)
    configs: list[CodecConfig] = []

    class Recorded(StreamEncoder):
        def __init__(self, config: CodecConfig | None = None) -> None:
            assert config is not None
            configs.append(config)
            super().__init__(config)

    monkeypatch.setattr(encode_module, "StreamEncoder", Recorded)
    out = tmp_path / "s.srs"
    stats = encode_recording(rec, out, bitrate_mbps=0.5)
    assert stats.fps == 5.0 and StreamFile(out).fps == 5.0
    main_camera = sr.load_recording(rec).server_frames[0].main.camera
    w, h = main_camera.width, main_camera.height
    encode_recording(rec, tmp_path / "default.srs")
    assert [(c.fps, c.bitrate_mbps) for c in configs] == [
        (5.0, 0.5), (5.0, pytest.approx(40.0 * w * h / (2560 * 1440)))]
    # Measured over its 4 frames: 0.391 Mb/s (-22 %; 0.281 budgeted at 10 per second).
    assert abs(_mbps(out) / 0.5 - 1) <= 0.44
