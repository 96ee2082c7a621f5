"""PNG files of 8-bit images, through Pillow.

Every PNG the package writes (stills, montages, the frames of ``splitrender play``, the colour and
shadow buffers of the authors' dataset layout) goes through :func:`write_png`, which checks the
array first (a specific :class:`~splitrender.errors.InvalidInputError` instead of Pillow's) and
writes atomically: a temporary file in the same folder, renamed over ``path`` when complete.
"""

from __future__ import annotations

import io
import os

import numpy as np
import numpy.typing as npt
from PIL import Image

from splitrender.errors import InvalidInputError
from splitrender.files import write_atomic

__all__ = ["encode_png", "write_png"]

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
