"""Every command path run for real (issue 12): what it writes, not just its exit status.

One tiny recording (courtyard, dynamic, 77x43, 0.25 s: 4 server frames, 30 client frames of which
the middle 6 are scored) is rendered once with ``splitrender render`` and encoded once with
``splitrender encode``; the ``play`` paths (stream file, ``--bitrate``, ``--video``, a scene
name) run on it. The ``--backend wgpu`` paths of ``demo``, ``play``, ``eval`` and ``bench`` run
at 32x18 and skip without a wgpu adapter, like tests/test_wgpu.py (CI installs lavapipe and
sets ``REPROJ_WGPU_REQUIRE_ADAPTER=1``, where test_wgpu.py fails without one). ``python -m
splitrender`` and the ``splitrender`` console script run in subprocesses.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import pytest
import splitrender as sr
from PIL import Image
from splitrender import gpu
from splitrender.cli import main
from splitrender.client.client import Client
from splitrender.evaluation.metrics import SKIP_FRAMES, psnr, psnr_of_mse, ssim
from splitrender.reproject import METHODS

av = pytest.importorskip("av")

HAVE_GPU = gpu.available()
needs_gpu = pytest.mark.skipif(
    not HAVE_GPU,
    reason="no wgpu adapter (apt-get install mesa-vulkan-drivers gives Mesa's lavapipe)",
)

#: courtyard at scale 0.03 is 77x43 (odd sizes: client.mp4 pads them to even).
SCALE, W, H = "0.03", 77, 43
#: 0.25 s: 30 client frames at 120 FPS (12 skipped at each end, 6 scored), 4 server frames.
SECONDS, N_CLIENT, N_SERVER = "0.25", 30, 4
SCORED = N_CLIENT - 2 * SKIP_FRAMES
#: Total target of the stream; at 77x43 the fixed cost (headers, lossless parts) is ~0.2 Mb/s.
BITRATE = 0.7
#: The wgpu paths at 32x18 (lavapipe is slow).
GPU_SCALE, GPU_W, GPU_H = "0.0125", 32, 18
#: README "GPU path": at least 99.5 % identical pixels, mean absolute difference below 0.5/255.
MIN_EQUAL, MAX_MAD = 0.995, 0.5

Image8 = npt.NDArray[np.uint8]


def run_cli(*argv: str) -> None:
    assert main([*argv, "--quiet"]) == 0, argv


def read_png(path: Path) -> Image8:
    with Image.open(path) as im:
        assert im.mode == "RGB", path
        return np.asarray(im)


def read_json(path: Path) -> Any:
    return json.loads(path.read_text(encoding="utf-8"))


def agreement(a: Image8, b: Image8) -> tuple[float, float]:
    equal = float(np.all(a == b, axis=2).mean())
    mad = float(np.abs(a.astype(np.int16) - b.astype(np.int16)).mean())
    return equal, mad


def assert_gpu_parity(a: Image8, b: Image8, what: str) -> None:
    assert a.shape == b.shape, what
    equal, mad = agreement(a, b)
    assert equal >= MIN_EQUAL and mad < MAX_MAD, f"{what}: {100 * equal:.2f} % equal, MAD {mad}"


def assert_close_metrics(a: dict[str, Any], b: dict[str, Any], what: str) -> None:
    """Two rows of metrics of the same frames reprojected on two backends (README's parity
    holds per image; this is what it gives the means at these sizes)."""
    assert a["ssim"] == pytest.approx(b["ssim"], abs=0.01), what
    assert a["flip"] == pytest.approx(b["flip"], abs=0.01), what
    assert a["psnr"] == pytest.approx(b["psnr"], abs=0.5), what


@contextmanager
def client_backends() -> Iterator[set[tuple[str, str]]]:
    """The ``(method, backend)`` of every :class:`~splitrender.Client` made inside."""
    seen: set[tuple[str, str]] = set()
    init = Client.__init__

    def spy(self: Client, *args: Any, **kwargs: Any) -> None:
        init(self, *args, **kwargs)
        seen.add((self.method, self.backend))

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(Client, "__init__", spy)
        yield seen


def check_play_json(
    out: Path, *, source: str, recording: Path, bitrate: float | None, method: str = "ours",
    delay: int = 0, size: tuple[int, int] = (W, H),
) -> dict[str, Any]:
    data: dict[str, Any] = read_json(out / "play.json")
    assert data["source"] == source and data["recording"] == str(recording)
    assert data["method"] == method and data["delay"] == delay
    assert data["bitrate_mbps"] == bitrate
    assert (data["width"], data["height"]) == size
    assert data["client_frames"] == N_CLIENT and data["server_frames"] == N_SERVER
    modes = data["mode_per_frame"]
    assert len(modes) == N_CLIENT
    assert data["modes"] == {m: modes.count(m) for m in ("interpolate", "extrapolate", "hold")}
    assert 0 < data["ssim"] <= 1 and 0 <= data["flip"] <= 1 and data["psnr"] > 0
    assert data["vmaf"] is None  # --no-vmaf
    assert data["mbps"] > 0 and data["frames"] == SCORED
    return data


def png_frames(out: Path, size: tuple[int, int] = (W, H)) -> list[Image8]:
    paths = sorted((out / "frames").glob("*.png"))
    assert [p.name for p in paths] == [f"{n:04d}.png" for n in range(N_CLIENT)]
    frames = [read_png(p) for p in paths]
    assert all(f.shape == (size[1], size[0], 3) for f in frames)
    return frames


# -- the shared recording, its stream file, and their plays ------------------------------------


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("render") / "rec"
    run_cli("render", "courtyard", "--scale", SCALE, "--seconds", SECONDS, "--out", str(out))
    return out


@pytest.fixture(scope="module")
def stream(recording: Path) -> Path:
    out = recording.parent / "rec.srs"
    run_cli("encode", str(recording), "--bitrate", str(BITRATE), "--out", str(out))
    return out


@pytest.fixture(scope="module")
def played_stream(recording: Path, stream: Path) -> Path:
    out = recording.parent / "play-stream"
    run_cli("play", str(stream), "--recording", str(recording), "--no-vmaf", "--out", str(out))
    return out


@pytest.fixture(scope="module")
def played_raw(recording: Path) -> Path:
    out = recording.parent / "play-raw"
    run_cli("play", str(recording), "--no-vmaf", "--out", str(out))
    return out


def test_render_and_encode_write_the_recording_and_a_stream_near_the_target(
    recording: Path, stream: Path
) -> None:
    manifest = read_json(recording / "manifest.json")
    assert (manifest["scene"], manifest["variant"]) == ("courtyard", "dynamic")
    assert manifest["scale"] == float(SCALE) and manifest["seconds"] == float(SECONDS)
    assert manifest["cameras"]["main"] == [W, H] and manifest["cameras"]["client"] == [W, H]
    rec = sr.load_recording(recording)
    assert len(rec.server_frames) == N_SERVER and len(rec.client_frames) == N_CLIENT
    packets = list(sr.read_stream(stream))
    assert len(packets) == N_SERVER
    mbps = sr.stream_stats(packets, 10.0).mbps_total()
    assert mbps == pytest.approx(BITRATE, rel=0.2)


def test_an_output_inside_an_input_is_refused_and_the_input_kept(
    recording: Path, stream: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # Issue 15: `encode REC --out REC/manifest.json` exited 0 and destroyed the recording.
    before = {p.name: p.read_bytes() for p in recording.iterdir() if p.is_file()}
    names = sorted(p.name for p in recording.iterdir())
    stream_bytes = stream.read_bytes()
    rec = str(recording)
    for out, argv in [
        (recording / "manifest.json", ["encode", rec]),
        (recording, ["encode", rec]),
        (recording / "ds", ["dataset", "export", rec]),
        (recording, ["play", rec, "--no-vmaf"]),
        (recording / "play", ["play", str(stream), "--recording", rec, "--no-vmaf"]),
        (stream, ["play", str(stream), "--recording", rec, "--no-vmaf"]),
    ]:
        assert main([*argv, "--out", str(out), "--quiet"]) == 2, argv
        err = capsys.readouterr().err
        assert err.startswith("splitrender: error: ") and err.count("\n") == 1, err
        assert f"{out}: the output " in err and "expected a path outside it" in err, err
        assert (str(stream) if out == stream else rec) in err.split(": the output ")[1], err
    assert sorted(p.name for p in recording.iterdir()) == names
    assert {p.name: p.read_bytes() for p in recording.iterdir() if p.is_file()} == before
    assert stream.read_bytes() == stream_bytes


def test_play_of_a_stream_without_frames_is_refused(
    recording: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # It used to score held black frames and exit 0.
    empty = tmp_path / "empty.srs"
    sr.write_stream(empty, [])
    argv = ["play", str(empty), "--recording", str(recording), "--no-vmaf"]
    assert main([*argv, "--out", str(tmp_path / "out"), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err == (
        f"splitrender: error: {empty}: the stream has no frames; expected at least one server "
        "frame\n"
    )
    assert not (tmp_path / "out").exists()


def _restamped(packet: bytes, **fields: Any) -> bytes:
    """``packet`` with ``fields`` replaced (its payloads kept), packed again with a fresh CRC."""
    from dataclasses import replace

    from splitrender.codec.stream import pack_packet, unpack_packet

    return pack_packet(replace(unpack_packet(packet), **fields))


def _moved(packet: bytes) -> bytes:
    """``packet`` with its main camera moved 1 cm: a stream of another take."""
    from dataclasses import replace

    from splitrender.codec.stream import unpack_packet

    cams = unpack_packet(packet).cameras
    view = cams[0].view.copy()
    view[0, 3] += 0.01
    return _restamped(packet, cameras=(replace(cams[0], view=view), *cams[1:]))


@pytest.mark.parametrize("case", ["fps", "shifted", "moved", "short", "first missing"])
def test_play_refuses_a_stream_not_encoded_from_the_recording(
    recording: Path, stream: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str],
    case: str,
) -> None:
    # A stream of another scene or take used to be scored against the recording's ground
    # truth without complaint (a lab stream against a courtyard recording: SSIM 0.19, exit 0).
    packets = list(sr.read_stream(stream))
    fps, expected = 10.0, ""
    if case == "fps":
        fps = 20.0
        expected = "the stream is at 20 server frames per second, the recording at 10"
    elif case == "shifted":
        packets = packets[1:] + [_restamped(packets[-1], index=N_SERVER, time=N_SERVER / 10)]
        expected = "its frame 0 is server frame 1 at 0.1 s, the recording's is 0 at 0 s"
    elif case == "first missing":
        # It was told to give a shorter --seconds, which then left too few client frames.
        packets = packets[1:]
        expected = "its frame 0 is server frame 1 at 0.1 s, the recording's is 0 at 0 s"
    elif case == "moved":
        packets[2] = _moved(packets[2])
        expected = ("frame 2's main camera has another view matrix (a stream of another scene, "
                    "take or scale?)")
    foreign = tmp_path / "foreign.srs"
    if case == "short":
        sr.write_stream(foreign, packets[:2], fps)
    else:
        sr.write_stream(foreign, packets, fps)
        expected = f"foreign.srs was not encoded from {recording}: {expected}"
    if case == "short":
        expected = (f"{foreign}: the stream has 2 server frames, {SECONDS} s of the recording "
                    f"need {N_SERVER}; give --seconds 0.1 or less")
    out = tmp_path / "out"
    argv = ["play", str(foreign), "--recording", str(recording), "--no-vmaf", "--out", str(out)]
    assert main([*argv, "--quiet"]) == 2
    assert capsys.readouterr().err == f"splitrender: error: {expected}\n"
    assert not out.exists()


def test_a_recording_too_short_to_score_is_named_rather_than_seconds(
    recording: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # Without --seconds the length is the recording's: "--seconds: 0.01 s is 1 client frames"
    # blamed an option that was not given.
    short = Path(shutil.copytree(recording, tmp_path / "short"))
    m = read_json(short / "manifest.json")
    m.update(seconds=0.01, server_frames=m["server_frames"][:1],
             client_frames=m["client_frames"][:1])
    (short / "manifest.json").write_text(json.dumps(m))
    out = tmp_path / "out"
    assert main(["play", str(short), "--no-vmaf", "--out", str(out), "--quiet"]) == 2
    assert capsys.readouterr().err == (
        f"splitrender: error: {short} lasts 0.01 s, 1 client frames; at least "
        f"{2 * SKIP_FRAMES + 1} are needed ({SKIP_FRAMES} skipped at each end)\n")
    assert main(["play", str(recording), "--seconds", "0.1", "--no-vmaf", "--out", str(out),
                 "--quiet"]) == 2
    assert capsys.readouterr().err.startswith("splitrender: error: --seconds: 0.1 s, 12 client")
    assert not out.exists()


def test_a_play_into_a_used_folder_replaces_its_outputs_or_leaves_them_as_they_were(
    recording: Path, stream: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # A failed play wrote new frame PNGs as it went, beside the previous run's play.json.
    from splitrender.cli import play as play_cli

    out = tmp_path / "out"
    argv = ["play", str(stream), "--recording", str(recording), "--no-vmaf", "--out", str(out)]
    run_cli(*argv, "--video")
    (out / "notes.txt").write_text("mine")
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    assert sorted(before) == ["client.mp4", "notes.txt", "play.json"]
    write_png, written = play_cli.write_png, []

    def interrupted(path: Path, image: Image8) -> None:
        if len(written) == 5:
            raise KeyboardInterrupt
        write_png(path, image)
        written.append(path)

    monkeypatch.setattr(play_cli, "write_png", interrupted)
    assert main([*argv, "--quiet"]) == 130  # "interrupted"
    assert len(written) == 5
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    monkeypatch.undo()
    # A complete play replaces every output of a play: the video of the run before goes too.
    run_cli(*argv)
    assert sorted(p.name for p in out.iterdir()) == ["frames", "notes.txt", "play.json"]
    assert len(png_frames(out)) == N_CLIENT


def test_a_play_in_which_no_server_frame_arrives_is_refused(
    recording: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # With --delay 40 on 30 client frames every scored frame was black, scored (SSIM 0.001)
    # and written with exit 0.
    out = tmp_path / "out"
    argv = ["play", str(recording), "--no-vmaf", "--delay", "40", "--out", str(out), "--quiet"]
    assert main(argv) == 2
    assert capsys.readouterr().err == (
        "splitrender: error: no server frame reached the client by its last scored frame "
        f"({(N_CLIENT - SKIP_FRAMES - 1) / 120:g} s; l = 40, ideal link (no loss)): every "
        "scored frame would be black; expected a shorter delay or latency, less loss, or a "
        "longer --seconds\n")
    assert not out.exists()
    # A delay that leaves some scored frames black is what the model is for: played.
    run_cli("play", str(recording), "--no-vmaf", "--delay", "16", "--out", str(out))
    assert read_json(out / "play.json")["modes"]["hold"] > 0


def test_play_stream_file_scores_the_frames_it_writes(
    recording: Path, stream: Path, played_stream: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    data = check_play_json(played_stream, source=str(stream), recording=recording, bitrate=None)
    # The stream's own rate, as its packets say.
    assert data["mbps"] == pytest.approx(
        sr.stream_stats(list(sr.read_stream(stream)), 10.0).mbps_total(), rel=1e-4
    )
    frames = png_frames(played_stream)
    # The PNGs are the frames that were scored: their metrics against the recording's ground
    # truth (first and last SKIP_FRAMES excluded) are play.json's.
    rec = sr.load_recording(recording)
    kept = range(SKIP_FRAMES, N_CLIENT - SKIP_FRAMES)
    truth = {n: rec.client_frames[n].ground_truth for n in kept}
    # A sequence's PSNR is that of its mean squared error (metrics.py, issue 16).
    mse = np.mean([10.0 ** (-psnr(frames[n], truth[n]) / 10.0) for n in kept])
    assert data["psnr"] == pytest.approx(psnr_of_mse(float(mse)))
    assert data["ssim"] == pytest.approx(np.mean([ssim(frames[n], truth[n]) for n in kept]))
    assert data["modes"]["interpolate"] > 0  # l = 0: the pairs arrive in time


def test_play_recording_with_bitrate_encodes_and_decodes_on_the_fly(
    recording: Path, played_stream: Path, played_raw: Path
) -> None:
    out = recording.parent / "play-bitrate"
    run_cli("play", str(recording), "--bitrate", str(BITRATE), "--no-vmaf", "--out", str(out))
    data = check_play_json(out, source=str(recording), recording=recording, bitrate=BITRATE)
    assert data["mbps"] == pytest.approx(BITRATE, rel=0.2)
    # The same codec as `encode --bitrate` on the same frames: the rate and quality of the
    # stream file's play.
    streamed = read_json(played_stream / "play.json")
    assert data["mbps"] == pytest.approx(streamed["mbps"], rel=0.05)
    assert data["ssim"] == pytest.approx(streamed["ssim"], abs=0.02)
    # Not the uncompressed frames: those are played at their raw rate, to other images.
    raw = read_json(played_raw / "play.json")
    assert raw["bitrate_mbps"] is None and raw["mbps"] > 10 * data["mbps"]
    assert any((a != b).any() for a, b in zip(png_frames(out), png_frames(played_raw)))


@pytest.mark.parametrize("how", ["stream", "bitrate", "raw"])
def test_play_reads_each_server_frame_when_the_client_needs_it(
    recording: Path, stream: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, how: str
) -> None:
    # It used to decode (or read) the whole run before the first client frame: about 50 MB per
    # 1280x720 server frame held for the whole play.
    from splitrender.cli import play as play_cli
    from splitrender.codec.coder import StreamDecoder
    from splitrender.scene.recording import Recording

    events: list[tuple[str, int]] = []
    decode, read, write_png = StreamDecoder.decode, Recording._server, play_cli.write_png

    def spy_decode(self: StreamDecoder, data: bytes | memoryview) -> sr.ServerFrame:
        f = decode(self, data)
        events.append(("decoded", f.index))
        return f

    def spy_read(self: Recording, k: int) -> sr.ServerFrame:
        events.append(("read", k))
        return read(self, k)

    def spy_png(path: Path, image: Image8) -> None:
        events.append(("png", int(path.stem)))
        write_png(path, image)

    monkeypatch.setattr(StreamDecoder, "decode", spy_decode)
    monkeypatch.setattr(Recording, "_server", spy_read)
    monkeypatch.setattr(play_cli, "write_png", spy_png)
    argv = {"stream": [str(stream), "--recording", str(recording)],
            "bitrate": [str(recording), "--bitrate", str(BITRATE)],
            "raw": [str(recording)]}[how]
    run_cli("play", *argv, "--no-vmaf", "--out", str(tmp_path / "out"))
    assert [n for e, n in events if e == "png"] == list(range(N_CLIENT))
    first = events.index(("png", 0))
    # The first client frame needs the first pair; the last server frame comes later.
    made = "read" if how == "raw" else "decoded"
    later = [n for e, n in events[first:] if e == made]
    assert later and later[-1] == N_SERVER - 1, events
    if how != "raw":  # each packet decoded once, the last after the first client frame
        assert sorted(n for e, n in events if e == "decoded") == list(range(N_SERVER))
        assert ("decoded", N_SERVER - 1) not in events[:first], events


def test_play_refuses_a_damaged_stream_before_it_writes_anything(
    recording: Path, stream: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # The frames are decoded as the client plays, so a damaged packet must be caught before.
    data = bytearray(stream.read_bytes())
    third = list(sr.read_stream(stream))[2]
    data[data.find(third) + len(third) // 2] ^= 0x55
    damaged = tmp_path / "damaged.srs"
    damaged.write_bytes(data)
    out = tmp_path / "out"
    argv = ["play", str(damaged), "--recording", str(recording), "--no-vmaf", "--out", str(out)]
    assert main([*argv, "--quiet"]) == 2
    err = capsys.readouterr().err
    # Naming the file: "frame 2: packet CRC mismatch" did not say which.
    assert err.startswith(f"splitrender: error: {damaged}: frame 2: packet CRC mismatch"), err
    assert not out.exists()


def test_play_video_writes_client_mp4_with_every_client_frame(
    recording: Path, stream: Path, played_stream: Path
) -> None:
    out = recording.parent / "play-video"
    run_cli("play", str(stream), "--recording", str(recording), "--video", "--no-vmaf",
            "--out", str(out))
    assert sorted(p.name for p in out.iterdir()) == ["client.mp4", "play.json"]
    data = check_play_json(out, source=str(stream), recording=recording, bitrate=None)
    streamed = read_json(played_stream / "play.json")
    for k in ("ssim", "flip", "psnr", "mbps", "modes"):
        assert data[k] == streamed[k], k
    with av.open(str(out / "client.mp4")) as c:
        video = [f.to_ndarray(format="rgb24") for f in c.decode(c.streams.video[0])]
    assert len(video) == N_CLIENT
    assert all(f.shape == (H + 1, W + 1, 3) for f in video)  # padded to even sides
    # Frame n is the PNG frame n of the same play (up to the lossy 4:2:0 coding).
    pngs = png_frames(played_stream)
    crop = [f[:H, :W].astype(np.int16) for f in video]

    def mae(a: npt.NDArray[np.int16], b: Image8) -> float:
        return float(np.abs(a - b).mean())

    assert max(mae(v, p) for v, p in zip(crop, pngs)) < 8
    assert mae(crop[0], pngs[0]) < mae(crop[0], pngs[-1])
    assert mae(crop[-1], pngs[-1]) < mae(crop[-1], pngs[0])


def test_play_scene_name_renders_into_out_recording(recording: Path, played_raw: Path) -> None:
    out = recording.parent / "play-scene"
    run_cli("play", "courtyard", "--scale", SCALE, "--seconds", SECONDS, "--no-vmaf",
            "--out", str(out))
    rendered = out / "recording"
    data = check_play_json(out, source="courtyard", recording=rendered, bitrate=None)
    # The recording `render` makes with the same arguments (rendering is deterministic), ...
    files = sorted(p.relative_to(rendered) for p in rendered.rglob("*") if p.is_file())
    assert files == sorted(p.relative_to(recording) for p in recording.rglob("*") if p.is_file())
    for f in files:
        assert (rendered / f).read_bytes() == (recording / f).read_bytes(), f
    # ... played uncompressed like that recording.
    raw = read_json(played_raw / "play.json")
    for k in ("ssim", "flip", "psnr", "mbps", "mode_per_frame"):
        assert data[k] == raw[k], k
    assert len(png_frames(out)) == N_CLIENT


# -- --backend wgpu: the methods with a GPU kernel on the GPU, the baselines on the CPU ---------


@needs_gpu
def test_demo_on_wgpu_runs_ours_on_the_gpu_and_timewarp_on_the_cpu(tmp_path: Path) -> None:
    args = ["demo", "--scale", GPU_SCALE, "--seconds", SECONDS, "--methods", "ours,timewarp",
            "--no-vmaf"]
    run_cli(*args, "--out", str(tmp_path / "cpu"))
    with client_backends() as seen:
        run_cli(*args, "--backend", "wgpu", "--out", str(tmp_path / "wgpu"))
    assert seen == {("ours", "wgpu"), ("timewarp", "cpu")}
    rows = {b: {r["method"]: r for r in read_json(tmp_path / b / "summary.json")["rows"]}
            for b in ("cpu", "wgpu")}
    assert list(rows["wgpu"]) == ["ours", "timewarp"]
    for method in ("ours", "timewarp"):
        assert rows["wgpu"][method]["frames"] == SCORED
        assert_close_metrics(rows["wgpu"][method], rows["cpu"][method], method)
    stills = sorted(p.name for p in (tmp_path / "wgpu" / "stills").glob("*_ours.png"))
    assert stills
    for name in stills:
        images = [read_png(tmp_path / b / "stills" / name) for b in ("wgpu", "cpu")]
        assert images[0].shape == (GPU_H, GPU_W, 3)
        assert_gpu_parity(images[0], images[1], name)


@needs_gpu
def test_play_on_wgpu_matches_the_cpu(tmp_path: Path) -> None:
    # --delay 6: the first half of each server interval extrapolates, the second interpolates.
    wgpu_out, cpu_out = tmp_path / "wgpu", tmp_path / "cpu"
    with client_backends() as seen:
        run_cli("play", "courtyard", "--scale", GPU_SCALE, "--seconds", SECONDS, "--delay", "6",
                "--backend", "wgpu", "--no-vmaf", "--out", str(wgpu_out))
    assert seen == {("ours", "wgpu")}
    rec = wgpu_out / "recording"
    run_cli("play", str(rec), "--delay", "6", "--no-vmaf", "--out", str(cpu_out))
    size = (GPU_W, GPU_H)
    data = check_play_json(wgpu_out, source="courtyard", recording=rec, bitrate=None, delay=6,
                           size=size)
    cpu = check_play_json(cpu_out, source=str(rec), recording=rec, bitrate=None, delay=6,
                          size=size)
    assert data["mode_per_frame"] == cpu["mode_per_frame"]
    assert data["modes"]["interpolate"] > 0 and data["modes"]["extrapolate"] > 0
    assert_close_metrics(data, cpu, "play")
    for n, (a, b) in enumerate(zip(png_frames(wgpu_out, size), png_frames(cpu_out, size))):
        assert_gpu_parity(a, b, f"client frame {n}")


@needs_gpu
def test_eval_on_wgpu_gives_the_cpu_rows(tmp_path: Path) -> None:
    args = ["eval", "--scale", GPU_SCALE, "--seconds", SECONDS, "--scenes", "courtyard",
            "--methods", "ours,timewarp", "--variants", "dynamic", "--delays", "0", "--no-vmaf"]
    run_cli(*args, "--out", str(tmp_path / "cpu"))
    # The recordings come from the session's sweep cache (conftest.py); the rows do not: the
    # backend is part of a score task's key.
    with client_backends() as seen:
        run_cli(*args, "--backend", "wgpu", "--out", str(tmp_path / "wgpu"))
    assert seen == {("ours", "wgpu"), ("ours_extrapolate", "wgpu"), ("timewarp", "cpu")}

    def rows(b: str) -> dict[tuple[str, float | None], dict[str, Any]]:
        return {(r["method"], r["bitrate_mbps"]): r
                for r in read_json(tmp_path / b / "results.json")}

    got, want = rows("wgpu"), rows("cpu")
    assert got.keys() == want.keys()
    # Table 1 (uncompressed) for both methods, Table 2 (compressed) for ours and
    # ours_extrapolate.
    assert sorted((m, br is None) for m, br in got) == [
        ("ours", False), ("ours", True), ("ours_extrapolate", False), ("timewarp", True)]
    for key, r in got.items():
        assert r["frames"] == SCORED and r["mbps"] == pytest.approx(want[key]["mbps"])
        assert_close_metrics(r, want[key], str(key))


@needs_gpu
def test_bench_on_wgpu_rows_say_wgpu(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import tempfile

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))  # the recording cache
    path = tmp_path / "bench.json"
    run_cli("bench", "--scale", GPU_SCALE, "--frames", "2", "--methods", "ours,forward_splat",
            "--backend", "wgpu", "--json", str(path))
    rows = read_json(path)
    assert [r["method"] for r in rows] == ["ours", "forward_splat"]
    for r in rows:
        assert r["backend"] == "wgpu" and (r["width"], r["height"]) == (GPU_W, GPU_H)
        assert r["ms_per_frame"] > 0 and r["ns_per_pixel"] > 0
        assert r["decode_ms_per_server_frame"] > 0


# -- python -m splitrender and the console script ------------------------------------------------


def _env() -> dict[str, str]:
    """The environment with this test's splitrender first on the path."""
    here = str(Path(sr.__file__).resolve().parents[1])
    return dict(os.environ, PYTHONPATH=os.pathsep.join(
        [here, *filter(None, [os.environ.get("PYTHONPATH")])]))


def _run(argv: list[str], cwd: Path) -> subprocess.CompletedProcess[str]:
    r = subprocess.run(argv, cwd=cwd, env=_env(), capture_output=True, text=True, timeout=120,
                       check=False)
    assert r.returncode == 0, r.stderr
    return r


def _check_example(out: Path, printed: str) -> None:
    names = ["ground_truth", *METHODS]
    assert sorted(p.name for p in out.iterdir()) == sorted(f"{n}.png" for n in [*names, "montage"])
    images = {n: read_png(out / f"{n}.png") for n in names}
    assert all(im.shape == (18, 32, 3) for im in images.values())
    # The montage is the tiles row by row, 3 per row, 4 pixels apart, each under a caption bar
    # of `bar` rows with its label in black on white.
    montage = read_png(out / "montage.png")
    bar = (montage.shape[0] - 2 * 18 - 4) // 2
    assert bar > 0 and montage.shape == (2 * (bar + 18) + 4, 3 * 32 + 2 * 4, 3)
    for k, n in enumerate(names):
        y, x = divmod(k, 3)
        y, x = y * (bar + 18 + 4), x * 36
        np.testing.assert_array_equal(montage[y + bar:y + bar + 18, x:x + 32], images[n])
        caption = montage[y:y + bar, x:x + 32]
        assert caption.min() < 64 and np.median(caption) == 255, n
    # The printed MAE of each method is that of its PNG against ground_truth.png.
    truth = images["ground_truth"].astype(np.int16)
    for m in METHODS:
        mae = float(np.abs(images[m].astype(np.int16) - truth).mean())
        line = next(ln for ln in printed.splitlines() if ln.split()[:1] == [m])
        assert float(line.split()[1]) == pytest.approx(mae, abs=0.006), line


def test_python_m_splitrender(tmp_path: Path) -> None:
    r = _run([sys.executable, "-m", "splitrender", "--version"], tmp_path)
    assert r.stdout.strip() == f"splitrender {sr.__version__}"
    r = _run([sys.executable, "-m", "splitrender", "example", "--width", "32", "--height", "18",
              "--out", "ex"], tmp_path)
    _check_example(tmp_path / "ex", r.stdout)


def test_console_script(tmp_path: Path) -> None:
    exe = shutil.which("splitrender")
    if exe is None:
        pytest.skip("no splitrender console script on PATH (pip install the package)")
    r = _run([exe, "--version"], tmp_path)
    assert r.stdout.strip() == f"splitrender {sr.__version__}"
    r = _run([exe, "example", "--width", "32", "--height", "18", "--out", "ex"], tmp_path)
    _check_example(tmp_path / "ex", r.stdout)
