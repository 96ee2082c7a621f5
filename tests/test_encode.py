"""`splitrender encode`: a recording of a built-in scene into a stream file and back."""

from __future__ import annotations

import threading
from pathlib import Path

import numpy as np
import pytest

import splitrender as sr
from splitrender.cli import main
from splitrender.codec.coder import DecodedStream, StreamDecoder, decode_packets
from splitrender.codec.encode import encode_recording


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


def test_encode_recording_ends_its_worker_threads(recording: Path, tmp_path: Path) -> None:
    # The encoder was never closed: its worker threads outlived the call until it was collected.
    def workers() -> set[threading.Thread]:
        return {t for t in threading.enumerate() if t.name.startswith("splitrender-enc")}

    before = workers()
    encode_recording(recording, tmp_path / "s.srs", bitrate_mbps=0.5)
    assert workers() - before == set()


def test_encode_cli(recording: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "s.srs"
    assert main(["encode", str(recording), "--bitrate", "0.5", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "total" in text and "picture.color" in text
    assert out.is_file()


def test_encode_cli_errors_are_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["encode", str(tmp_path / "missing"), "--out", str(tmp_path / "x.srs")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("splitrender: error:") and "\n" not in err
    with pytest.raises(SystemExit) as e:
        main(["encode", str(tmp_path), "--bitrate", "-3", "--out", str(tmp_path / "x.srs")])
    assert e.value.code == 2
    capsys.readouterr()
    # 1e300 reached the encoder and ended in an OverflowError traceback.
    with pytest.raises(SystemExit) as e:
        main(["encode", str(tmp_path), "--bitrate", "1e300", "--out", str(tmp_path / "x.srs")])
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert "--bitrate: expected a finite number >= 0.01 and <= 100000 Mb/s, got 1e300" in err
