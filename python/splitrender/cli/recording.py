"""``splitrender render`` and ``encode``: recordings of the reference renderer, and their encoding into stream files."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING, Any

from splitrender.cli.args import (
    add_out,
    add_quiet,
    add_samples,
    add_scale,
    add_trace,
    bitrate,
    command,
    in_path,
    open_scene,
    scene_description,
    seconds,
    run_stages,
    wrote_dir,
)

if TYPE_CHECKING:
    from splitrender.codec.stream import StreamStats
    from splitrender.progress import Progress


def add_render(sub: Any) -> None:
    re = command(sub, "render", render)
    re.add_argument(
        "scene",
        metavar="SCENE",
        help="built-in scene (courtyard, colonnade, lab), or a JSON scene description (*.json) that "
        "places glTF models into one; see splitrender.scene.builtin.Scene.from_description",
    )
    add_out(re, "recording directory")
    re.add_argument(
        "--variant",
        choices=("static", "dynamic"),
        default=None,
        help="still or animated objects and light (default: dynamic); a built-in scene's only: "
        'a scene description names its own ("variant")',
    )
    re.add_argument(
        "--seconds",
        type=seconds,
        default=2.0,
        metavar="S",
        help="length to record, at most the scene's 4 s (default: %(default)s)",
    )
    add_scale(re, 0.125)
    add_trace(re, " (60 Hz)")
    re.add_argument("--stereo", action="store_true", help="two eyes (IPD 7 cm) per client frame")
    add_samples(re)
    re.add_argument("--force", action="store_true", help="replace DIR if it exists")
    add_quiet(re, "no progress bar")


def render(args: argparse.Namespace) -> int:
    # Imported here: the renderer is not needed by the other commands.
    from splitrender.scene.recording import plan, write_recording
    from splitrender.scene.builtin import load_trace
    from splitrender.files import check_apart

    def work(bar: Progress) -> Path:
        # With --force the old DIR is removed once the new recording is in place: it must not
        # hold the scene description or the trace (nor be one of them).
        inputs: dict[str, str | Path] = {} if args.trace is None else {"trace": args.trace}
        desc = scene_description(args.scene)
        if desc is not None:
            inputs["scene description"] = desc
        check_apart(args.out, inputs, replaced=args.force)
        scene = open_scene(args.scene, variant=args.variant)
        # And the description's glTF models (not their buffers or textures): a recording folder
        # holding one lost it to --force once the new recording was in place.
        for model in scene.models:
            check_apart(args.out, {"glTF model": model.path}, replaced=args.force)
        trace = None if args.trace is None else load_trace(args.trace)
        n_server, n_client = plan(args.seconds, 10.0, 120.0)
        w, h = scene.main_size(args.scale)
        bar.stage(
            f"rendering {scene.name} ({scene.variant}) at {w}x{h}: {n_server} server frames, "
            f"{n_client} client frames{' (stereo)' if args.stereo else ''}"
        )
        return write_recording(
            args.out,
            scene,
            seconds=args.seconds,
            scale=args.scale,
            stereo=args.stereo,
            trace=trace,
            translation_scale=args.trace_scale,
            samples=args.samples,
            overwrite=args.force,
            progress=lambda done, total: bar.bar(done, total, "frames"),
        )

    return run_stages(1, args.quiet, work, wrote_dir)


def add_encode(sub: Any) -> None:
    en = command(sub, "encode", encode)
    en.add_argument("recording", metavar="REC", type=in_path, help="recording directory")
    add_out(en, "stream file to write", "FILE")
    en.add_argument(
        "--bitrate",
        type=bitrate,
        metavar="MBPS",
        help="total target in Mb/s (default: the paper's 40 Mb/s at 2560x1440 scaled to the "
        "recording's main camera by pixel count)",
    )
    add_quiet(en, "no progress bar")


def encode(args: argparse.Namespace) -> int:
    from splitrender.codec.encode import encode_recording

    def work(bar: Progress) -> StreamStats:
        def progress(done: int, total: int) -> None:
            # The stage line once the recording has been read: a bad REC gives only the error
            # line.
            if bar.step == 0:
                bar.stage(f"encoding {total} server frames of {args.recording} into {args.out}")
            bar.bar(done, total, "server frames")

        return encode_recording(
            args.recording, args.out, bitrate_mbps=args.bitrate, progress=progress
        )

    def report(stats: StreamStats, seconds: float) -> None:
        print(f"wrote {args.out} ({stats.frames} server frames) in {seconds:.1f} s")
        print(f"  {'buffer':<28} {'Mb/s':>8}")
        for name, mbps in sorted(stats.mbps_by_buffer().items()):
            print(f"  {name:<28} {mbps:8.3f}")
        for name, mbps in sorted(stats.mbps_by_camera().items()):
            print(f"  {'camera ' + name:<28} {mbps:8.3f}")
        print(f"  {'total':<28} {stats.mbps_total():8.3f}")

    return run_stages(1, args.quiet, work, report)


