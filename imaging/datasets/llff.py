"""LLFF datasets: ``poses_bounds.npy`` + an ``images/`` or ``images_K/`` folder (e.g. fern).

``poses_bounds.npy`` is an (N, 17) float array, one row per image in sorted file-name order: a
3x5 matrix (row-major) then the near and far depth bounds. Its first three columns are the
camera-to-world rotation with camera axes ordered (down, right, backward), the fourth the camera
centre in world coordinates and the fifth (height, width, focal) of the full-resolution images.
LLFF derives these from a COLMAP reconstruction by permuting the camera axes only, so the world
frame is COLMAP's. The OpenCV camera-to-world rotation is therefore
``[right, down, forward] = [col1, col0, -col2]``.

The format stores no principal point and no distortion: the principal point is the image centre
and images are used as they are (fern's images were produced that way for NeRF's experiments).
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from ..cameras import Camera
from ..images import ImageReadError, image_size
from .base import (
    Dataset,
    DatasetError,
    View,
    downscaled_camera,
    hold_out_split,
    nearest_rotation,
    rigid_inverse,
)

_IMAGE_SUFFIXES = {".png", ".jpg", ".jpeg"}


def read_poses_bounds(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(c2w (N, 4, 4) in OpenCV axes, hwf (N, 3), bounds (N, 2)) from a poses_bounds.npy file."""
    try:
        data = np.load(path, allow_pickle=False)
    except (ValueError, OSError, EOFError) as exc:
        raise DatasetError(f"{path}: not a readable .npy array ({str(exc).splitlines()[0]})") \
            from None
    if data.ndim != 2 or data.shape[1] != 17 or data.shape[0] == 0 or data.dtype.kind not in "fiu":
        raise DatasetError(f"{path}: expected an (N, 17) numeric array, found {data.shape} "
                           f"{data.dtype}")
    data = data.astype(np.float64)
    if not np.isfinite(data).all():
        raise DatasetError(f"{path}: poses contain non-finite values")
    mats = data[:, :15].reshape(-1, 3, 5)
    down, right, back = mats[:, :, 0], mats[:, :, 1], mats[:, :, 2]
    rot = np.stack([right, down, -back], axis=2)  # columns: camera x, y, z axes in world
    err = np.abs(np.einsum("nji,njk->nik", rot, rot) - np.eye(3)).max(axis=(1, 2))
    if (err > 1e-2).any() or (np.linalg.det(rot) <= 0).any():
        bad = int(np.argmax((err > 1e-2) | (np.linalg.det(rot) <= 0)))
        raise DatasetError(f"{path}: pose {bad} is not a rotation in LLFF (down, right, back) axes")
    c2w = np.tile(np.eye(4), (len(data), 1, 1))
    c2w[:, :3, :3] = [nearest_rotation(r) for r in rot]
    c2w[:, :3, 3] = mats[:, :, 3]
    hwf = mats[:, :, 4]
    if (hwf <= 0).any():
        raise DatasetError(f"{path}: non-positive image size or focal length in the poses")
    return c2w, hwf, data[:, 15:17]


def list_images(folder: Path) -> list[Path]:
    return sorted(p for p in folder.iterdir()
                  if p.is_file() and p.suffix.lower() in _IMAGE_SUFFIXES
                  and not p.name.startswith("."))


def _image_folder(root: Path, count: int) -> tuple[Path, list[Path]]:
    """``images/`` when it holds one image per pose, else the least-downsampled ``images_K/``."""
    candidates = []
    for folder in root.iterdir():
        match = re.fullmatch(r"images(?:_(\d+))?", folder.name)
        if match and folder.is_dir():
            candidates.append((int(match.group(1) or 1), folder))
    found = []
    for _, folder in sorted(candidates):
        images = list_images(folder)
        if len(images) == count:
            return folder, images
        found.append(f"{folder.name}/ has {len(images)}")
    detail = "; ".join(found) if found else "no images/ or images_K/ folder"
    raise DatasetError(f"{root / 'poses_bounds.npy'} has {count} poses but no image folder has "
                       f"as many images ({detail})")


def load_llff(root: Path, downscale: int, background: np.ndarray, test_every: int) -> Dataset:
    c2w, hwf, _bounds = read_poses_bounds(root / "poses_bounds.npy")
    folder, images = _image_folder(root, len(c2w))
    views = []
    for path, pose, (height, width, focal) in zip(images, c2w, hwf):
        try:
            w, h = image_size(path)
        except ImageReadError as exc:
            raise DatasetError(str(exc)) from None
        sx, sy = w / width, h / height
        if abs(sx - sy) * max(width, height) > 1.0:
            raise DatasetError(f"image {path} is {w}x{h}, not a uniform scaling of the "
                               f"{width:.0f}x{height:.0f} of poses_bounds.npy")
        w2c = rigid_inverse(pose)
        name = path.stem
        camera = Camera(w, h, focal * sx, focal * sy, w / 2.0, h / 2.0, w2c, name)
        views.append(View(name, downscaled_camera(camera, downscale), path, background,
                          downscale))
    train, test = hold_out_split(views, test_every)
    return Dataset(root.name, root, "llff", train, test, background)
