"""``splitrender bench``: times client decoding and reprojection on a built-in recording.

A recording of two server frames (and the client frames between them) of the scene's dynamic
variant is rendered once per (scene, scale, version) into the temporary directory and reused.
The two server frames are encoded at the paper's 40 Mb/s scaled by pixel count and decoded
``repeats`` times with a fresh :class:`~splitrender.codec.coder.StreamDecoder`: the decode figure is the
median seconds per server frame (all cameras, all buffers; key and non-key frame together).
Each method then reprojects client frames between the two *decoded* server frames at their
client poses (:func:`~splitrender.reproject.reproject`, no previous frame) with one
:class:`~splitrender.BidirHistory` kept for the pair, as :class:`~splitrender.Client` does: half
a second of untimed calls (the first also does the pair-level work of ``ours``, done once per
server-frame pair; :func:`time_frames` says why half a second), then ``frames`` timed calls
cycling through the client frames; the figure is the median, i.e. the cost of a client frame
inside a pair, in the steady state of a client that renders without pause, and
``ms_per_frame_max`` the slowest of them (a display must hold every frame under its refresh,
not the median one).

With ``backend="wgpu"`` (:mod:`splitrender.gpu`) the pair a method uses is uploaded to the device
once, and each timed call uploads the client pose, runs the frame and downloads the image (the
previous output stays on the device): the device-resident client, not the per-call API.

``ns_per_pixel`` divides it by the output pixels (main camera). The effective GB/s is an
estimate: bytes touched = every source buffer the method reads (its ``nbytes``) + the output
image written (``W·H·3``), divided by the median time. The buffers read per method:

- ``ours``: every camera (main + 2 auxiliary) of both frames: colour, depth, the older frame's
  forward and the newer frame's backward motion and shadow buffers (bits, min, max);
- ``ours_extrapolate``: every camera of the frame it extrapolates from: colour, depth, backward
  motion and shadows;
- ``forward_splat``: every camera of that frame (its auxiliary cameras fill what the main one
  leaves): colour, depth, backward motion;
- ``timewarp``: that frame's main camera: colour, depth;
- ``backward_bidir``: the main camera of both frames: colour, depth, the directional motion.

The unidirectional methods extrapolate from the newest frame at or before the client time: in
the bench, whose client frames lie between the two server frames, the older one.

Intermediate buffers (splat grids, history) are not counted, so it is a lower bound of the
traffic.

The memory-copy floor is measured in the same run, right after each method: the median time of
a copy (:func:`numpy.copyto`) of as many bytes as the method touches, between two buffers already
in memory, on as many threads as the CPU methods run on (rayon's pool, ``copy_threads``; the
bytes in as many equal parts copied at once), or on one where that is faster (a small copy, whose
threads cost more to start than they save). No method can touch its bytes faster than they can
be copied with the cores it has, so ``ms_per_frame / copy_floor_ms`` says how far a method is
from the hardware on this machine today (this VM's speed drifts from day to day; the ratio much
less). Until 2026-12-05 the floor was one thread's copy, which on the Intel Xeon of that day
took 2–2.7× as long as two threads' (docs/performance.md, "The copy floor on the kernel's
threads").

Each row also records the machine (:mod:`splitrender.machine`): ``processor``,
``cpus`` and ``simd``, the instruction set of the CPU kernels' row loops; the table's first line
says them. ``host_steal_pct`` (the table's ``steal %``) is the share of the machine's CPU time
that a virtual machine's host took while the method and its floor were timed: a row timed while
the host took a tenth of the cores is slower for that, not for the method.
"""

from __future__ import annotations

import math
import os
import statistics
import tempfile
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from splitrender.errors import InvalidInputError
from splitrender.machine import (
    cpu_times,
    describe_recorded,
    host_busy,
    steal_note,
    steal_share,
    this_machine,
    usable_cpus,
)
from splitrender.progress import Progress
from splitrender.reproject import METHODS
from splitrender.types import CameraFrame, ServerFrame, ShadowBuffers

__all__ = [
    "BENCH_KEYS",
    "WARM_UP_S",
    "BenchArgumentError",
    "BenchRow",
    "bytes_touched",
    "run_bench",
    "time_frames",
]

#: Keys of each JSON row, in order.
BENCH_KEYS: tuple[str, ...] = (
    "method",
    "backend",
    "width",
    "height",
    "ms_per_frame",
    "ms_per_frame_max",
    "ns_per_pixel",
    "decode_ms_per_server_frame",
    "copy_floor_ms",
    "copy_threads",
    "ratio_to_floor",
    "processor",
    "cpus",
    "simd",
    "host_steal_pct",
)


class BenchArgumentError(InvalidInputError):
    """A bench argument that cannot work."""


@dataclass(frozen=True)
class BenchRow:
    method: str
    backend: str
    width: int
    height: int
    ms_per_frame: float
    ms_per_frame_max: float
    ns_per_pixel: float
    decode_ms_per_server_frame: float
    gb_per_s: float
    mb_touched: float
    copy_floor_ms: float
    copy_threads: int = 1
    #: The machine (:mod:`splitrender.machine`): the processor in words, the CPUs
    #: the process could run on and the instruction set of the CPU kernels' row loops.
    processor: str = ""
    cpus: int = 0
    simd: str = ""
    #: The share of the machine's CPU time, in per cent, that a virtual machine's host took
    #: while the method's frames and its copy floor were timed (steal,
    #: :func:`~splitrender.machine.steal_share`); ``None`` where the platform does not count it.
    host_steal_pct: float | None = None

    @property
    def ratio_to_floor(self) -> float:
        """How many memory-copy floors one frame takes."""
        return self.ms_per_frame / self.copy_floor_ms if self.copy_floor_ms > 0 else math.inf

    def to_json(self) -> dict[str, Any]:
        return {k: getattr(self, k) for k in BENCH_KEYS}


def _nbytes(cf: CameraFrame, direction: str, *, motion: bool, shadows: bool) -> int:
    n = int(cf.color.nbytes + cf.depth.nbytes)
    if motion:
        m = cf.motion_fwd if direction == "fwd" else cf.motion_bwd
        n += 0 if m is None else int(m.nbytes)
    if shadows:
        s: ShadowBuffers | None = cf.shadow_fwd if direction == "fwd" else cf.shadow_bwd
        if s is not None:
            n += int(s.bits.nbytes + s.s_min.nbytes + s.s_max.nbytes)
    return n


def bytes_touched(method: str, older: ServerFrame, newer: ServerFrame) -> int:
    """The estimate of bytes one client frame of ``method`` reads and writes (module docstring),
    for a client time between ``older`` and ``newer``."""
    out = newer.main.color.nbytes

    def every_camera(f: ServerFrame, direction: str, *, shadows: bool) -> int:
        return sum(_nbytes(c, direction, motion=True, shadows=shadows) for c in (f.main, *f.aux))

    if method == "ours":
        src = every_camera(older, "fwd", shadows=True) + every_camera(newer, "bwd", shadows=True)
    elif method == "ours_extrapolate":
        src = every_camera(older, "bwd", shadows=True)
    elif method == "forward_splat":
        src = every_camera(older, "bwd", shadows=False)
    elif method == "timewarp":
        src = _nbytes(older.main, "bwd", motion=False, shadows=False)
    else:  # backward_bidir
        src = _nbytes(older.main, "fwd", motion=True, shadows=False)
        src += _nbytes(newer.main, "bwd", motion=True, shadows=False)
    return int(src + out)


#: Seconds of untimed client frames before the timed ones (:func:`time_frames`).
WARM_UP_S = 0.5


def time_frames(
    one: Callable[[Any], None],
    requests: Sequence[Any],
    frames: int,
    warm_up_s: float = WARM_UP_S,
    clock: Callable[[], float] = time.perf_counter,
) -> list[float]:
    """Seconds of each of ``frames`` calls ``one(requests[i % len(requests)])``, after untimed
    calls cycling through the same requests for at least ``warm_up_s`` seconds (and at least
    one call).

    Why the warm-up lasts a time and not one call: the first call allocates, fills the thread
    pool and does the pair-level work kept in the history, but the frames after it are slower
    still. At 1280×720 on courtyard the first ten frames after the first call took 14.7 falling
    to 12.3 ms, the frames after them 11.3–12.0 ms (the same request every time, or after a
    second of copying memory: the same decline, docs/performance.md), so a median of 24
    frames counted that decline and one of 96 less of it. A client renders without pause;
    the bench reports that steady state, as criterion warms up for a time before it measures."""
    start = clock()
    k = 0
    while k == 0 or clock() - start < warm_up_s:
        one(requests[k % len(requests)])
        k += 1
    samples = []
    for i in range(frames):
        t0 = clock()
        one(requests[i % len(requests)])
        samples.append(clock() - t0)
    return samples


def copy_floor_s(nbytes: int, threads: int = 1, repeats: int = 5) -> tuple[float, int]:
    """The memory-copy floor of ``nbytes`` (module docstring) and the threads it was reached
    with: the smaller of two medians of ``repeats`` copies between two buffers touched
    beforehand (a first touch of fresh pages costs far more than a copy on this VM, and would
    not be the floor), one on one thread and one with the bytes in ``threads`` equal parts
    copied at once on as many threads (numpy releases the GIL while it copies)."""
    src = np.ones(max(int(nbytes), 1), np.uint8)
    dst = np.zeros_like(src)
    parts = [(dst[a:b], src[a:b]) for a, b in equal_parts(len(src), threads)]

    def median_copy(pool: ThreadPoolExecutor | None) -> float:
        samples = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            if pool is None:
                np.copyto(dst, src)
            else:
                for f in [pool.submit(np.copyto, d, s) for d, s in parts]:
                    f.result()
            samples.append(time.perf_counter() - t0)
        return statistics.median(samples)

    best = (median_copy(None), 1)
    if threads > 1:
        with ThreadPoolExecutor(max_workers=threads) as pool:
            median_copy(pool)  # starts the pool's threads
            best = min(best, (median_copy(pool), threads))
    return best


def equal_parts(n: int, k: int) -> list[tuple[int, int]]:
    """``[0, n)`` in ``k`` consecutive ranges ``(start, end)`` whose lengths differ by at most 1."""
    bounds = [n * i // k for i in range(k + 1)]
    return list(zip(bounds, bounds[1:]))


def kernel_threads() -> int:
    """How many threads the CPU methods run a client frame on: rayon's global pool."""
    from splitrender._native import render_thread_ids

    return len(render_thread_ids()) or usable_cpus()


def _cache_dir(scene: str, scale: float) -> Path:
    from splitrender._native import __version__

    return Path(tempfile.gettempdir()) / f"splitrender-bench-{scene}-{scale:g}-{__version__}"


def _recording(scene: str, scale: float, log: Any) -> Any:
    from splitrender.scene.recording import RecordingError, load_recording, write_recording

    path = _cache_dir(scene, scale)
    try:
        rec = load_recording(path)
        if len(rec.server_frames) >= 2 and len(rec.client_frames) >= 2:
            # Every frame against its hash, not only the manifest: a damaged frame file
            # failed every later bench, as if the user's input were wrong.
            rec.verify()
            log(f"reusing the cached recording {path}")
            return rec
    except RecordingError:  # missing, damaged or of another version: rendered again
        pass
    log(f"rendering 2 server frames of {scene} at scale {scale:g} into {path} (cached)")
    # 0.1 s at 120 FPS: client frames 0..11, server frames 0 and 1.
    write_recording(path, scene, seconds=0.1, scale=scale, overwrite=True)
    return load_recording(path)


def check_args(
    scene: str, methods: Sequence[str], scale: float, frames: int, backend: str = "cpu"
) -> None:
    from splitrender.gpu import check_backend
    from splitrender.scene.builtin import SCENE_NAMES, Scene

    try:
        check_backend(backend)
        for m in methods:
            if m in METHODS:
                check_backend(backend, m)
    except InvalidInputError as e:
        raise BenchArgumentError(f"--backend: {e}") from None

    if scene not in SCENE_NAMES:
        raise BenchArgumentError(
            f"unknown scene {scene!r}; expected one of: {', '.join(SCENE_NAMES)}"
        )
    if not methods:
        raise BenchArgumentError("--methods: expected at least one method")
    bad = [m for m in methods if m not in METHODS]
    if bad:
        raise BenchArgumentError(
            f"--methods: unknown method {bad[0]!r}; expected some of: {', '.join(METHODS)}"
        )
    if frames < 1:
        raise BenchArgumentError(f"--frames: expected an integer >= 1, got {frames}")
    w, h = Scene(scene).main_size(scale)
    if min(w, h) < 16 or max(w, h) > 4096:
        raise BenchArgumentError(
            f"--scale: {scale:g} gives a {w}x{h} main camera; expected 16..4096 pixels a side"
        )


def run_bench(
    scene: str = "courtyard",
    methods: Sequence[str] = METHODS,
    scale: float = 0.5,
    frames: int = 5,
    repeats: int = 3,
    progress: bool = True,
    backend: str = "cpu",
) -> list[BenchRow]:
    """Runs the benchmark (module docstring) and returns one row per method.

    Raises:
        BenchArgumentError: for arguments that cannot work (including a method the backend
            cannot run).
        GpuUnavailableError: for ``backend="wgpu"`` without a GPU adapter.
    """
    from splitrender._native import BidirHistory
    from splitrender.codec.coder import CodecConfig, StreamDecoder, StreamEncoder
    from splitrender.reproject import reproject

    check_args(scene, methods, scale, frames, backend)
    gpu_run = _GpuRun() if backend == "wgpu" else None
    threads = kernel_threads()
    machine = this_machine()

    # One stage line each: the recording, the codec, every method.
    stages = Progress(2 + len(methods), progress)
    rec = _recording(scene, scale, stages.stage)
    f0, f1 = rec.server_frames[0], rec.server_frames[1]
    w, h = f0.main.camera.width, f0.main.camera.height
    cfg = CodecConfig.scaled(w, h)
    stages.stage(
        f"encoding 2 server frames at {w}x{h} + aux at {cfg.bitrate_mbps:.3g} Mb/s, "
        f"timing their decoding ({repeats} times)"
    )
    with StreamEncoder(cfg) as enc:
        packets = [enc.encode(f0), enc.encode(f1)]
    times: list[float] = []
    decoded: list[ServerFrame] = []
    # One decoder through all the passes, as a client's runs through its stream (key frame, then
    # the next one, again and again); the first pass, which allocates the decoders' pictures
    # and the output arrays, is not timed. Each pass drops the frames of the one before.
    with StreamDecoder() as dec:
        for i in range(repeats + 1):
            decoded = []
            t0 = time.perf_counter()
            decoded = [dec.decode(p) for p in packets]
            if i:
                times.append((time.perf_counter() - t0) / len(packets))
    decode_ms = statistics.median(times) * 1e3
    older, newer = decoded
    # Client frames strictly between the two server frames (t in (0, 0.1)).
    requests = [c.request for c in rec.client_frames if 0.0 < c.time < newer.time]
    if not requests:
        requests = [rec.client_frames[len(rec.client_frames) // 2].request]
    rows: list[BenchRow] = []
    for method in methods:
        stages.stage(f"timing {method} on {frames} client frames ({backend})")
        times0 = cpu_times()
        if gpu_run is not None:
            samples = gpu_run.time(method, older, newer, requests, frames)
        else:
            history = BidirHistory()

            def one(req: Any, method: str = method, history: Any = history) -> None:
                reproject(older, newer, req, method, history=history)

            samples = time_frames(one, requests, frames)
        sec = statistics.median(samples)
        touched = bytes_touched(method, older, newer)
        floor, copy_threads = copy_floor_s(touched, threads)
        steal = steal_share(times0, cpu_times())
        row = BenchRow(
            method=method,
            backend=backend,
            width=w,
            height=h,
            ms_per_frame=sec * 1e3,
            ms_per_frame_max=max(samples) * 1e3,
            ns_per_pixel=sec * 1e9 / (w * h),
            decode_ms_per_server_frame=decode_ms,
            gb_per_s=touched / sec / 1e9,
            mb_touched=touched / 1e6,
            copy_floor_ms=floor * 1e3,
            copy_threads=copy_threads,
            processor=machine.processor,
            cpus=machine.cpus,
            simd=machine.simd,
            host_steal_pct=None if steal is None else 100.0 * steal,
        )
        rows.append(row)
    return rows


class _GpuRun:
    """Times the wgpu backend as a client runs it: the pair uploaded once per method, then per
    client frame the pose up and the image down (the previous output stays on the device)."""

    def __init__(self) -> None:
        from splitrender.gpu import GpuReprojector

        self.gpu = GpuReprojector()

    def time(
        self,
        method: str,
        older: ServerFrame,
        newer: ServerFrame,
        requests: Sequence[Any],
        frames: int,
    ) -> list[float]:
        # The frames and α that splitrender.reproject picks (its module docs): `ours` between
        # the pair; the unidirectional methods extrapolate from the newest frame at or before t.
        fs = 1.0 / (newer.time - older.time)
        if method == "ours":
            self.gpu.load(older, newer)

            def alpha(t: float) -> float:
                return (t - older.time) * fs

        else:
            self.gpu.load(None, older)

            def alpha(t: float) -> float:
                return 1.0 + (t - older.time) * fs

        def one(req: Any) -> None:
            self.gpu.render(req.camera, alpha(req.time), method, previous="keep")

        return time_frames(one, requests, frames)


def format_rows(rows: Sequence[BenchRow], cpus: int | None = None) -> str:
    """A plain-text table of the rows."""
    if not rows:
        return "(no rows)"
    r0 = rows[0]
    cpus = cpus if cpus is not None else (r0.cpus or usable_cpus())
    lines: list[str] = []
    machine = describe_recorded(r0.processor, r0.cpus, r0.simd)
    if machine is not None:  # rows made by hand without their machine say nothing of it
        lines.append(f"machine: {machine}")
    lines += [
        (
            f"backend {r0.backend} ({_backend_detail(r0.backend, cpus)}), client "
            f"{r0.width}x{r0.height}; decode "
            f"{r0.decode_ms_per_server_frame:.1f} ms per server frame"
        ),
        (
            f"{'method':<18} {'ms/frame':>9} {'max ms':>8} {'FPS':>7} {'ns/pixel':>9} "
            f"{'MB touched':>11} {'GB/s':>7} {'copy floor':>11} {'threads':>7} {'x floor':>8}"
            f" {'steal %':>7}"
        ),
    ]
    for r in rows:
        fps = 1e3 / r.ms_per_frame if r.ms_per_frame > 0 else float("inf")
        lines.append(
            f"{r.method:<18} {r.ms_per_frame:9.2f} {r.ms_per_frame_max:8.2f} {fps:7.1f} "
            f"{r.ns_per_pixel:9.2f} {r.mb_touched:11.2f} {r.gb_per_s:7.2f} "
            f"{r.copy_floor_ms:8.2f} ms {r.copy_threads:7d} {r.ratio_to_floor:8.1f}"
            f" {'n/a' if r.host_steal_pct is None else f'{r.host_steal_pct:.1f}':>7}"
        )
    busy = [r.method for r in rows if host_busy(r.host_steal_pct)]
    note = steal_note([r.host_steal_pct for r in rows],
                      f"{', '.join(busy)} {'was' if len(busy) == 1 else 'were'} timed")
    return "\n".join(lines if note is None else [*lines, note])


def _backend_detail(backend: str, cpus: int) -> str:
    if backend == "wgpu":
        from splitrender.gpu import adapter

        return adapter()
    return f"{cpus} cores"
