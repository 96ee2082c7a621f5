"""``splitrender eval``: the paper's experiments (seeds/000 §4.2) on the built-in scenes.

* Table 1: every method × scene × static/dynamic on the uncompressed server frames (ideal link,
  ``l = 0``).
* Table 2: ``ours`` on the dynamic scenes with an extra delay of ``l`` client frames
  (default ``l ∈ {0, 1, 2, 4, 8, 12}``), compressed at the default bitrate (the paper's 40 Mb/s
  scaled by pixel count), plus ``ours_extrapolate`` at ``l = 0`` for comparison.
* Table 3 (``stereo=True``): every method on the dynamic scenes, compressed, mono (left eye of
  the mono recording) vs stereo (both eyes, IPD 7 cm; the metrics are the means over both eyes).

Recordings are rendered once per (scene, variant[, stereo]) into ``OUT/recordings/`` and reused
while their scale, length and client motion match. Every result is a row with exactly the keys
:data:`ROW_KEYS`; ``results.json`` (the list of rows, rewritten after each experiment),
``tables.md`` (one Markdown table per experiment) and ``delays.png`` (metrics against ``l``) are
written to ``OUT``.

* Figure 6 (``bitrates``): every method on the dynamic scenes at each paper-equivalent bitrate
  (scaled by pixel count), plus ``video_streaming`` (the ground truth encoded as one 120 FPS
  HEVC video at the same bitrate), plotted as ``rate_distortion.png`` (VMAF, or SSIM without
  VMAF, against the achieved Mb/s; the uncompressed Table 1 values dotted). The paper's
  "timewarp at 30/60 FPS" reference lines are not built: they need server frames at 30/60 FPS
  with 33/17 ms prediction delays, and the scenes' prediction delay is fixed at 100 ms.
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

from splitrender.demo import (
    DEFAULT_METHODS,
    FC,
    FS,
    DemoArgumentError,
    Stages,
    _json_number,
    check_run_args,
)
from splitrender.errors import SplitRenderError
from splitrender.metrics import SKIP_FRAMES, VMAF_MIN_SIDE

__all__ = [
    "DEFAULT_DELAYS",
    "DEFAULT_SCENES",
    "ROW_KEYS",
    "EvalArgumentError",
    "EvalConfig",
    "format_rows",
    "run_eval",
]

ROW_KEYS: tuple[str, ...] = (
    "scene", "variant", "method", "bitrate_mbps", "delay", "stereo",
    "ssim", "flip", "psnr", "vmaf", "mbps", "frames",
)
DEFAULT_SCENES: tuple[str, ...] = ("courtyard", "colonnade", "lab")
DEFAULT_DELAYS: tuple[int, ...] = (0, 1, 2, 4, 8, 12)
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
    methods: tuple[str, ...] = DEFAULT_METHODS
    delays: tuple[int, ...] = DEFAULT_DELAYS
    scale: float = 0.05
    seconds: float = 1.0
    bitrate_mbps: float | None = None
    #: Figure 6: paper-equivalent bitrates (Mb/s at 2560x1440, scaled by pixel count); empty: none.
    bitrates: tuple[float, ...] = ()
    stereo: bool = False
    vmaf: bool = True
    trace: Path | None = None
    trace_scale: float = 1.0
    progress: bool = True


@dataclass
class EvalResult:
    rows: list[Row]
    files: list[Path] = field(default_factory=list)
    width: int = 0
    height: int = 0
    bitrate_mbps: float = 0.0


def check_config(cfg: EvalConfig) -> None:
    """Raises :class:`EvalArgumentError` (one line) for a configuration that cannot run."""
    from splitrender.scenes import SCENE_NAMES

    if not cfg.scenes:
        raise EvalArgumentError("--scenes: expected at least one scene")
    for s in cfg.scenes:
        if s not in SCENE_NAMES:
            raise EvalArgumentError(
                f"--scenes: unknown scene {s!r}; expected some of: {', '.join(SCENE_NAMES)}"
            )
    if len(set(cfg.scenes)) != len(cfg.scenes):
        raise EvalArgumentError("--scenes: a scene is listed twice")
    if any(d < 0 for d in cfg.delays) or len(set(cfg.delays)) != len(cfg.delays):
        raise EvalArgumentError("--delays: expected distinct integers >= 0")
    check_run_args(cfg.scenes, cfg.methods, cfg.seconds, cfg.scale, EvalArgumentError)
    if any(not (b > 0 and math.isfinite(b)) for b in cfg.bitrates):
        raise EvalArgumentError("--bitrates: expected finite numbers > 0")
    if len(set(cfg.bitrates)) != len(cfg.bitrates):
        raise EvalArgumentError("--bitrates: a bitrate is listed twice")
    if cfg.trace is not None and not cfg.trace.is_file():
        raise EvalArgumentError(f"--trace: {cfg.trace}: no such file")


def _cell(v: Any, fmt: str) -> str:
    if v is None:
        return "–"
    if isinstance(v, str):
        return v
    return format(v, fmt)


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
        cells = [_cell(r[k], "") if k != "bitrate_mbps" else _cell(r[k], ".3g") for k in keys]
        for metric, _, fmt, _ in _METRIC_HEAD:
            c = _cell(r[metric], fmt)
            cells.append(f"**{c}**" if metric in b and r[metric] == b[metric] else c)
        cells += [_cell(r["mbps"], ".3f"), str(r["frames"])]
        lines.append("| " + " | ".join(str(c) for c in cells) + " |")
    return "\n".join(lines)


def _plan_stages(cfg: EvalConfig) -> int:
    n = len(cfg.scenes) * 2  # recordings
    n += len(cfg.scenes) * 2 * len(cfg.methods)  # Table 1
    n += len(cfg.scenes) * (1 + len(cfg.delays) + 1)  # Table 2: encode, delays, extrapolate
    if cfg.stereo:
        n += len(cfg.scenes) * (1 + 1 + 2 * len(cfg.methods))  # recording, encode, mono/stereo
    n += len(cfg.scenes) * len(cfg.bitrates) * (2 + len(cfg.methods))  # Figure 6
    return n


def run_eval(cfg: EvalConfig) -> EvalResult:
    """Runs the experiments (see the module docstring) and writes their files to ``cfg.out``."""
    from splitrender.codec import CodecConfig
    from splitrender.network import NetworkModel
    from splitrender.pipeline import encode_decode, play_and_score, raw_mbps
    from splitrender.recording import Recording, load_recording, plan, write_recording
    from splitrender.scenes import Scene, Trace, load_trace

    check_config(cfg)
    out = cfg.out
    out.mkdir(parents=True, exist_ok=True)
    (out / "recordings").mkdir(exist_ok=True)
    trace: Trace | None = None if cfg.trace is None else load_trace(cfg.trace)
    w, h = Scene(cfg.scenes[0]).main_size(cfg.scale)
    n_server, n_client = plan(cfg.seconds, FS, FC)
    codec_cfg = (
        CodecConfig.scaled(w, h)
        if cfg.bitrate_mbps is None
        else CodecConfig(bitrate_mbps=cfg.bitrate_mbps)
    )
    bitrate = codec_cfg.bitrate_mbps
    use_vmaf = cfg.vmaf
    if use_vmaf and min(w, h) < VMAF_MIN_SIDE:
        use_vmaf = False
        if cfg.progress:
            print(f"note: {w}x{h} is below VMAF's {VMAF_MIN_SIDE} pixels a side; VMAF skipped",
                  file=sys.stderr)
    metrics = ("ssim", "flip", "psnr", "vmaf") if use_vmaf else ("ssim", "flip", "psnr")
    stages = Stages(_plan_stages(cfg), cfg.progress)
    rows: list[Row] = []
    cache: dict[tuple[Any, ...], Row] = {}
    tables: list[tuple[str, str, list[Row], tuple[str, ...], tuple[str, ...]]] = []

    def recording(scene: str, variant: str, stereo: bool) -> Recording:
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
            trace=trace, translation_scale=cfg.trace_scale, overwrite=True,
            progress=lambda d, t: stages.bar(d, t, "frames"),
        )
        return load_recording(path)

    def score(
        scene: str, variant: str, method: str, server: Sequence[Any], sizes: list[int] | None,
        br: float | None, mbps: float, delay: int, cams: Sequence[Sequence[Any]],
        truth: Sequence[Sequence[_Image]],
    ) -> Row:
        stereo = len(cams) > 1
        key = (scene, variant, method, br, delay, stereo)
        if key in cache:
            return cache[key]
        net = NetworkModel(extra_delay_frames=delay, client_fps=FC)
        means: dict[str, list[float]] = {}
        frames = 0
        for eye_cams, eye_truth in zip(cams, truth):
            s = play_and_score(server, eye_cams, eye_truth, method, net, FC, metrics,
                               frame_sizes=sizes, bar=stages.bar)
            r = s.row()
            for m in metrics:
                means.setdefault(m, []).append(float(r[m]))
            frames = int(r["frames"])
        row: Row = {
            "scene": scene, "variant": variant, "method": method, "bitrate_mbps": br,
            "delay": delay, "stereo": stereo,
            **{m: (float(np.mean(means[m])) if m in means else None)
               for m in ("ssim", "flip", "psnr", "vmaf")},
            "mbps": mbps, "frames": frames,
        }
        cache[key] = row
        rows.append(row)
        return row

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
        (out / "results.json").write_text(json.dumps(data, indent=1) + "\n", encoding="utf-8")

    # Table 1: uncompressed, scenes x variants x methods.
    t1: list[Row] = []
    for scene in cfg.scenes:
        for variant in ("static", "dynamic"):
            server, cams, truth = load(scene, variant, False)
            mbps = raw_mbps(server, FS)
            for method in cfg.methods:
                stages.stage(f"table 1: {scene} ({variant}), {method}, uncompressed")
                t1.append(score(scene, variant, method, server, None, None, mbps, 0, cams, truth))
    tables.append((
        "Table 1: methods × scenes × static/dynamic, uncompressed",
        f"Ideal link (l = 0), uncompressed server frames (Mb/s: their raw rate). Bold: the best "
        f"per scene and variant.", t1, ("scene", "variant", "method"), ("scene", "variant"),
    ))
    write_results()

    # Table 2: delays on the dynamic scenes, compressed.
    t2: list[Row] = []
    decoded_mono: dict[str, tuple[list[Any], list[int], float]] = {}
    for scene in cfg.scenes:
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
    tables.append((
        "Table 2: extra delay l (client frames), dynamic scenes, compressed",
        f"`ours` with the next server frame arriving l client frames late (f_c = {FC:g} FPS, "
        f"f_s = {FS:g} FPS), compressed at {bitrate:.3g} Mb/s (the paper's 40 Mb/s scaled by "
        "pixel count); `ours_extrapolate` (l = 0) for comparison. Bold: the best per scene.",
        t2, ("scene", "method", "delay"), ("scene",),
    ))
    write_results()

    # Table 3: mono vs stereo, compressed.
    if cfg.stereo:
        t3: list[Row] = []
        for scene in cfg.scenes:
            server, cams, truth = load(scene, "dynamic", True)
            stages.stage(f"table 3: {scene} (stereo): encoding and decoding")
            dec, sizes, mbps = encode_decode(server, codec_cfg, FS, stages.bar, len(server))
            mdec, msizes, mmbps = decoded_mono[scene]
            _, mcams, mtruth = load(scene, "dynamic", False)
            for method in cfg.methods:
                stages.stage(f"table 3: {scene}, {method}, mono")
                t3.append(score(scene, "dynamic", method, mdec, msizes, bitrate, mmbps, 0,
                                mcams, mtruth))
                stages.stage(f"table 3: {scene}, {method}, stereo")
                t3.append(score(scene, "dynamic", method, dec, sizes, bitrate, mbps, 0,
                                cams, truth))
        tables.append((
            "Table 3: mono vs stereo, dynamic scenes, compressed",
            f"Compressed at {bitrate:.3g} Mb/s, l = 0. Stereo: IPD 7 cm, metrics averaged over "
            "both eyes (frames: per eye). Bold: the best per scene and stereo setting.",
            t3, ("scene", "method", "stereo"), ("scene", "stereo"),
        ))
        write_results()

    # Figure 6: rate-distortion on the dynamic scenes.
    f6: list[Row] = []
    if cfg.bitrates:
        for scene in cfg.scenes:
            server, cams, truth = load(scene, "dynamic", False)
            for paper in sorted(cfg.bitrates):
                cc = CodecConfig.scaled(w, h, paper_mbps=paper)
                br = cc.bitrate_mbps
                stages.stage(f"figure 6: {scene}: encoding and decoding at {br:.3g} Mb/s "
                             f"({paper:g} Mb/s at 2560x1440)")
                dec, sizes, mbps = encode_decode(server, cc, FS, stages.bar, len(server))
                for method in cfg.methods:
                    stages.stage(f"figure 6: {scene}, {method}, {br:.3g} Mb/s")
                    f6.append(score(scene, "dynamic", method, dec, sizes, br, mbps, 0, cams,
                                    truth))
                stages.stage(f"figure 6: {scene}, video streaming of the ground truth at "
                             f"{br:.3g} Mb/s")
                f6.append(_video_streaming_row(scene, truth[0], br, metrics, stages.bar))
                rows.append(f6[-1])
        tables.append((
            "Figure 6: rate-distortion, dynamic scenes",
            "Every method at each bitrate (l = 0; the paper-equivalent bitrate scaled by pixel "
            "count), and `video_streaming`: the ground-truth client frames themselves encoded "
            f"as one {FC:g} FPS HEVC video at the same bitrate (zero latency, perfect "
            "prediction). Plotted in `rate_distortion.png` with the uncompressed Table 1 values "
            "as dotted lines. Bold: the best per scene and bitrate.",
            f6, ("scene", "bitrate_mbps", "method"), ("scene", "bitrate_mbps"),
        ))
        write_results()

    files = [out / "results.json"]
    md = [
        f"# splitrender eval: {', '.join(cfg.scenes)} at {w}x{h}",
        "",
        f"{cfg.seconds:g} s per scene: {n_server} server frames at {FS:g} FPS, {n_client} client "
        f"frames at {FC:g} FPS; per-frame means against the ground truth at the client pose, "
        f"first and last {SKIP_FRAMES} client frames excluded"
        f"{'' if use_vmaf else '; VMAF not computed'}. Client motion: "
        f"{'the scenes head paths' if trace is None else f'head trace {cfg.trace}'}.",
        "",
    ]
    for title, note, trows, keys, group in tables:
        md += [f"## {title}", "", note, "", format_rows(trows, keys, group), ""]
    (out / "tables.md").write_text("\n".join(md), encoding="utf-8")
    files.append(out / "tables.md")
    png = _plot_delays(out / "delays.png", t2, metrics)
    if png is not None:
        files.append(png)
    if f6:
        png = _plot_rate_distortion(out / "rate_distortion.png", f6, t1, metrics)
        if png is not None:
            files.append(png)
    return EvalResult(rows, files, w, h, bitrate)


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
    from splitrender.metrics import evaluate_sequence

    frames, achieved = _video_streaming(truth, mbps, FC)
    sm = evaluate_sequence(frames, truth, SKIP_FRAMES, metrics, fps=FC,
                           progress=lambda m, d, t: bar(d, t, m))
    return {
        "scene": scene, "variant": "dynamic", "method": "video_streaming",
        "bitrate_mbps": mbps, "delay": 0, "stereo": False,
        **{m: sm.mean.get(m) for m in ("ssim", "flip", "psnr", "vmaf")},
        "mbps": achieved, "frames": len(sm.frames),
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
    fig, axes = plt.subplots(1, len(scenes), figsize=(4.4 * len(scenes), 3.6), squeeze=False)
    colors: Callable[[int], Any] = plt.get_cmap("tab10")
    for ax, scene in zip(axes[0], scenes):
        for i, method in enumerate(methods):
            pts = sorted((r["mbps"], r[metric]) for r in rows
                         if r["scene"] == scene and r["method"] == method)
            style = "s--" if method == "video_streaming" else "o-"
            ax.plot([p for p, _ in pts], [v for _, v in pts], style, color=colors(i),
                    label=method)
            ref = [r[metric] for r in uncompressed if r["scene"] == scene
                   and r["variant"] == "dynamic" and r["method"] == method]
            if ref:
                ax.axhline(ref[0], color=colors(i), linestyle=":", linewidth=1)
        ax.set_title(scene, fontsize=10)
        ax.set_xlabel("achieved Mb/s")
        ax.set_ylabel(f"{metric.upper()} ↑")
        ax.grid(alpha=0.3)
    axes[0][0].legend(fontsize=7)
    fig.suptitle("Figure 6: rate-distortion (dotted: uncompressed)", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
