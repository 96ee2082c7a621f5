"""Pieces of the split-rendering pipeline shared by ``demo``, ``play`` and ``eval``.

:func:`encode_packets` runs server frames through :class:`~splitrender.codec.coder.StreamEncoder`;
the packets play through :class:`~splitrender.codec.coder.DecodedStream`, each frame decoded when
the client needs it (what the client sees of a compressed stream; ``demo``, ``play`` and
``eval``, each play decoding them again rather than holding them decoded);
:func:`play_and_score_eyes` plays one method through the network model and the client and scores
its frames (of one eye or two) against the ground truth as they are made
(:class:`~splitrender.evaluation.metrics.SequenceScorer`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from splitrender.client.playback import PlaybackResult, play
from splitrender.codec.coder import CodecConfig, StreamEncoder
from splitrender.evaluation.metrics import (
    SKIP_FRAMES,
    SequenceMetrics,
    SequenceScorer,
    psnr_of_mse,
)
from splitrender.net.model import NetworkModel
from splitrender.codec.stream import stream_stats, unpack_packet
from splitrender.errors import InvalidInputError
from splitrender.scene.recording import Recording
from splitrender.types import Camera, ReprojectOptions, ServerFrame

__all__ = [
    "Scored",
    "check_stream_of",
    "encode_packets",
    "mean_of_eyes",
    "mean_row",
    "network_json",
    "network_text",
    "play_and_score_eyes",
    "raw_mbps",
]

_Image = npt.NDArray[np.uint8]
#: ``bar(done, total, label)``: one progress bar (e.g. :meth:`splitrender.progress.Progress.bar`).
Bar = Callable[[int, int, str], None]


def encode_packets(
    frames: Iterable[ServerFrame], config: CodecConfig, fps: float, bar: Bar | None = None,
    total: int = 0,
) -> tuple[list[bytes], float]:
    """Encodes every frame; returns ``(packets, achieved Mb/s at fps)``. The packets play
    through :class:`~splitrender.codec.coder.DecodedStream`, decoded as the client needs each."""
    packets: list[bytes] = []
    with StreamEncoder(config) as enc:
        for k, f in enumerate(frames):
            packets.append(enc.encode(f))
            if bar is not None:
                bar(k + 1, total, "server frames encoded")
    return packets, stream_stats(packets, fps).mbps_total()


def check_stream_of(packets: Sequence[bytes], fps: float, rec: Recording, name: str) -> None:
    """Checks that ``packets`` (of the stream file ``name``, at ``fps`` server frames per
    second) were encoded from ``rec``'s first server frames: the same rate, and packet ``k`` of
    server frame ``k``'s index and time, with its cameras' sizes and matrices. A stream is
    played at the recording's client cameras and scored against its ground truth, so a stream
    of another scene or take would be scored without complaint (a lab stream against a
    courtyard recording scored SSIM 0.19).

    # Errors
    :class:`InvalidInputError` naming the first frame and field that differ; a malformed
    packet raises :class:`StreamError` (:func:`~splitrender.codec.stream.unpack_packet`)."""
    here = f"{name} was not encoded from {rec.path}"
    if not math.isclose(fps, rec.fs, rel_tol=1e-9):
        raise InvalidInputError(f"{here}: the stream is at {fps:g} server frames per second, "
                                f"the recording at {rec.fs:g}")
    entries = rec.manifest["server_frames"]
    if len(packets) > len(entries):
        raise InvalidInputError(f"{here}: the stream has {len(packets)} frames, the recording "
                                f"{len(entries)} server frames")
    for k, data in enumerate(packets):
        p, entry = unpack_packet(data), entries[k]
        if p.index != entry["index"] or p.time != entry["time"]:
            raise InvalidInputError(
                f"{here}: its frame {k} is server frame {p.index} at {p.time:g} s, the "
                f"recording's is {entry['index']} at {entry['time']:g} s")
        cams = rec.server_cameras(k)
        if len(p.cameras) != len(cams):
            raise InvalidInputError(f"{here}: frame {p.index} has {len(p.cameras)} cameras, "
                                    f"the recording's {len(cams)}")
        for c, (got, want) in enumerate(zip(p.cameras, cams)):
            what = "main camera" if c == 0 else f"auxiliary camera {c - 1}"
            if (got.width, got.height) != (want.width, want.height):
                raise InvalidInputError(
                    f"{here}: frame {p.index}'s {what} is {got.width}x{got.height}, the "
                    f"recording's {want.width}x{want.height}")
            # The packet carries the float64 matrices the encoder was given: equal, not close.
            for m in ("view", "proj"):
                if not np.array_equal(getattr(got, m), getattr(want, m)):
                    raise InvalidInputError(
                        f"{here}: frame {p.index}'s {what} has another {m} matrix (a stream "
                        "of another scene, take or scale?)")


def raw_mbps(rec: Recording) -> float:
    """The rate of ``rec``'s server frames uncompressed (every buffer's bytes,
    :func:`~splitrender.client.playback.frame_nbytes`) in Mb/s at its server frame rate, from
    its manifest (no frame is read)."""
    return float(rec.server_nbytes * 8 * rec.fs / 1e6)


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


def network_json(network: NetworkModel) -> dict[str, Any]:
    """The settings of ``network`` for a results file: ``bandwidth_mbps`` (``None``:
    unlimited), ``latency_ms``, ``jitter_ms``, ``loss`` (a fraction), ``seed`` and
    ``extra_delay_frames``."""
    return {
        "bandwidth_mbps": network.bandwidth_mbps,
        "latency_ms": network.latency_ms,
        "jitter_ms": network.jitter_ms,
        "loss": network.loss,
        "seed": network.seed,
        "extra_delay_frames": network.extra_delay_frames,
    }


def play_and_score_eyes(
    frames: Iterable[ServerFrame],
    cameras: Sequence[Sequence[Camera]],
    truth: Sequence[Sequence[_Image]],
    method: str,
    network: NetworkModel,
    fc: float,
    metrics: Sequence[str],
    *,
    frame_sizes: Sequence[int] | None = None,
    bar: Bar | None = None,
    on_frame: Callable[[int, int, _Image, Any], None] | None = None,
    options: ReprojectOptions | None = None,
    backend: str = "cpu",
    flip_every: int = 1,
    keep_images: bool = True,
) -> list[Scored]:
    """Plays ``frames`` with ``method`` through ``network`` at each eye's client cameras
    (``cameras[e]``, ``fc`` FPS) and scores eye ``e``'s client frames against ``truth[e]``
    (first and last ``SKIP_FRAMES`` excluded); one :class:`Scored` per eye (one eye: mono; two:
    stereo, left then right). The same ``frames`` go through the same ``network`` for every
    eye, so the eyes share their schedule. They are iterated once per eye: a list, a
    recording's lazy frames (each read when the client needs it) or a
    :class:`~splitrender.codec.coder.DecodedStream` (each decoded when the client needs it).
    ``on_frame(eye, n, image, info)`` is called for every client frame of every eye.
    ``options`` go to the client (e.g. ``server_fps`` for a server at another rate than 10 FPS);
    ``backend`` is ``"cpu"`` or ``"wgpu"`` (:class:`~splitrender.Client`); ``flip_every`` as in
    :func:`~splitrender.evaluation.metrics.evaluate_sequence`. :func:`mean_row` averages the
    result over the eyes.

    Each client frame is scored as it is made
    (:class:`~splitrender.evaluation.metrics.SequenceScorer`; VMAF's ffmpeg runs beside the
    client) and ``truth[e][n]`` is read when frame ``n`` is made: with ``keep_images=False``
    (the playbacks then hold no images) and a lazy ``truth`` (a recording's frames), the
    memory does not grow with the sequence's length."""
    out = []
    for eye, (eye_cams, eye_truth) in enumerate(zip(cameras, truth)):
        n_client = len(eye_cams)
        with SequenceScorer(n_client, SKIP_FRAMES, metrics, fps=fc,
                            flip_every=flip_every) as scorer:

            def frame_done(n: int, image: _Image, info: Any) -> None:
                scorer.add(image, eye_truth[n])
                if bar is not None:
                    bar(n + 1, n_client, "client frames (played and scored)")
                if on_frame is not None:
                    on_frame(eye, n, image, info)

            res = play(frames, eye_cams, network, fc, method, frame_sizes=frame_sizes,
                       on_frame=frame_done, options=options, backend=backend,
                       keep_images=keep_images)
            _check_shown(res, n_client, fc, network)
            # What VMAF's ffmpeg has still to do once the last frame is given to it.
            vmaf_bar = bar if "vmaf" in metrics else None
            if vmaf_bar is not None:
                vmaf_bar(0, 1, "vmaf (the rest of ffmpeg's work)")
            sm = scorer.finish()
            if vmaf_bar is not None:
                vmaf_bar(1, 1, "vmaf (the rest of ffmpeg's work)")
        out.append(Scored(res, sm))
    return out


def _check_shown(res: PlaybackResult, n_client: int, fc: float, network: NetworkModel) -> None:
    """Raises :class:`InvalidInputError` when no scored client frame had a server frame to show
    (all black): the network model's delay, latency or loss is longer than the session, and
    its scores (SSIM 0.001 with `--delay 40` on 30 frames) would measure nothing of the method."""
    scored = res.info[SKIP_FRAMES:n_client - SKIP_FRAMES]
    if scored and all(i.newer is None for i in scored):
        last = (n_client - SKIP_FRAMES - 1) / fc
        raise InvalidInputError(
            f"no server frame reached the client by its last scored frame ({last:g} s; "
            f"{network_text(network)}): every scored frame would be black; expected a shorter "
            "delay or latency, less loss, or a longer --seconds")


def mean_row(scored: Sequence[Scored]) -> dict[str, Any]:
    """The :meth:`Scored.row` of one or more eyes averaged: each metric's mean over the eyes
    (``None`` when not computed), ``frames`` per eye."""
    return mean_of_eyes([{**s.row(), "mse": s.metrics.mse} for s in scored])


def mean_of_eyes(rows: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """Rows of :meth:`Scored.row` with the key ``mse`` (:attr:`SequenceMetrics.mse`) of one or
    more eyes, averaged: each metric's mean over the eyes (``None`` when not computed) but PSNR,
    the PSNR of the eyes' mean MSE (metrics.py's convention); ``frames`` per eye."""
    out: dict[str, Any] = {}
    for m in ("ssim", "flip", "psnr", "vmaf"):
        vs = [r[m] for r in rows]
        out[m] = None if any(v is None for v in vs) else float(np.mean(vs))
    mses = [r.get("mse") for r in rows]
    if out["psnr"] is not None and all(isinstance(v, float) for v in mses):
        out["psnr"] = psnr_of_mse(float(np.mean([float(v) for v in mses if v is not None])))
    out["frames"] = rows[0]["frames"]
    return out


def network_text(network: NetworkModel) -> str:
    """``network`` in words for a summary: ``"l = 2, ideal link"`` or ``"l = 0, 5 Mb/s, 20 ms
    latency, jitter 0-5 ms, 10 % loss (seed 0)"``."""
    parts = [f"l = {network.extra_delay_frames}"]
    if network.bandwidth_mbps is not None:
        parts.append(f"{network.bandwidth_mbps:g} Mb/s")
    if network.latency_ms:
        parts.append(f"{network.latency_ms:g} ms latency")
    if network.jitter_ms:
        parts.append(f"jitter 0-{network.jitter_ms:g} ms")
    if network.loss:
        parts.append(f"{100 * network.loss:g} % loss")
    if len(parts) == 1:
        return f"{parts[0]}, ideal link (no loss)"
    if network.jitter_ms or network.loss:
        parts[-1] += f" (seed {network.seed})"
    return ", ".join(parts)
