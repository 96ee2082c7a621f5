"""The sweep engine of ``splitrender eval``: a task graph, a content-addressed cache and two
executors (docs/sweeps.md).

A sweep is a list of :class:`Task` in dependency order: *render* (a recording, or the
timewarp lines' server frames) → *encode* (a recording's server frames at one bit-rate, a stream
file) → *score* (one method × delay × bit-rate × eye played and scored: one small JSON row).
Each task's output lives in the :class:`Cache` under the task's key, a SHA-256 of everything
that determines its bytes: the task's parameters, its inputs' keys, the formats' versions and a
fingerprint of the code that renders, encodes, plays and scores (:func:`code_fingerprint`).
A task whose output exists is not run again: a re-run, another sweep sharing tasks, or a sweep
interrupted half-way (finished rows stay in the cache) picks up where the cache stands.

Executors run the same graph:

- ``local`` (:func:`run_local`): ``jobs == 1`` runs the tasks in order in this process;
  ``jobs > 1`` submits each task to a :class:`concurrent.futures.ProcessPoolExecutor` once its
  inputs are done. Needs no Ray.
- ``ray`` (:func:`run_ray`): one ``ray.remote`` task per graph task, its inputs passed as the
  ``ObjectRef``\\ s of the tasks that make them (each returns only its key: the data stays in the
  cache folder, which every node must see), collected with ``ray.wait`` as they finish.

Tasks write their outputs atomically (temporary name, then rename: ``files.write_atomic``,
the recording and stream writers), so a killed task leaves nothing that reads as finished.
"""

from __future__ import annotations

import concurrent.futures as cf
import hashlib
import importlib
import json
import math
import multiprocessing
import os
import re
import socket
import time
from collections.abc import Callable, Sequence
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from splitrender.errors import SplitRenderError, is_user_error
from splitrender.evaluation.metrics import PSNR_CAP_DB
from splitrender.files import JSON_KINDS, read_json, read_regular
from splitrender.progress import Progress

__all__ = [
    "STAGES",
    "Cache",
    "ClusterUnreachableError",
    "DamagedCacheError",
    "RayMissingError",
    "SweepStats",
    "Task",
    "TaskFailedError",
    "code_fingerprint",
    "default_cache_dir",
    "make_task",
    "run_graph",
]

#: The stages of a sweep, in order (a task's ``stage``).
STAGES: tuple[str, ...] = ("render", "encode", "score")
#: Version of the cache's layout and of the tasks' output formats; part of every key.
CACHE_VERSION = 1
#: Seconds to wait for a TCP connection to a Ray cluster's address before giving up.
CONNECT_TIMEOUT_S = 10.0

# The code whose behaviour determines the bytes a task writes (relative to the package). The
# tables, plots and command-line code are not in it: changing them must not re-render.
_FINGERPRINTED = (
    "_native.abi3.so", "_native.pyi", "reproject.py", "types.py", "gpu.py", "imageio.py",
    "scene", "codec", "client", "net", "evaluation/metrics.py", "evaluation/pipeline.py",
    "evaluation/sweep_tasks.py", "evaluation/references.py",
)


class SweepError(SplitRenderError):
    """A sweep that cannot run or did not finish."""


class RayMissingError(SweepError):
    """``--executor ray`` without Ray installed."""


class ClusterUnreachableError(SweepError):
    """The Ray cluster at ``--address`` does not answer."""


class TaskFailedError(SweepError):
    """A task of the sweep raised; the message names the task and its inputs."""


class DamagedCacheError(SweepError):
    """An entry of the :class:`Cache` that does not read back as a task wrote it (a file
    changed or damaged after the fact: the writes are atomic). The message names the entry and
    says to remove it, which makes the next run compute it anew."""


@dataclass(frozen=True)
class Task:
    """One node of the graph. ``fn`` (``"module:function"``) is called in a worker as
    ``fn(task, cache)`` and writes the task's output into ``cache`` under ``key``. ``params``
    are JSON values and part of the key; ``paths`` are places of outside inputs (a dataset's
    recording) that are not part of the key (their content is, through ``params``). ``label``
    names the task and its inputs for progress lines and errors."""

    key: str
    stage: str
    fn: str
    params: dict[str, Any]
    deps: tuple[str, ...] = ()
    paths: dict[str, str] = field(default_factory=dict)
    label: str = ""


_fingerprint: str | None = None


def code_fingerprint() -> str:
    """SHA-256 of the package version, the formats' versions and the files of the code that
    renders, encodes, plays and scores (the native extension included: the renderer is compiled
    into it). Any change to that code gives every task a new key."""
    global _fingerprint
    if _fingerprint is None:
        import splitrender
        from splitrender.codec.stream import PACKET_VERSION, STREAM_VERSION
        from splitrender.scene.recording import VERSION as RECORDING_VERSION

        root = Path(splitrender.__file__).parent
        h = hashlib.sha256()
        h.update(json.dumps({
            "package": splitrender.__version__, "recording": RECORDING_VERSION,
            "stream": STREAM_VERSION, "packet": PACKET_VERSION, "cache": CACHE_VERSION,
        }, sort_keys=True).encode())
        for name in _FINGERPRINTED:
            p = root / name
            files = sorted(p.rglob("*.py")) if p.is_dir() else [p] if p.is_file() else []
            for f in files:
                h.update(str(f.relative_to(root)).encode() + b"\0")
                h.update(hashlib.sha256(f.read_bytes()).digest())
        _fingerprint = h.hexdigest()
    return _fingerprint


def make_task(stage: str, fn: str, params: dict[str, Any], deps: Sequence[Task] = (),
              paths: dict[str, str] | None = None, label: str = "") -> Task:
    """A :class:`Task` with its key: the SHA-256 of ``stage``, ``fn``, ``params``, the inputs'
    keys and :func:`code_fingerprint`."""
    if stage not in STAGES:
        raise ValueError(f"stage: expected one of {', '.join(STAGES)}, got {stage!r}")
    blob = json.dumps({"stage": stage, "fn": fn, "params": params,
                       "deps": [d.key for d in deps], "code": code_fingerprint()},
                      sort_keys=True, separators=(",", ":"), allow_nan=False)
    key = hashlib.sha256(blob.encode()).hexdigest()
    return Task(key, stage, fn, params, tuple(d.key for d in deps), dict(paths or {}), label)


def default_cache_dir() -> Path:
    """``$SPLITRENDER_CACHE``, else ``$XDG_CACHE_HOME/splitrender``, else
    ``~/.cache/splitrender``."""
    env = os.environ.get("SPLITRENDER_CACHE")
    if env:
        return Path(env)
    xdg = os.environ.get("XDG_CACHE_HOME")
    return (Path(xdg) if xdg else Path.home() / ".cache") / "splitrender"


class Cache:
    """The content-addressed store under ``root``: ``chunks/KEY/`` (frames of a recording
    being rendered, removed once it is assembled), ``recordings/KEY/`` (a recording folder),
    ``timewarp/KEY.npz``, ``streams/KEY.stream`` with ``streams/KEY.json`` (written last),
    ``rows/KEY.json`` (one score task's row). An entry exists only once complete."""

    def __init__(self, root: str | os.PathLike[str]) -> None:
        self.root = Path(root)

    def prepare(self) -> None:
        """Creates the folders (raises ``OSError`` when ``root`` cannot be one)."""
        for sub in _SUBFOLDERS:
            (self.root / sub).mkdir(parents=True, exist_ok=True)

    def recording(self, key: str) -> Path:
        return self.root / "recordings" / key

    def timewarp(self, key: str) -> Path:
        return self.root / "timewarp" / f"{key}.npz"

    def stream(self, key: str) -> Path:
        return self.root / "streams" / f"{key}.stream"

    def stream_info(self, key: str) -> Path:
        return self.root / "streams" / f"{key}.json"

    def chunk(self, key: str) -> Path:
        return self.root / "chunks" / key

    def row(self, key: str) -> Path:
        return self.root / "rows" / f"{key}.json"

    def marker(self, task: Task) -> Path:
        """The path whose existence says ``task`` is finished (its last write)."""
        if task.stage == "score":
            return self.row(task.key)
        if task.stage == "encode":
            return self.stream_info(task.key)
        if task.fn.endswith(":render_timewarp"):
            return self.timewarp(task.key)
        if task.fn.endswith(":render_chunk"):
            return self.chunk(task.key) / "entries.json"
        return self.recording(task.key) / "manifest.json"

    def has(self, task: Task) -> bool:
        """Whether ``task``'s output is there; a recording given from outside (``--dataset``,
        keyed by its manifest) always is. A stream is there with both its files: the advice
        for a damaged one is to remove the ``.stream``, after which the ``.json`` marker alone
        kept the encode task from running again, and every later run failed on the missing
        stream."""
        if task.stage == "render" and "given" in task.params:
            return True
        return self.marker(task).is_file() and (
            task.stage != "encode" or self.stream(task.key).is_file())

    def read_row(self, key: str) -> dict[str, Any]:
        """The row a score task wrote (``sweep_tasks._write_part``): ``ssim``, ``flip``,
        ``psnr``, ``vmaf`` and ``mse`` (each null, where not computed, or a number in its range,
        :data:`_METRIC_RANGES`), ``frames`` (an integer ≥ 0) and ``mbps`` (a finite number
        ≥ 0), and nothing else.

        Raises:
            DamagedCacheError: for a file that is not such an object."""
        path = self.row(key)
        data = self._read_json(path, "row")
        if not isinstance(data, dict) or set(data) != _ROW_FIELDS:
            keys = sorted(data) if isinstance(data, dict) else JSON_KINDS[type(data)]
            raise self.damaged(path, f"expected an object with {sorted(_ROW_FIELDS)}, "
                                     f"got {keys}")
        for name, value in sorted(data.items()):
            if name == "frames":
                ok, expected = _count(value), "an integer >= 0"
            elif name == "mbps":
                ok, expected = _finite(value) and value >= 0, "a finite number >= 0"
            else:
                lo, hi = _METRIC_RANGES[name]
                # The bounds are the metrics' own; the slack lets through a mean that rounding
                # put a few ulps past one (an SSIM of 1 + 2e-16), never a damaged value.
                ok = value is None or (_finite(value)
                                       and lo - _RANGE_SLACK <= value <= hi + _RANGE_SLACK)
                expected = f"null or a number in [{lo:g}, {hi:g}]"
            if not ok:
                raise self.damaged(path, f"{name} is {value!r}, expected {expected}")
        return data

    def read_stream_info(self, key: str) -> tuple[list[int], float]:
        """What an encode task wrote beside its stream: each packet's size in bytes and the
        stream's Mb/s.

        Raises:
            DamagedCacheError: for a file that is not ``{"sizes": [int ≥ 0, ...], "mbps":
                number ≥ 0}``."""
        path = self.stream_info(key)
        data = self._read_json(path, "stream information")
        if not (isinstance(data, dict) and set(data) == {"sizes", "mbps"}
                and isinstance(data["sizes"], list) and all(map(_count, data["sizes"]))
                and _finite(data["mbps"]) and data["mbps"] >= 0):
            raise self.damaged(path, 'expected {"sizes": [integers >= 0], "mbps": a number '
                                     ">= 0}")
        return list(data["sizes"]), float(data["mbps"])

    def read_chunk_info(self, key: str) -> tuple[str, list[float], list[str], list[list[int]]]:
        """What a render task wrote last into its chunk (``sweep_tasks.render_chunk``): the
        part (``"server"`` or ``"client"``), each frame's time and its file's SHA-256 (hex),
        and the auxiliary cameras' sizes.

        Raises:
            DamagedCacheError: for a file that is not ``{"part", "times": [numbers],
                "sha256": [64 hex digits, one per time], "aux": [[int, int], ...]}``."""
        path = self.chunk(key) / "entries.json"
        data = self._read_json(path, "chunk entries")
        if not (isinstance(data, dict) and set(data) == {"part", "times", "sha256", "aux"}
                and data["part"] in ("server", "client")
                and isinstance(data["times"], list) and all(map(_finite, data["times"]))
                and isinstance(data["sha256"], list)
                and len(data["sha256"]) == len(data["times"])
                and all(isinstance(d, str) and _SHA256.fullmatch(d) for d in data["sha256"])
                and isinstance(data["aux"], list)
                # A server frame has auxiliary cameras (their sizes), a client frame none.
                and (len(data["aux"]) > 0) == (data["part"] == "server")
                and all(isinstance(a, list) and len(a) == 2 and all(map(_positive, a))
                        for a in data["aux"])):
            raise self.damaged(path, 'expected {"part": "server" or "client", "times": '
                                     '[numbers], "sha256": [one per time], "aux": [[width, '
                                     "height], ...] (a server chunk's cameras; [] for a client "
                                     "chunk)}")
        return data["part"], list(data["times"]), list(data["sha256"]), list(data["aux"])

    def read_file(self, path: Path, limit: int, what: str) -> bytes:
        """The bytes of the cache's file ``path``, at most ``limit`` (``files.read_regular``).

        Raises:
            DamagedCacheError: for a longer file, or one that is not a regular file."""
        data: bytes = self._read(read_regular, path, limit, what)
        return data

    def _read_json(self, path: Path, what: str) -> Any:
        return self._read(read_json, path, 1 << 24, f"cached {what}")

    def _read(self, reader: Callable[[Path, int, str, type[Exception]], Any], path: Path,
              limit: int, what: str) -> Any:
        """``reader(path, limit, what, DamagedCacheError)`` (``files.read_regular`` or
        ``read_json``), its error turned into :meth:`damaged`'s, which names the entry."""
        try:
            return reader(path, limit, what, DamagedCacheError)
        except DamagedCacheError as e:
            raise self.damaged(path, str(e).removeprefix(f"{path}: ")) from None

    def entry(self, path: str | os.PathLike[str]) -> Path | None:
        """The entry of the cache that ``path`` is, or is in (``recordings/KEY``,
        ``streams/KEY.stream``, ...); ``None`` for a path outside the cache's folders."""
        try:
            rel = Path(path).relative_to(self.root)
        except ValueError:
            return None
        if len(rel.parts) < 2 or rel.parts[0] not in _SUBFOLDERS:
            return None
        return self.root / rel.parts[0] / rel.parts[1]

    def damaged(self, path: str | os.PathLike[str], problem: str) -> DamagedCacheError:
        """The error for the cache's file ``path`` that reads back wrong."""
        entry = self.entry(path) or Path(path)
        return DamagedCacheError(
            f"{path}: {problem}: a damaged cache entry (changed after it was written); remove "
            f"{entry} and run the same command again to compute it anew")


#: The cache's folders, one per kind of entry (:class:`Cache`).
_SUBFOLDERS = ("chunks", "recordings", "timewarp", "streams", "rows")
#: The fields of a score task's row in the cache.
_ROW_FIELDS = {"ssim", "flip", "psnr", "vmaf", "mse", "frames", "mbps"}
#: The range of each metric of a row (evaluation/metrics.py): SSIM's map is in [-1, 1] and so
#: its mean; LDR-FLIP's error map in [0, 1]; PSNR is capped at PSNR_CAP_DB (identical images give
#: the cap, not inf) and is >= 0 as the MSE of values in [0, 1] is <= 1; libvmaf's default model
#: clips its score to [0, 100]. Rows hold means of these (over frames, and over eyes).
_METRIC_RANGES = {"ssim": (-1.0, 1.0), "flip": (0.0, 1.0), "psnr": (0.0, PSNR_CAP_DB),
                  "vmaf": (0.0, 100.0), "mse": (0.0, 1.0)}
_RANGE_SLACK = 1e-9
_SHA256 = re.compile("[0-9a-f]{64}")


def _finite(value: object) -> bool:
    return (isinstance(value, (int, float)) and not isinstance(value, bool)
            and math.isfinite(value))


def _count(value: object) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value >= 0


def _positive(value: object) -> bool:
    return _count(value) and value != 0


@dataclass
class SweepStats:
    """What a sweep did: per stage, tasks in the graph, found in the cache, and run now."""

    total: dict[str, int] = field(default_factory=lambda: dict.fromkeys(STAGES, 0))
    cached: dict[str, int] = field(default_factory=lambda: dict.fromkeys(STAGES, 0))
    computed: dict[str, int] = field(default_factory=lambda: dict.fromkeys(STAGES, 0))
    seconds: float = 0.0

    def to_json(self) -> dict[str, Any]:
        return {"tasks": self.total, "cached": self.cached, "computed": self.computed,
                "seconds": round(self.seconds, 3)}


def run_task(root: str, task: Task) -> str:
    """Runs ``task`` (in whichever process) unless its output already exists; returns its key.

    A recording or stream in the cache that fails its checks when the task reads it (each
    error names the file first) is a :class:`DamagedCacheError`, naming the entry to remove."""
    from splitrender.errors import StreamError
    from splitrender.scene.recording import RecordingError

    cache = Cache(root)
    if not cache.has(task):
        module, name = task.fn.split(":")
        fn: Callable[[Task, Cache], None] = getattr(importlib.import_module(module), name)
        try:
            fn(task, cache)
        except (RecordingError, StreamError) as e:
            path, sep, problem = str(e).partition(": ")
            if not sep or cache.entry(path) is None:
                raise
            raise cache.damaged(path, problem) from None
    return task.key


def _ray_task(root: str, task: Task, *inputs: str) -> str:
    """The body of the Ray task: ``inputs`` are the keys the dependencies returned (Ray passes
    an ``ObjectRef`` argument as its value once that task has finished)."""
    return run_task(root, task)


class _Report:
    """Progress of a sweep: one line per finished task with the per-stage counts."""

    def __init__(self, todo: Sequence[Task], stats: SweepStats, progress: Progress) -> None:
        self.left = {s: sum(t.stage == s for t in todo) for s in STAGES}
        self.done = dict.fromkeys(STAGES, 0)
        self.stats = stats
        self.progress = progress

    def finished(self, task: Task) -> None:
        self.done[task.stage] += 1
        self.stats.computed[task.stage] += 1
        counts = ", ".join(f"{s} {self.done[s]}/{self.left[s]}" for s in STAGES if self.left[s])
        self.progress.stage(f"{task.stage}: {task.label} done ({counts})")


def _failed(task: Task, error: BaseException, cache: Cache, finished: int,
            beside: Sequence[Task] = ()) -> TaskFailedError:
    """The error for ``task``; ``beside``: the other tasks running then (named only when a
    worker died, since then any of them may be the one whose worker it was)."""
    inputs = ", ".join(f"{k}={v}" for k, v in sorted(task.paths.items()))
    # Imported by name: `cf.process` exists only once something imported the submodule, so
    # with --jobs 1 (no pool made) every failed task became an internal AttributeError.
    if isinstance(error, BrokenProcessPool):
        # A worker ended without an exception to report: a signal, most often the kernel's OOM
        # killer (two large score tasks at once can outgrow the machine's memory). The pool
        # then fails every task it was running, and cannot say whose worker died.
        others = "".join(f"; or the one running {t.label}" for t in beside)
        what = ("the worker process running it died (killed by the operating system; running "
                f"out of memory is the usual cause: try fewer --jobs){others}")
    else:
        what = f"{type(error).__name__}: {error}"
    # The same command fails the same way on the caller's error: it resumes once that is fixed.
    again = ("run the command again once that is fixed to resume from there"
             if is_user_error(error) else "run the same command again to resume from there")
    return TaskFailedError(
        f"task {task.stage} {task.key[:12]} ({task.label}{'; ' + inputs if inputs else ''}) "
        f"failed: {what}. {finished} task(s) finished and are kept in the cache {cache.root}; "
        f"{again}"
    )


def _worker_init(threads: int) -> None:
    # Each of the N worker processes gets its share of the cores for the native kernels'
    # thread pool (rayon reads this when the extension first runs a parallel kernel).
    os.environ["RAYON_NUM_THREADS"] = str(threads)


def run_local(todo: Sequence[Task], cache: Cache, jobs: int, report: _Report,
              fault: Callable[[Task], None] | None = None) -> None:
    """Runs ``todo`` (dependency order; dependencies outside it are finished) in this process
    (``jobs == 1``) or in ``jobs`` worker processes."""
    if jobs == 1:
        for i, t in enumerate(todo):
            try:
                if fault is not None:
                    fault(t)
                run_task(str(cache.root), t)
            except Exception as e:
                raise _failed(t, e, cache, i) from e
            report.finished(t)
        return
    pending = {t.key: t for t in todo}
    running: dict[cf.Future[str], Task] = {}
    finished = 0
    error: TaskFailedError | None = None
    threads = max(1, (os.cpu_count() or 1) // jobs)
    # spawn: a fork of a process whose native thread pool may already run would copy its
    # locks in whatever state they are in.
    ctx = multiprocessing.get_context("spawn")
    with cf.ProcessPoolExecutor(jobs, mp_context=ctx, initializer=_worker_init,
                                initargs=(threads,)) as pool:
        while pending or running:
            if error is None:
                for key, t in list(pending.items()):
                    # No more submitted than there are workers: the tasks in `running` are the
                    # ones being run, so a worker that dies is reported among them, not a task
                    # that was only queued.
                    if len(running) >= jobs:
                        break
                    if not any(d in pending or d in {r.key for r in running.values()}
                               for d in t.deps):
                        if fault is not None:
                            fault(t)
                        running[pool.submit(run_task, str(cache.root), t)] = t
                        del pending[key]
            else:
                pending.clear()  # after a failure only the running tasks are waited for
            if not running:
                break
            done, _ = cf.wait(running, return_when=cf.FIRST_COMPLETED)
            for fut in done:
                t = running.pop(fut)
                exc = fut.exception()
                if exc is not None:
                    if error is None:
                        error = _failed(t, exc, cache, finished, list(running.values()))
                    continue
                finished += 1
                report.finished(t)
    if error is not None:
        raise error


def check_ray_installed() -> None:
    """Raises :class:`RayMissingError` when Ray cannot be imported, without importing it (which
    takes seconds): for ``--executor ray`` to be refused before any work."""
    import importlib.util

    if importlib.util.find_spec("ray") is None:
        raise RayMissingError(_RAY_MISSING)


_RAY_MISSING = (
    "--executor ray: Ray is not installed; install it with "
    "`pip install 'splitrender[ray]'` (or `pip install 'ray[default]>=2.40,<3'`)"
)


def _import_ray() -> Any:
    try:
        import ray
    except ImportError as e:
        raise RayMissingError(_RAY_MISSING) from e
    return ray


# What a Ray cluster's address answers: Ray's head (GCS, HOST:6379) and its client server
# (ray://HOST:10001) are gRPC servers, and a gRPC server answers the HTTP/2 client preface with
# a SETTINGS frame (RFC 9113 §3.4). Probing that bounds the wait for something that accepts
# connections but is not Ray (another service, a stale port forward), where ``ray.init`` would
# retry for minutes.
_H2_PREFACE = b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n"
_H2_EMPTY_SETTINGS = b"\x00\x00\x00\x04\x00\x00\x00\x00\x00"  # length 0, type 4, stream 0
_H2_SETTINGS = 0x04


def _check_reachable(address: str) -> None:
    """Raises :class:`ClusterUnreachableError` unless ``host:port`` (or ``ray://host:port``)
    accepts a TCP connection and answers as a gRPC server (Ray's head and client server are),
    each within :data:`CONNECT_TIMEOUT_S` (``ray.init`` itself retries for minutes)."""
    if address == "auto":
        return
    hostport = address.split("://", 1)[-1]
    host, sep, port = hostport.rpartition(":")
    if not sep or not port.isdigit() or not host:
        raise ClusterUnreachableError(
            f"--address: expected HOST:PORT, ray://HOST:PORT or auto, got {address!r}")
    expected = "expected the address `ray start --head` printed (HOST:6379) or ray://HOST:10001"
    try:
        with socket.create_connection((host.strip("[]"), int(port)), CONNECT_TIMEOUT_S) as s:
            s.settimeout(CONNECT_TIMEOUT_S)
            s.sendall(_H2_PREFACE + _H2_EMPTY_SETTINGS)
            head = b""
            while len(head) < 9:
                chunk = s.recv(9 - len(head))
                if not chunk:
                    break
                head += chunk
    except TimeoutError as e:
        raise ClusterUnreachableError(
            f"--address {address}: no Ray cluster answers there (nothing answered within "
            f"{CONNECT_TIMEOUT_S:g} s); {expected}"
        ) from e
    except OSError as e:
        raise ClusterUnreachableError(
            f"--address {address}: no Ray cluster answers there ({e}); {expected}"
        ) from e
    if len(head) < 9 or head[3] != _H2_SETTINGS:
        raise ClusterUnreachableError(
            f"--address {address}: something listens there but it is not a Ray cluster (it "
            f"did not answer as a gRPC server); {expected}"
        )


def run_ray(todo: Sequence[Task], cache: Cache, jobs: int, address: str | None, report: _Report,
            init: dict[str, Any] | None = None) -> None:
    """Runs ``todo`` as Ray tasks on the cluster at ``address`` (``None``: a local Ray with
    ``jobs`` CPUs, started now and stopped at the end)."""
    ray = _import_ray()
    if address is not None:
        _check_reachable(address)
    if not todo:
        return
    started = False
    if not ray.is_initialized():
        kwargs: dict[str, Any] = {"include_dashboard": False, "log_to_driver": False,
                                  "configure_logging": False}
        if address is None:
            kwargs["num_cpus"] = jobs
        kwargs.update(init or {})
        try:
            ray.init(address=address, **kwargs)
        except (ConnectionError, RuntimeError, TimeoutError) as e:
            raise ClusterUnreachableError(
                f"--address {address}: cannot join the Ray cluster: {e}") from e
        started = True
    try:
        # Ray schedules each task on one CPU (num_cpus=1), so the native kernels' thread pool
        # of a task gets one thread: N tasks on an N-CPU node use its N cores, no more.
        remote = ray.remote(max_retries=0, num_cpus=1, runtime_env={
            "env_vars": {"RAYON_NUM_THREADS": "1"}})(_ray_task)
        refs: dict[str, Any] = {}
        tasks: dict[Any, Task] = {}
        for t in todo:
            deps = [refs[d] for d in t.deps if d in refs]
            ref = remote.options(name=f"{t.stage}:{t.label}"[:200]).remote(
                str(cache.root), t, *deps)
            refs[t.key] = ref
            tasks[ref] = t
        waiting = list(tasks)
        finished = 0
        while waiting:
            ready, waiting = ray.wait(waiting, num_returns=1)
            t = tasks[ready[0]]
            try:
                ray.get(ready[0])
            except Exception as e:
                for ref in waiting:
                    ray.cancel(ref)
                cause = getattr(e, "cause", None) or e
                raise _failed(t, cause, cache, finished) from e
            finished += 1
            report.finished(t)
    finally:
        if started:
            ray.shutdown()


def run_graph(
    tasks: Sequence[Task], cache: Cache, *, executor: str = "local", jobs: int = 1,
    address: str | None = None, progress: Progress | None = None,
    fault: Callable[[Task], None] | None = None, ray_init: dict[str, Any] | None = None,
) -> SweepStats:
    """Runs every task of ``tasks`` (dependency order, keys unique) whose output is not in
    ``cache``; returns the counts. ``fault(task)`` is called before each task is started (tests
    inject failures with it; local executor only).

    Raises:
        TaskFailedError: a task raised (the finished ones stay in the cache).
        RayMissingError, ClusterUnreachableError: ``executor="ray"`` cannot start.
    """
    start = time.perf_counter()
    stats = SweepStats()
    # A task runs when its output is missing and something needs it: it is a final task (no
    # other depends on it) or a task that runs depends on it. So the chunks of a recording
    # already assembled, or a recording whose rows are all cached, are not made again.
    dependents: dict[str, int] = {}
    for t in tasks:
        for d in t.deps:
            dependents[d] = dependents.get(d, 0) + 1
    needed: set[str] = set()
    for t in reversed(tasks):
        if not cache.has(t) and (t.key in needed or not dependents.get(t.key)):
            needed.add(t.key)
            needed.update(t.deps)
    todo: list[Task] = []
    for t in tasks:
        stats.total[t.stage] += 1
        if t.key in needed and not cache.has(t):
            todo.append(t)
        else:
            stats.cached[t.stage] += 1
    if progress is None:
        progress = Progress(len(todo), enabled=False)
    progress.total = len(todo)
    report = _Report(todo, stats, progress)
    cached = ", ".join(f"{s} {stats.cached[s]}/{stats.total[s]}" for s in STAGES if stats.total[s])
    if progress.enabled:
        print(f"sweep: {len(tasks)} tasks, in the cache {cache.root}: {cached}; "
              f"{len(todo)} to run ({executor}, {jobs} {'job' if jobs == 1 else 'jobs'})",
              file=progress.stream)
    if executor == "ray":
        run_ray(todo, cache, jobs, address, report, ray_init)
    elif executor == "local":
        run_local(todo, cache, jobs, report, fault)
    else:
        raise SweepError(f"--executor: expected local or ray, got {executor!r}")
    stats.seconds = time.perf_counter() - start
    return stats
