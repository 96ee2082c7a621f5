"""``splitrender bench``'s accounting: the bytes each method touches, whose copy is the floor its
time is compared with."""

from __future__ import annotations

import dataclasses
import itertools
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import splitrender as sr
from conftest import Pair
from splitrender.evaluation.bench import bytes_touched
from splitrender.machine import CpuTimes, Machine
from splitrender.types import ShadowBuffers

FIELDS = ("color", "depth", "motion_fwd", "motion_bwd", "shadow_fwd", "shadow_bwd")


def _perturbed(value, field: str):
    """The buffer with every value changed and still valid."""
    if field == "color":
        return 255 - value
    if field == "depth":
        return (value * np.float32(0.97)).astype(np.float32)
    if field.startswith("motion"):
        return (value + np.float32(0.02)).astype(np.float32)
    return ShadowBuffers(value.bits, 255 - value.s_min, 255 - value.s_max)


def _nbytes(value) -> int:
    if isinstance(value, ShadowBuffers):
        return value.bits.nbytes + value.s_min.nbytes + value.s_max.nbytes
    return int(value.nbytes)


def _buffers_read(pair: Pair, method: str) -> dict[str, int]:
    """Every buffer of the pair whose change changes ``method``'s output, with its size."""
    base = sr.reproject(pair.older, pair.newer, pair.request, method)
    read = {}
    for which, frame in (("older", pair.older), ("newer", pair.newer)):
        cams = (frame.main, *frame.aux)
        for k, cam in enumerate(cams):
            for field in FIELDS:
                value = getattr(cam, field)
                if value is None:
                    continue
                changed = list(cams)
                changed[k] = dataclasses.replace(cam, **{field: _perturbed(value, field)})
                frame2 = dataclasses.replace(frame, main=changed[0], aux=tuple(changed[1:]))
                older, newer = (frame2, pair.newer) if which == "older" else (pair.older, frame2)
                out = sr.reproject(older, newer, pair.request, method)
                if not np.array_equal(out, base):
                    read[f"{which}.cam{k}.{field}"] = _nbytes(value)
    return read


@pytest.mark.parametrize("method", sr.METHODS)
def test_bytes_touched_counts_every_buffer_the_output_depends_on(pair: Pair, method: str) -> None:
    """The estimate is a lower bound of the traffic (module docstring): at least the output
    image and every source buffer the output changes with."""
    read = _buffers_read(pair, method)
    assert read, "the perturbations changed nothing: the test would prove nothing"
    floor = pair.newer.main.color.nbytes + sum(read.values())
    assert bytes_touched(method, pair.older, pair.newer) >= floor, read


#: The buffers each method reads, as bench.py's module docstring lists them: (frame, cameras,
#: fields); "all" is the main and the auxiliary cameras.
DOCUMENTED = {
    "ours": (("older", "all", ("color", "depth", "motion_fwd", "shadow_fwd")),
             ("newer", "all", ("color", "depth", "motion_bwd", "shadow_bwd"))),
    "ours_extrapolate": (("older", "all", ("color", "depth", "motion_bwd", "shadow_bwd")),),
    "forward_splat": (("older", "all", ("color", "depth", "motion_bwd")),),
    "timewarp": (("older", "main", ("color", "depth")),),
    "backward_bidir": (("older", "main", ("color", "depth", "motion_fwd")),
                       ("newer", "main", ("color", "depth", "motion_bwd"))),
}


@pytest.mark.parametrize("method", sr.METHODS)
def test_bytes_touched_is_the_output_and_the_documented_buffers(pair: Pair, method: str) -> None:
    """Exactly the output image and the buffers the module docstring lists (a lower bound
    alone let a method count buffers it never reads), and those include every buffer the
    output was seen to change with."""
    documented: dict[str, int] = {}
    for which, cams, fields in DOCUMENTED[method]:
        frame = pair.older if which == "older" else pair.newer
        for k, cam in enumerate((frame.main, *frame.aux) if cams == "all" else (frame.main,)):
            for field in fields:
                if getattr(cam, field) is not None:
                    documented[f"{which}.cam{k}.{field}"] = _nbytes(getattr(cam, field))
    assert set(_buffers_read(pair, method)) <= set(documented)
    expected = pair.newer.main.color.nbytes + sum(documented.values())
    assert bytes_touched(method, pair.older, pair.newer) == expected, documented


def test_forward_splat_reads_its_auxiliary_cameras(pair: Pair) -> None:
    """Why ``forward_splat`` counts them: its main camera leaves pixels that they fill."""
    read = _buffers_read(pair, "forward_splat")
    assert any(".cam1." in k or ".cam2." in k for k in read), read


def test_time_frames_warms_up_for_its_time_then_times_each_frame_from_the_first_request() -> None:
    from splitrender.evaluation.bench import time_frames

    now = [0.0]
    calls: list[str] = []

    def one(req: str) -> None:
        calls.append(req)
        now[0] += 0.125  # every call takes 125 ms of the fake clock

    samples = time_frames(one, ["a", "b", "c"], 4, warm_up_s=0.5, clock=lambda: now[0])
    # Four untimed calls fill the half second (cycling through the requests), then the four
    # timed ones start again from the first request.
    assert calls == ["a", "b", "c", "a", "a", "b", "c", "a"]
    assert samples == [0.125] * 4


def test_time_frames_warms_up_with_at_least_one_call() -> None:
    from splitrender.evaluation.bench import time_frames

    calls: list[int] = []
    samples = time_frames(calls.append, [7], 2, warm_up_s=0.0)
    assert calls == [7, 7, 7] and len(samples) == 2


@pytest.mark.parametrize(("n", "k"), [(10, 1), (10, 3), (83_000_001, 2), (2, 5)])
def test_equal_parts_cover_every_byte_once(n: int, k: int) -> None:
    from splitrender.evaluation.bench import equal_parts

    parts = equal_parts(n, k)
    assert len(parts) == k
    assert parts[0][0] == 0 and parts[-1][1] == n
    assert all(a[1] == b[0] for a, b in zip(parts, parts[1:]))
    lengths = [b - a for a, b in parts]
    assert max(lengths) - min(lengths) <= 1


def test_kernel_threads_are_rayons_pool() -> None:
    """The floor's threads are those of rayon's pool, which ``RAYON_NUM_THREADS`` sets: a floor
    of one thread beside a frame on two would flatter the frame."""
    code = "from splitrender.evaluation.bench import kernel_threads\nprint(kernel_threads())\n"
    env = {**os.environ, "RAYON_NUM_THREADS": "3"}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                         timeout=60, check=True).stdout.split()
    assert out == ["3"]


def test_the_copy_floor_copies_every_byte_in_equal_parts_on_the_threads_asked(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    import threading

    from splitrender.evaluation.bench import copy_floor_s

    calls: list[tuple[int, int]] = []
    real = np.copyto

    def copyto(dst: np.ndarray, src: np.ndarray) -> None:
        calls.append((threading.get_ident(), len(src)))
        real(dst, src)

    monkeypatch.setattr(np, "copyto", copyto)
    seconds, threads = copy_floor_s(1001, 3, repeats=2)
    main = threading.get_ident()
    whole = [t for t, n in calls if n == 1001]
    parts = [(t, n) for t, n in calls if n != 1001]
    # One thread: the whole copy, on the caller's thread, twice.
    assert whole == [main, main]
    # Three threads: the pool's start and then the timed copies, two rounds each of three
    # parts (333 + 334 + 334 bytes), none on the caller's thread.
    assert sorted(n for _, n in parts) == [333] * 4 + [334] * 8
    assert main not in {t for t, _ in parts}
    assert seconds > 0 and threads in (1, 3)


@pytest.mark.parametrize(("part_s", "expected"), [(1.0, (3.0, 3)), (5.0, (10.0, 1))])
def test_the_copy_floor_is_the_faster_of_one_thread_and_the_parts(
    monkeypatch: pytest.MonkeyPatch, part_s: float, expected: tuple[float, int]
) -> None:
    """On a clock where the whole copy takes 10 s and each of 3 parts ``part_s``: the floor is
    the median of the faster way (3 parts one after the other: 3 s, or 15 s) and its threads."""
    import threading
    import types

    from splitrender.evaluation import bench

    now = [0.0]
    lock = threading.Lock()
    real = np.copyto

    def copyto(dst: np.ndarray, src: np.ndarray) -> None:
        with lock:
            now[0] += 10.0 if len(src) == 1001 else part_s
        real(dst, src)

    monkeypatch.setattr(np, "copyto", copyto)
    monkeypatch.setattr(bench, "time", types.SimpleNamespace(perf_counter=lambda: now[0]))
    assert bench.copy_floor_s(1001, 3, repeats=3) == expected


def test_bench_rows_are_the_median_and_the_copy_floor_of_the_bytes_touched(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """run_bench's accounting with fake timings: the median and slowest sample, per pixel, the
    copy floor measured on each method's bytes touched (of the two server frames) on rayon's
    threads, GB/s and the ratio from them."""
    import tempfile

    from splitrender.evaluation import bench

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    samples = [3e-3, 1e-3, 2e-3, 10e-3, 4e-3]  # median 3 ms, slowest 10 ms
    timed: list[str] = []

    def time_frames(one, requests, frames, **kw):  # type: ignore[no-untyped-def]
        one(requests[0])
        timed.append(str(frames))
        return samples

    floors: list[tuple[int, int]] = []

    def copy_floor_s(nbytes: int, threads: int = 1, repeats: int = 5) -> tuple[float, int]:
        floors.append((nbytes, threads))
        return 5e-4, 7

    monkeypatch.setattr(bench, "time_frames", time_frames)
    monkeypatch.setattr(bench, "copy_floor_s", copy_floor_s)
    machine = Machine("Test CPU (family 1, model 2)", 3, "avx2")
    monkeypatch.setattr(bench, "this_machine", lambda: machine)
    # The machine's CPU times before each method and after its floor: the host took 10 % of
    # the first interval, and from then on the readings are 200 ticks apart with 5 stolen.
    readings = itertools.count()

    def cpu_times() -> CpuTimes:
        k = next(readings)
        return CpuTimes(total=200 * k, steal=0 if k == 0 else 15 + 5 * k)

    monkeypatch.setattr(bench, "cpu_times", cpu_times)
    rows = bench.run_bench("courtyard", sr.METHODS, 0.02, frames=5, repeats=1, progress=False)
    rec = bench._recording("courtyard", 0.02, lambda _: None)
    f0, f1 = rec.server_frames[0], rec.server_frames[1]
    w, h = f0.main.camera.width, f0.main.camera.height
    assert [r.method for r in rows] == list(sr.METHODS) and timed == ["5"] * len(rows)
    for r, (nbytes, threads) in zip(rows, floors):
        assert nbytes == bytes_touched(r.method, f0, f1) and threads == bench.kernel_threads()
        assert (r.width, r.height, r.backend) == (w, h, "cpu")
        assert r.ms_per_frame == pytest.approx(3.0, rel=1e-12)
        assert r.ms_per_frame_max == pytest.approx(10.0, rel=1e-12)
        assert r.ns_per_pixel == pytest.approx(3e6 / (w * h), rel=1e-12)
        assert r.mb_touched == pytest.approx(nbytes / 1e6, rel=1e-12)
        assert r.gb_per_s == pytest.approx(nbytes / 3e-3 / 1e9, rel=1e-12)
        assert r.copy_floor_ms == pytest.approx(0.5, rel=1e-12) and r.copy_threads == 7
        assert r.ratio_to_floor == pytest.approx(6.0, rel=1e-12)
        assert list(r.to_json()) == list(bench.BENCH_KEYS)
        assert r.to_json()["ratio_to_floor"] == r.ratio_to_floor
        assert (r.processor, r.cpus, r.simd) == ("Test CPU (family 1, model 2)", 3, "avx2")
    assert [r.host_steal_pct for r in rows] == [10.0] + [2.5] * (len(rows) - 1)
    # The table says where it was measured before anything else, and the host's share last.
    table = bench.format_rows(rows).splitlines()
    assert table[0] == "machine: Test CPU (family 1, model 2), 3 CPUs, CPU row loops AVX2"
    assert table[2].split()[-2:] == ["steal", "%"]
    assert [line.split()[-1] for line in table[3:-1]] == ["10.0"] + ["2.5"] * (len(rows) - 1)
    # The host took 5 % or more while the first method was timed: a note names it, last.
    assert table[-1] == (
        f"note: the virtual machine's host took 5 % or more of the CPU time while "
        f"{rows[0].method} was timed (steal): the figures include its time; run again when it "
        "takes none"
    )
    assert "note:" not in bench.format_rows(rows[1:])
    # Where the platform does not count it: n/a.
    bare = dataclasses.replace(rows[0], host_steal_pct=None)
    assert bench.format_rows([bare]).splitlines()[-1].split()[-1] == "n/a"


def test_a_damaged_cached_recording_is_rendered_again(tmp_path, monkeypatch) -> None:
    # A flipped byte in a cached frame failed every later bench ("SHA-256 does not match the
    # manifest"), reported as the user's error: the manifest was checked, not the frames.
    import tempfile

    from splitrender.evaluation.bench import _recording

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    said: list[str] = []
    first = _recording("courtyard", 0.02, said.append)
    frame = first.path / "server" / "000001.npz"
    data = bytearray(frame.read_bytes())
    data[len(data) // 2] ^= 0x55
    frame.write_bytes(data)
    again = _recording("courtyard", 0.02, said.append)
    again.verify()
    assert [s.split()[0] for s in said] == ["rendering", "rendering"]
    assert _recording("courtyard", 0.02, said.append).path == first.path
    assert said[-1].startswith("reusing the cached recording")


@pytest.mark.parametrize(
    ("argv", "words"),
    [
        # An IndexError of the key-frame mean (no frame timed).
        (["--frames", "0", "--sizes", "64x36"], ("--frames", "1..100000", "got 0")),
        # The scene's InvalidInputError, a traceback naming "width".
        (["--sizes", "0x0", "--frames", "1"], ("--sizes", "WxH", "1..16384", "'0x0'")),
        # ValueError of int().
        (["--sizes", "abc"], ("--sizes", "WxH", "'abc'")),
        (["--sizes", "64x36,64", "--frames", "1"], ("--sizes", "'64'")),
        # Sides the scene takes, but a picture of the stream the codec cannot carry.
        (["--sizes", "16384x16", "--frames", "1"], ("--sizes", "picture.color 24576x32")),
        (["--paper-mbps", "0", "--sizes", "64x36", "--frames", "1"], ("--paper-mbps", "got 0")),
        # Within the option's range, but scaled to the size beyond CodecConfig's.
        (["--paper-mbps", "100000", "--sizes", "2600x1440", "--frames", "1"],
         ("--paper-mbps", "2600x1440", "at most the codec's 100000 Mb/s")),
        (["--preset", "fastest", "--sizes", "64x36", "--frames", "1"],
         ("--preset", "'fastest'", "superfast")),
    ],
)
def test_bench_codec_argument_errors_are_one_line_and_exit_2(
    argv: list[str], words: tuple[str, ...], capsys: pytest.CaptureFixture[str]
) -> None:
    from splitrender.cli.bench_codec import main

    with pytest.raises(SystemExit) as e:
        main(argv)
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith("python -m splitrender.cli.bench_codec: error: argument ")
    assert err.count("\n") == 1 and all(w in err for w in words), err


def test_bench_realtime_names_the_stream_option_and_path_of_a_file_that_is_no_stream(
    tmp_path, monkeypatch, capsys
) -> None:
    # It said "afile: file of 6 bytes has no header": the file's bare name, not where it is nor
    # which option gave it.
    from splitrender.cli.dispatch import main

    monkeypatch.chdir(tmp_path)
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "afile").write_text("hello\n")
    sr.write_stream(tmp_path / "sub" / "empty.srs", [])
    argv = ["bench", "--realtime", "--seconds", "0.25", "--quiet", "--stream"]
    assert main([*argv, "sub/afile"]) == 2
    assert capsys.readouterr().err == (
        "splitrender: error: --stream: sub/afile: file of 6 bytes has no header\n")
    assert main([*argv, "sub/empty.srs"]) == 2
    assert capsys.readouterr().err == (
        "splitrender: error: --stream: sub/empty.srs: the stream has no frames\n")


@pytest.mark.parametrize("gap", [5e-324, 1e-9])
def test_bench_realtime_takes_the_server_rate_from_the_stream_files_header(
    tmp_path, capsys, gap: float
) -> None:
    # The rate was taken from the first two packets' times: a gap of 5e-324 s raised
    # OverflowError ("internal error", exit 1) and one of 1e-9 s planned 10^9 packets a second
    # of the run, which grew without bound (900 MB in a minute) instead of running 0.1 s.
    from splitrender.cli.dispatch import main
    from splitrender.codec.coder import CodecConfig, StreamEncoder
    from splitrender.codec.stream import pack_packet, unpack_packet

    scene = sr.SyntheticScene(dynamic=True)
    with StreamEncoder(CodecConfig(bitrate_mbps=0.5)) as enc:
        packets = [enc.encode(scene.server_frame(i, i / 10, 32, 18)) for i in range(2)]
    packets[1] = pack_packet(dataclasses.replace(unpack_packet(packets[1]), time=gap))
    sr.write_stream(tmp_path / "s.srs", packets, fps=10.0)
    out = tmp_path / "rt.json"
    assert main(["bench", "--realtime", "--stream", str(tmp_path / "s.srs"), "--seconds", "0.1",
                 "--display-priority", "normal", "--json", str(out), "--quiet"]) == 0, (
        capsys.readouterr().err)
    assert out.is_file()
