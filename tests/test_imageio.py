"""splitrender.imageio: PNG bytes and files of 8-bit images, and labelled montages."""

from __future__ import annotations

import io
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from PIL import Image

from splitrender.errors import InvalidInputError
from splitrender.imageio import caption_height, encode_png, montage, write_png


def _decoded(data: bytes) -> np.ndarray:
    with Image.open(io.BytesIO(data)) as im:
        return np.asarray(im)


@pytest.mark.parametrize("shape", [(5, 7), (5, 7, 3), (5, 7, 4)])
def test_png_round_trips_grey_rgb_and_rgba(shape: tuple[int, ...]) -> None:
    image = np.random.default_rng(3).integers(0, 256, shape, dtype=np.uint8)
    assert np.array_equal(_decoded(encode_png(image)), image)
    # Any zlib level gives the same pixels; a strided view is written as the image it shows.
    assert np.array_equal(_decoded(encode_png(image, level=0)), image)
    wide = np.zeros((5, 14, *shape[2:]), np.uint8)
    wide[:, ::2] = image
    assert np.array_equal(_decoded(encode_png(wide[:, ::2])), image)


def test_write_png_writes_the_encoded_bytes_and_nothing_else(tmp_path: Path) -> None:
    image = np.full((4, 6, 3), (10, 200, 30), np.uint8)
    path = tmp_path / "still.png"
    write_png(path, image)
    assert path.read_bytes() == encode_png(image)
    assert [p.name for p in tmp_path.iterdir()] == ["still.png"]


@pytest.mark.parametrize(
    ("image", "problem"),
    [
        ([[0, 1], [2, 3]], r"image: expected uint8 array of shape \(H, W\), .* got list"),
        (np.zeros((4, 4, 3), np.float32), r"image: expected uint8 .* got float32 \(4, 4, 3\)"),
        (np.zeros((4, 4, 2), np.uint8), r"got uint8 \(4, 4, 2\)"),
        (np.zeros(16, np.uint8), r"got uint8 \(16,\)"),
        (np.zeros((0, 4, 3), np.uint8), r"image: expected a non-empty image, got shape \(0, 4, "),
        (np.zeros((4, 0), np.uint8), r"image: expected a non-empty image, got shape \(4, 0\)"),
    ],
)
def test_a_bad_image_is_refused_before_anything_is_written(
    image: Any, problem: str, tmp_path: Path
) -> None:
    with pytest.raises(InvalidInputError, match=problem):
        write_png(tmp_path / "x.png", image)
    assert not any(tmp_path.iterdir())


def _tiles(n: int, h: int = 2, w: int = 3) -> list[np.ndarray]:
    return [np.full((h, w, 3), 10 * (k + 1), np.uint8) for k in range(n)]


def test_montage_places_tiles_row_by_row_gap_apart_on_white() -> None:
    tiles = _tiles(3)
    out = montage(tiles, 2, gap=4)
    assert out.shape == (2 + 4 + 2, 3 + 4 + 3, 3)
    for k, (y, x) in enumerate([(0, 0), (0, 7), (6, 0)]):
        assert np.array_equal(out[y : y + 2, x : x + 3], tiles[k])
    assert (out[2:6] == 255).all() and (out[:, 3:7] == 255).all()
    assert (out[6:, 7:] == 255).all()  # the third row's empty cell
    assert montage(tiles).shape == (2, 3 * 3 + 2 * 4, 3)  # one row by default


def test_montage_captions_each_tile_above_it() -> None:
    tiles = _tiles(2, h=48, w=64)
    out = montage(tiles, labels=["ours", "timewarp"], gap=0)
    bar = caption_height(48)
    assert out.shape == (bar + 48, 128, 3)
    for k in range(2):
        caption = out[:bar, 64 * k : 64 * (k + 1)]
        assert (caption == 0).any() and (caption == 255).any()  # black text on white
        assert np.array_equal(out[bar:, 64 * k : 64 * (k + 1)], tiles[k])
    # Different words, different pixels.
    assert not np.array_equal(out[:bar, :64], out[:bar, 64:])


@pytest.mark.parametrize(
    ("tiles", "kwargs", "problem"),
    [
        ([], {}, "tiles: expected at least one image, got none"),
        (_tiles(1) + [np.zeros((2, 4, 3), np.uint8)], {},
         r"tiles\[1\]: expected uint8 array of shape \(2, 3, 3\), got uint8 \(2, 4, 3\)"),
        (_tiles(1) + [np.zeros((2, 3, 3), np.float32)], {},
         r"tiles\[1\]: .* got float32 \(2, 3, 3\)"),
        (_tiles(2), {"labels": ["one"]}, r"labels: expected one per tile \(2\), got 1"),
        (_tiles(2), {"columns": 0}, "columns: expected >= 1, got 0"),
    ],
)
def test_montage_refuses_what_it_cannot_lay_out(
    tiles: list[np.ndarray], kwargs: dict[str, Any], problem: str
) -> None:
    with pytest.raises(InvalidInputError, match=f"^{problem}$"):
        montage(tiles, **kwargs)
