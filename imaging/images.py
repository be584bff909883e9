"""Image files and layouts for evaluation: read, write, downscale, compare, tile (numpy + Pillow).

Images inside spcodec are float32 arrays of shape (H, W, 3) with values in [0, 1], linear in the
stored 8-bit code values (no gamma handling: PSNR/SSIM in the 3DGS literature are computed on the
stored sRGB values, and so are ours).

Pillow is imported lazily so that importing this module (e.g. for :func:`downscale_area`) costs
nothing when no file is touched. EXIF orientation tags are deliberately ignored: COLMAP and the
NeRF loaders use the pixel array as stored, and the camera intrinsics refer to that array.
"""

from __future__ import annotations

import io
import os
from typing import Sequence

import numpy as np

from spcodec.fileio import atomic_write

ImageArray = np.ndarray
"""float32 (H, W, 3) in [0, 1]."""

IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".PNG", ".JPG", ".JPEG")
"""Extensions tried, in this order, when a dataset names an image without one."""


class ImageReadError(ValueError):
    """An image file is missing, unreadable or of an unsupported pixel format."""


def _open(path: str | os.PathLike):
    from PIL import Image, UnidentifiedImageError

    try:
        return Image.open(path)
    except FileNotFoundError:
        raise ImageReadError(f"image {os.fspath(path)} does not exist") from None
    except (UnidentifiedImageError, OSError) as exc:
        raise ImageReadError(f"image {os.fspath(path)} is not a readable image ({exc})") from None


def image_size(path: str | os.PathLike) -> tuple[int, int]:
    """(width, height) from the file header only; cheap enough to check every image of a dataset."""
    with _open(path) as img:
        return int(img.width), int(img.height)


def image_has_alpha(path: str | os.PathLike) -> bool:
    """Whether the file stores an alpha channel (RGBA, LA, or a palette with transparency)."""
    with _open(path) as img:
        return img.mode in ("RGBA", "LA", "PA") or (img.mode == "P" and "transparency" in img.info)


def read_image(path: str | os.PathLike,
               background: Sequence[float] | np.ndarray = (0.0, 0.0, 0.0)) -> ImageArray:
    """Read a PNG/JPEG as float32 (H, W, 3) in [0, 1]; alpha is composited over ``background``.

    Grey images are replicated to three channels, 16-bit PNGs are scaled by 1/65535. Compositing
    ``rgb * a + background * (1 - a)`` is what NeRF-synthetic evaluation does with its white (or
    black) background, so the reference matches a render made with the same background colour.
    """
    with _open(path) as img:
        try:
            img.load()
        except OSError as exc:
            raise ImageReadError(f"image {os.fspath(path)} is truncated or corrupt ({exc})") \
                from None
        mode = img.mode
        if mode in ("I;16", "I;16B", "I;16L", "I"):
            data = np.asarray(img, dtype=np.float64)
            scale = 65535.0 if mode.startswith("I;16") or data.max(initial=0) > 255 else 255.0
            grey = (data / scale).astype(np.float32)
            return np.repeat(grey[:, :, None], 3, axis=2)
        if mode == "F":
            grey = np.clip(np.asarray(img, dtype=np.float32), 0.0, 1.0)
            return np.repeat(grey[:, :, None], 3, axis=2)
        has_alpha = mode in ("RGBA", "LA", "PA") or (mode == "P" and "transparency" in img.info)
        converted = img.convert("RGBA" if has_alpha else "RGB")
        data = np.asarray(converted, dtype=np.float32) / 255.0
    if has_alpha:
        return composite_alpha(data, background)
    return np.ascontiguousarray(data)


def composite_alpha(rgba: np.ndarray, background: Sequence[float] | np.ndarray) -> ImageArray:
    """Blend a straight-alpha (H, W, 4) image over a constant colour, giving (H, W, 3) float32."""
    bg = np.asarray(background, dtype=np.float32).reshape(1, 1, 3)
    alpha = rgba[:, :, 3:4].astype(np.float32)
    return (rgba[:, :, :3] * alpha + bg * (1.0 - alpha)).astype(np.float32)


def to_uint8(image: np.ndarray) -> np.ndarray:
    """Round a [0, 1] float image to 8-bit codes (values outside [0, 1] are clipped)."""
    return (np.clip(np.asarray(image, dtype=np.float32), 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def encode_png(image: np.ndarray) -> bytes:
    """PNG bytes of an (H, W, 3) or (H, W) float image in [0, 1] (or a uint8 image)."""
    from PIL import Image

    array = np.asarray(image)
    if array.dtype != np.uint8:
        array = to_uint8(array)
    if array.ndim == 3 and array.shape[2] == 1:
        array = array[:, :, 0]
    if array.ndim not in (2, 3) or (array.ndim == 3 and array.shape[2] not in (3, 4)):
        raise ValueError(f"cannot write an image of shape {array.shape} as PNG")
    buffer = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(array)).save(buffer, format="PNG")
    return buffer.getvalue()


def write_png(path: str | os.PathLike, image: np.ndarray) -> None:
    """Write a PNG atomically: a crash never leaves a half-written file under ``path``."""
    atomic_write(path, encode_png(image))


def downscale_area(image: np.ndarray, factor: int) -> np.ndarray:
    """Shrink by an integer ``factor`` by averaging factor x factor blocks (area resampling).

    Rows/columns that do not fill a whole block (at the right and bottom edges) are dropped, so
    output pixel (r, c) is exactly the mean of input pixels [r*f, (r+1)*f) x [c*f, (c+1)*f) and a
    camera maps to the new image by dividing fx, fy, cx, cy by ``factor`` (see
    :func:`spcodec.imaging.datasets.downscaled_camera`).
    """
    if factor < 1 or int(factor) != factor:
        raise ValueError(f"downscale factor must be a positive integer, got {factor!r}")
    factor = int(factor)
    if factor == 1:
        return image
    h, w = image.shape[0] // factor, image.shape[1] // factor
    if h == 0 or w == 0:
        raise ValueError(f"image of {image.shape[1]}x{image.shape[0]} is too small to downscale "
                         f"by {factor}")
    cropped = image[: h * factor, : w * factor]
    blocks = cropped.reshape(h, factor, w, factor, *image.shape[2:])
    return blocks.mean(axis=(1, 3), dtype=np.float64).astype(image.dtype, copy=False)


# ------------------------------------------------------------------------------ comparison layouts
_HEAT_STOPS = np.array([  # black -> dark red -> orange -> yellow -> white, easy to read at a glance
    [0.0, 0.0, 0.0], [0.55, 0.0, 0.05], [0.95, 0.35, 0.0], [1.0, 0.85, 0.1], [1.0, 1.0, 1.0],
], dtype=np.float32)


def error_map(reference: np.ndarray, ours: np.ndarray, vmax: float = 0.25) -> ImageArray:
    """Colour-coded per-pixel error: mean absolute channel difference, ``vmax`` and above = white.

    A fixed ``vmax`` (not the image's own maximum) keeps maps of different methods and views
    comparable: the same colour always means the same error.
    """
    _check_same_shape(reference, ours)
    err = np.abs(np.asarray(reference, np.float32) - np.asarray(ours, np.float32)).mean(axis=2)
    t = np.clip(err / float(vmax), 0.0, 1.0) * (len(_HEAT_STOPS) - 1)
    low = np.minimum(np.floor(t).astype(np.int64), len(_HEAT_STOPS) - 2)
    frac = (t - low)[:, :, None]
    return (_HEAT_STOPS[low] * (1.0 - frac) + _HEAT_STOPS[low + 1] * frac).astype(np.float32)


def side_by_side(reference: np.ndarray, ours: np.ndarray, gap: int = 4, vmax: float = 0.25,
                 gap_colour: Sequence[float] = (1.0, 1.0, 1.0)) -> ImageArray:
    """``reference | ours | error map`` in one image, for ``--save-renders``."""
    _check_same_shape(reference, ours)
    return contact_sheet([np.asarray(reference, np.float32), np.asarray(ours, np.float32),
                          error_map(reference, ours, vmax)], columns=3, gap=gap,
                         background=gap_colour)


def contact_sheet(images: Sequence[np.ndarray], columns: int | None = None, gap: int = 4,
                  background: Sequence[float] = (1.0, 1.0, 1.0)) -> ImageArray:
    """Tile images row by row into one grid (e.g. a ``--turntable`` overview).

    Cells have the size of the largest image; smaller images are centred in theirs. ``columns``
    defaults to the smallest count giving a grid at least as wide as it is tall (in cells).
    """
    if len(images) == 0:
        raise ValueError("a contact sheet needs at least one image")
    tiles = [_as_rgb(img) for img in images]
    cols = columns or int(np.ceil(np.sqrt(len(tiles))))
    if cols < 1:
        raise ValueError("columns must be positive")
    rows = -(-len(tiles) // cols)
    cell_h = max(t.shape[0] for t in tiles)
    cell_w = max(t.shape[1] for t in tiles)
    sheet = np.empty((rows * cell_h + (rows - 1) * gap, cols * cell_w + (cols - 1) * gap, 3),
                     dtype=np.float32)
    sheet[:] = np.asarray(background, dtype=np.float32)
    for index, tile in enumerate(tiles):
        r, c = divmod(index, cols)
        top = r * (cell_h + gap) + (cell_h - tile.shape[0]) // 2
        left = c * (cell_w + gap) + (cell_w - tile.shape[1]) // 2
        sheet[top: top + tile.shape[0], left: left + tile.shape[1]] = tile
    return sheet


def _as_rgb(image: np.ndarray) -> np.ndarray:
    array = np.asarray(image)
    if array.dtype == np.uint8:
        array = array.astype(np.float32) / 255.0
    if array.ndim == 2:
        array = np.repeat(array[:, :, None], 3, axis=2)
    if array.ndim != 3 or array.shape[2] != 3:
        raise ValueError(f"expected an (H, W, 3) image, got shape {array.shape}")
    return array.astype(np.float32, copy=False)


def _check_same_shape(a: np.ndarray, b: np.ndarray) -> None:
    if np.shape(a) != np.shape(b) or np.ndim(a) != 3 or np.shape(a)[2] != 3:
        raise ValueError(f"images must both be (H, W, 3) of one size, got {np.shape(a)} and "
                         f"{np.shape(b)}")
