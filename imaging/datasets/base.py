"""The dataset model: views (camera + lazily loaded image), splits, errors and warnings.

Every loader produces the same :class:`Dataset`: pinhole :class:`~spcodec.imaging.cameras.Camera`
objects in OpenCV conventions (already undistorted and downscaled) and images that are read only
when asked for, because a real capture does not fit in memory as float32 (fox: 67 x 25 MB).
"""

from __future__ import annotations

import os
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Iterator, Sequence

import numpy as np

from spcodec.errors import FormatError

from ..cameras import Camera
from ..images import IMAGE_EXTENSIONS, ImageReadError, downscale_area, read_image
from .distortion import Undistorter

TEST_EVERY = 8
"""Hold-out rule when a dataset has no test split of its own: sorted view index % 8 == 0 is a test
view (the convention of 3DGS / Mip-NeRF 360 evaluations, ``--eval`` with ``llffhold=8``)."""


class DatasetError(FormatError):
    """A dataset folder cannot be used: missing files, unparsable poses, unknown camera model...

    The message is one line naming the problem and the file; the code is ``dataset-invalid``.
    """

    default_code = "dataset-invalid"


class MissingImageWarning(UserWarning):
    """Some views were skipped because their image file is absent (issued with ``warnings``)."""


@dataclass(frozen=True, eq=False)
class View:
    """One posed image: its final pinhole camera and how to produce the matching image."""

    name: str
    camera: Camera
    image_path: Path
    background: np.ndarray = field(repr=False)
    downscale: int = 1
    undistorter: Undistorter | None = field(default=None, repr=False)

    def load_image(self) -> np.ndarray:
        """float32 (H, W, 3) in [0, 1], composited, undistorted and downscaled like ``camera``."""
        try:
            image = read_image(self.image_path, self.background)
        except ImageReadError as exc:
            raise DatasetError(str(exc)) from None
        expected = (self.camera.height, self.camera.width)
        if self.undistorter is not None:
            full = (self.undistorter.height, self.undistorter.width)
            if image.shape[:2] != full:
                raise DatasetError(f"image {self.image_path} is {image.shape[1]}x{image.shape[0]}"
                                   f", its camera says {full[1]}x{full[0]}")
            image = self.undistorter.undistort(image)
        image = downscale_area(image, self.downscale)
        if image.shape[:2] != expected:
            raise DatasetError(f"image {self.image_path} gives {image.shape[1]}x{image.shape[0]} "
                               f"pixels, its camera says {expected[1]}x{expected[0]}")
        return image

    def valid_mask(self) -> np.ndarray | None:
        """(H, W) bool of pixels with captured data after undistortion; None when all are valid.

        A downscaled pixel is valid only when every full-resolution pixel it averages is.
        """
        if self.undistorter is None:
            return None
        mask = self.undistorter.valid_mask()
        if mask.all():
            return None
        return downscale_area(mask.astype(np.float32), self.downscale) >= 1.0


@dataclass(eq=False)
class Dataset:
    """Posed images of one scene, split into training and test views."""

    name: str
    root: Path
    format: str
    train: list[View]
    test: list[View]
    background: np.ndarray
    points: np.ndarray | None = field(default=None, repr=False)
    """Sparse 3D points (N, 3) of the reconstruction when the format has them (COLMAP)."""
    point_colors: np.ndarray | None = field(default=None, repr=False)
    """Their colours, uint8 (N, 3)."""

    @property
    def views(self) -> list[View]:
        return self.train + self.test

    def split(self, name: str) -> list[View]:
        """``"train"`` or ``"test"``."""
        if name not in ("train", "test"):
            raise ValueError(f"unknown split {name!r}: use 'train' or 'test'")
        return self.train if name == "train" else self.test

    def images(self, split: str = "test") -> Iterator[tuple[View, np.ndarray]]:
        """Each view of a split with its image, loaded one at a time."""
        for view in self.split(split):
            yield view, view.load_image()

    def __repr__(self) -> str:
        return (f"Dataset({self.name!r}, format={self.format}, train={len(self.train)}, "
                f"test={len(self.test)})")


def downscaled_camera(camera: Camera, factor: int) -> Camera:
    """The camera of an image shrunk by :func:`~spcodec.imaging.images.downscale_area`.

    Exact for any size: the output keeps floor(W/f) x floor(H/f) whole blocks and pixel coordinate
    u maps to u/f, so all four intrinsics are divided by ``factor``. (``Camera.scaled`` rounds the
    size and rescales by the rounded ratio, which is off by a fraction of a pixel when the size
    is not a multiple of the factor.)
    """
    if factor == 1:
        return camera
    width, height = camera.width // factor, camera.height // factor
    if width == 0 or height == 0:
        raise DatasetError(f"downscale {factor} leaves no pixel of a {camera.width}x"
                           f"{camera.height} image")
    return replace(camera, width=width, height=height, fx=camera.fx / factor,
                   fy=camera.fy / factor, cx=camera.cx / factor, cy=camera.cy / factor)


def release_unshared_maps(views: Sequence[View]) -> None:
    """Turn off map caching for undistorters that a single view uses (see Undistorter)."""
    users: dict[int, int] = {}
    for view in views:
        if view.undistorter is not None:
            users[id(view.undistorter)] = users.get(id(view.undistorter), 0) + 1
    for view in views:
        if view.undistorter is not None and users[id(view.undistorter)] == 1:
            view.undistorter.keep_maps = False


def rigid_inverse(matrix: np.ndarray) -> np.ndarray:
    """Inverse of a 4x4 rotation + translation, exact to rounding (no general matrix inverse)."""
    rot = matrix[:3, :3]
    out = np.eye(4)
    out[:3, :3] = rot.T
    out[:3, 3] = -rot.T @ matrix[:3, 3]
    return out


def nearest_rotation(matrix: np.ndarray) -> np.ndarray:
    """The rotation closest to an almost-orthonormal 3x3 (float noise in stored poses)."""
    u, _, vt = np.linalg.svd(matrix)
    return u @ vt


def hold_out_split(views: Sequence[View], every: int = TEST_EVERY) -> tuple[list[View], list[View]]:
    """(train, test): views sorted by name, index % ``every`` == 0 goes to test."""
    ordered = sorted(views, key=lambda v: v.name)
    test = [v for i, v in enumerate(ordered) if i % every == 0]
    train = [v for i, v in enumerate(ordered) if i % every != 0]
    return train, test


def warn_missing(source: str | os.PathLike, missing: Sequence[str], total: int) -> None:
    """One :class:`MissingImageWarning` per source file, naming the count and the first few."""
    if not missing:
        return
    shown = ", ".join(missing[:3]) + (", ..." if len(missing) > 3 else "")
    warnings.warn(f"{os.fspath(source)}: skipped {len(missing)} of {total} frames whose image is "
                  f"missing ({shown})", MissingImageWarning, stacklevel=3)


def parse_background(background: Sequence[float] | str | None, default: Sequence[float]
                     ) -> np.ndarray:
    """A background colour from None (use ``default``), ``"white"``/``"black"`` or an RGB triple."""
    if background is None:
        colour = default
    elif isinstance(background, str):
        names = {"white": (1.0, 1.0, 1.0), "black": (0.0, 0.0, 0.0)}
        if background.lower() not in names:
            raise ValueError(f"unknown background {background!r}: use 'white', 'black' or an RGB "
                             "triple in [0, 1]")
        colour = names[background.lower()]
    else:
        colour = background
    array = np.asarray(colour, dtype=np.float32).reshape(-1)
    if array.shape != (3,) or not np.all((array >= 0) & (array <= 1)):
        raise ValueError(f"background must be three values in [0, 1], got {background!r}")
    return array


def require_views(views: Sequence[View], root: Path, what: str) -> None:
    """Raise when nothing is left to use (every image missing, or none listed)."""
    if not views:
        raise DatasetError(f"dataset {root}: no usable views ({what})")


def resolve_image(folder: Path, name: str) -> Path | None:
    """The image file for ``name`` inside ``folder``: as given, else with a known extension."""
    candidate = folder / name
    if candidate.suffix and candidate.is_file():
        return candidate
    for ext in IMAGE_EXTENSIONS:
        with_ext = candidate.with_name(candidate.name + ext)
        if with_ext.is_file():
            return with_ext
    return candidate if candidate.is_file() else None
