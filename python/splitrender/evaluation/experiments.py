"""``splitrender eval``: the paper's experiments (seeds/000 §4.2) on the built-in scenes.

* Table 1: every method × scene × static/dynamic on the uncompressed server frames (ideal link,
  ``l = 0``).
* Table 2: ``ours`` on the dynamic scenes with an extra delay of ``l`` client frames
  (default ``l ∈ {0, 1, 2, 4, 8, 12}``), compressed at the default bitrate (the paper's 40 Mb/s
  scaled by pixel count), plus ``ours_extrapolate`` at ``l = 0`` for comparison.
* Table 3 (``stereo=True``): every method on the dynamic scenes, compressed, mono (left eye of
  the mono recording) vs stereo (both eyes, IPD 7 cm; the metrics are the means over both eyes).

The experiments run as one sweep (:mod:`splitrender.evaluation.sweep`, docs/sweeps.md): a task
graph of renders (one recording per scene, variant[, stereo]), encodes (per bit-rate) and scores
(per method × delay × bit-rate × eye) on the local or the Ray executor, every output kept in a
content-addressed cache that later runs reuse. Every result is a row with exactly the keys
:data:`ROW_KEYS`; ``results.json`` (the list of rows, the same bytes whichever executor made
them), ``tables.md`` (one Markdown table per experiment), ``delays.png`` (metrics against ``l``)
and ``run-info.json`` (executor, host, seconds, task counts) are written to ``OUT``;
``OUT/recordings/SCENE-VARIANT[-stereo]`` link to the recordings in the cache (for ``play``).

* Figure 6 (``bitrates``): every method on the dynamic scenes of ``rd_scenes`` (default: all)
  at each paper-equivalent bitrate (scaled by pixel count), plus the reference lines of
  seeds/000 Fig. 6: ``video_streaming`` (the ground truth encoded as one 120 FPS HEVC video at
  the same bitrate: perfect prediction, zero latency) and ``timewarp_10fps``/``_30fps``/
  ``_60fps`` (a traditional streaming setup: the server renders the main camera's colour and
  depth at 10/30/60 FPS with a prediction window of one frame, 100/33.3/16.7 ms, streamed at
  the same bitrate, and the client timewarps the newest frame), plotted as
  ``rate_distortion.png`` (VMAF, or SSIM without VMAF, against the achieved Mb/s; the
  uncompressed Table 1 values dotted). The bitrates at which ``ours`` reaches VMAF 60 and 80
  (linear interpolation between measured points) are in ``tables.md`` and
  :attr:`EvalResult.summary`.

``video_interp`` (a method of Tables 1 and Fig. 6, not a reprojection method) is FFmpeg's
``minterpolate`` (motion-compensated frame interpolation) of the server's main-camera colour
video from f_s to f_c: it cannot use the client's pose, so it shows what plain video frame
interpolation gives. Alignment: the server frames enter at their times ``k / f_s`` (frame 0
at 0), ``minterpolate`` emits frames at ``n / f_c``, so output ``n`` is client frame ``n``
(output ``12 k`` reproduces server frame ``k``; tested); the last server frame is repeated once
so that the filter, which needs a successor, emits the frames up to its time. Like ``ours`` it
needs the next server frame, so it belongs to the same timing (l = 0). In Fig. 6 the colour
video alone is HEVC-coded at the bitrate (at f_s) before interpolation.
"""

from __future__ import annotations

import json
import math
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from splitrender.evaluation.demo import (
    DEFAULT_METHODS,
    FC,
    FS,
    DemoArgumentError,
    _json_number,
    cell,
    check_gpu,
    check_methods,
    check_run_args,
    metric_names,
)
from splitrender.errors import InvalidInputError
from splitrender.files import OutputFolder, write_atomic
from splitrender.progress import Progress
from splitrender.evaluation.metrics import PSNR_CAP_DB, SKIP_FRAMES
from splitrender.evaluation.references import minterpolate
from splitrender.evaluation.sweep import SweepStats, Task, check_ray_installed, make_task
from splitrender.net.model import NetworkModel

__all__ = [
    "DEFAULT_DELAYS",
    "DEFAULT_EVAL_METHODS",
    "DEFAULT_SCENES",
    "ROW_KEYS",
    "EvalArgumentError",
    "EvalConfig",
    "TIMEWARP_LINES",
    "VIDEO_INTERP",
    "format_rows",
    "minterpolate",
    "run_eval",
    "vmaf_crossings",
]

ROW_KEYS: tuple[str, ...] = (
    "scene", "variant", "method", "bitrate_mbps", "delay", "stereo",
    "ssim", "flip", "psnr", "vmaf", "mbps", "frames", "network",
)
DEFAULT_SCENES: tuple[str, ...] = ("courtyard", "colonnade", "lab")
DEFAULT_DELAYS: tuple[int, ...] = (0, 1, 2, 4, 8, 12)
#: FFmpeg's minterpolate of the server colour video (an extra method of eval).
VIDEO_INTERP = "video_interp"
DEFAULT_EVAL_METHODS: tuple[str, ...] = (*DEFAULT_METHODS, VIDEO_INTERP)
#: Figure 6's timewarp reference lines: (server FPS, prediction delay in seconds).
TIMEWARP_LINES: tuple[tuple[int, float], ...] = ((10, 0.1), (30, 1 / 30), (60, 1 / 60))
#: The VMAF levels whose bitrates Figure 6 reports for ``ours``.
VMAF_LEVELS: tuple[float, ...] = (60.0, 80.0)
_METRIC_HEAD = (("ssim", "SSIM ↑", ".4f", max), ("flip", "FLIP ↓", ".4f", min),
                ("psnr", "PSNR ↑", ".2f", max), ("vmaf", "VMAF ↑", ".2f", max))

_Image = npt.NDArray[np.uint8]
Row = dict[str, Any]


class EvalArgumentError(DemoArgumentError):
    """An argument of ``eval`` that cannot work."""


@dataclass
class EvalConfig:
    out: Path = Path("splitrender-eval")
    scenes: tuple[str, ...] = DEFAULT_SCENES
    methods: tuple[str, ...] = DEFAULT_EVAL_METHODS
    delays: tuple[int, ...] = DEFAULT_DELAYS
    scale: float = 0.05
    seconds: float = 1.0
    bitrate_mbps: float | None = None
    #: Figure 6: paper-equivalent bitrates (Mb/s at 2560x1440, scaled by pixel count); empty: none.
    bitrates: tuple[float, ...] = ()
    #: Table 1's variants (``"static"``, ``"dynamic"``).
    variants: tuple[str, ...] = ("static", "dynamic")
    #: Figure 6's scenes (a subset of ``scenes``); ``None``: all of them.
    rd_scenes: tuple[str, ...] | None = None
    stereo: bool = False
    vmaf: bool = True
    trace: Path | None = None
    trace_scale: float = 1.0
    progress: bool = True
    #: ``"cpu"`` or ``"wgpu"`` (the methods with a GPU kernel; see ``gpu.backend_for``).
    backend: str = "cpu"
    #: Colour sub-samples per pixel side of every render (server, ground truth, the timewarp
    #: lines' servers); ``None``: ``scenes.default_samples`` of each camera's size.
    samples: int | None = None
    #: The link of every experiment (bandwidth, latency, jitter, loss, seed); ``None``: the ideal
    #: link. Its ``extra_delay_frames`` is each experiment's ``l`` (0 but in Table 2).
    network: NetworkModel | None = None
    #: A recording (e.g. an imported dataset) to evaluate instead of rendering the built-in
    #: scenes: Table 1 only (uncompressed, every method) on it, as the one scene ``scenes[0]``
    #: and its own variant, rates and length (``delays``, ``variants``, ``scale`` and
    #: ``seconds`` are not used; ``stereo``, ``bitrates``, ``rd_scenes``, ``trace`` and
    #: ``samples`` must be left unset).
    recording: Path | None = None
    #: ``"local"`` (processes of this machine) or ``"ray"`` (docs/sweeps.md).
    executor: str = "local"
    #: Local: worker processes (1: this process); Ray without ``address``: the local Ray's CPUs.
    #: ``None``: 1 for local, every CPU (``os.cpu_count()``) for a local Ray.
    jobs: int | None = None
    #: Ray: the cluster to join (``HOST:PORT``, ``ray://HOST:PORT`` or ``auto``); ``None``:
    #: start a local Ray and stop it at the end.
    address: str | None = None
    #: FLIP on every N-th scored client frame only (``evaluate_sequence``'s ``flip_every``):
    #: FLIP is most of the scoring time at 1280x720. 1: every frame.
    flip_every: int = 1
    #: The content-addressed cache of recordings, streams and rows; ``None``:
    #: :func:`~splitrender.evaluation.sweep.default_cache_dir`.
    cache: Path | None = None


@dataclass
class EvalResult:
    rows: list[Row]
    files: list[Path] = field(default_factory=list)
    width: int = 0
    height: int = 0
    bitrate_mbps: float = 0.0
    #: Lines worth printing (Figure 6: the bitrates at which ``ours`` reaches VMAF 60 and 80).
    summary: list[str] = field(default_factory=list)
    #: Tasks of the sweep per stage: in the graph, found in the cache, run now.
    stats: SweepStats | None = None


#: What ``eval`` writes into its folder besides ``recordings/``, replaced together.
_OUTPUTS = ("tables.md", "delays.png", "rate_distortion.png", "run-info.json", "results.json")


def _check_recording_config(cfg: EvalConfig) -> None:
    if len(cfg.scenes) != 1:
        raise EvalArgumentError("--dataset: evaluates one recording, named by one scene")
    for name, unset in (("--stereo", not cfg.stereo), ("--bitrates", not cfg.bitrates),
                        ("--rd-scenes", cfg.rd_scenes is None), ("--trace", cfg.trace is None),
                        ("--samples", cfg.samples is None)):
        if not unset:
            raise EvalArgumentError(f"{name}: not with --dataset (Table 1 only, on the "
                                    "dataset as it is)")
    check_methods(cfg.methods, EvalArgumentError, extra_methods=(VIDEO_INTERP,))


def check_config(cfg: EvalConfig) -> None:
    """Raises :class:`EvalArgumentError` (one line) for a configuration that cannot run."""
    from splitrender.scene.builtin import SCENE_NAMES

    if not cfg.scenes:
        raise EvalArgumentError("--scenes: expected at least one scene")
    if cfg.recording is not None:
        _check_recording_config(cfg)
        return
    from splitrender.scene.builtin import MAX_SAMPLES

    if cfg.samples is not None and not 1 <= cfg.samples <= MAX_SAMPLES:
        raise EvalArgumentError(f"--samples: expected 1..{MAX_SAMPLES}, got {cfg.samples}")
    for s in cfg.scenes:
        if s not in SCENE_NAMES:
            raise EvalArgumentError(
                f"--scenes: unknown scene {s!r}; expected some of: {', '.join(SCENE_NAMES)}"
            )
    if len(set(cfg.scenes)) != len(cfg.scenes):
        raise EvalArgumentError("--scenes: a scene is listed twice")
    if any(d < 0 for d in cfg.delays) or len(set(cfg.delays)) != len(cfg.delays):
        raise EvalArgumentError("--delays: expected distinct integers >= 0")
    check_run_args(cfg.scenes, cfg.methods, cfg.seconds, cfg.scale, EvalArgumentError,
                   extra_methods=(VIDEO_INTERP,))
    from splitrender.scene.recording import plan

    # A delay past the last scored client frame leaves every scored frame black: refused here,
    # before the render, not by the score task after it (pipeline._check_shown).
    _, n_client = plan(cfg.seconds, FS, FC)
    last = n_client - SKIP_FRAMES - 1
    if cfg.delays and max(cfg.delays) > last:
        raise EvalArgumentError(
            f"--delays: {max(cfg.delays)} client frames is past the last scored frame of "
            f"{cfg.seconds:g} s ({n_client} client frames, {SKIP_FRAMES} skipped at each end); "
            f"expected at most {last}, or a longer --seconds")
    # Likewise a latency that delays every frame past the last scored client frame (the score
    # task found it after rendering and encoding).
    if cfg.network is not None:
        worst = max(cfg.delays, default=0)
        if cfg.network.latency_ms * 1e-3 + worst / FC > last / FC:
            with_delays = f" with --delays up to {worst}" if worst else ""
            raise EvalArgumentError(
                f"--latency: {cfg.network.latency_ms:g} ms{with_delays} is past the last scored "
                f"client frame of {cfg.seconds:g} s (at {last / FC * 1e3:.4g} ms); expected "
                "less, or a longer --seconds")
    if not cfg.variants or any(v not in ("static", "dynamic") for v in cfg.variants) or len(
        set(cfg.variants)
    ) != len(cfg.variants):
        raise EvalArgumentError("--variants: expected static, dynamic or both, each once")
    if cfg.rd_scenes is not None:
        if not cfg.rd_scenes or any(s not in cfg.scenes for s in cfg.rd_scenes):
            raise EvalArgumentError(
                f"--rd-scenes: expected some of the --scenes ({', '.join(cfg.scenes)})"
            )
        if len(set(cfg.rd_scenes)) != len(cfg.rd_scenes):
            raise EvalArgumentError("--rd-scenes: a scene is listed twice")
    if any(not (b > 0 and math.isfinite(b)) for b in cfg.bitrates):
        raise EvalArgumentError("--bitrates: expected finite numbers > 0")
    if len(set(cfg.bitrates)) != len(cfg.bitrates):
        raise EvalArgumentError("--bitrates: a bitrate is listed twice")
    if cfg.trace is not None and not cfg.trace.is_file():
        raise EvalArgumentError(f"--trace: {cfg.trace}: no such file")


def format_rows(rows: Sequence[Row], keys: Sequence[str], group: Sequence[str] = ()) -> str:
    """``rows`` as a Markdown table: the columns ``keys`` then the metrics, Mb/s and frames; the
    best value of each metric among the rows that agree on ``group`` is in bold."""
    best: dict[tuple[Any, ...], dict[str, float]] = {}
    for metric, _, _, pick in _METRIC_HEAD:
        by: dict[tuple[Any, ...], list[float]] = {}
        for r in rows:
            v = r[metric]
            if isinstance(v, (int, float)) and math.isfinite(v):
                by.setdefault(tuple(r[g] for g in group), []).append(float(v))
        for g, vs in by.items():
            if len(vs) > 1:
                best.setdefault(g, {})[metric] = pick(vs)
    head = [*keys, *(h for _, h, _, _ in _METRIC_HEAD), "Mb/s", "frames"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        b = best.get(tuple(r[g] for g in group), {})
        cells = [cell(r[k], "") if k != "bitrate_mbps" else cell(r[k], ".3g") for k in keys]
        for metric, _, fmt, _ in _METRIC_HEAD:
            c = cell(r[metric], fmt)
            cells.append(f"**{c}**" if metric in b and r[metric] == b[metric] else c)
        cells += [cell(r["mbps"], ".3f"), str(r["frames"])]
        lines.append("| " + " | ".join(str(c) for c in cells) + " |")
    return "\n".join(lines)


_TASKS = "splitrender.evaluation.sweep_tasks"


@dataclass
class _Planned:
    """A row of the results before the sweep ran: its fixed fields and the score tasks whose
    parts (one per eye) make its metrics."""

    fixed: Row
    parts: tuple[str, ...]


class _Plan:
    """The task graph of one ``eval`` (built in the order the rows appear in results.json)."""

    def __init__(self, cfg: EvalConfig, trace: Any, metrics: tuple[str, ...],
                 given: Any) -> None:
        self.cfg = cfg
        self.trace = trace
        self.metrics = metrics
        self.given = given
        self.tasks: dict[str, Task] = {}
        #: ``OUT/recordings/`` names of the rendered recordings, by task key.
        self.names: dict[str, str] = {}

    def add(self, stage: str, fn: str, params: Row, deps: Sequence[Task] = (),
            label: str = "") -> Task:
        paths = {} if self.given is None else {"recording": str(self.given.path)}
        if self.trace is not None and stage == "render":
            paths["trace"] = str(self.cfg.trace)
        t = make_task(stage, f"{_TASKS}:{fn}", params, deps, paths, label)
        self.tasks.setdefault(t.key, t)
        return t

    def _motion(self) -> Row:
        cfg = self.cfg
        return {"seconds": cfg.seconds, "scale": cfg.scale, "samples": cfg.samples,
                "trace_sha256": None if self.trace is None else self.trace.sha256,
                "trace_scale": cfg.trace_scale if self.trace is not None else None}

    def recording(self, scene: str, variant: str, stereo: bool) -> Task:
        if self.given is not None:
            import hashlib

            # The manifest as load_recording read and checked it (not a second read of the
            # file): with every frame file's SHA-256 in it, it names the recording's bytes.
            manifest = json.dumps(self.given.manifest, sort_keys=True).encode()
            return self.add("render", "render_recording",
                            {"given": hashlib.sha256(manifest).hexdigest()},
                            label=f"{scene} (the recording {self.given.path})")
        from splitrender.evaluation.sweep_tasks import chunk_params
        from splitrender.scene.recording import plan

        params = {"scene": scene, "variant": variant, "stereo": stereo, **self._motion()}
        label = f"{scene} ({variant}{', stereo' if stereo else ''})"
        n_server, n_client = plan(self.cfg.seconds, FS, FC)
        parts = [
            self.add("render", "render_chunk", c,
                     label=f"{label} {c['part']} frames {c['start']}-{c['stop'] - 1}")
            for c in chunk_params(params, n_server, n_client)
        ]
        t = self.add("render", "render_recording", params, parts, label=label)
        self.names[t.key] = f"{scene}-{variant}{'-stereo' if stereo else ''}"
        return t

    def timewarp(self, scene: str, fps: int, delay: float) -> Task:
        return self.add("render", "render_timewarp",
                        {"scene": scene, "fps": fps, "delay": delay, **self._motion()},
                        label=f"{scene} main camera at {fps} FPS, prediction "
                        f"{1000 * delay:.1f} ms")

    def stream(self, rec: Task, codec: Any) -> Task:
        from dataclasses import asdict

        return self.add("encode", "encode_stream", {"codec": asdict(codec)}, (rec,),
                        label=f"{rec.label} at {codec.bitrate_mbps:.3g} Mb/s")

    def play(self, fixed: Row, rec: Task, stream: Task | None, eyes: int,
             which: Sequence[str] | None = None) -> _Planned:
        cfg = self.cfg
        deps = (rec,) if stream is None else (rec, stream)
        parts = []
        for eye in range(eyes):
            params = {"method": fixed["method"], "eye": eye, "stream": stream is not None,
                      "network": fixed["network"], "metrics": list(which or self.metrics),
                      "flip_every": cfg.flip_every,
                      "backend": cfg.backend, "own_rates": self.given is not None}
            where = f"{'stereo eye ' + str(eye) + ', ' if eyes > 1 else ''}l = {fixed['delay']}"
            parts.append(self.add("score", "score_play", params, deps,
                                  label=f"{fixed['method']} on {(stream or rec).label}, {where}"))
        return _Planned(fixed, tuple(t.key for t in parts))

    def score(self, fixed: Row, fn: str, params: Row, deps: Sequence[Task],
              which: Sequence[str] | None = None) -> _Planned:
        t = self.add("score", fn, {**params, "metrics": list(which or self.metrics),
                                   "flip_every": self.cfg.flip_every}, deps,
                     label=f"{fixed['method']} on {deps[0].label}"
                     + ("" if fixed["bitrate_mbps"] is None
                        else f" at {fixed['bitrate_mbps']:.3g} Mb/s"))
        return _Planned(fixed, (t.key,))


def _fixed(scene: str, variant: str, method: str, br: float | None, delay: int, stereo: bool,
           network: Row | None) -> Row:
    return {"scene": scene, "variant": variant, "method": method, "bitrate_mbps": br,
            "delay": delay, "stereo": stereo, "network": network}


def _link_recordings(folder: Path, targets: dict[str, Path]) -> None:
    """``folder/NAME`` as a symbolic link to each recording in the cache (for ``play``), each
    replaced atomically (a link made beside it, renamed over it). The links of an earlier run
    into the same folder that this one has not made are removed (a ``-stereo`` one stayed
    after a run without stereo, beside tables without its rows); anything else is left."""
    import os

    from splitrender.files import temporary_beside

    if folder.is_dir():
        for old in folder.iterdir():
            if old.is_symlink() and old.name not in targets:
                old.unlink(missing_ok=True)
    if not targets:
        return
    folder.mkdir(exist_ok=True)
    for name, target in sorted(targets.items()):
        link = folder / name
        if link.exists() and not link.is_symlink():
            continue  # a recording of an earlier version of eval: left as it is
        tmp = temporary_beside(link)
        os.symlink(target.resolve(), tmp, target_is_directory=True)
        try:
            os.replace(tmp, link)
        except BaseException:
            tmp.unlink(missing_ok=True)
            raise


def run_eval(
    cfg: EvalConfig, *, fault: Callable[[Task], None] | None = None,
    ray_init: dict[str, Any] | None = None,
) -> EvalResult:
    """Runs the experiments (see the module docstring) as one sweep (docs/sweeps.md) and writes
    their files to ``cfg.out``. ``fault(task)`` is called before each task starts (tests inject
    failures with it); ``ray_init`` adds ``ray.init`` arguments when a local Ray is started.

    Raises:
        EvalArgumentError: a configuration that cannot run.
        splitrender.evaluation.sweep.TaskFailedError: a task failed (what finished is cached).
        splitrender.evaluation.sweep.SweepError: the executor cannot start.
    """
    import platform
    from dataclasses import replace

    from splitrender.codec.coder import CodecConfig
    from splitrender.evaluation.pipeline import mean_of_eyes, network_json, network_text
    from splitrender.evaluation.sweep import Cache, default_cache_dir, run_graph
    from splitrender.scene.builtin import PREDICTION_DELAY, Scene, Trace, load_trace
    from splitrender.scene.recording import load_recording, plan

    check_config(cfg)
    check_gpu(cfg.backend)
    if cfg.executor not in ("local", "ray"):
        raise EvalArgumentError(f"--executor: expected local or ray, got {cfg.executor!r}")
    import os

    jobs = cfg.jobs if cfg.jobs is not None else (
        1 if cfg.executor == "local" else os.cpu_count() or 1)
    if jobs < 1:
        raise EvalArgumentError(f"--jobs: expected an integer >= 1, got {jobs}")
    if cfg.address is not None and cfg.executor != "ray":
        raise EvalArgumentError("--address: goes with --executor ray")
    if cfg.executor == "ray":
        check_ray_installed()  # before the cache and the outputs are touched
    given = None if cfg.recording is None else load_recording(cfg.recording)
    trace: Trace | None = None if cfg.trace is None else load_trace(cfg.trace)
    if trace is not None and given is None and cfg.seconds > trace.duration + 1e-9:
        # The render task found it, after the cache was laid out, naming no option.
        raise EvalArgumentError(f"--trace: {cfg.trace} lasts {trace.duration:.3f} s; "
                                f"expected at least --seconds {cfg.seconds:g}")
    out = cfg.out
    try:
        # Before the sweep, which may take hours: an --out that cannot take the outputs was
        # found when they were written.
        OutputFolder(out, _OUTPUTS).check()
    except InvalidInputError as e:
        raise EvalArgumentError(f"--out: {e}") from None
    cache = Cache(default_cache_dir() if cfg.cache is None else cfg.cache)
    try:
        cache.prepare()
    except OSError as e:
        raise EvalArgumentError(f"--cache: {cache.root}: cannot create the cache there: "
                                f"{e.strerror or e}") from e
    network = cfg.network or NetworkModel()
    fs, fc = FS, FC
    if given is None:
        w, h = Scene(cfg.scenes[0]).main_size(cfg.scale)
        n_server, n_client = plan(cfg.seconds, FS, FC)
        seconds = cfg.seconds
    else:
        fs, fc = given.fs, given.fc
        w, h = given.manifest["cameras"]["main"]
        n_server, n_client = len(given.server_frames), len(given.client_frames)
        seconds = float(given.manifest["seconds"])
    codec_cfg = (
        CodecConfig.scaled(w, h)
        if cfg.bitrate_mbps is None
        else CodecConfig(bitrate_mbps=cfg.bitrate_mbps)
    )
    bitrate = codec_cfg.bitrate_mbps
    metrics = tuple(metric_names(cfg.vmaf, w, h, cfg.progress))
    use_vmaf = "vmaf" in metrics
    g = _Plan(cfg, trace, metrics, given)
    tables: list[tuple[str, str, list[_Planned], tuple[str, ...], tuple[str, ...]]] = []
    core_methods = [m for m in cfg.methods if m != VIDEO_INTERP]

    def link(delay: int) -> Row:
        return network_json(replace(network, extra_delay_frames=delay, client_fps=fc))

    # Table 1: uncompressed, scenes x variants x methods.
    t1: list[_Planned] = []
    variants = cfg.variants if given is None else (given.variant,)
    for scene in cfg.scenes:
        for variant in variants:
            rec = g.recording(scene, variant, False)
            for method in cfg.methods:
                if method == VIDEO_INTERP:
                    t1.append(g.score(_fixed(scene, variant, method, None, 0, False, None),
                                      "score_interp", {"bitrate": None}, (rec,)))
                else:
                    t1.append(g.play(_fixed(scene, variant, method, None, 0, False, link(0)),
                                     rec, None, 1))
    tables.append((
        "Table 1: methods × scenes × static/dynamic, uncompressed",
        (f"Link: {network_text(network)}; uncompressed server frames (Mb/s: their raw rate). "
         "Bold: the best per scene and variant."),
        t1, ("scene", "variant", "method"), ("scene", "variant"),
    ))

    # Table 2: delays on the dynamic scenes, compressed.
    t2: list[_Planned] = []
    for scene in cfg.scenes if given is None else ():  # a recording given: Table 1 only
        rec = g.recording(scene, "dynamic", False)
        st = g.stream(rec, codec_cfg)
        for d in cfg.delays:
            t2.append(g.play(_fixed(scene, "dynamic", "ours", bitrate, d, False, link(d)),
                             rec, st, 1))
        t2.append(g.play(_fixed(scene, "dynamic", "ours_extrapolate", bitrate, 0, False,
                                link(0)), rec, st, 1))
    if t2:
        # Only the default is the paper's rate; a --bitrate given is the user's own.
        scaled = " (the paper's 40 Mb/s scaled by pixel count)" if cfg.bitrate_mbps is None else ""
        tables.append((
            "Table 2: extra delay l (client frames), dynamic scenes, compressed",
            (f"`ours` with the next server frame arriving l client frames late (f_c = {FC:g} "
             f"FPS, f_s = {FS:g} FPS), compressed at {bitrate:.3g} Mb/s{scaled}; "
             "`ours_extrapolate` (l = 0) for comparison. Bold: the best "
             "per scene."), t2, ("scene", "method", "delay"), ("scene",),
        ))

    # Table 3: mono vs stereo, compressed.
    if cfg.stereo:
        t3: list[_Planned] = []
        for scene in cfg.scenes:
            mono = g.recording(scene, "dynamic", False)
            mst = g.stream(mono, codec_cfg)
            rec = g.recording(scene, "dynamic", True)
            st = g.stream(rec, codec_cfg)
            for method in core_methods:
                t3.append(g.play(_fixed(scene, "dynamic", method, bitrate, 0, False, link(0)),
                                 mono, mst, 1))
                t3.append(g.play(_fixed(scene, "dynamic", method, bitrate, 0, True, link(0)),
                                 rec, st, 2))
        tables.append((
            "Table 3: mono vs stereo, dynamic scenes, compressed",
            (f"Compressed at {bitrate:.3g} Mb/s, l = 0. Stereo: IPD 7 cm, metrics averaged "
             "over both eyes (PSNR: of the mean MSE; frames: per eye). Bold: the best per scene "
             "and stereo setting."),
            t3, ("scene", "method", "stereo"), ("scene", "stereo"),
        ))

    # Figure 6: rate-distortion on the dynamic scenes.
    f6: list[_Planned] = []
    rd_scenes = cfg.scenes if cfg.rd_scenes is None else cfg.rd_scenes
    # Figure 6 plots VMAF; FLIP (three quarters of the evaluation time) is skipped there when
    # VMAF is computed.
    rd_metrics = tuple(m for m in metrics if m != "flip") if use_vmaf else metrics
    for scene in rd_scenes if cfg.bitrates else ():
        rec = g.recording(scene, "dynamic", False)
        tw: dict[int, Task | None] = {}
        for fps, delay in TIMEWARP_LINES:
            own = fps == FS and delay == PREDICTION_DELAY and trace is None
            tw[fps] = None if own else g.timewarp(scene, fps, delay)
        for paper in sorted(cfg.bitrates):
            cc = CodecConfig.scaled(w, h, paper_mbps=paper)
            br = cc.bitrate_mbps
            st = g.stream(rec, cc)
            for method in cfg.methods:
                if method == VIDEO_INTERP:
                    f6.append(g.score(_fixed(scene, "dynamic", method, br, 0, False, None),
                                      "score_interp", {"bitrate": br}, (rec,), rd_metrics))
                else:
                    f6.append(g.play(_fixed(scene, "dynamic", method, br, 0, False, link(0)),
                                     rec, st, 1, rd_metrics))
            f6.append(g.score(_fixed(scene, "dynamic", "video_streaming", br, 0, False, None),
                              "score_video_streaming", {"bitrate": br}, (rec,), rd_metrics))
            for fps, _ in TIMEWARP_LINES:
                src = tw[fps]
                f6.append(g.score(
                    _fixed(scene, "dynamic", f"timewarp_{fps}fps", br, 0, False, link(0)),
                    "score_timewarp",
                    {"fps": fps, "bitrate": br, "network": link(0),
                     "source": "recording" if src is None else "timewarp"},
                    (rec,) if src is None else (rec, src), rd_metrics))

    stages = Progress(0, cfg.progress)
    stats = run_graph(list(g.tasks.values()), cache, executor=cfg.executor, jobs=jobs,
                      address=cfg.address, progress=stages, fault=fault, ray_init=ray_init)
    stages.close()

    parts: dict[str, Row] = {}

    def row(p: _Planned) -> Row:
        got = [parts.setdefault(k, cache.read_row(k)) for k in p.parts]
        merged = mean_of_eyes(got)
        return {**p.fixed, **merged, "mbps": got[0]["mbps"]}

    rows: list[Row] = []
    seen: set[tuple[Any, ...]] = set()
    done_tables = []
    for title, note, planned, keys, group in tables:
        trows = [row(p) for p in planned]
        done_tables.append((title, note, trows, keys, group))
        for r in trows:
            k = tuple(r[x] for x in ("scene", "variant", "method", "bitrate_mbps", "delay",
                                     "stereo"))
            if k not in seen:
                seen.add(k)
                rows.append(r)
    t1_rows = done_tables[0][2]
    t2_rows = next((t[2] for t in done_tables if t[0].startswith("Table 2")), [])
    f6_rows = [row(p) for p in f6]
    for r in f6_rows:
        k = tuple(r[x] for x in ("scene", "variant", "method", "bitrate_mbps", "delay", "stereo"))
        if k not in seen:
            seen.add(k)
            rows.append(r)

    summary: list[str] = []
    if f6 and use_vmaf:
        for scene in rd_scenes:
            ours = [r for r in f6_rows if r["scene"] == scene and r["method"] == "ours"]
            for level, at in vmaf_crossings(ours, VMAF_LEVELS).items():
                paper_scale = 2560 * 1440 / (w * h)
                if at is not None:
                    summary.append(
                        f"{scene}: ours reaches VMAF {level:g} at {at:.3g} Mb/s "
                        f"({at * paper_scale:.3g} Mb/s at 2560x1440)"
                    )
                elif ours:
                    best = max(ours, key=lambda r: float(r["vmaf"]))
                    summary.append(
                        f"{scene}: ours does not reach VMAF {level:g} at the measured "
                        f"bitrates (best {best['vmaf']:.2f} at {best['mbps']:.3g} Mb/s)"
                    )
    if f6:
        done_tables.append((
            "Figure 6: rate-distortion, dynamic scenes",
            "Every method at each bitrate (l = 0; the paper-equivalent bitrate scaled by pixel "
            "count); `video_interp`: the main colour video alone, HEVC at the bitrate at "
            f"{FS:g} FPS, then FFmpeg minterpolate to {FC:g} FPS; `video_streaming`: the "
            f"ground-truth client frames themselves encoded as one {FC:g} FPS HEVC video at "
            "the same bitrate (zero latency, perfect prediction); `timewarp_Nfps`: the main "
            "camera's colour and depth rendered at N FPS with a prediction window of one frame "
            "(100/33.3/16.7 ms at 10/30/60 FPS), streamed at the bitrate, timewarped by the "
            "client. Plotted in `rate_distortion.png` with the uncompressed Table 1 values "
            "as dotted lines. Bold: the best per scene and bitrate."
            + (" FLIP is not computed here (the figure is VMAF; FLIP is most of the "
               "evaluation time)." if rd_metrics != metrics else "")
            + ("\n\n" + "\n".join(f"* {line}" for line in summary) if summary else ""),
            f6_rows, ("scene", "bitrate_mbps", "method"), ("scene", "bitrate_mbps"),
        ))

    # The results replace the previous run's together, results.json last (files.OutputFolder):
    # a plot of a run before (delays.png where this one has no Table 2) does not stay beside
    # them, and an interrupted write leaves the previous set.
    outputs = OutputFolder(out, _OUTPUTS)
    with outputs as stage:
        data = [{k: (_json_number(r[k]) if k in ("ssim", "flip", "psnr", "vmaf", "mbps")
                     else r[k]) for k in ROW_KEYS} for r in rows]
        write_atomic(stage / "results.json", json.dumps(data, indent=1, allow_nan=False) + "\n")
        files = [stage / "results.json"]
        motion = (f"the recording {cfg.recording}'s client poses" if given is not None
                  else "the scenes head paths" if trace is None else f"head trace {cfg.trace}")
        flip_note = ("" if cfg.flip_every == 1 else
                     f"; FLIP on every {_ordinal(cfg.flip_every)} of those frames only "
                     "(--flip-every)")
        md = [
            f"# splitrender eval: {', '.join(cfg.scenes)} at {w}x{h}",
            "",
            f"{seconds:g} s per scene: {n_server} server frames at {fs:g} FPS, {n_client} "
            f"client frames at {fc:g} FPS; per-frame means against the ground truth at the "
            "client pose, "
            f"first and last {SKIP_FRAMES} client frames excluded (PSNR: of the mean squared "
            f"error over those frames, capped at {PSNR_CAP_DB:g} dB)"
            f"{'' if use_vmaf else '; VMAF not computed'}"
            f"{flip_note}. Client motion: {motion}. Network: "
            f"{network_text(network)}{' (Table 2: l as given)' if t2 else ''}.",
            "",
        ]
        for title, note, trows, keys, group in done_tables:
            md += [f"## {title}", "", note, "", format_rows(trows, keys, group), ""]
        write_atomic(stage / "tables.md", "\n".join(md))
        files.append(stage / "tables.md")
        png = _plot_delays(stage / "delays.png", t2_rows, metrics) if t2_rows else None
        if png is not None:
            files.append(png)
        if f6_rows:
            png = _plot_rate_distortion(stage / "rate_distortion.png", f6_rows, t1_rows, metrics)
            if png is not None:
                files.append(png)
        # What made the results, apart from them: results.json holds nothing of the run itself.
        info = {"executor": cfg.executor, "jobs": jobs, "address": cfg.address,
                "cache": str(cache.root), "host": platform.node(), **stats.to_json()}
        write_atomic(stage / "run-info.json", json.dumps(info, indent=1, sort_keys=True) + "\n")
        files.append(stage / "run-info.json")
        files = [outputs.final(p) for p in files]
    # After the outputs are in place: a run that fails before (a damaged cached row, a plot
    # that cannot be written) changes neither them nor the links beside them.
    _link_recordings(out / "recordings", {n: cache.recording(k) for k, n in g.names.items()})
    return EvalResult(rows, files, w, h, bitrate, summary, stats)


def _ordinal(n: int) -> str:
    """``n`` as an English ordinal: 1st, 2nd, 3rd, 4th, 11th, 12th, 13th, 21st, ..."""
    suffix = "th" if n % 100 in (11, 12, 13) else {1: "st", 2: "nd", 3: "rd"}.get(n % 10, "th")
    return f"{n}{suffix}"


def vmaf_crossings(
    rows: Sequence[Row], levels: Sequence[float] = VMAF_LEVELS
) -> dict[float, float | None]:
    """Per VMAF level, the achieved Mb/s at which ``rows`` (one method's rate-distortion points)
    first reach it, interpolated linearly between the two measured points around it; the lowest
    rate if even that reaches it; ``None`` if no point does."""
    pts = sorted((float(r["mbps"]), float(r["vmaf"])) for r in rows
                 if isinstance(r.get("vmaf"), (int, float)) and math.isfinite(r["vmaf"]))
    out: dict[float, float | None] = {}
    for level in levels:
        at: float | None = None
        for i, (m, v) in enumerate(pts):
            if v >= level:
                if i == 0:
                    at = m
                else:
                    m0, v0 = pts[i - 1]
                    at = m0 + (level - v0) * (m - m0) / (v - v0)
                break
        out[level] = at
    return out


def _plot_delays(path: Path, rows: Sequence[Row], metrics: Sequence[str]) -> Path | None:
    """Metric vs l per scene for ``ours``, ``ours_extrapolate`` as a dashed line."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:  # pragma: no cover - matplotlib is a dependency
        print("note: matplotlib missing; delays.png not written", file=sys.stderr)
        return None
    shown = [m for m in ("ssim", "flip", "vmaf") if m in metrics]
    fig, axes = plt.subplots(1, len(shown), figsize=(4.2 * len(shown), 3.4), squeeze=False)
    scenes = list(dict.fromkeys(r["scene"] for r in rows))
    colors: Callable[[int], Any] = plt.get_cmap("tab10")
    for ax, metric in zip(axes[0], shown):
        for i, scene in enumerate(scenes):
            ours = sorted((r["delay"], r[metric]) for r in rows
                          if r["scene"] == scene and r["method"] == "ours")
            ax.plot([d for d, _ in ours], [v for _, v in ours], "o-", color=colors(i),
                    label=f"{scene}: ours")
            ext = [r[metric] for r in rows
                   if r["scene"] == scene and r["method"] == "ours_extrapolate"]
            if ext:
                ax.axhline(ext[0], color=colors(i), linestyle="--", linewidth=1,
                           label=f"{scene}: ours_extrapolate")
        ax.set_xlabel("extra delay l (client frames at 120 FPS)")
        ax.set_ylabel(f"{metric.upper()} {'↓' if metric == 'flip' else '↑'}")
        ax.grid(alpha=0.3)
    axes[0][0].legend(fontsize=7)
    fig.suptitle("Table 2: ours under delay (dashed: ours_extrapolate, l = 0)", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def _plot_rate_distortion(
    path: Path, rows: Sequence[Row], uncompressed: Sequence[Row], metrics: Sequence[str]
) -> Path | None:
    """Figure 6: VMAF (SSIM without VMAF) against the achieved Mb/s per scene and method; the
    uncompressed values (Table 1, dynamic) dotted."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:  # pragma: no cover - matplotlib is a dependency
        return None
    metric = "vmaf" if "vmaf" in metrics else "ssim"
    scenes = list(dict.fromkeys(r["scene"] for r in rows))
    methods = list(dict.fromkeys(r["method"] for r in rows))
    fig, axes = plt.subplots(1, len(scenes), figsize=(6.4 * len(scenes), 4.6), squeeze=False)
    palette: Callable[[int], Any] = plt.get_cmap("tab10")
    grey = {"timewarp_10fps": "0.65", "timewarp_30fps": "0.45", "timewarp_60fps": "0.2"}
    marker = {"timewarp_10fps": "v", "timewarp_30fps": "^", "timewarp_60fps": "D"}
    for ax, scene in zip(axes[0], scenes):
        for i, method in enumerate(m for m in methods if m not in grey):
            pts = sorted((r["mbps"], r[metric]) for r in rows
                         if r["scene"] == scene and r["method"] == method)
            style = "s--" if method == "video_streaming" else "o-"
            width = 2.2 if method == "ours" else 1.3
            ax.plot([p for p, _ in pts], [v for _, v in pts], style, color=palette(i),
                    label=method, linewidth=width, markersize=4)
            ref = [r[metric] for r in uncompressed if r["scene"] == scene
                   and r["variant"] == "dynamic" and r["method"] == method]
            if ref:
                ax.axhline(ref[0], color=palette(i), linestyle=":", linewidth=1)
        for method in (m for m in methods if m in grey):
            pts = sorted((r["mbps"], r[metric]) for r in rows
                         if r["scene"] == scene and r["method"] == method)
            ax.plot([p for p, _ in pts], [v for _, v in pts], "-.", marker=marker[method],
                    color=grey[method], label=method, linewidth=1.3, markersize=4)
        if metric == "vmaf":
            for level in VMAF_LEVELS:
                ax.axhline(level, color="0.85", linewidth=0.8, zorder=0)
        ax.set_title(scene, fontsize=10)
        ax.set_xlabel("achieved Mb/s")
        ax.set_ylabel(f"{metric.upper()} ↑")
        ax.grid(alpha=0.3)
    axes[0][-1].legend(fontsize=7, loc="center left", bbox_to_anchor=(1.02, 0.5))
    fig.suptitle("Figure 6: rate-distortion\n(dotted: uncompressed; grey: timewarp at 10/30/60 "
                 "FPS with one-frame prediction)", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
