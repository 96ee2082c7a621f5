"""The references the methods are compared with that are not reprojection: FFmpeg's
``minterpolate`` of the server colour video (``video_interp``), the ground truth as one HEVC
video (Figure 6's ``video streaming``), and what a timewarp server streams (the main camera's
colour and depth).

The sweep's score tasks (:mod:`~splitrender.evaluation.sweep_tasks`) run them and
:mod:`~splitrender.evaluation.experiments` plans them; this module sits below both, and its
code is part of the sweep cache's fingerprint (it determines the bytes the tasks score).
"""

from __future__ import annotations

import subprocess
from collections.abc import Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

from splitrender.errors import SplitRenderError

__all__ = ["main_colour_depth", "minterpolate", "video_streaming"]

_Image = npt.NDArray[np.uint8]


def _rate(v: float) -> str:
    from fractions import Fraction

    f = Fraction(v).limit_denominator(1001)
    return f"{f.numerator}/{f.denominator}"


#: The smallest side (pixels) FFmpeg's minterpolate emits frames for: two of its 16-pixel blocks.
_MINTERPOLATE_MIN = 32


def minterpolate(
    frames: Sequence[_Image], fs: float, fc: float, n_out: int
) -> list[_Image]:
    """FFmpeg's motion-compensated interpolation (``minterpolate``, ``mi_mode=mci``,
    ``mc_mode=aobmc``, ``me_mode=bidir``, ``vsbmc=1``, no scene-change fallback) of ``frames``
    (RGB8, frame ``k`` at time ``k / fs``) to ``fc``; returns ``n_out`` frames, frame ``n`` at
    time ``n / fc`` (output ``n`` with ``n·fs/fc`` an integer ``k`` reproduces input ``k`` up to
    the filter's 8-bit YCbCr 4:4:4 round trip). The last frame is repeated once: the filter
    needs a successor to emit the frames up to its time.

    Raises:
        SplitRenderError: when ffmpeg fails or emits fewer than ``n_out`` frames.
    """
    from splitrender.evaluation.metrics import _ffmpeg

    if not frames:
        raise SplitRenderError("minterpolate: no frames")
    h0, w0 = frames[0].shape[:2]
    # The filter emits nothing for a picture under two 16-pixel blocks a side (ffmpeg exits 234
    # "Nothing was written"; e.g. a 26x14 dataset, found by the fuzz suite): smaller frames are
    # padded by repeating their edge and the output cropped back.
    ph, pw = max(0, _MINTERPOLATE_MIN - h0), max(0, _MINTERPOLATE_MIN - w0)
    h, w = h0 + ph, w0 + pw
    data = b"".join(
        np.ascontiguousarray(np.pad(f, ((0, ph), (0, pw), (0, 0)), mode="edge") if ph or pw
                             else f, dtype=np.uint8).tobytes()
        for f in [*frames, frames[-1]]
    )
    cmd = [
        _ffmpeg(), "-nostdin", "-hide_banner", "-loglevel", "error",
        "-f", "rawvideo", "-pix_fmt", "rgb24", "-s", f"{w}x{h}", "-r", _rate(fs), "-i", "-",
        "-vf", (f"format=yuv444p,minterpolate=fps={_rate(fc)}:mi_mode=mci:mc_mode=aobmc"
                ":me_mode=bidir:vsbmc=1:scd=none,format=rgb24"),
        "-f", "rawvideo", "-pix_fmt", "rgb24", "-",
    ]
    proc = subprocess.run(cmd, input=data, capture_output=True, check=False)
    if proc.returncode != 0:
        tail = proc.stderr.decode("utf-8", "replace").strip().splitlines()[-1:] or ["?"]
        raise SplitRenderError(f"minterpolate: ffmpeg exited with status {proc.returncode}: "
                               f"{tail[0]}")
    n = len(proc.stdout) // (w * h * 3)
    if n < n_out:
        raise SplitRenderError(f"minterpolate: ffmpeg emitted {n} frames, expected {n_out}")
    out = np.frombuffer(proc.stdout, np.uint8, count=n_out * h * w * 3).reshape(n_out, h, w, 3)
    return [out[i, :h0, :w0].copy() for i in range(n_out)]


def main_colour_depth(f: Any) -> Any:
    """``f`` reduced to what timewarp streams: the main camera's colour and depth."""
    from splitrender.types import CameraFrame, ServerFrame

    return ServerFrame(f.index, f.time, CameraFrame(f.main.camera, f.main.color, f.main.depth))


def video_streaming(
    truth: Sequence[_Image], mbps: float, fps: float
) -> tuple[list[_Image], float]:
    """``truth`` encoded as one low-latency HEVC video (libx265, 4:2:0, no B-frames) at ``mbps``
    and decoded; returns the decoded frames and the achieved Mb/s."""
    from fractions import Fraction

    import av

    h, w = truth[0].shape[:2]
    pw, ph = max(16, w + (w & 1)), max(16, h + (h & 1))
    kbps = max(2, round(mbps * 1000))
    enc: Any = av.CodecContext.create("libx265", "w")
    enc.width, enc.height, enc.pix_fmt = pw, ph, "yuv420p"
    rate = Fraction(fps).limit_denominator(1001)
    enc.time_base, enc.framerate, enc.bit_rate = 1 / rate, rate, kbps * 1000
    enc.options = {
        "preset": "medium",
        "tune": "zerolatency",
        "x265-params": f"bframes=0:scenecut=0:vbv-maxrate={kbps}:vbv-bufsize={max(1, kbps // 10)}"
        ":pools=1:frame-threads=1:log-level=error:info=0",
    }
    enc.open()
    dec: Any = av.CodecContext.create("hevc", "r")
    out: list[_Image] = []
    nbytes = 0

    def take(packets: Any) -> None:
        nonlocal nbytes
        for p in packets:
            nbytes += p.size
            for f in dec.decode(p):
                out.append(f.to_ndarray(format="rgb24")[:h, :w])

    for n, img in enumerate(truth):
        pad = np.zeros((ph, pw, 3), np.uint8)
        pad[:h, :w] = img
        frame = av.VideoFrame.from_ndarray(pad, format="rgb24").reformat(format="yuv420p")
        frame.pts = n
        take(enc.encode(frame))
    take(enc.encode(None))
    for f in dec.decode(None):
        out.append(f.to_ndarray(format="rgb24")[:h, :w])
    if len(out) != len(truth):
        raise SplitRenderError(f"video streaming: decoded {len(out)} of {len(truth)} frames")
    return out, nbytes * 8 * fps / len(truth) / 1e6
