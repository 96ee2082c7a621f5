"""The command line's options for what the API has (issue 12): ``dataset export/import``,
``--dataset``, the network model's options and ``--stereo``, at a tiny scale."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import splitrender as sr
from splitrender.cli import main
from splitrender.cli.dispatch import build_parser
from splitrender.net.model import NetworkModel

pytest.importorskip("av")

#: 77x43, 4 server and 36 client frames.
SCALE, SECONDS = 0.03, 0.3
QUICK = ["--no-vmaf", "--quiet"]


@pytest.fixture(scope="module")
def work(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("cli-options")


@pytest.fixture(scope="module")
def rec(work: Path) -> Path:
    """A small stereo recording, shared by every test."""
    return sr.write_recording(work / "rec", "courtyard", seconds=SECONDS, scale=SCALE, stereo=True)


@pytest.fixture(scope="module")
def dataset(rec: Path, work: Path) -> Path:
    """``rec`` exported by the API."""
    return sr.export_dataset(rec, work / "ds-api")


def _play(out: Path, *argv: str) -> dict[str, Any]:
    assert main(["play", *argv, *QUICK, "--out", str(out)]) == 0
    data: dict[str, Any] = json.loads((out / "play.json").read_text())
    return data


@pytest.fixture(scope="module")
def ideal(rec: Path, work: Path) -> dict[str, Any]:
    """``play`` of ``rec`` (left eye) over the ideal link."""
    return _play(work / "ideal", str(rec), "--method", "ours")


def _error(argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    """Runs ``argv`` expecting a user error: exit status 2 and one ``error:`` line."""
    with pytest.raises(SystemExit) as e:
        raise SystemExit(main([*argv, "--quiet"]))
    assert e.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("splitrender") and " error: " in err
    return err


def test_dataset_export_then_import_matches_the_api(
    rec: Path, dataset: Path, work: Path
) -> None:
    ds = work / "ds-cli"
    assert main(["dataset", "export", str(rec), "--out", str(ds), "--quiet"]) == 0
    files = sorted(p.relative_to(dataset) for p in dataset.rglob("*") if p.is_file())
    assert files == sorted(p.relative_to(ds) for p in ds.rglob("*") if p.is_file())
    assert all((ds / f).read_bytes() == (dataset / f).read_bytes() for f in files)

    back = work / "rec-back"
    assert main(["dataset", "import", str(ds), "--out", str(back), "--quiet"]) == 0
    api = sr.import_dataset(dataset)
    got = sr.load_recording(back)
    assert (got.fs, got.fc, got.stereo, got.scene) == (10.0, 120.0, False, "ds-cli")
    assert len(got.server_frames) == len(api.server_frames)
    for g, a in zip(got.server_frames, api.server_frames):
        assert (g.index, g.time) == (a.index, a.time)
        for gc, ac in zip((g.main, *g.aux), (a.main, *a.aux)):
            assert np.array_equal(gc.camera.view, ac.camera.view)
            assert np.array_equal(gc.color, ac.color) and np.array_equal(gc.depth, ac.depth)
            for name in ("motion_fwd", "motion_bwd"):
                want = getattr(ac, name)  # None (no slot in the layout): zero, no motion
                assert np.array_equal(getattr(gc, name), np.zeros_like(gc.motion_fwd)
                                      if want is None else want)
            for name in ("shadow_fwd", "shadow_bwd"):
                gs, as_ = getattr(gc, name), getattr(ac, name)
                if as_ is None:  # no slot in the layout (frame 0's backward): no shadow change
                    assert not gs.bits.any()
                else:
                    assert np.array_equal(gs.bits, as_.bits)
                    assert np.array_equal(gs.s_min, as_.s_min)
                    assert np.array_equal(gs.s_max, as_.s_max)
    assert len(got.client_frames) == len(api.client_requests) == 36
    for c, req, truth in zip(got.client_frames, api.client_requests, api.ground_truth):
        assert c.time == req.time and np.array_equal(c.camera.view, req.camera.view)
        assert truth is not None and np.array_equal(c.ground_truth, truth)


def test_dataset_layout_options_name_the_folders(rec: Path, dataset: Path, work: Path) -> None:
    # --aux-names and --client reach export_dataset; --aux and --client reach the import.
    ds = work / "ds-names"
    assert main(["dataset", "export", str(rec), "--out", str(ds), "--aux-names", "l,r",
                 "--client", "viewer", "--quiet"]) == 0
    assert sorted(p.name for p in ds.iterdir()) == ["l", "main", "r", "viewer"]
    back = work / "rec-names"
    assert main(["dataset", "import", str(ds), "--out", str(back), "--aux", "l,r",
                 "--client", "viewer", "--quiet"]) == 0
    got, api = sr.load_recording(back), sr.import_dataset(dataset)
    assert len(got.server_frames) == len(api.server_frames)
    assert len(got.client_frames) == len(api.client_requests) == 36
    for g, a in zip(got.server_frames, api.server_frames):
        assert all(np.array_equal(gc.color, ac.color)
                   for gc, ac in zip((g.main, *g.aux), (a.main, *a.aux)))


def test_dataset_user_errors(
    rec: Path, dataset: Path, work: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert "not an empty directory" in _error(
        ["dataset", "export", str(rec), "--out", str(dataset)], capsys)
    assert "no such dataset" in _error(
        ["dataset", "import", str(work / "nowhere"), "--out", str(work / "x")], capsys)
    assert "two auxiliary cameras" in _error(
        ["dataset", "import", str(dataset), "--aux", "left", "--out", str(work / "x")], capsys)
    assert "already exists" in _error(
        ["dataset", "import", str(dataset), "--out", str(rec)], capsys)


def test_network_options_parse_with_units_and_ranges(
    capsys: pytest.CaptureFixture[str],
) -> None:
    from splitrender.cli.args import network_model

    for cmd in (["play", "x", "--out", "o"], ["demo"], ["eval", "--out", "o"]):
        args = build_parser().parse_args([*cmd, "--bandwidth", "8", "--latency", "20",
                                          "--jitter", "5", "--loss", "2.5%", "--seed", "7"])
        assert network_model(args) == NetworkModel(8.0, 20.0, 5.0, 0, 0.025, 7)
    args = build_parser().parse_args(["demo", "--loss", "0.1", "--delay", "3"])
    assert network_model(args) == NetworkModel(extra_delay_frames=3, loss=0.1)
    assert network_model(build_parser().parse_args(["demo"])) == NetworkModel()  # ideal link
    for bad in (["--loss", "1.5"], ["--loss", "120%"], ["--latency", "-1"],
                ["--latency", "60001"], ["--bandwidth", "0"], ["--jitter", "x"]):
        # Refused by the option's own range, which the message names, not later by the model.
        assert f"argument {bad[0]}: expected" in _error(["demo", *bad], capsys), bad


def test_serve_encoder_threads_reach_the_encoder(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """``serve --encoder-threads N`` is the encoder's thread count (``CodecConfig.threads``),
    1 by default; out of range it is refused by the option. The server is stopped at its
    construction (its options recorded), before it renders or listens."""
    from types import SimpleNamespace

    from splitrender.net import server

    seen: list[server.ServerOptions] = []
    codec_config = server.LiveServer.codec_config

    def record(options: server.ServerOptions, **_: Any) -> None:
        seen.append(options)
        raise sr.InvalidInputError("stopped here")

    monkeypatch.setattr(server, "LiveServer", record)
    for argv, threads in ((["--encoder-threads", "3"], 3), (["--encoder-threads", "0"], 0),
                          ([], 1)):
        assert main(["serve", "--port", "0", "--token", "t", *argv]) == 2
        assert "stopped here" in capsys.readouterr().err
        fake = SimpleNamespace(options=seen[-1], max_mbps=lambda: 1.0)
        assert codec_config(fake).threads == threads  # type: ignore[arg-type]
    assert "--encoder-threads: expected an integer in 0..1024" in _error(
        ["serve", "--encoder-threads", "-1"], capsys)


def test_play_loss_drops_the_seeded_frames(
    rec: Path, ideal: dict[str, Any], work: Path
) -> None:
    lossy = _play(work / "lossy", str(rec), "--method", "ours", "--loss", "0.5", "--seed", "1")
    assert lossy["network"]["loss"] == 0.5 and lossy["network"]["seed"] == 1
    assert ideal["network"] == {"bandwidth_mbps": None, "latency_ms": 0.0, "jitter_ms": 0.0,
                                "loss": 0.0, "seed": 0, "extra_delay_frames": 0}
    assert None not in ideal["arrivals"] and ideal["modes"]["interpolate"] == 36
    lost = [a is None for a in lossy["arrivals"]]
    sends = [k / 10 - 0.1 for k in range(len(lost))]
    assert lost == [a is None for a in NetworkModel(loss=0.5, seed=1).arrival_times(sends)]
    assert any(lost) and lossy["mode_per_frame"] != ideal["mode_per_frame"]


def test_play_low_bandwidth_makes_frames_late(
    rec: Path, ideal: dict[str, Any], work: Path
) -> None:
    # Uncompressed, a server frame is ~250 kB (20 Mb/s at 10 FPS); 10 Mb/s takes 0.2 s each.
    slow = _play(work / "slow", str(rec), "--method", "ours", "--bandwidth", "10")
    assert slow["network"]["bandwidth_mbps"] == 10.0
    assert all(s > i for s, i in zip(slow["arrivals"][1:], ideal["arrivals"][1:]))
    late = slow["modes"]["extrapolate"] + slow["modes"]["hold"]
    assert late > ideal["modes"]["extrapolate"] + ideal["modes"]["hold"]
    assert slow["modes"]["interpolate"] < 36


def test_play_stereo_scores_both_eyes(
    rec: Path, ideal: dict[str, Any], work: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = work / "stereo"
    data = _play(out, str(rec), "--method", "ours", "--stereo")
    assert data["stereo"] is True and [e["eye"] for e in data["eyes"]] == ["left", "right"]
    left, right = data["eyes"]
    assert left["ssim"] == pytest.approx(ideal["ssim"])  # the left eye is the mono play
    assert left["ssim"] != right["ssim"]
    assert data["ssim"] == pytest.approx((left["ssim"] + right["ssim"]) / 2)
    for eye in ("left", "right"):
        assert len(list((out / "frames" / eye).glob("*.png"))) == 36
    printed = capsys.readouterr().out
    assert "ours (left)" in printed and "ours (right)" in printed and "ours (mean)" in printed


def test_play_dataset_plays_the_imported_folder(
    dataset: Path, ideal: dict[str, Any], work: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = work / "play-ds"
    data = _play(out, "--dataset", str(dataset), "--method", "ours")
    assert data["recording"] == str(out / "recording")
    assert sr.load_recording(out / "recording").scene == "ds-api"
    assert data["client_frames"] == 36 and data["mode_per_frame"] == ideal["mode_per_frame"]
    # Half-float depth and motion: close to the original recording's scores, not equal.
    assert data["ssim"] == pytest.approx(ideal["ssim"], abs=0.01)
    assert "mono" in _error(["play", "--dataset", str(dataset), "--stereo",
                             "--out", str(work / "x")], capsys)
    assert "--scale" in _error(["play", "--dataset", str(dataset), "--scale", "0.03",
                                "--out", str(work / "x")], capsys)
    _error(["play", "courtyard", "--dataset", str(dataset), "--out", str(work / "x")], capsys)


def test_eval_dataset_gives_table_1_rows_with_the_link(
    dataset: Path, work: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = work / "eval-ds"
    assert main(["eval", "--dataset", str(dataset), "--methods", "ours,timewarp",
                 "--latency", "10", *QUICK, "--out", str(out)]) == 0
    rows = json.loads((out / "results.json").read_text())
    assert [(r["scene"], r["variant"], r["method"], r["delay"]) for r in rows] == [
        ("ds-api", "dataset", "ours", 0), ("ds-api", "dataset", "timewarp", 0)]
    assert all(r["network"]["latency_ms"] == 10.0 and r["frames"] == 12 for r in rows)
    assert "10 ms latency" in (out / "tables.md").read_text()
    # The link reaches the plays, not only the rows: over the ideal link `ours` interpolates
    # the first client frames of each period that 10 ms of latency make it extrapolate.
    ideal = work / "eval-ds-ideal"
    assert main(["eval", "--dataset", str(dataset), "--methods", "ours", *QUICK,
                 "--out", str(ideal)]) == 0
    (row,) = json.loads((ideal / "results.json").read_text())
    assert row["network"]["latency_ms"] == 0.0 and row["frames"] == 12
    assert row["ssim"] != rows[0]["ssim"]
    for flag in (["--scenes", "lab"], ["--stereo"], ["--delays", "0"], ["--seconds", "0.3"]):
        assert flag[0] in _error(["eval", "--dataset", str(dataset), *flag,
                                  "--out", str(work / "x")], capsys)


def test_demo_stereo_scores_both_eyes_and_records_the_link(work: Path) -> None:
    out = work / "demo"
    assert main(["demo", "--scale", str(SCALE), "--seconds", str(SECONDS), "--methods",
                 "ours", "--stereo", "--jitter", "30", "--seed", "2", *QUICK,
                 "--out", str(out)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["stereo"] is True
    assert summary["network"]["jitter_ms"] == 30.0 and summary["network"]["seed"] == 2
    (row,) = summary["rows"]
    # The jitter reaches the play: frame k + 1, sent at k / 10, arrives after the link's
    # seeded draw; until then client frame n (at n / 120) extrapolates from frame k. (Timewarp,
    # which needs frame k only, sent a period ahead, showed no 30 ms jitter: its scores were
    # those of the ideal link.)
    link = NetworkModel(jitter_ms=30.0, seed=2)
    arrivals = [a for a in link.arrival_times([k / 10 - 0.1 for k in range(4)]) if a is not None]
    assert len(arrivals) == 4
    late = sum(1 for n in range(36) if arrivals[n * 10 // 120 + 1] > n / 120)
    assert late > 0 and row["modes"] == {"interpolate": 36 - late, "extrapolate": late, "hold": 0}
    left, right = row["eyes"]
    assert left["ssim"] != right["ssim"]
    assert row["ssim"] == pytest.approx((left["ssim"] + right["ssim"]) / 2)
    assert "jitter 0-30 ms" in (out / "summary.md").read_text()


def test_bench_json_help_names_every_key_a_row_has() -> None:
    """`bench --json`'s help lists the keys of the rows it writes: each of BENCH_KEYS."""
    from splitrender.evaluation.bench import BENCH_KEYS

    sub = next(
        a for a in build_parser()._actions if a.choices and "bench" in a.choices  # type: ignore
    ).choices["bench"]
    text = next(a.help for a in sub._actions if "--json" in a.option_strings)
    named = {w.strip(",()") for w in " ".join(text.split()).split()}
    assert set(BENCH_KEYS) <= named, set(BENCH_KEYS) - named
