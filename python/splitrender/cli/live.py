"""``splitrender serve``, ``splitrender connect`` and ``splitrender relay``: live split rendering
over QUIC (docs/protocol.md, docs/live.md)."""

from __future__ import annotations

import argparse
import asyncio
import json
import math
import secrets
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from splitrender.cli.args import (
    MAX_SECONDS,
    add_always_interpolate,
    add_backend,
    add_max_divisor,
    add_no_vmaf,
    add_out,
    add_quiet,
    add_scale,
    add_trace,
    command,
    fail,
    in_path,
    integer,
    loss,
    milliseconds,
    bitrate,
    open_scene,
    seconds,
)
from splitrender.client.realtime import DISPLAY_FPS, MAX_DIVISOR
from splitrender.errors import SplitRenderError
from splitrender.files import OutputFolder, write_atomic
from splitrender.gpu import GPU_METHODS
from splitrender.gpu import require as require_backend
from splitrender.machine import steal_note, this_machine
from splitrender.reproject import METHODS
from splitrender.net.protocol import (
    MAX_FPS,
    MAX_TOKEN,
    MIN_DISPLAY_FPS,
    MIN_SERVER_FPS,
    Welcome,
    normalise_fingerprint,
)
from splitrender.types import MAX_SPAN, MAX_THREADS

if TYPE_CHECKING:  # imported where used (it loads the native module)
    from splitrender.scene.builtin import Scene

__all__ = ["add_connect", "add_relay", "add_serve"]


def _address(text: str, lowest: int = 1) -> tuple[str, int]:
    """``HOST:PORT``; port 0 (``lowest`` 0) only where it means "any free port" (a listening
    address): a peer's port 0 passed the parser and failed later as the API's ``port``."""
    host, sep, port = text.rpartition(":")
    if not sep or not host:
        raise argparse.ArgumentTypeError(f"expected HOST:PORT, got {text!r}")
    return host.strip("[]"), integer(port, lowest, 65535, "a port")


def _listen_address(text: str) -> tuple[str, int]:
    return _address(text, 0)


def _port(text: str) -> int:
    return integer(text, 0, 65535, "a port")


def _fps(text: str, lowest: float, why: str = "") -> float:
    """A rate in FPS in ``lowest``..:data:`MAX_FPS`, the protocol's range, checked by the
    parser (it checked the codec's, from 0.001, and the command then refused what was below
    the protocol's with another minimum)."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of FPS, got {text!r}") from None
    if not (math.isfinite(v) and lowest <= v <= MAX_FPS):
        raise argparse.ArgumentTypeError(
            f"expected at least {lowest:g} FPS{why} and at most {MAX_FPS:g}, got {text}")
    return v


def _server_fps(text: str) -> float:
    return _fps(text, MIN_SERVER_FPS, " (the least a client accepts)")


def _display_fps(text: str) -> float:
    return _fps(text, MIN_DISPLAY_FPS)


def _fingerprint(text: str) -> str:
    """64 hex digits (colons and case ignored), checked when parsed, so that the error names
    --fingerprint (ConnectOptions names its field, ``fingerprint``)."""
    try:
        return normalise_fingerprint(text)
    except SplitRenderError as e:
        raise argparse.ArgumentTypeError(str(e).removeprefix("fingerprint: ")) from None


def _new_token() -> str:
    """A random session token of 128 bits, in hex: never starts with '-', which argparse
    takes for an option (``connect --token -Ab..`` said "expected one argument" for the ~1.5 %
    of ``token_urlsafe`` tokens that did), and needs no quoting in a shell."""
    return secrets.token_hex(16)


def _step(text: str) -> tuple[float, float]:
    from splitrender.codec.coder import MAX_BITRATE_MBPS

    t, sep, mbps = text.partition(":")
    try:
        v = (float(t), float(mbps))
    except ValueError:
        v = (math.nan, math.nan)
    if not sep or not all(math.isfinite(x) and x >= 0 for x in v) or (
        v[0] > MAX_SECONDS or v[1] > MAX_BITRATE_MBPS
    ):
        raise argparse.ArgumentTypeError(
            f"expected SECONDS:MBPS (SECONDS in 0..{MAX_SECONDS:g}, MBPS in "
            f"0..{MAX_BITRATE_MBPS:g}), got {text!r}"
        )
    return v


# -- serve ---------------------------------------------------------------------------------------


def add_serve(sub: Any) -> None:
    from splitrender.net.predict import PREDICTORS

    p = command(sub, "serve", run_serve)
    p.add_argument("--host", default="127.0.0.1",
                   help="address to listen on (default: %(default)s)")
    p.add_argument("--port", type=_port, default=4433, help="UDP port (default: %(default)s)")
    p.add_argument("--scene", default="courtyard", metavar="SCENE",
                   help="built-in scene (courtyard, colonnade, lab) or a JSON scene description "
                   "(default: %(default)s)")
    add_scale(p, 0.0625)
    p.add_argument("--fps", type=_server_fps, default=10.0, metavar="FS",
                   help="server frames per second, f_s (default: %(default)s); a server that "
                   "cannot keep it renders every m-th frame (see --max-span)")
    p.add_argument("--max-span", type=lambda t: integer(t, 1, MAX_SPAN), default=MAX_SPAN,
                   metavar="M", help="when rendering cannot keep --fps, render every m-th frame "
                   "(m <= M, f_s / m FPS, motion spanning m periods) so that the client still "
                   "gets pairs to interpolate; 1: keep --fps and skip the frames that would "
                   "be late instead (default: %(default)s)")
    p.add_argument("--bitrate", type=bitrate, default=None, metavar="MBPS",
                   help="encoder target at the start and its ceiling (default: the paper's "
                   "40 Mb/s scaled by pixel count)")
    p.add_argument("--min-bitrate", type=bitrate, default=None, metavar="MBPS",
                   help="floor of the adaptive target (default: a quarter of --bitrate)")
    p.add_argument("--gop", type=lambda t: integer(t, 1, 1000), default=None, metavar="N",
                   help="key frame every N server frames (default: one per 10 s: the client asks "
                   "for one when it needs it, and each regular key frame restarts the encoders' "
                   "rate control, which is slow)")
    p.add_argument("--encoder-threads", type=lambda t: integer(t, 0, MAX_THREADS), default=1,
                   metavar="N", help="threads that encode a frame's three HEVC pictures side by "
                   "side; 0: one per core (default: 1, which leaves the other cores to a client "
                   "on the same machine; on a server of its own, 0 or 3 cut the encode time)")
    p.add_argument("--token", default=None,
                   help="session token the client must send (default: a random one, printed)")
    p.add_argument("--cert", type=in_path, default=None, metavar="PEM",
                   help="certificate (PEM); with --key. Default: a new self-signed one")
    p.add_argument("--key", type=in_path, default=None, metavar="PEM", help="private key (PEM)")
    p.add_argument("--predictor", choices=PREDICTORS, default="constant-velocity",
                   help="head-pose predictor (default: %(default)s)")
    p.add_argument("--sessions", type=lambda t: integer(t, 0, 1000000), default=0, metavar="N",
                   help="exit after N sessions (default: 0, serve until interrupted)")
    p.add_argument("--retry", action="store_true",
                   help="validate each client's address with a QUIC Retry before keeping any "
                   "state for it (a round trip more to connect; for a server others can reach)")
    p.add_argument("--drop-every", type=lambda t: integer(t, 0, 1000000), default=0,
                   metavar="N", help="fault injection: do not send every N-th frame that is "
                   "not a key frame, as if lost (the client asks for a key frame) (default: 0)")


def _quiet_quic() -> None:
    """aioquic logs a peer's protocol violations ("Error: 5, reason: Wrong stream initiator")
    on its logger "quic"; with no handler anywhere Python prints them to stderr, one line per
    connection a peer chooses, beside the command's own lines. The commands say what ended a
    session themselves; a program that configures logging still gets aioquic's records."""
    import logging

    quic = logging.getLogger("quic")
    if not any(isinstance(h, logging.NullHandler) for h in quic.handlers):  # once a process
        quic.addHandler(logging.NullHandler())


def run_serve(args: argparse.Namespace) -> int:
    from splitrender.net.server import (
        LiveServer,
        ServerOptions,
        check_scale,
        load_certificate_chain,
    )

    _quiet_quic()
    if (args.cert is None) != (args.key is None):
        return fail("--cert and --key go together")
    if args.bitrate is not None and args.min_bitrate is not None and (
        args.min_bitrate > args.bitrate
    ):
        return fail(f"--min-bitrate {args.min_bitrate:g} is above --bitrate {args.bitrate:g}")
    token = args.token if args.token is not None else _new_token()
    if len(token.encode()) > MAX_TOKEN:
        return fail(f"--token: at most {MAX_TOKEN} bytes")
    if not token:
        # A client that sends none (connect's default) would be let in.
        return fail("--token: expected a non-empty token (leave it out for a random one)")
    try:
        scene = open_scene(args.scene, "--scene: ")
        name = scene.name
        # Before anything is rendered (LiveServer renders two frames to start).
        check_scale(scene, args.scale, "--scale")
        cert = key = None
        chain: list[Any] = []
        if args.cert is not None:
            # The intermediates too: a client that verifies against the root CA needs them.
            cert, key, chain = load_certificate_chain(args.cert, args.key)
        gop = args.gop if args.gop is not None else max(1, round(10 * args.fps))
        server = LiveServer(
            ServerOptions(name, args.scale, args.fps, args.bitrate, args.min_bitrate, gop,
                          token, args.predictor, args.sessions,
                          encoder_threads=args.encoder_threads,
                          drop_every=args.drop_every, max_span=args.max_span,
                          retry=args.retry),
            scene=scene, certificate=cert, private_key=key, certificate_chain=chain,
        )
    except (SplitRenderError, ValueError, OSError) as e:
        return fail(str(e))

    def ready(s: LiveServer) -> None:
        w, h = s.size
        print(f"listening on {args.host}:{s.port}: {name} at {w}x{h} (scale {args.scale:g}), "
              f"{args.fps:g} FPS, {s.min_mbps():.3g}-{s.max_mbps():.3g} Mb/s, first frame "
              f"rendered + encoded in {s.proc_estimate * 1e3:.0f} ms", flush=True)
        print(f"fingerprint {s.fingerprint}", flush=True)
        print(f"scene digest {s.scene_digest.hex()}", flush=True)
        if args.token is None:
            print(f"token {token}", flush=True)

    try:
        asyncio.run(server.run(args.host, args.port, ready))
    except OSError as e:
        return fail(f"cannot listen on {args.host}:{args.port}: {e}")
    return 0


# -- connect -------------------------------------------------------------------------------------


def add_connect(sub: Any) -> None:
    p = command(sub, "connect", run_connect)
    p.add_argument("server", type=_address, metavar="HOST:PORT", help="the server to connect to")
    p.add_argument("--token", default="", help="the server's session token (one that starts "
                   "with '-': --token=-...)")
    p.add_argument("--fingerprint", type=_fingerprint, default=None, metavar="SHA256",
                   help="the server certificate's SHA-256 (hex, colons and case ignored), as "
                   "`splitrender serve` prints it; a mismatch is refused")
    p.add_argument("--insecure", action="store_true",
                   help="accept any certificate (no --fingerprint; for a trusted loopback only)")
    p.add_argument("--method", default="ours", choices=METHODS, metavar="M",
                   help=f"reprojection method: {', '.join(METHODS)} (default: %(default)s)")
    p.add_argument("--seconds", type=seconds, default=5.0, metavar="S",
                   help="session length (default: %(default)s)")
    p.add_argument("--fps", type=_display_fps, default=DISPLAY_FPS, metavar="FC",
                   help="display frames per second, f_c (default: %(default)s)")
    add_max_divisor(p, MAX_DIVISOR)
    add_always_interpolate(p)
    p.add_argument("--scene", default=None, metavar="SCENE",
                   help="the scene the server renders, for the poses and --score's ground "
                   "truth: the JSON scene description given to `serve --scene` (a copy "
                   "elsewhere will do), or a built-in scene; one whose scene digest is not "
                   "the one the server sends is refused (default: the built-in scene the "
                   "server names)")
    add_trace(p)
    add_out(p)
    p.add_argument("--score", action="store_true",
                   help="afterwards, render the ground truth at the poses the client had and "
                   "score the display frames (ssim, flip, psnr, vmaf) into report.json; "
                   "against a server of a scene description give it with --scene (refused "
                   "without)")
    p.add_argument("--compare", default=None, choices=METHODS, metavar="M",
                   help="with --score: afterwards, replay the packets this session decoded, "
                   "at the same arrival times and poses, through method M and score it too "
                   "(report.json's compare): the two methods in the same conditions")
    p.add_argument("--stereo", action="store_true",
                   help="two eyes per display frame (IPD 7 cm), both rendered by the frame's "
                   "deadline from the same server frames, as a headset shows them (the server "
                   "is sent the head's pose); the video shows them side by side, and --score "
                   "scores each eye against its own ground truth (the mean of the two, as "
                   "eval's Table 3)")
    add_backend(p, "ours, ours_extrapolate and forward_splat; the display renders on the GPU "
                "and the receiving worker uploads each pair there")
    add_no_vmaf(p)
    add_quiet(p)
    p.add_argument("--protocol-version", type=lambda t: integer(t, 0, 65535), default=None,
                   help=argparse.SUPPRESS)  # tests: a hello of another version, to be refused


def _even(img: npt.NDArray[np.uint8]) -> npt.NDArray[np.uint8]:
    h, w = img.shape[:2]
    return np.pad(img, ((0, h & 1), (0, w & 1), (0, 0)), mode="edge") if (h | w) & 1 else img


def run_connect(args: argparse.Namespace) -> int:
    from splitrender.client.live import ConnectOptions, LiveClient
    from splitrender.net.protocol import PROTOCOL_VERSION
    from splitrender.scene.builtin import SCENE_NAMES, Scene, TraceMotion, load_trace

    _quiet_quic()
    if args.compare is not None and not args.score:
        return fail("--compare: needs --score")
    if args.fingerprint is None and not args.insecure:
        return fail("--fingerprint: expected the server's certificate fingerprint (or --insecure)")
    if len(args.token.encode()) > MAX_TOKEN:
        return fail(f"--token: at most {MAX_TOKEN} bytes")
    if args.backend == "wgpu" and args.method not in GPU_METHODS:
        # Said here in the command's words (the API's check says backend='cpu').
        return fail(f"--method {args.method}: has no wgpu kernel (--backend wgpu runs "
                    f"{', '.join(GPU_METHODS)}); use --backend cpu for it")
    # The video and the report replace the previous run's together, the report last; an
    # interrupted score leaves the previous pair.
    outputs = OutputFolder(args.out, ("video.mp4", "report.json"))
    try:
        # Checked before the session: found after it, a file there lost the session's results.
        outputs.check()
    except SplitRenderError as e:
        return fail(f"--out {e}")
    try:
        trace = None if args.trace is None else load_trace(args.trace)
        # Before connecting: a description that does not load is named without a session.
        given = None if args.scene is None else open_scene(args.scene, "--scene: ")
        # Its models read for the digest before connecting too (the server ends a session
        # that sends no pose for 3 s).
        given_digest = None if given is None else given.digest()
        # Before connecting: a method without a GPU kernel, or no adapter, fails here.
        require_backend(args.backend, args.method)
    except SplitRenderError as e:
        return fail(str(e))
    host, port = args.server
    try:
        opts = ConnectOptions(
            host, port, args.token, args.fingerprint, args.method, args.fps, backend=args.backend,
            version=PROTOCOL_VERSION if args.protocol_version is None else args.protocol_version,
            max_divisor=args.max_divisor, keep_packets=args.compare is not None,
            defer_interpolation=not args.always_interpolate,
        )
    except SplitRenderError as e:
        return fail(str(e))
    client = LiveClient(opts)
    try:
        welcome = client.connect()
    except SplitRenderError as e:
        return fail(str(e))
    try:
        if welcome.scene not in SCENE_NAMES:
            client.close()
            return fail(f"the server renders {welcome.scene!r}, not a built-in scene: this "
                        "client cannot compute its poses in it")
        scene = given if given is not None else Scene(welcome.scene)
        problem = _scene_mismatch(
            welcome, scene, given_digest if given_digest is not None else scene.digest(),
            args.scene, args.score,
        )
        if problem is not None:
            # Scored against another scene, the session would compare two different scenes.
            client.close()
            return fail(problem)
        if trace is not None:
            motion = TraceMotion(scene, trace, args.trace_scale).client_pose
        else:
            motion = scene.client_pose
        if not args.quiet:
            print(f"connected to {host}:{port}: {welcome.scene} {welcome.width}x"
                  f"{welcome.height} at {welcome.server_fps:g} FPS; displaying {args.method} "
                  + ("(two eyes) " if args.stereo else "")
                  + f"at {args.fps:g} FPS for {args.seconds:g} s", file=sys.stderr, flush=True)
        frames: list[tuple[float, npt.NDArray[np.uint8]]] = []  # stereo: left | right
        eyes = 2 if args.stereo else 1
        first_shown: list[float] = []
        # The display frames are kept (for the video and the score, written afterwards so
        # that no display frame pays for encoding) within MAX_KEPT_BYTES: past it the video
        # shows every `stride`-th refresh only (its rate drops), and of the frames made for
        # the refreshes up to one it shows only the newest is kept, what the display showed
        # then, so a long session at a large scale cannot exhaust memory.
        stride = [1]
        kept: list[int] = []  # the refresh index of each frame in `frames`
        captions: list[str] = []  # and its caption in the video (_frame_caption)

        def slot(index: int) -> int:
            return -(-index // stride[0])  # the first video refresh that shows it

        def on_frame(shown: Any, rec: Any) -> None:
            if rec.mode != "hold" and not first_shown:
                first_shown.append(rec.time)
            if kept and slot(kept[-1]) == slot(rec.index):
                frames.pop()  # a newer frame for the same video refresh
                kept.pop()
                captions.pop()
            img = _kept_image(shown)
            frames.append((rec.time, img))
            kept.append(rec.index)
            captions.append(_frame_caption(args.method, rec))
            while len(frames) > 1 and len(frames) * img.nbytes > MAX_KEPT_BYTES:
                stride[0] *= 2
                last = [i for i in range(len(kept))
                        if i + 1 == len(kept) or slot(kept[i]) != slot(kept[i + 1])]
                frames[:] = [frames[i] for i in last]
                kept[:] = [kept[i] for i in last]
                captions[:] = [captions[i] for i in last]

        report = client.run(motion, args.seconds, on_frame=on_frame, stereo=args.stereo)
    except SplitRenderError as e:
        client.close()
        return fail(str(e))
    # What the poses and the ground truth came from: the server names only a built-in scene.
    report["scene"] = welcome.scene if args.scene is None else args.scene
    report["scene_digest"] = welcome.scene_digest.hex()  # what the server rendered
    # Where the display ran, as the benchmarks record it: its times depend on it.
    here = this_machine()
    report.update(processor=here.processor, cpus=here.cpus, simd=here.simd)
    out: Path = args.out
    with outputs as stage:
        _write_video(stage / "video.mp4", frames, args.fps, args.seconds, stride[0], captions,
                     eyes)
        if args.score:
            # Scored from the first frame made from a server frame on: before it every method
            # shows the same black start-up (no server frame yet); holds after it count.
            start = first_shown[0] if first_shown else math.inf
            picked = _pick([f for f in frames if f[0] >= start])
            if not args.quiet:
                print(f"scoring {sum(len(run) - 2 for run in picked)} display frames against "
                      "the ground truth rendered at the client's poses", file=sys.stderr,
                      flush=True)
            other: _Shown = []  # the compared method's display frames
            summary: dict[str, Any] = {}
            if args.compare is not None:
                summary = client.replay(
                    args.compare, motion, args.seconds, stereo=args.stereo,
                    on_frame=lambda shown, rec: other.append((rec.time, _kept_image(shown))))
            score, compared = _scores(
                scene, welcome.scale, args.fps, motion, picked,
                None if args.compare is None else other, args.no_vmaf, eyes,
            )
            report.update(score)
            if compared is not None:
                summary.update(compared)
                report["compare"] = {"method": args.compare, **summary}
        write_atomic(stage / "report.json", json.dumps(report, indent=1) + "\n")
    net = report["network"]
    p50 = report["pose_to_display_ms_p50"]  # None: no display frame showed a server frame
    print(f"{report['frames']} frames ({report['full_rate_pct']:.0f} % at the full rate), "
          f"{report['deadline_misses']} deadline misses, modes "
          f"{report['modes']}"
          + (f" ({report['interpolation_deferred']} extrapolated where interpolating would "
             "have missed)" if report.get("interpolation_deferred") else "")
          + f", {report['server_frames_received']} server frames "
          f"({net['frames_lost']} lost, {net['key_recoveries']} key-frame recoveries), "
          f"pose-to-display p50 {'n/a' if p50 is None else f'{p50:.0f} ms'}, "
          f"{report['mbps']:.3f} Mb/s; wrote {out}/: report.json, video.mp4")
    note = steal_note([report.get("host_steal_pct")], "the display ran")
    if note is not None:
        print(note)
    if report.get("gpu_lost") is not None:
        print(f"the GPU device was lost ({report['gpu_lost']}): the display went on on the CPU "
              "from then on")
    if args.score:
        print(_score_line(args.method, report, args.no_vmaf))
        if args.compare is not None:
            print(_score_line(f"{args.compare} (replayed)", report["compare"], args.no_vmaf))
    return 0


def _score_line(method: str, scores: dict[str, Any], no_vmaf: bool) -> str:
    """The printed scores of ``method`` (``scores``: what :func:`_score` put in the report)."""
    n = scores["scored_frames"]
    if n == 0:
        return f"{method}: no display frame showed a server frame: nothing scored"
    from splitrender.evaluation.shown import format_scores

    parts = [format_scores(scores)]
    if "vmaf" not in scores:
        from splitrender.evaluation.metrics import VMAF_MIN_SIDE

        parts.append("no VMAF (--no-vmaf)" if no_vmaf
                     else f"no VMAF (a side under {VMAF_MIN_SIDE} pixels)")
    return f"{method}: {', '.join(parts)} over {n} display frames"


def _scene_mismatch(
    welcome: Welcome, scene: Scene, digest: bytes, given: str | None, score: bool
) -> str | None:
    """Why ``connect`` must not go on with ``scene`` (``digest``: its :meth:`Scene.digest`;
    ``given``: ``--scene`` as given, ``None``: the built-in scene ``welcome`` names) against
    the server of ``welcome``; ``None`` when it may. A ``--scene`` is the user's word that it
    is the server's scene: refused when its digest differs. Without one, the built-in
    scene's head path gives the poses whatever the server renders, but scoring against it
    compares two scenes: ``--score`` is refused when the server renders something else (a
    scene description, another variant)."""
    if digest == welcome.scene_digest:
        return None
    server = (f"the server renders {welcome.scene!r} with scene digest "
              f"{welcome.scene_digest.hex()}")
    advice = "pass --scene the scene description the server was given"
    if given is not None:
        models = len(scene.models)
        return (f"--scene {given}: not the scene the server renders: {server}, this one "
                f"({scene.name}, {scene.variant}, {models} model{'s' * (models != 1)}) "
                f"{digest.hex()}; {advice}")
    if score:
        return (f"--score: {server}, not the built-in {welcome.scene!r} ({digest.hex()}), "
                f"whose ground truth would not be the session's; {advice}")
    return None


#: Highest frame rate of connect's video: what players and the H.264 writers take (as
#: ``video_fps`` says); a faster display's video shows every m-th refresh.
MAX_VIDEO_FPS = 240.0


def _video_timeline(
    times: list[float], fc: float, seconds: float, stride: int = 1
) -> tuple[list[int], float]:
    """The video of display frames shown at ``times`` (display seconds, in order, the first
    at 0) on a display refreshing at ``fc`` for ``seconds``: which frame each video frame
    shows (an index into ``times``) and the video's rate. A video frame per refresh, or per
    ``m``-th refresh where only every ``stride``-th was kept or ``fc`` is above
    :data:`MAX_VIDEO_FPS` (m a multiple of ``stride``), each showing the newest display frame
    made for that refresh or before: a frame shown at half rate, or repeated over the
    refreshes it overran, covers them all, as it did on the display. So the video lasts the
    session (one frame per display frame made it too short, and fast, where frames were
    shown at half rate or refreshes dropped)."""
    import bisect

    m = stride * max(1, math.ceil(fc / stride / MAX_VIDEO_FPS - 1e-9))
    refreshes = round(seconds * fc)
    shown = []
    for j in range(0, refreshes, m):
        # The newest frame made for refresh j or before (1e-9: the times are j / fc, rounded).
        shown.append(max(0, bisect.bisect_right(times, j / fc + 1e-9) - 1))
    return shown, fc / m


def _kept_image(shown: Any) -> npt.NDArray[np.uint8]:
    """A copy of what ``on_frame`` was given: the image, or a stereo frame's two eyes side by
    side (left | right)."""
    if isinstance(shown, tuple):
        return np.concatenate(shown, axis=1)
    return np.array(shown)


def _eye_images(img: npt.NDArray[np.uint8], eyes: int) -> list[npt.NDArray[np.uint8]]:
    """The ``eyes`` images of a kept frame (:func:`_kept_image`), left first."""
    if eyes == 1:
        return [img]
    w = img.shape[1] // eyes
    return [np.ascontiguousarray(img[:, e * w : (e + 1) * w]) for e in range(eyes)]


def _write_video(
    path: Path, frames: _Shown, fc: float, seconds: float, stride: int = 1,
    captions: Sequence[str] | None = None, eyes: int = 1,
) -> None:
    """The display ``frames`` ``(display time, image)`` as a video of the session's length
    (:func:`_video_timeline`), each under its caption where ``captions`` (one per frame) are
    given; a stereo session's (``eyes`` 2) shows the eyes side by side under one caption."""
    from splitrender.evaluation.demo import _Video
    from splitrender.imageio import montage

    if not frames:
        return
    shown, rate = _video_timeline([t for t, _ in frames], fc, seconds, stride)

    def picture(i: int) -> npt.NDArray[np.uint8]:
        tiles = _eye_images(frames[i][1], eyes)
        # A stereo frame's eyes side by side under one caption across both: at the small live
        # scales a caption cut at one eye's width kept little more than the method's name.
        img = tiles[0] if eyes == 1 else montage(tiles)
        if captions is None:
            return _even(img)
        label = captions[i] if eyes == 1 else f"{captions[i]}  (left | right eye)"
        return _even(montage([img], labels=[label]))

    first = picture(0)
    # _Video writes beside path and renames when complete: a reader never sees half a video.
    with _Video(path, first.shape[1], first.shape[0], rate) as video:
        last, img = -1, first
        for i in shown:
            if i != last:  # a frame repeated over refreshes is drawn once
                last, img = i, picture(i)
            video.write(img)


def _frame_caption(method: str, rec: Any) -> str:
    """The caption of display frame ``rec`` (a :class:`~splitrender.client.realtime.
    DisplayFrame`) in connect's video: the method and its mode, the display time, the time it
    took against its deadline, and the age of the newest server frame it used: what the viewer
    needs to tell a hold or a late frame from a reprojection artefact."""
    text = f"{method} {rec.mode}  t {rec.time:.3f} s  {rec.render_ms:.1f} ms"
    if not rec.met:
        text += " LATE"
    if rec.server_age_ms is not None:
        text += f"  server frame {rec.server_age_ms:.0f} ms old"
    return text


#: Most bytes of display frames `connect` keeps for its video and score.
MAX_KEPT_BYTES = 1 << 30


_Shown = list[tuple[float, npt.NDArray[np.uint8]]]


def _pick(frames: _Shown) -> list[_Shown]:
    """The display frames to score: the first and last SKIP_FRAMES left out (as `play`
    does), and of the rest runs of consecutive ones that score at most SCORED, spread over
    them (the ground truth costs a render per frame; each run's first and last frame are
    VMAF's context only, `shown.runs`). Consecutive as kept: past MAX_KEPT_BYTES, a
    stride of refreshes apart, as in the video."""
    from splitrender.evaluation.metrics import SKIP_FRAMES
    from splitrender.evaluation.shown import SCORED, runs

    inner = frames[SKIP_FRAMES : len(frames) - SKIP_FRAMES]
    # Spread over all of them: with fewer than SCORED, the steps of SCORED bunched every
    # frame scored into the session's first part (36 frames: 11, from its first third).
    return [[inner[i] for i in run] for run in runs(range(len(inner)), SCORED)]


def _shown(frames: _Shown, times: list[float]) -> list[npt.NDArray[np.uint8] | None]:
    """What a display that made ``frames`` (in time order) showed at each of ``times``: the
    newest frame made for that time or before (``None`` before its first)."""
    import bisect

    at = [t for t, _ in frames]
    out: list[npt.NDArray[np.uint8] | None] = []
    for t in times:
        i = bisect.bisect_right(at, t + 1e-9) - 1
        out.append(frames[i][1] if i >= 0 else None)
    return out


def _truths(
    scene: Any, scale: float, fc: float, motion: Any, picked: list[_Shown], eyes: int = 1
) -> list[list[list[npt.NDArray[np.uint8]]]]:
    """The ground truth (run, frame, eye) at the display times of ``picked``, rendered at the
    poses the client had (``motion(t)``: the same function that gave them)."""
    return [
        [[img for _, img in scene.client_frames(round(t * fc), scale, fc, eyes == 2,
                                                pose=motion(t))]
         for t, _ in run]
        for run in picked
    ]


def _score(
    picked: list[_Shown], truth: list[list[list[npt.NDArray[np.uint8]]]], no_vmaf: bool,
    eyes: int = 1,
) -> dict[str, Any]:
    """The runs of display frames ``picked`` (display time, image; each run's first and last
    VMAF's context only, :func:`_pick`) against ``truth`` (:func:`_truths`). A stereo
    session's (``eyes`` 2, the eyes side by side) scores each eye against the ground truth of
    that eye; the metrics are the means over both (as eval's Table 3), and ``per_eye`` holds
    each eye's."""
    from splitrender.evaluation.shown import score_images

    shown = [[_eye_images(img, eyes) for _, img in run] for run in picked]  # run, frame, eye
    return score_images(shown, truth, no_vmaf)[0]


def _scores(
    scene: Any, scale: float, fc: float, motion: Any, picked: list[_Shown],
    other: _Shown | None, no_vmaf: bool, eyes: int = 1,
) -> tuple[dict[str, Any], dict[str, Any] | None]:
    """The score of ``picked`` (:func:`_score`) and, where ``other`` holds the frames of a
    replay of the session with another method, its score at the same display times: what
    its display showed then (a refresh whose frame was late repeats the one before, as it
    did live; a time before its first frame is left out of both of its run's lists). The
    ground truth is rendered once for both: it is most of a score's cost."""
    truth = _truths(scene, scale, fc, motion, picked, eyes)
    score = _score(picked, truth, no_vmaf, eyes)
    if other is None:
        return score, None
    runs: list[_Shown] = []
    truths: list[list[list[npt.NDArray[np.uint8]]]] = []
    for run, want in zip(picked, truth):
        times = [t for t, _ in run]
        kept = [(t, img, g) for t, img, g in zip(times, _shown(other, times), want)
                if img is not None]
        runs.append([(t, img) for t, img, _ in kept])
        truths.append([g for _, _, g in kept])
    return score, _score(runs, truths, no_vmaf, eyes)


# -- relay ---------------------------------------------------------------------------------------


def add_relay(sub: Any) -> None:
    p = command(sub, "relay", run_relay)
    p.add_argument("--listen", type=_listen_address, default=("127.0.0.1", 4434),
                   metavar="HOST:PORT",
                   help="where clients connect (loopback only; default: 127.0.0.1:4434)")
    p.add_argument("--target", type=_address, default=("127.0.0.1", 4433), metavar="HOST:PORT",
                   help="the server (loopback only; default: 127.0.0.1:4433)")
    p.add_argument("--delay", type=milliseconds, default=0.0, metavar="MS",
                   help="one-way delay, each direction (default: %(default)s)")
    p.add_argument("--jitter", type=milliseconds, default=0.0, metavar="MS",
                   help="plus a uniform jitter in [-MS, MS] per datagram (default: %(default)s)")
    p.add_argument("--loss", type=loss, default=0.0, metavar="P",
                   help="datagram loss probability per direction, below 1: 0.01 or 1%% "
                   "(default: 0)")
    p.add_argument("--bandwidth", type=bitrate, default=None, metavar="MBPS",
                   help="cap of the server-to-client direction (default: none)")
    p.add_argument("--bandwidth-at", type=_step, action="append", default=[],
                   metavar="SECONDS:MBPS",
                   help="change the cap SECONDS after the first datagram of the client "
                   "(repeatable; 0 removes it)")
    p.add_argument("--queue", type=milliseconds, default=500.0, metavar="MS",
                   help="longest queue before the cap drops datagrams (default: %(default)s)")
    p.add_argument("--seed", type=lambda t: integer(t, 0, 2**32 - 1), default=0, metavar="N",
                   help="seed of the loss and jitter draws (default: %(default)s)")
    p.add_argument("--seconds", type=seconds, default=None, metavar="S",
                   help="stop after S seconds (default: run until interrupted)")
    add_quiet(p, "no summary at the end")


def run_relay(args: argparse.Namespace) -> int:
    from splitrender.net.relay import Impairment, Relay

    if args.loss >= 1.0:
        return fail("--loss: expected below 1 (at 100 % no datagram crosses), got 1")
    try:
        up = Impairment(args.delay, args.jitter, args.loss)
        down = Impairment(args.delay, args.jitter, args.loss, args.bandwidth or 0.0,
                          args.queue, tuple(args.bandwidth_at))
        relay = Relay(
            args.target, up, down, args.seed, args.listen,
            on_step=lambda d, mbps, when: print(
                f"bandwidth {d} {mbps:g} Mb/s at monotonic {when:.4f}", flush=True
            ),
        )
    except SplitRenderError as e:
        return fail(str(e))

    async def main() -> None:
        await relay.start()
        print(f"relaying {relay.listen[0]}:{relay.port} -> {relay.target[0]}:{relay.target[1]}",
              flush=True)
        try:
            if args.seconds is None:
                await asyncio.Event().wait()
            else:
                await asyncio.sleep(args.seconds)
        finally:
            relay.close()

    try:
        asyncio.run(main())
    except OSError as e:
        return fail(f"relay: {e}")
    except KeyboardInterrupt:
        pass
    if not args.quiet:
        s = relay.stats
        print(f"forwarded {s.forwarded}, lost {s.lost}, queue drops {s.queue_drops}", flush=True)
    return 0
