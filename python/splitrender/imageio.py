"""PNG files of 8-bit images, and the labelled montages of stills and videos, through Pillow.

Every PNG the package writes (stills, montages, the frames of ``splitrender play``, the colour and
shadow buffers of the authors' dataset layout) goes through :func:`write_png`, which checks the
array first (a specific :class:`~splitrender.errors.InvalidInputError` instead of Pillow's) and
writes atomically: a temporary file in the same folder, renamed over ``path`` when complete.
"""

from __future__ import annotations

import functools
import io
import os
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt
from PIL import Image, ImageDraw, ImageFont

from splitrender.errors import InvalidInputError
from splitrender.files import write_atomic

__all__ = ["caption_height", "encode_png", "montage", "write_png"]

_MODES = {2: "L", 3: "RGB", 4: "RGBA"}


def _pil_image(image: npt.NDArray[np.uint8]) -> Image.Image:
    want = "uint8 array of shape (H, W), (H, W, 3) or (H, W, 4)"
    if not isinstance(image, np.ndarray):
        raise InvalidInputError(f"image: expected {want}, got {type(image).__name__}")
    if image.dtype != np.uint8 or image.ndim not in (2, 3) or (
        image.ndim == 3 and image.shape[2] not in (3, 4)
    ):
        raise InvalidInputError(f"image: expected {want}, got {image.dtype} {image.shape}")
    if image.shape[0] == 0 or image.shape[1] == 0:
        raise InvalidInputError(f"image: expected a non-empty image, got shape {image.shape}")
    mode = _MODES[image.ndim if image.ndim == 2 else image.shape[2]]
    return Image.fromarray(np.ascontiguousarray(image), mode)


def encode_png(image: npt.NDArray[np.uint8], *, level: int = 6) -> bytes:
    """PNG bytes of an 8-bit image: ``uint8[H, W]`` (grey), ``[H, W, 3]`` (RGB) or
    ``[H, W, 4]`` (RGBA), zlib level ``level`` (0-9)."""
    buf = io.BytesIO()
    _pil_image(image).save(buf, format="PNG", compress_level=level)
    return buf.getvalue()


def write_png(
    path: str | os.PathLike[str], image: npt.NDArray[np.uint8], *, level: int = 6
) -> None:
    """Writes ``image`` (see :func:`encode_png`) to ``path`` as PNG, atomically
    (:func:`splitrender.files.write_atomic`)."""
    write_atomic(path, encode_png(image, level=level))


def _caption_font(tile_height: int) -> tuple[int, int]:
    """Text size and the margin above and below it of a caption over a tile ``tile_height``
    pixels high: 1/24 of the tile's height (at least 12 pixels: legible at the demo's 256x144)
    and a quarter of that (at least 2)."""
    size = max(12, round(tile_height / 24))
    return size, max(2, size // 4)


def caption_height(tile_height: int) -> int:
    """Height in pixels of the caption bar :func:`montage` puts above a tile ``tile_height``
    pixels high."""
    size, margin = _caption_font(tile_height)
    return size + 2 * margin


def montage(
    tiles: Sequence[npt.NDArray[np.uint8]],
    columns: int | None = None,
    *,
    labels: Sequence[str] | None = None,
    gap: int = 4,
) -> npt.NDArray[np.uint8]:
    """The RGB ``tiles`` (``uint8[H, W, 3]``, all one size) row by row, ``columns`` to a row
    (default: one row), ``gap`` white pixels apart, unchanged. With ``labels`` (one per tile),
    each tile sits under a white bar :func:`caption_height` pixels high holding its label in
    black, cut at the tile's width: a montage or video says which image is which by itself."""
    if not tiles:
        raise InvalidInputError("tiles: expected at least one image, got none")
    h, w = tiles[0].shape[:2]
    for k, tile in enumerate(tiles):
        if tile.dtype != np.uint8 or tile.shape != (h, w, 3):
            raise InvalidInputError(
                f"tiles[{k}]: expected uint8 array of shape {(h, w, 3)}, got "
                f"{tile.dtype} {tile.shape}")
    if labels is not None and len(labels) != len(tiles):
        raise InvalidInputError(
            f"labels: expected one per tile ({len(tiles)}), got {len(labels)}")
    columns = len(tiles) if columns is None else columns
    if columns < 1:
        raise InvalidInputError(f"columns: expected >= 1, got {columns}")
    rows = -(-len(tiles) // columns)
    cols = min(columns, len(tiles))
    bar = 0 if labels is None else caption_height(h)
    cell_h = bar + h
    out = np.full((rows * cell_h + (rows - 1) * gap, cols * w + (cols - 1) * gap, 3), 255,
                  np.uint8)
    for k, tile in enumerate(tiles):
        r, c = divmod(k, columns)
        y, x = r * (cell_h + gap), c * (w + gap)
        out[y + bar : y + cell_h, x : x + w] = tile
        if labels is not None:
            out[y : y + bar, x : x + w] = _caption(labels[k], w, h)
    return out


def _caption(text: str, width: int, tile_height: int) -> npt.NDArray[np.uint8]:
    """The white caption bar of a tile ``width`` x ``tile_height`` with ``text`` in black,
    left-aligned, in Pillow's bundled default font (the same glyphs on every machine with the
    same Pillow)."""
    size, margin = _caption_font(tile_height)
    bar = Image.new("RGB", (width, size + 2 * margin), (255, 255, 255))
    ImageDraw.Draw(bar).text((margin, margin), text, fill=(0, 0, 0), font=_font(size))
    return np.asarray(bar, np.uint8)


@functools.lru_cache(maxsize=8)
def _font(size: int) -> ImageFont.FreeTypeFont | ImageFont.ImageFont:
    # Loaded once per size: Pillow decodes the bundled font's bytes on every call (a video
    # captions each of its frames).
    return ImageFont.load_default(size=size)
