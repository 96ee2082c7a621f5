"""Import and export of the authors' dataset layout (shared/REFERENCE.md §1; docs/dataset-format.md).

Layout (one directory per camera, files ``NNNN.png`` / ``NNNN.exr`` numbered by ``frames[k].idx``)::

    OUT/main/   cam.json, color/, depth/, forwardFlowField/, backwardFlowField/,
                forwardShadowInfo/, forwardShadowColorA/, forwardShadowColorB/,
                backwardShadowInfo/, backwardShadowColorA/, backwardShadowColorB/
    OUT/left/   the same for our auxiliary camera 0
    OUT/right/  the same for our auxiliary camera 1
    OUT/client_ol/  cam.json (+ color/NNNN.png: the ground truth)

Conventions, theirs → ours (derived in docs/dataset-format.md):

- Matrices: ``w2c`` is our ``view`` and the stored ``proj`` our ``proj``, unchanged. Both are
  reversed-Z ``[0, 1]``, right-handed, y up; the reference normalises ``P = F_y·D·Z·P_stored`` and
  maps NDC ``y_n = −1`` to image row 0, i.e. stored ``y = +1`` is row 0 (the top), which is our
  convention (row 0 at the top, y up). ``eRC`` is row ``R``, column ``C``.
- Depth: their ``d`` is the reversed-Z device depth of ``P_stored``, which is our ``Z``.
- Motion: theirs is ``(Δx, Δy_n, Δz_n)`` in the normalised NDC, with ``y_n = −y`` and
  ``z_n = 1 − 2Z``; so ours is ``(Δx, −Δy_n, −Δz_n / 2)``.
- Pairing (§1.5/§1.6): ``forward*/[idx_k]`` are frame ``k``'s forward buffers (toward ``k+1``),
  ``backward*/[idx_k]`` frame ``k+1``'s backward buffers (toward ``k``). The export also writes
  the last frame's forward buffers under its own idx (never read by the reference); the first
  frame's backward buffers (toward ``k = −1``) have no slot and are not exported.
- Shadows: ``Φ = (R≪16)|(G≪8)|B`` is our bitfield, ColorA our ``s_min``, ColorB our ``s_max``
  (alpha written 255, ignored on import).
"""

from __future__ import annotations

import contextlib
import ctypes
import functools
import io
import json
import math
import os
import shutil
import stat
import struct
import sys
import tempfile
import threading
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np
import numpy.typing as npt
import OpenEXR  # type: ignore[import-not-found]  # compiled module, no stubs
from PIL import Image

from splitrender._native import __version__, singular_camera
from splitrender.errors import SplitRenderError
from splitrender.files import (
    check_apart,
    check_name,
    joined,
    read_json_object,
    rename_new_folder,
    temporary_beside,
    unwritable_folder,
)
from splitrender.imageio import write_png
from splitrender.scene.recording import (
    MAX_FRAMES,
    ClientFrame,
    LazyFrames,
    Recording,
    check_destination,
    load_recording,
    plan,
    write_frames,
)
from splitrender.types import (
    MAX_SIDE,
    Camera,
    CameraFrame,
    ClientRequest,
    ServerFrame,
    ShadowBuffers,
)
from splitrender.types import (  # argument checks
    PATH,
    checked,
    instances,
    items,
    optional,
    strs,
)

if TYPE_CHECKING:
    from splitrender.progress import Progress

__all__ = [
    "DatasetError",
    "DatasetInfo",
    "ImportedDataset",
    "dataset_info",
    "export_dataset",
    "import_dataset",
    "import_dataset_as_recording",
]

_MAX_JSON_BYTES = 64 * 1024 * 1024
_FPS_RANGE = (1e-3, 1e4)
# S = floor(shadowFps / serverFps) shadow subframes: 2 bits each of the 24-bit ShadowInfo
# (R, G, B; REFERENCE.md §1.6), so at most 12; subframe 0 is the key frame itself, so at least 1.
_SUBFRAMES = (1, 12)
_EYE = np.eye(4)
_KEYS = [f"e{r}{c}" for r in range(4) for c in range(4)]
_EXR_HEADER = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
_FLOW = {"fwd": "forwardFlowField", "bwd": "backwardFlowField"}
_SHADOW = {
    d: (f"{p}ShadowInfo", f"{p}ShadowColorA", f"{p}ShadowColorB")
    for d, p in (("fwd", "forward"), ("bwd", "backward"))
}

_U8 = npt.NDArray[np.uint8]
_F32 = npt.NDArray[np.float32]


class DatasetError(SplitRenderError):
    """A dataset in the authors' layout that cannot be read or written; the message names the
    file and the problem."""


def _fail(where: Path | str, problem: str) -> DatasetError:
    return DatasetError(f"{where}: {problem}")


# --------------------------------------------------------------------------------------------
# Conversions (pure functions, exported for tests and tools)


def matrix_to_unity(m: npt.NDArray[np.float64]) -> dict[str, float]:
    """A 4x4 matrix as a Unity ``Matrix4x4`` object (``eRC`` = row ``R``, column ``C``)."""
    return {f"e{r}{c}": float(m[r, c]) for r in range(4) for c in range(4)}


def matrix_from_unity(obj: object, where: Path | str = "matrix") -> npt.NDArray[np.float64]:
    """The inverse of :func:`matrix_to_unity`; raises :class:`DatasetError` naming ``where``."""
    if not isinstance(obj, dict):
        raise _fail(where, f"expected an object with keys e00..e33, got {type(obj).__name__}")
    m = np.empty((4, 4), np.float64)
    for r in range(4):
        for c in range(4):
            v = obj.get(f"e{r}{c}")
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise _fail(where, f"e{r}{c}: expected a finite number, got {v!r}")
            m[r, c] = float(v)
    return m


def motion_to_theirs(motion: _F32) -> _F32:
    """Our motion ``(Δx, Δy, ΔZ)`` (y up, reversed depth Z) → theirs ``(Δx, Δy_n, Δz_n)`` in the
    normalised NDC (``y_n = −y``, ``z_n = 1 − 2Z``)."""
    out = np.array(motion, dtype=np.float32, copy=True)
    out[..., 1] *= -1.0
    out[..., 2] *= -2.0
    return out


def motion_from_theirs(motion: _F32) -> _F32:
    """The inverse of :func:`motion_to_theirs`."""
    out = np.array(motion, dtype=np.float32, copy=True)
    out[..., 1] *= -1.0
    out[..., 2] *= -0.5
    return out


def bits_to_rgba(bits: npt.NDArray[np.uint32]) -> _U8:
    """Shadow bitfield → RGBA8 with ``Φ = (R≪16)|(G≪8)|B`` and alpha 255."""
    if bits.size and int(bits.max()) >= 1 << 24:
        raise DatasetError("shadow bitfield: values above 24 bits do not fit the RGB8 PNG")
    h, w = bits.shape
    out = np.empty((h, w, 4), np.uint8)
    out[..., 0] = (bits >> 16) & 0xFF
    out[..., 1] = (bits >> 8) & 0xFF
    out[..., 2] = bits & 0xFF
    out[..., 3] = 255
    return out


def bits_from_rgba(rgba: _U8) -> npt.NDArray[np.uint32]:
    """The inverse of :func:`bits_to_rgba` (alpha ignored)."""
    c = rgba.astype(np.uint32)
    return np.ascontiguousarray((c[..., 0] << 16) | (c[..., 1] << 8) | c[..., 2])


# --------------------------------------------------------------------------------------------
# File I/O


def _name(idx: int, ext: str) -> str:
    return f"{idx:04d}.{ext}"


def _write_exr(path: Path, channels: dict[str, npt.NDArray[Any]]) -> None:
    # A value beyond half's range (|v| > 65504) is written as an infinity, which marks the
    # pixel invalid (DESIGN.md): said in docs/dataset-format.md, not as numpy's RuntimeWarning
    # ("overflow encountered in cast") on the command line's stderr.
    with np.errstate(over="ignore"):
        half = {k: np.ascontiguousarray(v.astype(np.float16)) for k, v in channels.items()}
    OpenEXR.File(dict(_EXR_HEADER), half).write(str(path))


def _read_png(path: Path, size: tuple[int, int]) -> _U8:
    """RGBA8 of the 8-bit PNG at ``path``, which must be ``size = (w, h)`` (checked before
    decoding). As the authors' loader does (REFERENCE.md §1.6, "Colour PNGs are loaded as
    RGBA8"), any 8-bit colour type is read (grey, palette, RGB, with or without alpha; the
    callers ignore alpha); a 16-bit PNG or another format named ``.png`` is refused."""
    _check_file(path)
    try:
        with Image.open(path) as im:
            # Pillow opens whatever it can: a JPEG named .png (lossy), a 16-bit PNG cut to 8
            # bits (a grey 300 read as 255; RGB samples to their high byte).
            if im.format != "PNG":
                raise _fail(path, f"a {im.format} file, expected an 8-bit PNG")
            if im.size != size:
                raise _fail(
                    path,
                    f"resolution {im.size[0]}x{im.size[1]} does not match cam.json's "
                    f"{size[0]}x{size[1]}",
                )
            # The bit depth from the IHDR (the first chunk, which Pillow has parsed): Pillow
            # opens a 16-bit RGB PNG in mode RGB.
            with open(path, "rb") as f:
                ihdr = f.read(26)
            if len(ihdr) < 26 or ihdr[12:16] != b"IHDR":
                raise _fail(path, "cannot read PNG: the first chunk is not IHDR")
            if ihdr[24] > 8:
                raise _fail(path, f"a {ihdr[24]}-bit PNG (mode {im.mode}), expected 8 bits a "
                                  "sample (RGB8 or RGBA8)")
            if im.mode not in ("RGB", "RGBA"):
                im = im.convert("RGBA")
            a = np.asarray(im)
    except DatasetError:
        raise
    except (OSError, ValueError, SyntaxError, EOFError, Image.DecompressionBombError) as e:
        # Pillow reports a malformed chunk as SyntaxError ("broken PNG file"), found by the
        # fuzz suite (issue 15).
        raise _fail(path, f"cannot read PNG: {e}") from None
    if a.dtype != np.uint8 or a.ndim != 3 or a.shape[2] not in (3, 4):
        raise _fail(path, f"expected an 8-bit RGB(A) PNG, got {a.dtype} {a.shape}")
    if a.shape[2] == 3:
        a = np.concatenate([a, np.full(a.shape[:2] + (1,), 255, np.uint8)], axis=2)
    return np.ascontiguousarray(a)


def _read_exr(path: Path, size: tuple[int, int], want: str) -> _F32:
    """``want="depth"``: the single channel as ``float32[H, W]``; ``want="flow"``: R, G, B as
    ``float32[H, W, 3]``. The size, parts and channels are checked from the header before the
    pixels are read: every part and channel of the file is decoded, so these bound what is
    allocated (a second part or extra channels were decoded whatever their size). So is the
    layout of the file's chunks (:func:`_check_exr_chunks`), so that a file cut short or with
    a broken offset table is refused in our words; what the library still says about a file
    (corrupt compressed data) is folded into the error (:func:`_library_output`), as nothing
    of it may reach the command line's stdout or stderr."""
    _check_file(path)
    said: list[str] = []
    try:
        with _library_output(path) as said:
            header_file = OpenEXR.File(str(path), header_only=True)
        parts = len(header_file.parts)
        hdr = header_file.header()
        lo, hi = (np.asarray(v) for v in hdr["dataWindow"])
        w, h = int(hi[0] - lo[0] + 1), int(hi[1] - lo[1] + 1)
        names = [c.name for c in hdr["channels"]]
    except (RuntimeError, OSError, KeyError, TypeError, ValueError) as e:
        _exr_header_end(path)  # a specific reason where the layout gives one
        raise _fail(path, f"cannot read EXR: {_said(said) or e}") from None
    if said:
        raise _fail(path, f"cannot read EXR: {_said(said)}")
    if parts != 1:
        raise _fail(path, f"{parts} parts, expected a single-part EXR")
    if (w, h) != size:
        raise _fail(
            path, f"resolution {w}x{h} does not match cam.json's {size[0]}x{size[1]}"
        )
    if want == "depth" and len(names) != 1:
        raise _fail(path, f"expected a single-channel depth EXR, got {_channels(names)}")
    if want == "flow" and not {"R", "G", "B"} <= set(names) <= {"R", "G", "B", "A"}:
        raise _fail(path, f"expected channels R, G, B (A optional), got {_channels(names)}")
    _check_exr_chunks(path, int(hdr["compression"]), int(lo[1]), w, h)
    try:
        with _library_output(path) as said, OpenEXR.File(
            str(path), separate_channels=True
        ) as f:
            ch = f.channels()
            keys = names if want == "depth" else ["R", "G", "B"]
            planes = [np.asarray(ch[k].pixels) for k in keys]
    except (RuntimeError, OSError, KeyError, TypeError, ValueError) as e:
        # The library reports corrupt pixel data on stderr and stdout and then raises about
        # something else ("Invalid part index '0': file has 0 parts"): what it said comes first.
        raise _fail(path, f"cannot read EXR: {_said(said) or e}") from None
    if said:  # it complained but returned: the pixels are not the file's
        raise _fail(path, f"cannot read EXR: {_said(said)}")
    for k, p in zip(keys, planes):
        if p.shape != (h, w):
            raise _fail(path, f"channel of shape {p.shape}, expected {(h, w)}")
        if p.dtype not in (np.float16, np.float32):  # a UINT channel was read as a float
            raise _fail(path, f"channel {k} holds {p.dtype} samples, expected half or float")
    if want == "depth":
        return np.ascontiguousarray(planes[0], dtype=np.float32)
    return np.ascontiguousarray(np.stack(planes, axis=-1), dtype=np.float32)


# The layout of a scanline OpenEXR file (openexr.com, "OpenEXR File Layout"): the magic number
# and version flags, the header (attributes ``name\0 type\0 size:int32 value``, ended by a NUL),
# the offset table (one uint64 per chunk, ordered by y whatever the line order) and the chunks
# (``y:int32 packed size:int32 data``).
_EXR_MAGIC = b"\x76\x2f\x31\x01"
_EXR_TILED, _EXR_DEEP, _EXR_MULTIPART = 0x200, 0x800, 0x1000
#: Lines per chunk by compression code, fixed by the format. Codes above 11 (ZSTD, LJ2K) are not
#: in every version of the library with the same geometry: their files are not checked here.
_EXR_LINES_PER_CHUNK = {0: 1, 1: 1, 2: 1, 3: 16, 4: 32, 5: 16, 6: 32, 7: 32, 8: 32, 9: 256,
                        10: 256, 11: 32}
_EXR_SAMPLE_BYTES = {0: 4, 1: 2, 2: 4}  # UINT, HALF, FLOAT


class _ExrHeader(NamedTuple):
    """What :func:`_exr_header_end` finds: the file's size and flags, where its header ends
    and the bytes a pixel takes over all channels (``None``: subsampled or unknown channels)."""

    size: int
    flags: int
    end: int
    pixel_bytes: int | None


def _exr_header_end(path: Path) -> _ExrHeader:
    """Walks the header of the EXR at ``path`` (each attribute's size checked against the file's
    before it is skipped); raises :class:`DatasetError` for a file that is not an EXR or whose
    header is cut short."""
    try:
        with open(path, "rb", buffering=0) as f:
            size = os.fstat(f.fileno()).st_size
            head = f.read(8)
            if len(head) < 8 or head[:4] != _EXR_MAGIC:
                raise _fail(path, "cannot read EXR: not an OpenEXR file (no magic number)")
            flags = int.from_bytes(head[4:], "little")
            # Names and types of at most 31 bytes, 255 with the long-names flag (0x400): the
            # looser bound for all, as this walk only finds where the header ends.
            longest = 256
            pos, pixel_bytes = 8, None
            while True:
                f.seek(pos)
                buf = f.read(2 * longest + 4)
                if buf[:1] == b"\0":
                    pos += 1
                    break
                name_end = buf.find(b"\0", 0, longest)
                type_end = buf.find(b"\0", name_end + 1, name_end + 1 + longest)
                if name_end <= 0 or type_end < 0 or type_end + 5 > len(buf):
                    raise _cut(path, size, f"the attribute at byte {pos}")
                (n,) = struct.unpack_from("<i", buf, type_end + 1)
                start = pos + type_end + 5
                if n < 0 or start + n > size:
                    raise _cut(path, size, f"attribute {buf[:name_end].decode('latin-1')!r}")
                if buf[:name_end] == b"channels" and n <= 4096:
                    f.seek(start)
                    pixel_bytes = _chlist_pixel_bytes(f.read(n))
                pos = start + n
    except OSError as e:
        raise _fail(path, f"cannot read EXR: {e.strerror or e}") from None
    return _ExrHeader(size, flags, pos, pixel_bytes)


def _cut(path: Path, size: int, what: str) -> DatasetError:
    return _fail(path, f"cannot read EXR: truncated or corrupt header: {what} runs past the end "
                       f"of the file ({size} bytes)")


def _chlist_pixel_bytes(value: bytes) -> int | None:
    """The bytes a pixel takes in all channels of the ``chlist`` ``value``; ``None`` where a
    channel is subsampled or of an unknown type, or the list is malformed."""
    total, pos = 0, 0
    while pos < len(value) and value[pos] != 0:
        end = value.find(b"\0", pos)
        if end < 0 or end + 17 > len(value):
            return None
        kind, _, xs, ys = struct.unpack_from("<iB3xii", value, end + 1)
        if kind not in _EXR_SAMPLE_BYTES or (xs, ys) != (1, 1):
            return None
        total += _EXR_SAMPLE_BYTES[kind]
        pos = end + 17
    return total if pos < len(value) else None


def _check_exr_chunks(path: Path, compression: int, y_min: int, w: int, h: int) -> None:
    """Refuses a scanline EXR whose offset table or chunks do not fit the file: ``ceil(h /
    lines per chunk)`` offsets after the header, each chunk within the file past the table,
    saying the first line it should hold and holding no more bytes than its lines take
    uncompressed (exactly as many without compression), no two overlapping. These read the
    table and 8 bytes a chunk. Given such files, the library printed its own lines on stderr
    and stdout, or (an offset out of the file) rebuilt the table by scanning the file without
    a word. Tiled, deep and multi-part files (with one part) and compressions of other codes
    are left to the library."""
    hdr = _exr_header_end(path)
    lines = _EXR_LINES_PER_CHUNK.get(compression)
    if hdr.flags & (_EXR_TILED | _EXR_DEEP | _EXR_MULTIPART) or lines is None:
        return
    try:
        chunks = _exr_chunks(path, hdr, compression, y_min, w, h, lines)
    except (OSError, struct.error) as e:  # struct.error: the file shrank while it was read
        raise _fail(path, f"cannot read EXR: {e}") from None
    chunks.sort()
    for (_, end, i), (at, _, j) in zip(chunks, chunks[1:]):
        if at < end:
            raise _fail(path, f"cannot read EXR: corrupt offset table: chunk {j} at byte {at} "
                              f"lies inside chunk {i} (which ends at byte {end})")


def _exr_chunks(
    path: Path, hdr: _ExrHeader, compression: int, y_min: int, w: int, h: int, lines: int
) -> list[tuple[int, int, int]]:
    """(start, end, index) of each chunk of the scanline EXR at ``path``, each checked as
    :func:`_check_exr_chunks` says but for the overlaps."""
    n = -(-h // lines)
    lead = 8  # y, packed size
    table_end = hdr.end + 8 * n
    if table_end > hdr.size:
        raise _fail(path, f"cannot read EXR: truncated: its offset table ({n} x 8 bytes) ends "
                          f"at byte {table_end}, past the end of the file ({hdr.size} bytes)")
    chunks = []
    with open(path, "rb", buffering=0) as f:  # 8 bytes a chunk: no read-ahead
        f.seek(hdr.end)
        offsets = struct.unpack(f"<{n}Q", f.read(8 * n))
        for i, at in enumerate(offsets):
            y0 = y_min + i * lines
            what = f"chunk {i} (lines {y0}..{min(y0 + lines, y_min + h) - 1})"
            if at < table_end:
                raise _fail(path, f"cannot read EXR: corrupt offset table: {what} at byte {at}, "
                                  f"before the end of the table (byte {table_end})")
            if at > hdr.size - lead:
                where = "," if at >= hdr.size else f", whose {lead}-byte header runs"
                raise _fail(path, f"cannot read EXR: truncated or corrupt offset table: {what} "
                                  f"at byte {at}{where} past the end of the file ({hdr.size} "
                                  "bytes)")
            f.seek(at)
            y, packed = struct.unpack("<ii", f.read(lead))
            if y != y0:
                raise _fail(path, f"cannot read EXR: corrupt {what} at byte {at}: it says line "
                                  f"{y}, expected {y0}")
            if not 0 <= packed <= hdr.size - at - lead:
                raise _fail(path, f"cannot read EXR: truncated or corrupt {what} at byte {at}: "
                                  f"{packed} bytes of data, but only {hdr.size - at - lead} "
                                  f"follow its header in the file ({hdr.size} bytes)")
            if hdr.pixel_bytes is not None:
                raw = (min(y0 + lines, y_min + h) - y0) * w * hdr.pixel_bytes
                if packed > raw or (compression == 0 and packed != raw):
                    expected = f"{raw}" if compression == 0 else f"at most {raw}"
                    raise _fail(path, f"cannot read EXR: corrupt {what} at byte {at}: {packed} "
                                      f"bytes of data, expected {expected} (its lines "
                                      f"uncompressed)")
            chunks.append((at, at + lead + packed, i))
    return chunks


# fd 1 and 2 and sys.stdout are the process's: one capture at a time.
_OUTPUT_LOCK = threading.Lock()
#: How the Python binding reports an exception of the C++ library (py::print to sys.stdout).
_BINDING_WARNING = "Warning: Exception raised reading pixel data for part "
_SAID_LINES, _SAID_CHARS = 3, 200
_CAPTURED = 1 << 20  # bytes of a capture sorted into the library's lines and others'


@contextlib.contextmanager
def _library_output(path: Path) -> Iterator[list[str]]:
    """Runs the block with the library's output captured: the C core's error lines (on fd 2,
    ``PATH: (EXR_ERR_...) ...``) and the binding's warnings (``py::print`` on sys.stdout) are
    appended to the list it gives, without the file name; anything else written meanwhile (by
    another thread) is written where it was going once the block ends. fd 1 is captured too,
    for the C stdio of the library (flushed before it is given back)."""
    said: list[str] = []
    with _OUTPUT_LOCK:
        for stream in (sys.stdout, sys.stderr):
            with contextlib.suppress(Exception):
                stream.flush()
        saved = _redirect_fds((1, 2))
        py_out = io.StringIO()
        try:
            with contextlib.redirect_stdout(py_out):
                yield said
        finally:
            _fflush_c()
            name = str(path)
            for fd, old, tmp in saved:
                os.dup2(old, fd)
                os.close(old)
                with tmp:
                    tmp.seek(0)
                    _sort_lines(tmp.read(_CAPTURED).decode("utf-8", "replace"), name, said,
                                functools.partial(_write_fd, fd))
                    while rest := tmp.read(_CAPTURED):  # another's flood: passed on as it is
                        _write_fd(fd, rest)
            _sort_lines(py_out.getvalue(), name, said, sys.stdout.write)  # restored by now


def _redirect_fds(fds: tuple[int, ...]) -> list[tuple[int, int, Any]]:
    """Points each of ``fds`` at a new temporary file; returns (fd, saved copy, file) for those
    it could (a closed fd is left as it is)."""
    saved = []
    for fd in fds:
        try:
            old = os.dup(fd)
        except OSError:
            continue
        try:
            tmp = tempfile.TemporaryFile()
            os.dup2(tmp.fileno(), fd)
        except OSError:
            os.close(old)
            continue
        saved.append((fd, old, tmp))
    return saved


@functools.cache
def _libc_fflush() -> Any:
    try:
        return ctypes.CDLL(None).fflush
    except (OSError, AttributeError, TypeError):  # not a POSIX C library
        return None


def _fflush_c() -> None:
    """Flushes the C stdio buffers (what the library wrote with printf)."""
    fflush = _libc_fflush()
    if fflush is not None:
        fflush(None)


def _sort_lines(text: str, name: str, said: list[str], other: Callable[[str], object]) -> None:
    """Appends the library's lines of ``text`` to ``said`` (without the file name ``name``),
    hands the rest to ``other``."""
    rest = []
    for line in text.splitlines(keepends=True):
        bare = line.rstrip("\r\n")
        if bare.startswith(_BINDING_WARNING):
            said.append(bare[len(_BINDING_WARNING):].partition(" - ")[2] or bare)
        elif bare.startswith(name + ": "):
            said.append(bare[len(name) + 2:])
        else:
            rest.append(line)
    if rest:
        with contextlib.suppress(Exception):
            other("".join(rest))


def _write_fd(fd: int, text: str | bytes) -> None:
    data = text.encode() if isinstance(text, str) else text
    while data:
        data = data[os.write(fd, data):]


def _said(said: list[str]) -> str:
    """The library's lines as one, without repeats: the first few, each cut to a length."""
    lines = list(dict.fromkeys(s.strip() for s in said if s.strip()))
    shown = [s if len(s) <= _SAID_CHARS else s[: _SAID_CHARS - 3] + "..."
             for s in lines[:_SAID_LINES]]
    more = f"; ... ({len(lines)} lines in all)" if len(lines) > _SAID_LINES else ""
    return "; ".join(shown) + more


def _channels(names: Sequence[str], shown: int = 8) -> str:
    """``channels ['A', 'B']``, or the first ``shown`` names and the count of a longer list (a
    hostile file may name thousands)."""
    names = sorted(names)
    more = f" ... ({len(names)} in all)" if len(names) > shown else ""
    return f"channels {names[:shown]}{more}"


def _check_file(path: Path) -> None:
    """Refuses a buffer ``path`` that is missing or not a regular file (a folder, a device: it
    was "missing file")."""
    if path.is_file():
        return
    try:
        mode = path.stat().st_mode
    except OSError:
        raise _fail(path, "missing file") from None
    kind = "a folder" if stat.S_ISDIR(mode) else "a device, FIFO or socket"
    raise _fail(path, f"not a regular file ({kind}), expected an image file")


def _read_json(path: Path) -> dict[str, Any]:
    return read_json_object(path, _MAX_JSON_BYTES, "camera file", DatasetError)


def _number(m: dict[str, Any], key: str, default: float, path: Path) -> float:
    """A frame rate of ``cam.json``, in ``_FPS_RANGE``: the rates are divided and multiplied
    (``shadowFps / serverFps``, frame plans), and 1e300 over 1e-300 made ``floor`` of an
    infinity raise OverflowError."""
    v = m.get(key, default)
    lo, hi = _FPS_RANGE
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not lo <= v <= hi:
        raise _fail(path, f"{key}: expected a number in {lo:g}..{hi:g} (frames/s), got {v!r}")
    return float(v)


def _check_names(root: Path, aux: Sequence[str], client: str | None) -> None:
    """Refuses camera folder names that are not plain names (``../ds/left`` read a folder
    outside the dataset, ``.`` the dataset's own ``cam.json``) or that repeat one (``left,left``
    read one camera twice, a client ``main`` took the server's colour as the ground truth), as
    :func:`export_dataset` refuses them."""
    for i, a in enumerate(aux):
        check_name(a, f"aux[{i}]", DatasetError)
    names = ["main", *aux]
    if client is not None:
        names.append(check_name(client, "client", DatasetError))
    if len(set(names)) != len(names):
        raise _fail(root, f"camera directory names must differ, got {names}")


@dataclass(frozen=True, slots=True)
class _Cam:
    """One parsed ``cam.json``."""

    path: Path
    width: int
    height: int
    frames: list[tuple[int, npt.NDArray[np.float64], npt.NDArray[np.float64]]]
    raw: dict[str, Any]

    @property
    def size(self) -> tuple[int, int]:
        return (self.width, self.height)


def _near_far(proj: npt.NDArray[np.float64]) -> tuple[float, float]:
    """Near and far planes of a reversed-Z perspective projection with bottom row
    ``(0, 0, -1, 0)`` (``z' = A z + B``, ``w' = -z``: ``near = B / (1 + A)``, ``far = B / A``);
    NaN or an infinity where they do not exist. :func:`_check_proj` refuses those."""
    a, b = float(proj[2, 2]), float(proj[2, 3])
    with np.errstate(all="ignore"):
        near = float(np.float64(b) / np.float64(1.0 + a))
        far = float(np.float64(b) / np.float64(a))
    return near, far


def _check_proj(proj: npt.NDArray[np.float64], where: str) -> None:
    """Refuses a ``proj`` that is not a reversed-Z ``[0, 1]`` perspective projection (REFERENCE.md
    §1.3): the reprojection inverts it, and the recording's ``near``/``far`` are read from it
    (:func:`_near_far`). An all-zero or orthographic matrix was accepted here and only failed
    in ``splitrender play``, far from the file that held it."""
    row = proj[3]
    # Unity writes this row exactly; the tolerance only absorbs a decimal round trip.
    if np.abs(row - (0.0, 0.0, -1.0, 0.0)).max() > 1e-6:
        got = ", ".join(f"{v + 0.0:g}" for v in row)  # + 0.0: -0 reads as 0
        raise _fail(
            where,
            f"bottom row ({got}), expected (0, 0, -1, 0): a perspective projection (w = -z)",
        )
    if singular_camera(_EYE, proj) is not None:  # the kernels' own test of P = proj · view
        raise _fail(where, "singular matrix, expected an invertible perspective projection")
    near, far = _near_far(proj)
    # far <= near also catches a projection that is not reversed-Z: OpenGL's [-1, 1] and the
    # conventional [0, 1] projection both give near = f and far < f here.
    if not (math.isfinite(near) and math.isfinite(far) and 0.0 < near < far):
        raise _fail(
            where,
            f"near plane {near:g} and far plane {far:g} (from e22, e23), expected a reversed-Z "
            "[0, 1] projection (depth 1 at the near plane, 0 at the far one) with "
            "0 < near < far < inf",
        )


def _read_cam(path: Path, *, need_resolution: bool = True, distinct: bool = True) -> _Cam:
    """``distinct``: refuse two frames with the same ``idx`` (they would read the same files;
    for the client only the ground truth is read by idx)."""
    m = _read_json(path)
    res = m.get("resolution")
    w = h = 0
    if res is not None or need_resolution:
        if not isinstance(res, dict):
            raise _fail(path, f"resolution: expected {{x, y}}, got {res!r}")
        x, y = res.get("x"), res.get("y")
        for v in (x, y):
            if isinstance(v, bool) or not isinstance(v, int) or not 1 <= v <= MAX_SIDE:
                raise _fail(path, f"resolution: expected ints in 1..{MAX_SIDE}, got {res!r}")
        w, h = int(x), int(y)  # type: ignore[arg-type]
    frames = m.get("frames")
    if not isinstance(frames, list) or not frames:
        raise _fail(path, "frames: expected a non-empty array")
    out = []
    seen: dict[int, int] = {}
    for i, fr in enumerate(frames):
        if not isinstance(fr, dict):
            raise _fail(path, f"frames[{i}]: expected an object")
        idx = fr.get("idx")
        if isinstance(idx, bool) or not isinstance(idx, int) or idx < 0:
            raise _fail(path, f"frames[{i}].idx: expected an int >= 0, got {idx!r}")
        # Two frames with one idx read the same colour and depth, and the pairs (k, k+1) they
        # start the same flow and shadow files. The idx need not increase: time and pairing
        # follow the position in the list (REFERENCE.md §1.2), the idx only names files.
        if distinct and idx in seen:
            raise _fail(
                path,
                f"frames[{seen[idx]}] and frames[{i}] both have idx {idx}, expected a distinct "
                "idx per frame (each frame reads the files numbered by its idx)",
            )
        seen.setdefault(idx, i)
        view = matrix_from_unity(fr.get("w2c"), f"{path}: frames[{i}].w2c")
        if singular_camera(view, _EYE) is not None:
            # The import inverts it for the recording's poses (numpy raised LinAlgError) and the
            # reprojection for every pixel.
            raise _fail(
                path,
                f"frames[{i}].w2c: singular matrix, expected an invertible world-to-camera matrix",
            )
        proj = matrix_from_unity(fr.get("proj"), f"{path}: frames[{i}].proj")
        _check_proj(proj, f"{path}: frames[{i}].proj")
        if singular_camera(view, proj) is not None:  # each invertible, their product not
            raise _fail(path, f"frames[{i}]: proj · w2c is singular, expected an invertible "
                        "view-projection")
        out.append((idx, view, proj))
    return _Cam(path, w, h, out, m)


# --------------------------------------------------------------------------------------------
# Export


def _cam_json(
    cams: Sequence[Camera], idxs: Sequence[int], fs: float, shadow_fps: float, fc: float
) -> dict[str, Any]:
    return {
        "frames": [
            {"idx": i, "w2c": matrix_to_unity(c.view), "proj": matrix_to_unity(c.proj)}
            for i, c in zip(idxs, cams)
        ],
        "resolution": {"x": cams[0].width, "y": cams[0].height},
        "serverFps": fs,
        "shadowFps": shadow_fps,
        "clientFps": fc,
        "objectMotion": True,
        "shadowGradients": True,
    }


@checked(
    recording=instances((Recording, str, os.PathLike)), out_dir=PATH, aux_names=items(strs()),
    client=strs(),
)
def export_dataset(
    recording: Recording | str | os.PathLike[str],
    out_dir: str | os.PathLike[str],
    *,
    aux_names: Sequence[str] = ("left", "right"),
    client: str = "client_ol",
) -> Path:
    """Writes ``recording`` (a :class:`Recording` or its directory) in the authors' layout
    under ``out_dir`` (created; it must not exist or be empty) and returns its path.

    Our auxiliary camera ``i`` goes to ``aux_names[i]``; the client's (first eye's) cameras and
    ground truth to ``client``. Depth and motion are written as half floats.

    Raises:
        DatasetError: ``out_dir`` is not empty, is the current directory, is the recording's
            directory or lies inside it, a name of ``aux_names`` or ``client`` is not a plain
            folder name (empty, with a separator, ``.`` or ``..``), or the recording has more
            auxiliary cameras than ``aux_names``.
        OSError: ``out_dir``'s folder cannot be written (the error names ``out_dir``).
        RecordingError: the recording cannot be read.
    """
    out = Path(out_dir)
    # The camera folders are joined under out: a name with a separator or '..' would write
    # outside it, so every name is checked before anything is read or written.
    for i, a in enumerate(aux_names):
        check_name(a, f"aux_names[{i}]", DatasetError)
    check_name(client, "client", DatasetError)
    rec = recording if isinstance(recording, Recording) else load_recording(recording)
    check_apart(out, {"recording": rec.path}, DatasetError)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise _fail(out, "exists and is not an empty directory")
    # The finished export is renamed over an empty out: "." was an internal error (it has no
    # name to put a temporary folder beside), "../here" left the shell in a removed folder.
    if out.exists() and out.resolve() == Path.cwd().resolve():
        raise _fail(out, "is the current directory; expected a folder beside or below it")
    frames = list(rec.server_frames)
    n_aux = len(frames[0].aux)
    if n_aux > len(aux_names):
        raise _fail(out, f"{n_aux} auxiliary cameras but only {len(aux_names)} aux_names")
    names = ["main", *aux_names[:n_aux]]
    if len(set(names)) != len(names) or client in names:
        raise _fail(out, f"camera directory names must differ, got {[*names, client]}")
    # Written into a temporary folder beside out and renamed when complete: an interrupted
    # export leaves no dataset that reads as valid with cameras or frames missing.
    tmp = temporary_beside(out)
    _make_temporary(tmp, out)
    try:
        _write_layout(tmp, rec, frames, names, client)
        rename_new_folder(tmp, out, DatasetError, "; expected a new or empty folder")
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return out


def _make_temporary(tmp: Path, out: Path) -> None:
    """Creates the folder ``tmp`` beside ``out`` (and the folders above), or raises the
    ``OSError`` naming ``out``, the path the caller gave: the hidden ``tmp`` was named."""
    try:
        tmp.parent.mkdir(parents=True, exist_ok=True)
        tmp.mkdir()
    except OSError as e:
        why = unwritable_folder(e, out.parent)
        raise type(e)(e.errno, f"cannot write the dataset: {why}", str(out)) from None


def _write_layout(
    root: Path, rec: Recording, frames: Sequence[ServerFrame], names: Sequence[str], client: str
) -> None:
    """Writes the cameras ``names`` (main first) and the client folder of :func:`export_dataset`
    under ``root``."""
    fs, fc = rec.fs, rec.fc
    shadow_fps = fs * rec.subframes
    idxs = [f.index for f in frames]
    for ci, name in enumerate(names):
        d = joined(root, name, "camera folder", DatasetError)
        cam_frames = [f.main if ci == 0 else f.aux[ci - 1] for f in frames]
        for sub in ("color", "depth", *_FLOW.values(), *_SHADOW["fwd"], *_SHADOW["bwd"]):
            (d / sub).mkdir(parents=True, exist_ok=True)
        (d / "cam.json").write_text(
            json.dumps(_cam_json([c.camera for c in cam_frames], idxs, fs, shadow_fps, fc)),
            encoding="utf-8",
        )
        for k, (idx, cf) in enumerate(zip(idxs, cam_frames)):
            h, w = cf.camera.height, cf.camera.width
            write_png(d / "color" / _name(idx, "png"), cf.color, level=1)
            _write_exr(d / "depth" / _name(idx, "exr"), {"Y": cf.depth})
            # Pair (k, k+1) is numbered by the older frame's idx: frame k's forward buffers and
            # frame k+1's backward buffers. The last frame's forward buffers go under its idx.
            nxt = cam_frames[k + 1] if k + 1 < len(cam_frames) else None
            for direction, src in (("fwd", cf), ("bwd", nxt)):
                if src is None:
                    continue
                mot = src.motion_fwd if direction == "fwd" else src.motion_bwd
                if mot is None:
                    mot = np.zeros((h, w, 3), np.float32)
                theirs = motion_to_theirs(mot)
                _write_exr(
                    d / _FLOW[direction] / _name(idx, "exr"),
                    {"R": theirs[..., 0], "G": theirs[..., 1], "B": theirs[..., 2]},
                )
                sh = src.shadow_fwd if direction == "fwd" else src.shadow_bwd
                if sh is None:
                    z3 = np.zeros((h, w, 3), np.uint8)
                    sh = ShadowBuffers(np.zeros((h, w), np.uint32), z3, z3)
                info, col_a, col_b = _SHADOW[direction]
                alpha = np.full((h, w, 1), 255, np.uint8)
                write_png(d / info / _name(idx, "png"), bits_to_rgba(sh.bits), level=1)
                write_png(d / col_a / _name(idx, "png"), np.concatenate([sh.s_min, alpha], 2), level=1)
                write_png(d / col_b / _name(idx, "png"), np.concatenate([sh.s_max, alpha], 2), level=1)
    cd = joined(root, client, "client", DatasetError)
    (cd / "color").mkdir(parents=True, exist_ok=True)
    cframes = list(rec.client_frames)
    (cd / "cam.json").write_text(
        json.dumps(
            _cam_json([c.camera for c in cframes], [c.index for c in cframes], fs, shadow_fps, fc)
        ),
        encoding="utf-8",
    )
    for c in cframes:
        write_png(cd / "color" / _name(c.index, "png"), c.ground_truth, level=1)


# --------------------------------------------------------------------------------------------
# Import


@dataclass(frozen=True, slots=True)
class DatasetInfo:
    """The rates and sizes of a dataset (main ``cam.json``; client rate from the client's)."""

    server_fps: float
    shadow_fps: float
    client_fps: float
    width: int
    height: int

    @property
    def subframes(self) -> int:
        """``S = ⌊shadowFps / serverFps⌋`` (REFERENCE.md §1.6); :func:`dataset_info` refuses rates
        for which it is not in 1..12 (0 is taken as 1 where there are no shadow buffers)."""
        return max(1, _subframes(self.shadow_fps, self.server_fps))


def _subframes(shadow_fps: float, server_fps: float) -> int:
    # The reference floors; 1e-9 keeps a quotient such as 0.7 / 0.1 = 6.9999... at 7.
    return int(math.floor(shadow_fps / server_fps + 1e-9))


def dataset_info(in_dir: str | os.PathLike[str], client: str | None = "client_ol") -> DatasetInfo:
    """The :class:`DatasetInfo` of the dataset in ``in_dir`` (``client``: the client's folder
    name in it, or ``None``: main's ``clientFps``).

    Raises:
        DatasetError: as :func:`import_dataset` for ``main/cam.json`` and the client's name,
            a rate out of range, or ``shadowFps`` that gives more than
            12 shadow subframes, or none where the dataset has shadow buffers.
    """
    root = Path(in_dir)
    _check_names(root, (), client)
    main = _read_cam(root / "main" / "cam.json")
    fc_src = main.raw
    if client is not None:
        if not (root / client).is_dir():  # as import_dataset says it
            raise _fail(root / client, "missing client directory")
        fc_src = _read_json(root / client / "cam.json")
    # Each rate from the file the authors' program reads it from (REFERENCE.md §1.2): main's
    # serverFps and shadowFps, the client's clientFps; the others' copies are not read.
    fs = _number(main.raw, "serverFps", 10.0, main.path)
    fd = _number(main.raw, "shadowFps", 60.0, main.path)
    s, (lo, hi) = _subframes(fd, fs), _SUBFRAMES
    shadows = any((d / _SHADOW[k][0]).is_dir() for d in root.iterdir() if d.is_dir()
                  for k in _SHADOW)
    if not lo <= s <= hi and (shadows or s > hi):
        # Clamped before. Above 12 the subframes past the 24 bits read as level 0, at other
        # times than those rendered. S = 0 (shadowFps below serverFps) contradicts shadow
        # buffers (subframe 0 is the key frame itself); without any it changes nothing and is
        # taken as 1 (the reference plays such a dataset, without shadows).
        raise _fail(
            main.path,
            f"shadowFps: {fd:g} at serverFps {fs:g} gives floor(shadowFps / serverFps) = {s} "
            f"shadow subframes, expected {lo}..{hi} (shadowFps from {lo * fs:g} to below "
            f"{(hi + 1) * fs:g})",
        )
    return DatasetInfo(
        fs,
        fd,
        _number(fc_src, "clientFps", 60.0, root / (client or "main") / "cam.json"),
        main.width,
        main.height,
    )


class ImportedDataset(NamedTuple):
    """What :func:`import_dataset` returns: the server frames, one client request (camera and
    time ``n / clientFps``) per client frame, and the ground truth per client frame (``None``
    where the client directory has no ``color/``)."""

    server_frames: list[ServerFrame]
    client_requests: list[ClientRequest]
    ground_truth: list[_U8 | None]


def _camera_frames(d: Path, cam: _Cam) -> LazyFrames[CameraFrame]:
    """The frames of the camera folder ``d`` (with ``cam.json`` ``cam``), each read from its
    files when asked for (:func:`import_dataset_as_recording` holds one at a time)."""
    size = cam.size
    w, h = size
    n = len(cam.frames)
    flows = {k: (d / v).is_dir() for k, v in _FLOW.items()}
    shadows = {k: (d / v[0]).is_dir() and (d / v[1]).is_dir() for k, v in _SHADOW.items()}

    def frame(k: int) -> CameraFrame:
        idx, view, proj = cam.frames[k]
        color = np.ascontiguousarray(_read_png(d / "color" / _name(idx, "png"), size)[..., :3])
        depth = _read_exr(d / "depth" / _name(idx, "exr"), size, "depth")
        motion: dict[str, _F32 | None] = {"fwd": None, "bwd": None}
        shadow: dict[str, ShadowBuffers | None] = {"fwd": None, "bwd": None}
        # The pair (j, j+1) is numbered idx_j: its forward files are frame j's, its backward
        # files frame j+1's. Frame 0 has no backward files; the forward files of the last
        # frame are optional (the reference never reads them).
        for direction, j in (("fwd", k), ("bwd", k - 1)):
            if j < 0:
                continue
            pair = cam.frames[j][0]
            optional = direction == "fwd" and k + 1 >= n
            if flows[direction]:
                p = d / _FLOW[direction] / _name(pair, "exr")
                if not (optional and not p.is_file()):
                    motion[direction] = motion_from_theirs(_read_exr(p, size, "flow"))
            if shadows[direction]:
                info, col_a, col_b = _SHADOW[direction]
                p = d / info / _name(pair, "png")
                if optional and not p.is_file():
                    continue
                bits = bits_from_rgba(_read_png(p, size))
                s_min = _read_png(d / col_a / _name(pair, "png"), size)[..., :3]
                if (d / col_b).is_dir():
                    s_max = _read_png(d / col_b / _name(pair, "png"), size)[..., :3]
                else:  # REFERENCE.md §1.6: ColorB missing → the base colour is used
                    s_max = color
                shadow[direction] = ShadowBuffers(
                    bits, np.ascontiguousarray(s_min), np.ascontiguousarray(s_max)
                )
        try:
            return CameraFrame(
                Camera(view, proj, w, h),
                color,
                depth,
                motion["fwd"],
                motion["bwd"],
                shadow["fwd"],
                shadow["bwd"],
            )
        except SplitRenderError as e:
            raise _fail(cam.path, f"frames[{k}]: {e}") from None

    return LazyFrames(n, frame)


@dataclass(frozen=True, slots=True)
class _Layout:
    """A dataset's ``cam.json`` files, read and checked (:func:`_open_layout`); no image read."""

    fs: float
    #: The camera folders, main then the auxiliary ones, with their cam.json.
    cams: list[tuple[Path, _Cam]]
    #: The client folder and its cam.json (None: no client).
    client: tuple[Path, _Cam] | None
    fc: float
    requests: list[ClientRequest]
    has_truth: bool

    def server_frame(self, frames: Sequence[Sequence[CameraFrame]], k: int) -> ServerFrame:
        """Server frame ``k`` of the cameras' ``frames`` (main first), at ``k / serverFps``."""
        return ServerFrame(k, k / self.fs, frames[0][k], tuple(f[k] for f in frames[1:]))

    def truth(self, n: int) -> _U8:
        """Client frame ``n``'s ground truth, read from its file."""
        assert self.client is not None
        cd, cc = self.client
        cam = self.requests[n].camera
        png = _read_png(cd / "color" / _name(cc.frames[n][0], "png"), (cam.width, cam.height))
        return np.ascontiguousarray(png[..., :3])


def _open_layout(root: Path, aux: Sequence[str], client: str | None) -> _Layout:
    """Reads and checks the ``cam.json`` files of the dataset ``root`` as :func:`import_dataset`
    does (names, folders, matrices, frame counts, rates, client cameras)."""
    # The names are joined under in_dir: checked before anything is read.
    _check_names(root, aux, client)
    if not root.is_dir():
        raise _fail(root, "no such dataset directory")
    info_main = _read_cam(root / "main" / "cam.json")
    # Each rate from the file the authors' program reads it from (REFERENCE.md §1.2).
    fs = _number(info_main.raw, "serverFps", 10.0, info_main.path)
    cams = [(root / "main", info_main)]
    for name in aux:
        d = root / name
        if not d.is_dir():
            raise _fail(d, "missing auxiliary camera directory")
        c = _read_cam(d / "cam.json")
        if len(c.frames) != len(info_main.frames):
            raise _fail(
                c.path,
                f"{len(c.frames)} frames, but main/cam.json has {len(info_main.frames)}",
            )
        cams.append((d, c))
    if client is None:
        return _Layout(fs, cams, None, 0.0, [], False)
    cd = root / client
    if not cd.is_dir():
        raise _fail(cd, "missing client directory")
    has_truth = (cd / "color").is_dir()
    # Without ground truth the client's idx reads no file (the reference ignores it).
    cc = _read_cam(cd / "cam.json", need_resolution=False, distinct=has_truth)
    fc = _number(cc.raw, "clientFps", 60.0, cc.path)
    w, h = cc.size if cc.width else info_main.size
    requests = []
    for n, (_, view, proj) in enumerate(cc.frames):
        try:
            requests.append(ClientRequest(Camera(view, proj, w, h), n / fc))
        except SplitRenderError as e:
            raise _fail(cc.path, f"frames[{n}]: {e}") from None
    return _Layout(fs, cams, (cd, cc), fc, requests, has_truth)


@checked(in_dir=PATH, aux=items(strs()), client=optional(PATH))
def import_dataset(
    in_dir: str | os.PathLike[str],
    aux: Sequence[str] = ("left", "right"),
    client: str | os.PathLike[str] | None = "client_ol",
) -> ImportedDataset:
    """Reads the dataset in the authors' layout under ``in_dir``: the ``main`` camera, the
    auxiliary cameras ``aux`` (in rig order) and the client directory ``client`` (folder names
    in ``in_dir``; ``None``: no client) and converts it to our conventions (see the module
    docstring). Server frame ``k`` gets index ``k`` and time ``k / serverFps``; client
    frame ``n`` time ``n / clientFps`` and the client ``cam.json``'s resolution (the main
    camera's when it has none).

    Raises:
        DatasetError: naming the file, for a name of ``aux`` or ``client`` that is not a plain
            folder name (empty, with a separator, ``.`` or ``..``) or that repeats another (or
            ``main``), a missing directory, ``cam.json`` or buffer file, a file whose
            resolution differs from its ``cam.json``, malformed JSON or matrices, a singular
            ``w2c``, a ``proj`` that is not an invertible reversed-Z
            perspective projection with 0 < near < far < inf, two frames of one camera with
            the same ``idx`` (the client's only when it has ground truth), aux frame lists of
            another length than main's, unreadable images, an image that is not an 8-bit PNG
            (a JPEG named ``.png``, a 16-bit PNG), or an EXR of more than one part, other
            channels than it needs or integer samples, whose offset table or chunks do not fit
            the file (cut short, an offset out of place) or whose data the library cannot
            decode (what it said is in the message; nothing of it reaches stdout or stderr).
    """
    lay = _open_layout(Path(in_dir), aux, None if client is None else os.fspath(client))
    per_cam = [list(_camera_frames(d, c)) for d, c in lay.cams]
    server = [lay.server_frame(per_cam, k) for k in range(len(per_cam[0]))]
    truth = [lay.truth(n) if lay.has_truth else None for n in range(len(lay.requests))]
    return ImportedDataset(server, lay.requests, truth)


def _client_frames_kept(n_client: int, n_server: int, fs: float, fc: float) -> int:
    """How many of the first client frames lie between two of the ``n_server`` server frames
    or on the last (at or before its time): the recording's client frames (:func:`plan`). At
    least one where ``n_client >= 1``: the first client frame lies on server frame 0."""
    while n_client > 0 and plan(n_client / fc, fs, fc)[0] > n_server:
        n_client -= 1
    return n_client


def import_dataset_as_recording(
    in_dir: str | os.PathLike[str],
    out: str | os.PathLike[str],
    *,
    aux: Sequence[str] = ("left", "right"),
    client: str = "client_ol",
    overwrite: bool = False,
    stages: Progress | None = None,
) -> Path:
    """Reads the dataset in the authors' layout under ``in_dir`` (:func:`import_dataset`) and
    writes it as a recording to ``out`` (see ``splitrender dataset import --help``); returns
    ``out``. The frames are read and written one at a time, so the memory it takes does not
    grow with the dataset's length. ``stages`` gets two stages (checking the ``cam.json``
    files, converting the frames).

    Raises:
        DatasetError: the dataset cannot be read or cannot be a recording (not two auxiliary
            cameras, no ground truth, a client size other than the main camera's, more server
            frames or more client frames than a recording holds), or ``out`` is the dataset's
            directory, lies inside it or holds it. An image that cannot be read is found while
            the recording is written into ``out.partial-<pid>``, which is then removed: ``out``
            is left as it was.
        RecordingError: ``out`` exists (without ``overwrite``).
    """
    root, dest = Path(in_dir), Path(out)
    if len(aux) != 2:
        raise DatasetError(f"aux: a recording has two auxiliary cameras, got {len(aux)}")
    # With overwrite, write_frames removes the old dest: that must not be (or hold) the dataset.
    check_apart(dest, {"dataset": root}, DatasetError, replaced=overwrite)
    check_destination(dest, overwrite)
    if stages is not None:
        stages.stage(f"checking the dataset {root}")
    # The rates and shadow subframes (dataset_info), then every cam.json (_open_layout): the
    # frame counts are checked from them before any image is read, as a recording holds at
    # most MAX_FRAMES server and client frames (load_recording refused the one written with
    # more).
    _check_names(root, aux, client)
    if not root.is_dir():
        raise _fail(root, "no such dataset directory")
    info = dataset_info(root, client)
    fs, fc = info.server_fps, info.client_fps
    lay = _open_layout(root, aux, client)
    main_cam = lay.cams[0][1]
    n_server = len(main_cam.frames)
    if n_server > MAX_FRAMES:
        raise _fail(main_cam.path, f"{n_server} server frames, a recording holds at most "
                    f"{MAX_FRAMES}")
    n_client = _client_frames_kept(len(lay.requests), n_server, fs, fc)
    if n_client > MAX_FRAMES:
        raise _fail(root / client / "cam.json", f"{n_client} client frames lie between two "
                    f"server frames, a recording holds at most {MAX_FRAMES}")
    if not lay.requests or not lay.has_truth:
        raise DatasetError(f"{root / client}/color: missing; a recording needs the ground truth")
    w, h = main_cam.size
    cw, ch = lay.requests[0].camera.width, lay.requests[0].camera.height
    if (cw, ch) != (w, h):
        raise DatasetError(f"{root / client}/cam.json: client size {cw}x{ch}, a recording "
                           f"needs the main camera's {w}x{h}")
    # The ground truth of the client frames left out is checked as import_dataset checks it
    # (one image at a time), so that the same datasets are refused.
    for n in range(n_client, len(lay.requests)):
        lay.truth(n)

    # Server frame k is at k / fs (import_dataset's time); buffers the layout has no slot for
    # (frame 0's backward ones) are None, which write_frames writes as zeros. Each frame is
    # read from its files when write_frames asks for it and dropped once written.
    cameras = [_camera_frames(d, c) for d, c in lay.cams]

    def server_frame(k: int) -> tuple[npt.NDArray[np.float64], ServerFrame]:
        f = lay.server_frame(cameras, k)
        return np.linalg.inv(f.main.camera.view).astype(np.float64), f

    def client_frame(n: int) -> ClientFrame:
        cam = lay.requests[n].camera
        pose = np.linalg.inv(cam.view).astype(np.float64)
        return ClientFrame(n, n / fc, pose, (cam,), (lay.truth(n),))

    near, far = _near_far(main_cam.frames[0][2])  # checked by _read_cam
    fields = {
        "generator": f"splitrender {__version__} (dataset import)",
        "scene": root.resolve().name,
        "variant": "dataset",
        "scale": w / 2560,
        "fs": fs,
        "fc": fc,
        "subframes": info.subframes,  # in 1..12: dataset_info refuses others
        "seconds": n_client / fc,
        "stereo": False,
        "samples": {"main": 1, "aux": 1, "client": 1},
        "near": near,
        "far": far,
        "cameras": {
            "main": [w, h],
            "aux": [list(c.size) for _, c in lay.cams[1:]],
            "client": [w, h],
            "eyes": 1,
        },
        "client_motion": {"source": "dataset", "dir": str(root)},
    }
    if stages is not None:
        stages.stage(f"converting {n_server} server frames and {n_client} client frames of "
                     f"{root} into {dest}")
    bar = None if stages is None else functools.partial(stages.bar, unit="frames")
    return write_frames(dest, fields, LazyFrames(n_server, server_frame),
                        LazyFrames(n_client, client_frame), overwrite=overwrite, progress=bar)
