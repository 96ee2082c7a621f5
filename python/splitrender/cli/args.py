"""Argument types, checks and shared options of the ``splitrender`` subcommands."""

from __future__ import annotations

import argparse
import math
import re
import sys
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any, NoReturn, TypeVar

from splitrender.cli.help import DESCRIPTION, HELP
from splitrender.client.realtime import MAX_DIVISOR
from splitrender.errors import SplitRenderError
from splitrender.progress import Progress
from splitrender.reproject import MAX_PREPARE_THREADS, METHODS
from splitrender.types import MAX_SIDE

if TYPE_CHECKING:
    from splitrender.net.model import NetworkModel
    from splitrender.scene.builtin import Scene

PROG = "splitrender"

T = TypeVar("T")


class Parser(argparse.ArgumentParser):
    """argparse with one-line errors (``splitrender: error: ...``) and no usage dump."""

    _argv: list[str] = []

    def parse_known_args(  # type: ignore[override]
        self, args: Any = None, namespace: Any = None
    ) -> tuple[argparse.Namespace, list[str]]:
        # Kept for error(): argparse reads "--opt -1:0.5" as two options and says only that
        # --opt lacks its value.
        self._argv = list(sys.argv[1:] if args is None else args)
        return super().parse_known_args(args, namespace)

    def error(self, message: str) -> NoReturn:
        hint = self._dash_value_hint(message)
        self.exit(2, f"{self.prog}: error: {message}{hint} (see '{self.prog} --help')\n")

    def _dash_value_hint(self, message: str) -> str:
        """``; write --opt=VALUE ...`` when ``message`` says an option lacks its value and the
        word after it starts with ``-`` (a value argparse took for an option)."""
        found = re.match(r"argument (\S+): expected one argument$", message)
        if found is None:
            return ""
        names = found.group(1).split("/")
        for word, following in zip(self._argv, self._argv[1:]):
            if word in names and following.startswith("-") and len(following) > 1:
                return f"; a value that starts with '-' is written {word}={following}"
        return ""


def fail(message: str) -> int:
    """Prints ``splitrender: error: message`` on stderr and returns exit status 2 (a user error)."""
    print(f"{PROG}: error: {message}", file=sys.stderr)
    return 2


def run_stages(
    stages: int, quiet: bool, work: Callable[[Progress], T], report: Callable[[T, float], None]
) -> int:
    """Runs ``work(bar)`` with a :class:`~splitrender.progress.Progress` ``bar`` of ``stages``
    stages (silent with ``quiet``; closed at the end), then ``report(result, seconds)``; returns
    0, or the exit status of :func:`fail` for a ``SplitRenderError``."""
    bar = Progress(stages, not quiet)
    try:
        result = work(bar)
    except SplitRenderError as e:
        return fail(str(e))
    finally:
        bar.close()
    report(result, bar.elapsed())
    return 0


def wrote_dir(out: Path, seconds: float) -> None:
    """The last line of a command that wrote the directory ``out`` in ``seconds``."""
    print(f"wrote {out}/ in {seconds:.1f} s")


def integer(text: str, lo: int, hi: int, what: str = "an integer", unit: str = "") -> int:
    """``text`` as an int in ``lo..hi``, or an ``ArgumentTypeError`` saying ``what`` is expected
    (``expected 1..8 per pixel side`` instead when a ``unit`` is given)."""
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
    if not lo <= v <= hi:
        want = f"{lo}..{hi} {unit}" if unit else f"{what} in {lo}..{hi}"
        raise argparse.ArgumentTypeError(f"expected {want}, got {v}")
    return v


def side(text: str) -> int:
    return integer(text, 1, MAX_SIDE, "a size")


def samples(text: str) -> int:
    from splitrender.scene.builtin import MAX_SAMPLES

    return integer(text, 1, MAX_SAMPLES, unit="per pixel side")


SAMPLES_HELP = (
    "colour sub-samples per pixel side N: server colour, shadow colours and ground truth are "
    "the mean of N x N samples (depth, motion and shadow bits stay at the pixel centre); "
    "default: 3 up to 640x360 pixels per camera, 2 above"
)


def number(text: str, lo: float, hi: float, unit: str = "", *, low_open: bool = False) -> float:
    """``text`` as a finite float in ``lo..hi`` (``lo`` excluded with ``low_open``), or an
    ``ArgumentTypeError`` saying so (with ``unit`` after the range). Every numeric option goes
    through here at parse time, so NaN, infinities and values no later step can use (``1e300``,
    ``1e-9``) never reach the commands."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not (math.isfinite(v) and (v > lo if low_open else v >= lo) and v <= hi):
        above = f"> {lo:g}" if low_open else f">= {lo:g}"
        raise argparse.ArgumentTypeError(
            f"expected a finite number {above} and <= {hi:g}{' ' + unit if unit else ''}, "
            f"got {text}"
        )
    return v


#: Shortest and longest ``--seconds``: about one client frame at 120 FPS (1e-9 rendered a
#: one-frame recording and exited 0), and a day.
MIN_SECONDS, MAX_SECONDS = 0.01, 86400.0


def seconds(text: str) -> float:
    """A duration in seconds, :data:`MIN_SECONDS` .. :data:`MAX_SECONDS` (a scene's own length
    is checked later, against the scene)."""
    return number(text, MIN_SECONDS, MAX_SECONDS, "s")


def scale(text: str) -> float:
    """A main-camera scale ``X``: ``round(2560X) x round(1440X)`` must be 1..MAX_SIDE pixels a
    side."""
    v = number(text, 0.0, MAX_SIDE / 2560, low_open=True)
    if round(1440 * v) < 1:
        raise argparse.ArgumentTypeError(
            f"expected a scale giving at least 1 pixel a side (>= {1 / 2880:.5f}), got {text}"
        )
    return v


def rate(text: str) -> float:
    """A frame rate in FPS, as the codec takes it (``CodecConfig.fps``'s range)."""
    from splitrender.codec.coder import MAX_FPS, MIN_FPS

    return number(text, MIN_FPS, MAX_FPS, "FPS")


def video_fps(text: str) -> float:
    """A video's frame rate, 1..240 FPS: what players and the H.264/MPEG-4 writers take (the
    rate is stored as a fraction with a denominator of at most 1001, so below 1 FPS it would be
    coarse, and 1e-9 became 0, which PyAV replaced by its default 24)."""
    return number(text, 1.0, 240.0, "FPS")


#: Lowest ``--bitrate`` or ``--bandwidth`` (Mb/s, 10 kb/s): far below a stream's fixed cost
#: (headers and lossless parts, about 0.15 Mb/s at 256x144), so only a slip goes lower (1e-9
#: reached the encoder, and as a link made every frame arrive years late).
MIN_BITRATE_MBPS = 0.01


def bitrate(text: str) -> float:
    """A target bitrate (or link bandwidth) in Mb/s: :data:`MIN_BITRATE_MBPS` and at most what
    :class:`CodecConfig` takes (1e300 reached the encoder and raised OverflowError)."""
    from splitrender.codec.coder import MAX_BITRATE_MBPS

    return number(text, MIN_BITRATE_MBPS, MAX_BITRATE_MBPS, "Mb/s")


def in_path(text: str) -> Path:
    """An input file or folder; the empty string is refused (``Path("")`` is the current
    directory, which was then read as a recording, a dataset or a trace)."""
    if text == "":
        raise argparse.ArgumentTypeError("expected a path, got ''")
    return Path(text)


def out_dir(text: str) -> Path:
    """An output directory: it may be missing (it is created, with its parents), but the
    nearest existing path above it must be a directory (a file there cannot hold it). The path
    itself the command checks (it may be an input, which check_apart names)."""
    path = Path(text)
    if text == "":
        raise argparse.ArgumentTypeError("expected a directory path, got ''")
    for up in path.absolute().parents:
        if up.exists():
            if not up.is_dir():
                raise argparse.ArgumentTypeError(
                    f"{text}: {up} is not a directory; expected a path under a directory"
                )
            break
    return path


def out_file(text: str) -> Path:
    """An output file in an existing directory (that it is not itself a directory, or an input,
    the command checks, saying which)."""
    path = Path(text)
    if text == "":
        raise argparse.ArgumentTypeError("expected a file name, got ''")
    parent = path.absolute().parent
    if not parent.is_dir():
        raise argparse.ArgumentTypeError(
            f"{text}: expected a file in an existing directory, {parent} is "
            f"{'not a directory' if parent.exists() else 'missing'}"
        )
    return path


def scene_description(text: str, where: str = "") -> Path | None:
    """The scene description a SCENE argument names, or ``None`` for a built-in scene's name:
    a name ending in .json (any case) or any other existing path (which the description reader
    refuses if it is not a regular JSON file). A glTF model given directly is refused naming
    what to write instead (it was "unknown scene", or "not UTF-8" for serve's --scene)."""
    from splitrender.errors import InvalidInputError
    from splitrender.scene.builtin import SCENE_NAMES

    if text in SCENE_NAMES:
        return None
    path = Path(text)
    if path.suffix.lower() in (".gltf", ".glb"):
        raise InvalidInputError(
            f"{where}{text} is a glTF model, not a scene; expected a built-in scene "
            f"({', '.join(SCENE_NAMES)}) or a JSON scene description that places the model into "
            f'one, e.g. {{"scene": "courtyard", "models": [{{"path": "{path.name}", '
            '"position": [0, 0, -3]}]} (see splitrender.Scene.from_description)'
        )
    if path.suffix.lower() == ".json" or path.exists():
        return path
    return None


def open_scene(text: str, where: str = "", variant: str | None = None) -> Scene:
    """The scene a SCENE argument names (:func:`scene_description`): a built-in scene in
    ``variant`` (default dynamic), or a scene description, which names its own variant:
    ``variant`` given with one is refused (render's --variant was ignored)."""
    from splitrender.errors import InvalidInputError
    from splitrender.scene.builtin import SCENE_NAMES, Scene

    desc = scene_description(text, where)
    if desc is not None:
        if variant is not None:
            raise InvalidInputError(
                f"--variant: only for a built-in scene; the scene description {text} names its "
                'own ("variant", default dynamic)'
            )
        return Scene.from_description(desc)
    if text not in SCENE_NAMES:
        raise InvalidInputError(
            f'{where}unknown scene "{text}"; valid scenes: {", ".join(SCENE_NAMES)}, or a JSON '
            "scene description file (*.json)"
        )
    return Scene(text, variant or "dynamic")


def _method_list(text: str, known: tuple[str, ...]) -> tuple[str, ...]:
    names = tuple(m.strip() for m in text.split(",") if m.strip())
    if not names:
        raise argparse.ArgumentTypeError("expected a comma-separated list of methods")
    for m in names:
        if m not in known:
            raise argparse.ArgumentTypeError(
                f"unknown method {m!r}; expected some of: {','.join(known)}"
            )
    if len(set(names)) != len(names):
        raise argparse.ArgumentTypeError(f"a method is listed twice in {text!r}")
    return names


def methods(text: str) -> tuple[str, ...]:
    return _method_list(text, METHODS)


def count(text: str) -> int:
    return integer(text, 1, 100000)


def prepare_threads(text: str) -> int:
    return integer(text, 1, MAX_PREPARE_THREADS, "a thread count")


def frames_delay(text: str) -> int:
    return integer(text, 0, 1000)


def command(
    sub: Any,
    name: str,
    run: Callable[[argparse.Namespace], int] | None,
    key: str | None = None,
) -> argparse.ArgumentParser:
    """The parser of the subcommand ``name`` in ``sub`` (an ``add_subparsers`` action), with its
    line in the parent's list and its ``--help`` text from :mod:`.help` (under ``key``, by default
    ``name``); ``run``, unless None (a parent of subcommands), is the parser's ``run`` default
    that :mod:`.main` calls."""
    k = name if key is None else key
    p: argparse.ArgumentParser = sub.add_parser(name, help=HELP[k], description=DESCRIPTION[k])
    if run is not None:
        p.set_defaults(run=run)
    return p


def add_out(
    p: argparse.ArgumentParser, help: str = "output directory", metavar: str = "DIR",
    default: Path | None = None,
) -> None:
    """``--out``: a directory (:func:`out_dir`), or a file (:func:`out_file`) when ``metavar``
    is ``FILE``; required unless a ``default`` is given."""
    p.add_argument("--out", type=out_file if metavar == "FILE" else out_dir,
                   required=default is None, default=default, metavar=metavar, help=help)


def add_quiet(p: argparse.ArgumentParser, help: str = "no progress on stderr") -> None:
    p.add_argument("--quiet", action="store_true", help=help)


def add_no_vmaf(p: argparse.ArgumentParser, help: str = "skip VMAF") -> None:
    p.add_argument("--no-vmaf", action="store_true", help=help)


def add_scale(p: argparse.ArgumentParser, default: float | None, shown: str = "") -> None:
    """``--scale`` of the main camera; the help shows ``default`` with its size (256x144 for
    0.1), or ``shown`` where the default is None (decided later)."""
    if default is not None:
        shown = f"%(default)s = {round(2560 * default)}x{round(1440 * default)}"
    p.add_argument("--scale", type=scale, default=default, metavar="X",
                   help=f"main camera size round(2560X) x round(1440X) (default: {shown})")


def add_trace(p: argparse.ArgumentParser, rate: str = "") -> None:
    """``--trace FILE`` (a head trace as client motion; ``rate``, e.g. `` (60 Hz)``, in its help)
    and ``--trace-scale``."""
    p.add_argument("--trace", type=in_path, default=None, metavar="FILE",
                   help=f"head trace 'px py pz pitch yaw roll t_ms' per line{rate} as client "
                   "motion")
    p.add_argument("--trace-scale", type=lambda t: number(t, 0.0, 1000.0), default=1.0,
                   metavar="F",
                   help="scale of the trace's translation (default: %(default)s)")


def add_max_divisor(p: Any, default: int | None, when: str = "") -> None:
    """``--max-divisor D`` (1–4): the most the display may divide ``--fps`` by when its frames
    do not fit the refresh (:class:`~splitrender.client.realtime.RateGovernor`). ``default``
    ``None`` lets the caller see whether it was given; ``when`` (e.g. ``"with --realtime: "``)
    opens its help."""
    p.add_argument(
        "--max-divisor", type=int, choices=(1, 2, 3, 4), default=default, metavar="D",
        help=f"{when}the most the display may divide --fps by when its frames do not fit the "
        "refresh (2: half rate, as headset runtimes do; 1: hold --fps whatever the frames "
        f"cost; default: {MAX_DIVISOR})",
    )


def add_always_interpolate(p: Any, when: str = "") -> None:
    """``--always-interpolate``: a frame that can interpolate its pair does, whatever it costs
    (``RealtimeClient(defer_interpolation=False)``; by default it extrapolates where an
    interpolated frame would miss its deadline:
    :class:`~splitrender.client.realtime.ModeGovernor`). ``when`` opens its help, e.g.
    ``"with --realtime: "``."""
    p.add_argument(
        "--always-interpolate", action="store_true",
        help=f"{when}interpolate every frame that has its pair, even where an interpolated "
        "frame would miss its deadline (default: such a frame extrapolates from the pair's "
        "older frame instead, which costs about 60 %% as much)",
    )


def add_samples(p: argparse.ArgumentParser, more: str = "") -> None:
    """``--samples N`` (:data:`SAMPLES_HELP`, then ``more``)."""
    p.add_argument("--samples", type=samples, default=None, metavar="N", help=SAMPLES_HELP + more)


def add_backend(p: Any, scope: str) -> None:
    p.add_argument(
        "--backend", choices=("cpu", "wgpu"), default="cpu",
        help=f"where the reprojection runs: cpu (reproj-core) or wgpu (GPU compute shaders; "
        f"{scope}; without a GPU, Mesa's lavapipe: apt-get install mesa-vulkan-drivers) "
        "(default: %(default)s)",
    )


def add_scene(p: Any) -> None:
    p.add_argument("--scene", default="courtyard", metavar="NAME",
                   help="built-in scene: courtyard, colonnade, lab (default: %(default)s)")


def names(text: str) -> tuple[str, ...]:
    names = tuple(m.strip() for m in text.split(",") if m.strip())
    if not names:
        raise argparse.ArgumentTypeError("expected a comma-separated list")
    return names


def bitrates(text: str) -> tuple[float, ...]:
    return tuple(bitrate(t) for t in names(text))


def delays(text: str) -> tuple[int, ...]:
    return tuple(frames_delay(t) for t in names(text))


def eval_methods(text: str) -> tuple[str, ...]:
    from splitrender.evaluation.experiments import VIDEO_INTERP

    return _method_list(text, (*METHODS, VIDEO_INTERP))


def milliseconds(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of ms, got {text!r}") from None
    if not 0 <= v <= 60000:
        raise argparse.ArgumentTypeError(f"expected 0..60000 ms, got {text}")
    return v


def loss(text: str) -> float:
    """A loss probability: a fraction in ``[0, 1]`` (``0.05``) or a percentage (``5%``)."""
    t = text.strip()
    percent = t.endswith("%")
    try:
        v = float(t[:-1] if percent else t)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected a fraction in 0..1 or a percentage like 5%, got {text!r}"
        ) from None
    if percent:
        v /= 100.0
    if not 0.0 <= v <= 1.0:
        raise argparse.ArgumentTypeError(f"expected a loss in 0..1 (0%..100%), got {text}")
    return v


def add_network(p: Any, delay: bool = True) -> None:
    """The network model's options (``--delay``, ``--bandwidth``, ``--latency``, ``--jitter``,
    ``--loss``, ``--seed``); the defaults are the ideal link. ``delay=False`` leaves out
    ``--delay`` (``eval`` has ``--delays``). :func:`network_model` builds the model."""
    g = p.add_argument_group(
        "network model",
        "the one-way link from server to client (splitrender.NetworkModel); each server frame "
        "is one packet of its encoded (or, uncompressed, its raw) size, serialised in order at "
        "--bandwidth, then delayed by --latency plus a uniform jitter in [0, --jitter] plus "
        "--delay client frames, delivered in order, or lost with probability --loss. The "
        "defaults are the ideal link (unlimited bandwidth, no latency, jitter or loss)",
    )
    if delay:
        g.add_argument("--delay", type=frames_delay, default=0, metavar="L",
                       help="extra network delay in client frames, l (default: %(default)s)")
    g.add_argument("--bandwidth", type=bitrate, default=None, metavar="MBPS",
                   help="link bandwidth in Mb/s (10^6 bits/s) (default: unlimited)")
    g.add_argument("--latency", type=milliseconds, default=0.0, metavar="MS",
                   help="one-way latency in milliseconds (default: %(default)s)")
    g.add_argument("--jitter", type=milliseconds, default=0.0, metavar="MS",
                   help="extra delay per packet, uniform in [0, MS] milliseconds; packets stay "
                   "in order (default: %(default)s)")
    g.add_argument("--loss", type=loss, default=0.0, metavar="P",
                   help="probability that a server frame is lost: a fraction in 0..1 (0.05) or "
                   "a percentage (5%%) (default: %(default)s)")
    g.add_argument("--seed", type=lambda t: integer(t, 0, 2**32 - 1), default=0, metavar="N",
                   help="seed of the jitter and loss draws (default: %(default)s)")


def network_model(args: argparse.Namespace, client_fps: float = 120.0) -> NetworkModel:
    """The :class:`~splitrender.net.model.NetworkModel` of the options :func:`add_network`
    added (``extra_delay_frames`` 0 without ``--delay``)."""
    from splitrender.net.model import NetworkModel

    return NetworkModel(
        bandwidth_mbps=args.bandwidth, latency_ms=args.latency, jitter_ms=args.jitter,
        extra_delay_frames=getattr(args, "delay", 0), loss=args.loss, seed=args.seed,
        client_fps=client_fps,
    )
