"""``splitrender demo``: the whole pipeline on a built-in dynamic scene, end to end.

Stages (progress on stderr, the summary table on stdout at the end):

1. render the server frames (10 FPS, main + two auxiliary cameras, every buffer, at the scene's
   predicted pose), each encoded as it is made with
   :class:`~splitrender.codec.coder.StreamEncoder` at the bitrate (default: the paper's 40 Mb/s
   scaled by pixel count, :meth:`CodecConfig.scaled`, but at least 1.6 Mb/s, see
   :data:`MIN_DEMO_BITRATE_MBPS`); only the packets are kept;
2. render the ground-truth client frames (120 FPS, at the client's actual pose) into a
   :class:`TruthStore` on disk;
3. per method: :func:`~splitrender.play` of the packets, decoded as the client needs each
   (:class:`~splitrender.codec.coder.DecodedStream`: the client only sees decoded frames),
   through the network model (default: ideal link, ``l = 0``, no loss; the packets' real sizes),
   each client frame scored as it is made against the ground truth
   (:func:`~splitrender.evaluation.pipeline.play_and_score_eyes`; first and last 12 client
   frames excluded), its stills written, and for ``ours`` (else the first method) its frame of
   ``video.mp4`` (ground truth | ``ours`` | FLIP error map of ``ours``);
4. write ``summary.md`` and ``summary.json``.

Memory does not grow with the run's length or the number of methods: no sequence of frames is
held (the packets, a few MB a second, are). The ground truth takes ``eyes x frames x W x H x 3``
bytes of disk in the output directory while the demo runs (1.3 GB per eye for 4 s at 1280x720),
and nothing once it ends.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import sys
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, cast

import numpy as np
import numpy.typing as npt

from splitrender.errors import InvalidInputError
from splitrender.files import AtomicWriter, OutputFolder, temporary_beside, write_atomic
from splitrender.net.model import NetworkModel
from splitrender.progress import Progress
from splitrender.imageio import montage, write_png
from splitrender.evaluation.metrics import SKIP_FRAMES, VMAF_MIN_SIDE, flip_map
from splitrender.reproject import METHODS

__all__ = [
    "DEFAULT_METHODS",
    "DemoArgumentError",
    "DemoConfig",
    "DemoResult",
    "colormap",
    "format_table",
    "run_demo",
]

DEFAULT_METHODS: tuple[str, ...] = (
    "ours",
    "ours_extrapolate",
    "forward_splat",
    "timewarp",
    "backward_bidir",
)
#: Server and client frame rates of the demo (DESIGN.md).
FS, FC = 10.0, 120.0
#: Columns of the summary rows, in order.
ROW_KEYS: tuple[str, ...] = ("method", "ssim", "flip", "psnr", "vmaf", "mbps", "frames")

_Image = npt.NDArray[np.uint8]

# Magma (matplotlib's) sampled at 9 points: enough for a smooth error-map colouring.
_MAGMA = np.array(
    [
        [0, 0, 4],
        [28, 16, 68],
        [79, 18, 123],
        [129, 37, 129],
        [181, 54, 122],
        [229, 80, 100],
        [251, 135, 97],
        [254, 194, 135],
        [252, 253, 191],
    ],
    dtype=np.float64,
)


class DemoArgumentError(InvalidInputError):
    """An argument of the demo that cannot work (too short, too small, unknown method ...)."""


def colormap(err: npt.NDArray[np.floating[Any]]) -> _Image:
    """``uint8[H, W, 3]`` magma colouring of an error map in ``[0, 1]`` (0 black, 1 pale)."""
    x = np.clip(np.nan_to_num(err.astype(np.float64)), 0.0, 1.0) * (len(_MAGMA) - 1)
    i = np.minimum(x.astype(np.int64), len(_MAGMA) - 2)
    f = (x - i)[..., None]
    rgb = _MAGMA[i] * (1 - f) + _MAGMA[i + 1] * f
    out: _Image = np.rint(rgb).astype(np.uint8)
    return out


@dataclass
class DemoConfig:
    scene: str = "courtyard"
    out: Path = Path("splitrender-demo")
    scale: float = 0.1
    seconds: float = 1.0
    bitrate_mbps: float | None = None
    methods: tuple[str, ...] = DEFAULT_METHODS
    vmaf: bool = True
    delay_frames: int = 0
    #: The link (bandwidth, latency, jitter, loss, seed); ``None``: the ideal link. Its
    #: ``extra_delay_frames`` and ``client_fps`` are replaced by ``delay_frames`` and :data:`FC`.
    network: NetworkModel | None = None
    #: Render two eyes (IPD 7 cm) and score both; the rows hold the mean and ``eyes``.
    stereo: bool = False
    video_fps: float = 30.0
    stills: int = 3
    progress: bool = True
    #: ``"cpu"`` or ``"wgpu"`` (the methods with a GPU kernel; see ``gpu.backend_for``).
    backend: str = "cpu"


@dataclass
class DemoResult:
    width: int
    height: int
    server_frames: int
    client_frames: int
    bitrate_mbps: float
    mbps: float
    rows: list[dict[str, Any]]
    files: list[Path] = field(default_factory=list)
    seconds: float = 0.0


def _json_number(v: float | None) -> float | str | None:
    if v is None:
        return None
    return v if math.isfinite(v) else str(v)


def cell(v: Any, fmt: str) -> str:
    """A table cell: ``–`` for ``None``, a string as is, a number formatted with ``fmt``."""
    if v is None:
        return "–"
    if isinstance(v, str):
        return v
    return format(v, fmt)


def format_table(rows: Sequence[dict[str, Any]], markdown: bool = False) -> str:
    """The summary rows as a plain-text (or Markdown) table."""
    head = ["method", "SSIM ↑", "FLIP ↓", "PSNR ↑", "VMAF ↑", "Mb/s", "frames"]
    body = [
        [
            str(r["method"]),
            cell(r["ssim"], ".4f"),
            cell(r["flip"], ".4f"),
            cell(r["psnr"], ".2f"),
            cell(r["vmaf"], ".2f"),
            cell(r["mbps"], ".3f"),
            str(r["frames"]),
        ]
        for r in rows
    ]
    if markdown:
        lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
        lines += ["| " + " | ".join(b) + " |" for b in body]
        return "\n".join(lines)
    widths = [max(len(h), *(len(b[i]) for b in body)) for i, h in enumerate(head)]
    fmt = [f"{{:<{widths[0]}}}"] + [f"{{:>{w}}}" for w in widths[1:]]
    lines = ["  ".join(f.format(h) for f, h in zip(fmt, head))]
    lines += ["  ".join(f.format(c) for f, c in zip(fmt, b)) for b in body]
    return "\n".join(lines)


def _even(a: int) -> int:
    return a + (a & 1)


def playback_speed(video_fps: float, client_fps: float = FC) -> str:
    """How ``video.mp4`` (one video frame per client frame, at ``video_fps``) plays the
    session: ``"4x slow motion"`` (30 FPS), ``"real time"`` (120), ``"2x fast motion"`` (240).
    Three significant digits; within 0.5 % of the session's speed, ``"about real time"``."""
    slow = client_fps / video_fps
    factor = f"{max(slow, 1 / slow):.3g}"
    if factor == "1":
        # "1x slow motion" at 120 FPS, "0.5x slow motion" at 240, said neither.
        return "real time" if slow == 1 else "about real time"
    return f"{factor}x {'slow' if slow > 1 else 'fast'} motion"


def _side_by_side(tiles: Sequence[_Image], labels: Sequence[str]) -> _Image:
    """Tiles in a row under their captions (:func:`~splitrender.imageio.montage`), padded
    (black) to even sides for yuv420p."""
    row = montage(tiles, labels=labels)
    h, width = row.shape[:2]
    out = np.zeros((_even(h), _even(width), 3), np.uint8)
    out[:h, :width] = row
    return out


class _Video(AtomicWriter):
    """An H.264 (or MPEG-4 Part 2 when libx264 is missing) ``yuv420p`` video written by PyAV.

    Written atomically, like every result file (:mod:`splitrender.files`): into a temporary
    file beside ``path`` that :meth:`close` finishes and renames over ``path``. An exception
    inside the ``with`` (or from a write or the close) calls :meth:`abort` instead, which removes
    it: a failed run leaves the previous video, never a shorter one that plays."""

    def __init__(self, path: Path, width: int, height: int, fps: float) -> None:
        from fractions import Fraction

        import av

        self._av = av
        self.path = path
        self._tmp = temporary_beside(path)
        self._done = False
        # The temporary name ends in .partial-*, from which PyAV cannot guess the container.
        # The rate is stored as a fraction: one that differs from fps (1e-9 became 0, which PyAV
        # silently replaced by 24) is refused before anything is written.
        rate = Fraction(0)
        if isinstance(fps, (int, float)) and 0 < fps <= 1000:
            rate = Fraction(fps).limit_denominator(1001)
        if not (rate > 0 and abs(float(rate) - fps) <= 1e-3 * fps):
            raise InvalidInputError(
                f"{path}: expected a video frame rate in 1/1001..1000 FPS that a fraction with "
                f"a denominator of at most 1001 holds, got {fps!r}"
            )
        self.container = av.open(str(self._tmp), mode="w", format="mp4")
        try:
            codec = "libx264" if "libx264" in av.codecs_available else "mpeg4"
            stream: Any = self.container.add_stream(codec, rate=rate)
            stream.width, stream.height, stream.pix_fmt = width, height, "yuv420p"
            if codec == "libx264":
                stream.options = {"crf": "18", "preset": "veryfast"}
            else:
                stream.bit_rate = max(1_000_000, width * height * 8)
        except BaseException:
            self.abort()
            raise
        self.stream = stream
        self.frames = 0

    def write(self, rgb: _Image) -> None:
        frame = self._av.VideoFrame.from_ndarray(np.ascontiguousarray(rgb), format="rgb24")
        for packet in self.stream.encode(frame):
            self.container.mux(packet)
        self.frames += 1

    def close(self) -> None:
        """Flushes the encoder and replaces ``path`` with the finished video (once)."""
        if self._done:
            return
        try:
            for packet in self.stream.encode():
                self.container.mux(packet)
            self.container.close()
            os.replace(self._tmp, self.path)
        except BaseException:
            self.abort()
            raise
        self._done = True

    def abort(self) -> None:
        """Drops the video: closes and removes the temporary file; ``path`` is as it was."""
        self._done = True
        # Closed only to release the file, which goes anyway: the error that led here wins.
        with contextlib.suppress(Exception):
            self.container.close()
        self._tmp.unlink(missing_ok=True)


def check_config(cfg: DemoConfig) -> None:
    """Raises :class:`DemoArgumentError` (one line) for a configuration that cannot run."""
    from splitrender.scene.builtin import SCENE_NAMES

    if cfg.scene not in SCENE_NAMES:
        raise DemoArgumentError(
            f"unknown scene {cfg.scene!r}; expected one of: {', '.join(SCENE_NAMES)}"
        )
    check_run_args([cfg.scene], cfg.methods, cfg.seconds, cfg.scale, DemoArgumentError)
    fps = cfg.video_fps
    if isinstance(fps, bool) or not isinstance(fps, (int, float)) or not 1 <= fps <= 240:
        raise DemoArgumentError(f"--video-fps: expected a number of FPS in 1..240, got {fps!r}")


def check_methods(
    methods: Sequence[str], error: type[DemoArgumentError], extra_methods: Sequence[str] = ()
) -> None:
    """At least one method, each a reprojection method or one of ``extra_methods``, each once;
    raises ``error`` (one line) naming ``--methods``."""
    if not methods:
        raise error("--methods: expected at least one method")
    known = (*METHODS, *extra_methods)
    bad = [m for m in methods if m not in known]
    if bad:
        raise error(f"--methods: unknown method {bad[0]!r}; expected some of: {', '.join(known)}")
    if len(set(methods)) != len(methods):
        raise error("--methods: a method is listed twice")


def check_run_args(
    scenes: Sequence[str],
    methods: Sequence[str],
    seconds: float,
    scale: float,
    error: type[DemoArgumentError],
    extra_methods: Sequence[str] = (),
) -> None:
    """The checks ``demo`` and ``eval`` share: the methods (the reprojection methods plus
    ``extra_methods``), a length every scene has and that leaves frames after the evaluation's
    skipped ends, and a usable image size. Raises ``error`` (one line) naming the option."""
    from splitrender.errors import SplitRenderError
    from splitrender.scene.builtin import Scene

    check_methods(methods, error, extra_methods)
    for name in scenes:
        duration = Scene(name).duration
        if seconds > duration + 1e-9:
            raise error(f"--seconds: scene {name!r} lasts {duration:g} s, asked for {seconds:g} s")
    n_client = max(1, round(seconds * FC))
    if n_client <= 2 * SKIP_FRAMES:
        need = (2 * SKIP_FRAMES + 1) / FC
        raise error(
            f"--seconds: {seconds:g} s is {n_client} client frames at {FC:g} FPS; the "
            f"evaluation skips {SKIP_FRAMES} at each end, so at least {need:.3f} s is needed"
        )
    # One message for every scale out of range, with the range of scales to type (below
    # 0.0008 the renderer's own check answered, in other words).
    try:
        w, h = Scene(scenes[0]).main_size(scale)
        size = f"a {w}x{h} main camera"
    except SplitRenderError:
        w = h = 0
        size = "a main camera under 2 pixels a side"
    if min(w, h) < 16 or max(w, h) > 4096:
        raise error(f"--scale: {scale:g} gives {size}; expected 16..4096 pixels a side "
                    "(--scale 0.0108 to 1.6)")


def check_gpu(backend: str) -> None:
    """For a GPU ``backend``: raises now (``GpuUnavailableError``) when it cannot run, not after
    rendering."""
    if backend != "cpu":
        from splitrender.gpu import adapter, check_backend

        check_backend(backend)
        adapter()


def metric_names(vmaf: bool, width: int, height: int, note: bool) -> tuple[str, ...]:
    """The metrics computed: SSIM, FLIP, PSNR, and VMAF when asked for and the image is large
    enough for it (else a note on stderr when ``note``)."""
    if vmaf and min(width, height) < VMAF_MIN_SIDE:
        vmaf = False
        if note:
            print(f"note: {width}x{height} is below VMAF's {VMAF_MIN_SIDE} pixels a side; VMAF "
                  "skipped", file=sys.stderr)
    return ("ssim", "flip", "psnr", "vmaf") if vmaf else ("ssim", "flip", "psnr")


#: The demo's bitrate floor (Mb/s). Packet headers and the lossless parts (shadow bitfields,
#: static-motion masks) cost a fixed amount (about 0.3 Mb/s with stream format 1; with format 2's
#: compressed header about 0.04 Mb/s of header plus ~0.1 Mb/s of lossless parts at 256x144), so
#: at the demo's small default size the paper's rate scaled by pixel count (0.4 Mb/s at 256x144)
#: leaves the video streams little and blurs every decoded image (measured with format 1: ours
#: SSIM 0.549 at 0.4 Mb/s, 0.652 at 1.6 Mb/s, courtyard 256x144).
MIN_DEMO_BITRATE_MBPS = 1.6


def default_bitrate_mbps(width: int, height: int) -> float:
    """The demo's default target: the paper's 40 Mb/s scaled to ``width x height`` by pixel count
    (:meth:`CodecConfig.scaled`), but at least :data:`MIN_DEMO_BITRATE_MBPS`."""
    from splitrender.codec.coder import CodecConfig  # imported lazily, like the rest of the demo

    scaled: float = CodecConfig.scaled(width, height).bitrate_mbps
    return max(scaled, MIN_DEMO_BITRATE_MBPS)


class TruthStore:
    """The ground-truth client frames of a run (``eyes x n`` images of ``height x width`` RGB8)
    in a file on disk, mapped into memory: the demo renders them once and every method is scored
    against them, but they are never all resident (a 4 s run at 1280x720 is 1.3 GB per eye; the
    pages are the file's, which the kernel drops under pressure and reads back when needed).

    The file is created in ``directory`` (the run's output directory: a temporary directory may
    be a RAM disk) already unlinked, so nothing is left behind however the run ends, and its
    blocks are reserved at once: a disk too full for it raises :class:`OSError` (``ENOSPC``) here
    with the size in the message, not a crash on a write to the mapping later."""

    def __init__(self, directory: Path, eyes: int, n: int, height: int, width: int) -> None:
        import tempfile

        shape = (eyes, n, height, width, 3)
        size = math.prod(shape)
        self._file = tempfile.TemporaryFile(dir=directory, prefix=".demo-truth-")
        try:
            if hasattr(os, "posix_fallocate"):
                os.posix_fallocate(self._file.fileno(), 0, max(size, 1))
            else:  # pragma: no cover - not Linux: a sparse file
                self._file.truncate(max(size, 1))
        except OSError as e:
            self._file.close()
            raise OSError(
                e.errno, f"cannot reserve {size / 1e9:.2f} GB for the {eyes * n} ground-truth "
                f"frames ({e.strerror or e})", str(directory)
            ) from None
        self.frames: np.memmap[Any, np.dtype[np.uint8]] = np.memmap(
            self._file, np.uint8, "r+", shape=shape
        )

    def eye(self, e: int) -> Sequence[_Image]:
        """Eye ``e``'s frames (views of the file, read when indexed)."""
        return cast(Sequence[_Image], self.frames[e])

    def close(self) -> None:
        """Closes the file. The mapping lasts while an array of it does (unmapping it under a
        view would crash its reader); the file system frees the blocks when it ends."""
        self._file.close()

    def __enter__(self) -> TruthStore:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


#: What a demo writes into its folder, replaced together
#: (:class:`~splitrender.files.OutputFolder`), ``summary.json`` last.
_OUTPUTS = ("stills", "video.mp4", "summary.md", "summary.json")


def run_demo(cfg: DemoConfig) -> DemoResult:
    """Runs the demo (see the module docstring) and writes its files to ``cfg.out``.

    They are written into a staging folder inside ``cfg.out`` and moved into place when the
    run completes (:class:`~splitrender.files.OutputFolder`): a failed or interrupted demo
    leaves the previous run's video, stills and summaries as they were."""
    check_config(cfg)
    check_gpu(cfg.backend)
    outputs = OutputFolder(cfg.out, _OUTPUTS)
    with outputs as stage:
        result = _demo(cfg, stage)
        result.files = [outputs.final(p) for p in result.files]
    return result


def _demo(cfg: DemoConfig, out: Path) -> DemoResult:
    """The demo, every file written into ``out`` (the staging folder)."""
    from dataclasses import replace

    from splitrender.codec.coder import CodecConfig, DecodedStream
    from splitrender.gpu import backend_for
    from splitrender.evaluation.pipeline import (
        encode_packets,
        mean_row,
        network_json,
        network_text,
        play_and_score_eyes,
    )
    from splitrender.scene.recording import plan
    from splitrender.scene.builtin import Scene
    from splitrender.types import ServerFrame

    scene = Scene(cfg.scene, "dynamic")
    w, h = scene.main_size(cfg.scale)
    n_server, n_client = plan(cfg.seconds, FS, FC)
    metrics = metric_names(cfg.vmaf, w, h, cfg.progress)
    stages = Progress(3 + len(cfg.methods), cfg.progress)
    eyes = 2 if cfg.stereo else 1
    (out / "stills").mkdir()
    files: list[Path] = []
    t0 = time.perf_counter()
    codec_cfg = (
        CodecConfig(bitrate_mbps=default_bitrate_mbps(w, h))
        if cfg.bitrate_mbps is None
        else CodecConfig(bitrate_mbps=cfg.bitrate_mbps)
    )

    # 1. render the server frames, each encoded as it is made: only the packets are kept, and
    # every method's play decodes them again as the client needs each frame (DecodedStream), so
    # that no decoded run (about 50 MB per 1280x720 server frame) is ever held whole.
    stages.stage(
        f"rendering {scene.name} (dynamic) at {w}x{h}: {n_server} server frames at {FS:g} FPS, "
        f"encoded at {codec_cfg.bitrate_mbps:.3g} Mb/s"
    )

    def rendered() -> Iterator[ServerFrame]:
        for k in range(n_server):
            yield scene.server_frame(k, cfg.scale, FS)

    packets, mbps = encode_packets(rendered(), codec_cfg, FS, stages.bar, n_server)
    sizes = [len(p) for p in packets]
    network = replace(cfg.network or NetworkModel(), extra_delay_frames=cfg.delay_frames,
                      client_fps=FC)

    lo, hi = SKIP_FRAMES, n_client - SKIP_FRAMES - 1
    still_idx = sorted({round(lo + (hi - lo) * (i + 1) / (cfg.stills + 1)) for i in range(cfg.stills)})
    video_method = "ours" if "ours" in cfg.methods else cfg.methods[0]
    rows: list[dict[str, Any]] = []
    video_path = out / "video.mp4"

    with TruthStore(out, eyes, n_client, h, w) as store:
        # 2. the ground truth at the client's actual pose, into the store on disk
        stages.stage(
            f"rendering {n_client} ground-truth client frames at {FC:g} FPS"
            f"{' per eye' if cfg.stereo else ''}"
        )
        cameras: list[list[Any]] = [[] for _ in range(eyes)]
        for n in range(n_client):
            for e, (cam, img) in enumerate(scene.client_frames(n, cfg.scale, FC, cfg.stereo)):
                cameras[e].append(cam)
                store.frames[e, n] = img
            stages.bar(n + 1, n_client, "frames")
        truths = [store.eye(e) for e in range(eyes)]
        truth = truths[0]  # the video and the stills show the (left) eye

        # 3. per method: play + evaluate; each client frame is scored as it is made and dropped
        # (keep_images=False), its still and its video frame written from `on_frame`.
        for method in cfg.methods:
            stages.stage(f"{method}: playing {n_client} client frames, then {', '.join(metrics)}"
                         + (f"; writing video.mp4 (ground truth | {method} | FLIP map)"
                            if method == video_method else ""))
            with contextlib.ExitStack() as stack:
                video: _Video | None = None
                if method == video_method:
                    vw, vh = _side_by_side([truth[0]] * 3, [""] * 3).shape[1::-1]
                    video = stack.enter_context(_Video(video_path, vw, vh, cfg.video_fps))

                def on_frame(eye: int, n: int, image: _Image, info: Any) -> None:
                    if eye != 0:
                        return
                    if n in still_idx:
                        still = out / "stills" / f"frame{n:04d}_{method}.png"
                        write_png(still, image)
                        files.append(still)
                    if video is None:
                        return
                    err = colormap(flip_map(image, truth[n]))
                    side = _side_by_side([truth[n], image, err], [
                        f"ground truth  t = {n / FC:.3f} s", f"{method}  {info.mode}",
                        f"FLIP error of {method}"])
                    video.write(side)
                    if n in still_idx:
                        for name, img in (
                            ("ground_truth", truth[n]), (f"flip_{method}", err),
                            ("side_by_side", side),
                        ):
                            still = out / "stills" / f"frame{n:04d}_{name}.png"
                            write_png(still, img)
                            files.append(still)

                scored = play_and_score_eyes(
                    DecodedStream(packets), cameras, truths, method, network, FC, metrics,
                    frame_sizes=sizes, bar=stages.bar, on_frame=on_frame,
                    backend=backend_for(method, cfg.backend), keep_images=False,
                )
            res = scored[0].playback
            row: dict[str, Any] = {"method": method, **mean_row(scored), "mbps": mbps}
            row = {k: row[k] for k in ROW_KEYS} | {"modes": res.summary()}
            if cfg.stereo:
                row["eyes"] = [s.row() for s in scored]
            rows.append(row)
            del res, scored

    # 4. summary
    stages.stage("writing summary.md and summary.json")
    files.insert(0, video_path)
    elapsed = time.perf_counter() - t0
    result = DemoResult(w, h, n_server, n_client, codec_cfg.bitrate_mbps, mbps, rows, files, elapsed)
    summary = {
        "scene": scene.name,
        "variant": scene.variant,
        "scale": cfg.scale,
        "width": w,
        "height": h,
        "seconds": cfg.seconds,
        "server_fps": FS,
        "client_fps": FC,
        "server_frames": n_server,
        "client_frames": n_client,
        "skip": SKIP_FRAMES,
        "bitrate_target_mbps": codec_cfg.bitrate_mbps,
        "mbps": mbps,
        "stereo": cfg.stereo,
        "network": network_json(network),
        "video": {"file": "video.mp4", "frames": n_client, "fps": cfg.video_fps,
                  "tiles": ["ground_truth", video_method, f"flip_{video_method}"]},
        "stills": still_idx,
        "runtime_s": elapsed,
        "rows": [
            {k: (_json_number(r[k]) if k not in ("method", "frames") else r[k]) for k in ROW_KEYS}
            | {"modes": r["modes"]}
            | ({"eyes": [{k: _json_number(v) if k != "frames" else v for k, v in e.items()}
                         for e in r["eyes"]]} if "eyes" in r else {})
            for r in rows
        ],
    }
    write_atomic(out / "summary.json", json.dumps(summary, indent=1) + "\n")
    md = [
        f"# splitrender demo: {scene.name} (dynamic), {w}x{h}",
        "",
        (
            f"{cfg.seconds:g} s: {n_server} server frames at {FS:g} FPS encoded at "
            f"{codec_cfg.bitrate_mbps:.3g} Mb/s (achieved {mbps:.3f} Mb/s), {n_client} client "
            f"frames at {FC:g} FPS{' per eye (stereo)' if cfg.stereo else ''} played through the "
            f"network model ({network_text(network)}). Metrics are per-frame means against the "
            f"ground truth at the client pose{', averaged over both eyes' if cfg.stereo else ''}, "
            f"first and last {SKIP_FRAMES} client frames excluded."
        ),
        "",
        format_table(rows, markdown=True),
        "",
        (
            f"`video.mp4`: ground truth | {video_method} | FLIP error map of {video_method} "
            f"(magma, black = no error), {n_client} frames at {cfg.video_fps:g} FPS "
            f"({playback_speed(cfg.video_fps)}). Stills of client frames "
            f"{', '.join(map(str, still_idx))} are in `stills/`."
        ),
        "",
    ]
    write_atomic(out / "summary.md", "\n".join(md))
    files += [out / "summary.md", out / "summary.json"]
    return result
