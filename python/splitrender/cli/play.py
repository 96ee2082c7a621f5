"""``splitrender play``: a recording, stream file or scene through the network model and the client."""

from __future__ import annotations

import argparse
import itertools
import math
from collections.abc import Callable, Sequence
from contextlib import ExitStack
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from splitrender.cli.args import (
    add_backend,
    add_network,
    add_no_vmaf,
    add_out,
    add_quiet,
    command,
    fail,
    in_path,
    network_model,
    bitrate,
    scale,
    seconds,
)
from splitrender.errors import InvalidInputError, SplitRenderError, StreamError
from splitrender.files import OutputFolder, check_apart, write_atomic
from splitrender.imageio import write_png
from splitrender.progress import Progress
from splitrender.reproject import METHODS

if TYPE_CHECKING:
    from splitrender.types import ServerFrame

#: What a play writes into OUT (besides ``recording/`` for a scene or dataset, which it replaces
#: when it makes one): a run replaces them all, the ones it did not make this time included,
#: ``play.json`` last.
_OUTPUTS = ("frames", "client.mp4", "client_left.mp4", "client_right.mp4", "play.json")


def add(sub: Any) -> None:
    pl = command(sub, "play", run)
    pl.add_argument("source", metavar="SOURCE", nargs="?",
                    help="recording directory, stream file or scene (or --dataset)")
    pl.add_argument("--dataset", type=in_path, default=None, metavar="DIR",
                    help="play a dataset in the authors' layout (main/, left/, right/, "
                    "client_ol/) instead of SOURCE; imported into OUT/recording first")
    add_out(pl)
    pl.add_argument("--recording", type=in_path, metavar="REC",
                    help="the recording a stream file was encoded from (needed for a stream)")
    pl.add_argument("--method", default="ours", choices=METHODS, metavar="M",
                    help=f"reprojection method: {', '.join(METHODS)} (default: %(default)s)")
    pl.add_argument("--bitrate", type=bitrate, default=None, metavar="MBPS",
                    help="encode and decode a recording's server frames at this total bitrate "
                    "first (default: uncompressed; a stream file is always decoded as is)")
    pl.add_argument("--scale", type=scale, default=None, metavar="X",
                    help="scale of a scene rendered from its name (default 0.1); for a recording "
                    "it must match the recording's")
    pl.add_argument("--seconds", type=seconds, default=None, metavar="S",
                    help="play only the first S seconds (default: all; 1.0 for a scene name)")
    pl.add_argument("--stereo", action="store_true",
                    help="play both eyes of a stereo recording (or stream file's recording) and "
                    "report the metrics per eye and their mean")
    pl.add_argument("--video", action="store_true", help="write OUT/client.mp4 instead of PNGs")
    add_backend(pl, "ours, ours_extrapolate and forward_splat")
    add_no_vmaf(pl)
    add_quiet(pl)
    add_network(pl)


def run(args: argparse.Namespace) -> int:
    from splitrender.gpu import check_backend
    from splitrender.scene.builtin import SCENE_NAMES
    from splitrender.scene.recording import check_destination

    try:
        check_backend(args.backend, args.method)
    except SplitRenderError as e:
        return fail(f"--backend: {e}")
    if (args.source is None) == (args.dataset is None):
        return fail("expected SOURCE or --dataset DIR (one of them)")
    if args.source == "":  # Path("") is the current directory
        return fail("SOURCE: expected a recording, stream file or scene, got ''")
    if args.dataset is not None:
        for flag, given in (("--recording", args.recording is not None),
                            ("--scale", args.scale is not None)):
            if given:
                return fail(f"{flag}: not with --dataset (the dataset has its own size and "
                            "client cameras)")
    src = Path(args.source) if args.source is not None else args.dataset
    out: Path = args.out
    # Frames and play.json written into a recording, a dataset or over a stream file would
    # damage the input being played.
    inputs = {"source" if args.dataset is None else "dataset": src, "recording": args.recording}
    try:
        check_apart(out, {k: v for k, v in inputs.items() if v is not None and v.exists()})
    except SplitRenderError as e:
        return fail(f"--out {e}")
    rendered = args.source in SCENE_NAMES and not src.exists()
    try:
        if rendered or args.dataset is not None:
            # Checked before the work: what the play replaces at the end must be a recording.
            check_destination(out / "recording", overwrite=True)
        outputs = OutputFolder(out, _OUTPUTS)
    except SplitRenderError as e:
        return fail(str(e))
    stages = Progress(3 if rendered else 4 if args.dataset is not None else 2, not args.quiet)
    # Everything is written into a staging folder and moved into OUT when the play completes:
    # a failed, refused or interrupted play leaves OUT's previous outputs as they were, never
    # new frames beside an old play.json.
    try:
        with outputs as stage:
            report = _play(args, src, rendered, stage, outputs.final, stages)
    except SplitRenderError as e:
        return fail(str(e))
    finally:
        stages.close()
    print(report)
    return 0


def _play(args: argparse.Namespace, src: Path, rendered: bool, stage: Path,
          final: Callable[[Path], Path], stages: Progress) -> str:
    """The play itself, every output written into ``stage``; returns the text to print once
    they are in place. ``final`` gives a staged path's place in OUT. A refusal found on the way
    (a stream of another recording, --seconds too long) is raised as InvalidInputError, which
    drops what was staged."""
    import json

    from splitrender.codec.coder import CodecConfig, DecodedStream
    from splitrender.codec.stream import StreamFile, stream_stats
    from splitrender.evaluation.demo import (
        DemoArgumentError,
        _json_number,
        _Video,
        check_run_args,
        format_table,
        metric_names,
    )
    from splitrender.evaluation.metrics import SKIP_FRAMES
    from splitrender.evaluation.pipeline import (
        check_stream_of,
        encode_packets,
        mean_row,
        network_json,
        play_and_score_eyes,
        raw_mbps,
    )
    from splitrender.scene.builtin import SCENE_NAMES, Scene
    from splitrender.scene.dataset import import_dataset_as_recording
    from splitrender.scene.recording import load_recording, plan, write_recording
    from splitrender.types import ReprojectOptions

    stream: StreamFile | None = None
    if args.dataset is not None:
        rec_path = stage / "recording"
        import_dataset_as_recording(args.dataset, rec_path, overwrite=True, stages=stages)
    elif src.is_dir():
        if args.recording is not None:
            # --recording names the recording of a stream file (its poses and ground
            # truth); a recording SOURCE has its own, so another one would be ignored.
            raise InvalidInputError(
                f"--recording: only with a stream file SOURCE; {src} is a "
                "recording, which has its own client poses and ground truth")
        rec_path = src
    elif src.is_file():
        try:  # any other file was called a stream file, and --recording asked for
            stream = StreamFile(src)
        except StreamError as e:
            raise InvalidInputError(
                f"{src}: expected a recording folder, a stream file or a built-in scene; {e}"
            ) from None
        if args.recording is None:
            raise InvalidInputError(
                f"{src} is a stream file; --recording REC must give its recording")
        if args.bitrate is not None:
            raise InvalidInputError("--bitrate: a stream file is played as encoded")
        rec_path = args.recording
    elif rendered:
        if args.recording is not None:
            raise InvalidInputError(
                f"--recording: only with a stream file SOURCE; {args.source} is "
                "rendered into OUT/recording")
        scale = 0.1 if args.scale is None else args.scale
        seconds = 1.0 if args.seconds is None else args.seconds
        rec_path = stage / "recording"
        if args.stereo:
            raise InvalidInputError(
                f"--stereo: {args.source} is rendered mono; render a stereo "
                "recording with `splitrender render --stereo` and play that")
        try:
            check_run_args([args.source], [args.method], seconds, scale, DemoArgumentError)
        except DemoArgumentError as e:
            raise InvalidInputError(str(e)) from None
        stages.stage(f"rendering {args.source} (dynamic) at scale {scale:g} into "
                     f"{final(rec_path)}")
        write_recording(rec_path, Scene(args.source, "dynamic"), seconds=seconds,
                        scale=scale, overwrite=True,
                        progress=lambda d, t: stages.bar(d, t, "frames"))
    else:
        raise InvalidInputError(
            f"{src}: no such recording or stream file, nor a built-in scene "
            f"({', '.join(SCENE_NAMES)})")
    rec = load_recording(rec_path)
    if rec_path.is_relative_to(stage):  # named where it will be, not in the staging folder
        rec_path = final(rec_path)
    if args.stereo and not rec.stereo:
        raise InvalidInputError(
            f"--stereo: {rec_path} is a mono recording (one eye); render one with "
            "`splitrender render --stereo`")
    if args.scale is not None and not math.isclose(rec.manifest["scale"], args.scale):
        raise InvalidInputError(
            f"--scale: {rec_path} was rendered at scale {rec.manifest['scale']:g}, "
            f"not {args.scale:g}")
    seconds = rec.manifest["seconds"] if args.seconds is None else args.seconds
    if seconds > rec.manifest["seconds"] + 1e-9:
        raise InvalidInputError(f"--seconds: {rec_path} lasts {rec.manifest['seconds']:g} s")
    n_server, n_client = plan(seconds, rec.fs, rec.fc)
    if n_client <= 2 * SKIP_FRAMES:
        # Without --seconds the length is the recording's (or the dataset's): name that.
        what = ("--seconds:" if args.seconds is not None
                else f"{args.dataset if args.dataset is not None else rec_path} lasts")
        raise InvalidInputError(
            f"{what} {seconds:g} s, {n_client} client frames; at least "
            f"{2 * SKIP_FRAMES + 1} are needed ({SKIP_FRAMES} skipped at each end)")
    eyes = 2 if args.stereo else 1
    # The ground truths are read as they are scored: a play never holds them all.
    per_eye = [rec.eye(e, n_client) for e in range(eyes)]
    cams, truth = [c for c, _ in per_eye], [t for _, t in per_eye]
    w, h = cams[0][0].width, cams[0][0].height
    # The server frames are decoded (or read) when the client needs each, not before the
    # play: a 1280x720 server frame with its auxiliary cameras is about 50 MB decoded, so a
    # 10 s run held whole would be 5 GB (a second eye decodes them again instead).
    sizes: list[int] | None
    server: Sequence[ServerFrame] | DecodedStream
    if stream is not None:
        stages.stage(f"reading {src}")
        packets = list(itertools.islice(stream.packets(), n_server))
        if not packets:
            # Scoring nothing but held black frames would report a result for no content.
            raise InvalidInputError(
                f"{src}: the stream has no frames; expected at least one "
                "server frame")
        # Every packet's structure and CRC, and that it was encoded from this recording,
        # before anything is written: a damaged or foreign stream file is refused here, not
        # half-way through the play. Before its length: a stream that lacks its first frame
        # was told to give a shorter --seconds, which then did not leave enough frames.
        try:
            check_stream_of(packets, stream.fps, rec, src.name)
            mbps, bitrate = stream_stats(packets, rec.fs).mbps_total(), None
        except StreamError as e:  # a packet's message names its frame, not the file
            raise StreamError(f"{src}: {e}") from None
        if len(packets) < n_server:
            # The client would extrapolate the rest from the last frame, scored as if the
            # stream had covered it.
            raise InvalidInputError(
                f"{src}: the stream has {len(packets)} server frames, "
                f"{seconds:g} s of the recording need {n_server}; give --seconds "
                f"{(len(packets) - 1) / rec.fs:g} or less")
        server, sizes = DecodedStream(packets), [len(p) for p in packets]
    else:
        frames = rec.server_frames[:n_server]
        if args.bitrate is not None:
            stages.stage(f"encoding at {args.bitrate:g} Mb/s (decoded as the client plays)")
            packets, mbps = encode_packets(
                frames, CodecConfig(bitrate_mbps=args.bitrate), rec.fs, stages.bar,
                len(frames))
            server, sizes = DecodedStream(packets), [len(p) for p in packets]
        else:
            stages.stage("uncompressed server frames")
            server, sizes, mbps = frames, None, raw_mbps(rec)
        bitrate = args.bitrate
    metrics = metric_names(not args.no_vmaf, w, h, note=False)
    network = network_model(args, rec.fc)
    names = ("left", "right") if args.stereo else ("",)
    videos: list[_Video] = []
    video_files = [f"client_{name}.mp4" if name else "client.mp4" for name in names]
    # Each video is finished and renamed into place if the play completes, and dropped if it
    # raises (_Video.__exit__): a failed play leaves no shorter video that plays.
    with ExitStack() as stack:
        if args.video:
            for file in video_files:
                videos.append(stack.enter_context(
                    _Video(stage / file, w + (w & 1), h + (h & 1), 30.0)))
        else:
            for name in names:
                (stage / "frames" / name).mkdir(parents=True, exist_ok=True)

        def on_frame(eye: int, n: int, image: npt.NDArray[np.uint8], info: Any) -> None:
            if videos:
                pad = np.zeros((h + (h & 1), w + (w & 1), 3), np.uint8)
                pad[:h, :w] = image
                videos[eye].write(pad)
            else:
                write_png(stage / "frames" / names[eye] / f"{n:04d}.png", image)

        stages.stage(f"{args.method}: playing {n_client} client frames"
                     f"{' per eye' if args.stereo else ''} (l = {args.delay}), "
                     f"then {', '.join(metrics)}")
        scored = play_and_score_eyes(
            server, cams, truth, args.method, network, rec.fc, metrics,
            frame_sizes=sizes, bar=stages.bar, on_frame=on_frame, backend=args.backend,
            options=ReprojectOptions(server_fps=rec.fs, shadow_subframes=rec.subframes),
            keep_images=False)  # each frame is written out by on_frame
    playback = scored[0].playback
    modes = playback.summary()
    row = {"method": args.method, **mean_row(scored), "mbps": mbps}
    numbers = ("ssim", "flip", "psnr", "vmaf")
    data = {
        "source": str(src), "recording": str(rec_path), "method": args.method,
        "delay": args.delay, "network": network_json(network), "bitrate_mbps": bitrate,
        "width": w, "height": h, "stereo": args.stereo,
        "client_frames": n_client, "server_frames": len(server), "modes": modes,
        "mode_per_frame": playback.modes(), "arrivals": playback.arrivals,
        **{k: _json_number(row[k]) for k in (*numbers, "mbps")},
        "frames": row["frames"],
    }
    if args.stereo:
        data["eyes"] = [{"eye": name, **{k: _json_number(s.row()[k]) for k in numbers}}
                        for name, s in zip(names, scored)]
    write_atomic(stage / "play.json", json.dumps(data, indent=1) + "\n")
    if args.video:
        where = ", ".join(video_files)
    else:
        where = f"frames/ ({n_client * eyes} PNGs)"
    lines = [f"wrote {args.out}/: {where}, play.json",
             "modes: " + ", ".join(f"{m} {c}" for m, c in modes.items())]
    if args.stereo:
        rows = [{"method": f"{args.method} ({name})", **s.row(), "mbps": mbps}
                for name, s in zip(names, scored)]
        lines.append(format_table([*rows, {**row, "method": f"{args.method} (mean)"}]))
    else:
        lines.append(format_table([row]))
    return "\n".join(lines)
