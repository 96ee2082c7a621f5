"""``splitrender demo``, ``eval`` and ``bench``: the whole pipeline with metrics, the paper's experiments, and the timings."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from splitrender.cli.args import (
    add_always_interpolate,
    add_backend,
    add_max_divisor,
    add_network,
    add_no_vmaf,
    add_out,
    add_quiet,
    add_samples,
    add_scale,
    add_scene,
    add_trace,
    bitrate,
    bitrates,
    command,
    count,
    delays,
    eval_methods,
    fail,
    in_path,
    integer,
    methods,
    names,
    network_model,
    out_file,
    prepare_threads,
    rate,
    seconds,
    video_fps,
)
from splitrender.client.realtime import (
    DISPLAY_FPS,
    DISPLAY_PRIORITIES,
    MAX_DIVISOR,
    PREPARE_THREADS,
    WORKER_PRIORITIES,
)
from splitrender.errors import InvalidInputError, SplitRenderError
from splitrender.evaluation.shown import SCORED, SCORED_RUN
from splitrender.files import check_apart, check_output_file, write_atomic
from splitrender.progress import Progress
from splitrender.reproject import METHODS


def add_demo(sub: Any) -> None:
    from splitrender.evaluation.demo import DEFAULT_METHODS

    de = command(sub, "demo", demo)
    add_scene(de)
    add_out(de, "output directory, created if missing; its outputs are replaced when the run "
            "completes (default: %(default)s)", default=Path("splitrender-demo"))
    add_scale(de, 0.1)
    de.add_argument(
        "--seconds", type=seconds, default=1.0, metavar="S",
        help="length, at least 0.21 s (25 client frames) and at most the scene's 4 s "
        "(default: %(default)s)",
    )
    de.add_argument(
        "--bitrate", type=bitrate, default=None, metavar="MBPS",
        help="target bitrate of the whole stream in Mb/s (default: the paper's 40 Mb/s at "
        "2560x1440 scaled by pixel count, at least 1.6: headers and lossless parts cost a "
        "fixed ~0.15 Mb/s at 256x144)",
    )
    de.add_argument(
        "--methods", type=methods, default=DEFAULT_METHODS, metavar="LIST",
        help=f"comma-separated methods (default: {','.join(DEFAULT_METHODS)})",
    )
    de.add_argument("--stereo", action="store_true",
                    help="render two eyes (IPD 7 cm) and score both (as eval's Table 3)")
    de.add_argument(
        "--video-fps", type=video_fps, default=30.0, metavar="FPS",
        help="frame rate of video.mp4; every client frame is one video frame, so 30 plays the "
        "120 FPS session 4x slowed down (default: %(default)s)",
    )
    add_backend(de, "ours, ours_extrapolate and forward_splat; the other methods stay on the CPU")
    add_no_vmaf(de, "skip VMAF (its column shows '-')")
    add_quiet(de)
    add_network(de)


def demo(args: argparse.Namespace) -> int:
    from splitrender.evaluation.demo import DemoArgumentError, DemoConfig, format_table, run_demo

    cfg = DemoConfig(
        scene=args.scene,
        out=args.out,
        scale=args.scale,
        seconds=args.seconds,
        bitrate_mbps=args.bitrate,
        methods=tuple(args.methods),
        vmaf=not args.no_vmaf,
        delay_frames=args.delay,
        network=network_model(args),
        stereo=args.stereo,
        video_fps=args.video_fps,
        progress=not args.quiet,
        backend=args.backend,
    )
    try:
        res = run_demo(cfg)
    except DemoArgumentError as e:
        return fail(str(e))
    print(
        f"{cfg.scene} (dynamic) at {res.width}x{res.height}, {res.client_frames} client frames "
        f"from {res.server_frames} server frames at {res.mbps:.3f} Mb/s "
        f"(target {res.bitrate_mbps:.3g}); done in {res.seconds:.1f} s"
    )
    print(f"wrote {cfg.out}/: video.mp4, stills/ ({sum(p.suffix == '.png' for p in res.files)} "
          "PNGs), summary.md, summary.json")
    print(format_table(res.rows))
    return 0


def add_eval(sub: Any) -> None:
    from splitrender.evaluation.experiments import (
        DEFAULT_DELAYS,
        DEFAULT_EVAL_METHODS,
        DEFAULT_SCENES,
        EvalConfig,
    )

    ev = command(sub, "eval", eval_)
    add_out(ev)
    ev.add_argument("--dataset", type=in_path, default=None, metavar="DIR",
                    help="evaluate a dataset in the authors' layout instead of the built-in "
                    "scenes (Table 1 only; not with --scenes, --variants, --delays, --bitrate, "
                    "--bitrates, --rd-scenes, --stereo, --scale, --seconds, --trace, --samples)")
    ev.add_argument("--scenes", type=names, default=None, metavar="LIST",
                    help=f"comma-separated scenes (default: {','.join(DEFAULT_SCENES)})")
    ev.add_argument("--methods", type=eval_methods, default=DEFAULT_EVAL_METHODS,
                    metavar="LIST",
                    help=f"Table 1/3 and Figure 6 methods (default: "
                    f"{','.join(DEFAULT_EVAL_METHODS)})")
    ev.add_argument("--delays", type=delays, default=None, metavar="LIST",
                    help=f"Table 2 delays l (default: {','.join(map(str, DEFAULT_DELAYS))})")
    ev.add_argument("--bitrate", type=bitrate, default=None, metavar="MBPS",
                    help="bitrate of the compressed experiments (default: the paper's 40 Mb/s "
                    "scaled by pixel count)")
    add_scale(ev, None, f"{EvalConfig.scale}")
    ev.add_argument("--seconds", type=seconds, default=None, metavar="S",
                    help=f"length per scene (default: {EvalConfig.seconds})")
    ev.add_argument("--bitrates", type=bitrates, default=(), metavar="LIST",
                    help="also Figure 6 (rate-distortion) at these paper-equivalent Mb/s (at "
                    "2560x1440, scaled by pixel count), e.g. 10,20,40,60,100; plus the 'video "
                    "streaming' and timewarp references; writes OUT/rate_distortion.png")
    ev.add_argument("--variants", type=names, default=None, metavar="LIST",
                    help="Table 1's scene variants (default: static,dynamic; Tables 2-3 and "
                    "Figure 6 use dynamic)")
    ev.add_argument("--rd-scenes", type=names, default=None, metavar="LIST",
                    help="Figure 6 on these of the --scenes only (default: all --scenes)")
    ev.add_argument("--stereo", action="store_true", help="also Table 3 (mono vs stereo)")
    add_trace(ev)
    add_samples(ev, " (every render: recordings and the timewarp lines)")
    add_backend(ev, "ours, ours_extrapolate and forward_splat; the other methods stay on the CPU")
    add_no_vmaf(ev)
    ev.add_argument("--flip-every", type=_flip_every, default=1, metavar="N",
                    help="FLIP on every N-th scored client frame only (the first, then every "
                    "N-th), the other metrics on every frame: FLIP costs ~2 s of CPU per "
                    "1280x720 frame, most of the scoring time at that size. Take N coprime with "
                    "the 12 client frames per server frame (e.g. 5 or 7) so that every phase "
                    "of a pair is sampled (default: %(default)s, every frame)")
    add_quiet(ev)
    add_network(ev, delay=False)
    sw = ev.add_argument_group("sweep (docs/sweeps.md)")
    sw.add_argument("--executor", choices=("local", "ray"), default="local",
                    help="local: worker processes of this machine (no Ray needed); ray: Ray "
                    "tasks on a local Ray started for the run or on the cluster at --address "
                    "(pip install 'splitrender[ray]') (default: %(default)s)")
    sw.add_argument("--jobs", type=_jobs, default=None, metavar="N",
                    help="local: worker processes (default 1: the renderer and the reprojection "
                    "kernels already use every core, and each worker holds a recording's frames "
                    "in memory); ray without --address: CPUs of the local Ray, one task per CPU "
                    "(default: every CPU)")
    sw.add_argument("--address", default=None, metavar="ADDR",
                    help="with --executor ray: join this running cluster (HOST:PORT, "
                    "ray://HOST:PORT or auto) instead of starting a local Ray")
    sw.add_argument("--cache", type=in_path, default=None, metavar="DIR",
                    help="content-addressed cache of recordings, streams and score rows, "
                    "reused by later runs and by a resumed one (a shared path on a cluster; "
                    "default: $SPLITRENDER_CACHE, else $XDG_CACHE_HOME/splitrender, else "
                    "~/.cache/splitrender)")


def _jobs(text: str) -> int:
    """``--jobs``: worker processes or Ray CPUs, 1..1024."""
    return integer(text, 1, 1024, "a number of jobs")


def _flip_every(text: str) -> int:
    """``--flip-every``: 1..1000."""
    return integer(text, 1, 1000, "a frame stride")


def eval_(args: argparse.Namespace) -> int:
    from splitrender.evaluation.experiments import EvalArgumentError, EvalConfig, run_eval
    from splitrender.evaluation.sweep import (
        ClusterUnreachableError,
        RayMissingError,
        default_cache_dir,
    )
    from splitrender.scene.dataset import import_dataset_as_recording

    d = EvalConfig()
    recording: Path | None = None
    scenes = d.scenes if args.scenes is None else args.scenes
    # The results, the imported recording and the cache's entries written into the dataset or
    # over the trace would mix into (or replace) what is being read.
    inputs = {k: v for k, v in (("dataset", args.dataset), ("trace", args.trace))
              if v is not None and v.exists()}
    for flag, path in (("--out", args.out), ("--cache", args.cache)):
        if path is not None:
            try:
                check_apart(path, inputs)
            except InvalidInputError as e:
                return fail(f"{flag} {e}")
    if args.dataset is not None:
        for flag, value in (("--scenes", args.scenes), ("--variants", args.variants),
                            ("--delays", args.delays), ("--bitrate", args.bitrate),
                            ("--bitrates", args.bitrates or None),
                            ("--rd-scenes", args.rd_scenes), ("--stereo", args.stereo or None),
                            ("--scale", args.scale), ("--seconds", args.seconds),
                            ("--trace", args.trace), ("--samples", args.samples)):
            if value is not None:
                return fail(f"{flag}: not with --dataset (Table 1 only, on the dataset's own "
                            "size, rates and length)")
        scenes = (args.dataset.resolve().name,)
        recording = args.out / "recordings" / f"{scenes[0]}-dataset"
    cfg = EvalConfig(
        out=args.out, scenes=tuple(scenes), methods=tuple(args.methods),
        delays=d.delays if args.delays is None else tuple(args.delays),
        scale=d.scale if args.scale is None else args.scale,
        seconds=d.seconds if args.seconds is None else args.seconds,
        bitrate_mbps=args.bitrate, bitrates=tuple(args.bitrates), stereo=args.stereo,
        vmaf=not args.no_vmaf, flip_every=args.flip_every,
        rd_scenes=None if args.rd_scenes is None else tuple(args.rd_scenes),
        variants=d.variants if args.variants is None else tuple(args.variants),
        trace=args.trace, trace_scale=args.trace_scale, progress=not args.quiet,
        backend=args.backend, samples=args.samples, network=network_model(args),
        recording=recording, executor=args.executor, jobs=args.jobs, address=args.address,
        cache=args.cache,
    )
    if recording is not None:
        try:
            import_dataset_as_recording(args.dataset, recording, overwrite=True,
                                        stages=Progress(2, not args.quiet))
        except SplitRenderError as e:
            return fail(str(e))
    try:
        res = run_eval(cfg)
    except (EvalArgumentError, RayMissingError, ClusterUnreachableError) as e:
        return fail(str(e))
    for line in res.summary:
        print(line)
    if res.stats is not None:
        s = res.stats
        print(f"{sum(s.total.values())} tasks ({sum(s.cached.values())} from the cache "
              f"{cfg.cache or default_cache_dir()}, {sum(s.computed.values())} run) in "
              f"{s.seconds:.1f} s on the {cfg.executor} executor")
    print(f"{len(res.rows)} rows at {res.width}x{res.height}; wrote "
          + ", ".join(str(p) for p in res.files))
    return 0


def add_bench(sub: Any) -> None:
    be = command(sub, "bench", bench)
    add_scene(be)
    be.add_argument(
        "--methods", type=methods, default=None, metavar="LIST",
        help=f"comma-separated methods (default: all: {','.join(METHODS)}; with --realtime "
        "one method, default ours)",
    )
    add_scale(be, None, "0.5 = 1280x720; with --realtime 0.25 = 640x360")
    be.add_argument(
        "--frames", type=count, default=None, metavar="N",
        help="timed client frames per method (median) (default: 5; not with --realtime, which "
        "runs for --seconds)",
    )
    be.add_argument(
        "--realtime", action="store_true",
        help="run the real-time client loop at wall-clock --fps instead (decoding and pair "
        "preparation on a worker thread) and report frame times and deadline misses",
    )
    be.add_argument(
        "--seconds", type=seconds, default=None, metavar="S",
        help="with --realtime: seconds of display (default: 10)",
    )
    be.add_argument(
        "--fps", type=rate, default=None, metavar="FC",
        help=f"with --realtime: display frames per second, f_c (default: {DISPLAY_FPS:g}; a "
        "headset that cannot hold 120 runs at 90, 72 or 60)",
    )
    be.add_argument(
        "--exclusive", action="store_true",
        help="with --realtime: the display waits, off the clock, until the worker has decoded "
        "and prepared each arriving frame, so that the deadlines measure the display alone",
    )
    be.add_argument(
        "--worker-priority", choices=WORKER_PRIORITIES, default=None,
        help="with --realtime: how the decoding and preparing worker yields the cores to the "
        "display: idle (Linux SCHED_IDLE: only cores the display leaves idle), low (nice 10) "
        "or normal (default: idle)",
    )
    be.add_argument(
        "--display-priority", choices=DISPLAY_PRIORITIES, default=None,
        help="with --realtime: how the display's threads are scheduled while they show frames: "
        "realtime (Linux SCHED_RR, where permitted; else normal, and the report says why) or "
        "normal (default: realtime)",
    )
    be.add_argument(
        "--prepare-threads", type=prepare_threads, default=None, metavar="N",
        help="with --realtime: threads of the worker's pair preparation (CPU backend; they "
        f"run at the worker's priority; default: {PREPARE_THREADS})",
    )
    add_max_divisor(be, None, "with --realtime: ")
    add_always_interpolate(be, "with --realtime: ")
    be.add_argument(
        "--stereo", action="store_true",
        help="with --realtime: two eyes per display frame (IPD 7 cm), both rendered from the "
        "same server frames by the frame's deadline, as a headset shows them",
    )
    be.add_argument(
        "--stream", type=in_path, default=None, metavar="FILE",
        help="with --realtime: play this stream file instead of the built-in --scene",
    )
    be.add_argument(
        "--json", type=out_file, default=None, metavar="FILE",
        help="also write a JSON list of rows with the keys method, backend, width, height, "
        "ms_per_frame, ms_per_frame_max, ns_per_pixel, decode_ms_per_server_frame, "
        "copy_floor_ms, copy_threads, ratio_to_floor, processor, cpus, simd, host_steal_pct "
        "(with --realtime: one object with at least method, source, width, height, frames, "
        "deadline_misses, frame_ms_p50, frame_ms_p99, decode_ms_per_server_frame, "
        "host_steal_pct)",
    )
    be.add_argument(
        "--plot", type=out_file, default=None, metavar="FILE",
        help="with --realtime: also draw the run as a PNG: each display frame's time from its "
        "refresh to done, by mode, against the refresh period, the deadline misses, and the age "
        "of the newest server frame",
    )
    be.add_argument(
        "--score", type=count, nargs="?", const=SCORED, default=None, metavar="N",
        help="with --realtime on a built-in --scene: afterwards, score what the display showed "
        f"at N refreshes (default N: {SCORED}; in runs of {SCORED_RUN} consecutive ones spread "
        "over the run, as VMAF's motion feature needs) against the ground truth at their poses "
        "(ssim, flip, psnr, vmaf), by the mode of the frame shown and its age: a missed "
        "deadline counts as the older image left up",
    )
    add_no_vmaf(be, "with --score: skip VMAF")
    add_backend(
        be, "ours, ours_extrapolate and forward_splat only; with --realtime the display renders "
        "on the GPU and the worker uploads each pair there",
    )
    add_quiet(be)


def bench(args: argparse.Namespace) -> int:
    import json

    from splitrender.evaluation.bench import BenchArgumentError, format_rows, run_bench

    if args.realtime:
        return _bench_realtime(args)
    # Each option of the other mode is refused, not ignored: `bench --seconds 2` timed five
    # frames per method and said nothing.
    for flag, given in (
        ("--seconds", args.seconds is not None),
        ("--stream", args.stream is not None),
        ("--fps", args.fps is not None),
        ("--exclusive", args.exclusive),
        ("--worker-priority", args.worker_priority is not None),
        ("--display-priority", args.display_priority is not None),
        ("--max-divisor", args.max_divisor is not None),
        ("--always-interpolate", args.always_interpolate),
        ("--prepare-threads", args.prepare_threads is not None),
        ("--plot", args.plot is not None),
        ("--stereo", args.stereo),
        ("--score", args.score is not None),
        ("--no-vmaf", args.no_vmaf),
    ):
        if given:
            return fail(f"{flag} goes with --realtime")
    if args.json is not None:
        try:
            check_output_file(args.json)
        except InvalidInputError as e:
            return fail(f"--json: {e}")
    try:
        rows = run_bench(
            args.scene, tuple(args.methods or METHODS),
            0.5 if args.scale is None else args.scale, 5 if args.frames is None else args.frames,
            progress=not args.quiet, backend=args.backend,
        )
    except BenchArgumentError as e:
        return fail(str(e))
    print(format_rows(rows))
    if args.json is not None:
        write_atomic(args.json, json.dumps([r.to_json() for r in rows], indent=1) + "\n")
        print(f"wrote {args.json}")
    return 0


def _bench_realtime(args: argparse.Namespace) -> int:
    from splitrender.errors import StreamError
    from splitrender.evaluation.bench_realtime import (
        format_realtime,
        run_realtime_bench,
        write_realtime_json,
        write_realtime_plot,
    )

    if args.frames is not None:
        return fail("--frames: not with --realtime, which runs for --seconds")
    chosen = args.methods or ("ours",)
    if len(chosen) != 1:
        return fail(f"--methods: --realtime runs one method, got {len(chosen)}")
    # The outputs are checked before the run, which takes --seconds and more: a result that
    # cannot be written would be lost.
    outputs = {k: v for k, v in (("--json", args.json), ("--plot", args.plot)) if v is not None}
    for flag, path in outputs.items():
        try:
            check_output_file(path)
        except InvalidInputError as e:
            return fail(f"{flag}: {e}")
        try:
            check_apart(path, {} if args.stream is None else {"stream": args.stream})
        except InvalidInputError as e:
            return fail(f"{flag} {e}")
    if len(outputs) == 2 and args.json.resolve() == args.plot.resolve():
        return fail(f"--plot: {args.plot} is the --json file too; expected another file")
    if args.no_vmaf and args.score is None:
        return fail("--no-vmaf goes with --score")
    try:
        result = run_realtime_bench(
            args.scene, 0.25 if args.scale is None else args.scale,
            10.0 if args.seconds is None else args.seconds, chosen[0],
            stream=args.stream, display_fps=DISPLAY_FPS if args.fps is None else args.fps,
            progress=not args.quiet, exclusive=args.exclusive,
            worker_priority=args.worker_priority or "idle",
            display_priority=args.display_priority or "realtime", backend=args.backend,
            max_divisor=MAX_DIVISOR if args.max_divisor is None else args.max_divisor,
            prepare_threads=args.prepare_threads, stereo=args.stereo,
            defer_interpolation=not args.always_interpolate, score=args.score or 0,
            no_vmaf=args.no_vmaf,
        )
    except (InvalidInputError, StreamError) as e:
        return fail(str(e))
    print(format_realtime(result))
    if args.json is not None:
        write_realtime_json(args.json, result)
        print(f"wrote {args.json}")
    if args.plot is not None:
        write_realtime_plot(args.plot, result)
        print(f"wrote {args.plot}")
    return 0
