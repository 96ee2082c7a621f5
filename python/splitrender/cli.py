"""The ``splitrender`` command line.

``splitrender example`` renders two server frames of the synthetic dynamic scene, reprojects a
client frame between them with every method, writes the images and a montage as PNG and prints
each method's mean absolute error against the ground truth.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any, NoReturn

import numpy as np
import numpy.typing as npt

from splitrender import __version__
from splitrender.errors import SplitRenderError
from splitrender.imageio import write_png
from splitrender.reproject import METHODS, reproject
from splitrender.synthetic import SyntheticScene
from splitrender.types import MAX_SIDE, ClientRequest

__all__ = ["main"]

PROG = "splitrender"


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors (``splitrender: error: ...``) and no usage dump."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (see '{self.prog} --help')\n")


def _side(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
    if not 1 <= v <= MAX_SIDE:
        raise argparse.ArgumentTypeError(f"expected a size in 1..{MAX_SIDE}, got {v}")
    return v


def _build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog=PROG,
        description=(
            "Image-based split rendering: synthesise display-rate client frames from sparse "
            "server frames by bidirectional reprojection (Steiner et al. 2025)."
        ),
        epilog=f"Methods: {', '.join(METHODS)}. Example: {PROG} example --out splitrender-out",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    sub.required = True
    ex = sub.add_parser(
        "example",
        help="reproject a synthetic dynamic scene with every method and write PNGs",
        description=(
            "Render server frames 0 and 1 (10 FPS) of the synthetic dynamic scene (main camera "
            "plus two auxiliary cameras), reproject client frame 7 at 120 FPS (between them) at "
            "the client's own pose with every method, write <method>.png, ground_truth.png and "
            "montage.png to --out, and print each method's mean absolute error (MAE, 0-255) "
            "against the ground truth. Pixels a method leaves unmatched stay black."
        ),
    )
    ex.add_argument(
        "--out",
        type=Path,
        default=Path("splitrender-out"),
        metavar="DIR",
        help="output directory, created if missing (default: %(default)s)",
    )
    ex.add_argument(
        "--width", type=_side, default=640, metavar="W", help="main camera width (default: 640)"
    )
    ex.add_argument(
        "--height",
        type=_side,
        default=360,
        metavar="H",
        help="main camera height (default: 360)",
    )
    ex.add_argument(
        "--static",
        action="store_true",
        help="freeze the moving objects (default: dynamic scene)",
    )
    _add_render(sub)
    _add_encode(sub)
    _add_demo(sub)
    _add_play(sub)
    _add_eval(sub)
    _add_bench(sub)
    return parser


def _samples(text: str) -> int:
    from splitrender.scenes import MAX_SAMPLES

    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
    if not 1 <= v <= MAX_SAMPLES:
        raise argparse.ArgumentTypeError(f"expected 1..{MAX_SAMPLES} per pixel side, got {v}")
    return v


_SAMPLES_HELP = (
    "colour sub-samples per pixel side N: server colour, shadow colours and ground truth are "
    "the mean of N x N samples (depth, motion and shadow bits stay at the pixel centre); "
    "default: 3 up to 640x360 pixels per camera, 2 above"
)


def _positive(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not (v > 0 and v < float("inf")):
        raise argparse.ArgumentTypeError(f"expected a finite number > 0, got {text}")
    return v


def _add_render(sub: Any) -> None:
    re = sub.add_parser(
        "render",
        help="render a recording of a built-in scene (server buffers + ground truth)",
        description=(
            "Render SCENE with the reference renderer into a recording (docs/recording-format.md): "
            "every buffer of the main and both auxiliary cameras for every server frame (10 FPS, "
            "4 shadow subframes), the ground-truth client frames (120 FPS) and the client poses. "
            "Client motion: the scene's head-box path with its deterministic deviation, the server "
            "predicting with a 100 ms delay; or a recorded head trace (--trace), re-anchored at "
            "the path's start. The recording is written to DIR.partial-<pid> and renamed to DIR "
            "when complete. Rendering the same arguments twice gives identical bytes. Time: on 2 "
            "CPU cores about 0.8 s per server frame and 0.23 s per client frame at scale 0.125 "
            "(320x180, 3x3 colour samples), about 4x that at 0.25 (640x360); the defaults take "
            "about 70 s."
        ),
    )
    re.add_argument(
        "scene",
        metavar="SCENE",
        help="built-in scene (courtyard, colonnade, lab), or a JSON scene description (*.json) that "
        "places glTF models into one; see splitrender.scenes.Scene.from_description",
    )
    re.add_argument("--out", type=Path, required=True, metavar="DIR", help="recording directory")
    re.add_argument(
        "--variant",
        choices=("static", "dynamic"),
        default="dynamic",
        help="still or animated objects and light (default: %(default)s)",
    )
    re.add_argument(
        "--seconds",
        type=_positive,
        default=2.0,
        metavar="S",
        help="length to record, at most the scene's 4 s (default: %(default)s)",
    )
    re.add_argument(
        "--scale",
        type=_positive,
        default=0.125,
        metavar="X",
        help="main camera size round(2560X) x round(1440X) (default: %(default)s = 320x180)",
    )
    re.add_argument(
        "--trace",
        type=Path,
        metavar="FILE",
        help="head trace 'px py pz pitch yaw roll t_ms' per line (60 Hz) as client motion",
    )
    re.add_argument(
        "--trace-scale",
        type=float,
        default=1.0,
        metavar="F",
        help="scale of the trace's translation (default: %(default)s)",
    )
    re.add_argument("--stereo", action="store_true", help="two eyes (IPD 7 cm) per client frame")
    re.add_argument("--samples", type=_samples, default=None, metavar="N", help=_SAMPLES_HELP)
    re.add_argument("--force", action="store_true", help="replace DIR if it exists")
    re.add_argument("--quiet", action="store_true", help="no progress bar")


class _Bar:
    """A one-line text progress bar on stderr: frames done / total, elapsed and ETA."""

    def __init__(self, enabled: bool) -> None:
        self.enabled = enabled
        self.start = time.perf_counter()

    def __call__(self, done: int, total: int) -> None:
        if not self.enabled:
            return
        elapsed = time.perf_counter() - self.start
        eta = elapsed / done * (total - done) if done else 0.0
        width = 30
        fill = width * done // total
        bar = "#" * fill + "-" * (width - fill)
        end = "\n" if done == total else ""
        sys.stderr.write(
            f"\r[{bar}] {done}/{total} frames  {elapsed:5.1f} s  ETA {eta:5.1f} s{end}"
        )
        sys.stderr.flush()


def _render(args: argparse.Namespace) -> int:
    # Imported here: the renderer is not needed by the other commands.
    from splitrender.recording import plan, write_recording
    from splitrender.scenes import Scene, load_trace

    try:
        scene = (
            Scene.from_description(args.scene)
            if args.scene.endswith(".json")
            else Scene(args.scene, args.variant)
        )
        trace = None if args.trace is None else load_trace(args.trace)
        n_server, n_client = plan(args.seconds, 10.0, 120.0)
        w, h = scene.main_size(args.scale)
        if not args.quiet:
            print(
                f"rendering {scene.name} ({scene.variant}) at {w}x{h}: {n_server} server frames, "
                f"{n_client} client frames{' (stereo)' if args.stereo else ''}",
                file=sys.stderr,
            )
        bar = _Bar(not args.quiet)
        out = write_recording(
            args.out,
            scene,
            seconds=args.seconds,
            scale=args.scale,
            stereo=args.stereo,
            trace=trace,
            translation_scale=args.trace_scale,
            samples=args.samples,
            overwrite=args.force,
            progress=bar,
        )
    except SplitRenderError as e:
        print(f"{PROG}: error: {e}", file=sys.stderr)
        return 2
    print(f"wrote {out}/ in {time.perf_counter() - bar.start:.1f} s")
    return 0


def _add_encode(sub: Any) -> None:
    en = sub.add_parser(
        "encode",
        help="encode a recording into a stream file (HEVC + zstd, versioned packets)",
        description=(
            "Encode every server frame of the recording REC (from `splitrender render`) into a "
            "stream file (docs/stream-format.md): colour and shadow colours in 8-bit HEVC, depth "
            "and motion in 12-bit HEVC, shadow bitfields losslessly with zstd, split over the "
            "cameras (main 60 %%, auxiliary 20 %% each) and buffers (colour 50 %%, depth 20 %%, "
            "motion 20 %%, shadow colours 10 %%). Prints the achieved Mb/s per buffer, per camera "
            "and in total. The file is written under a temporary name and renamed when complete."
        ),
    )
    en.add_argument("recording", metavar="REC", type=Path, help="recording directory")
    en.add_argument("--out", type=Path, required=True, metavar="FILE", help="stream file to write")
    en.add_argument(
        "--bitrate",
        type=_positive,
        metavar="MBPS",
        help="total target in Mb/s (default: the paper's 40 Mb/s at 2560x1440 scaled to the "
        "recording's main camera by pixel count)",
    )
    en.add_argument("--quiet", action="store_true", help="no progress bar")


def _encode(args: argparse.Namespace) -> int:
    from splitrender.encode import encode_recording

    bar = _Bar(not args.quiet)
    try:
        stats = encode_recording(args.recording, args.out, bitrate_mbps=args.bitrate, progress=bar)
    except SplitRenderError as e:
        print(f"{PROG}: error: {e}", file=sys.stderr)
        return 2
    print(f"wrote {args.out} ({stats.frames} server frames) in {time.perf_counter() - bar.start:.1f} s")
    print(f"  {'buffer':<28} {'Mb/s':>8}")
    for name, mbps in sorted(stats.mbps_by_buffer().items()):
        print(f"  {name:<28} {mbps:8.3f}")
    for name, mbps in sorted(stats.mbps_by_camera().items()):
        print(f"  {'camera ' + name:<28} {mbps:8.3f}")
    print(f"  {'total':<28} {stats.mbps_total():8.3f}")
    return 0


def _methods(text: str) -> tuple[str, ...]:
    names = tuple(m.strip() for m in text.split(",") if m.strip())
    if not names:
        raise argparse.ArgumentTypeError("expected a comma-separated list of methods")
    for m in names:
        if m not in METHODS:
            raise argparse.ArgumentTypeError(
                f"unknown method {m!r}; expected some of: {','.join(METHODS)}"
            )
    if len(set(names)) != len(names):
        raise argparse.ArgumentTypeError(f"a method is listed twice in {text!r}")
    return names


def _count(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
    if not 1 <= v <= 100000:
        raise argparse.ArgumentTypeError(f"expected an integer in 1..100000, got {v}")
    return v


def _frames_delay(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
    if not 0 <= v <= 1000:
        raise argparse.ArgumentTypeError(f"expected an integer in 0..1000, got {v}")
    return v


def _add_backend(p: Any, scope: str) -> None:
    p.add_argument(
        "--backend", choices=("cpu", "wgpu"), default="cpu",
        help=f"where the reprojection runs: cpu (reproj-core) or wgpu (GPU compute shaders; "
        f"{scope}; without a GPU, Mesa's lavapipe: apt-get install mesa-vulkan-drivers) "
        "(default: %(default)s)",
    )


def _add_demo(sub: Any) -> None:
    from splitrender.demo import DEFAULT_METHODS

    de = sub.add_parser(
        "demo",
        help="render, encode, stream and reproject a built-in dynamic scene; video + metrics",
        description=(
            "The whole pipeline on a built-in dynamic scene: render the server frames (10 FPS, "
            "main + 2 auxiliary cameras, every buffer) and the ground-truth client frames "
            "(120 FPS, at the client's actual pose, which deviates from the server's predicted "
            "one); encode the server frames at --bitrate and decode them; play them through the "
            "network model (ideal link, no loss, --delay extra client frames) and the client with "
            "every method; score each method against the ground truth (SSIM, FLIP, PSNR, VMAF; "
            "first and last 12 client frames excluded). Writes to --out: video.mp4 (ground truth "
            "| ours | FLIP error map of ours, side by side, at --video-fps), stills/*.png "
            "(three client frames: ground truth, every method, the FLIP map, the side-by-side), "
            "summary.md and summary.json (per method: ssim, flip, psnr, vmaf, mbps, frames), "
            "and prints the table. The defaults (courtyard at 256x144, 1 s) take about 1.5 minutes "
            "on 2 CPU cores; time grows with scale^2 x seconds."
        ),
    )
    de.add_argument(
        "--scene", default="courtyard", metavar="NAME",
        help="built-in scene: courtyard, colonnade, lab (default: %(default)s)",
    )
    de.add_argument(
        "--out", type=Path, default=Path("splitrender-demo"), metavar="DIR",
        help="output directory, created if missing; files in it are replaced "
        "(default: %(default)s)",
    )
    de.add_argument(
        "--scale", type=_positive, default=0.1, metavar="X",
        help="main camera size round(2560X) x round(1440X) (default: %(default)s = 256x144)",
    )
    de.add_argument(
        "--seconds", type=_positive, default=1.0, metavar="S",
        help="length, at least 0.21 s (25 client frames) and at most the scene's 4 s "
        "(default: %(default)s)",
    )
    de.add_argument(
        "--bitrate", type=_positive, default=None, metavar="MBPS",
        help="target bitrate of the whole stream in Mb/s (default: the paper's 40 Mb/s at "
        "2560x1440 scaled by pixel count, at least 1.6: headers and lossless parts cost a "
        "fixed ~0.15 Mb/s at 256x144)",
    )
    de.add_argument(
        "--methods", type=_methods, default=DEFAULT_METHODS, metavar="LIST",
        help=f"comma-separated methods (default: {','.join(DEFAULT_METHODS)})",
    )
    de.add_argument(
        "--delay", type=_frames_delay, default=0, metavar="L",
        help="extra network delay in client frames, l (default: %(default)s)",
    )
    de.add_argument(
        "--video-fps", type=_positive, default=30.0, metavar="FPS",
        help="frame rate of video.mp4; every client frame is one video frame, so 30 plays the "
        "120 FPS session 4x slowed down (default: %(default)s)",
    )
    _add_backend(de, "ours, ours_extrapolate and forward_splat; the other methods stay on the CPU")
    de.add_argument("--no-vmaf", action="store_true", help="skip VMAF (its column shows '-')")
    de.add_argument("--quiet", action="store_true", help="no progress on stderr")


def _add_bench(sub: Any) -> None:
    be = sub.add_parser(
        "bench",
        help="time client decoding and reprojection per method on a built-in recording",
        description=(
            "Render (once; cached in the temporary directory) two server frames of SCENE at "
            "--scale, encode them at the paper's 40 Mb/s scaled by pixel count and time their "
            "decoding (median ms per server frame), then time reproject() between the two "
            "decoded frames per method on --frames client frames (median, after one warm-up). "
            "Prints per method: ms per client frame, FPS, ns per output pixel, MB touched and "
            "effective GB/s, where bytes touched = the source buffers the method reads (ours: "
            "colour, depth, one motion and one shadow direction of every camera of both frames) "
            "+ the output written (W*H*3), intermediates not counted. With --backend wgpu the "
        "pair is uploaded once and each client frame uploads its pose and downloads the image. "
            "Time on 2 cores at the default scale 0.5 (1280x720, the Targets' size): about "
            "30 s the first time (rendering), about 15 s with the cache."
        ),
    )
    be.add_argument(
        "--scene", default="courtyard", metavar="NAME",
        help="built-in scene: courtyard, colonnade, lab (default: %(default)s)",
    )
    be.add_argument(
        "--methods", type=_methods, default=METHODS, metavar="LIST",
        help=f"comma-separated methods (default: all: {','.join(METHODS)})",
    )
    be.add_argument(
        "--scale", type=_positive, default=0.5, metavar="X",
        help="main camera size round(2560X) x round(1440X) (default: %(default)s = 1280x720)",
    )
    be.add_argument(
        "--frames", type=_count, default=5, metavar="N",
        help="timed client frames per method (median) (default: %(default)s)",
    )
    be.add_argument(
        "--json", type=Path, default=None, metavar="FILE",
        help="also write a JSON list of rows with the keys method, backend, width, height, "
        "ms_per_frame, ns_per_pixel, decode_ms_per_server_frame",
    )
    _add_backend(be, "ours, ours_extrapolate and forward_splat only")
    be.add_argument("--quiet", action="store_true", help="no progress on stderr")


def _demo(args: argparse.Namespace) -> int:
    from splitrender.demo import DemoArgumentError, DemoConfig, format_table, run_demo

    cfg = DemoConfig(
        scene=args.scene,
        out=args.out,
        scale=args.scale,
        seconds=args.seconds,
        bitrate_mbps=args.bitrate,
        methods=tuple(args.methods),
        vmaf=not args.no_vmaf,
        delay_frames=args.delay,
        video_fps=args.video_fps,
        progress=not args.quiet,
        backend=args.backend,
    )
    try:
        res = run_demo(cfg)
    except DemoArgumentError as e:
        print(f"{PROG}: error: {e}", file=sys.stderr)
        return 2
    print(
        f"{cfg.scene} (dynamic) at {res.width}x{res.height}, {res.client_frames} client frames "
        f"from {res.server_frames} server frames at {res.mbps:.3f} Mb/s "
        f"(target {res.bitrate_mbps:.3g}); done in {res.seconds:.1f} s"
    )
    print(f"wrote {cfg.out}/: video.mp4, stills/ ({sum(p.suffix == '.png' for p in res.files)} "
          "PNGs), summary.md, summary.json")
    print(format_table(res.rows))
    return 0


def _names(text: str) -> tuple[str, ...]:
    names = tuple(m.strip() for m in text.split(",") if m.strip())
    if not names:
        raise argparse.ArgumentTypeError("expected a comma-separated list")
    return names


def _bitrates(text: str) -> tuple[float, ...]:
    return tuple(_positive(t) for t in _names(text))


def _delays(text: str) -> tuple[int, ...]:
    return tuple(_frames_delay(t) for t in _names(text))


def _add_play(sub: Any) -> None:
    pl = sub.add_parser(
        "play",
        help="play a recording or stream file through the network model and the client",
        description=(
            "Play SOURCE through the network model (ideal link, --delay extra client frames, no "
            "loss) and the client with --method, and score the client frames against the "
            "ground truth (SSIM, FLIP, PSNR, VMAF; first and last 12 client frames excluded). "
            "SOURCE is a recording directory (`splitrender render`; its server frames are played "
            "uncompressed, or encoded and decoded at --bitrate), a stream file (`splitrender "
            "encode`; --recording gives the recording it was encoded from, for the client poses "
            "and the ground truth), or a built-in scene name (rendered at --scale/--seconds into "
            "OUT/recording first). Writes OUT/frames/NNNN.png per client frame (or OUT/client.mp4 "
            "with --video) and OUT/play.json; prints the per-frame mode counts (interpolate, "
            "extrapolate, hold) and the metrics. A stereo recording plays its left eye."
        ),
    )
    pl.add_argument("source", metavar="SOURCE", help="recording directory, stream file or scene")
    pl.add_argument("--out", type=Path, required=True, metavar="DIR", help="output directory")
    pl.add_argument("--recording", type=Path, metavar="REC",
                    help="the recording a stream file was encoded from (needed for a stream)")
    pl.add_argument("--method", default="ours", choices=METHODS, metavar="M",
                    help=f"reprojection method: {', '.join(METHODS)} (default: %(default)s)")
    pl.add_argument("--delay", type=_frames_delay, default=0, metavar="L",
                    help="extra network delay in client frames, l (default: %(default)s)")
    pl.add_argument("--bitrate", type=_positive, default=None, metavar="MBPS",
                    help="encode and decode a recording's server frames at this total bitrate "
                    "first (default: uncompressed; a stream file is always decoded as is)")
    pl.add_argument("--scale", type=_positive, default=None, metavar="X",
                    help="scale of a scene rendered from its name (default 0.1); for a recording "
                    "it must match the recording's")
    pl.add_argument("--seconds", type=_positive, default=None, metavar="S",
                    help="play only the first S seconds (default: all; 1.0 for a scene name)")
    pl.add_argument("--video", action="store_true", help="write OUT/client.mp4 instead of PNGs")
    _add_backend(pl, "ours, ours_extrapolate and forward_splat")
    pl.add_argument("--no-vmaf", action="store_true", help="skip VMAF")
    pl.add_argument("--quiet", action="store_true", help="no progress on stderr")


def _play(args: argparse.Namespace) -> int:
    import json

    from splitrender.codec import CodecConfig, StreamDecoder
    from splitrender.demo import FC, Stages, _json_number, _Video, format_table
    from splitrender.metrics import SKIP_FRAMES, VMAF_MIN_SIDE
    from splitrender.network import NetworkModel
    from splitrender.pipeline import encode_decode, play_and_score, raw_mbps
    from splitrender.recording import load_recording, plan, write_recording
    from splitrender.scenes import SCENE_NAMES, Scene
    from splitrender.stream import StreamFile, stream_stats

    def fail(msg: str) -> int:
        print(f"{PROG}: error: {msg}", file=sys.stderr)
        return 2

    from splitrender.gpu import check_backend

    try:
        check_backend(args.backend, args.method)
    except SplitRenderError as e:
        return fail(f"--backend: {e}")
    src = Path(args.source)
    out: Path = args.out
    stages = Stages(3 if args.source in SCENE_NAMES else 2, not args.quiet)
    try:
        stream_path: Path | None = None
        if src.is_dir():
            rec_path = src
        elif src.is_file():
            if args.recording is None:
                return fail(f"{src} is a stream file; --recording REC must give its recording")
            if args.bitrate is not None:
                return fail("--bitrate: a stream file is played as encoded")
            stream_path, rec_path = src, args.recording
        elif args.source in SCENE_NAMES:
            scale = 0.1 if args.scale is None else args.scale
            seconds = 1.0 if args.seconds is None else args.seconds
            rec_path = out / "recording"
            if round(seconds * FC) <= 2 * SKIP_FRAMES:
                return fail(f"--seconds: {seconds:g} s is {round(seconds * FC)} client frames; at "
                            f"least {2 * SKIP_FRAMES + 1} are needed ({SKIP_FRAMES} skipped at "
                            "each end)")
            try:
                sw, sh = Scene(args.source).main_size(scale)
            except SplitRenderError as e:
                return fail(f"--scale: {e}")
            if min(sw, sh) < 16 or max(sw, sh) > 4096:
                return fail(f"--scale: {scale:g} gives a {sw}x{sh} main camera; expected "
                            "16..4096 pixels a side")
            stages.stage(f"rendering {args.source} (dynamic) at scale {scale:g} into {rec_path}")
            write_recording(rec_path, Scene(args.source, "dynamic"), seconds=seconds,
                            scale=scale, overwrite=True,
                            progress=lambda d, t: stages.bar(d, t, "frames"))
        else:
            return fail(f"{src}: no such recording or stream file, nor a built-in scene "
                        f"({', '.join(SCENE_NAMES)})")
        rec = load_recording(rec_path)
        if args.scale is not None and not math.isclose(rec.manifest["scale"], args.scale):
            return fail(f"--scale: {rec_path} was rendered at scale {rec.manifest['scale']:g}, "
                        f"not {args.scale:g}")
        seconds = rec.manifest["seconds"] if args.seconds is None else args.seconds
        if seconds > rec.manifest["seconds"] + 1e-9:
            return fail(f"--seconds: {rec_path} lasts {rec.manifest['seconds']:g} s")
        n_server, n_client = plan(seconds, rec.fs, rec.fc)
        if n_client <= 2 * SKIP_FRAMES:
            return fail(f"--seconds: {seconds:g} s is {n_client} client frames; at least "
                        f"{2 * SKIP_FRAMES + 1} are needed ({SKIP_FRAMES} skipped at each end)")
        clients = rec.client_frames[:n_client]
        cams = [c.camera for c in clients]
        truth = [c.ground_truth for c in clients]
        w, h = cams[0].width, cams[0].height
        sizes: list[int] | None
        if stream_path is not None:
            stages.stage(f"decoding {stream_path}")
            sf = StreamFile(stream_path)
            packets = list(sf.packets())[:n_server]
            with StreamDecoder() as dec:
                server = []
                for k, p in enumerate(packets):
                    server.append(dec.decode(p))
                    stages.bar(k + 1, len(packets), "server frames")
            sizes = [len(p) for p in packets]
            mbps, bitrate = stream_stats(packets, rec.fs).mbps_total(), None
        else:
            server = list(rec.server_frames[:n_server])
            if args.bitrate is not None:
                stages.stage(f"encoding and decoding at {args.bitrate:g} Mb/s")
                server, sizes, mbps = encode_decode(
                    server, CodecConfig(bitrate_mbps=args.bitrate), rec.fs, stages.bar,
                    len(server))
            else:
                stages.stage("uncompressed server frames")
                sizes, mbps = None, raw_mbps(server, rec.fs)
            bitrate = args.bitrate
        use_vmaf = not args.no_vmaf and min(w, h) >= VMAF_MIN_SIDE
        metrics = ("ssim", "flip", "psnr", "vmaf") if use_vmaf else ("ssim", "flip", "psnr")
        out.mkdir(parents=True, exist_ok=True)
        video = _Video(out / "client.mp4", w + (w & 1), h + (h & 1), 30.0) if args.video else None
        if not args.video:
            (out / "frames").mkdir(exist_ok=True)

        def on_frame(n: int, image: npt.NDArray[np.uint8], info: Any) -> None:
            if video is not None:
                pad = np.zeros((h + (h & 1), w + (w & 1), 3), np.uint8)
                pad[:h, :w] = image
                video.write(pad)
            else:
                write_png(out / "frames" / f"{n:04d}.png", image)

        stages.stage(f"{args.method}: playing {n_client} client frames (l = {args.delay}), "
                     f"then {', '.join(metrics)}")
        try:
            scored = play_and_score(
                server, cams, truth, args.method,
                NetworkModel(extra_delay_frames=args.delay, client_fps=rec.fc), rec.fc, metrics,
                frame_sizes=sizes, bar=stages.bar, on_frame=on_frame, backend=args.backend)
        finally:
            if video is not None:
                video.close()
    except SplitRenderError as e:
        return fail(str(e))
    modes = scored.playback.summary()
    row = {"method": args.method, **scored.row(), "mbps": mbps}
    data = {
        "source": str(src), "recording": str(rec_path), "method": args.method,
        "delay": args.delay, "bitrate_mbps": bitrate, "width": w, "height": h,
        "client_frames": n_client, "server_frames": len(server), "modes": modes,
        "mode_per_frame": scored.playback.modes(),
        **{k: _json_number(row[k]) for k in ("ssim", "flip", "psnr", "vmaf", "mbps")},
        "frames": row["frames"],
    }
    (out / "play.json").write_text(json.dumps(data, indent=1) + "\n", encoding="utf-8")
    where = "client.mp4" if args.video else f"frames/ ({n_client} PNGs)"
    print(f"wrote {out}/: {where}, play.json")
    print("modes: " + ", ".join(f"{m} {c}" for m, c in modes.items()))
    print(format_table([row]))
    return 0


def _eval_methods(text: str) -> tuple[str, ...]:
    from splitrender.evaluate import VIDEO_INTERP

    names = tuple(m.strip() for m in text.split(",") if m.strip())
    if not names:
        raise argparse.ArgumentTypeError("expected a comma-separated list of methods")
    for m in names:
        if m not in METHODS and m != VIDEO_INTERP:
            raise argparse.ArgumentTypeError(
                f"unknown method {m!r}; expected some of: {','.join((*METHODS, VIDEO_INTERP))}"
            )
    if len(set(names)) != len(names):
        raise argparse.ArgumentTypeError(f"a method is listed twice in {text!r}")
    return names


def _add_eval(sub: Any) -> None:
    from splitrender.evaluate import DEFAULT_DELAYS, DEFAULT_EVAL_METHODS, DEFAULT_SCENES

    ev = sub.add_parser(
        "eval",
        help="the paper's experiments (Tables 1-3, Fig. 6) on the built-in scenes: JSON, "
        "Markdown, plots",
        description=(
            "Table 1: every --methods x --scenes x --variants on uncompressed server frames "
            "(ideal link, l = 0). Table 2: ours on the dynamic scenes with --delays extra client "
            "frames, compressed at --bitrate, plus ours_extrapolate (l = 0). Table 3 (--stereo): "
            "every method, mono vs stereo, compressed. Figure 6 (--bitrates, on --rd-scenes): "
            "every method at each bitrate plus the references 'video_streaming' (the ground "
            "truth as one 120 FPS HEVC video) and 'timewarp_10fps/_30fps/_60fps' (main colour "
            "and depth rendered at 10/30/60 FPS with 100/33.3/16.7 ms prediction, timewarped); "
            "prints the bitrates at which ours reaches VMAF 60 and 80. 'video_interp' (a "
            "--methods entry, not in Tables 2-3) is FFmpeg's minterpolate of the server colour "
            "video from 10 to 120 FPS. Recordings are rendered once per "
            "(scene, variant) into OUT/recordings/ and reused. Writes OUT/results.json (a list "
            "of rows with the keys scene, variant, method, bitrate_mbps (null: uncompressed), "
            "delay, stereo, ssim, flip, psnr, vmaf, mbps, frames), OUT/tables.md and "
            "OUT/delays.png (+ OUT/rate_distortion.png). The defaults take about 3 minutes on 2 "
            "CPU cores (about 1 minute per scene)."
        ),
    )
    ev.add_argument("--out", type=Path, required=True, metavar="DIR", help="output directory")
    ev.add_argument("--scenes", type=_names, default=DEFAULT_SCENES, metavar="LIST",
                    help=f"comma-separated scenes (default: {','.join(DEFAULT_SCENES)})")
    ev.add_argument("--methods", type=_eval_methods, default=DEFAULT_EVAL_METHODS,
                    metavar="LIST",
                    help=f"Table 1/3 and Figure 6 methods (default: "
                    f"{','.join(DEFAULT_EVAL_METHODS)})")
    ev.add_argument("--delays", type=_delays, default=DEFAULT_DELAYS, metavar="LIST",
                    help=f"Table 2 delays l (default: {','.join(map(str, DEFAULT_DELAYS))})")
    ev.add_argument("--bitrate", type=_positive, default=None, metavar="MBPS",
                    help="bitrate of the compressed experiments (default: the paper's 40 Mb/s "
                    "scaled by pixel count)")
    ev.add_argument("--scale", type=_positive, default=0.05, metavar="X",
                    help="main camera size round(2560X) x round(1440X) (default: %(default)s)")
    ev.add_argument("--seconds", type=_positive, default=1.0, metavar="S",
                    help="length per scene (default: %(default)s)")
    ev.add_argument("--bitrates", type=_bitrates, default=(), metavar="LIST",
                    help="also Figure 6 (rate-distortion) at these paper-equivalent Mb/s (at "
                    "2560x1440, scaled by pixel count), e.g. 10,20,40,60,100; plus the 'video "
                    "streaming' and timewarp references; writes OUT/rate_distortion.png")
    ev.add_argument("--variants", type=_names, default=("static", "dynamic"), metavar="LIST",
                    help="Table 1's scene variants (default: static,dynamic; Tables 2-3 and "
                    "Figure 6 use dynamic)")
    ev.add_argument("--rd-scenes", type=_names, default=None, metavar="LIST",
                    help="Figure 6 on these of the --scenes only (default: all --scenes)")
    ev.add_argument("--stereo", action="store_true", help="also Table 3 (mono vs stereo)")
    ev.add_argument("--trace", type=Path, default=None, metavar="FILE",
                    help="head trace 'px py pz pitch yaw roll t_ms' per line as client motion")
    ev.add_argument("--trace-scale", type=float, default=1.0, metavar="F",
                    help="scale of the trace's translation (default: %(default)s)")
    ev.add_argument("--samples", type=_samples, default=None, metavar="N",
                    help=_SAMPLES_HELP + " (every render: recordings and the timewarp lines)")
    _add_backend(ev, "ours, ours_extrapolate and forward_splat; the other methods stay on the CPU")
    ev.add_argument("--no-vmaf", action="store_true", help="skip VMAF")
    ev.add_argument("--quiet", action="store_true", help="no progress on stderr")


def _eval(args: argparse.Namespace) -> int:
    from splitrender.evaluate import EvalArgumentError, EvalConfig, run_eval

    cfg = EvalConfig(
        out=args.out, scenes=tuple(args.scenes), methods=tuple(args.methods),
        delays=tuple(args.delays), scale=args.scale, seconds=args.seconds,
        bitrate_mbps=args.bitrate, bitrates=tuple(args.bitrates), stereo=args.stereo, vmaf=not args.no_vmaf,
        rd_scenes=None if args.rd_scenes is None else tuple(args.rd_scenes),
        variants=tuple(args.variants),
        trace=args.trace, trace_scale=args.trace_scale, progress=not args.quiet,
        backend=args.backend, samples=args.samples,
    )
    try:
        res = run_eval(cfg)
    except EvalArgumentError as e:
        print(f"{PROG}: error: {e}", file=sys.stderr)
        return 2
    for line in res.summary:
        print(line)
    print(f"{len(res.rows)} rows at {res.width}x{res.height}; wrote "
          + ", ".join(str(p) for p in res.files))
    return 0


def _bench(args: argparse.Namespace) -> int:
    import json

    from splitrender.bench import BenchArgumentError, format_rows, run_bench

    try:
        rows = run_bench(
            args.scene, tuple(args.methods), args.scale, args.frames, progress=not args.quiet,
            backend=args.backend,
        )
    except BenchArgumentError as e:
        print(f"{PROG}: error: {e}", file=sys.stderr)
        return 2
    print(format_rows(rows))
    if args.json is not None:
        args.json.write_text(
            json.dumps([r.to_json() for r in rows], indent=1) + "\n", encoding="utf-8"
        )
        print(f"wrote {args.json}")
    return 0


def _progress(step: int, total: int, text: str) -> None:
    print(f"[{step}/{total}] {text}", flush=True)


def _montage(
    tiles: Sequence[npt.NDArray[np.uint8]], columns: int, gap: int = 4
) -> npt.NDArray[np.uint8]:
    h, w = tiles[0].shape[:2]
    rows = -(-len(tiles) // columns)
    out = np.full(
        (rows * h + (rows - 1) * gap, columns * w + (columns - 1) * gap, 3), 255, np.uint8
    )
    for k, tile in enumerate(tiles):
        r, c = divmod(k, columns)
        out[r * (h + gap) : r * (h + gap) + h, c * (w + gap) : c * (w + gap) + w] = tile
    return out


def _example(args: argparse.Namespace) -> int:
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    fps, client_fps, n = 10.0, 120.0, 7
    t = n / client_fps
    scene = SyntheticScene(dynamic=not args.static)
    total = 3 + len(METHODS)
    t0 = time.perf_counter()
    _progress(1, total, f"rendering server frame 0 (t = 0.000 s) at {args.width}x{args.height}")
    f0 = scene.server_frame(0, 0.0, args.width, args.height, fps=fps)
    _progress(2, total, f"rendering server frame 1 (t = {1 / fps:.3f} s)")
    f1 = scene.server_frame(1, 1.0 / fps, args.width, args.height, fps=fps)
    _progress(3, total, f"rendering ground truth at the client pose (t = {t:.4f} s)")
    # The client's actual head deviates from the path the server rendered (a prediction error).
    camera = scene.client_camera(t, args.width, args.height)
    truth = scene.ground_truth(camera, t)
    write_png(out / "ground_truth.png", truth)
    request = ClientRequest(camera, t)
    images = [truth]
    results: list[tuple[str, float, float, float]] = []
    for k, method in enumerate(METHODS):
        _progress(4 + k, total, f"reprojecting with {method}")
        start = time.perf_counter()
        r = reproject(f0, f1, request, method, diagnostics=True)
        ms = (time.perf_counter() - start) * 1e3
        mae = float(np.abs(r.image.astype(np.int16) - truth.astype(np.int16)).mean())
        coverage = float(r.matched.mean())
        write_png(out / f"{method}.png", r.image)
        images.append(r.image)
        results.append((method, mae, coverage, ms))
    write_png(out / "montage.png", _montage(images, columns=3))
    print(f"done in {time.perf_counter() - t0:.1f} s; wrote {len(images) + 1} PNGs to {out}/")
    print(f"montage.png, row by row: ground_truth, {', '.join(METHODS)}")
    print(f"client frame {n} at t = {t:.4f} s (alpha = {t * fps:.3f}); MAE against ground truth:")
    print(f"  {'method':<18} {'MAE':>7} {'matched':>8} {'time':>9}")
    for method, mae, coverage, ms in results:
        print(f"  {method:<18} {mae:7.2f} {coverage:8.1%} {ms:7.1f} ms")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``splitrender`` console script; returns the exit status."""
    parser = _build_parser()
    args = parser.parse_args(argv)
    try:
        if args.command == "example":
            return _example(args)
        if args.command == "render":
            return _render(args)
        if args.command == "encode":
            return _encode(args)
        if args.command == "demo":
            return _demo(args)
        if args.command == "bench":
            return _bench(args)
        if args.command == "play":
            return _play(args)
        if args.command == "eval":
            return _eval(args)
    except SplitRenderError as e:
        print(f"{PROG}: error: {e}", file=sys.stderr)
        return 1
    except OSError as e:
        print(f"{PROG}: error: {e}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted", file=sys.stderr)
        return 130
    parser.error(f"unknown command {args.command!r}")


if __name__ == "__main__":
    sys.exit(main())
