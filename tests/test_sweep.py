"""``eval``'s sweep engine (docs/sweeps.md): the same results.json bytes from the local
executor with one and two processes and from Ray on a local 2-CPU cluster; a sweep interrupted
by a failing task resumes without recomputing what finished; clear errors for a Ray cluster
that does not answer and for Ray missing. Tiny: one scene at 77x43, 0.3 s."""

from __future__ import annotations

import contextlib
import dataclasses
import json
import socket
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import splitrender as sr
from splitrender.cli import main
from splitrender.evaluation import sweep
from splitrender.evaluation.experiments import ROW_KEYS, EvalConfig, run_eval

pytest.importorskip("av")

# One scene, dynamic only, two methods: render 4 (4 server frames in one chunk, 36 client frames
# in two, the recording assembled from them), encode 1, score 4 (Table 1: ours, timewarp;
# Table 2: ours at l = 0, ours_extrapolate).
SWEEP = ["eval", "--scale", "0.03", "--seconds", "0.3", "--scenes", "courtyard", "--variants",
         "dynamic", "--methods", "ours,timewarp", "--delays", "0", "--no-vmaf", "--quiet"]
TASKS = {"render": 4, "encode": 1, "score": 4}


def _config(out: Path, cache: Path, **kw: Any) -> EvalConfig:
    return EvalConfig(out=out, cache=cache, scenes=("courtyard",), variants=("dynamic",),
                      methods=("ours", "timewarp"), delays=(0,), scale=0.03, seconds=0.3,
                      vmaf=False, progress=False, **kw)


def _info(out: Path) -> dict[str, Any]:
    data: dict[str, Any] = json.loads((out / "run-info.json").read_text())
    return data


@pytest.fixture(scope="module")
def serial(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The sweep on the local executor in this process (--jobs 1), with its own cache."""
    work = tmp_path_factory.mktemp("sweep")
    assert main([*SWEEP, "--jobs", "1", "--cache", str(work / "cache"),
                 "--out", str(work / "out")]) == 0
    return work / "out"


def test_flip_every_rescores_only_and_is_stated(serial: Path, tmp_path: Path) -> None:
    """--flip-every changes the score tasks only (the recordings and streams come from the
    cache), SSIM stays the same, FLIP is the mean over the sampled frames, and the tables say
    so."""
    out = tmp_path / "out"
    assert main([*SWEEP, "--flip-every", "5", "--cache", str(serial.parent / "cache"),
                 "--out", str(out)]) == 0
    info = _info(out)
    assert info["computed"] == {"render": 0, "encode": 0, "score": TASKS["score"]}
    every = json.loads((serial / "results.json").read_text())
    sampled = json.loads((out / "results.json").read_text())
    assert [r["ssim"] for r in sampled] == [r["ssim"] for r in every]
    assert [r["flip"] for r in sampled] != [r["flip"] for r in every]
    assert "FLIP on every 5th of those frames only" in (out / "tables.md").read_text()


def test_results_have_no_run_details_and_run_info_has_them(serial: Path) -> None:
    text = (serial / "results.json").read_text()
    rows = json.loads(text)
    assert [(r["method"], r["bitrate_mbps"] is None) for r in rows] == [
        ("ours", True), ("timewarp", True), ("ours", False), ("ours_extrapolate", False)]
    info = _info(serial)
    assert info["tasks"] == info["computed"] == TASKS and info["executor"] == "local"
    assert all(list(r) == list(ROW_KEYS) for r in rows)  # no host, time or executor
    assert {"host", "seconds", "executor"} <= set(info)


def test_two_local_processes_give_the_same_bytes(serial: Path, tmp_path: Path) -> None:
    assert main([*SWEEP, "--jobs", "2", "--cache", str(tmp_path / "cache"),
                 "--out", str(tmp_path / "out")]) == 0
    assert _info(tmp_path / "out")["computed"] == TASKS  # computed again, not read back
    assert (tmp_path / "out" / "results.json").read_bytes() == (
        serial / "results.json").read_bytes()


def test_interrupted_sweep_resumes_without_recomputing(serial: Path, tmp_path: Path) -> None:
    started: list[sweep.Task] = []

    def fail_sixth(task: sweep.Task) -> None:
        started.append(task)
        if len(started) == 6:
            raise RuntimeError("injected fault")

    cache, out = tmp_path / "cache", tmp_path / "out"
    with pytest.raises(sweep.TaskFailedError) as e:
        run_eval(_config(out, cache), fault=fail_sixth)
    message = str(e.value)
    # Which task, on what, why, and how to resume.
    assert started[5].key[:12] in message and "injected fault" in message
    assert started[5].label in message and "run the same command again" in message
    # Finished: the three chunks, the recording assembled from them, one score row.
    assert [t.stage for t in started[:5]] == ["render"] * 4 + ["score"]
    assert len(list((cache / "rows").glob("*.json"))) == 1
    assert not any((cache / "chunks").iterdir())  # removed once assembled

    again: list[str] = []
    res = run_eval(_config(out, cache), fault=lambda t: again.append(t.key))
    assert res.stats is not None
    # Nothing that had finished ran again (nor the chunks of the cached recording).
    assert not {t.key for t in started[:5]} & set(again) and len(again) == 4
    assert res.stats.cached == {"render": 4, "encode": 0, "score": 1}
    assert (out / "results.json").read_bytes() == (serial / "results.json").read_bytes()

    # A third run on the same cache computes nothing.
    third: list[str] = []
    res = run_eval(_config(tmp_path / "out3", cache), fault=lambda t: third.append(t.key))
    assert third == [] and res.stats is not None and res.stats.cached == TASKS


def test_ray_missing_is_one_line_with_what_to_install(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    import sys

    monkeypatch.setitem(sys.modules, "ray", None)  # import ray raises ImportError
    assert main([*SWEEP, "--executor", "ray", "--cache", str(tmp_path / "c"),
                 "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "pip install 'splitrender[ray]'" in err
    # Refused before the cache and the outputs are made.
    assert not (tmp_path / "c").exists() and not (tmp_path / "o").exists()


def test_address_without_ray_executor_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main([*SWEEP, "--address", "127.0.0.1:6379", "--cache", str(tmp_path / "c"),
                 "--out", str(tmp_path / "o")]) == 2
    assert "--executor ray" in capsys.readouterr().err


# ------------------------------------------------------------------------------------- Ray


@pytest.fixture(scope="module")
def local_ray() -> Iterator[Any]:
    """A local Ray of 2 CPUs for this module; ``eval --executor ray`` joins it (ray.init is
    not called again) instead of starting its own."""
    ray = pytest.importorskip("ray")
    ray.init(num_cpus=2, include_dashboard=False, object_store_memory=200 * 1024**2,
             log_to_driver=False, configure_logging=False)
    try:
        yield ray
    finally:
        ray.shutdown()


def test_ray_gives_the_local_bytes(serial: Path, local_ray: Any, tmp_path: Path) -> None:
    assert main([*SWEEP, "--executor", "ray", "--jobs", "2", "--cache", str(tmp_path / "cache"),
                 "--out", str(tmp_path / "out")]) == 0
    info = _info(tmp_path / "out")
    assert info["executor"] == "ray" and info["computed"] == TASKS
    assert (tmp_path / "out" / "results.json").read_bytes() == (
        serial / "results.json").read_bytes()


def test_dataset_through_both_executors(local_ray: Any, tmp_path: Path) -> None:
    rec = sr.write_recording(tmp_path / "rec", "courtyard", seconds=0.3, scale=0.03)
    ds = sr.export_dataset(rec, tmp_path / "ds")
    results = []
    for executor in ("local", "ray"):
        out = tmp_path / executor
        assert main(["eval", "--dataset", str(ds), "--methods", "ours", "--no-vmaf", "--quiet",
                     "--executor", executor, "--cache", str(tmp_path / f"cache-{executor}"),
                     "--out", str(out)]) == 0
        assert _info(out)["computed"]["score"] == 1
        results.append((out / "results.json").read_bytes())
    assert results[0] == results[1]
    assert [r["method"] for r in json.loads(results[0])] == ["ours"]


@contextlib.contextmanager
def _listener(kind: str) -> Iterator[str]:
    """A loopback address that is not a Ray cluster, of one ``kind``:
    ``refused`` (nothing listens), ``backlog`` (a full accept queue: the TCP connection itself
    times out), ``silent`` (accepts and never answers), ``http1`` (answers, but not gRPC)."""
    with socket.socket() as lsock:
        lsock.bind(("127.0.0.1", 0))
        port = lsock.getsockname()[1]
        held: list[socket.socket] = []
        stop = threading.Event()
        if kind == "refused":
            lsock.close()
        elif kind == "backlog":
            # listen(0) queues one connection; with it never accepted, the kernel drops the
            # next SYNs, so a client's connect() waits until its own timeout.
            lsock.listen(0)
            held.append(socket.create_connection(("127.0.0.1", port), 5))
        else:
            lsock.listen(8)
            lsock.settimeout(0.05)

            def serve() -> None:
                while not stop.is_set():
                    try:
                        conn, _ = lsock.accept()
                    except TimeoutError:
                        continue
                    held.append(conn)
                    if kind == "http1":
                        conn.sendall(b"HTTP/1.1 400 Bad Request\r\nContent-Length: 0\r\n\r\n")

            thread = threading.Thread(target=serve, daemon=True)
            thread.start()
        try:
            yield f"127.0.0.1:{port}"
        finally:
            stop.set()
            if kind in ("silent", "http1"):
                thread.join(5)
            for c in held:
                c.close()


@pytest.mark.parametrize("kind", ["refused", "backlog", "silent", "http1", "unresolvable",
                                  "malformed"])
def test_unreachable_cluster_is_a_bounded_one_line_error(
    kind: str, tmp_path: Path, capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Whatever is (or is not) at ``--address``, eval stops within a bounded time with one
    line naming the address, instead of ``ray.init`` retrying for minutes (it waited more
    than 5 minutes on a silent listener before this check). Tests talk to loopback only: a
    name under ``.invalid`` never resolves."""
    pytest.importorskip("ray")
    monkeypatch.setattr(sweep, "CONNECT_TIMEOUT_S", 0.5)
    fixed = {"unresolvable": "nowhere.invalid:6379", "malformed": "nowhere"}
    with contextlib.ExitStack() as stack:
        address = fixed.get(kind) or stack.enter_context(_listener(kind))
        start = time.monotonic()
        assert main([*SWEEP, "--executor", "ray", "--address", address,
                     "--cache", str(tmp_path / "c"), "--out", str(tmp_path / "o")]) == 2
        # Generous: the check waits at most twice CONNECT_TIMEOUT_S (connect, then answer).
        assert time.monotonic() - start < 30.0
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--address" in err and address in err
    if kind in ("backlog", "silent"):
        assert "nothing answered within 0.5 s" in err
    if kind == "http1":
        assert "not a Ray cluster" in err


def test_the_address_check_accepts_a_real_ray_head(local_ray: Any) -> None:
    """The gRPC handshake probe passes against Ray's own head (GCS) of the local cluster."""
    sweep._check_reachable(local_ray.get_runtime_context().gcs_address)


def _failing_graph(tmp_path: Path) -> tuple[list[sweep.Task], sweep.Cache]:
    """Two independent score tasks: one returns (``operator.eq``, writing nothing), the other
    raises in the worker (``json.loads`` of a Task is a TypeError)."""
    cache = sweep.Cache(tmp_path / "cache")
    cache.prepare()
    good = sweep.make_task("score", "operator:eq", {"n": 1}, label="a task that works")
    bad = sweep.make_task("score", "json:loads", {"n": 2}, paths={"input": "/some/file"},
                          label="a task that fails")
    return [good, bad], cache


@pytest.mark.parametrize("executor", ["local", "ray"])
def test_a_failing_task_is_named_with_its_inputs(
    executor: str, tmp_path: Path, request: pytest.FixtureRequest
) -> None:
    if executor == "ray":
        request.getfixturevalue("local_ray")
    tasks, cache = _failing_graph(tmp_path)
    with pytest.raises(sweep.TaskFailedError) as e:
        sweep.run_graph(tasks, cache, executor=executor, jobs=2)
    message = str(e.value)
    assert "a task that fails" in message and "input=/some/file" in message
    assert "TypeError" in message and str(cache.root) in message
    assert "a task that works" not in message


def test_timewarp_frames_hold_one_copy_of_each_stack(tmp_path: Path) -> None:
    """The timewarp lines' frames are read back holding one copy of the colour and depth stacks
    (every frame a view of it), not one decompressed copy per frame (N² memory: 13 GB for the
    60 FPS line at 320x180), with the values written."""
    import numpy as np
    from splitrender.evaluation.sweep_tasks import _timewarp_frames

    n, h, w = 7, 5, 6
    rng = np.random.default_rng(3)
    color = rng.integers(0, 256, (n, h, w, 3), dtype=np.uint8)
    depth = rng.random((n, h, w), dtype=np.float32)
    view = np.stack([np.eye(4)] * n)
    proj = np.stack([np.diag([1.0, 1.0, -1.0, 0.0])] * n)
    path = tmp_path / "tw.npz"
    np.savez(path, index=np.arange(n, dtype=np.int64), time=np.arange(n) / 30.0, view=view,
             proj=proj, color=color, depth=depth)
    frames = _timewarp_frames(path)
    assert [f.index for f in frames] == list(range(n))
    for k, f in enumerate(frames):
        np.testing.assert_array_equal(f.main.color, color[k])
        np.testing.assert_array_equal(f.main.depth, depth[k])
    for name in ("color", "depth"):
        bases = {id(getattr(f.main, name).base) for f in frames}
        assert len(bases) == 1, f"{name}: {len(bases)} copies of the stack for {n} frames"


def test_a_worker_that_dies_is_named_with_its_task(tmp_path: Path) -> None:
    """A worker process killed while running a task (as the kernel's OOM killer does) fails the
    sweep naming that task (among those running beside it: the pool cannot tell whose worker
    died) and what probably happened."""
    import sys

    (tmp_path / "sweep_dying_worker.py").write_text(
        "import os\n\ndef die(task, cache):\n    os._exit(9)\n")
    sys.path.insert(0, str(tmp_path))  # the spawned workers get this process's sys.path
    try:
        cache = sweep.Cache(tmp_path / "cache")
        cache.prepare()
        dies = sweep.make_task("score", "sweep_dying_worker:die", {"n": 1},
                               label="a task whose worker dies")
        queued = [sweep.make_task("score", "operator:eq", {"n": k}, label=f"queued task {k}")
                  for k in range(2, 6)]
        with pytest.raises(sweep.TaskFailedError) as e:
            sweep.run_graph([dies, *queued], cache, executor="local", jobs=2)
    finally:
        sys.path.remove(str(tmp_path))
    message = str(e.value)
    assert "a task whose worker dies" in message and "worker process running it died" in message
    assert "--jobs" in message


def test_a_failing_task_in_one_process_is_named_not_an_internal_error(tmp_path: Path) -> None:
    # With --jobs 1 no process pool is made, so `concurrent.futures.process` was never imported
    # and naming the failure raised AttributeError: every failed task of `eval` (a run whose
    # frames all arrive too late, say) became "internal error". A fresh interpreter, since the
    # test session has imported the submodule long before.
    import subprocess
    import sys

    code = (
        "import sys\n"
        "from pathlib import Path\n"
        "from splitrender.evaluation import sweep\n"
        "t = sweep.Task('k' * 64, 'score', 'm:f', {}, label='a task')\n"
        "print(sweep._failed(t, ValueError('bad'), sweep.Cache(Path(sys.argv[1])), 0))\n"
    )
    out = subprocess.run([sys.executable, "-c", code, str(tmp_path)], capture_output=True,
                         text=True, timeout=60, check=False)
    assert out.returncode == 0, out.stderr
    assert "task score kkkkkkkkkkkk (a task) failed: ValueError: bad." in out.stdout
    # The caller's error fails the same way again: the advice says to fix it first.
    from splitrender.errors import InvalidInputError

    task = sweep.Task("k" * 64, "score", "m:f", {}, label="a task")
    message = str(sweep._failed(task, InvalidInputError("bad"), sweep.Cache(tmp_path), 3))
    assert message.endswith("3 task(s) finished and are kept in the cache "
                            f"{tmp_path}; run the command again once that is fixed to resume "
                            "from there")


def _damaged_cache(serial: Path, tmp_path: Path) -> Path:
    """A copy of the serial sweep's cache, to damage."""
    import shutil

    cache = tmp_path / "cache"
    shutil.copytree(serial.parent / "cache", cache, symlinks=True)
    return cache


def _eval(cache: Path, out: Path, capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    code = main([*SWEEP, "--jobs", "1", "--cache", str(cache), "--out", str(out)])
    return code, capsys.readouterr().err


@pytest.mark.parametrize("content", ['{"ssim": 0.5}\n', '{"ssim": "0.5", "flip": null, "psnr":'
                                     ' null, "vmaf": null, "mse": null, "frames": 3, "mbps": 1}',
                                     # A 300-digit SSIM in tables.md before.
                                     '{"ssim": 1e300, "flip": null, "psnr": null, "vmaf": null,'
                                     ' "mse": null, "frames": 3, "mbps": 1}',
                                     "not json"])
def test_a_damaged_cached_row_is_named_with_what_to_remove(
    serial: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str], content: str
) -> None:
    """A cached row that is not what a score task writes (missing or mistyped fields, not
    JSON) is named, with the entry to remove: it was an internal KeyError or numpy's TypeError.
    The failed run writes no outputs and no links to its recordings. Removed as told, the next
    run computes it again and gives the sweep's bytes."""
    import re

    cache = _damaged_cache(serial, tmp_path)
    rows = sorted((cache / "rows").glob("*.json"))  # the other tests' rows too: all damaged
    for row in rows:
        row.write_text(content)
    code, err = _eval(cache, tmp_path / "out", capsys)
    assert code == 2 and "internal error" not in err
    named = re.search(r"(\S+\.json): .*: a damaged cache entry \(changed after it was "
                      r"written\); remove (\S+) and run the same command again", err)
    assert named is not None and named[1] == named[2] and Path(named[1]) in rows, err
    assert not (tmp_path / "out" / "results.json").exists()
    assert not (tmp_path / "out" / "recordings").exists()
    for row in rows:
        row.unlink()
    assert _eval(cache, tmp_path / "out", capsys)[0] == 0
    assert (tmp_path / "out" / "results.json").read_bytes() == \
        (serial / "results.json").read_bytes()


_ROW = {"ssim": 0.9, "flip": 0.1, "psnr": 30.0, "vmaf": 90.0, "mse": 1e-3, "frames": 3,
        "mbps": 1.5}


@pytest.mark.parametrize(
    ("name", "value", "expected"),
    [("ssim", 1e300, r"null or a number in \[-1, 1\]"), ("ssim", 1.5, None), ("ssim", -1.01, None),
     ("flip", 1.5, r"null or a number in \[0, 1\]"), ("flip", -0.1, None),
     ("psnr", 100.5, r"null or a number in \[0, 100\]"), ("psnr", -3.0, None),
     ("vmaf", 1e300, r"null or a number in \[0, 100\]"), ("vmaf", -1.0, None),
     ("mse", 2.0, r"null or a number in \[0, 1\]"), ("mse", -1e-3, None),
     ("frames", 2.5, "an integer >= 0"), ("mbps", -1.0, "a finite number >= 0")],
)
def test_a_cached_row_out_of_its_metrics_ranges_is_damaged(
    tmp_path: Path, name: str, value: float, expected: str | None
) -> None:
    """docs/sweeps.md says a row is checked for fields, types and ranges, but only finiteness
    was: an SSIM of 1e300 reached tables.md with 300 digits. Each metric has its range
    (metrics.py); the values the pipeline makes, its ends included, are read."""
    import re

    cache = sweep.Cache(tmp_path / "cache")
    cache.prepare()
    key = "a" * 64
    path = cache.row(key)
    path.write_text(json.dumps({**_ROW, name: value}))
    what = rf"{name} is {re.escape(repr(value))}, expected {expected or '.*'}"
    with pytest.raises(sweep.DamagedCacheError,
                       match=rf"^{re.escape(str(path))}: {what}: a damaged cache entry \(changed "
                             rf"after it was written\); remove {re.escape(str(path))} and run"):
        cache.read_row(key)
    # The ends of the ranges: identical images give SSIM 1, FLIP 0, PSNR the 100 dB cap (not
    # inf) and MSE 0; a metric not computed is null.
    ends = [{"ssim": 1.0, "flip": 0.0, "psnr": 100.0, "vmaf": 100.0, "mse": 0.0},
            {"ssim": -1.0, "flip": 1.0, "psnr": 0.0, "vmaf": 0.0, "mse": 1.0, "frames": 0,
             "mbps": 0.0},
            {"ssim": None, "flip": None, "psnr": None, "vmaf": None, "mse": None},
            {"ssim": 1 + 2**-52, "mse": 1 + 2**-52, "psnr": -1e-15}]  # rounding in a mean
    for row in ends:
        path.write_text(json.dumps({**_ROW, **row}))
        assert cache.read_row(key) == {**_ROW, **row}


def test_a_damaged_cached_stream_or_recording_names_the_entry(
    serial: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Stream information that is not what an encode task writes, and a cached recording whose
    ground truth fails its SHA-256, fail the task that reads them naming the cache entry to
    remove (a recording's folder, not the frame file)."""
    cache = _damaged_cache(serial, tmp_path)
    for row in (cache / "rows").glob("*.json"):
        row.unlink()  # the score tasks run again and read the stream and the recording
    [info] = (cache / "streams").glob("*.json")
    good = info.read_text()
    info.write_text('{"sizes": [1, -2], "mbps": 3.0}\n')
    code, err = _eval(cache, tmp_path / "out", capsys)
    assert code == 2 and f"{info}: expected " in err and f"remove {info} and run" in err
    # Well-formed, but another stream's sizes: the stream beside it is not the one it describes.
    other = json.loads(good)
    other["sizes"][0] += 1
    info.write_text(json.dumps(other) + "\n")
    code, err = _eval(cache, tmp_path / "out", capsys)
    assert code == 2 and f"{info}: the sizes of another stream than {info.stem}" in err, err

    info.write_text(good)
    for row in (cache / "rows").glob("*.json"):
        row.unlink()  # those that ran before the stream's task failed
    [rec] = (cache / "recordings").iterdir()
    frame = rec / "client" / "000010.npz"  # a ground truth every score task reads
    data = bytearray(frame.read_bytes())
    data[len(data) // 2] ^= 0x01
    frame.write_bytes(bytes(data))
    code, err = _eval(cache, tmp_path / "out", capsys)
    assert code == 2 and "internal error" not in err
    assert f"{frame}: SHA-256 does not match" in err and f"remove {rec} and run" in err


def _fails_reading(task: sweep.Task, cache: sweep.Cache) -> None:
    from splitrender.scene.recording import RecordingError

    raise RecordingError(task.params["message"])


def test_run_task_calls_only_a_file_of_the_cache_a_damaged_entry(tmp_path: Path) -> None:
    # A task's read error names its file first: a file of the cache is a damaged entry to
    # remove; any other file (a --dataset recording, say) or a message without a path is the
    # error as it was.
    from splitrender.scene.recording import RecordingError

    root = tmp_path / "cache"
    inside = root / "recordings" / "k1" / "client" / "000010.npz"
    for message, error in [
        (f"{tmp_path / 'dataset' / 'x.npz'}: SHA-256 does not match", RecordingError),
        ("the recording is empty", RecordingError),
        (f"{inside}: SHA-256 does not match", sweep.DamagedCacheError),
    ]:
        task = sweep.Task(key="k1", stage="score", fn="test_sweep:_fails_reading",
                          params={"message": message})
        with pytest.raises(error) as e:
            sweep.run_task(str(root), task)
        assert type(e.value) is error
    assert f"remove {root / 'recordings' / 'k1'} and run" in str(e.value)


def test_a_trace_changed_since_planning_fails_its_task_as_the_callers_input(
    tmp_path: Path,
) -> None:
    from splitrender.errors import is_user_error
    from splitrender.evaluation.sweep_tasks import _trace
    from splitrender.scene.builtin import TraceError, load_trace

    path = tmp_path / "trace.txt"
    path.write_text("0 0 0 0 0 0 0\n0 0 0 0 0 0 100\n")
    planned = load_trace(path).sha256
    task = sweep.Task(key="k", stage="render", fn="x:y", params={"trace_sha256": planned},
                      paths={"trace": str(path)})
    assert _trace(task).sha256 == planned
    path.write_text("0 0 0 0 0 0 0\n0 0 1 0 0 0 100\n")
    with pytest.raises(TraceError, match=f"^{path}: the trace changed since the sweep was") as e:
        _trace(task)
    assert is_user_error(e.value)


def test_damaged_timewarp_frames_are_refused_before_reading(tmp_path: Path) -> None:
    """The timewarp lines' frames whose npy headers disagree (another frame count, another
    size, another dtype) or claim more than their member holds are refused naming the file,
    before numpy allocates what a header says."""
    import numpy as np
    from splitrender.evaluation.sweep_tasks import _timewarp_frames
    from splitrender.scene.recording import RecordingError

    n, h, w = 3, 5, 6
    good = dict(index=np.arange(n, dtype=np.int64), time=np.arange(n) / 30.0,
                view=np.stack([np.eye(4)] * n),
                proj=np.stack([np.diag([1.0, 1.0, -1.0, 0.0])] * n),
                color=np.zeros((n, h, w, 3), np.uint8), depth=np.zeros((n, h, w), np.float32))
    path = tmp_path / "tw.npz"
    np.savez(path, **good)
    assert len(_timewarp_frames(path)) == n
    without_proj = {k: v for k, v in good.items() if k != "proj"}
    for members in (without_proj, {**good, "extra": good["time"]}):
        np.savez(path, **members)
        with pytest.raises(RecordingError, match=f"^{path}: members \\[.*\\], expected "):
            _timewarp_frames(path)
    for name, bad in (("depth", np.zeros((n, h + 1, w), np.float32)),
                      ("time", np.arange(n + 1) / 30.0),
                      ("color", np.zeros((n, h, w, 3), np.uint16))):
        np.savez(path, **{**good, name: bad})
        with pytest.raises(RecordingError, match=f"{path}: "):
            _timewarp_frames(path)
    # A depth header that claims 90 G elements in a member of 360 bytes (its CRC-32 right).
    import io
    import zipfile

    member = io.BytesIO()
    np.lib.format.write_array(member, good["depth"], version=(1, 0))
    header, huge = b"'shape': (3, 5, 6), }" + b" " * 9, b"'shape': (3, 5, 6000000000), }"
    assert member.getvalue().count(header) == 1 and len(huge) == len(header)  # its padding
    with zipfile.ZipFile(path, "w") as zf:
        for name, a in good.items():
            if name == "depth":
                zf.writestr("depth.npy", member.getvalue().replace(header, huge))
            else:
                with zf.open(f"{name}.npy", "w") as f:
                    np.lib.format.write_array(f, a, version=(1, 0))
    with pytest.raises(RecordingError, match=f"{path}: depth: float32 \\(3, 5, 6000000000\\)"):
        _timewarp_frames(path)


@pytest.mark.parametrize("damage", ["flipped", "grown", "removed"])
def test_a_damaged_chunk_is_not_assembled_into_a_recording(tmp_path: Path, damage: str) -> None:
    """A chunk's frame file changed before the recording is assembled from it is refused: the
    recording's manifest takes the SHA-256 of the bytes it is given, so the damage would pass
    every later check. A file longer than such a frame can be is refused by its size, before
    it is read whole (and hashed)."""
    def stop_at_assembly(task: sweep.Task) -> None:
        if task.fn.endswith(":render_recording"):
            raise RuntimeError("stopped before the assembly")

    cache, out = tmp_path / "cache", tmp_path / "out"
    with pytest.raises(sweep.TaskFailedError, match="stopped before the assembly"):
        run_eval(_config(out, cache), fault=stop_at_assembly)
    frame = sorted((cache / "chunks").glob("*/000001.npz"))[0]
    data = bytearray(frame.read_bytes())
    if damage == "flipped":
        data[len(data) // 2] ^= 0x01
        problem = "SHA-256 does not match the chunk's entries.json"
    elif damage == "grown":  # twice its size: more than its arrays and any header can take
        data += bytes(len(data))
        problem = "chunk frame is more than "
    frame.write_bytes(bytes(data))
    where = frame
    if damage == "removed":
        n = len(list(frame.parent.glob("*.npz")))
        frame.unlink()
        where, problem = frame.parent, f"{n - 1} frames, expected {n}"
    with pytest.raises(sweep.TaskFailedError) as e:
        run_eval(_config(out, cache))
    assert f"{where}: {problem}" in str(e.value)
    assert f"remove {frame.parent} and run" in str(e.value)
    assert not any((cache / "recordings").iterdir())


@pytest.mark.parametrize("aux", [[[9, 9], [9, 9]], []])
def test_server_chunks_with_another_rig_are_not_assembled(tmp_path: Path, aux: Any) -> None:
    """The assembled manifest names one rig's auxiliary cameras: a server chunk whose sizes
    differ from another's is refused with both named, and a server chunk without auxiliary
    cameras is damaged, never an internal error at the manifest."""
    def stop_at_assembly(task: sweep.Task) -> None:
        if task.fn.endswith(":render_recording"):
            raise RuntimeError("stopped before the assembly")

    cache, out = tmp_path / "cache", tmp_path / "out"
    config = dataclasses.replace(_config(out, cache), seconds=0.5)  # two server chunks
    with pytest.raises(sweep.TaskFailedError, match="stopped before the assembly"):
        run_eval(config, fault=stop_at_assembly)
    server = [p for p in sorted((cache / "chunks").glob("*/entries.json"))
              if json.loads(p.read_text())["part"] == "server"]
    assert len(server) == 2
    entries = json.loads(server[1].read_text())
    assert entries["aux"] != aux and len(entries["aux"]) == 2
    server[1].write_text(json.dumps({**entries, "aux": aux}))
    with pytest.raises(sweep.TaskFailedError) as e:
        run_eval(config)
    if aux:
        a, b = (p.parent.name for p in server)  # in either order: the graph's, not ours
        assert (f"server chunks {a} and {b} disagree" in str(e.value)
                or f"server chunks {b} and {a} disagree" in str(e.value))
        assert "on the auxiliary cameras' sizes ([[" in str(e.value)
        assert f"remove {cache / 'chunks'} and run" in str(e.value)
    else:
        assert f"{server[1]}: expected" in str(e.value)
        assert f"remove {server[1].parent} and run" in str(e.value)
    assert not any((cache / "recordings").iterdir())


@pytest.mark.parametrize("damage", ["packet", "trailer", "truncated"])
def test_a_damaged_cached_stream_names_the_stream(
    serial: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str], damage: str
) -> None:
    """A cached stream changed after it was written (a byte of a packet, its trailer, the file
    cut short) fails the score task that plays it naming the stream to remove. Its errors,
    raised when the file is opened or a packet is decoded during the playback, named the file
    by its base name or not at all ("frame 0: packet CRC mismatch"), with the advice to run
    again, which failed the same way."""
    cache = _damaged_cache(serial, tmp_path)
    for row in (cache / "rows").glob("*.json"):
        row.unlink()
    [stream] = (cache / "streams").glob("*.stream")
    data = bytearray(stream.read_bytes())
    if damage == "packet":
        data[100] ^= 0x01
    elif damage == "trailer":  # which says where the index is: the records are then scanned
        data[-10:] = bytes(b ^ 0xFF for b in data[-10:])
    else:
        del data[len(data) // 2:]
    stream.write_bytes(bytes(data))
    code, err = _eval(cache, tmp_path / "out", capsys)
    assert code == 2 and "internal error" not in err, err
    assert f"{stream}: " in err and f"remove {stream} and run" in err, err
    assert f"{stream}: {stream.name}" not in err  # named once
    if damage == "packet":  # found by the decoding, during the playback
        assert f"{stream}: frame 0: packet CRC mismatch" in err, err
    # The advice works: the stream's information beside it kept the encode task from running
    # again, and every later run failed on the missing stream.
    stream.unlink()
    code, err = _eval(cache, tmp_path / "out", capsys)
    assert code == 0, err
    assert (tmp_path / "out" / "results.json").read_bytes() == (
        serial / "results.json").read_bytes()


def test_a_damaged_cached_timewarp_array_names_the_file(serial: Path, tmp_path: Path) -> None:
    """A byte changed in an array of the cached timewarp frames (their npy headers, checked
    first, intact) fails its member's CRC-32 when the arrays are read: that was BadZipFile,
    naming no file, with the advice to run again, which failed the same way."""
    import re

    import numpy as np

    cache = sweep.Cache(tmp_path / "cache")
    cache.prepare()
    # Members of more than the 4 KiB zipfile reads at once: a smaller one is read whole, and
    # its CRC-32 checked, with its header.
    n, h, w = 3, 40, 40
    depth = np.arange(n * h * w, dtype=np.float32).reshape(n, h, w)
    path = cache.timewarp("b" * 64)
    np.savez(path, index=np.arange(n, dtype=np.int64), time=np.arange(n) / 30.0,
             view=np.stack([np.eye(4)] * n), proj=np.stack([np.eye(4)] * n),
             color=np.zeros((n, h, w, 3), np.uint8), depth=depth)
    data = bytearray(path.read_bytes())
    data[data.index(depth.tobytes()) + depth.nbytes // 2] ^= 0x01  # stored, not compressed
    path.write_bytes(bytes(data))
    [rec] = (serial.parent / "cache" / "recordings").iterdir()
    task = sweep.Task("c" * 64, "score", "splitrender.evaluation.sweep_tasks:score_timewarp",
                      {"fps": 10, "source": "timewarp"}, ("r" * 64, "b" * 64),
                      {"recording": str(rec)})
    p = re.escape(str(path))
    with pytest.raises(sweep.DamagedCacheError, match=rf"^{p}: not a valid npz: BadZipFile: .*"
                                                      rf"; remove {p} and run"):
        sweep.run_task(str(cache.root), task)


def _stopped_before_assembly(tmp_path: Path) -> tuple[sweep.Cache, list[sweep.Task]]:
    """A sweep's cache with its chunks made, stopped before the recording's assembly, and the
    tasks it started (the chunks, then the recording)."""
    started: list[sweep.Task] = []

    def stop_at_assembly(task: sweep.Task) -> None:
        started.append(task)
        if task.fn.endswith(":render_recording"):
            raise RuntimeError("stopped before the assembly")

    cache = sweep.Cache(tmp_path / "cache")
    with pytest.raises(sweep.TaskFailedError, match="stopped before the assembly"):
        run_eval(_config(tmp_path / "out", cache.root), fault=stop_at_assembly)
    return cache, started


@pytest.mark.parametrize("when", ["before", "during"])
def test_a_chunk_made_after_another_run_assembled_its_recording_is_not_left(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, when: str
) -> None:
    """Two runs sharing a cache: one run's chunk task finishes after the other run assembled
    the recording and removed its chunks, ``before`` it starts or ``during`` its rendering.
    Its chunk stayed for good (this run's recording task, finding the recording, does not
    run): 1-2 chunks of ~280 MB at 1280x720 for every two runs."""
    from splitrender.evaluation import sweep_tasks

    cache, started = _stopped_before_assembly(tmp_path)
    *parts, rec = started
    assert len(parts) == 3 and all(t.fn.endswith(":render_chunk") for t in parts)
    if when == "before":
        sweep_tasks.render_recording(rec, cache)  # the other run
    else:
        write_atomic = sweep_tasks.write_atomic

        def assembled_meanwhile(path: Path, data: Any) -> None:
            write_atomic(path, data)  # the chunk's entries.json, just before its rename
            sweep_tasks.render_recording(rec, cache)  # the other run

        monkeypatch.setattr(sweep_tasks, "write_atomic", assembled_meanwhile)
    sweep_tasks.render_chunk(parts[0], cache)  # this run's, planned before the assembly
    assert cache.has(rec)
    assert not any((cache.root / "chunks").iterdir())


def test_a_chunk_replaces_an_empty_folder_and_keeps_another_rename_failure(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """An empty folder where the chunk goes is no twin: the chunk replaces it (a check for
    anything there left it empty, and the task done without its chunk). A rename failing for
    another reason with nothing there fails the task and leaves no temporary folder."""
    import errno
    import os
    import shutil

    from splitrender.evaluation import sweep_tasks

    cache, started = _stopped_before_assembly(tmp_path)
    chunk = started[0]
    dest = cache.chunk(chunk.key)
    made = {p.name: p.read_bytes() for p in dest.iterdir()}
    shutil.rmtree(dest)
    dest.mkdir()
    sweep_tasks.render_chunk(chunk, cache)
    assert {p.name: p.read_bytes() for p in dest.iterdir()} == made
    shutil.rmtree(dest)

    def failing(src: Any, dst: Any) -> None:
        raise OSError(errno.EIO, "Input/output error", str(dst))

    monkeypatch.setattr(os, "rename", failing)
    with pytest.raises(OSError, match="Input/output error"):
        sweep_tasks.render_chunk(chunk, cache)
    assert sorted(p.name for p in (cache.root / "chunks").iterdir()) == sorted(
        t.key for t in started[1:-1])


def test_a_chunk_whose_twin_lands_just_before_its_rename_leaves_the_twin(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Two runs render the same chunk: the twin renamed into place between this one's check
    and its rename failed the task (ENOTEMPTY) where docs/sweeps.md says the twin stays."""
    import os

    from splitrender.evaluation import sweep_tasks

    cache, started = _stopped_before_assembly(tmp_path)
    chunk = started[0]
    dest = cache.chunk(chunk.key)
    twin = {p.name: p.read_bytes() for p in dest.iterdir()}
    aside = tmp_path / "twin"
    rename = os.rename
    rename(dest, aside)  # not there yet when this one checks

    def twin_first(src: Any, dst: Any) -> None:
        if Path(dst) == dest:
            rename(aside, dst)  # the twin lands
        rename(src, dst)  # ENOTEMPTY for this one

    monkeypatch.setattr(os, "rename", twin_first)
    sweep_tasks.render_chunk(chunk, cache)
    assert {p.name: p.read_bytes() for p in cache.chunk(chunk.key).iterdir()} == twin
    assert sorted(p.name for p in (cache.root / "chunks").iterdir()) == sorted(
        t.key for t in started[:-1])
