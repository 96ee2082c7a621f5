"""Compression of server frames (seeds/000 §3.4, §4.1; DESIGN.md "Wire format and codecs").

:class:`StreamEncoder` turns each :class:`~splitrender.types.ServerFrame` into one packet
(:mod:`splitrender.codec.stream`, format version 4); :class:`StreamDecoder` turns packets back
into the same dataclasses the client consumes. A frame is the older one of one pair and the newer
one of the next, so the client needs both directions of every frame.

The lossy buffers of *all* cameras travel as tiles of at most three HEVC pictures per frame
(version 2 sent 24 HEVC streams; decoding costs per sample, not per stream, so the samples
themselves were cut as well, see docs/codec-results.md):

==================  ===========================================================================
picture             tiles (every camera, in the order of :func:`_tiles`)
==================  ===========================================================================
``color``           colour, HEVC 8-bit YCbCr BT.709 full range, 4:2:0 (default) or 4:4:4
``geometry``        depth at full size and each channel of motion fwd and bwd at half size
                    (``ceil(w/2) x ceil(h/2)``), as linear 12-bit codes, HEVC ``gray12le``; the
                    per-tile scale/offset travel in the packet, and 0 is an exact motion code
                    (``offset = -z0 * scale``)
``shadow``          the four shadow colours (fwd/bwd s_min/s_max) at half size (since format 4),
                    8-bit like colour
==================  ===========================================================================

The geometry and shadow pictures are coded without HEVC's in-loop filters (deblocking, SAO;
format 4): a third of their decoding, for no loss (docs/stream-format.md, "Why version 4").

The tiles are packed into columns by :func:`_layout`, a pure function of the camera sizes, so the
packet needs no layout of its own; each tile sits on the 8-pixel grid and its slot is filled by
repeating its last row and column, so that no coding block straddles two tiles.

Lossless beside them (zstd, bit-exact):

- ``motion_*.static``: pixels whose motion is exactly 0; they decode to exactly 0 whatever the
  lossy codec did nearby. Motion at half size is the mean of the *moving* pixels of each 2x2
  block, so moving pixels next to static ones keep their own motion.
- ``depth/motion .invalid``: NaN/inf pixels (only when there are any); they decode to NaN.
- ``shadow_*.bits``: a bit-packed occupancy mask and the non-zero bitfields (all 32 bits). Shadow
  colours are only read where a bitfield is set: elsewhere they decode to 0. Each half-size
  sample is the mean of the set pixels of its 2x2 block (every set pixel of the block decodes
  to it); a sample without any is never read, and the encoder fills it with the mean of the
  used samples of its own 2x2 block (4:2:0: the chroma sample then is theirs) or 0, so it
  costs next to nothing.

Rate control: one libx265 encoder per picture, kept open across frames: zero-latency tuning, no
B-frames, ABR to a per-picture target with a VBV buffer of ``vbv_buffer_s`` seconds
(``vbv-maxrate`` = target). After the lossless parts (measured, not assumed), the budget is
split colour 50 %, geometry (depth + motion) 40 %, shadow colours 10 %, all configurable. Within
a picture x265 spends bits where the content needs them; ``camera_shares`` (main 60 %, auxiliary
20 % each) is no longer a separate target (one picture holds every camera) but the tile areas
give about that split (main 4/6, each auxiliary camera 1/6 of the pixels). At every key frame the
targets are recomputed from the lossless bytes, the achieved rate of the last GOP and the
shortfall of the whole stream so far (a bounded gain), because x265's ABR drifts over short
sequences.

Decoding: the (up to) three pictures decode in parallel on a thread pool (FFmpeg releases the
GIL), each with FFmpeg's slice threading over x265's wavefront rows, never frame threading, which
would hold each picture back by a frame. The colour picture is converted to RGB by swscale in one
call; every other buffer is dequantised straight from the decoded planes into the client's array.
The FFmpeg decoders and the output arrays live across frames (new memory is paid in page faults,
docs/performance.md "Codec"); an output array is reused only once nothing else holds it.

Random access: every ``gop`` frames a key frame forces an IDR with the parameter sets in every
picture; a :class:`StreamDecoder` can start at any key frame.

Where this differs from the reference code on purpose (REFERENCE.md §5, §8): shadow bitfields keep
all 32 bits (the reference keeps only the blue channel, losing subframes beyond 4); no morphological
opening of the shadow mask (lossless means lossless); no zeroing of |v| < 1e-4 (exact zeros are kept
by the static mask instead); the same rate mode for every picture (the vbr CRF bug does not arise);
the depth/motion codes are taken straight from float32 (a detour through half floats would only
add error once 12 bits are taken).
"""

from __future__ import annotations

import dataclasses
import math
import os
import sys
import threading
from collections.abc import Callable, Iterator, Mapping, Sequence
from concurrent.futures import Future, ThreadPoolExecutor, wait
from dataclasses import dataclass, field
from fractions import Fraction
from functools import lru_cache
from types import MappingProxyType
from typing import TYPE_CHECKING, Any

import av
import numpy as np
import numpy.typing as npt
import zstandard

from splitrender.codec.stream import (
    KIND_CHANNELS,
    MAX_PIXELS,
    PICTURE_KINDS,
    TILE_PICTURE,
    BufferEntry,
    BufferKind,
    CameraRecord,
    Codec,
    Packet,
    buffer_name,
    camera_name,
    pack_packet,
    unpack_packet,
)
from splitrender import _native
from splitrender.errors import InvalidInputError, StreamError
from splitrender.types import (
    Camera,
    CameraFrame,
    ServerFrame,
    ShadowBuffers,
    check_server_frame,
)
from splitrender.types import (  # argument checks
    MAX_SIDE,
    MAX_THREADS,
    buffers,
    check_bool,
    check_float,
    check_int,
    check_items,
    check_str,
    checked,
    floats,
    instances,
    ints,
    items,
    optional,
)

if TYPE_CHECKING:
    from typing_extensions import Self  # annotations only (Python 3.10)

__all__ = [
    "CodecConfig", "DecodedStream", "StreamDecoder", "StreamEncoder", "oversized_picture",
]

_K = BufferKind
_CODE_MAX = 4095  # 12 bits
# The smallest span quantised over its codes: below it (a denormal range such as motion of
# 1e-45) span / codes rounds to a float32 scale of 0.0 or a denormal, and the division by the
# scale raised ZeroDivisionError or gave infinities. A narrower span is coded as constant
# (scale 1.0, every code the same), an error below 5e-35.
_MIN_SPAN = float(np.finfo(np.float32).tiny) * _CODE_MAX
_ALIGN = 8  # tiles on the 8x8 transform grid: no block straddles two tiles

_PIC_COLOR, _PIC_GEOMETRY, _PIC_SHADOW = (
    _K.PICTURE_COLOR,
    _K.PICTURE_GEOMETRY,
    _K.PICTURE_SHADOW,
)
_SHADOW_COLOURS = PICTURE_KINDS[_PIC_SHADOW]
_MOTION = {
    "fwd": (_K.MOTION_FWD, _K.MOTION_FWD_STATIC, _K.MOTION_FWD_INVALID),
    "bwd": (_K.MOTION_BWD, _K.MOTION_BWD_STATIC, _K.MOTION_BWD_INVALID),
}
_SHADOW = {
    "fwd": (_K.SHADOW_FWD_BITS, _K.SHADOW_FWD_MIN, _K.SHADOW_FWD_MAX),
    "bwd": (_K.SHADOW_BWD_BITS, _K.SHADOW_BWD_MIN, _K.SHADOW_BWD_MAX),
}
_SHADOW_BITS = {v[0] for v in _SHADOW.values()}
_SHADOW_OF = {v[0]: v for v in _SHADOW.values()}  # a bitfield's kind -> its three kinds


#: Largest ``CodecConfig.bitrate_mbps`` (100 Gb/s, beyond any link the stream is meant for):
#: the target reaches x265 as an integer in kb/s, and 1e300 Mb/s raised OverflowError there.
MAX_BITRATE_MBPS = 100_000.0
#: Range of ``CodecConfig.fps`` (exclusive below): like the bitrate it reaches libav, as a
#: fraction of denominator <= 1001 that 1e-300 rounded to 0 (ZeroDivisionError), and the rate
#: control divides by it.
MIN_FPS, MAX_FPS = 1e-3, 1000.0
#: The presets of x265 (``CodecConfig.preset``), fastest first.
X265_PRESETS = (
    "ultrafast", "superfast", "veryfast", "faster", "fast", "medium", "slow", "slower",
    "veryslow", "placebo",
)
#: Largest ``CodecConfig.vbv_buffer_s``: x265's VBV buffer is this many seconds of the bitrate.
MAX_VBV_BUFFER_S = 60.0


@dataclass(frozen=True, slots=True)
class CodecConfig:
    """Settings of a :class:`StreamEncoder` (the decoder needs none: the packets say it all).

    ``bitrate_mbps`` is the target of the whole stream (all cameras, all buffers, headers) at
    ``fps`` server frames per second; DESIGN.md scales it with the pixel count (the paper's
    40 Mb/s at 2560x1440 is 10 Mb/s at 1280x720, see :meth:`scaled`).

    ``camera_shares`` must still give one share per camera (it fixes the number of cameras the
    stream expects), but since stream format 3 every picture holds all cameras and x265 splits
    its bits between their tiles by content. ``chroma`` is that of the colour and shadow
    pictures; 4:2:0 by default since format 3 (half the decode time of the colour picture,
    docs/codec-results.md).

    ``lossless_share`` is the most of the target that a frame's lossless parts (masks, shadow
    bitfields, headers) may take: beyond it the shadow bitfields of the auxiliary cameras, then
    of the main camera, are left out of that frame (sent as ZERO, as for a camera without moving
    shadows), so that the pictures keep the rest. Without it a scene whose soft shadows move
    over ~1 % of the pixels spent more than a 2.5 Mb/s target on the bitfields alone at
    1280×720 and left the colour 3 % of the stream. A quarter: of the shares tried (0, 0.25,
    0.5), the one never worse for Figure 6's `ours` at any scene and rate measured
    (docs/codec-results.md, "Lossless parts beyond a quarter of the target")."""

    bitrate_mbps: float = 10.0
    camera_shares: tuple[float, ...] = (0.6, 0.2, 0.2)
    color_share: float = 0.5
    depth_share: float = 0.2
    motion_share: float = 0.2
    shadow_color_share: float = 0.1
    chroma: str = "420"
    preset: str = "superfast"
    fps: float = 10.0
    gop: int = 10
    vbv_buffer_s: float = 0.3
    uncompressed: bool = False
    zstd_level: int = 10
    lossless_share: float = 0.25
    exact_static_motion: bool = True
    rate_feedback: bool = True
    threads: int = 0

    def __post_init__(self) -> None:
        for name, low, top in (
            ("bitrate_mbps", 0.0, MAX_BITRATE_MBPS),
            ("fps", MIN_FPS, MAX_FPS),
            ("vbv_buffer_s", 0.0, MAX_VBV_BUFFER_S),
        ):
            # Any real number (numpy scalars too), as a float; then the range, open below.
            v = check_float(f"CodecConfig.{name}", getattr(self, name))
            if not low < v <= top:
                raise InvalidInputError(
                    f"CodecConfig.{name}: expected a number > {low:g} and <= {top:g}, got {v!r}"
                )
            object.__setattr__(self, name, v)
        for name in ("color_share", "depth_share", "motion_share", "shadow_color_share"):
            object.__setattr__(self, name, check_float(f"CodecConfig.{name}", getattr(self, name)))
        object.__setattr__(self, "lossless_share", check_float(
            "CodecConfig.lossless_share", self.lossless_share, lo=0.0, hi=1.0))
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
        cs = tuple(
            check_items("CodecConfig.camera_shares", self.camera_shares, floats(lo=0.0))
        )
        if (
            not cs
            or any(not (math.isfinite(s) and s > 0) for s in cs)
            or abs(sum(cs) - 1) > 1e-6
        ):
            raise InvalidInputError(
                f"CodecConfig.camera_shares: expected values > 0 summing to 1, got {cs}"
            )
        object.__setattr__(self, "camera_shares", cs)
        # chroma=420 said "expected '444' or '420', got 420": a str is expected, not the number.
        check_str("CodecConfig.chroma", self.chroma, ("444", "420"))
        # As ints (a numpy integer stayed one, in the config's repr and what it compares to).
        for name, hi in (("gop", 100000), ("zstd_level", 22), ("threads", MAX_THREADS)):
            lo = 0 if name == "threads" else 1
            object.__setattr__(
                self, name, check_int(f"CodecConfig.{name}", getattr(self, name), lo, hi))
        check_str("CodecConfig.preset", self.preset, X265_PRESETS)
        for name in ("uncompressed", "exact_static_motion", "rate_feedback"):
            object.__setattr__(self, name, check_bool(f"CodecConfig.{name}", getattr(self, name)))

    @classmethod
    @checked(width=ints(1, MAX_SIDE), height=ints(1, MAX_SIDE), paper_mbps=floats(positive=True))
    def scaled(
        cls, width: int, height: int, paper_mbps: float = 40.0, **kwargs: Any
    ) -> CodecConfig:
        """A config whose bitrate is ``paper_mbps`` (given for the paper's 2560x1440 main camera)
        scaled to a ``width x height`` main camera by pixel count."""
        # bitrate_mbps is what this sets; any other name is not an option.
        unknown = set(kwargs) - ({f.name for f in dataclasses.fields(cls)} - {"bitrate_mbps"})
        if unknown:
            raise InvalidInputError(f"CodecConfig.scaled: unknown options {sorted(unknown)}")
        return cls(bitrate_mbps=paper_mbps * width * height / (2560 * 1440), **kwargs)

    def shares(self) -> dict[str, float]:
        return {
            "color": self.color_share,
            "depth": self.depth_share,
            "motion": self.motion_share,
            "shadow_color": self.shadow_color_share,
        }


# --------------------------------------------------------------------------------------------
# Tiles


@dataclass(frozen=True, slots=True)
class _Tile:
    """Where one buffer (or one channel of motion) lies in its picture."""

    camera: int
    kind: BufferKind
    channel: int
    w: int
    h: int
    x: int = 0
    y: int = 0


def _aligned(n: int) -> int:
    return -(-n // _ALIGN) * _ALIGN


def _half(n: int) -> int:
    return (n + 1) // 2


def _tiles(picture: BufferKind, sizes: tuple[tuple[int, int], ...]) -> list[_Tile]:
    """The tiles of ``picture`` for cameras of ``sizes``, unplaced, in their canonical order."""
    out = []
    for ci, (w, h) in enumerate(sizes):
        if picture == _PIC_COLOR:
            out.append(_Tile(ci, _K.COLOR, 0, w, h))
        elif picture == _PIC_GEOMETRY:
            out.append(_Tile(ci, _K.DEPTH, 0, w, h))
            out += [
                _Tile(ci, k, c, _half(w), _half(h))
                for k in (_K.MOTION_FWD, _K.MOTION_BWD)
                for c in range(3)
            ]
        else:
            # Half size since format 4, like motion: read only where a bitfield is set, and
            # the picture's decoding costs per sample (docs/stream-format.md, "Why version 4").
            out += [_Tile(ci, k, 0, _half(w), _half(h)) for k in _SHADOW_COLOURS]
    return out


def _place(
    tiles: list[_Tile], col_h: int
) -> tuple[dict[tuple[int, BufferKind, int], _Tile], int]:
    """Tiles, sorted tallest first, in columns of height ``col_h`` (see :func:`_layout`) and the
    width they take."""
    placed: dict[tuple[int, BufferKind, int], _Tile] = {}
    x = y = col_w = 0
    for t in tiles:
        tw, th = _aligned(t.w), _aligned(t.h)
        if y + th > col_h:
            x, y, col_w = x + col_w, 0, 0
        placed[(t.camera, t.kind, t.channel)] = _Tile(
            t.camera, t.kind, t.channel, t.w, t.h, x, y
        )
        y += th
        col_w = max(col_w, tw)
    return placed, x + col_w


#: The longest picture side HEVC level 4.1 allows, rounded down to whole 16-pixel blocks
#: (sqrt(8 · 2,228,224 samples) = 4222): a longer one is level 5 (see :func:`_layout`).
_LEVEL5_SIDE = 4208


def oversized_picture(sizes: Sequence[tuple[int, int]]) -> tuple[str, int, int] | None:
    """The first picture a stream of cameras of ``sizes`` (``(width, height)``, main first)
    would have that the codec cannot carry, a side beyond :data:`MAX_SIDE`, as ``(name,
    width, height)``; ``None`` when every picture fits. :class:`StreamEncoder` refuses such a
    stream at its first frame; a server checks its scale with this before rendering one."""
    return _oversized(tuple((int(w), int(h)) for w, h in sizes))


@lru_cache(maxsize=64)
def _oversized(layout: tuple[tuple[int, int], ...]) -> tuple[str, int, int] | None:
    """:func:`oversized_picture` of a layout in its hashable form (cached for the server's
    scale check, which bisects)."""
    for pic in PICTURE_KINDS:
        _, pw, ph = _layout(pic, layout)
        if max(pw, ph) > MAX_SIDE:
            return buffer_name(0, pic), pw, ph
    return None


@lru_cache(maxsize=64)
def _layout(
    picture: BufferKind, sizes: tuple[tuple[int, int], ...]
) -> tuple[Mapping[tuple[int, BufferKind, int], _Tile], int, int]:
    """``(tiles by (camera, kind, channel), width, height)`` of a picture, read-only: cached,
    as the encoder and decoder ask for it per camera and buffer of every frame (uncached it
    was a fifth of encoding a 160x90 server frame).

    Columns filled top to bottom with the tiles from the tallest down (ties in canonical order),
    as tall as gives the picture the fewest pixels (decoding costs per sample): the tallest
    slot, or a stack of two to four slots of one height, up to twice the tallest (ties: the
    lower). 1280x720 + two 640x360 cameras give a 1920x720 colour picture without a gap; their
    half-size 320x180 shadow tiles take 320x184 slots, two of which fit a column of 368 but not
    of 360. At most 1 + 3 x 32 heights are tried (16 cameras, two tile heights each), so that a
    packet's odd camera sizes cannot make the decoder search for long. Deterministic, so
    encoder and decoder agree without a table."""
    tiles = sorted(_tiles(picture, sizes), key=lambda t: -t.h)
    low = _aligned(tiles[0].h)
    candidates = {low} | {k * _aligned(t.h) for t in tiles for k in (2, 3, 4)}
    best: tuple[int, int, dict[tuple[int, BufferKind, int], _Tile], int] | None = None
    for col_h in sorted(c for c in candidates if low <= c <= 2 * low):
        placed, width = _place(tiles, col_h)
        if best is None or width * col_h < best[0]:
            best = (width * col_h, col_h, placed, width)
    assert best is not None
    _, col_h, placed, width = best
    # libx265's smallest picture is 16x16 (8x8 tiles of a tiny camera would be less)
    width, col_h = max(16, width), max(16, col_h)
    if max(width, col_h) > _LEVEL5_SIDE:
        # A side this long needs HEVC level 5, whose coding tree units are at least 32x32,
        # and x265 sizes them down to a short side of 16: it refused to open (a 1024x1
        # camera's geometry picture is 8192x16). Only such pictures grow, so every stream
        # that could be written before keeps its layout.
        width, col_h = max(32, width), max(32, col_h)
    return MappingProxyType(placed), width, col_h


def _put(atlas: npt.NDArray[Any], t: _Tile, a: npt.NDArray[Any]) -> None:
    """Writes ``a`` into its tile and repeats its last column and row to the end of the slot."""
    x1, y1 = t.x + t.w, t.y + t.h
    x2, y2 = t.x + _aligned(t.w), t.y + _aligned(t.h)
    atlas[t.y : y1, t.x : x1] = a
    if x2 > x1:
        atlas[t.y : y1, x1:x2] = atlas[t.y : y1, x1 - 1 : x1]
    if y2 > y1:
        atlas[y1:y2, t.x : x2] = atlas[y1 - 1 : y1, t.x : x2]


def _with_header(payload_bytes: int, entries: int) -> int:
    """``payload_bytes`` plus the rate control's estimate of a packet's header with ``entries``
    buffer entries (stream format version 4: about 10 bytes per entry and 250 for the
    cameras)."""
    return payload_bytes + 10 * entries + 250


def _clear(atlas: npt.NDArray[Any], t: _Tile) -> None:
    """Zeros a tile's whole slot (what an unwritten tile holds)."""
    atlas[t.y : t.y + _aligned(t.h), t.x : t.x + _aligned(t.w)] = 0


def _block_mean(
    a: npt.NDArray[np.float32], weight: npt.NDArray[np.bool_]
) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.bool_]]:
    """Per 2x2 block (odd sizes padded): the mean of ``a`` over the pixels where ``weight`` is set
    (0 where none is), and whether any is set. ``a`` is ``(h, w, c)``. The sums are taken in
    float64: four finite float32 values near the largest one overflow a float32 sum, and their
    mean is finite (``reproj_core::quant::block_mean``; as numpy, a reduction over the two
    short axes of a strided view, it took 20 ms a buffer at 1280x720, 60 % of an encode)."""
    return _native.block_mean(np.ascontiguousarray(a, np.float32), np.ascontiguousarray(weight))


def _every_channel(a: npt.NDArray[np.bool_]) -> npt.NDArray[np.bool_]:
    """``a.all(axis=2)`` of an ``(h, w, c)`` mask, one channel at a time: numpy's reduction over
    the short last axis took 13 ms at 1280x720x3, this 0.5 ms."""
    out: npt.NDArray[np.bool_] = a[..., 0].copy()
    for c in range(1, a.shape[2]):
        out &= a[..., c]
    return out


def _shadow_fill(
    col: npt.NDArray[np.uint8], on: npt.NDArray[np.bool_], subsampled: bool
) -> npt.NDArray[np.uint8]:
    """A shadow colour as coded: itself where ``on``; elsewhere (never read) 0, or with 4:2:0 the
    mean of the ``on`` pixels of its 2x2 block, so that the block's chroma sample is theirs and
    not dragged towards black."""
    if not subsampled:
        return np.where(on[..., None], col, np.uint8(0))
    mean, _ = _block_mean(col.astype(np.float32), on)
    h, w = on.shape
    fill = np.repeat(np.repeat(mean, 2, axis=0), 2, axis=1)[:h, :w]
    return np.where(on[..., None], col, np.rint(fill).astype(np.uint8))


def _hevc_format(picture: BufferKind, chroma: str) -> str:
    if picture == _PIC_GEOMETRY:
        return "gray12le"
    return "yuv444p" if chroma == "444" else "yuv420p"


#: x265 settings of one picture beyond those of all. The geometry and shadow pictures go without
#: HEVC's in-loop filters (deblocking, SAO): they smooth block edges of natural images, but
#: there they cost about a third of the pictures' decoding (nearly empty samples, which FFmpeg
#: filters all the same) for no gain in the error the client sees (docs/stream-format.md, "Why
#: version 4"). ``no-`` is how x265 turns a flag off (``deblock=0`` would mean offsets 0:0).
_PICTURE_PARAMS: dict[BufferKind, list[str]] = {
    _PIC_GEOMETRY: ["no-deblock=1", "no-sao=1"],
    _PIC_SHADOW: ["no-deblock=1", "no-sao=1"],
}

_DECODED_FORMATS: dict[BufferKind, tuple[str, ...]] = {
    # full-range 8-bit pictures come back as the (deprecated) "j" formats for 4:2:0
    _PIC_COLOR: ("yuv444p", "yuv420p", "yuvj444p", "yuvj420p"),
    _PIC_SHADOW: ("yuv444p", "yuv420p", "yuvj444p", "yuvj420p"),
    _PIC_GEOMETRY: ("gray12le",),
}


class _HevcStream:
    """One libx265 encoder of a picture, kept open across frames, reopened when its target
    changes."""

    def __init__(self, picture: BufferKind, w: int, h: int, cfg: CodecConfig) -> None:
        self.picture, self.w, self.h, self.cfg = picture, w, h, cfg
        self.fmt = _hevc_format(picture, cfg.chroma)
        self.ctx: Any = None
        self.target_bps = 0.0
        self.pts = 0
        self.need_idr = True
        self.bits_since_update = 0
        self.frames_since_update = 0

    def open(self, target_bps: float) -> None:
        kbps = max(2, round(target_bps / 1000))
        buf = max(1, round(kbps * self.cfg.vbv_buffer_s))
        ctx = av.CodecContext.create("libx265", "w")
        ctx.width, ctx.height, ctx.pix_fmt = self.w, self.h, self.fmt
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
            # Wavefront rows (x265's default, stated because the decoder's slice threads rely
            # on their entry points).
            "wpp=1",
            "log-level=error",
            "info=0",  # no SEI with the encoder settings (about 2 kB per stream start)
        ]
        if self.picture != _PIC_GEOMETRY:
            params += ["colorprim=bt709", "transfer=bt709", "colormatrix=bt709"]
        params += _PICTURE_PARAMS.get(self.picture, [])
        ctx.options = {
            "preset": self.cfg.preset,
            "tune": "zerolatency",
            "forced-idr": "1",
            "x265-params": ":".join(params),
        }
        try:
            ctx.open()
        except av.FFmpegError as e:  # a ValueError of PyAV's, outside the package's errors
            raise InvalidInputError(
                f"{buffer_name(0, self.picture)}: libx265 cannot encode a {self.w}x{self.h} "
                f"picture of these cameras ({e})") from None
        self.ctx = ctx
        self.target_bps = kbps * 1000.0
        self.need_idr = True

    def encode(self, atlas: npt.NDArray[Any], key: bool) -> bytes:
        if atlas.ndim == 3:
            frame = av.VideoFrame.from_ndarray(atlas, format="rgb24").reformat(
                format=self.fmt,
                dst_colorspace="ITU709",
                dst_color_range="JPEG",
                interpolation="BICUBIC",
            )
        else:
            frame = av.VideoFrame(self.w, self.h, self.fmt)
            _fill_plane(frame.planes[0], atlas)
        frame.pts = self.pts
        self.pts += 1
        if key or self.need_idr:
            frame.pict_type = av.video.frame.PictureType.I
            self.need_idr = False
        out = b"".join(bytes(p) for p in self.ctx.encode(frame))
        self.bits_since_update += 8 * len(out)
        self.frames_since_update += 1
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


def _plane_rows(plane: Any, dtype: type[np.generic]) -> npt.NDArray[Any]:
    """A decoded plane as its rows of ``line_size`` bytes, padding included (no copy): the
    C-contiguous view the dequantisation kernels take."""
    itemsize = np.dtype(dtype).itemsize
    return np.frombuffer(plane, dtype=dtype).reshape(-1, plane.line_size // itemsize)


def _plane_array(
    plane: Any, w: int, h: int, dtype: type[np.generic]
) -> npt.NDArray[Any]:
    """A view of a decoded plane's visible ``w x h`` samples (no copy)."""
    return _plane_rows(plane, dtype)[:h, :w]


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
    if size < 0:  # -1: the frame leaves its size out (streaming compression does)
        raise StreamError(
            f"{where}: zstd payload does not declare its size (expected a frame that declares "
            f"it, at most {limit} bytes)"
        )
    if size > limit:
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
    # unpackbits gives 0/1 bytes: the bool view is the mask without a second array
    return np.unpackbits(np.frombuffer(raw, np.uint8), count=w * h).reshape(h, w).view(np.bool_)


def _unpack_bits(
    where: str,
    payload: bytes | memoryview,
    w: int,
    h: int,
    out: npt.NDArray[np.uint32] | None = None,
) -> npt.NDArray[np.uint32]:
    """The bitfields of a ``w x h`` camera, into ``out`` (``uint32[h, w]``) when given."""
    mbytes = (w * h + 7) // 8
    raw = _unzstd(where, payload, 1 + mbytes + 4 * w * h)
    if len(raw) < 1 + mbytes or raw[0] not in (1, 2, 3, 4):
        raise StreamError(
            f"{where}: malformed shadow bitfield payload ({len(raw)} bytes)"
        )
    n = raw[0]
    # unpackbits gives 0/1 bytes: their bool view is the mask without a copy
    nz = np.unpackbits(np.frombuffer(raw, np.uint8, mbytes, 1), count=w * h).view(np.bool_)
    count = int(np.count_nonzero(nz))
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
    if out is None:
        out = np.empty((h, w), np.uint32)
    out.fill(0)
    out.reshape(-1)[nz] = vals
    return out


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
    scale = float(np.float32((hi - lo) / _CODE_MAX)) if hi - lo >= _MIN_SPAN else 1.0
    q = np.rint((np.where(finite, d, lo).astype(np.float64) - lo) / scale)
    return np.clip(q, 0, _CODE_MAX).astype(np.uint16), scale, lo, invalid


def _quantise_motion(
    m: npt.NDArray[np.float32],
) -> tuple[
    list[npt.NDArray[np.uint16]], tuple[float, float, float], tuple[float, float, float]
]:
    """Per channel: a range that includes 0, ``scale = range / 4093`` (two codes to spare for
    the rounding of ``z0``) and the code ``z0`` of 0, so that ``code * scale + offset`` with
    ``offset = -z0 * scale`` is exactly 0.0 for ``z0``."""
    planes, scales, offsets = [], [], []
    for c in range(3):
        v = m[..., c].astype(np.float64)
        lo, hi = min(float(v.min()), 0.0), max(float(v.max()), 0.0)
        # float32-representable, so the decoder's float32 arithmetic also gives exactly 0.0
        scale = float(np.float32((hi - lo) / (_CODE_MAX - 2))) if hi - lo >= _MIN_SPAN else 1.0
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
    #: The cameras whose shadow bitfields were left out (``CodecConfig.lossless_share``).
    shadows_left_out: tuple[int, ...] = ()


class _WorkerThreads:
    """A lazily started pool of worker threads, ended by :meth:`close` or a ``with`` block."""

    _pool: ThreadPoolExecutor | None = None

    def _executor(self, threads: int, name: str) -> ThreadPoolExecutor:
        if self._pool is None:
            self._pool = ThreadPoolExecutor(
                max_workers=threads, thread_name_prefix=name
            )
        return self._pool

    def close(self) -> None:
        """Ends the worker threads. The object stays usable: a later call that needs them
        starts them again (and they run until the next :meth:`close`)."""
        if self._pool is not None:
            self._pool.shutdown()
            self._pool = None

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _group_share(cfg: CodecConfig, picture: BufferKind, motion: bool) -> float:
    if picture == _PIC_COLOR:
        return cfg.color_share
    if picture == _PIC_SHADOW:
        return cfg.shadow_color_share
    return cfg.depth_share + (cfg.motion_share if motion else 0.0)


class StreamEncoder(_WorkerThreads):
    """Encodes server frames into packets: one libx265 encoder per picture (colour, geometry,
    shadow colours), each holding every camera's tiles.

    The first frame fixes the layout (number of cameras and their sizes); later frames must keep
    it. One frame is encoded at a time (it is a stream): a second thread's :meth:`encode` while
    one runs is refused. Internally the pictures of a frame are encoded in parallel
    (``config.threads``, 0 = one per CPU), on worker threads that run until :meth:`close` (or
    the end of a ``with`` block).

    # Errors
    :class:`~splitrender.errors.InvalidInputError` for a frame that does not match the layout or
    the camera shares, and for an :meth:`encode` while another thread's runs."""

    @checked(config=optional(instances(CodecConfig)))
    def __init__(self, config: CodecConfig | None = None) -> None:
        self.config = config if config is not None else CodecConfig()
        # Held by encode: two frames at once would drive the same x265 contexts from two
        # threads, which crashes the process (libx265 is not reentrant per encoder).
        self._encoding = threading.Lock()
        self._layout: tuple[tuple[int, int], ...] | None = None
        self._streams: dict[BufferKind, _HevcStream] = {}
        self._frames = 0
        self._gain = 1.0
        # The target in effect over the frames since the last update, and whether it was
        # lowered since (set_bitrate): the gain is measured against the former.
        self._gop_total = self.config.bitrate_mbps * 1e6
        self._lowered = False
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
            if not self.config.uncompressed:
                # The decoder places no tile beyond MAX_SIDE (a picture that long was
                # encoded, and every packet then refused): cameras a few pixels tall or wide
                # tile into one long row or column.
                over = oversized_picture(layout)
                if over is not None:
                    name, pw, ph = over
                    raise InvalidInputError(
                        f"frame {frame.index}: with cameras of {layout}, {name} would be "
                        f"{pw}x{ph}, beyond the codec's {MAX_SIDE} pixels a side; expected "
                        "cameras nearer to square, or CodecConfig(uncompressed=True)")
            self._layout = layout
        elif layout != self._layout:
            raise InvalidInputError(
                f"frame {frame.index}: camera sizes {layout} differ from the stream's {self._layout}"
            )

    @checked(frame=instances(ServerFrame))
    def encode(self, frame: ServerFrame) -> bytes:
        """One packet holding ``frame`` (see :mod:`splitrender.codec.stream`).

        Raises:
            InvalidInputError: for a buffer of the wrong dtype or shape (naming it, e.g.
                ``frame.aux[0].color``), a frame that does not match the stream's layout, or
                while another thread encodes with this encoder.
        """
        if not self._encoding.acquire(blocking=False):
            raise InvalidInputError(
                "StreamEncoder.encode: this encoder is encoding a frame in another thread; a "
                "stream is encoded one frame at a time, in order (use one encoder per stream)")
        try:
            return self._encode(frame)
        finally:
            self._encoding.release()

    def close(self) -> None:
        """Ends the worker threads, after a frame being encoded in another thread. The encoder
        keeps its state: a later :meth:`encode` goes on with the stream (its threads start
        again until the next :meth:`close`)."""
        with self._encoding:
            super().close()

    def _encode(self, frame: ServerFrame) -> bytes:
        """:meth:`encode` on one thread at a time."""
        self._check_layout(frame)
        assert self._layout is not None
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
            # A picture that skips this frame (no shadows) restarts with an IDR later.
            for s in self._streams.values():
                s.need_idr = True
        atlases: dict[BufferKind, npt.NDArray[Any]] = {}
        if not cfg.uncompressed:
            for pic in PICTURE_KINDS:
                _, pw, ph = _layout(pic, self._layout)
                atlases[pic] = (
                    np.zeros((ph, pw), np.uint16)
                    if pic == _PIC_GEOMETRY
                    else np.zeros((ph, pw, 3), np.uint8)
                )
        per_camera = [
            self._raw_jobs(ci, cf) if cfg.uncompressed else self._camera_jobs(ci, cf, atlases)
            for ci, cf in enumerate(cams)
        ]
        left_out = () if cfg.uncompressed else self._leave_out_shadows(per_camera, atlases)
        jobs = [j for cj in per_camera for j in cj]
        used = {TILE_PICTURE[j.kind] for j in jobs if j.codec == Codec.TILE}
        motion = any(
            j.codec == Codec.TILE and j.kind in (_K.MOTION_FWD, _K.MOTION_BWD)
            for j in jobs
        )
        for pic in PICTURE_KINDS:
            if pic in used:
                jobs.append(self._picture_job(pic, atlases[pic], key))
        lossless = sum(len(j.payload) for j in jobs if isinstance(j.payload, bytes))
        if not cfg.uncompressed:
            self._update_rates(jobs, lossless, key and rates_at_key, motion)
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
            {buffer_name(0, k): s.target_bps for k, s in self._streams.items()},
            left_out,
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

    @checked(mbps=floats(positive=True, hi=MAX_BITRATE_MBPS))
    def set_bitrate(self, mbps: float) -> None:
        """Moves the stream's target to ``mbps``. The HEVC encoders take it at the next key
        frame, regular or requested (x265 is reopened, which needs an IDR), so a caller that
        needs it sooner also calls :meth:`request_key_frame`. The shortfall accounting restarts
        from here, so that the new target is not pulled towards the old one.

        Raises:
            InvalidInputError: for a rate that is not a finite number > 0.
        """
        import dataclasses

        self._lowered = self._lowered or mbps < self.config.bitrate_mbps
        self.config = dataclasses.replace(self.config, bitrate_mbps=mbps)
        self._bits_total = round(mbps * 1e6 * self._frames / self.config.fps)
        self._rate_changed = True

    # -- rate control -------------------------------------------------------------------------

    def _update_rates(
        self, jobs: list[_Job], lossless: int, key: bool, motion: bool
    ) -> None:
        """At key frames: (re)opens the HEVC encoders with targets from the budget left after the
        lossless parts, corrected by the rate achieved over the last GOP."""
        cfg = self.config
        total = cfg.bitrate_mbps * 1e6
        lossy = [j.kind for j in jobs if j.codec == Codec.HEVC]
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
            # A picture that coded nothing in some frames (its buffers left out or absent there)
            # did not fall short of its target in them: those frames count at its target, so
            # that the gain corrects the encoders' shortfall and not the pictures' idleness (an
            # idle shadow picture had read as a shortfall, and the next GOP overshot: +10 % over
            # two GOPs on the courtyard at 512×288 and the paper's 20 Mb/s). The deficit term
            # above still brings the stream's total to the target.
            achieved_bps += sum(
                s.target_bps * (1 - s.frames_since_update / self._frames_since_update)
                for s in self._streams.values()
            )
            if cfg.rate_feedback and achieved_bps > 0:
                # Multiplicative correction, bounded so one odd GOP cannot run away. The GOP
                # ran at the target then in effect: after set_bitrate, what it achieved says
                # how the encoders met that one, not the new one (measured against the new
                # one, a drop read as an overshoot and a climb as a shortfall).
                then = wanted if self._gop_total == total else wanted * self._gop_total / total
                ratio = min(max(then / achieved_bps, 1 / 3), 3.0)
                self._gain = min(max(self._gain * ratio, 0.25), 8.0)
            if self._lowered:
                # A gain above 1 was learned where the encoders fell short of a higher target
                # (often: nothing left to spend the bits on) and promises nothing at a lower
                # one; kept, it overshoots at once on a link that was just found narrower,
                # while a shortfall is corrected at the next update.
                self._gain = min(self._gain, 1.0)
        elif not self._streams:
            # First frame: this frame's lossless bytes and its packet header.
            self._lossless_bps = 8 * _with_header(lossless, len(jobs)) * cfg.fps
        budget = max(total - self._lossless_bps, 0.05 * total) * self._gain
        shares = {k: _group_share(cfg, k, motion) for k in lossy}
        norm = sum(shares.values()) or 1.0
        assert self._layout is not None
        for pic in lossy:
            t = budget * shares[pic] / norm
            s = self._streams.get(pic)
            if not key and s is not None:
                continue  # mid-GOP: only open the new streams
            if s is None:
                _, pw, ph = _layout(pic, self._layout)
                s = self._streams[pic] = _HevcStream(pic, pw, ph, cfg)
                s.open(t)
            elif abs(t - s.target_bps) > 0.03 * s.target_bps:
                s.open(t)
            s.bits_since_update = 0
            s.frames_since_update = 0
        if not key:
            return
        for pic, s in self._streams.items():
            if pic not in lossy:
                s.bits_since_update = 0
                s.frames_since_update = 0
        self._lossless_since_update = 0
        self._frames_since_update = 0
        self._gop_total = total
        self._lowered = False

    # -- buffers --------------------------------------------------------------------------------

    def _leave_out_shadows(
        self, per_camera: list[list[_Job]], atlases: dict[BufferKind, npt.NDArray[Any]]
    ) -> tuple[int, ...]:
        """Leaves out the shadow bitfields (and so the shadow colours) of the auxiliary cameras,
        the last first, then of the main camera, while this frame's lossless parts exceed
        ``lossless_share`` of the target per frame; returns the cameras left out. A camera left
        out is coded exactly as one without moving shadows: ZERO entries and zero tiles. Below
        the cap nothing changes, byte for byte.

        Why these: the bitfields are lossless and cost what the shadows' motion makes them cost
        whatever the target (~1.5 % of the pixels of a scene with moving soft shadows, some
        9 kB per direction and 1280×720 camera), while without them a pixel only loses the
        change of its shadow between the two server frames (its colour is that of the frame it
        comes from); the auxiliary cameras fill disocclusions only, so theirs go first. (The
        shadow picture then codes nothing in that frame; the rate control counts such frames
        apart, ``_update_rates``.)"""
        cfg = self.config
        assert self._layout is not None
        # The lossless payloads and the packet header, the pictures' entries included.
        cost = _with_header(
            sum(len(j.payload) for cj in per_camera for j in cj if isinstance(j.payload, bytes)),
            sum(len(cj) for cj in per_camera) + len(PICTURE_KINDS),
        )
        cap = cfg.lossless_share * cfg.bitrate_mbps * 1e6 / (8 * cfg.fps)
        shadow_tiles, _, _ = _layout(_PIC_SHADOW, self._layout)
        left_out: list[int] = []
        for ci in [*range(len(per_camera) - 1, 0, -1), 0]:
            if cost <= cap:
                break
            bits = [j for j in per_camera[ci] if j.kind in _SHADOW_BITS and j.codec == Codec.ZSTD]
            if not bits:
                continue
            cost -= sum(len(j.payload) for j in bits if isinstance(j.payload, bytes))
            shadows = {k for j in bits for k in _SHADOW_OF[j.kind]}
            for j in per_camera[ci]:
                if j.kind in shadows and j.codec == Codec.TILE:
                    _clear(atlases[_PIC_SHADOW], shadow_tiles[(ci, j.kind, 0)])
            per_camera[ci] = [
                _Job(ci, j.kind, j.w, j.h, Codec.ZERO) if j.kind in shadows else j
                for j in per_camera[ci]
            ]
            left_out.append(ci)
        return tuple(left_out)

    def _raw_jobs(self, ci: int, cf: CameraFrame) -> list[_Job]:
        """Every buffer as its bytes (``uncompressed``)."""
        w, h = cf.camera.width, cf.camera.height
        arrays: list[tuple[BufferKind, npt.NDArray[Any]]] = [
            (_K.COLOR, cf.color),
            (_K.DEPTH, cf.depth.astype("<f4")),
        ]
        for d in ("fwd", "bwd"):
            m = getattr(cf, f"motion_{d}")
            if m is not None:
                arrays.append((_MOTION[d][0], m.astype("<f4")))
            s = getattr(cf, f"shadow_{d}")
            if s is not None:
                kb, kmin, kmax = _SHADOW[d]
                arrays += [(kb, s.bits.astype("<u4")), (kmin, s.s_min), (kmax, s.s_max)]
        return [_Job(ci, k, w, h, Codec.RAW, a.tobytes()) for k, a in arrays]

    def _camera_jobs(
        self, ci: int, cf: CameraFrame, atlases: dict[BufferKind, npt.NDArray[Any]]
    ) -> list[_Job]:
        """The lossless parts and tile entries of one camera; its tiles go into ``atlases``."""
        cfg = self.config
        assert self._layout is not None
        w, h = cf.camera.width, cf.camera.height
        lvl = cfg.zstd_level
        colour_tiles, _, _ = _layout(_PIC_COLOR, self._layout)
        geo_tiles, _, _ = _layout(_PIC_GEOMETRY, self._layout)
        shadow_tiles, _, _ = _layout(_PIC_SHADOW, self._layout)
        _put(atlases[_PIC_COLOR], colour_tiles[(ci, _K.COLOR, 0)], cf.color)
        jobs = [_Job(ci, _K.COLOR, w, h, Codec.TILE)]
        q, scale, lo, invalid = _quantise_depth(cf.depth)
        _put(atlases[_PIC_GEOMETRY], geo_tiles[(ci, _K.DEPTH, 0)], q)
        jobs.append(
            _Job(ci, _K.DEPTH, w, h, Codec.TILE, b"", (scale, 0, 0), (lo, 0, 0))
        )
        if invalid is not None:
            jobs.append(
                _Job(ci, _K.DEPTH_INVALID, w, h, Codec.ZSTD, _pack_mask(invalid, lvl))
            )
        for d in ("fwd", "bwd"):
            m = getattr(cf, f"motion_{d}")
            kind, kstatic, kinvalid = _MOTION[d]
            if m is not None:
                finite = _every_channel(np.isfinite(m))
                mm = (
                    m if finite.all() else np.where(finite[..., None], m, np.float32(0))
                )
                static = _every_channel(mm == 0)
                if static.all():
                    jobs.append(_Job(ci, kind, w, h, Codec.ZERO))
                else:
                    # With the static mask, static pixels decode to 0 anyway: the half-size
                    # motion is the mean of the moving ones only (invalid ones never count).
                    weight = finite & ~static if cfg.exact_static_motion else finite
                    half, _ = _block_mean(mm, weight)
                    planes, sc, off = _quantise_motion(half)
                    for c in range(3):
                        _put(
                            atlases[_PIC_GEOMETRY], geo_tiles[(ci, kind, c)], planes[c]
                        )
                    jobs.append(_Job(ci, kind, w, h, Codec.TILE, b"", sc, off))
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
                    # Half size: per 2x2 block the mean of its set pixels (the decoder gives
                    # each set pixel its block's sample), then the fill of the unread samples.
                    half, on = _block_mean(col.astype(np.float32), nz)
                    filled = _shadow_fill(
                        np.rint(half).astype(np.uint8), on, cfg.chroma == "420"
                    )
                    _put(atlases[_PIC_SHADOW], shadow_tiles[(ci, k, 0)], filled)
                    jobs.append(_Job(ci, k, w, h, Codec.TILE))
        return jobs

    def _picture_job(
        self, picture: BufferKind, atlas: npt.NDArray[Any], key: bool
    ) -> _Job:
        def run() -> bytes:
            return self._streams[picture].encode(atlas, key)

        assert self._layout is not None
        w, h = self._layout[0]
        return _Job(0, picture, w, h, Codec.HEVC, run)


# --------------------------------------------------------------------------------------------
# Decoder


def _hevc_decoder(width: int, height: int, threads: int = 1) -> Any:
    """An HEVC decoder that refuses pictures larger than ``width x height`` pixels.

    The payload is untrusted: its sequence parameter set could declare a picture far larger than
    the packet's cameras imply, and FFmpeg would allocate it before we could compare sizes.
    FFmpeg's ``max_pixels`` limit makes it reject such a picture before allocating. The limit
    allows each side to be rounded up to a whole 64-pixel coding tree unit, since the coded size
    of a picture (which FFmpeg checks) may exceed its cropped size by that much.

    ``threads > 1`` turns on slice threading only (over the wavefront rows): frame threading
    would return each picture one call late, and the client needs it as soon as it arrives."""
    ctx = av.CodecContext.create("hevc", "r")
    ctx.thread_type = "SLICE" if threads > 1 else "NONE"
    ctx.thread_count = threads
    ctx.options = {"max_pixels": str((-(-width // 64) * 64) * (-(-height // 64) * 64))}
    return ctx


_Decoded = dict[tuple[int, BufferKind], npt.NDArray[Any]]


class _Outputs:
    """The arrays of the last few decoded frames, reused for a later frame once nobody but this
    pool holds them.

    A new array costs more than the values written into it: the kernel's first write to each
    4 kB page faults it in (about 60 MB per 1280x720 server frame, a third of the decode CPU
    time measured in docs/performance.md). The client keeps the two frames of its pair, so the
    arrays of the frame before those are free again by the time the next one decodes. An array
    is reused only when CPython's reference count says the pool's list is its only holder: any
    ServerFrame, view or buffer export that can still reach it holds a reference, so a frame
    handed out is never overwritten."""

    #: Arrays kept per buffer: the client's pair, the frame being decoded and one spare.
    DEPTH = 4

    def __init__(self) -> None:
        self._arrays: dict[tuple[int, BufferKind], list[npt.NDArray[Any]]] = {}

    def take(
        self, key: tuple[int, BufferKind], shape: tuple[int, ...], dtype: type[np.generic]
    ) -> npt.NDArray[Any]:
        """A C-contiguous ``shape`` array of ``dtype`` with undefined contents, for ``key``'s
        buffer of the frame being decoded (each key is taken by one thread at a time)."""
        kept = self._arrays.setdefault(key, [])
        for i in range(len(kept)):
            # 2: the list's reference and getrefcount's argument, nothing else.
            if sys.getrefcount(kept[i]) == 2 and kept[i].shape == shape and kept[i].dtype == dtype:
                a = kept.pop(i)
                kept.append(a)  # most recently handed out last
                return a
        a = np.empty(shape, dtype)
        if len(kept) >= self.DEPTH:
            kept.pop(0)  # the oldest: still held by the client, no longer ours to reuse
        kept.append(a)
        return a


class StreamDecoder(_WorkerThreads):
    """Decodes packets into :class:`~splitrender.types.ServerFrame` values, in order.

    Decoding starts at a key frame; after that every packet must follow the previous one
    (frame index + 1), or be a key frame. The HEVC decoders live across key frames (an IDR
    restarts a picture's references; a fresh FFmpeg decoder would allocate, and page-fault in,
    all its picture buffers again, which cost more than the decoding of a nearly empty picture);
    they are created afresh when a picture's size changes and after a packet that failed once its
    pictures were being decoded.
    :meth:`decode` may be called from any thread; calls on one instance run one at a time (a
    stream has an order), and the HEVC decoding, which is most of the time, releases the GIL.

    ``threads`` (0 = one per CPU) is the number of pictures decoded at once and the slice threads
    of each picture's decoder (at least two for the colour picture where ``threads`` > 1). The
    worker threads start with the first packet and run until :meth:`close` (or the end of a
    ``with`` block): close a decoder when its stream ends.

    # Errors
    :class:`~splitrender.errors.StreamError` naming the frame and buffer for anything wrong in a
    packet (see :func:`splitrender.codec.stream.unpack_packet`), a payload that does not decode or does
    not match its table entry, a missing buffer, or a non-key packet without its predecessor."""

    @checked(threads=ints(0, MAX_THREADS), max_pixels=ints(1, 1 << 40))
    def __init__(self, threads: int = 0, max_pixels: int = MAX_PIXELS) -> None:
        # Per picture: its size and the FFmpeg decoder made for it.
        self._decoders: dict[BufferKind, tuple[tuple[int, int], Any]] = {}
        self._last: int | None = None
        # The camera sizes of the last decoded frame: a frame that is not a key frame keeps them.
        self._sizes: tuple[tuple[int, int], ...] = ()
        self._threads = threads or (os.cpu_count() or 1)
        self._lock = threading.Lock()
        self._out = _Outputs()
        self.max_pixels = max_pixels

    @checked(data=buffers())
    def decode(self, data: bytes | memoryview) -> ServerFrame:
        """The server frame held by one packet."""
        with self._lock:
            try:
                return self._decode(data)
            except BaseException:
                # A packet refused before any picture was touched (unparsable, say) leaves the
                # stream where it was. Otherwise the next packet must be a key frame, and its
                # pictures start from new decoders, free of whatever state the failed one left.
                if self._last is None:
                    self._decoders = {}
                raise

    def _decode(self, data: bytes | memoryview) -> ServerFrame:
        p = unpack_packet(data)
        where = f"frame {p.index}"
        total = 0
        for i, c in enumerate(p.cameras):
            total += c.width * c.height
            if c.width * c.height > self.max_pixels:
                raise StreamError(
                    f"{where}, {camera_name(i)}: {c.width}x{c.height} exceeds the decoder's "
                    f"limit of {self.max_pixels} pixels"
                )
        # The pictures hold every camera: bound the sum too, before any of them is allocated.
        if total > self.max_pixels:
            raise StreamError(
                f"{where}: the cameras hold {total} pixels together, beyond the decoder's "
                f"limit of {self.max_pixels}"
            )
        if not p.key and (self._last is None or p.index != self._last + 1):
            after = "none" if self._last is None else str(self._last)
            self._last = None
            raise StreamError(
                f"{where}: not a key frame and it does not follow the last decoded frame "
                f"({after}); decoding must start at a key frame"
            )
        sizes = tuple((c.width, c.height) for c in p.cameras)
        if not p.key and sizes != self._sizes:
            # Its pictures predict from pictures of another layout: it failed as "picture.shadow:
            # HEVC payload of 505 bytes did not decode (0 pictures)", or, where the pictures
            # kept their sizes, decoded from the wrong tiles.
            self._last = None
            raise StreamError(
                f"{where}: camera sizes {_sizes_text(sizes)} differ from frame {p.index - 1}'s "
                f"{_sizes_text(self._sizes)}; the cameras may change only at a key frame"
            )
        seen: dict[tuple[int, BufferKind], BufferEntry] = {}
        for b in p.buffers:
            if (b.camera, b.kind) in seen:
                raise StreamError(f"{where}, {b.name}: buffer appears twice")
            seen[(b.camera, b.kind)] = b
        for b in p.buffers:
            if b.codec == Codec.TILE and (0, TILE_PICTURE[b.kind]) not in seen:
                raise StreamError(
                    f"{where}, {b.name}: a tile of {buffer_name(0, TILE_PICTURE[b.kind])}, "
                    "which the packet does not hold"
                )
        self._last = None  # until this frame has decoded fully
        pictures = [b for b in p.buffers if b.codec == Codec.HEVC]
        for b in pictures:
            # Odd camera shapes waste room in the columns: bound the picture itself too, at
            # four times max_pixels (what format 3's full-size shadow picture of one camera
            # needed; format 4's largest, geometry, needs 2.5 times plus slot padding).
            _, pw, ph = _layout(b.kind, sizes)
            if pw * ph > 4 * self.max_pixels + (1 << 16):
                raise StreamError(
                    f"{where}, {b.name}: a {pw}x{ph} picture for these cameras exceeds the "
                    f"decoder's limit of {4 * self.max_pixels + (1 << 16)} pixels"
                )
            if max(pw, ph) > MAX_SIDE:  # no encoder of ours writes one (StreamEncoder)
                raise StreamError(
                    f"{where}, {b.name}: a {pw}x{ph} picture for these cameras; expected "
                    f"at most {MAX_SIDE} pixels a side"
                )
        # The colour and geometry pictures start at once on the workers. This thread meanwhile
        # unpacks the lossless parts, hands their static and invalid masks to the geometry
        # picture's worker (which applies them once its picture is decoded), then decodes the
        # (quickest) shadow picture itself and converts the shadow colours: all of it beside
        # the two long pictures. Before, the geometry picture waited for the lossless parts
        # and for a worker to finish the shadow picture, and was the last to end in the
        # frames that are not key frames (docs/performance.md).
        parallel = len(pictures) > 1 and self._threads > 1
        # This thread's pictures: the shadow picture, or all of them without workers.
        mine = [b for b in pictures if not parallel or b.kind == _PIC_SHADOW]
        futs: list[Future[tuple[_Decoded, list[npt.NDArray[np.uint8]]]]] = []
        masks: Future[_Decoded] = Future()
        if parallel:
            pool = self._executor(min(self._threads, 3), "splitrender-dec")
            futs = [
                pool.submit(self._picture, p.index, b, sizes, seen, masks.result)
                for b in sorted(pictures, key=lambda b: b.kind != _PIC_COLOR)
                if b.kind != _PIC_SHADOW
            ]
        errors: list[StreamError] = []
        lossless: _Decoded = {}
        parts = []
        shadow_rgb: _Decoded = {}
        try:
            try:
                lossless = _lossless(p, seen, self._out)
                masks.set_result(lossless)
            except StreamError as e:
                errors.append(e)
                masks.set_exception(e)  # the geometry worker stops with it
            for b in mine:
                if errors:
                    break
                try:
                    part = self._picture(p.index, b, sizes, seen, masks.result)
                except StreamError as e:
                    errors.append(e)
                    continue
                parts.append(part)
                if part[1]:  # the shadow picture's planes
                    shadow_rgb = self._shadow_colours(p, seen, lossless, part[1])
            for f in futs:
                try:
                    parts.append(f.result())
                except StreamError as e:
                    if e is not masks.exception():
                        errors.append(e)
        finally:
            if not masks.done():  # an exception other than a StreamError: free the workers
                masks.set_exception(StreamError(f"frame {p.index}: decoding was interrupted"))
            wait(futs)  # none may outlive this call (thread safety)
        if errors:
            raise errors[0]
        results: _Decoded = dict(lossless)
        for out, _ in parts:
            results.update(out)
        cams = [
            self._camera(p, ci, rec, seen, results, shadow_rgb)
            for ci, rec in enumerate(p.cameras)
        ]
        self._last, self._sizes = p.index, sizes
        return ServerFrame(
            index=p.index, time=p.time, main=cams[0], aux=tuple(cams[1:])
        )

    def _picture(
        self,
        index: int,
        b: BufferEntry,
        sizes: tuple[tuple[int, int], ...],
        seen: dict[tuple[int, BufferKind], BufferEntry],
        masks: Callable[[], _Decoded],
    ) -> tuple[_Decoded, list[npt.NDArray[np.uint8]]]:
        """Decodes one picture: ``(colour and geometry buffers, shadow picture planes)``. The
        shadow colours are converted later, where their bitfields are set. Depth and motion
        leave with the static and invalid masks (the unpacked lossless parts, which ``masks()``
        returns, waiting for them if need be, once the picture is decoded) applied."""
        where = f"frame {index}, {b.name}"
        tiles, pw, ph = _layout(b.kind, sizes)
        size, ctx = self._decoders.get(b.kind, ((0, 0), None))
        if ctx is None or size != (pw, ph):
            threads = max(1, self._threads - len(PICTURE_KINDS) + 1)
            if b.kind == _PIC_COLOR:
                # A key frame's colour picture is about half of its FFmpeg time, on one worker
                # after the other pictures are done: two slice threads let the other core help
                # (1280x720 on 2 cores: a server frame's wall time 0.59 instead of 0.65 of its
                # CPU time, a key frame's 0.68 instead of 0.77; docs/performance.md). The decoded
                # pictures are the same bytes on any number of threads (tests/test_codec.py).
                threads = max(threads, min(self._threads, 2))
            ctx = _hevc_decoder(pw, ph, threads)
            self._decoders[b.kind] = ((pw, ph), ctx)
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
        fmt = f.format.name
        if (f.width, f.height) != (pw, ph) or fmt not in _DECODED_FORMATS[b.kind]:
            raise StreamError(
                f"{where}: HEVC picture is {f.width}x{f.height} {fmt}, expected "
                f"{pw}x{ph} {'/'.join(_DECODED_FORMATS[b.kind])}"
            )
        out: _Decoded = {}
        if b.kind == _PIC_SHADOW:
            return out, [_plane_rows(f.planes[c], np.uint8) for c in range(3)]
        if b.kind == _PIC_COLOR:
            rgb = f.reformat(
                format="rgb24",
                src_colorspace="ITU709",
                src_color_range="JPEG",
                interpolation="BICUBIC",
            )
            full = _plane_array(rgb.planes[0], 3 * pw, ph, np.uint8).reshape(ph, pw, 3)
            for (ci, kind, _), t in tiles.items():
                if seen.get((ci, kind), b).codec == Codec.TILE:
                    dst = self._out.take((ci, kind), (t.h, t.w, 3), np.uint8)
                    np.copyto(dst, full[t.y : t.y + t.h, t.x : t.x + t.w])
                    out[(ci, kind)] = dst
            return out, []
        # Dequantised in the core (reproj_core::dequant): code * scale + offset in float32,
        # motion from its half-size tiles, the lossless masks applied in the same pass.
        q = _plane_rows(f.planes[0], np.uint16)
        lossless = masks()
        for ci, (w, h) in enumerate(sizes):
            entry = seen.get((ci, _K.DEPTH))
            if entry is not None and entry.codec == Codec.TILE:
                t = tiles[(ci, _K.DEPTH, 0)]
                out[(ci, _K.DEPTH)] = _native.dequantise_depth(
                    q, t.x, t.y, w, h, entry.scale[0], entry.offset[0],
                    lossless.get((ci, _K.DEPTH_INVALID)),
                    self._out.take((ci, _K.DEPTH), (h, w), np.float32),
                )
            for kind in (_K.MOTION_FWD, _K.MOTION_BWD):
                entry = seen.get((ci, kind))
                if entry is not None and entry.codec == Codec.TILE:
                    _, kstatic, kinvalid = _MOTION[
                        "fwd" if kind == _K.MOTION_FWD else "bwd"
                    ]
                    ct = [tiles[(ci, kind, c)] for c in range(3)]
                    out[(ci, kind)] = _native.dequantise_motion(
                        q, [(t.x, t.y) for t in ct], w, h, entry.scale, entry.offset,
                        lossless.get((ci, kstatic)), lossless.get((ci, kinvalid)),
                        self._out.take((ci, kind), (h, w, 3), np.float32),
                    )
        return out, []

    def _shadow_colours(
        self,
        p: Packet,
        seen: dict[tuple[int, BufferKind], BufferEntry],
        lossless: _Decoded,
        planes: list[npt.NDArray[np.uint8]],
    ) -> _Decoded:
        """Every shadow colour tile of the packet whose bitfield came as zstd, converted (BT.709,
        full range) where that bitfield is set; :meth:`_camera` refuses the other tiles."""
        sizes = tuple((c.width, c.height) for c in p.cameras)
        tiles, _, _ = _layout(_PIC_SHADOW, sizes)
        luma, cb, cr = planes
        out: _Decoded = {}
        for ci, (w, h) in enumerate(sizes):
            for kb, kmin, kmax in _SHADOW.values():
                bits = lossless.get((ci, kb))
                if bits is None:
                    continue
                for k in (kmin, kmax):
                    b = seen.get((ci, k))
                    if b is not None and b.codec == Codec.TILE:
                        t = tiles[(ci, k, 0)]
                        out[(ci, k)] = _native.shadow_colour(
                            luma, cb, cr, t.x, t.y, bits,
                            self._out.take((ci, k), (h, w, 3), np.uint8), half=True,
                        )
        return out

    def _camera(
        self,
        p: Packet,
        ci: int,
        rec: CameraRecord,
        seen: dict[tuple[int, BufferKind], BufferEntry],
        results: _Decoded,
        shadow_rgb: _Decoded,
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
            if b.codec in (Codec.TILE, Codec.ZSTD):
                return results.get((ci, kind))
            if b.codec == Codec.ZERO:
                return np.zeros(shape, dtype)
            want = int(np.prod(shape)) * np.dtype(dtype).itemsize
            if len(b.payload) != want:
                raise StreamError(
                    f"{where}: raw payload of {len(b.payload)} bytes, expected {want}"
                )
            raw: npt.NDArray[Any] = (
                np.frombuffer(b.payload, dtype).reshape(shape).copy()
            )
            return raw

        def mask(kind: BufferKind) -> npt.NDArray[np.bool_] | None:
            b = seen.get((ci, kind))
            if b is not None and b.codec == Codec.RAW:
                raise StreamError(f"frame {p.index}, {b.name}: a mask cannot be raw")
            return get(kind, "bool", (h, w))

        color = get(_K.COLOR, "u1", (h, w, 3), required=True)
        depth = get(_K.DEPTH, "<f4", (h, w), required=True)
        assert color is not None and depth is not None
        # Tiles left their picture with the masks applied; raw buffers get them here.
        inv = mask(_K.DEPTH_INVALID)
        if inv is not None and seen[(ci, _K.DEPTH)].codec != Codec.TILE:
            np.copyto(depth, np.float32(np.nan), where=inv)
        motions: dict[str, npt.NDArray[np.float32] | None] = {}
        shadows: dict[str, ShadowBuffers | None] = {}
        for d in ("fwd", "bwd"):
            kind, kstatic, kinvalid = _MOTION[d]
            m = get(kind, "<f4", (h, w, 3))
            if m is not None:
                st, iv = mask(kstatic), mask(kinvalid)  # checked for tiles too
                raw = seen[(ci, kind)].codec != Codec.TILE
                if st is not None and raw:
                    m[st] = 0.0
                if iv is not None and raw:
                    np.copyto(m, np.float32(np.nan), where=iv[..., None])
            motions[d] = m
            kb, kmin, kmax = _SHADOW[d]
            bits = get(kb, "<u4", (h, w))
            if bits is None:
                shadows[d] = None
                continue
            colours = []
            for k in (kmin, kmax):
                b = seen.get((ci, k))
                if b is not None and b.codec == Codec.TILE:
                    if seen[(ci, kb)].codec != Codec.ZSTD:
                        raise StreamError(
                            f"frame {p.index}, {b.name}: a tile needs its bitfield as zstd"
                        )
                    if (ci, k) not in shadow_rgb:
                        raise StreamError(
                            f"frame {p.index}, {b.name}: a tile without its shadow picture"
                        )
                    colours.append(shadow_rgb[(ci, k)])
                else:
                    c = get(k, "u1", (h, w, 3), required=True)
                    assert c is not None
                    colours.append(c)
            shadows[d] = ShadowBuffers(bits, colours[0], colours[1])
        return CameraFrame(
            camera=Camera(rec.view, rec.proj, w, h),
            color=color,
            depth=depth,
            motion_fwd=motions["fwd"],
            motion_bwd=motions["bwd"],
            shadow_fwd=shadows["fwd"],
            shadow_bwd=shadows["bwd"],
        )


def _sizes_text(sizes: tuple[tuple[int, int], ...]) -> str:
    """``"64x36, 32x18"``: a frame's camera sizes, main first."""
    return ", ".join(f"{w}x{h}" for w, h in sizes)


def _lossless(
    p: Packet, seen: dict[tuple[int, BufferKind], BufferEntry], outputs: _Outputs
) -> _Decoded:
    """Every zstd buffer of a packet: masks as bool arrays, bitfields as uint32 (in arrays of
    ``outputs``: they go to the client)."""
    out: _Decoded = {}
    for (ci, kind), b in seen.items():
        if b.codec != Codec.ZSTD:
            continue
        where = f"frame {p.index}, {b.name}"
        w, h = p.cameras[ci].width, p.cameras[ci].height
        if kind in (_K.SHADOW_FWD_BITS, _K.SHADOW_BWD_BITS):
            out[(ci, kind)] = _unpack_bits(
                where, b.payload, w, h, outputs.take((ci, kind), (h, w), np.uint32)
            )
        elif kind in (
            _K.DEPTH_INVALID,
            _K.MOTION_FWD_STATIC,
            _K.MOTION_BWD_STATIC,
            _K.MOTION_FWD_INVALID,
            _K.MOTION_BWD_INVALID,
        ):
            out[(ci, kind)] = _unpack_mask(where, b.payload, w, h)
        else:
            raise StreamError(f"{where}: zstd is not a codec of this buffer kind")
    return out


def decode_packets(packets: Sequence[bytes]) -> list[ServerFrame]:
    """Decodes a whole run of packets (starting at a key frame) with one decoder, every frame
    held (one pass of :class:`DecodedStream`)."""
    return list(DecodedStream(packets))


class DecodedStream:
    """The server frames of a run of packets (starting at a key frame), decoded as they are
    iterated: what :func:`~splitrender.client.playback.play` consumes for a compressed stream
    without holding it decoded.

    A decoded 1280x720 server frame with its auxiliary cameras takes about 50 MB (docs/sweeps.md):
    a 10 s run at 10 FPS held whole (:func:`decode_packets`) is 5 GB per process, where a client
    holds its pair. Iterated, one frame is decoded when the next is asked for, and the decoder's
    arrays are reused once the frames before are dropped (``_Outputs``). Each iteration decodes the
    packets anew with its own :class:`StreamDecoder` (closed when the iteration ends or is
    dropped): a second eye or method pays the decoding again instead of the memory.

    # Errors
    As :meth:`StreamDecoder.decode`, raised by the iteration at the packet that fails."""

    @checked(packets=items(buffers()))
    def __init__(self, packets: Sequence[bytes]) -> None:
        self._packets = list(packets)

    def __len__(self) -> int:
        return len(self._packets)

    def __iter__(self) -> Iterator[ServerFrame]:
        with StreamDecoder() as d:
            for p in self._packets:
                yield d.decode(p)
