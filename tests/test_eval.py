"""``splitrender eval`` and ``splitrender play`` end to end, at a tiny scale (seconds)."""

from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path
from typing import Any

import pytest
from splitrender.cli import main
from splitrender.evaluation.experiments import ROW_KEYS

pytest.importorskip("av")

TINY = ["--scale", "0.03", "--seconds", "0.3", "--quiet"]


@pytest.fixture(scope="module")
def eval_out(tmp_path_factory: pytest.TempPathFactory) -> Path:
    base = tmp_path_factory.mktemp("eval")
    out = base / "out"
    # A cache of its own: the streams in it are this sweep's (see test_eval_rows_score_...).
    args = ["eval", *TINY, "--scenes", "courtyard", "--methods", "ours,timewarp,video_interp",
            "--delays", "0,12", "--bitrates", "40", "--stereo", "--no-vmaf", "--out", str(out),
            "--cache", str(base / "cache")]
    assert main(args) == 0
    return out


def test_eval_rows_have_exactly_the_keys_and_types(eval_out: Path) -> None:
    rows = json.loads((eval_out / "results.json").read_text())
    assert isinstance(rows, list) and rows
    for r in rows:
        assert list(r) == list(ROW_KEYS)
        assert r["scene"] == "courtyard" and r["variant"] in ("static", "dynamic")
        assert isinstance(r["method"], str)
        assert r["bitrate_mbps"] is None or isinstance(r["bitrate_mbps"], float)
        assert isinstance(r["delay"], int) and isinstance(r["stereo"], bool)
        assert all(isinstance(r[k], float) for k in ("ssim", "flip", "psnr", "mbps"))
        assert r["vmaf"] is None  # --no-vmaf
        assert r["frames"] == 36 - 24
    keys = [(r["variant"], r["method"], r["bitrate_mbps"] is None, r["delay"], r["stereo"])
            for r in rows]
    assert len(set(keys)) == len(keys)  # a row shared by two experiments is written once
    assert set(keys) == {
        # Table 1: uncompressed, both variants
        *((v, m, True, 0, False) for v in ("static", "dynamic")
          for m in ("ours", "timewarp", "video_interp")),
        # Table 2: delays (ours at l = 0 also serves Table 3 and Figure 6)
        ("dynamic", "ours", False, 0, False), ("dynamic", "ours", False, 12, False),
        ("dynamic", "ours_extrapolate", False, 0, False),
        # Table 3: mono vs stereo (timewarp mono also serves Figure 6)
        ("dynamic", "timewarp", False, 0, False),
        ("dynamic", "ours", False, 0, True), ("dynamic", "timewarp", False, 0, True),
        # Figure 6: video_interp and the references (video streaming, timewarp at 10/30/60 FPS)
        ("dynamic", "video_interp", False, 0, False),
        ("dynamic", "video_streaming", False, 0, False),
        *(("dynamic", f"timewarp_{f}fps", False, 0, False) for f in (10, 30, 60)),
    }
    # Table 3 has no video_interp row: it cannot make a stereo pair.
    assert not any(r["method"] == "video_interp" and r["stereo"] for r in rows)


def _mse_and_ssim(images: Any, truth: Any, flip: bool = False) -> tuple[float, float, Any]:
    """The mean squared error (in [0, 1] units), mean SSIM and, with ``flip``, mean FLIP (else
    ``None``: 75 ms a frame) of ``images`` against ``truth`` over the scored client frames (the
    first and last SKIP_FRAMES left out)."""
    import numpy as np
    from splitrender import metrics as M

    kept = range(M.SKIP_FRAMES, len(truth) - M.SKIP_FRAMES)
    mse = np.mean([np.mean((images[n] / 255.0 - truth[n] / 255.0) ** 2) for n in kept])
    return (float(mse), float(np.mean([M.ssim(images[n], truth[n]) for n in kept])),
            float(np.mean([M.flip(images[n], truth[n]) for n in kept])) if flip else None)


def test_eval_rows_score_each_methods_frames_against_each_eyes_ground_truth(
    eval_out: Path, tmp_path: Path
) -> None:
    """The rows' PSNR and SSIM are those of the method's own client frames, made here again
    (played from the recording or the cached stream, minterpolate for video_interp), against
    the recording's ground truth of the same eye; a stereo row averages its two eyes (PSNR of
    the mean MSE). The row checks above only look at types: a score of the truth against
    itself, or of the right eye against the left eye's truth, passed them."""
    import numpy as np
    import splitrender as sr
    from splitrender import metrics as M
    from splitrender.evaluation.references import minterpolate

    rows = json.loads((eval_out / "results.json").read_text())

    def row(variant: str, method: str, compressed: bool, stereo: bool) -> dict[str, Any]:
        [r] = [r for r in rows if (r["variant"], r["method"], r["bitrate_mbps"] is not None,
                                   r["delay"], r["stereo"]) == (variant, method, compressed, 0,
                                                                stereo)]
        return r

    def check(r: dict[str, Any], eyes: list[tuple[float, float, Any]]) -> None:
        what = f"{r['variant']} {r['method']} stereo={r['stereo']}"
        assert r["psnr"] == pytest.approx(M.psnr_of_mse(np.mean([e[0] for e in eyes])),
                                          abs=1e-9), what
        assert r["ssim"] == pytest.approx(np.mean([e[1] for e in eyes]), abs=1e-9), what
        if all(e[2] is not None for e in eyes):  # FLIP's maps are float32: equal to 1e-6
            assert r["flip"] == pytest.approx(np.mean([e[2] for e in eyes]), abs=1e-6), what

    # Table 1: uncompressed, mono.
    for variant in ("static", "dynamic"):
        rec = sr.load_recording(eval_out / "recordings" / f"courtyard-{variant}")
        cams, lazy = rec.eye(0)
        truth = [lazy[n] for n in range(len(lazy))]
        server = list(rec.server_frames)
        for method in ("ours", "timewarp"):
            played = sr.play(server, cams, sr.NetworkModel(client_fps=rec.fc), rec.fc, method)
            flip = (variant, method) == ("dynamic", "ours")  # one row's FLIP: 1 s
            check(row(variant, method, False, False),
                  [_mse_and_ssim(played.images, truth, flip)])
        interp = minterpolate([f.main.color for f in server], rec.fs, rec.fc, len(truth))
        check(row(variant, "video_interp", False, False), [_mse_and_ssim(interp, truth)])
    # Figure 6's references at the sweep's one bitrate: the ground truth itself as a video, and
    # the main colour as a video before minterpolate; their rows' rates are those achieved.
    from splitrender.evaluation.references import video_streaming

    rec = sr.load_recording(eval_out / "recordings" / "courtyard-dynamic")
    truth = [rec.eye(0)[1][n] for n in range(len(rec.eye(0)[1]))]
    r = row("dynamic", "video_streaming", True, False)
    coded, mbps = video_streaming(truth, r["bitrate_mbps"], rec.fc)
    check(r, [_mse_and_ssim(coded, truth)])
    assert r["mbps"] == pytest.approx(mbps, rel=1e-6) and r["ssim"] < 1.0
    [r] = [r for r in rows if r["method"] == "video_interp" and r["bitrate_mbps"] is not None]
    colours, mbps = video_streaming([f.main.color for f in rec.server_frames],
                                    r["bitrate_mbps"], rec.fs)
    check(r, [_mse_and_ssim(minterpolate(colours, rec.fs, rec.fc, len(truth)), truth)])
    assert r["mbps"] == pytest.approx(mbps, rel=1e-6)
    # Table 3: stereo, from the stream at the sweep's bitrate (the one whose rate the row has).
    rec = sr.load_recording(eval_out / "recordings" / "courtyard-dynamic-stereo")
    cache = Path(json.loads((eval_out / "run-info.json").read_text())["cache"])
    for method in ("ours", "timewarp"):
        r = row("dynamic", method, True, True)
        streams = {p.read_bytes() for p in (cache / "streams").glob("*.stream")
                   if json.loads(p.with_suffix(".json").read_text())["mbps"] == r["mbps"]}
        assert len(streams) == 1, f"{len(streams)} cached streams at {r['mbps']} Mb/s"
        (path := tmp_path / f"{method}.srs").write_bytes(streams.pop())
        packets = list(sr.read_stream(path))
        eyes = []
        for eye in (0, 1):
            cams, lazy = rec.eye(eye)
            played = sr.play(sr.DecodedStream(packets), cams,
                             sr.NetworkModel(client_fps=rec.fc), rec.fc, method,
                             frame_sizes=[len(p) for p in packets])
            eyes.append(_mse_and_ssim(played.images, [lazy[n] for n in range(len(lazy))]))
        check(r, eyes)


def test_eval_timewarp_rows_score_each_rates_own_server_frames(eval_out: Path) -> None:
    """Figure 6's ``timewarp_Nfps`` rows are those of the main camera's colour and depth
    rendered at N FPS with a prediction window of one frame (10 FPS: the recording's own server
    frames; 30 and 60 FPS: the sweep's cached renders, here identified by their times and
    poses), encoded at the row's bitrate, timewarped at the recording's client cameras and
    scored against its ground truth; made here again, PSNR and SSIM equal to 1e-9. The row
    checks above only look at types: a 30 FPS row scored on the 10 FPS server's frames, or the
    truth scored against itself, passed them."""
    import numpy as np
    import splitrender as sr
    from splitrender import metrics as M
    from splitrender.scene.builtin import PathMotion

    rows = json.loads((eval_out / "results.json").read_text())
    cache = Path(json.loads((eval_out / "run-info.json").read_text())["cache"])
    rec = sr.load_recording(eval_out / "recordings" / "courtyard-dynamic")
    cams, lazy = rec.eye(0)
    truth = [lazy[n] for n in range(len(lazy))]
    scene = sr.Scene("courtyard", "dynamic")
    renders: dict[int, dict[str, Any]] = {}
    for path in (cache / "timewarp").glob("*.npz"):
        with np.load(path) as z:
            d = {k: z[k] for k in z.files}
        renders[round(1 / float(d["time"][1] - d["time"][0]))] = d
    assert sorted(renders) == [30, 60]  # 10 FPS with 100 ms is the recording's own
    for fps in (10, 30, 60):
        what = f"timewarp_{fps}fps"
        [r] = [r for r in rows if r["method"] == what]
        if fps == 10:
            server = [sr.ServerFrame(f.index, f.time, sr.CameraFrame(
                f.main.camera, f.main.color, f.main.depth)) for f in rec.server_frames]
        else:
            d = renders[fps]
            n, h, w = d["depth"].shape
            assert np.array_equal(d["time"], np.arange(n) / fps), what
            # Rendered at the pose predicted 1 / fps seconds ahead (the view is its inverse).
            motion = PathMotion(scene, 1 / fps)
            for k in range(n):
                assert np.allclose(d["view"][k], np.linalg.inv(motion.server_pose(k, fps)),
                                   rtol=0, atol=1e-12), (what, k)
            server = [sr.ServerFrame(int(d["index"][k]), float(d["time"][k]), sr.CameraFrame(
                sr.Camera(d["view"][k], d["proj"][k], int(w), int(h)), d["color"][k],
                d["depth"][k])) for k in range(n)]
        config = sr.CodecConfig(bitrate_mbps=r["bitrate_mbps"], camera_shares=(1.0,),
                                fps=float(fps), gop=fps)
        with sr.StreamEncoder(config) as enc:
            packets = [enc.encode(f) for f in server]
        assert r["mbps"] == pytest.approx(
            sum(map(len, packets)) * 8 * fps / len(packets) / 1e6, rel=1e-9), what
        played = sr.play(sr.DecodedStream(packets), cams, sr.NetworkModel(client_fps=rec.fc),
                         rec.fc, "timewarp", frame_sizes=[len(q) for q in packets],
                         options=sr.ReprojectOptions(server_fps=float(fps)))
        mse, ssim, _ = _mse_and_ssim(played.images, truth)
        assert r["psnr"] == pytest.approx(M.psnr_of_mse(mse), abs=1e-9), what
        assert r["ssim"] == pytest.approx(ssim, abs=1e-9) and ssim < 1.0, what


def test_eval_writes_tables_plots_and_one_recording_per_scene_variant(eval_out: Path) -> None:
    md = (eval_out / "tables.md").read_text()
    assert md.count("## Table") == 3 and md.count("## Figure 6") == 1 and "timewarp" in md
    for png in ("delays.png", "rate_distortion.png"):
        assert (eval_out / png).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    info = json.loads((eval_out / "run-info.json").read_text())
    # Recordings: static, dynamic, dynamic stereo (each of one server and two client chunks),
    # and the 30 and 60 FPS timewarp servers; streams: mono and stereo at the one bitrate
    # (Figure 6's 40 Mb/s is Table 2's here).
    assert info["tasks"] == {"render": 3 * 4 + 2, "encode": 2, "score": 19}
    assert info["executor"] == "local" and info["jobs"] == 1
    recordings = [p for p in (Path(info["cache"]) / "recordings").iterdir()
                  if (p / "manifest.json").is_file()]
    made = {(json.loads((p / "manifest.json").read_text())["variant"],
             json.loads((p / "manifest.json").read_text())["stereo"]) for p in recordings}
    assert {("static", False), ("dynamic", False), ("dynamic", True)} <= made


def test_play_writes_frames_and_prints_modes(
    eval_out: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rec = eval_out / "recordings" / "courtyard-dynamic"
    out = tmp_path / "play"
    assert main(["play", str(rec), "--method", "ours", "--delay", "2", "--no-vmaf", "--quiet",
                 "--out", str(out)]) == 0
    pngs = sorted((out / "frames").glob("*.png"))
    assert len(pngs) == 36 and pngs[0].read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    printed = capsys.readouterr().out
    assert "interpolate" in printed and "SSIM" in printed
    data = json.loads((out / "play.json").read_text())
    assert sum(data["modes"].values()) == 36 and data["delay"] == 2


@pytest.mark.parametrize(
    "argv",
    [
        ["eval", "--scenes", "nowhere", "--out", "x"],
        ["eval", "--methods", "ours,bogus", "--out", "x"],
        ["eval", "--delays", "0,-1", "--out", "x"],
        ["eval", "--bitrates", "10,0", "--out", "x"],
        ["eval", "--methods", "video_interp,video_interp", "--out", "x"],
        ["eval", "--variants", "moving", "--out", "x"],
        ["eval", "--scenes", "lab", "--rd-scenes", "courtyard", "--bitrates", "10",
         "--out", "x"],
        ["eval", "--seconds", "0.1", "--out", "x"],
        ["eval", "--scale", "0.001", "--out", "x"],
        ["play", "does-not-exist", "--out", "x"],
        ["play", "courtyard", "--method", "bogus", "--out", "x"],
        ["play", "courtyard", "--seconds", "0.1", "--out", "x"],
    ],
)
def test_bad_arguments_exit_2_with_one_line(
    argv: list[str], tmp_path: Path, capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as e:
        raise SystemExit(main([*argv, "--quiet"]))
    assert e.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("splitrender") and " error: " in err


def test_eval_reuses_matching_recordings(
    eval_out: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Another sweep on the same cache renders nothing it already has: its recording comes
    from the cache and only its new rows are computed."""
    cache = json.loads((eval_out / "run-info.json").read_text())["cache"]
    out = tmp_path / "again"
    # Into a copy of the first run's folder: its plots must not stay beside this run's results
    # (this run has no Figure 6, so no rate_distortion.png).
    shutil.copytree(eval_out, out, symlinks=True)
    (out / "notes.txt").write_text("mine")
    args = ["eval", "--scale", "0.03", "--seconds", "0.3", "--scenes", "courtyard",
            "--methods", "timewarp", "--delays", "0", "--no-vmaf", "--out", str(out),
            "--cache", cache]
    assert main(args) == 0
    info = json.loads((out / "run-info.json").read_text())
    assert info["cached"]["render"] == info["tasks"]["render"] == 2 * 4
    assert info["computed"]["render"] == 0 and info["cached"]["score"] >= 2
    err = capsys.readouterr().err
    assert "render:" not in err and "in the cache" in err
    assert not (out / "rate_distortion.png").exists()
    assert (out / "delays.png").read_bytes() != (eval_out / "delays.png").read_bytes()
    assert (out / "notes.txt").read_text() == "mine" and (out / "recordings").is_dir()
    # This run's recordings only: the first run's stereo link went (no stereo rows here).
    assert sorted(p.name for p in (out / "recordings").iterdir()) == [
        "courtyard-dynamic", "courtyard-static"]
    assert not [p.name for p in out.iterdir() if p.name.startswith(".")]


def test_minterpolate_output_n_is_client_frame_n() -> None:
    """Output frame n of video_interp is at time n / f_c: where that is a server frame's time
    (n = 12 k) it reproduces server frame k, the last one included; between them it differs
    from both neighbours (it interpolates)."""
    import numpy as np
    from splitrender.evaluation.experiments import minterpolate

    yy, xx = np.mgrid[0:72, 0:128]
    frames = []
    for k in range(4):  # a smooth pattern moving 3 px to the right per server frame
        v = 127.5 + 100 * np.sin((xx - 3 * k) / 7.0) * np.cos(yy / 9.0)
        frames.append(np.repeat(v[..., None], 3, axis=2).round().astype(np.uint8))
    out = minterpolate(frames, 10.0, 120.0, 37)
    assert len(out) == 37 and out[0].shape == (72, 128, 3) and out[0].dtype == np.uint8

    def err(a: np.ndarray, b: np.ndarray) -> float:
        return float(np.abs(a.astype(int) - b.astype(int)).mean())

    for k in range(4):
        assert err(out[12 * k], frames[k]) < 1.0, k
    assert err(out[6], frames[0]) > 3 and err(out[6], frames[1]) > 3


def test_minterpolate_works_below_two_blocks_a_side() -> None:
    """FFmpeg's filter emits nothing under 32 pixels a side (a 26x14 dataset failed eval):
    such frames are padded and the output cropped, server frames still reproduced."""
    import numpy as np
    from splitrender.evaluation.experiments import minterpolate

    rng = np.random.default_rng(1)
    frames = [rng.integers(0, 256, (14, 26, 3), dtype=np.uint8) for _ in range(3)]
    out = minterpolate(frames, 10.0, 120.0, 25)
    assert len(out) == 25 and out[0].shape == (14, 26, 3)
    for k in range(3):
        assert np.abs(out[12 * k].astype(int) - frames[k]).max() <= 2, k


def test_vmaf_crossings_interpolate_between_measured_points() -> None:
    from splitrender.evaluation.experiments import vmaf_crossings

    rows = [{"mbps": 2.0, "vmaf": 70.0}, {"mbps": 1.0, "vmaf": 50.0},
            {"mbps": 4.0, "vmaf": 79.0}]
    got = vmaf_crossings(rows, (40.0, 60.0, 80.0))
    assert got[40.0] == 1.0  # already reached at the lowest rate
    assert got[60.0] == pytest.approx(1.5)
    assert got[80.0] is None


def _short_trace(path: Path) -> Path:
    path.write_text("0 1.6 0 0 0 0 0\n0.1 1.6 0 0 5 0 50\n")  # 50 ms
    return path


@pytest.mark.parametrize(
    "extra, option",
    [
        (lambda t: ["--out", str(t / "a-file")], "--out"),
        (lambda t: ["--out", "/proc/self"], "--out"),
        (lambda t: ["--latency", "5000"], "--latency"),
        (lambda t: ["--latency", "150", "--delays", "12"], "--latency"),
        (lambda t: ["--trace", str(_short_trace(t / "short.trace"))], "--trace"),
        (lambda t: ["--executor", "ray"], "--executor ray"),
    ],
    ids=["out-file", "out-proc", "latency", "latency-and-delay", "trace", "ray-missing"],
)
def test_eval_refuses_before_any_work(
    extra: Any, option: str, tmp_path: Path, capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # Each was found after the cache was laid out and, but for --out, by a task after rendering
    # (--out: after the whole sweep, at 1280x720 hours of it); Ray missing after the cache.
    import sys

    if option == "--out" and not Path("/proc/self").is_dir():
        pytest.skip("no /proc")
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray raises ImportError
    (tmp_path / "a-file").write_text("mine")
    argv = ["eval", *TINY, "--scenes", "courtyard", "--variants", "dynamic", "--methods",
            "ours", "--delays", "0", "--no-vmaf", "--cache", str(tmp_path / "cache"),
            "--out", str(tmp_path / "out"), *extra(tmp_path)]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and f"error: {option}" in err, err
    assert not (tmp_path / "cache").exists() and not (tmp_path / "out").exists()
    assert (tmp_path / "a-file").read_text() == "mine"


@pytest.mark.parametrize(
    ("change", "problem"),
    [
        ({"scenes": ()}, "--scenes: expected at least one scene"),
        ({"samples": 0}, "--samples: expected 1.."),
        ({"scenes": ("lab", "nowhere")}, "--scenes: unknown scene 'nowhere'; expected some of"),
        ({"scenes": ("lab", "lab")}, "--scenes: a scene is listed twice"),
        ({"delays": (-1,)}, "--delays: expected distinct integers >= 0"),
        ({"delays": (0, 0)}, "--delays: expected distinct integers >= 0"),
        ({"delays": (1000,)}, "--delays: 1000 client frames is past the last scored frame"),
        ({"network": "slow"}, "--latency: 10000 ms is past the last scored client frame"),
        ({"variants": ()}, "--variants: expected static, dynamic or both, each once"),
        ({"variants": ("static", "static")}, "--variants: expected static, dynamic or both"),
        ({"rd_scenes": ("courtyard",)}, r"--rd-scenes: expected some of the --scenes \(lab\)"),
        ({"rd_scenes": ("lab", "lab")}, "--rd-scenes: a scene is listed twice"),
        ({"bitrates": (float("nan"),)}, "--bitrates: expected finite numbers > 0"),
        ({"bitrates": (5.0, 5.0)}, "--bitrates: a bitrate is listed twice"),
        ({"trace": "missing"}, "--trace: .*missing: no such file"),
    ],
)
def test_eval_config_refusals_through_the_api(
    change: dict[str, Any], problem: str, tmp_path: Path
) -> None:
    # The command line checks most of these itself first: here, the API's own checks.
    import splitrender as sr
    from splitrender.evaluation.experiments import EvalArgumentError, EvalConfig, check_config

    if change.get("network") == "slow":
        change = {"network": sr.NetworkModel(latency_ms=10_000.0), "delays": (0,)}
    if change.get("trace") == "missing":
        change = {"trace": tmp_path / "missing"}
    cfg = EvalConfig(out=tmp_path / "out", scenes=("lab",))
    check_config(cfg)
    with pytest.raises(EvalArgumentError, match=f"^{problem}"):
        check_config(dataclasses.replace(cfg, **change))


@pytest.mark.parametrize(
    ("change", "problem"),
    [
        ({"executor": "dask"}, "--executor: expected local or ray, got 'dask'"),
        ({"jobs": 0}, "--jobs: expected an integer >= 1, got 0"),
        ({"address": "127.0.0.1:6379"}, "--address: goes with --executor ray"),
    ],
)
def test_run_eval_refuses_an_executor_it_cannot_use_before_any_work(
    change: dict[str, Any], problem: str, tmp_path: Path
) -> None:
    from splitrender.evaluation.experiments import EvalArgumentError, EvalConfig, run_eval

    cfg = EvalConfig(out=tmp_path / "out", scenes=("lab",), cache=tmp_path / "cache", **change)
    with pytest.raises(EvalArgumentError, match=f"^{problem}$"):
        run_eval(cfg)
    assert not (tmp_path / "out").exists() and not (tmp_path / "cache").exists()


@pytest.mark.parametrize(
    ("change", "problem"),
    [
        ({"scenes": ("a", "b")}, "--dataset: evaluates one recording, named by one scene"),
        ({"stereo": True}, "--stereo: not with --dataset"),
        ({"bitrates": (5.0,)}, "--bitrates: not with --dataset"),
        ({"samples": 2}, "--samples: not with --dataset"),
    ],
)
def test_a_recordings_evaluation_takes_table_1_only(
    change: dict[str, Any], problem: str, tmp_path: Path
) -> None:
    # Through the API, where the command line's own check of its options is not made.
    from splitrender.evaluation.experiments import EvalArgumentError, EvalConfig, check_config

    cfg = EvalConfig(out=tmp_path / "out", scenes=("ds",), recording=tmp_path / "ds")
    check_config(cfg)
    with pytest.raises(EvalArgumentError, match=f"^{problem}"):
        check_config(dataclasses.replace(cfg, **change))


def test_table_2_calls_only_the_default_bitrate_the_papers(
    eval_out: Path, tmp_path: Path
) -> None:
    from splitrender.evaluation.experiments import _ordinal

    assert "(the paper's 40 Mb/s scaled by pixel count)" in (eval_out / "tables.md").read_text()
    out = tmp_path / "out"
    assert main(["eval", *TINY, "--scenes", "courtyard", "--variants", "dynamic", "--methods",
                 "ours", "--delays", "0", "--no-vmaf", "--bitrate", "0.5",
                 "--out", str(out)]) == 0
    text = (out / "tables.md").read_text()
    assert "compressed at 0.5 Mb/s; `ours_extrapolate`" in text and "paper's 40" not in text
    # --flip-every's note in English ordinals.
    assert [_ordinal(n) for n in (1, 2, 3, 4, 11, 12, 13, 21, 22, 103, 111)] == [
        "1st", "2nd", "3rd", "4th", "11th", "12th", "13th", "21st", "22nd", "103rd", "111th"]


@pytest.mark.parametrize("scale", ["0.001", "0.0107", "1.601"])
def test_a_scale_out_of_range_names_the_range_of_scales(
    scale: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # Below 0.0008 the renderer's check answered ("each side must be in 2..=16384"), above it
    # this one ("expected 16..4096 pixels a side"): neither said which scales work.
    assert main(["eval", "--scale", scale, "--methods", "ours", "--quiet",
                 "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "expected 16..4096 pixels a side (--scale 0.0108 to 1.6)" in err, err


def test_tables_put_each_metric_under_its_label_and_bold_the_best_per_group() -> None:
    """tables.md's columns in order, each value under its own label, and in bold the best of
    each group: the highest SSIM, PSNR and VMAF, the lowest FLIP; none in a group of one."""
    from splitrender.evaluation.experiments import format_rows

    def r(method: str, delay: int, ssim: float, flip: float, psnr: float,
          vmaf: float | None) -> dict[str, Any]:
        return {"scene": "lab", "method": method, "bitrate_mbps": 1.23456, "delay": delay,
                "ssim": ssim, "flip": flip, "psnr": psnr, "vmaf": vmaf, "mbps": 2.5,
                "frames": 96}

    rows = [r("ours", 0, 0.91, 0.20, 30.0, 80.0), r("timewarp", 0, 0.85, 0.10, 31.0, None),
            r("ours", 2, 0.80, 0.30, 25.0, 70.0)]
    assert format_rows(rows, ("method", "bitrate_mbps", "delay"), ("delay",)).splitlines() == [
        "| method | bitrate_mbps | delay | SSIM ↑ | FLIP ↓ | PSNR ↑ | VMAF ↑ | Mb/s | frames |",
        "|---|---|---|---|---|---|---|---|---|",
        "| ours | 1.23 | 0 | **0.9100** | 0.2000 | 30.00 | 80.00 | 2.500 | 96 |",
        "| timewarp | 1.23 | 0 | 0.8500 | **0.1000** | **31.00** | – | 2.500 | 96 |",
        "| ours | 1.23 | 2 | 0.8000 | 0.3000 | 25.00 | 70.00 | 2.500 | 96 |",
    ]
