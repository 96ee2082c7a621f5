"""Pieces of the split-rendering pipeline shared by ``demo``, ``play`` and ``eval``.

:func:`encode_decode` runs server frames through :class:`~splitrender.codec.coder.StreamEncoder` and
:class:`~splitrender.codec.coder.StreamDecoder` (what the client sees of a compressed stream);
:func:`play_and_score` plays one method through the network model and the client and scores its
frames against the ground truth with :func:`~splitrender.evaluation.metrics.evaluate_sequence`.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from splitrender.client.playback import PlaybackResult, frame_nbytes, play
from splitrender.codec.coder import CodecConfig, StreamDecoder, StreamEncoder
from splitrender.evaluation.metrics import SKIP_FRAMES, SequenceMetrics, evaluate_sequence
from splitrender.net.model import NetworkModel
from splitrender.codec.stream import stream_stats
from splitrender.types import Camera, ReprojectOptions, ServerFrame

__all__ = ["Scored", "encode_decode", "play_and_score", "raw_mbps"]

_Image = npt.NDArray[np.uint8]
#: ``bar(done, total, label)``: one progress bar (e.g. :meth:`splitrender.progress.Progress.bar`).
Bar = Callable[[int, int, str], None]


def encode_decode(
    frames: Iterable[ServerFrame], config: CodecConfig, fps: float, bar: Bar | None = None,
    total: int = 0,
) -> tuple[list[ServerFrame], list[int], float]:
    """Encodes and decodes every frame; returns ``(decoded frames, packet sizes, achieved Mb/s
    at fps)``."""
    packets: list[bytes] = []
    decoded: list[ServerFrame] = []
    with StreamEncoder(config) as enc, StreamDecoder() as dec:
        for k, f in enumerate(frames):
            p = enc.encode(f)
            packets.append(p)
            decoded.append(dec.decode(p))
            if bar is not None:
                bar(k + 1, total, "server frames")
    return decoded, [len(p) for p in packets], stream_stats(packets, fps).mbps_total()


def raw_mbps(frames: Sequence[ServerFrame], fps: float) -> float:
    """The rate of the uncompressed frames (every buffer's bytes) in Mb/s at ``fps``."""
    if not frames:
        return 0.0
    return sum(frame_nbytes(f) for f in frames) * 8 * fps / len(frames) / 1e6


@dataclass
class Scored:
    """One method's playback and its scores."""

    playback: PlaybackResult
    metrics: SequenceMetrics

    def row(self) -> dict[str, Any]:
        """``ssim``, ``flip``, ``psnr``, ``vmaf`` (each ``None`` when not computed) and
        ``frames``."""
        m = self.metrics.mean
        return {
            "ssim": m.get("ssim"),
            "flip": m.get("flip"),
            "psnr": m.get("psnr"),
            "vmaf": m.get("vmaf"),
            "frames": len(self.metrics.frames),
        }


def play_and_score(
    frames: Iterable[ServerFrame],
    cameras: Sequence[Camera],
    truth: Sequence[_Image],
    method: str,
    network: NetworkModel,
    fc: float,
    metrics: Sequence[str],
    *,
    frame_sizes: Sequence[int] | None = None,
    bar: Bar | None = None,
    on_frame: Callable[[int, _Image, Any], None] | None = None,
    options: ReprojectOptions | None = None,
    backend: str = "cpu",
) -> Scored:
    """Plays ``frames`` with ``method`` through ``network`` at the client ``cameras`` (``fc``
    FPS) and scores the client frames against ``truth`` (first and last ``SKIP_FRAMES``
    excluded). ``options`` go to the client (e.g. ``server_fps`` for a server at another rate
    than 10 FPS); ``backend`` is ``"cpu"`` or ``"wgpu"`` (:class:`~splitrender.Client`)."""
    n_client = len(cameras)

    def frame_done(n: int, image: _Image, info: Any) -> None:
        if bar is not None:
            bar(n + 1, n_client, "client frames")
        if on_frame is not None:
            on_frame(n, image, info)

    res = play(frames, cameras, network, fc, method, frame_sizes=frame_sizes, on_frame=frame_done,
               options=options, backend=backend)

    def progress(metric: str, done: int, total: int) -> None:
        if bar is not None:
            bar(done, total, metric)

    sm = evaluate_sequence(res.images, truth, SKIP_FRAMES, metrics, fps=fc, progress=progress)
    return Scored(res, sm)
