"""COLMAP datasets: ``sparse/0/`` (or ``sparse/``) model + ``images/`` folder, as 3DGS trains on.

COLMAP poses are already world-to-camera in OpenCV axes, so they are used unchanged; distorted
camera models are undistorted to a same-size pinhole camera (see :mod:`.distortion`).
"""

from __future__ import annotations

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
    release_unshared_maps,
    require_views,
    warn_missing,
)
from .colmap_model import ColmapCamera, ColmapModel, read_model
from .distortion import Distortion, Undistorter

SUPPORTED_MODELS = ("SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV")


def pinhole_and_distortion(camera: ColmapCamera
                           ) -> tuple[tuple[float, float, float, float], Distortion]:
    """((fx, fy, cx, cy), distortion) of a COLMAP camera; DatasetError for other models."""
    p = camera.params
    model = camera.model
    if model == "SIMPLE_PINHOLE":
        return (p[0], p[0], p[1], p[2]), Distortion()
    if model == "PINHOLE":
        return (p[0], p[1], p[2], p[3]), Distortion()
    if model == "SIMPLE_RADIAL":
        return (p[0], p[0], p[1], p[2]), Distortion(k1=p[3])
    if model == "RADIAL":
        return (p[0], p[0], p[1], p[2]), Distortion(k1=p[3], k2=p[4])
    if model == "OPENCV":
        return (p[0], p[1], p[2], p[3]), Distortion(k1=p[4], k2=p[5], p1=p[6], p2=p[7])
    raise DatasetError(f"camera {camera.camera_id} uses COLMAP model {model}, which is not "
                       f"supported (supported: {', '.join(SUPPORTED_MODELS)})")


def load_colmap(root: Path, model_folder: Path, downscale: int, background: np.ndarray,
                test_every: int) -> Dataset:
    """Read the model in ``model_folder`` and the images of ``root/images``."""
    model = read_model(model_folder)
    image_folder = root / "images"
    if not image_folder.is_dir():
        raise DatasetError(f"COLMAP dataset {root} has no images/ folder")
    if not model.images:
        raise DatasetError(f"COLMAP model {model_folder} registers no images")
    views = _views(model, model_folder, image_folder, downscale, background)
    require_views(views, root, f"none of the {len(model.images)} images listed in "
                               f"{model_folder} exists in {image_folder}")
    release_unshared_maps(views)
    train, test = hold_out_split(views, test_every)
    points = colors = None
    if model.points is not None and len(model.points.ids):
        points, colors = model.points.xyz, model.points.rgb
    return Dataset(root.name, root, "colmap", train, test, background, points, colors)


def _views(model: ColmapModel, model_folder: Path, image_folder: Path, downscale: int,
           background: np.ndarray) -> list[View]:
    undistorters: dict[int, Undistorter | None] = {}
    pinholes: dict[int, tuple[float, float, float, float]] = {}
    views, missing = [], []
    for image in sorted(model.images.values(), key=lambda im: im.name):
        camera = model.cameras.get(image.camera_id)
        if camera is None:
            raise DatasetError(f"{model_folder}: image {image.name} refers to camera "
                               f"{image.camera_id}, which is not in the cameras file")
        if camera.camera_id not in pinholes:
            intrinsics, distortion = pinhole_and_distortion(camera)
            pinholes[camera.camera_id] = intrinsics
            undistorters[camera.camera_id] = None if distortion.is_identity else Undistorter(
                camera.width, camera.height, *intrinsics, distortion)
        path = image_folder / image.name
        if not path.is_file():
            missing.append(image.name)
            continue
        _check_size(path, camera)
        fx, fy, cx, cy = pinholes[camera.camera_id]
        w2c = image.world_to_camera()
        name = Path(image.name).with_suffix("").as_posix()
        full = Camera(camera.width, camera.height, fx, fy, cx, cy, w2c, name)
        views.append(View(name, downscaled_camera(full, downscale), path,
                          background, downscale, undistorters[camera.camera_id]))
    warn_missing(model_folder, missing, len(model.images))
    return views


def _check_size(path: Path, camera: ColmapCamera) -> None:
    try:
        size = image_size(path)
    except ImageReadError as exc:
        raise DatasetError(str(exc)) from None
    if size != (camera.width, camera.height):
        raise DatasetError(f"image {path} is {size[0]}x{size[1]} but COLMAP camera "
                           f"{camera.camera_id} is {camera.width}x{camera.height}")
