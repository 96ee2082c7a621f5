"""Compression of server frames (seeds/000 §3.4, §4.1; DESIGN.md "Wire format and codecs").

:class:`StreamEncoder` turns each :class:`~splitrender.types.ServerFrame` into one packet
(:mod:`splitrender.codec.stream`); :class:`StreamDecoder` turns packets back into the same dataclasses
the client consumes. Per camera, these buffers travel (a frame is the older one of one pair and the
newer one of the next, so the client needs both directions of every frame):

=====================  ==========================================================================
colour                 HEVC 8-bit (libx265), YCbCr BT.709 full range, 4:4:4 (default) or 4:2:0
depth                  linear 12-bit codes (per-frame min/max in the packet), HEVC ``gray12le``
motion_fwd/_bwd        linear 12-bit codes per channel, HEVC ``yuv444p12le`` (x, y, z in Y, Cb,
                       Cr); the per-channel scale/offset travel in the packet, and 0 is an exact
                       code (``offset = -z0 * scale``), so a code of ``z0`` decodes to 0.0
motion_*.static        lossless mask (zstd) of the pixels whose motion is exactly 0: they decode
                       to exactly 0 whatever the lossy codec did nearby
depth/motion .invalid  lossless mask (zstd) of NaN/inf pixels (only when there are any): they decode
                       to NaN, so invalid stays invalid (DESIGN.md)
shadow_*.bits          bit-exact: zstd level 10 of a bit-packed occupancy mask and the non-zero
                       bitfields only (0 = no dynamic shadow, the DESIGN.md sentinel); every bit of
                       the uint32 is kept, so up to 16 subframes survive (the reference code keeps 8)
shadow_*.s_min/_max    HEVC 8-bit like colour, zeroed where the bitfield is 0 (never read there)
=====================  ==========================================================================

Rate control: every HEVC stream is its own libx265 encoder, kept open across frames: zero-latency
tuning, no B-frames, ABR to a per-stream target with a VBV buffer of ``vbv_buffer_s`` seconds
(``vbv-maxrate`` = target). The total target is split main 60 % / auxiliary 20 % each; within a
camera, after the lossless parts (shadow bits, masks, headers; measured, not assumed), colour
50 %, depth 20 %, motion 20 % (half per direction), shadow colours 10 % (a quarter each), all
configurable. At every key frame the targets are recomputed from the lossless bytes, the
achieved rate of the last GOP and the shortfall of the whole stream so far (a bounded gain),
because sparse buffers such as shadow colours cannot use their share and x265's ABR drifts over
short sequences.

Random access: every ``gop`` frames a key frame forces an IDR with the parameter sets in every
HEVC stream; a :class:`StreamDecoder` can start at any key frame.

Where this differs from the reference code on purpose (REFERENCE.md §5, §8): shadow bitfields keep
all 32 bits (the reference keeps only the blue channel, losing subframes beyond 4); no morphological
opening of the shadow mask (lossless means lossless); no zeroing of |v| < 1e-4 (exact zeros are kept
by the static mask instead); the same rate mode for every buffer (the vbr CRF bug does not arise:
each stream has its own target); the depth/motion codes are taken straight from float32 (a detour
through half floats would only add error once 12 bits are taken).
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from fractions import Fraction
from typing import TYPE_CHECKING, Any

import av
import numpy as np
import numpy.typing as npt
import zstandard

from splitrender.codec.stream import (
    KIND_CHANNELS,
    MAX_PIXELS,
    BufferEntry,
    BufferKind,
    CameraRecord,
    Codec,
    Packet,
    buffer_name,
    pack_packet,
    unpack_packet,
)
from splitrender.errors import InvalidInputError, StreamError
from splitrender.types import (
    Camera,
    CameraFrame,
    ServerFrame,
    ShadowBuffers,
    check_server_frame,
)

if TYPE_CHECKING:
    from typing_extensions import Self  # annotations only (Python 3.10)

__all__ = ["CodecConfig", "StreamDecoder", "StreamEncoder"]

_K = BufferKind
_CODE_MAX = 4095  # 12 bits

#: Lossy kinds, their stream group (for the buffer shares) and the fraction of the group.
_GROUP: dict[BufferKind, tuple[str, float]] = {
    _K.COLOR: ("color", 1.0),
    _K.DEPTH: ("depth", 1.0),
    _K.MOTION_FWD: ("motion", 0.5),
    _K.MOTION_BWD: ("motion", 0.5),
    _K.SHADOW_FWD_MIN: ("shadow_color", 0.25),
    _K.SHADOW_FWD_MAX: ("shadow_color", 0.25),
    _K.SHADOW_BWD_MIN: ("shadow_color", 0.25),
    _K.SHADOW_BWD_MAX: ("shadow_color", 0.25),
}
_COLOR_KINDS = (
    _K.COLOR,
    _K.SHADOW_FWD_MIN,
    _K.SHADOW_FWD_MAX,
    _K.SHADOW_BWD_MIN,
    _K.SHADOW_BWD_MAX,
)
_MOTION = {
    "fwd": (_K.MOTION_FWD, _K.MOTION_FWD_STATIC, _K.MOTION_FWD_INVALID),
    "bwd": (_K.MOTION_BWD, _K.MOTION_BWD_STATIC, _K.MOTION_BWD_INVALID),
}
_SHADOW = {
    "fwd": (_K.SHADOW_FWD_BITS, _K.SHADOW_FWD_MIN, _K.SHADOW_FWD_MAX),
    "bwd": (_K.SHADOW_BWD_BITS, _K.SHADOW_BWD_MIN, _K.SHADOW_BWD_MAX),
}


@dataclass(frozen=True, slots=True)
class CodecConfig:
    """Settings of a :class:`StreamEncoder` (the decoder needs none: the packets say it all).

    ``bitrate_mbps`` is the target of the whole stream (all cameras, all buffers, headers) at
    ``fps`` server frames per second; DESIGN.md scales it with the pixel count (the paper's
    40 Mb/s at 2560x1440 is 10 Mb/s at 1280x720, see :meth:`scaled`)."""

    bitrate_mbps: float = 10.0
    camera_shares: tuple[float, ...] = (0.6, 0.2, 0.2)
    color_share: float = 0.5
    depth_share: float = 0.2
    motion_share: float = 0.2
    shadow_color_share: float = 0.1
    chroma: str = "444"
    preset: str = "superfast"
    fps: float = 10.0
    gop: int = 10
    vbv_buffer_s: float = 0.3
    uncompressed: bool = False
    zstd_level: int = 10
    exact_static_motion: bool = True
    rate_feedback: bool = True
    threads: int = 0

    def __post_init__(self) -> None:
        for name in ("bitrate_mbps", "fps", "vbv_buffer_s"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise InvalidInputError(
                    f"CodecConfig.{name}: expected a finite value > 0, got {v!r}"
                )
        shares = (
            self.color_share,
            self.depth_share,
            self.motion_share,
            self.shadow_color_share,
        )
        if (
            any(not (math.isfinite(s) and s >= 0) for s in shares)
            or abs(sum(shares) - 1) > 1e-6
        ):
            raise InvalidInputError(
                f"CodecConfig: buffer shares must be >= 0 and sum to 1, got {shares}"
            )
        cs = tuple(float(s) for s in self.camera_shares)
        if (
            not cs
            or any(not (math.isfinite(s) and s > 0) for s in cs)
            or abs(sum(cs) - 1) > 1e-6
        ):
            raise InvalidInputError(
                f"CodecConfig.camera_shares: expected values > 0 summing to 1, got {cs}"
            )
        object.__setattr__(self, "camera_shares", cs)
        if self.chroma not in ("444", "420"):
            raise InvalidInputError(
                f"CodecConfig.chroma: expected '444' or '420', got {self.chroma!r}"
            )
        if not (isinstance(self.gop, int) and 1 <= self.gop <= 100000):
            raise InvalidInputError(
                f"CodecConfig.gop: expected an int in [1, 100000], got {self.gop!r}"
            )
        if not (isinstance(self.zstd_level, int) and 1 <= self.zstd_level <= 22):
            raise InvalidInputError(
                f"CodecConfig.zstd_level: expected 1..22, got {self.zstd_level!r}"
            )
        if not (isinstance(self.threads, int) and self.threads >= 0):
            raise InvalidInputError(
                f"CodecConfig.threads: expected an int >= 0, got {self.threads!r}"
            )

    @classmethod
    def scaled(
        cls, width: int, height: int, paper_mbps: float = 40.0, **kwargs: Any
    ) -> CodecConfig:
        """A config whose bitrate is ``paper_mbps`` (given for the paper's 2560x1440 main camera)
        scaled to a ``width x height`` main camera by pixel count."""
        return cls(bitrate_mbps=paper_mbps * width * height / (2560 * 1440), **kwargs)

    def shares(self) -> dict[str, float]:
        return {
            "color": self.color_share,
            "depth": self.depth_share,
            "motion": self.motion_share,
            "shadow_color": self.shadow_color_share,
        }


def _padded(w: int, h: int) -> tuple[int, int]:
    """The coded size: even (4:2:0) and at least 16 (libx265's minimum)."""
    return max(16, w + (w & 1)), max(16, h + (h & 1))


def _pad(a: npt.NDArray[Any], w: int, h: int) -> npt.NDArray[Any]:
    pw, ph = _padded(w, h)
    if (pw, ph) == (w, h):
        return a
    widths = [(0, ph - h), (0, pw - w)] + [(0, 0)] * (a.ndim - 2)
    return np.pad(a, widths, mode="edge")


def _hevc_format(kind: BufferKind, chroma: str) -> str:
    if kind in _COLOR_KINDS:
        return "yuv444p" if chroma == "444" else "yuv420p"
    return "gray12le" if kind == _K.DEPTH else "yuv444p12le"


_DECODED_FORMATS: dict[BufferKind, tuple[str, ...]] = {
    # full-range 8-bit pictures come back as the (deprecated) "j" formats for 4:2:0
    **{k: ("yuv444p", "yuv420p", "yuvj444p", "yuvj420p") for k in _COLOR_KINDS},
    _K.DEPTH: ("gray12le",),
    _K.MOTION_FWD: ("yuv444p12le",),
    _K.MOTION_BWD: ("yuv444p12le",),
}


class _HevcStream:
    """One libx265 encoder, kept open across frames, reopened when its target changes."""

    def __init__(self, kind: BufferKind, w: int, h: int, cfg: CodecConfig) -> None:
        self.kind, self.w, self.h, self.cfg = kind, w, h, cfg
        self.fmt = _hevc_format(kind, cfg.chroma)
        self.ctx: Any = None
        self.target_bps = 0.0
        self.pts = 0
        self.need_idr = True
        self.bits_since_update = 0

    def open(self, target_bps: float) -> None:
        kbps = max(2, round(target_bps / 1000))
        buf = max(1, round(kbps * self.cfg.vbv_buffer_s))
        pw, ph = _padded(self.w, self.h)
        ctx = av.CodecContext.create("libx265", "w")
        ctx.width, ctx.height, ctx.pix_fmt = pw, ph, self.fmt
        fps = Fraction(self.cfg.fps).limit_denominator(1001)
        ctx.time_base = 1 / fps
        ctx.framerate = fps
        ctx.bit_rate = kbps * 1000
        params = [
            "bframes=0",
            "keyint=-1",  # infinite: key frames are forced (IDR) by the encoder's GOP
            "scenecut=0",
            "open-gop=0",
            "repeat-headers=1",
            f"vbv-maxrate={kbps}",
            f"vbv-bufsize={buf}",
            "range=full",
            "pools=1",
            "frame-threads=1",
            "log-level=error",
            "info=0",  # no SEI with the encoder settings (about 2 kB per stream start)
        ]
        if self.kind in _COLOR_KINDS:
            params += ["colorprim=bt709", "transfer=bt709", "colormatrix=bt709"]
        ctx.options = {
            "preset": self.cfg.preset,
            "tune": "zerolatency",
            "forced-idr": "1",
            "x265-params": ":".join(params),
        }
        ctx.open()
        self.ctx = ctx
        self.target_bps = kbps * 1000.0
        self.need_idr = True

    def encode(
        self, planes: list[npt.NDArray[Any]] | npt.NDArray[np.uint8], key: bool
    ) -> bytes:
        pw, ph = _padded(self.w, self.h)
        if self.kind in _COLOR_KINDS:
            rgb = _pad(planes, self.w, self.h)  # type: ignore[arg-type]
            frame = av.VideoFrame.from_ndarray(
                np.ascontiguousarray(rgb), format="rgb24"
            )
            frame = frame.reformat(
                format=self.fmt,
                dst_colorspace="ITU709",
                dst_color_range="JPEG",
                interpolation="BICUBIC",
            )
        else:
            frame = av.VideoFrame(pw, ph, self.fmt)
            for plane, src in zip(frame.planes, planes):
                _fill_plane(plane, _pad(src, self.w, self.h))
        frame.pts = self.pts
        self.pts += 1
        if key or self.need_idr:
            frame.pict_type = av.video.frame.PictureType.I
            self.need_idr = False
        out = b"".join(bytes(p) for p in self.ctx.encode(frame))
        self.bits_since_update += 8 * len(out)
        return out


def _fill_plane(plane: Any, a: npt.NDArray[np.uint16]) -> None:
    """Copies ``a`` into a frame plane honouring its line stride."""
    h, w = a.shape
    itemsize = a.dtype.itemsize
    if plane.line_size == w * itemsize:
        plane.update(np.ascontiguousarray(a))
        return
    buf = np.frombuffer(plane, dtype=a.dtype).reshape(h, plane.line_size // itemsize)
    buf[:, :w] = a


def _dequantise(
    q: npt.NDArray[np.uint16], scale: float, offset: float
) -> npt.NDArray[np.float32]:
    """``q * scale + offset`` in float32 (scale and offset are float32 values on the wire)."""
    out = q.astype(np.float32)
    out *= np.float32(scale)
    out += np.float32(offset)
    return out


def _sparse_colour(
    img: npt.NDArray[np.uint8],
    on: npt.NDArray[np.bool_],
    ycbcr: bool,
) -> npt.NDArray[np.uint8]:
    """A shadow colour image with every pixel whose bitfield is 0 set to 0. A 4:4:4 HEVC picture
    arrives as its raw Y, Cb, Cr planes and is converted (BT.709, full range) only where ``on``."""
    out = np.zeros_like(img)
    if ycbcr:
        yuv = img[on].astype(np.float32)
        y, cb, cr = yuv[:, 0], yuv[:, 1] - 128.0, yuv[:, 2] - 128.0
        rgb = np.stack(
            [y + 1.5748 * cr, y - 0.187324 * cb - 0.468124 * cr, y + 1.8556 * cb],
            axis=-1,
        )
        out[on] = np.clip(np.rint(rgb), 0, 255).astype(np.uint8)
    else:
        out[on] = img[on]
    return out


def _plane_array(
    plane: Any, w: int, h: int, dtype: type[np.generic]
) -> npt.NDArray[Any]:
    itemsize = np.dtype(dtype).itemsize
    buf = np.frombuffer(plane, dtype=dtype)
    return buf.reshape(-1, plane.line_size // itemsize)[:h, :w]


# --------------------------------------------------------------------------------------------
# Lossless parts


def _zstd(cfg: CodecConfig) -> zstandard.ZstdCompressor:
    return zstandard.ZstdCompressor(level=cfg.zstd_level, write_content_size=True)


def _pack_mask(mask: npt.NDArray[np.bool_], level: int) -> bytes:
    return zstandard.ZstdCompressor(level=level, write_content_size=True).compress(
        np.packbits(mask, axis=None).tobytes()
    )


def _pack_bits(bits: npt.NDArray[np.uint32], level: int) -> bytes:
    """Sparse shadow bitfields: ``u8 value bytes n``, the occupancy mask (packbits of
    ``bits != 0``), then the non-zero values as ``n`` byte planes (low byte first), zstd."""
    nz = bits != 0
    vals = bits[nz]
    top = int(vals.max()) if vals.size else 0
    n = 1 if top < 1 << 8 else 2 if top < 1 << 16 else 3 if top < 1 << 24 else 4
    planes = vals.astype("<u4").view(np.uint8).reshape(-1, 4)[:, :n].T
    raw = (
        bytes([n])
        + np.packbits(nz, axis=None).tobytes()
        + np.ascontiguousarray(planes).tobytes()
    )
    return zstandard.ZstdCompressor(level=level, write_content_size=True).compress(raw)


def _unzstd(where: str, payload: bytes | memoryview, limit: int) -> bytes:
    """Decompresses an untrusted zstd frame whose declared size must not exceed ``limit``."""
    data = bytes(payload)
    try:
        size = zstandard.frame_content_size(data)
    except zstandard.ZstdError as e:
        raise StreamError(
            f"{where}: zstd payload of {len(data)} bytes is not a zstd frame ({e})"
        ) from None
    if size < 0 or size > limit:
        raise StreamError(
            f"{where}: zstd payload declares {size} bytes (expected at most {limit})"
        )
    try:
        out = zstandard.ZstdDecompressor().decompress(data, max_output_size=limit)
    except zstandard.ZstdError as e:
        raise StreamError(
            f"{where}: zstd payload of {len(data)} bytes did not decompress ({e})"
        ) from None
    if len(out) != size:
        raise StreamError(
            f"{where}: zstd payload decompressed to {len(out)} of {size} bytes"
        )
    return out


def _unpack_mask(
    where: str, payload: bytes | memoryview, w: int, h: int
) -> npt.NDArray[np.bool_]:
    n = (w * h + 7) // 8
    raw = _unzstd(where, payload, n)
    if len(raw) != n:
        raise StreamError(f"{where}: mask of {len(raw)} bytes, expected {n}")
    return (
        np.unpackbits(np.frombuffer(raw, np.uint8), count=w * h)
        .reshape(h, w)
        .astype(bool)
    )


def _unpack_bits(
    where: str, payload: bytes | memoryview, w: int, h: int
) -> npt.NDArray[np.uint32]:
    mbytes = (w * h + 7) // 8
    raw = _unzstd(where, payload, 1 + mbytes + 4 * w * h)
    if len(raw) < 1 + mbytes or raw[0] not in (1, 2, 3, 4):
        raise StreamError(
            f"{where}: malformed shadow bitfield payload ({len(raw)} bytes)"
        )
    n = raw[0]
    nz = np.unpackbits(np.frombuffer(raw, np.uint8, mbytes, 1), count=w * h).astype(
        bool
    )
    count = int(nz.sum())
    if len(raw) != 1 + mbytes + n * count:
        raise StreamError(
            f"{where}: shadow bitfield payload holds {len(raw) - 1 - mbytes} value bytes for "
            f"{count} pixels of {n} bytes"
        )
    planes = np.frombuffer(raw, np.uint8, n * count, 1 + mbytes).reshape(n, count)
    vals = np.zeros(count, np.uint32)
    for i in range(n):
        vals |= planes[i].astype(np.uint32) << np.uint32(8 * i)
    if np.any(vals == 0):
        raise StreamError(
            f"{where}: shadow bitfield payload stores a zero for a set pixel"
        )
    out = np.zeros(w * h, np.uint32)
    out[nz] = vals
    return out.reshape(h, w)


# --------------------------------------------------------------------------------------------
# Quantisation of depth and motion


def _quantise_depth(
    d: npt.NDArray[np.float32],
) -> tuple[npt.NDArray[np.uint16], float, float, npt.NDArray[np.bool_] | None]:
    finite = np.isfinite(d)
    invalid = None if finite.all() else ~finite
    vals = d[finite] if invalid is not None else d
    lo = float(vals.min()) if vals.size else 0.0
    hi = float(vals.max()) if vals.size else 0.0
    scale = float(np.float32((hi - lo) / _CODE_MAX)) if hi > lo else 1.0
    q = np.rint((np.where(finite, d, lo).astype(np.float64) - lo) / scale)
    return np.clip(q, 0, _CODE_MAX).astype(np.uint16), scale, lo, invalid


def _quantise_motion(
    m: npt.NDArray[np.float32],
) -> tuple[
    list[npt.NDArray[np.uint16]], tuple[float, float, float], tuple[float, float, float]
]:
    """Per channel: a range that includes 0, ``scale = range / 4094`` and the code ``z0`` of 0, so
    that ``code * scale + offset`` with ``offset = -z0 * scale`` is exactly 0.0 for ``z0``."""
    planes, scales, offsets = [], [], []
    for c in range(3):
        v = m[..., c].astype(np.float64)
        lo, hi = min(float(v.min()), 0.0), max(float(v.max()), 0.0)
        # float32-representable, so the decoder's float32 arithmetic also gives exactly 0.0
        scale = float(np.float32((hi - lo) / (_CODE_MAX - 2))) if hi > lo else 1.0
        z0 = float(np.rint(-lo / scale))
        q = np.clip(np.rint(v / scale) + z0, 0, _CODE_MAX).astype(np.uint16)
        planes.append(q)
        scales.append(scale)
        offsets.append(float(np.float32(-(z0 * scale))))
    return planes, tuple(scales), tuple(offsets)  # type: ignore[return-value]


# --------------------------------------------------------------------------------------------
# Encoder


@dataclass
class _Job:
    camera: int
    kind: BufferKind
    w: int
    h: int
    codec: Codec
    payload: bytes | Future[bytes] | Callable[[], bytes] = b""
    scale: tuple[float, float, float] = (0.0, 0.0, 0.0)
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)


def _cameras_of(frame: ServerFrame) -> tuple[CameraFrame, ...]:
    return (frame.main, *frame.aux)


@dataclass
class EncodeStats:
    """What the last call of :meth:`StreamEncoder.encode` did."""

    packet_bytes: int = 0
    lossless_bytes: int = 0
    hevc_targets_bps: dict[str, float] = field(default_factory=dict)


class _WorkerThreads:
    """A lazily started pool of worker threads, ended by :meth:`close` or a ``with`` block."""

    _pool: ThreadPoolExecutor | None = None

    def _executor(self, threads: int, name: str) -> ThreadPoolExecutor:
        if self._pool is None:
            self._pool = ThreadPoolExecutor(max_workers=threads, thread_name_prefix=name)
        return self._pool

    def close(self) -> None:
        """Ends the worker threads."""
        if self._pool is not None:
            self._pool.shutdown()
            self._pool = None

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class StreamEncoder(_WorkerThreads):
    """Encodes server frames into packets, one libx265 encoder per (camera, lossy buffer).

    The first frame fixes the layout (number of cameras and their sizes); later frames must keep
    it. Not thread-safe (it is a stream); internally the HEVC streams of a frame are encoded in
    parallel (``config.threads``, 0 = one per CPU).

    # Errors
    :class:`~splitrender.errors.InvalidInputError` for a frame that does not match the layout or
    the camera shares."""

    def __init__(self, config: CodecConfig | None = None) -> None:
        self.config = config if config is not None else CodecConfig()
        self._layout: tuple[tuple[int, int], ...] | None = None
        self._streams: dict[tuple[int, BufferKind], _HevcStream] = {}
        self._frames = 0
        self._gain = 1.0
        self._lossless_since_update = 0
        self._frames_since_update = 0
        self._lossless_bps = 0.0
        self._bits_total = 0
        self._force_key = False
        self._rate_changed = False
        self.last = EncodeStats()

    def _check_layout(self, frame: ServerFrame) -> None:
        # Every buffer as the coder reads it (numpy arrays stay mutable after the frame is made).
        check_server_frame("frame", frame)
        layout = tuple((c.camera.width, c.camera.height) for c in _cameras_of(frame))
        if self._layout is None:
            if len(layout) != len(self.config.camera_shares):
                raise InvalidInputError(
                    f"frame {frame.index}: {len(layout)} cameras but "
                    f"{len(self.config.camera_shares)} camera shares in the CodecConfig"
                )
            self._layout = layout
        elif layout != self._layout:
            raise InvalidInputError(
                f"frame {frame.index}: camera sizes {layout} differ from the stream's {self._layout}"
            )

    def encode(self, frame: ServerFrame) -> bytes:
        """One packet holding ``frame`` (see :mod:`splitrender.codec.stream`).

        Raises:
            InvalidInputError: for a buffer of the wrong dtype or shape (naming it, e.g.
                ``frame.aux[0].color``) or a frame that does not match the stream's layout.
        """
        self._check_layout(frame)
        cfg = self.config
        regular = self._frames % cfg.gop == 0
        key = regular or self._force_key
        # A forced key frame restarts the pictures (IDR) but not the rate control, unless the
        # target changed: reopening x265 costs tens of ms per stream.
        rates_at_key = regular or self._rate_changed
        self._force_key = False
        if key:
            self._rate_changed = False
        cams = _cameras_of(frame)
        if key:
            # Streams that skip this frame (no motion, no shadow) restart with an IDR later.
            for s in self._streams.values():
                s.need_idr = True
        jobs: list[_Job] = []
        for ci, cf in enumerate(cams):
            jobs += self._camera_jobs(ci, cf, key)
        lossless = sum(len(j.payload) for j in jobs if isinstance(j.payload, bytes))
        if not cfg.uncompressed:
            self._update_rates(frame, jobs, lossless, key and rates_at_key)
        # The encoders themselves are freed with the object.
        pool = self._executor(cfg.threads or (os.cpu_count() or 1), "splitrender-enc")
        for j in jobs:
            if callable(j.payload):
                j.payload = pool.submit(j.payload)
        entries = []
        for j in jobs:
            payload = j.payload.result() if isinstance(j.payload, Future) else j.payload
            assert isinstance(payload, bytes)
            entries.append(
                BufferEntry(
                    j.camera,
                    j.kind,
                    j.codec,
                    KIND_CHANNELS[j.kind],
                    j.w,
                    j.h,
                    payload,
                    j.scale,
                    j.offset,
                )
            )
        packet = pack_packet(
            Packet(
                index=frame.index,
                time=frame.time,
                key=key,
                uncompressed=cfg.uncompressed,
                cameras=tuple(
                    CameraRecord(
                        c.camera.view, c.camera.proj, c.camera.width, c.camera.height
                    )
                    for c in cams
                ),
                buffers=tuple(entries),
            )
        )
        hevc = sum(len(e.payload) for e in entries if e.codec == Codec.HEVC)
        self._lossless_since_update += len(packet) - hevc
        self._bits_total += 8 * len(packet)
        self._frames_since_update += 1
        self._frames += 1
        self.last = EncodeStats(
            len(packet),
            len(packet) - hevc,
            {buffer_name(c, k): s.target_bps for (c, k), s in self._streams.items()},
        )
        return packet

    # -- live control (splitrender.net.server) --------------------------------------------------
    # Kept apart from the rest: a live server changes the stream while it runs, which the file
    # encoder never needed. A key frame may come at any frame (the decoder restarts at every
    # key frame whatever the index); the regular key frames keep their schedule.

    def request_key_frame(self) -> None:
        """Makes the next :meth:`encode` a key frame (a client that lost a frame can decode
        again from it)."""
        self._force_key = True

    def set_bitrate(self, mbps: float) -> None:
        """Moves the stream's target to ``mbps``. The HEVC encoders take it at the next key
        frame, regular or requested (x265 is reopened, which needs an IDR), so a caller that
        needs it sooner also calls :meth:`request_key_frame`. The shortfall accounting restarts from here, so that
        the new target is not pulled towards the old one.

        Raises:
            InvalidInputError: for a rate that is not a finite number > 0.
        """
        import dataclasses

        self.config = dataclasses.replace(self.config, bitrate_mbps=mbps)
        self._bits_total = round(mbps * 1e6 * self._frames / self.config.fps)
        self._rate_changed = True

    # -- rate control -------------------------------------------------------------------------

    def _update_rates(
        self, frame: ServerFrame, jobs: list[_Job], lossless: int, key: bool
    ) -> None:
        """At key frames: (re)opens the HEVC encoders with targets from the budget left after the
        lossless parts, corrected by the rate achieved over the last GOP."""
        cfg = self.config
        total = cfg.bitrate_mbps * 1e6
        lossy = [(j.camera, j.kind) for j in jobs if callable(j.payload)]
        new = [k for k in lossy if k not in self._streams]
        if not key and not new:
            return
        if key and self._frames_since_update:
            # Measured over the last GOP: lossless bytes (with headers) and the HEVC rate.
            self._lossless_bps = (
                8 * self._lossless_since_update * cfg.fps / self._frames_since_update
            )
            achieved = sum(s.bits_since_update for s in self._streams.values())
            achieved_bps = achieved * cfg.fps / self._frames_since_update
            # Aim the next GOP at the target plus whatever the stream so far is short of (or
            # over) it, so the whole sequence lands on the target, not just each GOP.
            deficit = total * self._frames / cfg.fps - self._bits_total
            aim = min(
                max(total + deficit * cfg.fps / cfg.gop, 0.5 * total), 2.0 * total
            )
            wanted = max(aim - self._lossless_bps, 0.05 * total)
            if cfg.rate_feedback and achieved_bps > 0:
                # Multiplicative correction, bounded so one odd GOP cannot run away.
                ratio = min(max(wanted / achieved_bps, 1 / 3), 3.0)
                self._gain = min(max(self._gain * ratio, 0.25), 8.0)
        elif not self._streams:
            # First frame: this frame's lossless bytes plus an estimate of the packet header
            # (stream format version 2: about 10 bytes per buffer and 250 for the cameras).
            self._lossless_bps = 8 * (lossless + 10 * len(jobs) + 250) * cfg.fps
        budget = max(total - self._lossless_bps, 0.05 * total) * self._gain
        shares = cfg.shares()
        targets: dict[tuple[int, BufferKind], float] = {}
        for cam in sorted({c for c, _ in lossy}):
            kinds = [k for c, k in lossy if c == cam]
            groups = {_GROUP[k][0] for k in kinds}
            norm = sum(shares[g] for g in groups) or 1.0
            group_size = {
                g: sum(_GROUP[k][1] for k in kinds if _GROUP[k][0] == g) for g in groups
            }
            for k in kinds:
                g, frac = _GROUP[k]
                targets[(cam, k)] = (
                    budget
                    * cfg.camera_shares[cam]
                    * shares[g]
                    / norm
                    * frac
                    / group_size[g]
                )
        for sk, t in targets.items():
            s = self._streams.get(sk)
            if not key and s is not None:
                continue  # mid-GOP: only open the new streams
            if s is None:
                assert self._layout is not None
                w, h = self._layout[sk[0]]
                s = self._streams[sk] = _HevcStream(sk[1], w, h, cfg)
                s.open(t)
            elif abs(t - s.target_bps) > 0.03 * s.target_bps:
                s.open(t)
            s.bits_since_update = 0
        if not key:
            return
        for sk, s in self._streams.items():
            if sk not in targets:
                s.bits_since_update = 0
        self._lossless_since_update = 0
        self._frames_since_update = 0

    # -- buffers --------------------------------------------------------------------------------

    def _camera_jobs(self, ci: int, cf: CameraFrame, key: bool) -> list[_Job]:
        cfg = self.config
        w, h = cf.camera.width, cf.camera.height
        jobs: list[_Job] = []
        if cfg.uncompressed:
            jobs.append(_Job(ci, _K.COLOR, w, h, Codec.RAW, cf.color.tobytes()))
            jobs.append(
                _Job(ci, _K.DEPTH, w, h, Codec.RAW, cf.depth.astype("<f4").tobytes())
            )
            for d in ("fwd", "bwd"):
                m = getattr(cf, f"motion_{d}")
                if m is not None:
                    jobs.append(
                        _Job(
                            ci,
                            _MOTION[d][0],
                            w,
                            h,
                            Codec.RAW,
                            m.astype("<f4").tobytes(),
                        )
                    )
                s = getattr(cf, f"shadow_{d}")
                if s is not None:
                    kb, kmin, kmax = _SHADOW[d]
                    jobs.append(
                        _Job(ci, kb, w, h, Codec.RAW, s.bits.astype("<u4").tobytes())
                    )
                    jobs.append(_Job(ci, kmin, w, h, Codec.RAW, s.s_min.tobytes()))
                    jobs.append(_Job(ci, kmax, w, h, Codec.RAW, s.s_max.tobytes()))
            return jobs

        lvl = cfg.zstd_level
        jobs.append(self._hevc_job(ci, _K.COLOR, w, h, cf.color, key))
        q, scale, lo, invalid = _quantise_depth(cf.depth)
        jobs.append(
            self._hevc_job(ci, _K.DEPTH, w, h, [q], key, (scale, 0, 0), (lo, 0, 0))
        )
        if invalid is not None:
            jobs.append(
                _Job(ci, _K.DEPTH_INVALID, w, h, Codec.ZSTD, _pack_mask(invalid, lvl))
            )
        for d in ("fwd", "bwd"):
            m = getattr(cf, f"motion_{d}")
            kind, kstatic, kinvalid = _MOTION[d]
            if m is not None:
                finite = np.isfinite(m).all(axis=2)
                mm = (
                    m if finite.all() else np.where(finite[..., None], m, np.float32(0))
                )
                static = (mm == 0).all(axis=2)
                if static.all():
                    jobs.append(_Job(ci, kind, w, h, Codec.ZERO))
                else:
                    planes, sc, off = _quantise_motion(mm)
                    jobs.append(self._hevc_job(ci, kind, w, h, planes, key, sc, off))
                    if cfg.exact_static_motion:
                        jobs.append(
                            _Job(ci, kstatic, w, h, Codec.ZSTD, _pack_mask(static, lvl))
                            if static.any()
                            else _Job(ci, kstatic, w, h, Codec.ZERO)
                        )
                if not finite.all():
                    jobs.append(
                        _Job(ci, kinvalid, w, h, Codec.ZSTD, _pack_mask(~finite, lvl))
                    )
            s = getattr(cf, f"shadow_{d}")
            if s is not None:
                kb, kmin, kmax = _SHADOW[d]
                nz = s.bits != 0
                if not nz.any():
                    jobs += [_Job(ci, k, w, h, Codec.ZERO) for k in (kb, kmin, kmax)]
                    continue
                jobs.append(_Job(ci, kb, w, h, Codec.ZSTD, _pack_bits(s.bits, lvl)))
                for k, col in ((kmin, s.s_min), (kmax, s.s_max)):
                    # Texels of pixels without dynamic shadow are never read: zero them so they
                    # cost no bits.
                    jobs.append(
                        self._hevc_job(
                            ci, k, w, h, np.where(nz[..., None], col, 0), key
                        )
                    )
        return jobs

    def _hevc_job(
        self,
        ci: int,
        kind: BufferKind,
        w: int,
        h: int,
        data: Any,
        key: bool,
        scale: tuple[float, float, float] = (0.0, 0.0, 0.0),
        offset: tuple[float, float, float] = (0.0, 0.0, 0.0),
    ) -> _Job:
        def run() -> bytes:
            return self._streams[(ci, kind)].encode(data, key)

        return _Job(ci, kind, w, h, Codec.HEVC, run, scale, offset)


# --------------------------------------------------------------------------------------------
# Decoder


def _hevc_decoder(width: int, height: int) -> Any:
    """An HEVC decoder that refuses pictures larger than ``width x height`` pixels.

    The payload is untrusted: its sequence parameter set could declare a picture far larger than
    the buffer table says, and FFmpeg would allocate it before we could compare sizes. FFmpeg's
    ``max_pixels`` limit makes it reject such a picture before allocating. The limit allows each
    side to be rounded up to a whole 64-pixel coding tree unit, since the coded size of a picture
    (which FFmpeg checks) may exceed its cropped size by that much."""
    ctx = av.CodecContext.create("hevc", "r")
    ctx.thread_count = 1
    ctx.options = {"max_pixels": str((-(-width // 64) * 64) * (-(-height // 64) * 64))}
    return ctx


class StreamDecoder(_WorkerThreads):
    """Decodes packets into :class:`~splitrender.types.ServerFrame` values, in order.

    Decoding starts at a key frame; after that every packet must follow the previous one
    (frame index + 1), or be a key frame. The HEVC decoders are created afresh at every key frame.

    # Errors
    :class:`~splitrender.errors.StreamError` naming the frame and buffer for anything wrong in a
    packet (see :func:`splitrender.codec.stream.unpack_packet`), a payload that does not decode or does
    not match its table entry, a missing buffer, or a non-key packet without its predecessor."""

    def __init__(self, threads: int = 0, max_pixels: int = MAX_PIXELS) -> None:
        self._decoders: dict[tuple[int, BufferKind], Any] = {}
        self._last: int | None = None
        self._threads = threads or (os.cpu_count() or 1)
        self.max_pixels = max_pixels

    def decode(self, data: bytes | memoryview) -> ServerFrame:
        """The server frame held by one packet."""
        p = unpack_packet(data)
        where = f"frame {p.index}"
        for i, c in enumerate(p.cameras):
            if c.width * c.height > self.max_pixels:
                raise StreamError(
                    f"{where}, {buffer_name(i, 0).split('.')[0]}: {c.width}x{c.height} exceeds "
                    f"the decoder's limit of {self.max_pixels} pixels"
                )
        if p.key:
            self._decoders = {}
        elif self._last is None or p.index != self._last + 1:
            after = "none" if self._last is None else str(self._last)
            self._last = None
            raise StreamError(
                f"{where}: not a key frame and it does not follow the last decoded frame "
                f"({after}); decoding must start at a key frame"
            )
        seen: dict[tuple[int, BufferKind], BufferEntry] = {}
        for b in p.buffers:
            if (b.camera, b.kind) in seen:
                raise StreamError(f"{where}, {b.name}: buffer appears twice")
            seen[(b.camera, b.kind)] = b
        self._last = None  # until this frame has decoded fully
        hevc = [b for b in p.buffers if b.codec == Codec.HEVC]
        results: dict[tuple[int, BufferKind], npt.NDArray[Any]] = {}
        ycbcr: set[tuple[int, BufferKind]] = set()
        if len(hevc) > 1 and self._threads > 1:
            pool = self._executor(self._threads, "splitrender-dec")
            futs = [(b, pool.submit(self._decode_hevc, p.index, b)) for b in hevc]
            errors = []
            for b, f in futs:
                try:
                    results[(b.camera, b.kind)], yuv = f.result()
                except StreamError as e:
                    errors.append(e)
                    continue
                if yuv:
                    ycbcr.add((b.camera, b.kind))
            if errors:
                raise errors[0]
        else:
            for b in hevc:
                results[(b.camera, b.kind)], yuv = self._decode_hevc(p.index, b)
                if yuv:
                    ycbcr.add((b.camera, b.kind))
        cams = []
        for ci, rec in enumerate(p.cameras):
            cams.append(self._camera(p, ci, rec, seen, results, ycbcr))
        self._last = p.index
        return ServerFrame(
            index=p.index, time=p.time, main=cams[0], aux=tuple(cams[1:])
        )

    def _decode_hevc(self, index: int, b: BufferEntry) -> tuple[npt.NDArray[Any], bool]:
        """The decoded picture as the buffer's array, and whether it is still Y, Cb, Cr (sparse
        shadow colours, converted later)."""
        where = f"frame {index}, {b.name}"
        if b.kind not in _DECODED_FORMATS:
            raise StreamError(f"{where}: HEVC is not a codec of this buffer kind")
        key = (b.camera, b.kind)
        ctx = self._decoders.get(key)
        if ctx is None:
            ctx = _hevc_decoder(*_padded(b.width, b.height))
            self._decoders[key] = ctx
        try:
            frames = ctx.decode(av.Packet(bytes(b.payload)))
        except av.error.FFmpegError as e:
            raise StreamError(
                f"{where}: HEVC payload of {len(b.payload)} bytes did not decode ({e})"
            ) from None
        if len(frames) != 1:
            raise StreamError(
                f"{where}: HEVC payload of {len(b.payload)} bytes did not decode "
                f"({len(frames)} pictures)"
            )
        f = frames[0]
        pw, ph = _padded(b.width, b.height)
        if (f.width, f.height) != (pw, ph) or f.format.name not in _DECODED_FORMATS[
            b.kind
        ]:
            raise StreamError(
                f"{where}: HEVC picture is {f.width}x{f.height} {f.format.name}, expected "
                f"{pw}x{ph} {'/'.join(_DECODED_FORMATS[b.kind])}"
            )
        w, h = b.width, b.height
        if (
            b.kind in _COLOR_KINDS
            and b.kind != _K.COLOR
            and f.format.name in ("yuv444p", "yuvj444p")
        ):
            # Shadow colours are sparse: convert only where a bitfield is set (later).
            planes = [_plane_array(f.planes[c], w, h, np.uint8) for c in range(3)]
            return np.stack(planes, axis=-1), True
        if b.kind in _COLOR_KINDS:
            rgb = f.reformat(
                format="rgb24",
                src_colorspace="ITU709",
                src_color_range="JPEG",
                interpolation="BICUBIC",
            ).to_ndarray()
            return np.ascontiguousarray(rgb[:h, :w]), False
        if b.kind == _K.DEPTH:
            q = _plane_array(f.planes[0], w, h, np.uint16)
            return _dequantise(q, b.scale[0], b.offset[0]), False
        out = np.empty((h, w, 3), np.float32)
        for c in range(3):
            q = _plane_array(f.planes[c], w, h, np.uint16)
            out[..., c] = _dequantise(q, b.scale[c], b.offset[c])
        return out, False

    def _camera(
        self,
        p: Packet,
        ci: int,
        rec: CameraRecord,
        seen: dict[tuple[int, BufferKind], BufferEntry],
        results: dict[tuple[int, BufferKind], npt.NDArray[Any]],
        ycbcr: set[tuple[int, BufferKind]],
    ) -> CameraFrame:
        w, h = rec.width, rec.height

        def get(
            kind: BufferKind,
            dtype: str,
            shape: tuple[int, ...],
            *,
            required: bool = False,
        ) -> npt.NDArray[Any] | None:
            where = f"frame {p.index}, {buffer_name(ci, kind)}"
            b = seen.get((ci, kind))
            if b is None:
                if required:
                    raise StreamError(f"{where}: buffer missing from the packet")
                return None
            if b.codec == Codec.HEVC:
                return results[(ci, kind)]
            if b.codec == Codec.ZERO:
                return np.zeros(shape, dtype)
            if b.codec == Codec.RAW:
                want = int(np.prod(shape)) * np.dtype(dtype).itemsize
                if len(b.payload) != want:
                    raise StreamError(
                        f"{where}: raw payload of {len(b.payload)} bytes, expected {want}"
                    )
                raw: npt.NDArray[Any] = (
                    np.frombuffer(b.payload, dtype).reshape(shape).copy()
                )
                return raw
            # ZSTD
            if kind in (_K.SHADOW_FWD_BITS, _K.SHADOW_BWD_BITS):
                return _unpack_bits(where, b.payload, w, h)
            if kind in (
                _K.DEPTH_INVALID,
                _K.MOTION_FWD_STATIC,
                _K.MOTION_BWD_STATIC,
                _K.MOTION_FWD_INVALID,
                _K.MOTION_BWD_INVALID,
            ):
                return _unpack_mask(where, b.payload, w, h)
            raise StreamError(f"{where}: zstd is not a codec of this buffer kind")

        def mask(kind: BufferKind) -> npt.NDArray[np.bool_] | None:
            b = seen.get((ci, kind))
            if b is not None and b.codec == Codec.RAW:
                raise StreamError(f"frame {p.index}, {b.name}: a mask cannot be raw")
            m = get(kind, "bool", (h, w))
            return None if m is None else m.astype(bool)

        color = get(_K.COLOR, "u1", (h, w, 3), required=True)
        depth = get(_K.DEPTH, "<f4", (h, w), required=True)
        assert color is not None and depth is not None
        inv = mask(_K.DEPTH_INVALID)
        if inv is not None:
            np.copyto(depth, np.float32(np.nan), where=inv)
        motions: dict[str, npt.NDArray[np.float32] | None] = {}
        shadows: dict[str, ShadowBuffers | None] = {}
        for d in ("fwd", "bwd"):
            kind, kstatic, kinvalid = _MOTION[d]
            m = get(kind, "<f4", (h, w, 3))
            if m is not None:
                st = mask(kstatic)
                if st is not None:
                    np.copyto(m, np.float32(0), where=st[..., None])
                iv = mask(kinvalid)
                if iv is not None:
                    np.copyto(m, np.float32(np.nan), where=iv[..., None])
            motions[d] = m
            kb, kmin, kmax = _SHADOW[d]
            bits = get(kb, "<u4", (h, w))
            if bits is None:
                shadows[d] = None
                continue
            smin = get(kmin, "u1", (h, w, 3), required=True)
            smax = get(kmax, "u1", (h, w, 3), required=True)
            assert smin is not None and smax is not None
            if seen[(ci, kb)].codec != Codec.RAW:
                on = bits != 0
                smin = _sparse_colour(smin, on, (ci, kmin) in ycbcr)
                smax = _sparse_colour(smax, on, (ci, kmax) in ycbcr)
            shadows[d] = ShadowBuffers(
                np.ascontiguousarray(bits, np.uint32),
                np.ascontiguousarray(smin),
                np.ascontiguousarray(smax),
            )
        camera = Camera(rec.view, rec.proj, w, h)
        return CameraFrame(
            camera=camera,
            color=np.ascontiguousarray(color),
            depth=np.ascontiguousarray(depth, dtype=np.float32),
            motion_fwd=motions["fwd"],
            motion_bwd=motions["bwd"],
            shadow_fwd=shadows["fwd"],
            shadow_bwd=shadows["bwd"],
        )


def decode_packets(packets: Sequence[bytes]) -> list[ServerFrame]:
    """Decodes a whole run of packets (starting at a key frame) with one decoder."""
    with StreamDecoder() as d:
        return [d.decode(p) for p in packets]
