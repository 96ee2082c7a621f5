"""Image and video quality metrics of the evaluation protocol (shared/DESIGN.md "Evaluation
protocol"; REFERENCE.md §6): SSIM, LDR-FLIP, PSNR and VMAF, per frame and averaged over a
sequence with the first and last ``skip`` client frames excluded.

Images are ``uint8[H, W, 3]`` (divided by 255) or ``float32``/``float64[H, W, 3]`` already in
``[0, 1]`` (no linearisation: they are sRGB-encoded values, as the reference reads its PNGs).
The two images of a comparison must have the same shape and dtype.

Settings, and where they differ from the reference (REFERENCE.md §6):

- **PSNR** ``= min(−10·log10(MSE), 100 dB)``, the MSE over every pixel and channel in ``[0, 1]``.
  The cap :data:`PSNR_CAP_DB` (reached at ``MSE <= 1e-10``, i.e. identical images, or one 8-bit
  level off in a single channel of fewer than ~0.2 % of a 320×180 image's pixels) keeps identical
  frames finite: a client frame equal to its ground truth (a head standing still) used to give
  ``inf``. A sequence's PSNR (:attr:`SequenceMetrics.mean`) follows the field's convention for
  video: the PSNR of the mean MSE over its scored frames (then capped), not the mean of the
  per-frame PSNRs, so one perfect frame cannot dominate it (the reference's plain mean of
  per-frame values is ``inf`` then). Means over stereo eyes likewise average the MSE
  (:attr:`SequenceMetrics.mse`).
- **SSIM** exactly as the reference ("3DGS-style"): an 11×11 Gaussian window with ``σ = 1.5``
  applied per channel with *zero* padding of 5 pixels, ``C1 = 0.01²``, ``C2 = 0.03²``, population
  (not sample) statistics, the mean of the full SSIM map over all pixels and channels.
  scikit-image's ``structural_similarity(gaussian_weights=True, sigma=1.5,
  use_sample_covariance=False, data_range=1)`` computes the same map in the interior but pads by
  reflection and averages only the pixels at least 5 from the border, so it differs slightly; we
  implement the reference's definition (``reproj_core::ssim``, compared in its tests with the
  full 11×11 window pixel by pixel) and the tests check the interiors agree with scikit-image.
- **FLIP**: NVIDIA's ``flip-evaluator`` (the reference uses FLIP's PyTorch port of the same
  algorithm), LDR mode, sRGB inputs clamped to ``[0, 1]``, 67 pixels per degree, the mean of the
  error map. Argument order is ours: ``flip(test, reference)``.
- **VMAF**: libvmaf inside the ffmpeg binary of the ``imageio-ffmpeg`` wheel, its default model
  (``vmaf_v0.6.1``), both sequences at 120 FPS. The reference feeds RGB PNGs and lets ffmpeg
  convert; we feed raw ``rgb24`` (each pair of frames as one picture, cropped apart in the filter
  graph) and convert explicitly with ``format=yuv444p`` (swscale's default BT.601 limited-range
  matrix, the same luma that the implicit conversion produces; VMAF reads luma only). VMAF is computed over the whole sequence (its motion feature needs the preceding
  frame) and then sliced, as the reference does. Identical sequences score 100 on frames with
  motion and ≈ 97.4 where the motion feature is 0 (the first frame, static content).
"""

from __future__ import annotations

import json
import math
import os
import queue
import subprocess
import tempfile
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from splitrender import _native
from splitrender.errors import InvalidInputError, SplitRenderError
from splitrender.types import (  # argument checks
    CALLABLE,
    checked,
    floats,
    ints,
    items,
    optional,
    strs,
)

__all__ = [
    "DEFAULT_METRICS",
    "FLIP_PPD",
    "METRICS",
    "PSNR_CAP_DB",
    "SKIP_FRAMES",
    "VMAF_FPS",
    "VMAF_MIN_SIDE",
    "SequenceMetrics",
    "SequenceScorer",
    "evaluate_sequence",
    "flip",
    "flip_map",
    "psnr",
    "psnr_of_mse",
    "ssim",
    "ssim_map",
    "vmaf",
]

#: Every metric :func:`evaluate_sequence` knows, in table order.
METRICS: tuple[str, ...] = ("ssim", "flip", "psnr", "vmaf")
DEFAULT_METRICS = METRICS
#: Client frames dropped at each end of a sequence (DESIGN.md, REFERENCE.md §6 ``-ff 12 -ft -12``).
SKIP_FRAMES = 12
#: FLIP's pixels per degree: 0.7 m from a 0.7 m wide 3840-pixel display (REFERENCE.md §6).
FLIP_PPD = 67.0
#: Frame rate both VMAF sequences are declared at (REFERENCE.md §6, ``-r 120``).
VMAF_FPS = 120.0
#: Smallest image side accepted by :func:`vmaf`: libvmaf in the imageio-ffmpeg binary crashes
#: (SIGSEGV) at 16 pixels (its four-scale pyramids run out); 32 keeps a margin.
VMAF_MIN_SIDE = 32
#: The highest PSNR reported (dB): the value of identical images (MSE 0), and of any MSE below
#: ``10**(-PSNR_CAP_DB / 10)``.
PSNR_CAP_DB = 100.0


_F64 = npt.NDArray[np.float64]
Progress = Callable[[str, int, int], None]


def _describe(value: object) -> str:
    if isinstance(value, np.ndarray):
        return f"{value.dtype} array of shape {tuple(value.shape)}"
    return type(value).__name__


def _check_image(where: str, img: object) -> npt.NDArray[Any]:
    if not isinstance(img, np.ndarray) or img.ndim != 3 or img.shape[2] != 3:
        raise InvalidInputError(
            f"{where}: expected an (H, W, 3) uint8 or float array, got {_describe(img)}"
        )
    if img.shape[0] < 1 or img.shape[1] < 1:
        raise InvalidInputError(f"{where}: expected a non-empty image, got {_describe(img)}")
    if img.dtype == np.uint8:
        return img
    if img.dtype in (np.float32, np.float64):
        if not np.isfinite(img).all():
            raise InvalidInputError(f"{where}: expected finite values, got NaN or inf")
        lo, hi = float(img.min()), float(img.max())
        if lo < 0.0 or hi > 1.0:
            raise InvalidInputError(
                f"{where}: expected float values in [0, 1], got the range [{lo}, {hi}]"
            )
        return img
    raise InvalidInputError(f"{where}: expected dtype uint8, float32 or float64, got {img.dtype}")


def _pair(a: object, b: object, names: tuple[str, str]) -> tuple[_F64, _F64]:
    """Both images as ``float64`` in ``[0, 1]`` after checking they match."""
    a = _check_image(names[0], a)
    b = _check_image(names[1], b)
    if a.shape != b.shape:
        raise InvalidInputError(
            f"{names[0]} and {names[1]}: expected the same shape, got {tuple(a.shape)} and "
            f"{tuple(b.shape)}"
        )
    if a.dtype != b.dtype:
        raise InvalidInputError(
            f"{names[0]} and {names[1]}: expected the same dtype, got {a.dtype} and {b.dtype}"
        )
    return _unit(a), _unit(b)


def _unit(img: npt.NDArray[Any]) -> _F64:
    """``img`` in ``[0, 1]`` as a C-contiguous float64 array (the SSIM kernel's input, which
    ``astype`` alone does not give for a transposed or strided view)."""
    x = np.ascontiguousarray(img, dtype=np.float64)
    return x / 255.0 if img.dtype == np.uint8 else x


def _to_u8(where: str, img: object) -> npt.NDArray[np.uint8]:
    img = _check_image(where, img)
    if img.dtype == np.uint8:
        return np.ascontiguousarray(img)
    return np.asarray(np.rint(img * 255.0), dtype=np.uint8)


def psnr(a: npt.ArrayLike, b: npt.ArrayLike) -> float:
    """PSNR in dB of two images, ``−10·log10(MSE)`` over all pixels and channels in ``[0, 1]``.

    Capped at :data:`PSNR_CAP_DB` (identical images give 100, not ``inf``).

    Raises:
        InvalidInputError: unless both are ``(H, W, 3)`` images of the same shape and dtype.
    """
    return psnr_of_mse(_mse(a, b))


def _mse(a: npt.ArrayLike, b: npt.ArrayLike) -> float:
    x, y = _pair(a, b, ("a", "b"))
    return float(np.mean((x - y) ** 2))


@checked(mse=floats(lo=0.0))
def psnr_of_mse(mse: float) -> float:
    """``min(−10·log10(mse), PSNR_CAP_DB)`` for a mean squared error of values in ``[0, 1]``."""
    if mse <= 10.0 ** (-PSNR_CAP_DB / 10.0):
        return PSNR_CAP_DB
    return min(PSNR_CAP_DB, -10.0 * math.log10(mse))


def ssim_map(a: npt.ArrayLike, b: npt.ArrayLike) -> _F64:
    """The per-pixel, per-channel SSIM map (``float64[H, W, 3]``) whose mean is :func:`ssim`."""
    x, y = _pair(a, b, ("a", "b"))
    _, out = _native.ssim(x, y, True)
    assert out is not None
    return out


def ssim(a: npt.ArrayLike, b: npt.ArrayLike) -> float:
    """SSIM of two images as REFERENCE.md §6 defines it (see the module docs): 11×11 Gaussian,
    ``σ = 1.5``, zero padding, ``C1 = 0.01²``, ``C2 = 0.03²``, the mean of the map. Symmetric;
    1.0 for identical images.

    Raises:
        InvalidInputError: unless both are ``(H, W, 3)`` images of the same shape and dtype.
    """
    x, y = _pair(a, b, ("a", "b"))
    return _native.ssim(x, y)[0]


def _flip(test: object, reference: object, ppd: float) -> tuple[npt.NDArray[np.float32], float]:
    import flip_evaluator  # type: ignore[import-untyped,unused-ignore]

    t, r = _pair(test, reference, ("test", "reference"))
    # flip_evaluator takes (reference, test); it exits the process on bad arguments, so every
    # argument is checked first (the images above, ppd by flip's and flip_map's @checked).
    # float32 is its native precision.
    err, mean, _ = flip_evaluator.evaluate(
        np.ascontiguousarray(r, dtype=np.float32),
        np.ascontiguousarray(t, dtype=np.float32),
        "LDR",
        inputsRGB=True,
        applyMagma=False,
        computeMeanError=True,
        parameters={"ppd": float(ppd)},
    )
    return np.asarray(err[..., 0], dtype=np.float32), float(mean)


@checked(ppd=floats(positive=True))
def flip(test: npt.ArrayLike, reference: npt.ArrayLike, ppd: float = FLIP_PPD) -> float:
    """Mean LDR-FLIP error (``0`` = identical, up to 1) of ``test`` against ``reference``,
    both sRGB in ``[0, 1]``, at ``ppd`` pixels per degree.

    Raises:
        InvalidInputError: unless both are ``(H, W, 3)`` images of the same shape and dtype, or
            for ``ppd <= 0``.
    """
    return _flip(test, reference, ppd)[1]


@checked(ppd=floats(positive=True))
def flip_map(
    test: npt.ArrayLike, reference: npt.ArrayLike, ppd: float = FLIP_PPD
) -> npt.NDArray[np.float32]:
    """The LDR-FLIP error map (``float32[H, W]`` in ``[0, 1]``) for visualisation; its mean is
    :func:`flip`."""
    return _flip(test, reference, ppd)[0]


def _check_sequence(where: str, frames: object) -> list[npt.NDArray[np.uint8]]:
    if isinstance(frames, np.ndarray) and frames.ndim == 4:
        frames = list(frames)
    if not isinstance(frames, Sequence) or isinstance(frames, (str, bytes)):
        raise InvalidInputError(
            f"{where}: expected a sequence of (H, W, 3) images, got {_describe(frames)}"
        )
    if len(frames) == 0:
        raise InvalidInputError(f"{where}: expected at least one frame, got none")
    out = [_to_u8(f"{where}[{i}]", f) for i, f in enumerate(frames)]
    shape = out[0].shape
    for i, f in enumerate(out):
        if f.shape != shape:
            raise InvalidInputError(
                f"{where}[{i}]: expected the shape of frame 0, {tuple(shape)}, got {tuple(f.shape)}"
            )
    return out


def _ffmpeg() -> str:
    try:
        import imageio_ffmpeg  # type: ignore[import-untyped,unused-ignore]
    except ImportError:
        raise SplitRenderError(
            "vmaf needs the imageio-ffmpeg wheel (pip install imageio-ffmpeg)"
        ) from None
    return str(imageio_ffmpeg.get_ffmpeg_exe())


@checked(fps=floats(positive=True, hi=1000.0), threads=optional(ints(1, 1024)))
def vmaf(
    distorted: Sequence[npt.ArrayLike] | npt.ArrayLike,
    reference: Sequence[npt.ArrayLike] | npt.ArrayLike,
    fps: float = VMAF_FPS,
    *,
    threads: int | None = None,
) -> list[float]:
    """Per-frame VMAF (0–100, default model) of ``distorted`` against ``reference``, two equally
    long sequences of equally sized ``(H, W, 3)`` images (a list, or one ``(N, H, W, 3)`` array),
    each side at least :data:`VMAF_MIN_SIDE` pixels.

    Raises:
        InvalidInputError: for mismatched or invalid sequences.
        SplitRenderError: when ffmpeg or its libvmaf filter fails (the message holds ffmpeg's
            last output).
    """
    d = _check_sequence("distorted", distorted)
    r = _check_sequence("reference", reference)
    if len(d) != len(r):
        raise InvalidInputError(
            f"distorted and reference: expected the same number of frames, got {len(d)} and "
            f"{len(r)}"
        )
    if d[0].shape != r[0].shape:
        raise InvalidInputError(
            f"distorted and reference: expected the same frame shape, got {tuple(d[0].shape)} "
            f"and {tuple(r[0].shape)}"
        )
    h, w = d[0].shape[:2]
    if min(h, w) < VMAF_MIN_SIDE:
        raise InvalidInputError(
            f"vmaf: expected frames of at least {VMAF_MIN_SIDE}x{VMAF_MIN_SIDE} pixels, got {w}x{h}"
        )
    stream = _VmafStream(w, h, fps, threads)
    try:
        for a, b in zip(d, r):
            stream.add(a, b)
        return stream.finish()
    finally:
        stream.close()


#: Frames :class:`_VmafStream` may hold while ffmpeg has not read them: enough for a producer
#: that is sometimes faster than libvmaf, few enough to bound the memory.
_VMAF_QUEUE = 8


class _VmafStream:
    """libvmaf (ffmpeg) over frames given one pair at a time, as they are made: a sequence is
    never held whole (2.8 MB per 1280×720 frame and side; 11 MB at 2560×1440).

    Each pair goes to ffmpeg as *one* raw picture, the distorted frame above the reference, and
    the filter graph crops the two apart: with two inputs, ffmpeg reads the first while it
    starts (its probe reads ahead, up to megabytes) before it opens the second, and a producer
    that feeds both in step waits for it forever. The crops give libvmaf the same pixels as two
    inputs would. On POSIX the input is a FIFO fed by a thread from a short queue
    (:data:`_VMAF_QUEUE`); elsewhere the pictures go to a file and ffmpeg runs at
    :meth:`finish`. :meth:`close` always ends ffmpeg and the thread (after a failure, too)."""

    def __init__(self, w: int, h: int, fps: float, threads: int | None) -> None:
        self._w, self._h, self._n = w, h, 0
        self._tmp = tempfile.TemporaryDirectory(prefix="splitrender-vmaf-")
        tmp = self._tmp.name
        self._log = os.path.join(tmp, "vmaf.json")
        self._err = os.path.join(tmp, "ffmpeg.txt")
        self._path = os.path.join(tmp, "pairs.rgb")
        n_threads = threads if threads is not None else (os.cpu_count() or 1)
        # The log path sits in a directory we created; ':' and '\' would need filter escaping.
        # libvmaf: its first input is the distorted frame, its second the reference.
        graph = (
            f"[0:v]split[top][bottom];[top]crop={w}:{h}:0:0,format=yuv444p[d];"
            f"[bottom]crop={w}:{h}:0:{h},format=yuv444p[r];"
            f"[d][r]libvmaf=log_fmt=json:log_path={_filter_escape(self._log)}:n_threads={n_threads}"
        )
        self._cmd = [
            _ffmpeg(), "-hide_banner", "-nostdin", "-v", "error",
            "-f", "rawvideo", "-pix_fmt", "rgb24", "-s", f"{w}x{2 * h}", "-r", f"{fps}",
            "-i", self._path, "-lavfi", graph, "-f", "null", "-",
        ]
        self._proc: subprocess.Popen[bytes] | None = None
        self._queue: queue.Queue[bytes | None] | None = None
        self._writer: threading.Thread | None = None
        self._file: Any = None
        if hasattr(os, "mkfifo"):
            os.mkfifo(self._path)
            self._queue = queue.Queue(maxsize=_VMAF_QUEUE)
            self._writer = threading.Thread(target=self._feed, args=(self._path, self._queue),
                                            daemon=True)
            self._writer.start()
            self._proc = self._start()
        else:
            self._file = open(self._path, "wb")  # noqa: SIM115

    def _start(self) -> subprocess.Popen[bytes]:
        with open(self._err, "wb") as err:  # ffmpeg's messages, for the error below
            return subprocess.Popen(self._cmd, stdin=subprocess.DEVNULL,
                                    stdout=subprocess.DEVNULL, stderr=err)

    @staticmethod
    def _feed(path: str, q: queue.Queue[bytes | None]) -> None:
        """Writes the queue's pictures into the FIFO until ``None``; once ffmpeg stops reading,
        the rest of the queue is taken and dropped, so that the producer never blocks."""
        out = None
        try:
            out = open(path, "wb")  # noqa: SIM115 (blocks until ffmpeg opens its end)
            while (data := q.get()) is not None:
                out.write(data)
        except OSError:  # ffmpeg stopped reading (BrokenPipeError; its status says why)
            while q.get() is not None:
                pass
        finally:
            if out is not None:
                try:
                    out.close()
                except OSError:
                    pass

    def add(self, distorted: npt.NDArray[np.uint8], reference: npt.NDArray[np.uint8]) -> None:
        """The next frame of both sequences (``uint8[h, w, 3]``; copied, so the caller may
        reuse its arrays)."""
        pair = np.concatenate((distorted, reference), axis=0).tobytes()
        if self._queue is not None:
            self._put(pair)
        else:
            self._file.write(pair)
        self._n += 1

    def _release(self) -> None:
        """Opens and closes the FIFO's read end: a writer still waiting for ffmpeg to open it
        (ffmpeg failed first) gets its open back, and its next write fails."""
        fd = os.open(self._path, os.O_RDONLY | os.O_NONBLOCK)
        os.close(fd)

    def _put(self, item: bytes | None) -> None:
        """Queues ``item``; should ffmpeg have exited (it failed; :meth:`finish` says why) with
        the queue full, the writer is released (:meth:`_release`) and drops what it gets."""
        assert self._queue is not None
        while True:
            try:
                self._queue.put(item, timeout=0.25)
                return
            except queue.Full:
                if self._proc is not None and self._proc.poll() is not None:
                    self._release()

    def _end_input(self) -> None:
        if self._queue is not None and self._writer is not None:
            self._put(None)
            self._writer.join(timeout=0.5)
            while self._writer.is_alive():
                # Released only once ffmpeg has exited: while it runs, a writer still waiting in
                # its open (ffmpeg slow to start on a loaded machine) is waiting for ffmpeg's
                # open, and releasing it would make it write into a FIFO nobody reads yet, fail
                # and leave ffmpeg waiting for a writer forever.
                if self._proc is None or self._proc.poll() is not None:
                    self._release()
                self._writer.join(timeout=0.5)
        self._queue = self._writer = None
        if self._file is not None:
            self._file.close()
            self._file = None

    def finish(self) -> list[float]:
        """Ends the input, waits for ffmpeg and returns the per-frame scores.

        Raises :class:`SplitRenderError` when ffmpeg fails or its log lacks frames."""
        self._end_input()
        if self._proc is None:
            self._proc = self._start()
        status = self._proc.wait()
        if status != 0 or not os.path.exists(self._log):
            with open(self._err, encoding="utf-8", errors="replace") as f:
                tail = f.read().strip()[-800:]
            raise SplitRenderError(
                f"vmaf: ffmpeg exited with status {status} on {self._n} frames of "
                f"{self._w}x{self._h}: {tail or '(no output)'}"
            )
        with open(self._log, encoding="utf-8") as f:
            data = json.load(f)
        frames = data.get("frames", [])
        if len(frames) != self._n:
            raise SplitRenderError(
                f"vmaf: expected {self._n} frames in libvmaf's log, got {len(frames)}"
            )
        frames = sorted(frames, key=lambda fr: int(fr["frameNum"]))
        return [float(fr["metrics"]["vmaf"]) for fr in frames]

    def close(self) -> None:
        """Stops ffmpeg (if still running) and the feeding thread, and removes the files."""
        if self._proc is not None and self._proc.poll() is None:
            self._proc.kill()
        self._end_input()
        if self._proc is not None:
            self._proc.wait()
        self._tmp.cleanup()


def _filter_escape(path: str) -> str:
    return path.replace("\\", "\\\\").replace(":", "\\:").replace("'", "\\'")


@dataclass
class SequenceMetrics:
    """The metrics of one rendered sequence against ground truth.

    ``frames`` are the indices of the evaluated frames (the first and last ``skip`` excluded);
    ``per_frame[i]`` maps each metric to its value for frame ``frames[i]``; ``mean`` is the plain
    arithmetic mean of each metric over those frames, but for PSNR: the PSNR of ``mse``, the
    mean squared error over those frames (see the module docstring)."""

    frames: list[int]
    per_frame: list[dict[str, float]]
    mean: dict[str, float] = field(default_factory=dict)
    #: The mean over the frames of each frame's MSE (``None`` when PSNR was not computed).
    mse: float | None = None

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready dict (a non-finite value, which no metric gives, would become a string
        such as ``"inf"``, not invalid JSON)."""

        def enc(v: float) -> float | str:
            return v if math.isfinite(v) else str(v)

        return {
            "frames": list(self.frames),
            "per_frame": [{k: enc(v) for k, v in d.items()} for d in self.per_frame],
            "mean": {k: enc(v) for k, v in self.mean.items()},
        }


#: The argument checks that :func:`evaluate_sequence` and :class:`SequenceScorer` share.
_SEQUENCE_CHECKS = dict(
    skip=ints(0, (1 << 31) - 1), metrics=items(strs()), fps=floats(positive=True),
    ppd=floats(positive=True), progress=optional(CALLABLE), flip_every=ints(1, 1 << 20),
)


@checked(**_SEQUENCE_CHECKS)
def evaluate_sequence(
    rendered: Sequence[npt.ArrayLike],
    truth: Sequence[npt.ArrayLike],
    skip: int = SKIP_FRAMES,
    metrics: Sequence[str] = DEFAULT_METRICS,
    *,
    fps: float = VMAF_FPS,
    ppd: float = FLIP_PPD,
    progress: Progress | None = None,
    flip_every: int = 1,
) -> SequenceMetrics:
    """Every metric in ``metrics`` for each client frame of ``rendered`` against ``truth`` (the
    ground truth at the client pose), excluding the first and last ``skip`` frames, and the
    means. ``progress(stage, done, total)`` is called after each frame of each metric (see
    :meth:`splitrender.progress.Progress.bar`).

    FLIP costs about 2 s of CPU per 1280×720 frame (``flip-evaluator``), 15× SSIM: with
    ``flip_every = N`` it is computed on every N-th scored frame only (the first, then every
    N-th; the other rows have no ``"flip"``) and its mean is over those. Choose N coprime with
    the client frames per server frame (12 at 120/10 FPS; e.g. 5 or 7), so that the sampled
    frames go through every phase of a server-frame pair instead of always the same α.

    Raises:
        InvalidInputError: for unknown metrics, sequences of different lengths or shapes, or
            fewer than ``2·skip + 1`` frames.
        SplitRenderError: when VMAF's ffmpeg fails.
    """
    r = _check_sequence("rendered", rendered)
    g = _check_sequence("truth", truth)
    if len(r) != len(g):
        raise InvalidInputError(
            f"rendered and truth: expected the same number of frames, got {len(r)} and {len(g)}"
        )
    if r[0].shape != g[0].shape:
        raise InvalidInputError(
            f"rendered and truth: expected the same frame shape, got {tuple(r[0].shape)} and "
            f"{tuple(g[0].shape)}"
        )
    with SequenceScorer(len(r), skip, metrics, fps=fps, ppd=ppd, progress=progress,
                        flip_every=flip_every) as scorer:
        for a, b in zip(r, g):
            scorer.add(a, b)
        return scorer.finish()


class SequenceScorer:
    """:func:`evaluate_sequence` one frame at a time, as a client makes them: ``add(rendered,
    truth)`` for each of the ``n`` frames in order, then :meth:`finish` gives the same
    :class:`SequenceMetrics`, value for value. Only the frame in hand is kept (and a few
    in flight to VMAF's ffmpeg, which runs beside the caller), so a long 1280×720 or 2560×1440
    sequence need not be held whole: that was 1 GB per sequence and eye at 1280×720, 3 s.

    Use it as a context manager (or call :meth:`close`): leaving ends ffmpeg also when a frame
    failed. The arguments are :func:`evaluate_sequence`'s; ``progress(metric, done, total)``
    is called after each frame's metric, and once with ``("vmaf", 1, 1)`` at the end.

    Raises:
        InvalidInputError: for unknown metrics, ``n <= 2·skip``, a frame that is not an image,
            or one whose shape is not the first frame's; from :meth:`finish`, for fewer or more
            than ``n`` frames.
        SplitRenderError: when VMAF's ffmpeg fails (from :meth:`finish`).
    """

    @checked(n=ints(1, (1 << 31) - 1), **_SEQUENCE_CHECKS)
    def __init__(
        self,
        n: int,
        skip: int = SKIP_FRAMES,
        metrics: Sequence[str] = DEFAULT_METRICS,
        *,
        fps: float = VMAF_FPS,
        ppd: float = FLIP_PPD,
        progress: Progress | None = None,
        flip_every: int = 1,
    ) -> None:
        unknown = [m for m in metrics if m not in METRICS]
        if unknown or not metrics:
            raise InvalidInputError(
                f"metrics: expected a non-empty subset of {', '.join(METRICS)}, got "
                f"{list(metrics)!r}"
            )
        if n <= 2 * skip:
            raise InvalidInputError(
                f"rendered: expected more than 2*skip = {2 * skip} frames, got {n}"
            )
        self._n, self._skip, self._fps, self._ppd = n, skip, fps, ppd
        self._progress, self._flip_every = progress, flip_every
        self._ordered = [m for m in METRICS if m in metrics]
        self._kept = list(range(skip, n - skip))
        self._per_frame: list[dict[str, float]] = [{} for _ in self._kept]
        self._done = dict.fromkeys(self._ordered, 0)
        self._mses: list[float] = []
        self._count = 0
        self._shape: tuple[int, ...] | None = None
        self._vmaf: _VmafStream | None = None

    def __enter__(self) -> SequenceScorer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _total(self, m: str) -> int:
        if m == "flip":
            return len(range(0, len(self._kept), self._flip_every))
        return len(self._kept)

    def add(self, rendered: npt.ArrayLike, truth: npt.ArrayLike) -> None:
        """Scores the next frame (``(H, W, 3)`` images as :func:`evaluate_sequence` takes)."""
        i = self._count
        if i >= self._n:
            raise InvalidInputError(f"rendered: expected {self._n} frames, got more")
        a = _to_u8(f"rendered[{i}]", rendered)
        b = _to_u8(f"truth[{i}]", truth)
        if a.shape != b.shape:
            raise InvalidInputError(
                f"rendered[{i}] and truth[{i}]: expected the same frame shape, got "
                f"{tuple(a.shape)} and {tuple(b.shape)}"
            )
        if self._shape is None:
            self._shape = a.shape
            if "vmaf" in self._ordered:
                h, w = a.shape[:2]
                if min(h, w) < VMAF_MIN_SIDE:
                    raise InvalidInputError(
                        f"vmaf: expected frames of at least {VMAF_MIN_SIDE}x{VMAF_MIN_SIDE} "
                        f"pixels, got {w}x{h}"
                    )
                self._vmaf = _VmafStream(w, h, self._fps, None)
        elif a.shape != self._shape:
            raise InvalidInputError(
                f"rendered[{i}]: expected the shape of frame 0, {tuple(self._shape)}, got "
                f"{tuple(a.shape)}"
            )
        self._count += 1
        if self._vmaf is not None:  # every frame: the motion feature needs context
            self._vmaf.add(a, b)
        j = i - self._skip
        if not 0 <= j < len(self._kept):
            return
        row = self._per_frame[j]
        for m in self._ordered:
            if m == "vmaf" or (m == "flip" and j % self._flip_every):
                continue
            if m == "ssim":
                row[m] = ssim(a, b)
            elif m == "flip":
                row[m] = flip(a, b, self._ppd)
            else:
                self._mses.append(_mse(a, b))
                row[m] = psnr_of_mse(self._mses[-1])
            self._done[m] += 1
            if self._progress is not None:
                self._progress(m, self._done[m], self._total(m))

    def finish(self) -> SequenceMetrics:
        """The metrics of the ``n`` frames added (VMAF's ffmpeg is waited for here)."""
        if self._count != self._n:
            raise InvalidInputError(f"rendered: expected {self._n} frames, got {self._count}")
        if self._vmaf is not None:
            scores = self._vmaf.finish()
            for row, i in zip(self._per_frame, self._kept):
                row["vmaf"] = scores[i]
            if self._progress is not None:
                self._progress("vmaf", 1, 1)
        per_frame = self._per_frame
        mean = {m: float(np.mean([row[m] for row in per_frame if m in row]))
                for m in self._ordered}
        mse = float(np.mean(self._mses)) if self._mses else None
        if mse is not None:
            mean["psnr"] = psnr_of_mse(mse)
        return SequenceMetrics(frames=list(self._kept), per_frame=per_frame, mean=mean, mse=mse)

    def close(self) -> None:
        """Ends VMAF's ffmpeg and its threads if they still run (after a failure)."""
        if self._vmaf is not None:
            self._vmaf.close()
            self._vmaf = None
