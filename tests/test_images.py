"""Image helpers: reading with alpha, atomic PNG writes, area downscale, comparison layouts."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from spcodec.imaging.images import (
    ImageReadError,
    composite_alpha,
    contact_sheet,
    downscale_area,
    error_map,
    image_has_alpha,
    image_size,
    read_image,
    side_by_side,
    to_uint8,
    write_png,
)


def test_png_round_trip_is_exact_for_8_bit_values(tmp_path: Path) -> None:
    codes = np.random.default_rng(0).integers(0, 256, (9, 13, 3), dtype=np.uint8)
    write_png(tmp_path / "a.png", codes / 255.0)
    back = read_image(tmp_path / "a.png")
    assert back.dtype == np.float32 and back.shape == (9, 13, 3)
    np.testing.assert_array_equal(to_uint8(back), codes)
    assert image_size(tmp_path / "a.png") == (13, 9) and not image_has_alpha(tmp_path / "a.png")
    assert not list(tmp_path.glob(".*part"))  # the temporary file was renamed away


def test_failed_write_leaves_the_previous_file(tmp_path: Path) -> None:
    target = tmp_path / "keep.png"
    write_png(target, np.zeros((4, 4, 3)))
    before = target.read_bytes()
    with pytest.raises(ValueError):
        write_png(target, np.zeros((4, 4, 5)))  # not an image shape: nothing is written
    assert target.read_bytes() == before


def test_rgba_grey_and_16_bit_inputs(tmp_path: Path) -> None:
    rgba = np.zeros((2, 2, 4), np.uint8)
    rgba[..., 0] = 255
    rgba[..., 3] = [[0, 255], [51, 204]]
    Image.fromarray(rgba).save(tmp_path / "rgba.png")
    assert image_has_alpha(tmp_path / "rgba.png")
    img = read_image(tmp_path / "rgba.png", background=(0.0, 0.0, 1.0))
    np.testing.assert_allclose(img[0, 0], [0, 0, 1])
    np.testing.assert_allclose(img[0, 1], [1, 0, 0])
    np.testing.assert_allclose(img[1, 0], [0.2, 0, 0.8], atol=1e-6)
    grey = np.array([[0, 128], [255, 64]], np.uint8)
    Image.fromarray(grey).save(tmp_path / "grey.png")
    np.testing.assert_allclose(read_image(tmp_path / "grey.png")[..., 1], grey / 255.0)
    wide = np.array([[0, 65535], [32768, 1000]], np.uint16)
    Image.fromarray(wide).save(tmp_path / "16.png")
    np.testing.assert_allclose(read_image(tmp_path / "16.png")[..., 0], wide / 65535.0, atol=1e-6)
    np.testing.assert_allclose(composite_alpha(np.array([[[1, 1, 1, 0.25]]]), [0, 0, 0]),
                               [[[0.25, 0.25, 0.25]]])


def test_unreadable_images_raise(tmp_path: Path) -> None:
    with pytest.raises(ImageReadError, match="does not exist"):
        read_image(tmp_path / "missing.png")
    (tmp_path / "bad.png").write_bytes(b"not an image")
    with pytest.raises(ImageReadError, match="not a readable image"):
        read_image(tmp_path / "bad.png")


def test_downscale_area_averages_whole_blocks() -> None:
    img = np.arange(7 * 9 * 3, dtype=np.float32).reshape(7, 9, 3)
    small = downscale_area(img, 2)
    assert small.shape == (3, 4, 3)  # the odd last row and column are dropped
    np.testing.assert_allclose(small[1, 2], img[2:4, 4:6].mean(axis=(0, 1)))
    assert downscale_area(img, 1) is img
    for bad in (0, 2.5):
        with pytest.raises(ValueError):
            downscale_area(img, bad)


def test_error_map_side_by_side_and_contact_sheet() -> None:
    ref = np.full((10, 12, 3), 0.5, np.float32)
    ours = ref.copy()
    ours[:, 6:] += 0.25  # right half off by vmax: white
    heat = error_map(ref, ours)
    np.testing.assert_allclose(heat[:, :6], 0.0)
    np.testing.assert_allclose(heat[:, 6:], 1.0)
    small = error_map(ref, ref + 0.05)
    assert 0.0 < small.max() < 1.0 and small[..., 0].max() > small[..., 2].max()  # reddish
    pair = side_by_side(ref, ours, gap=2)
    assert pair.shape == (10, 3 * 12 + 2 * 2, 3)
    np.testing.assert_allclose(pair[:, :12], ref)
    np.testing.assert_allclose(pair[:, 14:26], ours)
    np.testing.assert_allclose(pair[:, 12:14], 1.0)  # white gap
    tiles = [np.full((4, 6, 3), v, np.float32) for v in (0.1, 0.2, 0.3, 0.4, 0.5)]
    tiles.append(np.zeros((2, 2, 3), np.float32))
    sheet = contact_sheet(tiles, columns=3, gap=1, background=(1, 1, 1))
    assert sheet.shape == (2 * 4 + 1, 3 * 6 + 2, 3)
    np.testing.assert_allclose(sheet[5, 7], 0.5)  # second row, second tile
    np.testing.assert_allclose(sheet[6:8, 16:18], 0.0)  # the small tile is centred in its cell
    np.testing.assert_allclose(sheet[5, 14], 1.0)  # background around it
    assert contact_sheet(tiles[:4]).shape == (2 * 4 + 4, 2 * 6 + 4, 3)  # 2x2 by default
    with pytest.raises(ValueError):
        contact_sheet([])
    with pytest.raises(ValueError):
        side_by_side(ref, ours[:5])
