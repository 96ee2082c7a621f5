"""``splitrender bench --realtime``: a stream through the real-time client loop at wall-clock
``f_c`` (:class:`~splitrender.client.realtime.RealtimeClient`).

The source is a stream file, or a built-in scene whose server frames are rendered and encoded
once (at the paper's 40 Mb/s scaled by pixel count) into a stream file cached in the temporary
directory. Each server frame ``k`` (time ``t_k = k / f_s``, ``f_s`` the server rate in the
stream file's header) is handed to the client when the
model's server would send it over an ideal link, at display time ``t_k − 1 / f_s``
(:mod:`splitrender.net.model`), and decoded and prepared on the client's worker thread while
the display loop renders every refresh at the client's pose (with ``backend="wgpu"`` on the GPU,
the worker uploading each pair there instead of preparing it). A run longer than the source
loops it: packet ``k mod N`` is sent again as frame ``k`` (its header re-stamped; packet 0 is a
key frame, so the decoder starts over cleanly), and the pose follows the scene's path modulo
its length, so the seam is one jump of the content, nothing else.

The client's pose: for a built-in scene its head path (:meth:`Scene.client_pose`) with the
main camera's projection at the main camera's size; a stream file carries no client path, so
the client looks from the main camera of the newest server frame whose time has passed.
"""

from __future__ import annotations

import dataclasses
import math
import os
import tempfile
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from splitrender.client.realtime import DISPLAY_FPS, MAX_DIVISOR, PREPARE_THREADS, DisplayFrame
from splitrender.codec.stream import (
    PACKET_VERSION,
    CameraRecord,
    StreamFile,
    pack_packet,
    unpack_packet,
    without_file_name,
)
from splitrender.errors import InvalidInputError, StreamError
from splitrender.evaluation.shown import (
    Shown,
    ShownRecorder,
    MIN_RUN,
    format_scores,
    group,
    runs,
    score_shown,
    scorable,
)
from splitrender.files import write_atomic
from splitrender.gpu import require as require_backend
from splitrender.machine import describe_recorded, steal_note, this_machine, usable_cpus
from splitrender.progress import Progress
from splitrender.reproject import METHODS
from splitrender.types import Camera

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from splitrender.scene.builtin import Scene

__all__ = [
    "REALTIME_KEYS",
    "RealtimeBench",
    "format_realtime",
    "realtime_figure",
    "run_realtime_bench",
    "write_realtime_plot",
]

#: The keys ``--json`` always writes (the whole :meth:`RealtimeReport.summary` follows them).
REALTIME_KEYS: tuple[str, ...] = (
    "method",
    "source",
    "width",
    "height",
    "frames",
    "deadline_misses",
    "frame_ms_p50",
    "frame_ms_p99",
    "decode_ms_per_server_frame",
)

_FS = 10.0


@dataclass(frozen=True)
class RealtimeBench:
    """The result of :func:`run_realtime_bench`: what ran and the loop's summary."""

    method: str
    source: str
    width: int
    height: int
    looped: bool
    #: The display waited for the worker after each arrival (``--exclusive``).
    exclusive: bool
    #: How the worker yielded the cores to the display (``--worker-priority``).
    worker_priority: str
    #: How the display's threads were to be scheduled (``--display-priority``; the summary's
    #: ``display_scheduling`` says what they got).
    display_priority: str
    summary: dict[str, Any]
    #: Where the display renders: ``cpu`` or ``wgpu``.
    backend: str = "cpu"
    #: The wgpu adapter in words (``None`` on the CPU).
    adapter: str | None = None
    #: Every display frame of the run, in order (what :func:`realtime_figure` draws; not in
    #: the JSON, whose summary is made of them).
    frames: tuple[DisplayFrame, ...] = field(default=(), repr=False)
    #: The most the display could divide its rate by (``--max-divisor``; the summary's
    #: ``full_rate_pct`` and ``frames_by_divisor`` say what it did).
    max_divisor: int = MAX_DIVISOR
    #: The threads of the worker's pair preparation (``--prepare-threads``); ``None`` on the
    #: GPU backend, where the worker uploads each pair instead of preparing it.
    prepare_threads: int | None = PREPARE_THREADS
    #: A frame that could interpolate extrapolated where an interpolated frame would have
    #: missed its deadline (``False``: ``--always-interpolate``; the summary's
    #: ``interpolation_deferred`` counts those frames).
    defer_interpolation: bool = True
    #: With ``score``: what the display showed at that many refreshes against the ground truth
    #: (:func:`~splitrender.evaluation.shown.score_shown`: the means, ``by_mode``,
    #: ``by_staleness``); ``None`` without.
    score: dict[str, Any] | None = None
    #: The machine (:mod:`splitrender.machine`): the processor in words, the CPUs
    #: the process could run on and the instruction set of the CPU kernels' row loops.
    processor: str = ""
    cpus: int = 0
    simd: str = ""

    def to_json(self) -> dict[str, Any]:
        """What ran (every field but the summary and the frames), then the summary's keys."""
        head = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        summary = head.pop("summary")
        del head["frames"]
        return {**head, **summary}


def _scene_stream(scene: str, scale: float, n: int, progress: Progress) -> Path:
    """The stream file of server frames ``0..n-1`` of ``scene`` at ``scale``, rendered and
    encoded once into the temporary directory (StreamWriter writes it atomically, so an
    interrupted run leaves nothing that reads as valid)."""
    from splitrender._native import __version__
    from splitrender.codec.coder import CodecConfig, StreamEncoder
    from splitrender.codec.stream import StreamWriter
    from splitrender.scene.builtin import Scene

    path = Path(tempfile.gettempdir()) / (
        f"splitrender-realtime-{scene}-{scale:g}-{n}-{__version__}-v{PACKET_VERSION}.srs"
    )
    if path.is_file():
        try:
            # Every packet's structure and CRC, not only the count of the file's index: a
            # damaged cache failed every later run with a CRC mismatch that named no file.
            cached = StreamFile(path)
            if len(cached) == n:
                for data in cached.packets():
                    unpack_packet(data)
                progress.stage(f"reusing the cached stream {path}")
                return path
        except (StreamError, OSError):  # a damaged or foreign file: render it again
            pass
    sc = Scene(scene)
    w, h = sc.main_size(scale)
    cfg = CodecConfig.scaled(w, h)
    progress.stage(
        f"rendering and encoding {n} server frames of {scene} at {w}x{h} + aux, "
        f"{cfg.bitrate_mbps:.3g} Mb/s, into {path} (cached)"
    )
    with StreamEncoder(cfg) as enc, StreamWriter(path, fps=_FS) as out:
        for k in range(n):
            out.write(enc.encode(sc.server_frame(k, scale, _FS)))
            progress.bar(k + 1, n, "frames")
    return path


def _camera(rec: CameraRecord) -> Camera:
    return Camera(rec.view, rec.proj, rec.width, rec.height)


def check_realtime_args(method: str, seconds: float, scale: float, display_fps: float) -> None:
    if method not in METHODS:
        raise InvalidInputError(
            f"--methods: --realtime runs one method; expected one of: {', '.join(METHODS)}, "
            f"got {method!r}"
        )
    if not math.isfinite(seconds) or not 0.0 < seconds <= 3600.0:
        raise InvalidInputError(f"--seconds: expected 0 < S <= 3600, got {seconds:g}")
    if not math.isfinite(scale) or scale <= 0.0:
        raise InvalidInputError(f"--scale: expected a positive number, got {scale:g}")
    # Checked before the scene is rendered; the loop counts round(seconds · f_c) refreshes.
    if not math.isfinite(display_fps) or round(seconds * display_fps) < 1:
        raise InvalidInputError(
            f"--seconds {seconds:g} at --fps {display_fps:g}: expected at least one display "
            "frame (--seconds times --fps rounds to 0)"
        )


def run_realtime_bench(
    scene: str = "courtyard",
    scale: float = 0.25,
    seconds: float = 10.0,
    method: str = "ours",
    *,
    stream: str | os.PathLike[str] | None = None,
    display_fps: float = DISPLAY_FPS,
    progress: bool = True,
    exclusive: bool = False,
    worker_priority: str = "idle",
    display_priority: str = "realtime",
    backend: str = "cpu",
    max_divisor: int = MAX_DIVISOR,
    prepare_threads: int | None = None,
    stereo: bool = False,
    defer_interpolation: bool = True,
    score: int = 0,
    no_vmaf: bool = False,
) -> RealtimeBench:
    """Runs ``seconds`` of the real-time loop (module docs) and returns its summary.
    ``stereo``: each display frame is two eyes (:meth:`Camera.stereo
    <splitrender.Camera.stereo>` of the client's camera, IPD 7 cm) rendered from the same
    server frames, as a headset shows them; the frame times cover both.
    ``exclusive``: the display waits for the worker after each arrival, off the clock
    (:meth:`RealtimeClient.run`), so that the deadlines measure the display frames alone.
    ``worker_priority``: how the worker yields the cores to the display, ``display_priority``:
    how the display's threads are scheduled, ``max_divisor``: the most the display may divide
    its rate by when its frames do not fit the refresh (all three ``RealtimeClient``),
    ``prepare_threads``: the threads of the worker's pair preparation on the CPU (``None``:
    :data:`~splitrender.client.realtime.PREPARE_THREADS`; refused with ``backend="wgpu"``,
    where the worker uploads each pair instead).
    ``defer_interpolation``: a frame that could interpolate extrapolates where an
    interpolated frame would miss its deadline (``RealtimeClient``'s; ``False``:
    ``--always-interpolate``).
    ``backend``: where the display renders (``"wgpu"``: the GPU, the worker uploading each
    pair).
    ``score``: after the run, score what the display showed at that many refreshes (0: none)
    against the ground truth of the refreshes' times (a built-in scene's only;
    :mod:`splitrender.evaluation.shown`: a missed deadline counts as the older image left up,
    a halved rate as each image shown twice), without VMAF for ``no_vmaf``. The refreshes come
    in runs of :data:`~splitrender.evaluation.shown.SCORED_RUN` consecutive ones spread over
    the run, each with one more at each end for VMAF's motion feature
    (:func:`~splitrender.evaluation.shown.runs`). The first and last ``SKIP_FRAMES`` refreshes
    are left out, and in a looped run those within a server period of a seam (where a pair
    straddles the jump of the content, an artefact of the loop).

    Raises:
        InvalidInputError: for arguments that cannot work.
        StreamError: for a stream file that cannot be read, or one of whose packets does not
            decode.
        GpuUnavailableError: for ``backend="wgpu"`` without a GPU adapter.
    """
    from splitrender.client.client import Client
    from splitrender.client.realtime import RealtimeClient
    from splitrender.evaluation.metrics import SKIP_FRAMES
    from splitrender.scene.builtin import SCENE_NAMES, Scene

    check_realtime_args(method, seconds, scale, display_fps)
    if isinstance(score, bool) or not isinstance(score, int) or not 0 <= score <= 100_000:
        raise InvalidInputError(f"score: expected refreshes to score, 0 to 100000, got {score!r}")
    if score and stream is not None:
        raise InvalidInputError(
            "--score: a stream file carries no ground truth; score a built-in --scene"
        )
    n_frames = round(seconds * display_fps)
    if score and n_frames < 2 * SKIP_FRAMES + MIN_RUN:
        # Refused before the recording and the run: none of its refreshes would be scored (a
        # scored refresh needs one on each side, for VMAF's motion feature).
        raise InvalidInputError(
            f"--score: {seconds:g} s is {n_frames} refreshes at "
            f"{display_fps:g} FPS; the score leaves out {SKIP_FRAMES} at each end and scores "
            f"a refresh between two others, so at least "
            f"{(2 * SKIP_FRAMES + MIN_RUN) / display_fps:.3f} s is needed"
        )
    if prepare_threads is not None and backend != "cpu":
        # Said rather than ignored: no preparation pool runs on the GPU path.
        raise InvalidInputError(
            "--prepare-threads goes with --backend cpu (on the GPU the worker uploads each "
            "pair instead of preparing it)"
        )
    if backend == "cpu" and prepare_threads is None:
        prepare_threads = PREPARE_THREADS
    # Before anything is rendered: a method without a GPU kernel or a missing adapter fails here.
    adapter = require_backend(backend, method)
    machine = this_machine()
    stages = Progress((3 if stream is None else 2) + (score > 0), progress)
    if stream is None:
        if scene not in SCENE_NAMES:
            raise InvalidInputError(
                f"unknown scene {scene!r}; expected one of: {', '.join(SCENE_NAMES)}"
            )
        sc = Scene(scene)
        # The whole run's server frames, up to the scene's length (then it loops).
        n = min(math.ceil(seconds * _FS) + 1, int(round(sc.duration * _FS)))
        path = _scene_stream(scene, scale, n, stages)
        source = f"{scene} (built-in, scale {scale:g})"
    else:
        sc = None
        path = Path(stream)
        if not path.is_file():
            raise InvalidInputError(f"--stream: {path}: expected a stream file, found none")
        source = str(path)
    # What the errors of the file name: the option and the path as given, or the cache's path.
    where = str(path) if stream is None else f"--stream: {os.fspath(stream)}"
    try:
        file = StreamFile(path)
        packets = list(file.packets())
    except StreamError as e:
        # The reader's messages open with the file's bare name: "afile: ..." named neither the
        # option nor where the file is.
        raise StreamError(f"{where}: {without_file_name(str(e), path)}") from None
    if not packets:
        raise InvalidInputError(f"{where}: the stream has no frames")
    try:
        heads = [unpack_packet(p) for p in packets]
    except StreamError as e:  # the packet's message names its frame, not the file
        raise StreamError(f"{where}: {e}") from None
    main = heads[0].cameras[0]
    # The server rate the file's header gives (checked to be in (0, 1000] when it was read), not
    # one taken from the first two packets' times: a hostile gap of 5e-324 s raised
    # OverflowError, one of 1e-9 s asked for 10^9 packets a second (memory without bound).
    fs = file.fps
    cycle = len(packets) / fs
    n_sent = math.ceil(seconds * fs) + 1
    looped = n_sent > len(packets)

    def packet(k: int) -> bytes:
        """Packet ``k mod N`` sent as frame ``k`` at time ``k / f_s`` (its header re-stamped
        where it differs; the payloads are unchanged)."""
        p = heads[k % len(heads)]
        if p.index == k and p.time == k / fs:
            return packets[k]
        return pack_packet(dataclasses.replace(p, index=k, time=k / fs))

    pose: Callable[[float], Camera]
    if sc is not None:
        scene_obj = sc

        def pose(t: float) -> Camera:
            view = np.linalg.inv(scene_obj.client_pose(t % cycle)).astype(np.float64)
            return Camera(view, main.proj, main.width, main.height)

    else:
        cams = [_camera(h.cameras[0]) for h in heads]

        def pose(t: float) -> Camera:
            return cams[int(math.floor(t * fs + 1e-9)) % len(cams)]

    feed = [(k / fs - 1.0 / fs, packet(k)) for k in range(n_sent)]
    recorder, slot_runs = None, []
    if score:
        slot_runs = _scored_runs(n_frames, display_fps, cycle if looped else math.inf, fs, score)
        recorder = ShownRecorder([k for run in slot_runs for k in run], 0.0, display_fps)
    stages.stage(
        f"running {method} in real time for {seconds:g} s at {display_fps:g} FPS, "
        + ("two eyes of " if stereo else "") + f"{main.width}x{main.height} + aux"
        + (" (the source loops)" if looped else "")
        + ("" if adapter is None else f" on {adapter}")
    )
    with RealtimeClient(
        client=Client(method, server_fps=fs, backend=backend),
        display_fps=display_fps,
        worker_priority=worker_priority,
        display_priority=display_priority,
        max_divisor=max_divisor,
        defer_interpolation=defer_interpolation,
        prepare_threads=prepare_threads,
        keep_frames=None,  # the plots show every frame of the run (its length is the user's)
    ) as client:
        # Warmed up: the first packets are received and one frame rendered before the clock
        # starts, so that the run measures the steady state (the summary's warm_up_ms).
        report = client.run(
            (lambda t: pose(t).stereo()) if stereo else pose, seconds, feed=feed,
            start_time=0.0, exclusive=exclusive, warm_up=True, stereo=stereo,
            on_frame=recorder,
        )
    scored = None
    if recorder is not None and sc is not None:
        shown = group(recorder.finish(n_frames), slot_runs)
        scored = _score(sc, pose, cycle, stereo, shown, no_vmaf, stages)
    stages.close()
    if report.undecodable:
        # A live display goes on extrapolating past such a packet; a benchmark of a stream
        # that does not decode measures nothing of it (it showed 60 held frames and rc 0).
        raise StreamError(
            f"{source}: {report.packets_undecodable} packets did not decode; the first: "
            f"{report.undecodable[0]}"
        )
    return RealtimeBench(
        method, source, main.width, main.height, looped, exclusive, worker_priority,
        display_priority, report.summary(), backend, adapter, tuple(report.frames),
        max_divisor, prepare_threads, defer_interpolation, scored, machine.processor,
        machine.cpus, machine.simd,
    )


def _scored_runs(n_frames: int, fc: float, cycle: float, fs: float, count: int) -> list[list[int]]:
    """Runs of consecutive refresh slots (:func:`~splitrender.evaluation.shown.runs`) that
    score ``count`` spread over a run of ``n_frames`` at ``fc``: not the first or last
    ``SKIP_FRAMES``, nor those within a server period (``1 / fs``) of a seam of a source looped
    every ``cycle`` seconds (``inf``: not looped)."""
    from splitrender.evaluation.metrics import SKIP_FRAMES

    def near_seam(t: float) -> bool:
        phase = t % cycle
        return phase > cycle - 1.0 / fs or (t >= cycle and phase < 1.0 / fs)

    slots = [s for s in range(SKIP_FRAMES, n_frames - SKIP_FRAMES) if not near_seam(s / fc)]
    return runs(slots, count)


def _score(
    scene: Scene, pose: Callable[[float], Camera], cycle: float, stereo: bool,
    shown: list[list[Shown]], no_vmaf: bool, stages: Progress,
) -> dict[str, Any]:
    """The runs of refreshes ``shown`` against the ground truth at their poses (``pose``, as
    the run had them) and scene times (a looped run's modulo ``cycle``)."""
    # The runs score_shown scores (a run cut to fewer than three scores nothing): the counts.
    shown = scorable(shown)
    slots = sum(len(run) for run in shown)
    stages.stage(
        f"scoring what the display showed at {slots - 2 * len(shown)} "
        f"refreshes in {len(shown)} runs of consecutive ones against the ground truth rendered "
        "at their poses"
    )
    rendered = [0]

    def truth(t: float) -> list[npt.NDArray[np.uint8]]:
        cam = pose(t)
        images = [scene.ground_truth(c, t % cycle) for c in (cam.stereo() if stereo else (cam,))]
        rendered[0] += 1
        stages.bar(rendered[0], slots, "ground truths")
        return images

    return score_shown(shown, truth, no_vmaf, lambda m, d, n: stages.bar(d, n, m))


def _collections(s: dict[str, Any]) -> str:
    """The summary's garbage collection between frames, in words."""
    if not s.get("gc_between_frames"):
        return ("garbage collection: left to the application (Python's collector was disabled "
                "when the display started)")
    n, forced = s["gc_collections"], s["gc_forced"]
    return (
        f"garbage collection between frames: {n} collection{'s' * (n != 1)}"
        + ("" if not n else f", the longest {s['gc_ms_max']:.2f} ms")
        + ("" if not forced else f"; {forced} overdue, collected without the time to the "
           "next refresh")
    )


def format_realtime(b: RealtimeBench) -> str:
    """The summary as plain text."""
    s = b.summary
    machine = describe_recorded(b.processor, b.cpus, b.simd)  # None: a bench made by hand
    note = steal_note([s.get("host_steal_pct")], "the display ran")

    def ms(key: str) -> str:
        v = s.get(key)
        return "n/a" if v is None else f"{v:.2f} ms"

    modes = ", ".join(
        f"{k} {v}"
        + (f" ({s['interpolation_deferred']} of them instead of interpolating, which would "
           "have missed the deadline)"
           if k == "extrapolate" and s.get("interpolation_deferred") else "")
        for k, v in s["modes"].items()
    )
    fc = s["display_fps"]
    rates = ", ".join(
        f"{fc / int(d):g} FPS {100 * v / max(s['frames'], 1):.1f} %"
        for d, v in s["frames_by_divisor"].items()
    )
    return "\n".join(
        [
            f"{b.method} in real time on {b.source}: "
            + ("two eyes of " if s.get("eyes") == 2 else "")
            + f"{b.width}x{b.height} + aux at "
            f"{s['display_fps']:g} FPS for {s['wall_s']:.1f} s"
            + ("" if b.adapter is None else f", rendered on the GPU ({b.adapter})")
            + (" (source looped)" if b.looped else "")
            + (" (exclusive: the display waited for the worker off the clock)"
               if b.exclusive else "")
            + f"; worker priority {b.worker_priority}; display scheduling "
            + s["display_scheduling"],
        ]
        + ([] if machine is None else [f"  machine: {machine}"])
        + [
            f"  frames {s['frames']}, deadline misses {s['deadline_misses']} "
            f"({s['deadline_misses_pct']:.2f} %"
            + ("" if not s["deadline_misses"] or s.get("deadline_misses_by_cause") is None
               else "; " + _causes(s["deadline_misses_by_cause"]))
            + f"), dropped refreshes {s['dropped']}, achieved {s['achieved_fps']:.1f} FPS",
            f"  display rate (frames at each): {rates or 'n/a'}; "
            + (f"the rate may halve (--max-divisor {b.max_divisor})" if b.max_divisor == 2
               else "held at the full rate (--max-divisor 1)" if b.max_divisor == 1
               else f"the rate may fall to 1/{b.max_divisor} (--max-divisor {b.max_divisor})")
            + f"; refreshes repeated at a divided rate {s['repeated']}",
            f"  frame time p50 {ms('frame_ms_p50')}, p95 {ms('frame_ms_p95')}, "
            f"p99 {ms('frame_ms_p99')}, max {ms('frame_ms_max')}"
            + ("" if s.get("frame_cpu_ms_p50") is None
               else f"; display threads' CPU per frame p50 {ms('frame_cpu_ms_p50')}, "
               f"max {ms('frame_cpu_ms_max')}"),
            f"  modes: {modes}; pairs prepared off the display path: "
            f"{s['prepared_pct']:.1f} % of frames"
            + ("" if b.defer_interpolation else " (--always-interpolate)"),
            f"  decode {ms('decode_ms_per_server_frame')} and pair "
            + ("preparation " if b.backend == "cpu" else "upload ")
            + f"{ms('prepare_ms_per_server_frame')} per server frame (worker thread"
            + ("" if b.prepare_threads is None
               else f", preparing on {b.prepare_threads} thread{'s' * (b.prepare_threads != 1)}")
            + "; median; "
            f"usable after {ms('usable_ms_per_server_frame')}); "
            f"server frames {s['server_frames_received']} received, "
            f"{s['server_frames_late']} late"
            + ("" if not s["pairs_skipped"]
               else f", {s['pairs_skipped']} without their interpolation pair (it would have "
               "come too late: used from their own time, to extrapolate)")
            + ("" if not s.get("pairs_probed")
               else f", {s['pairs_probed']} such "
               + ("pair prepared anyway to measure it again" if s["pairs_probed"] == 1
                  else "pairs prepared anyway to measure them again")),
            f"  newest server frame's age at display: p50 {ms('server_age_ms_p50')}, "
            f"max {ms('server_age_ms_max')}; CPU {100 * s['cpu_utilisation']:.0f} % "
            f"of {b.cpus or usable_cpus()} cores"
            + ("" if s.get("host_steal_pct") is None
               else f"; the host took {s['host_steal_pct']:.1f} % of the machine's CPU time "
               "(steal)")
            + ("" if s.get("warm_up_ms") is None
               else f"; warm-up before the clock {s['warm_up_ms']:.0f} ms")
            + _seeds(s.get("warm_up_seed_ms")),
            "  " + _collections(s),
        ]
        + ([] if note is None else [f"  {note}"])
        + ([] if s.get("gpu_lost") is None else [
            f"  the GPU device was lost ({s['gpu_lost']}): the display went on on the CPU "
            "from then on (the figures mix the two backends)"])
        + ([] if b.score is None else _score_lines(b.score))
    )


_DONE = {"interpolate": "interpolated", "extrapolate": "extrapolated"}


def _seeds(seeds: dict[str, list[float]] | None) -> str:
    """The warm-up's frames timed for the interpolation governor, for the text report."""
    if not seeds:
        return ""
    return " (timed for the governor: " + ", ".join(
        f"{_DONE.get(mode, mode)} {'/'.join(f'{t:.1f}' for t in times)} ms"
        for mode, times in seeds.items()
    ) + ")"


def _score_lines(score: dict[str, Any]) -> list[str]:
    """The text report's lines of a ``--score`` (:func:`score_shown`'s result)."""
    n = score["scored_frames"]
    if not n:
        return ["  scored: no refresh showed a frame (nothing scored)"]

    def groups(split: dict[str, dict[str, Any]], name: Callable[[str], str]) -> str:
        return "; ".join(f"{name(k)} ({g['refreshes']}): {format_scores(g)}"
                         for k, g in split.items())

    return [
        f"  shown at {n} refreshes against the ground truth: {format_scores(score)}",
        "    by the mode of the frame shown: " + groups(score["by_mode"], str),
        "    by the age of its pose: " + groups(
            score["by_staleness"],
            lambda k: "its own refresh" if k == "0"
            else f"{k} refresh{'' if k == '1' else 'es'} old"),
    ]


#: How the text report names each cause of :meth:`RealtimeReport.miss_causes`.
_CAUSE_WORDS = {
    "late_start": "started late",
    "more_cpu": "more CPU than the median",
    "waited": "threads waited",
}


def _causes(causes: dict[str, int]) -> str:
    """The misses' causes as text: ``1 started late, 2 threads waited``."""
    return ", ".join(f"{n} {_CAUSE_WORDS[c]}" for c, n in causes.items() if n)


def write_realtime_json(path: Path, b: RealtimeBench) -> None:
    import json

    write_atomic(path, json.dumps(b.to_json(), indent=1) + "\n")


#: The colour of each mode in :func:`realtime_figure`.
MODE_COLOURS = {"interpolate": "tab:blue", "extrapolate": "tab:orange", "hold": "0.55"}
#: The colour of the frames that extrapolated where interpolating would have missed
#: (:class:`~splitrender.client.realtime.ModeGovernor`).
DEFERRED_COLOUR = "tab:brown"


def realtime_figure(b: RealtimeBench) -> Figure:
    """The run as a frame-time graph (matplotlib, not shown), display time along x:

    - above, each display frame's time from its refresh to done (the render time plus any
      wait before it started: what its deadline, the next refresh, is judged on), coloured by
      its mode (apart: the extrapolated frames that could have interpolated), against the
      refresh period (and, where the rate was halved, two periods: the deadline of those
      frames); every frame that missed its deadline is marked by a red
      cross; a frame beyond the plotted range (four periods, or the p99 if higher) sits at its
      top edge as a triangle;
    - below, the age of the newest server frame it used (display time minus the time that
      frame's pose was taken): the latency reprojection hides.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    s = b.summary
    machine = describe_recorded(b.processor, b.cpus, b.simd)
    period = 1e3 / s["display_fps"]
    fig, (top, low) = plt.subplots(
        2, 1, figsize=(10, 5.6), sharex=True, gridspec_kw={"height_ratios": [2, 1]}
    )
    times = np.array([f.time for f in b.frames], np.float64)
    # From the frame's refresh, which is its deadline less its periods (every frame has a
    # deadline; `refresh` is missing from frames recorded before it existed).
    ms = np.array(
        [(f.done - f.deadline) * 1e3 + f.divisor * period for f in b.frames], np.float64
    )
    ceiling = max(4.0 * period, 1.15 * float(np.percentile(ms, 99)) if len(ms) else 0.0)
    shown = np.minimum(ms, ceiling)
    deferred = np.array([f.deferred for f in b.frames], bool)
    kinds = [
        (mode, colour, np.array([f.mode == mode for f in b.frames], bool) & ~deferred)
        for mode, colour in MODE_COLOURS.items()
    ] + [("extrapolate, instead of interpolating", DEFERRED_COLOUR, deferred)]
    for label, colour, pick in kinds:
        if not pick.any():
            continue
        inside = pick & (ms <= ceiling)
        top.scatter(times[inside], shown[inside], s=6, color=colour,
                    label=f"{label} ({pick.sum()})", zorder=2)
        over = pick & (ms > ceiling)
        if over.any():
            top.scatter(times[over], shown[over], s=22, marker="^", color=colour, zorder=2)
    missed = np.array([not f.met for f in b.frames], bool)
    if missed.any():
        top.scatter(times[missed], shown[missed], s=30, marker="x", color="tab:red", zorder=3,
                    label=f"deadline missed ({missed.sum()})")
    top.axhline(period, color="tab:red", linestyle="--", linewidth=1,
                label=f"refresh period {period:.2f} ms")
    for d in sorted({f.divisor for f in b.frames} - {1}):
        n_d = sum(f.divisor == d for f in b.frames)
        top.axhline(d * period, color="tab:purple", linestyle=":", linewidth=1,
                    label=f"deadline at {s['display_fps'] / d:g} FPS ({n_d} frames)")
    top.set_ylim(0, ceiling * 1.05)
    top.set_ylabel("refresh to done (ms)")
    top.grid(alpha=0.3)
    top.legend(fontsize=7, loc="upper right", markerscale=2)
    pct = s["deadline_misses_pct"]
    p50, p99 = s.get("frame_ms_p50"), s.get("frame_ms_p99")
    top.set_title(
        f"{b.method} in real time on {b.source}: {b.width}x{b.height} + aux at "
        f"{s['display_fps']:g} FPS, {b.backend}\n"
        + "; ".join(
            ([] if machine is None else [machine])
            + ([] if s.get("host_steal_pct") is None
               else [f"the host took {s['host_steal_pct']:.1f} % of the CPU time (steal)"])
        )
        + ("" if machine is None and s.get("host_steal_pct") is None else "\n")
        + f"{s['frames']} frames"
        + ("" if s["full_rate_pct"] == 100.0 else f" ({s['full_rate_pct']:.1f} % at full rate)")
        + ", "
        f"{s['deadline_misses']} deadline misses ({pct:.1f} %), render time p50 "
        + ("n/a" if p50 is None else f"{p50:.2f} ms")
        + ("" if p99 is None else f", p99 {p99:.2f} ms"),
        fontsize=9,
    )
    aged = [(f.time, f.server_age_ms) for f in b.frames if f.server_age_ms is not None]
    if aged:
        low.plot([t for t, _ in aged], [a for _, a in aged], color="tab:green", linewidth=1)
    low.set_ylabel("newest server\nframe's age (ms)")
    low.set_xlabel("display time (s)")
    low.grid(alpha=0.3)
    fig.tight_layout()
    return fig


def write_realtime_plot(path: str | os.PathLike[str], b: RealtimeBench) -> None:
    """:func:`realtime_figure` as a PNG at ``path``, written atomically."""
    import io

    import matplotlib.pyplot as plt

    fig = realtime_figure(b)
    try:
        buf = io.BytesIO()
        fig.savefig(buf, format="png", dpi=120)
    finally:
        plt.close(fig)
    write_atomic(path, buf.getvalue())
