"""``splitrender demo`` and ``splitrender bench`` end to end, at a tiny scale (a few seconds)."""

from __future__ import annotations

import errno
import json
import os
from pathlib import Path
from typing import Any

import pytest
from splitrender.evaluation.bench import BENCH_KEYS
from splitrender.cli import main
from splitrender.cli.dispatch import build_parser
import numpy as np
from splitrender.evaluation.demo import DEFAULT_METHODS, ROW_KEYS, TruthStore, _Video, colormap
from splitrender.evaluation.metrics import flip_map

av = pytest.importorskip("av")

TINY = ["--scale", "0.04", "--seconds", "0.3", "--quiet"]


@pytest.fixture(scope="module")
def demo_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[bytes]]:
    """The demo's folder and the packets it encoded (kept aside by a spy on ``encode_packets``:
    the demo writes no stream file), from which the tests play and score the run again."""
    import splitrender.evaluation.pipeline as pipeline

    out = tmp_path_factory.mktemp("demo") / "out"
    encode, packets = pipeline.encode_packets, []

    def kept(*args: Any, **kwargs: Any) -> tuple[list[bytes], float]:
        made, mbps = encode(*args, **kwargs)
        packets.append(list(made))
        return made, mbps

    with pytest.MonkeyPatch.context() as m:
        m.setattr(pipeline, "encode_packets", kept)
        assert main(["demo", *TINY, "--no-vmaf", "--out", str(out)]) == 0
    [run] = packets
    return out, run


@pytest.fixture(scope="module")
def demo_out(demo_run: tuple[Path, list[bytes]]) -> Path:
    return demo_run[0]


@pytest.fixture(scope="module")
def replayed(demo_run: tuple[Path, list[bytes]]) -> dict[str, Any]:
    """The demo run made again outside the demo: the ground truth rendered here at the
    client's pose, and every default method played from the demo's packets (``sr.play``)."""
    import splitrender as sr
    from splitrender.scene.builtin import Scene

    _, packets = demo_run
    eyes = [Scene("courtyard", "dynamic").client_frames(n, 0.04, 120.0)[0] for n in range(36)]
    cams = [c for c, _ in eyes]
    frames = list(sr.DecodedStream(packets))
    played = {m: sr.play(frames, cams, sr.NetworkModel(client_fps=120.0), 120.0, m,
                         frame_sizes=[len(p) for p in packets])
              for m in DEFAULT_METHODS}
    return {"truth": [img for _, img in eyes], "played": played, "packets": packets}


def _png(path: Path) -> Any:
    from PIL import Image

    with Image.open(path) as im:
        assert im.mode == "RGB", path
        return np.asarray(im)


def test_demo_writes_a_video_of_truth_ours_and_its_flip_map_per_client_frame(
    demo_out: Path, replayed: dict[str, Any]
) -> None:
    # It counted the frames and the size only: a video of the ground truth three times passed.
    with av.open(str(demo_out / "video.mp4")) as c:
        stream = c.streams.video[0]
        frames = [f.to_ndarray(format="rgb24").astype(np.int16) for f in c.decode(stream)]
    assert len(frames) == round(0.3 * 120)
    # Three 102x58 tiles, 4 pixels apart, under a caption bar each.
    bar = frames[0].shape[0] - 58
    assert bar > 0 and frames[0].shape == (bar + 58, 3 * 102 + 2 * 4, 3)
    truth, ours = replayed["truth"], replayed["played"]["ours"].images

    def tile(frame: Any, k: int) -> Any:
        return frame[bar:, k * 106:k * 106 + 102]

    def mae(a: Any, b: Any) -> float:
        return float(np.abs(a - b.astype(np.int16)).mean())

    # Frame n shows client frame n (up to the lossy 4:2:0 coding): the ground truth, then ours,
    # each nearer its own image than ours' (the truth's) or another frame's on average, then
    # ours' FLIP map (checked on a few frames: FLIP costs ~70 ms a frame).
    other = [(n + 18) % 36 for n in range(36)]
    near = np.array([[mae(tile(f, 0), truth[n]), mae(tile(f, 1), ours[n])]
                     for n, f in enumerate(frames)])
    assert near.max() < 8, near
    # Per tile, the wrong images: another frame's, and the other image of the same frame.
    for far in ([truth[n] for n in other], [ours[n] for n in other]), (ours, truth):
        for k in (0, 1):
            mean_far = np.mean([mae(tile(f, k), far[k][n]) for n, f in enumerate(frames)])
            assert near[:, k].mean() < mean_far, (k, near[:, k].mean(), mean_far)
    for n in (0, 12, 24):
        got = tile(frames[n], 2)
        own = mae(got, colormap(flip_map(ours[n], truth[n])))
        assert own < 8 and own < mae(got, colormap(flip_map(ours[other[n]], truth[other[n]])))


def test_demo_summary_rows_score_each_methods_frames_against_the_ground_truth(
    demo_out: Path, replayed: dict[str, Any]
) -> None:
    """Each row's SSIM, PSNR (of the mean squared error) and FLIP are those of the method's
    client frames, played again here from the demo's packets, against the ground truth
    rendered again here, over the scored frames; Mb/s is the packets' rate. The row checks
    only looked at ranges: a score against the previous frame's ground truth, or a rate eight
    times the packets', passed them."""
    from splitrender import metrics as M

    summary = json.loads((demo_out / "summary.json").read_text())
    rows = summary["rows"]
    assert [r["method"] for r in rows] == list(DEFAULT_METHODS)
    truth, packets = replayed["truth"], replayed["packets"]
    mbps = sum(len(p) for p in packets) * 8 / 1e6 / (len(packets) / 10.0)
    assert summary["mbps"] == pytest.approx(mbps, rel=1e-12)
    kept = range(M.SKIP_FRAMES, 36 - M.SKIP_FRAMES)
    for r in rows:
        assert list(r) == [*ROW_KEYS, "modes"]
        played = replayed["played"][r["method"]]
        images = played.images
        mse = np.mean([np.mean((images[n] / 255.0 - truth[n] / 255.0) ** 2) for n in kept])
        assert r["psnr"] == pytest.approx(M.psnr_of_mse(float(mse)), abs=1e-9), r
        assert r["ssim"] == pytest.approx(np.mean([M.ssim(images[n], truth[n]) for n in kept]),
                                          abs=1e-9), r
        if r["method"] == "ours":  # FLIP costs ~70 ms a frame: one method's column
            assert r["flip"] == pytest.approx(
                np.mean([M.flip(images[n], truth[n]) for n in kept]), abs=1e-9)
        assert r["vmaf"] is None  # --no-vmaf
        assert r["mbps"] == summary["mbps"] and r["frames"] == len(kept)
        assert r["modes"] == played.summary()
    md = (demo_out / "summary.md").read_text()
    for r in rows:
        assert (f"| {r['method']} | {r['ssim']:.4f} | {r['flip']:.4f} | {r['psnr']:.2f} | – | "
                f"{r['mbps']:.3f} | 12 |") in md


def test_demo_stills_are_the_frames_it_scored(demo_out: Path, replayed: dict[str, Any]) -> None:
    # Only the PNG signature was checked: a still of the ground truth for every method passed.
    summary = json.loads((demo_out / "summary.json").read_text())
    idx = summary["stills"]
    assert len(set(idx)) == 3 and all(12 <= n < 36 - 12 for n in idx)
    names = ["ground_truth", *DEFAULT_METHODS, "flip_ours", "side_by_side"]
    assert sorted(p.name for p in (demo_out / "stills").iterdir()) == sorted(
        f"frame{n:04d}_{name}.png" for n in idx for name in names)
    truth, played = replayed["truth"], replayed["played"]
    for n in idx:
        still = {name: _png(demo_out / "stills" / f"frame{n:04d}_{name}.png") for name in names}
        assert np.array_equal(still["ground_truth"], truth[n])
        for m in DEFAULT_METHODS:
            assert np.array_equal(still[m], played[m].images[n]), (n, m)
        err = colormap(flip_map(played["ours"].images[n], truth[n]))
        assert np.array_equal(still["flip_ours"], err)
        side = still["side_by_side"]
        bar = side.shape[0] - 58  # the captions above the tiles (58 rows: even already)
        assert bar > 0 and side.shape == (bar + 58, 3 * 102 + 2 * 4, 3)
        for k, name in enumerate(("ground_truth", "ours", "flip_ours")):
            assert np.array_equal(side[bar:, k * 106:k * 106 + 102], still[name]), (n, name)
            assert side[:bar, k * 106:k * 106 + 102].min() < 64, (n, name)  # a caption


def test_demo_prints_the_table_and_one_progress_line_per_stage(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # It looked for the words "SSIM", "timewarp" and "VMAF" only (a table of zeros passed), and
    # ran with --quiet (progress printed or not, it passed).
    out = tmp_path / "o"
    assert main(["demo", *[a for a in TINY if a != "--quiet"], "--methods", "timewarp",
                 "--out", str(out)]) == 0
    printed = capsys.readouterr()
    (row,) = json.loads((out / "summary.json").read_text())["rows"]
    head, line = printed.out.splitlines()[-2:]
    assert head.split() == ["method", "SSIM", "↑", "FLIP", "↓", "PSNR", "↑", "VMAF", "↑",
                            "Mb/s", "frames"]
    assert line.split() == ["timewarp", f"{row['ssim']:.4f}", f"{row['flip']:.4f}",
                            f"{row['psnr']:.2f}", f"{row['vmaf']:.2f}", f"{row['mbps']:.3f}",
                            "12"]
    # Not a terminal: one plain line per stage (render, ground truth, each method, summary).
    assert "\r" not in printed.err
    assert [ln.split("  (")[0] for ln in printed.err.splitlines()] == [
        "[1/4] rendering courtyard (dynamic) at 102x58: 4 server frames at 10 FPS, encoded at "
        "1.6 Mb/s",
        "[2/4] rendering 36 ground-truth client frames at 120 FPS",
        "[3/4] timewarp: playing 36 client frames, then ssim, flip, psnr, vmaf; writing "
        "video.mp4 (ground truth | timewarp | FLIP map)",
        "[4/4] writing summary.md and summary.json",
    ]


def test_bench_json_rows_have_exactly_the_keys(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import tempfile

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))  # the recording cache
    path = tmp_path / "bench.json"
    args = ["bench", "--scale", "0.04", "--frames", "2", "--methods", "ours,timewarp"]
    assert main([*args, "--quiet", "--json", str(path)]) == 0
    rows = json.loads(path.read_text())
    assert [r["method"] for r in rows] == ["ours", "timewarp"]
    for r in rows:
        assert list(r) == list(BENCH_KEYS)
        assert r["backend"] == "cpu" and (r["width"], r["height"]) == (102, 58)
        assert r["ms_per_frame"] > 0 and r["ns_per_pixel"] > 0
        # The slowest of the timed frames is at least their median.
        assert r["ms_per_frame_max"] >= r["ms_per_frame"]
        assert r["decode_ms_per_server_frame"] > 0


@pytest.mark.parametrize(
    "argv",
    [
        ["demo", "--scale", "0"],
        ["demo", "--seconds", "abc"],
        ["demo", "--seconds", "0.1"],
        ["demo", "--seconds", "9"],
        ["demo", "--methods", "ours,nope"],
        ["demo", "--scene", "moon"],
        ["demo", "--bogus"],
        ["bench", "--frames", "0"],
        ["bench", "--methods", ""],
        ["bench", "--scene", "moon"],
    ],
)
def test_bad_arguments_exit_2_with_one_line(
    argv: list[str], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as e:
        code = main([*argv, *(["--out", str(tmp_path / "o")] if argv[0] == "demo" else [])])
        raise SystemExit(code)
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("splitrender") and " error: " in err
    assert not (tmp_path / "o").exists()


def test_help_of_demo_and_bench(demo_out: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Each command's --help prints its own description and options (it looked for "--scale"
    and "--methods" only, which the other command's help has too), and what the demo's says
    of its defaults, its limits and its summary is what the demo does."""
    from splitrender.cli.help import DESCRIPTION
    from splitrender.evaluation.demo import DemoArgumentError, DemoConfig, check_config
    from splitrender.scene.builtin import Scene

    def words(text: str) -> str:
        return " ".join(text.split())

    texts = {}
    for cmd, other in (("demo", "bench"), ("bench", "demo")):
        with pytest.raises(SystemExit) as e:
            main([cmd, "--help"])
        assert e.value.code == 0
        text = texts[cmd] = words(capsys.readouterr().out)
        assert text.startswith(f"usage: splitrender {cmd} ")
        assert words(DESCRIPTION[cmd]) in text and words(DESCRIPTION[other])[:80] not in text
        assert "--scale" in text and "--methods" in text
    # "The defaults (courtyard at 256x144, 1 s)"
    assert "The defaults (courtyard at 256x144, 1 s)" in DESCRIPTION["demo"]
    defaults = DemoConfig()
    assert (defaults.scene, defaults.seconds) == ("courtyard", 1.0)
    assert Scene("courtyard").main_size(defaults.scale) == (256, 144)
    args = build_parser().parse_args(["demo"])
    assert (args.scene, args.scale, args.seconds) == ("courtyard", defaults.scale, 1.0)
    assert "at least 0.21 s (25 client frames) and at most the scene's 4 s" in texts["demo"]
    for ok in (0.21, 4.0):
        check_config(DemoConfig(seconds=ok))
    for bad in (0.2, 4.01):
        with pytest.raises(DemoArgumentError, match="--seconds"):
            check_config(DemoConfig(seconds=bad))
    # "summary.json (the network settings; per method: ssim, flip, psnr, vmaf, mbps, frames,
    # modes)"
    said = DESCRIPTION["demo"].split("per method: ", 1)[1].split(")", 1)[0]
    summary = json.loads((demo_out / "summary.json").read_text())
    assert "network" in summary
    assert [k for k in summary["rows"][0] if k != "method"] == said.split(", ")


def test_colormap_is_dark_for_no_error_and_bright_for_full_error() -> None:
    import numpy as np

    c = colormap(np.array([[0.0, 0.5, 1.0, np.nan]], np.float32))
    assert c.dtype == np.uint8 and c.shape == (1, 4, 3)
    assert c[0, 0].sum() < 20 and c[0, 2].sum() > 600 and (c[0, 3] == c[0, 0]).all()


def test_a_failed_video_leaves_the_previous_one_and_no_temporary(tmp_path: Path) -> None:
    # Issue 15: the video was written in place and closed on the way out of an exception, which
    # left a shorter video that played.
    path = tmp_path / "video.mp4"
    frame = np.full((16, 32, 3), 128, np.uint8)
    with _Video(path, 32, 16, 24.0) as v:
        for _ in range(5):
            v.write(frame)
    good = path.read_bytes()
    with av.open(str(path)) as c:
        assert sum(1 for _ in c.decode(video=0)) == 5
    with pytest.raises(RuntimeError, match="midway"):
        with _Video(path, 32, 16, 24.0) as v:
            v.write(frame)
            raise RuntimeError("midway")
    assert path.read_bytes() == good
    assert [p.name for p in tmp_path.iterdir()] == ["video.mp4"]



def test_truth_store_holds_the_frames_in_an_unlinked_file(tmp_path: Path) -> None:
    # The demo's ground truth lives in a file mapped into memory, not in the heap, and the file
    # is gone from the directory from the start: nothing is left however the run ends.
    rng = np.random.default_rng(7)
    frames = rng.integers(0, 256, (2, 5, 6, 8, 3), dtype=np.uint8)
    with TruthStore(tmp_path, 2, 5, 6, 8) as store:
        assert isinstance(store.frames, np.memmap)
        assert list(tmp_path.iterdir()) == []
        for e in range(2):
            for n in range(5):
                store.frames[e, n] = frames[e, n]
        for e in range(2):
            eye = store.eye(e)
            assert len(eye) == 5
            assert all((eye[n] == frames[e, n]).all() for n in range(5))
    assert list(tmp_path.iterdir()) == []


def test_truth_store_on_a_full_disk_names_the_size_and_leaves_nothing(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    def full(fd: int, offset: int, size: int) -> None:
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(os, "posix_fallocate", full)
    with pytest.raises(OSError, match=r"cannot reserve 0\.14 GB for the 200 ground-truth") as e:
        TruthStore(tmp_path, 2, 100, 360, 640)
    assert e.value.errno == errno.ENOSPC and e.value.filename == str(tmp_path)
    assert list(tmp_path.iterdir()) == []


def _most_alive_in_demo(
    out: Path, seconds: float, monkeypatch: pytest.MonkeyPatch
) -> tuple[dict[str, int], Any]:
    """Runs a tiny demo (``timewarp`` and ``ours``) and counts, with weak references (the arrays
    are the native module's, outside what ``tracemalloc`` sees), the most ground truths and
    client images alive at once, and the decodings of the stream (``decodes``) with the frames
    each gave (``decoded``; the decoder reuses its arrays, so their life says nothing)."""
    import gc
    import weakref

    import splitrender.evaluation.pipeline as pipeline
    from splitrender.codec.coder import DecodedStream
    from splitrender.evaluation.demo import DemoConfig, run_demo
    from splitrender.scene.builtin import Scene

    now = {"truth": 0, "image": 0}
    most = {**now, "decodes": 0, "decoded": 0}

    def track(kind: str, a: Any) -> None:
        now[kind] += 1
        most[kind] = max(most[kind], now[kind])
        weakref.finalize(a, lambda: now.__setitem__(kind, now[kind] - 1))

    render, decode, play = Scene.client_frames, DecodedStream.__iter__, pipeline.play_and_score_eyes

    def rendered(self: Scene, *a: Any, **k: Any) -> Any:
        eyes = render(self, *a, **k)
        for _, img in eyes:
            track("truth", img)
        return eyes

    def decoded(self: DecodedStream) -> Any:
        most["decodes"] += 1
        for f in decode(self):
            most["decoded"] += 1
            yield f

    def played(*a: Any, on_frame: Any = None, **k: Any) -> Any:
        def seen(eye: int, n: int, image: Any, info: Any) -> None:
            track("image", image)
            if on_frame is not None:
                on_frame(eye, n, image, info)

        return play(*a, on_frame=seen, **k)

    with monkeypatch.context() as m:
        m.setattr(Scene, "client_frames", rendered)
        m.setattr(DecodedStream, "__iter__", decoded)
        m.setattr(pipeline, "play_and_score_eyes", played)
        gc.collect()
        res = run_demo(DemoConfig(out=out, scale=0.04, seconds=seconds, vmaf=False,
                                  methods=("timewarp", "ours"), progress=False))
    return most, res


def test_demo_holds_a_bounded_number_of_frames_whatever_the_length(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # The demo used to hold every ground truth, decoded server frame and client frame of `ours`
    # of the run (5 GB for 4 s at 1280x720). It now renders the ground truth into a file on
    # disk, decodes the packets as each play needs them and writes every client frame out as it
    # is made.
    short, _ = _most_alive_in_demo(tmp_path / "short", 0.3, monkeypatch)  # 4 + 36 frames
    long, res = _most_alive_in_demo(tmp_path / "long", 1.0, monkeypatch)  # 11 + 120
    assert [r["method"] for r in res.rows] == ["timewarp", "ours"]
    assert res.server_frames == 11 and res.client_frames == 120
    assert long["truth"] == short["truth"] <= 2 and long["image"] == short["image"] <= 2, (
        short, long)
    # Each play decodes the stream as it goes (none is decoded up front and held), and stops
    # once its last client frame is made: at most the 11 frames, and the pair of the last.
    assert long["decodes"] == short["decodes"] == 2
    assert 2 * 10 <= long["decoded"] <= 2 * 11
    # The video (of `ours`, written as it was played) has every client frame; the ground truth's
    # file is gone.
    with av.open(str(tmp_path / "long" / "video.mp4")) as c:
        assert sum(1 for _ in c.decode(video=0)) == 120
    assert sorted(p.name for p in (tmp_path / "long").iterdir()) == [
        "stills", "summary.json", "summary.md", "video.mp4"]


def test_summary_says_how_fast_the_video_plays(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from splitrender.evaluation.demo import playback_speed

    # They said "1x slow motion", "0.5x slow motion" and "17.1429x slow motion".
    assert playback_speed(30) == "4x slow motion"  # the default, as README.md says
    assert playback_speed(120) == "real time" and playback_speed(240) == "2x fast motion"
    assert playback_speed(120.3) == "about real time"
    out = tmp_path / "o"
    argv = ["demo", *TINY, "--no-vmaf", "--methods", "timewarp", "--video-fps", "7"]
    assert main([*argv, "--out", str(out)]) == 0
    assert capsys.readouterr().err == ""  # --quiet: no progress
    assert " frames at 7 FPS (17.1x slow motion). " in (out / "summary.md").read_text()
