"""Posed-image datasets for evaluation and training: COLMAP, NeRF/instant-ngp transforms, LLFF.

``load_dataset(path)`` detects the format of a folder, in this order:

1. ``transforms_train.json`` (+ ``transforms_test.json``) or ``transforms.json``: NeRF-synthetic /
   instant-ngp (a path to one ``.json`` file also works);
2. a COLMAP model (``sparse/0/``, ``sparse/`` or the folder itself, with cameras and images files,
   binary or text) and an ``images/`` folder;
3. ``poses_bounds.npy`` and an ``images*/`` folder: LLFF (used when COLMAP's images file is absent,
   as for fern).

The test split is the dataset's own (``transforms_test.json``) when it has one, else every 8th
view in name order (index % 8 == 0), the 3DGS / Mip-NeRF 360 convention.

Every problem with a dataset raises :class:`DatasetError` (a ``FormatError`` with the code
``dataset-invalid``) whose message is one line; skipped frames (missing images) issue a
:class:`MissingImageWarning` through :mod:`warnings`.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Sequence

from spcodec.errors import UsageError

from .base import (
    TEST_EVERY,
    Dataset,
    DatasetError,
    MissingImageWarning,
    View,
    downscaled_camera,
    hold_out_split,
    parse_background,
)
from .colmap import SUPPORTED_MODELS, load_colmap
from .colmap_model import find_model_folder
from .distortion import Distortion, Undistorter
from .llff import load_llff
from .transforms import find_transform_files, load_transforms

__all__ = [
    "Dataset", "DatasetError", "Distortion", "MissingImageWarning", "SUPPORTED_MODELS",
    "TEST_EVERY", "Undistorter", "View", "detect_format", "downscaled_camera", "hold_out_split",
    "load_dataset",
]

_BLACK = (0.0, 0.0, 0.0)


def detect_format(path: str | os.PathLike) -> str:
    """``"transforms"``, ``"colmap"`` or ``"llff"``; DatasetError when none fits."""
    root = Path(path)
    if not root.exists():
        raise DatasetError(f"dataset {root} does not exist")
    if root.is_file():
        if root.suffix.lower() == ".json":
            return "transforms"
        raise DatasetError(f"dataset {root} is a file; give a dataset folder or a transforms "
                           "JSON file")
    if not any(root.iterdir()):
        raise DatasetError(f"dataset folder {root} is empty")
    if find_transform_files(root) is not None:
        return "transforms"
    if find_model_folder(root) is not None:
        return "colmap"
    if (root / "poses_bounds.npy").is_file():
        return "llff"
    for folder in (root / "sparse" / "0", root / "sparse"):
        if (folder / "cameras.bin").is_file() or (folder / "cameras.txt").is_file():
            raise DatasetError(f"COLMAP model {folder} has no images.bin or images.txt (and "
                               f"there is no poses_bounds.npy)")
    raise DatasetError(f"no dataset found in {root}: expected transforms*.json, a COLMAP "
                       "sparse/0/ model or poses_bounds.npy")


def load_dataset(path: str | os.PathLike, downscale: int = 1,
                 background: Sequence[float] | str | None = None,
                 test_every: int = TEST_EVERY) -> Dataset:
    """Load the dataset at ``path`` (see the module docstring for the formats and the split).

    ``downscale``: integer factor; images are area-averaged and cameras scaled to match.
    ``background``: RGB in [0, 1] or "white"/"black" for compositing RGBA images; default white
    for transforms datasets whose images have alpha, black otherwise.
    """
    if isinstance(downscale, bool) or not isinstance(downscale, int) or downscale < 1:
        raise UsageError(f"downscale must be a positive integer, got {downscale!r}")
    if isinstance(test_every, bool) or not isinstance(test_every, int) or test_every < 2:
        raise UsageError(f"test_every must be an integer >= 2, got {test_every!r}")
    try:
        colour = None if background is None else parse_background(background, _BLACK)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    root = Path(path)
    kind = detect_format(root)
    if kind == "transforms":
        if root.is_file():
            return load_transforms(root.parent, root, None, downscale, colour, test_every)
        train_json, test_json = find_transform_files(root)
        return load_transforms(root, train_json, test_json, downscale, colour, test_every)
    colour = parse_background(None, _BLACK) if colour is None else colour
    if kind == "colmap":
        return load_colmap(root, find_model_folder(root), downscale, colour, test_every)
    return load_llff(root, downscale, colour, test_every)
