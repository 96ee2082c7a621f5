"""``splitrender eval``: the paper's experiments (seeds/000 §4.2) on the built-in scenes.

* Table 1: every method × scene × static/dynamic on the uncompressed server frames (ideal link,
  ``l = 0``).
* Table 2: ``ours`` on the dynamic scenes with an extra delay of ``l`` client frames
  (default ``l ∈ {0, 1, 2, 4, 8, 12}``), compressed at the default bitrate (the paper's 40 Mb/s
  scaled by pixel count), plus ``ours_extrapolate`` at ``l = 0`` for comparison.
* Table 3 (``stereo=True``): every method on the dynamic scenes, compressed, mono (left eye of
  the mono recording) vs stereo (both eyes, IPD 7 cm; the metrics are the means over both eyes).

Recordings are rendered once per (scene, variant[, stereo]) into ``OUT/recordings/`` and reused
while their format version, scale, length, colour sub-samples and client motion match. Every result is a row with exactly the keys
:data:`ROW_KEYS`; ``results.json`` (the list of rows, rewritten after each experiment),
``tables.md`` (one Markdown table per experiment) and ``delays.png`` (metrics against ``l``) are
written to ``OUT``.

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
import subprocess
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
from splitrender.errors import SplitRenderError
from splitrender.files import write_atomic
from splitrender.progress import Progress
from splitrender.evaluation.metrics import SKIP_FRAMES
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


@dataclass
class EvalResult:
    rows: list[Row]
    files: list[Path] = field(default_factory=list)
    width: int = 0
    height: int = 0
    bitrate_mbps: float = 0.0
    #: Lines worth printing (Figure 6: the bitrates at which ``ours`` reaches VMAF 60 and 80).
    summary: list[str] = field(default_factory=list)


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


def _plan_stages(cfg: EvalConfig) -> int:
    if cfg.recording is not None:
        return 1 + len(cfg.methods)  # loading, Table 1
    core = len([m for m in cfg.methods if m != VIDEO_INTERP])
    nv = len(set(cfg.variants) | {"dynamic"})
    n = len(cfg.scenes) * nv  # recordings
    n += len(cfg.scenes) * len(cfg.variants) * len(cfg.methods)  # Table 1
    n += len(cfg.scenes) * (1 + len(cfg.delays) + 1)  # Table 2: encode, delays, extrapolate
    if cfg.stereo:
        n += len(cfg.scenes) * (1 + 1 + 2 * core)  # recording, encode, mono/stereo
    if cfg.bitrates:
        rd = len(cfg.scenes if cfg.rd_scenes is None else cfg.rd_scenes)
        lines = len(TIMEWARP_LINES)
        # Per scene: the timewarp servers at 30/60 FPS; per bitrate: encode, the methods,
        # video streaming, each timewarp line.
        n += rd * ((lines - 1) + len(cfg.bitrates) * (2 + len(cfg.methods) + lines))
    return n


def run_eval(cfg: EvalConfig) -> EvalResult:
    """Runs the experiments (see the module docstring) and writes their files to ``cfg.out``."""
    from dataclasses import replace

    from splitrender.codec.coder import CodecConfig
    from splitrender.gpu import backend_for
    from splitrender.evaluation.pipeline import (
        encode_decode,
        mean_row,
        network_json,
        network_text,
        play_and_score,
        play_and_score_eyes,
        raw_mbps,
    )
    from splitrender.scene.recording import Recording, load_recording, plan, write_recording
    from splitrender.scene.builtin import PREDICTION_DELAY, Scene, Trace, default_samples, load_trace
    from splitrender.types import ReprojectOptions, ServerFrame

    check_config(cfg)
    check_gpu(cfg.backend)
    given = None if cfg.recording is None else load_recording(cfg.recording)
    out = cfg.out
    out.mkdir(parents=True, exist_ok=True)
    (out / "recordings").mkdir(exist_ok=True)
    trace: Trace | None = None if cfg.trace is None else load_trace(cfg.trace)
    network = cfg.network or NetworkModel()
    # Rates, size and length: the built-in scenes' (FS, FC, cfg.scale, cfg.seconds), or those of
    # the recording given; its server_fps and shadow subframes also go to the client.
    fs, fc = FS, FC
    options: ReprojectOptions | None = None
    if given is None:
        w, h = Scene(cfg.scenes[0]).main_size(cfg.scale)
        n_server, n_client = plan(cfg.seconds, FS, FC)
        seconds = cfg.seconds
    else:
        fs, fc = given.fs, given.fc
        w, h = given.manifest["cameras"]["main"]
        n_server, n_client = len(given.server_frames), len(given.client_frames)
        seconds = float(given.manifest["seconds"])
        options = ReprojectOptions(server_fps=fs, shadow_subframes=given.subframes)
    codec_cfg = (
        CodecConfig.scaled(w, h)
        if cfg.bitrate_mbps is None
        else CodecConfig(bitrate_mbps=cfg.bitrate_mbps)
    )
    bitrate = codec_cfg.bitrate_mbps
    metrics = metric_names(cfg.vmaf, w, h, cfg.progress)
    use_vmaf = "vmaf" in metrics
    stages = Progress(_plan_stages(cfg), cfg.progress)
    rows: list[Row] = []
    cache: dict[tuple[Any, ...], Row] = {}
    tables: list[tuple[str, str, list[Row], tuple[str, ...], tuple[str, ...]]] = []

    main_samples = default_samples(w, h) if cfg.samples is None else cfg.samples

    def recording(scene: str, variant: str, stereo: bool) -> Recording:
        if given is not None:
            stages.stage(f"loading {given.path} ({scene})")
            return given
        path = out / "recordings" / f"{scene}-{variant}{'-stereo' if stereo else ''}"
        if (path / "manifest.json").is_file():
            try:
                rec = load_recording(path)
                m = rec.manifest
                motion = m.get("client_motion", {})
                same_motion = (
                    motion.get("source") == "path"
                    if trace is None
                    else motion.get("sha256") == trace.sha256
                    and motion.get("translation_scale") == cfg.trace_scale
                )
                if (
                    m["scale"] == cfg.scale
                    and m["seconds"] == cfg.seconds
                    and m["samples"]["main"] == main_samples
                    and bool(m["stereo"]) == stereo
                    and same_motion
                ):
                    stages.stage(f"reusing {path}")
                    return rec
            except SplitRenderError:
                pass
        stages.stage(
            f"rendering {scene} ({variant}{', stereo' if stereo else ''}) at {w}x{h} into {path}"
        )
        write_recording(
            path, Scene(scene, variant), seconds=cfg.seconds, scale=cfg.scale, stereo=stereo,
            trace=trace, translation_scale=cfg.trace_scale, samples=cfg.samples, overwrite=True,
            progress=lambda d, t: stages.bar(d, t, "frames"),
        )
        return load_recording(path)

    def score(
        scene: str, variant: str, method: str, server: Sequence[Any], sizes: list[int] | None,
        br: float | None, mbps: float, delay: int, cams: Sequence[Sequence[Any]],
        truth: Sequence[Sequence[_Image]], which: Sequence[str] | None = None,
    ) -> Row:
        stereo = len(cams) > 1
        key = (scene, variant, method, br, delay, stereo)
        if key in cache:
            return cache[key]
        net = replace(network, extra_delay_frames=delay, client_fps=fc)
        scored = play_and_score_eyes(
            server, cams, truth, method, net, fc, metrics if which is None else which,
            frame_sizes=sizes, bar=stages.bar, options=options,
            backend=backend_for(method, cfg.backend),
        )
        row: Row = {
            "scene": scene, "variant": variant, "method": method, "bitrate_mbps": br,
            "delay": delay, "stereo": stereo, **mean_row(scored), "mbps": mbps,
            "network": network_json(net),
        }
        cache[key] = row
        rows.append(row)
        return row

    def interp(
        scene: str, variant: str, colours: Sequence[_Image], mbps: float, br: float | None,
        truth: Sequence[_Image], which: Sequence[str] = metrics,
    ) -> Row:
        frames = minterpolate(colours, fs, fc, len(truth))
        row = _score_frames(scene, variant, VIDEO_INTERP, br, frames, truth, mbps, which,
                            stages.bar)
        rows.append(row)
        return row

    core_methods = [m for m in cfg.methods if m != VIDEO_INTERP]
    loaded: dict[tuple[str, str, bool], tuple[list[Any], list[list[Any]], list[list[_Image]]]]
    loaded = {}

    def load(
        scene: str, variant: str, stereo: bool
    ) -> tuple[list[Any], list[list[Any]], list[list[_Image]]]:
        key = (scene, variant, stereo)
        if key in loaded:
            return loaded[key]
        rec = recording(scene, variant, stereo)
        eyes = 2 if stereo else 1
        server = list(rec.server_frames)
        cams: list[list[Any]] = [[] for _ in range(eyes)]
        truth: list[list[_Image]] = [[] for _ in range(eyes)]
        for c in rec.client_frames:
            for e in range(eyes):
                cams[e].append(c.cameras[e])
                truth[e].append(c.ground_truths[e])
        loaded[key] = (server, cams, truth)
        return loaded[key]

    def write_results() -> None:
        data = [{k: (_json_number(r[k]) if k in ("ssim", "flip", "psnr", "vmaf", "mbps")
                     else r[k]) for k in ROW_KEYS} for r in rows]
        write_atomic(out / "results.json", json.dumps(data, indent=1) + "\n")

    def add_table(
        title: str, note: str, trows: list[Row], keys: tuple[str, ...], group: tuple[str, ...]
    ) -> None:
        """A table for tables.md (written at the end); the rows so far go to results.json."""
        tables.append((title, note, trows, keys, group))
        write_results()

    # Table 1: uncompressed, scenes x variants x methods.
    t1: list[Row] = []
    variants = cfg.variants if given is None else (given.variant,)
    for scene in cfg.scenes:
        for variant in variants:
            server, cams, truth = load(scene, variant, False)
            mbps = raw_mbps(server, fs)
            for method in cfg.methods:
                stages.stage(f"table 1: {scene} ({variant}), {method}, uncompressed")
                if method == VIDEO_INTERP:
                    colours = [f.main.color for f in server]
                    raw = colours[0].nbytes * 8 * fs / 1e6
                    t1.append(interp(scene, variant, colours, raw, None, truth[0]))
                    continue
                t1.append(score(scene, variant, method, server, None, None, mbps, 0, cams, truth))
    add_table(
        "Table 1: methods × scenes × static/dynamic, uncompressed",
        f"Link: {network_text(network)}; uncompressed server frames (Mb/s: their raw rate). "
        "Bold: the best per scene and variant.",
        t1, ("scene", "variant", "method"), ("scene", "variant"),
    )

    # Table 2: delays on the dynamic scenes, compressed.
    t2: list[Row] = []
    decoded_mono: dict[str, tuple[list[Any], list[int], float]] = {}
    for scene in cfg.scenes if given is None else ():  # a recording given: Table 1 only
        server, cams, truth = load(scene, "dynamic", False)
        stages.stage(f"table 2: {scene}: encoding {len(server)} server frames at {bitrate:.3g} "
                     "Mb/s and decoding them")
        dec, sizes, mbps = encode_decode(server, codec_cfg, FS, stages.bar, len(server))
        decoded_mono[scene] = (dec, sizes, mbps)
        for d in cfg.delays:
            stages.stage(f"table 2: {scene}, ours, l = {d}")
            t2.append(score(scene, "dynamic", "ours", dec, sizes, bitrate, mbps, d, cams, truth))
        stages.stage(f"table 2: {scene}, ours_extrapolate, l = 0")
        t2.append(score(scene, "dynamic", "ours_extrapolate", dec, sizes, bitrate, mbps, 0,
                        cams, truth))
    if t2:
        add_table(
            "Table 2: extra delay l (client frames), dynamic scenes, compressed",
            f"`ours` with the next server frame arriving l client frames late (f_c = {FC:g} "
            f"FPS, f_s = {FS:g} FPS), compressed at {bitrate:.3g} Mb/s (the paper's 40 Mb/s "
            "scaled by pixel count); `ours_extrapolate` (l = 0) for comparison. Bold: the best "
            "per scene.", t2, ("scene", "method", "delay"), ("scene",),
        )

    # Table 3: mono vs stereo, compressed.
    if cfg.stereo:
        t3: list[Row] = []
        for scene in cfg.scenes:
            server, cams, truth = load(scene, "dynamic", True)
            stages.stage(f"table 3: {scene} (stereo): encoding and decoding")
            dec, sizes, mbps = encode_decode(server, codec_cfg, FS, stages.bar, len(server))
            mdec, msizes, mmbps = decoded_mono[scene]
            _, mcams, mtruth = load(scene, "dynamic", False)
            # Each method on the mono session (decoded for Table 2) and on the stereo one.
            sessions = {"mono": (mdec, msizes, mmbps, mcams, mtruth),
                        "stereo": (dec, sizes, mbps, cams, truth)}
            for method in core_methods:
                for eyes, (sdec, ssizes, smbps, scams, struth) in sessions.items():
                    stages.stage(f"table 3: {scene}, {method}, {eyes}")
                    t3.append(score(scene, "dynamic", method, sdec, ssizes, bitrate, smbps, 0,
                                    scams, struth))
        add_table(
            "Table 3: mono vs stereo, dynamic scenes, compressed",
            f"Compressed at {bitrate:.3g} Mb/s, l = 0. Stereo: IPD 7 cm, metrics averaged over "
            "both eyes (frames: per eye). Bold: the best per scene and stereo setting.",
            t3, ("scene", "method", "stereo"), ("scene", "stereo"),
        )

    # Figure 6: rate-distortion on the dynamic scenes.
    f6: list[Row] = []
    summary: list[str] = []
    rd_scenes = cfg.scenes if cfg.rd_scenes is None else cfg.rd_scenes
    # Figure 6 plots VMAF; FLIP (three quarters of the evaluation time) is skipped there when
    # VMAF is computed.
    rd_metrics = tuple(m for m in metrics if m != "flip") if "vmaf" in metrics else metrics
    if cfg.bitrates:
        for scene in rd_scenes:
            server, cams, truth = load(scene, "dynamic", False)
            tw_servers: dict[int, list[ServerFrame]] = {}
            for fps, delay in TIMEWARP_LINES:
                if fps == FS and delay == PREDICTION_DELAY and trace is None:
                    tw_servers[fps] = [_main_colour_depth(f) for f in server]
                    continue
                stages.stage(f"figure 6: {scene}: rendering the main camera at {fps} FPS "
                             f"(prediction {1000 * delay:.1f} ms) for the timewarp line")
                tw_servers[fps] = _timewarp_server(scene, fps, delay, cfg, trace, stages.bar)
            for paper in sorted(cfg.bitrates):
                cc = CodecConfig.scaled(w, h, paper_mbps=paper)
                br = cc.bitrate_mbps
                stages.stage(f"figure 6: {scene}: encoding and decoding at {br:.3g} Mb/s "
                             f"({paper:g} Mb/s at 2560x1440)")
                dec, sizes, mbps = encode_decode(server, cc, FS, stages.bar, len(server))
                for method in cfg.methods:
                    stages.stage(f"figure 6: {scene}, {method}, {br:.3g} Mb/s")
                    if method == VIDEO_INTERP:
                        coded, cmbps = _video_streaming([f.main.color for f in server], br, FS)
                        f6.append(interp(scene, "dynamic", coded, cmbps, br, truth[0],
                                         rd_metrics))
                        continue
                    f6.append(score(scene, "dynamic", method, dec, sizes, br, mbps, 0, cams,
                                    truth, rd_metrics))
                stages.stage(f"figure 6: {scene}, video streaming of the ground truth at "
                             f"{br:.3g} Mb/s")
                f6.append(_video_streaming_row(scene, truth[0], br, rd_metrics, stages.bar))
                rows.append(f6[-1])
                for fps, delay in TIMEWARP_LINES:
                    stages.stage(f"figure 6: {scene}, timewarp at {fps} FPS, {br:.3g} Mb/s")
                    twc = CodecConfig(bitrate_mbps=br, camera_shares=(1.0,), fps=float(fps),
                                      gop=fps)
                    tdec, tsizes, tmbps = encode_decode(tw_servers[fps], twc, float(fps))
                    tw_net = replace(network, extra_delay_frames=0, client_fps=FC)
                    sc = play_and_score(
                        tdec, cams[0], truth[0], "timewarp", tw_net, FC,
                        rd_metrics, frame_sizes=tsizes, bar=stages.bar,
                        options=ReprojectOptions(server_fps=float(fps)),
                    )
                    f6.append({
                        "scene": scene, "variant": "dynamic", "method": f"timewarp_{fps}fps",
                        "bitrate_mbps": br, "delay": 0, "stereo": False,
                        **{k: sc.metrics.mean.get(k) for k in ("ssim", "flip", "psnr", "vmaf")},
                        "mbps": tmbps, "frames": sc.row()["frames"],
                        "network": network_json(tw_net),
                    })
                    rows.append(f6[-1])
                write_results()
            if "vmaf" in metrics:
                ours = [r for r in f6 if r["scene"] == scene and r["method"] == "ours"]
                for level, at in vmaf_crossings(ours, VMAF_LEVELS).items():
                    paper_scale = 2560 * 1440 / (w * h)
                    if at is not None:
                        summary.append(
                            f"{scene}: ours reaches VMAF {level:g} at {at:.3g} Mb/s "
                            f"({at * paper_scale:.3g} Mb/s at 2560x1440)"
                        )
                    else:
                        best = max(ours, key=lambda r: float(r["vmaf"]))
                        summary.append(
                            f"{scene}: ours does not reach VMAF {level:g} at the measured "
                            f"bitrates (best {best['vmaf']:.2f} at {best['mbps']:.3g} Mb/s)"
                        )
        add_table(
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
            f6, ("scene", "bitrate_mbps", "method"), ("scene", "bitrate_mbps"),
        )

    files = [out / "results.json"]
    motion = (f"the recording {cfg.recording}'s client poses" if given is not None
              else "the scenes head paths" if trace is None else f"head trace {cfg.trace}")
    md = [
        f"# splitrender eval: {', '.join(cfg.scenes)} at {w}x{h}",
        "",
        f"{seconds:g} s per scene: {n_server} server frames at {fs:g} FPS, {n_client} client "
        f"frames at {fc:g} FPS; per-frame means against the ground truth at the client pose, "
        f"first and last {SKIP_FRAMES} client frames excluded"
        f"{'' if use_vmaf else '; VMAF not computed'}. Client motion: {motion}. Network: "
        f"{network_text(network)}{' (Table 2: l as given)' if t2 else ''}.",
        "",
    ]
    for title, note, trows, keys, group in tables:
        md += [f"## {title}", "", note, "", format_rows(trows, keys, group), ""]
    write_atomic(out / "tables.md", "\n".join(md))
    files.append(out / "tables.md")
    png = _plot_delays(out / "delays.png", t2, metrics) if t2 else None
    if png is not None:
        files.append(png)
    if f6:
        png = _plot_rate_distortion(out / "rate_distortion.png", f6, t1, metrics)
        if png is not None:
            files.append(png)
    return EvalResult(rows, files, w, h, bitrate, summary)


def _score_frames(
    scene: str, variant: str, method: str, br: float | None, frames: Sequence[_Image],
    truth: Sequence[_Image], mbps: float, metrics: Sequence[str],
    bar: Callable[[int, int, str], None],
) -> Row:
    from splitrender.evaluation.metrics import evaluate_sequence

    sm = evaluate_sequence(frames, truth, SKIP_FRAMES, metrics, fps=FC,
                           progress=lambda m, d, t: bar(d, t, m))
    return {
        "scene": scene, "variant": variant, "method": method, "bitrate_mbps": br, "delay": 0,
        "stereo": False, **{m: sm.mean.get(m) for m in ("ssim", "flip", "psnr", "vmaf")},
        "mbps": mbps, "frames": len(sm.frames), "network": None,
    }


def _rate(v: float) -> str:
    from fractions import Fraction

    f = Fraction(v).limit_denominator(1001)
    return f"{f.numerator}/{f.denominator}"


def minterpolate(
    frames: Sequence[_Image], fs: float, fc: float, n_out: int
) -> list[_Image]:
    """FFmpeg's motion-compensated interpolation (``minterpolate``, ``mi_mode=mci``,
    ``mc_mode=aobmc``, ``me_mode=bidir``, ``vsbmc=1``, no scene-change fallback) of ``frames``
    (RGB8, frame ``k`` at time ``k / fs``) to ``fc``; returns ``n_out`` frames, frame ``n`` at
    time ``n / fc`` (output ``n`` with ``n·fs/fc`` an integer ``k`` reproduces input ``k`` up to
    the filter's 8-bit YCbCr 4:4:4 round trip). The last frame is repeated once: the filter
    needs a successor to emit the frames up to its time.

    Raises:
        SplitRenderError: when ffmpeg fails or emits fewer than ``n_out`` frames.
    """
    from splitrender.evaluation.metrics import _ffmpeg

    if not frames:
        raise SplitRenderError("minterpolate: no frames")
    h, w = frames[0].shape[:2]
    data = b"".join(np.ascontiguousarray(f, dtype=np.uint8).tobytes()
                    for f in [*frames, frames[-1]])
    cmd = [
        _ffmpeg(), "-nostdin", "-hide_banner", "-loglevel", "error",
        "-f", "rawvideo", "-pix_fmt", "rgb24", "-s", f"{w}x{h}", "-r", _rate(fs), "-i", "-",
        "-vf", f"format=yuv444p,minterpolate=fps={_rate(fc)}:mi_mode=mci:mc_mode=aobmc"
        ":me_mode=bidir:vsbmc=1:scd=none,format=rgb24",
        "-f", "rawvideo", "-pix_fmt", "rgb24", "-",
    ]
    proc = subprocess.run(cmd, input=data, capture_output=True, check=False)
    if proc.returncode != 0:
        tail = proc.stderr.decode("utf-8", "replace").strip().splitlines()[-1:] or ["?"]
        raise SplitRenderError(f"minterpolate: ffmpeg exited with status {proc.returncode}: "
                               f"{tail[0]}")
    n = len(proc.stdout) // (w * h * 3)
    if n < n_out:
        raise SplitRenderError(f"minterpolate: ffmpeg emitted {n} frames, expected {n_out}")
    out = np.frombuffer(proc.stdout, np.uint8, count=n_out * h * w * 3).reshape(n_out, h, w, 3)
    return [out[i].copy() for i in range(n_out)]


def _main_colour_depth(f: Any) -> Any:
    """``f`` reduced to what timewarp streams: the main camera's colour and depth."""
    from splitrender.types import CameraFrame, ServerFrame

    return ServerFrame(f.index, f.time, CameraFrame(f.main.camera, f.main.color, f.main.depth))


def _timewarp_server(
    scene: str, fps: int, delay: float, cfg: EvalConfig, trace: Any,
    bar: Callable[[int, int, str], None],
) -> list[Any]:
    """The main camera's colour and depth at ``fps`` FPS, rendered at poses predicted
    ``delay`` seconds ahead (a traditional streaming server for the timewarp lines)."""
    from splitrender.scene.recording import plan
    from splitrender.scene.builtin import ClientMotion, PathMotion, Scene, TraceMotion

    sc = Scene(scene, "dynamic")
    motion: ClientMotion = (
        PathMotion(sc, delay) if trace is None
        else TraceMotion(sc, trace, cfg.trace_scale, delay)
    )
    n_server, _ = plan(cfg.seconds, float(fps), FC)
    out = []
    for k in range(n_server):
        f = sc.server_frame(k, cfg.scale, float(fps), 1, pose=motion.server_pose(k, float(fps)),
                            samples=cfg.samples)
        out.append(_main_colour_depth(f))
        bar(k + 1, n_server, "server frames")
    return out


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


def _video_streaming(
    truth: Sequence[_Image], mbps: float, fps: float
) -> tuple[list[_Image], float]:
    """``truth`` encoded as one low-latency HEVC video (libx265, 4:2:0, no B-frames) at ``mbps``
    and decoded; returns the decoded frames and the achieved Mb/s."""
    from fractions import Fraction

    import av

    h, w = truth[0].shape[:2]
    pw, ph = max(16, w + (w & 1)), max(16, h + (h & 1))
    kbps = max(2, round(mbps * 1000))
    enc: Any = av.CodecContext.create("libx265", "w")
    enc.width, enc.height, enc.pix_fmt = pw, ph, "yuv420p"
    rate = Fraction(fps).limit_denominator(1001)
    enc.time_base, enc.framerate, enc.bit_rate = 1 / rate, rate, kbps * 1000
    enc.options = {
        "preset": "medium",
        "tune": "zerolatency",
        "x265-params": f"bframes=0:scenecut=0:vbv-maxrate={kbps}:vbv-bufsize={max(1, kbps // 10)}"
        ":pools=1:frame-threads=1:log-level=error:info=0",
    }
    enc.open()
    dec: Any = av.CodecContext.create("hevc", "r")
    out: list[_Image] = []
    nbytes = 0

    def take(packets: Any) -> None:
        nonlocal nbytes
        for p in packets:
            nbytes += p.size
            for f in dec.decode(p):
                out.append(f.to_ndarray(format="rgb24")[:h, :w])

    for n, img in enumerate(truth):
        pad = np.zeros((ph, pw, 3), np.uint8)
        pad[:h, :w] = img
        frame = av.VideoFrame.from_ndarray(pad, format="rgb24").reformat(format="yuv420p")
        frame.pts = n
        take(enc.encode(frame))
    take(enc.encode(None))
    for f in dec.decode(None):
        out.append(f.to_ndarray(format="rgb24")[:h, :w])
    if len(out) != len(truth):
        raise SplitRenderError(f"video streaming: decoded {len(out)} of {len(truth)} frames")
    return out, nbytes * 8 * fps / len(truth) / 1e6


def _video_streaming_row(
    scene: str, truth: Sequence[_Image], mbps: float, metrics: Sequence[str],
    bar: Callable[[int, int, str], None],
) -> Row:
    from splitrender.evaluation.metrics import evaluate_sequence

    frames, achieved = _video_streaming(truth, mbps, FC)
    sm = evaluate_sequence(frames, truth, SKIP_FRAMES, metrics, fps=FC,
                           progress=lambda m, d, t: bar(d, t, m))
    return {
        "scene": scene, "variant": "dynamic", "method": "video_streaming",
        "bitrate_mbps": mbps, "delay": 0, "stereo": False,
        **{m: sm.mean.get(m) for m in ("ssim", "flip", "psnr", "vmaf")},
        "mbps": achieved, "frames": len(sm.frames), "network": None,
    }


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
