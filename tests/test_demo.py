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
import numpy as np
from splitrender.evaluation.demo import DEFAULT_METHODS, ROW_KEYS, TruthStore, _Video, colormap

av = pytest.importorskip("av")

TINY = ["--scale", "0.04", "--seconds", "0.3", "--quiet"]


@pytest.fixture(scope="module")
def demo_out(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("demo") / "out"
    assert main(["demo", *TINY, "--no-vmaf", "--out", str(out)]) == 0
    return out


def test_demo_writes_a_decodable_video_with_one_frame_per_client_frame(demo_out: Path) -> None:
    with av.open(str(demo_out / "video.mp4")) as c:
        stream = c.streams.video[0]
        frames = [f.to_ndarray(format="rgb24") for f in c.decode(stream)]
    assert len(frames) == round(0.3 * 120)
    h, w = frames[0].shape[:2]
    assert h % 2 == 0 and w % 2 == 0
    assert w >= 3 * 102 and h >= 58  # three 102x58 tiles side by side


def test_demo_writes_stills_and_a_summary_with_every_method(demo_out: Path) -> None:
    pngs = sorted((demo_out / "stills").glob("*.png"))
    names = {p.name.split("_", 1)[1] for p in pngs}
    assert {f"{m}.png" for m in DEFAULT_METHODS} | {"ground_truth.png", "flip_ours.png"} <= names
    for p in pngs:
        assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    summary = json.loads((demo_out / "summary.json").read_text())
    rows = summary["rows"]
    assert [r["method"] for r in rows] == list(DEFAULT_METHODS)
    for r in rows:
        assert set(ROW_KEYS) <= set(r)
        assert 0 < r["ssim"] <= 1 and 0 <= r["flip"] <= 1 and r["psnr"] > 0
        assert r["vmaf"] is None  # --no-vmaf
        assert r["mbps"] > 0 and r["frames"] == 36 - 24
    md = (demo_out / "summary.md").read_text()
    assert all(m in md for m in DEFAULT_METHODS)


def test_demo_prints_the_table(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    args = ["demo", *TINY, "--methods", "timewarp", "--out", str(tmp_path / "o")]
    assert main(args) == 0
    out = capsys.readouterr().out
    assert "SSIM" in out and "timewarp" in out and "VMAF" in out


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


def test_help_of_demo_and_bench(capsys: pytest.CaptureFixture[str]) -> None:
    for cmd in ("demo", "bench"):
        with pytest.raises(SystemExit) as e:
            main([cmd, "--help"])
        assert e.value.code == 0
        text = capsys.readouterr().out
        assert "--scale" in text and "--methods" in text


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


def test_summary_says_how_fast_the_video_plays(tmp_path: Path) -> None:
    from splitrender.evaluation.demo import playback_speed

    # They said "1x slow motion", "0.5x slow motion" and "17.1429x slow motion".
    assert playback_speed(30) == "4x slow motion"  # the default, as README.md says
    assert playback_speed(120) == "real time" and playback_speed(240) == "2x fast motion"
    assert playback_speed(120.3) == "about real time"
    out = tmp_path / "o"
    argv = ["demo", *TINY, "--no-vmaf", "--methods", "timewarp", "--video-fps", "7"]
    assert main([*argv, "--out", str(out)]) == 0
    assert " frames at 7 FPS (17.1x slow motion). " in (out / "summary.md").read_text()
