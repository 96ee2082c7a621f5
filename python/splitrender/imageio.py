"""A minimal PNG writer (zlib from the standard library; no extra dependency)."""

from __future__ import annotations

import os
import struct
import zlib

import numpy as np
import numpy.typing as npt

from splitrender.errors import InvalidInputError

__all__ = ["encode_png", "write_png"]


def _chunk(kind: bytes, data: bytes) -> bytes:
    crc = zlib.crc32(kind + data) & 0xFFFFFFFF
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", crc)


def encode_png(image: npt.NDArray[np.uint8], *, level: int = 6) -> bytes:
    """PNG bytes of an 8-bit image: ``uint8[H, W, 3]`` (RGB) or ``uint8[H, W]`` (grey)."""
    if not isinstance(image, np.ndarray) or image.dtype != np.uint8 or image.ndim not in (2, 3):
        got = (
            f"{image.dtype} {image.shape}"
            if isinstance(image, np.ndarray)
            else type(image).__name__
        )
        raise InvalidInputError(
            f"image: expected uint8 array of shape (H, W, 3) or (H, W), got {got}"
        )
    if image.ndim == 3 and image.shape[2] != 3:
        raise InvalidInputError(
            f"image: expected uint8 array of shape (H, W, 3) or (H, W), got {image.shape}"
        )
    h, w = image.shape[:2]
    if h == 0 or w == 0:
        raise InvalidInputError(f"image: expected a non-empty image, got shape {image.shape}")
    color_type = 2 if image.ndim == 3 else 0
    rows = np.ascontiguousarray(image).reshape(h, -1)
    # Filter type 0 (None) on every scanline: a zero byte in front of each row.
    raw = np.concatenate([np.zeros((h, 1), np.uint8), rows], axis=1).tobytes()
    header = struct.pack(">IIBBBBB", w, h, 8, color_type, 0, 0, 0)
    return b"".join(
        [
            b"\x89PNG\r\n\x1a\n",
            _chunk(b"IHDR", header),
            _chunk(b"IDAT", zlib.compress(raw, level)),
            _chunk(b"IEND", b""),
        ]
    )


def write_png(path: str | os.PathLike[str], image: npt.NDArray[np.uint8]) -> None:
    """Writes ``image`` (``uint8[H, W, 3]`` or ``uint8[H, W]``) to ``path`` as PNG."""
    data = encode_png(image)
    with open(path, "wb") as f:
        f.write(data)
