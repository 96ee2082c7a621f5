"""``splitrender play``: a recording, stream file or scene through the network model and the client."""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from splitrender.cli.args import PROG, add_backend, frames_delay, positive
from splitrender.errors import SplitRenderError
from splitrender.imageio import write_png
from splitrender.reproject import METHODS


def add(sub: Any) -> None:
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
    pl.set_defaults(run=run)
    pl.add_argument("source", metavar="SOURCE", help="recording directory, stream file or scene")
    pl.add_argument("--out", type=Path, required=True, metavar="DIR", help="output directory")
    pl.add_argument("--recording", type=Path, metavar="REC",
                    help="the recording a stream file was encoded from (needed for a stream)")
    pl.add_argument("--method", default="ours", choices=METHODS, metavar="M",
                    help=f"reprojection method: {', '.join(METHODS)} (default: %(default)s)")
    pl.add_argument("--delay", type=frames_delay, default=0, metavar="L",
                    help="extra network delay in client frames, l (default: %(default)s)")
    pl.add_argument("--bitrate", type=positive, default=None, metavar="MBPS",
                    help="encode and decode a recording's server frames at this total bitrate "
                    "first (default: uncompressed; a stream file is always decoded as is)")
    pl.add_argument("--scale", type=positive, default=None, metavar="X",
                    help="scale of a scene rendered from its name (default 0.1); for a recording "
                    "it must match the recording's")
    pl.add_argument("--seconds", type=positive, default=None, metavar="S",
                    help="play only the first S seconds (default: all; 1.0 for a scene name)")
    pl.add_argument("--video", action="store_true", help="write OUT/client.mp4 instead of PNGs")
    add_backend(pl, "ours, ours_extrapolate and forward_splat")
    pl.add_argument("--no-vmaf", action="store_true", help="skip VMAF")
    pl.add_argument("--quiet", action="store_true", help="no progress on stderr")


def run(args: argparse.Namespace) -> int:
    import json

    from splitrender.codec.coder import CodecConfig, StreamDecoder
    from splitrender.evaluation.demo import FC, _json_number, _Video, format_table
    from splitrender.progress import Progress
    from splitrender.evaluation.metrics import SKIP_FRAMES, VMAF_MIN_SIDE
    from splitrender.net.model import NetworkModel
    from splitrender.evaluation.pipeline import encode_decode, play_and_score, raw_mbps
    from splitrender.scene.recording import load_recording, plan, write_recording
    from splitrender.scene.builtin import SCENE_NAMES, Scene
    from splitrender.codec.stream import StreamFile, stream_stats

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
    stages = Progress(3 if args.source in SCENE_NAMES else 2, not args.quiet)
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


