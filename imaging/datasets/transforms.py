"""NeRF-synthetic / instant-ngp datasets: ``transforms_{train,test}.json`` or ``transforms.json``.

Conventions handled here:

* ``transform_matrix`` is camera-to-world with OpenGL/Blender camera axes (x right, y up,
  z backward). Our cameras are OpenCV (x right, y down, z forward), so the camera axes y and z are
  negated, ``c2w_cv = c2w_gl @ diag(1, -1, -1, 1)``, and the result is inverted to
  world-to-camera.
  World coordinates are kept as in the file (no recentring or rescaling, as in 3DGS).
* Intrinsics: ``fl_x``/``fl_y`` in pixels, else ``camera_angle_x``/``camera_angle_y`` (full field
  of view in radians); fy defaults to fx; ``cx``/``cy`` default to the image centre; ``w``/``h``
  default to the image size. Any of these, and the distortion terms ``k1 k2 k3 p1 p2``, may be
  overridden per frame.
* Image paths are relative to the JSON file, with or without an extension.
* RGBA images are composited over the background: white by default when the images carry alpha
  (the NeRF-synthetic evaluation convention), black otherwise; ``background=`` overrides.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from ..cameras import Camera
from ..images import ImageReadError, image_has_alpha, image_size
from .base import (
    Dataset,
    DatasetError,
    View,
    downscaled_camera,
    hold_out_split,
    nearest_rotation,
    release_unshared_maps,
    require_views,
    resolve_image,
    rigid_inverse,
    warn_missing,
)
from .distortion import Distortion, Undistorter

GL_TO_CV = np.diag([1.0, -1.0, -1.0, 1.0])
"""Right-multiplying a camera-to-world matrix by this flips its camera y and z axes."""

_INTRINSIC_KEYS = ("fl_x", "fl_y", "camera_angle_x", "camera_angle_y", "cx", "cy", "w", "h",
                   "k1", "k2", "k3", "p1", "p2")
_UNSUPPORTED_KEYS = ("k4", "is_fisheye")


def find_transform_files(root: Path) -> tuple[Path, Path | None] | None:
    """(train json, test json or None), or None when the folder has no transforms file."""
    train = root / "transforms_train.json"
    if train.is_file():
        test = root / "transforms_test.json"
        return train, test if test.is_file() else None
    single = root / "transforms.json"
    if single.is_file():
        return single, None
    return None


def load_transforms(root: Path, train_json: Path, test_json: Path | None, downscale: int,
                    background: np.ndarray | None, test_every: int) -> Dataset:
    """Load the frames of one or two transforms files; see the module docstring."""
    train_frames = _frames(train_json)
    test_frames = _frames(test_json) if test_json is not None else []
    if background is None:
        background = _default_background(train_frames + test_frames)
    cache: dict[tuple, Undistorter] = {}
    train = _views(train_json, train_frames, root, downscale, background, cache)
    test = _views(test_json, test_frames, root, downscale, background, cache) if test_json else []
    require_views(train + test, root, "every image listed in the transforms files is missing")
    release_unshared_maps(train + test)
    if test_json is None:
        train, test = hold_out_split(train, test_every)
    return Dataset(root.name, root, "transforms", train, test, background)


class _Frame:
    """One frame of a transforms file, with the file-level intrinsics merged in."""

    def __init__(self, source: Path, index: int, raw: dict[str, Any], top: dict[str, Any]) -> None:
        self.source, self.index = source, index
        where = f"{source}: frame {index}"
        path = raw.get("file_path")
        if not isinstance(path, str) or not path:
            raise DatasetError(f"{where} has no file_path")
        self.file_path = path
        self.where = f"{where} ({path})"
        self.params = {k: top[k] for k in _INTRINSIC_KEYS if k in top}
        self.params.update({k: raw[k] for k in _INTRINSIC_KEYS if k in raw})
        for key in _UNSUPPORTED_KEYS:
            value = raw.get(key, top.get(key))
            if value not in (None, 0, 0.0, False):
                raise DatasetError(f"{self.where}: {key}={value} (fisheye or k4 distortion) is "
                                   "not supported")
        for key, value in self.params.items():
            if not isinstance(value, (int, float)) or isinstance(value, bool) \
                    or not math.isfinite(value):
                raise DatasetError(f"{self.where}: {key} is not a finite number")
        self.c2w_gl = _pose(raw.get("transform_matrix"), self.where)
        self.image: Path | None = resolve_image(source.parent, path)


def _frames(path: Path) -> list[_Frame]:
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise DatasetError(f"{path}: not valid JSON ({str(exc).splitlines()[0]})") from None
    if not isinstance(data, dict) or not isinstance(data.get("frames"), list):
        raise DatasetError(f"{path}: no 'frames' list")
    frames = []
    for index, raw in enumerate(data["frames"]):
        if not isinstance(raw, dict):
            raise DatasetError(f"{path}: frame {index} is not an object")
        frames.append(_Frame(path, index, raw, data))
    return frames


def _pose(matrix: Any, where: str) -> np.ndarray:
    """The camera-to-world matrix as a finite rigid 4x4; DatasetError otherwise."""
    try:
        m = np.array(matrix, dtype=np.float64)
    except (TypeError, ValueError):
        raise DatasetError(f"{where}: transform_matrix is not a numeric matrix") from None
    if m.shape == (3, 4):
        m = np.vstack([m, [0.0, 0.0, 0.0, 1.0]])
    if m.shape != (4, 4) or not np.isfinite(m).all():
        raise DatasetError(f"{where}: transform_matrix is not a finite 4x4 (or 3x4) matrix")
    rot = m[:3, :3]
    if np.abs(rot.T @ rot - np.eye(3)).max() > 1e-2 or np.linalg.det(rot) <= 0:
        raise DatasetError(f"{where}: transform_matrix rotation is not orthonormal (a scaled or "
                           "mirrored pose)")
    m[:3, :3] = nearest_rotation(rot)  # remove float noise so world_to_camera is exactly rigid
    return m


def _default_background(frames: list[_Frame]) -> np.ndarray:
    for frame in frames:
        if frame.image is not None:
            try:
                alpha = image_has_alpha(frame.image)
            except ImageReadError as exc:
                raise DatasetError(str(exc)) from None
            return np.ones(3, np.float32) if alpha else np.zeros(3, np.float32)
    return np.zeros(3, np.float32)


def _views(source: Path, frames: list[_Frame], root: Path, downscale: int,
           background: np.ndarray, cache: dict[tuple, Undistorter]) -> list[View]:
    views, missing = [], []
    for frame in frames:
        if frame.image is None:
            missing.append(frame.file_path)
            continue
        camera, undistorter = _camera(frame, cache)
        name = _view_name(frame.image, root)
        camera = Camera(camera.width, camera.height, camera.fx, camera.fy, camera.cx, camera.cy,
                        camera.world_to_camera, name)
        views.append(View(name, downscaled_camera(camera, downscale), frame.image, background,
                          downscale, undistorter))
    warn_missing(source, missing, len(frames))
    return views


def _view_name(image: Path, root: Path) -> str:
    try:
        relative = image.relative_to(root)
    except ValueError:
        relative = Path(image.name)
    return relative.with_suffix("").as_posix()


def _camera(frame: _Frame, cache: dict[tuple, Undistorter]) -> tuple[Camera, Undistorter | None]:
    p = frame.params
    try:
        actual = image_size(frame.image)
    except ImageReadError as exc:
        raise DatasetError(str(exc)) from None
    width = int(round(p.get("w", actual[0])))
    height = int(round(p.get("h", actual[1])))
    if (width, height) != actual:
        raise DatasetError(f"{frame.where}: image is {actual[0]}x{actual[1]} but w/h say "
                           f"{width}x{height}")
    if "fl_x" in p:
        fx = float(p["fl_x"])
    elif "camera_angle_x" in p:
        fx = 0.5 * width / math.tan(0.5 * float(p["camera_angle_x"]))
    else:
        raise DatasetError(f"{frame.where}: no focal length (fl_x or camera_angle_x)")
    if "fl_y" in p:
        fy = float(p["fl_y"])
    elif "camera_angle_y" in p:
        fy = 0.5 * height / math.tan(0.5 * float(p["camera_angle_y"]))
    else:
        fy = fx
    cx = float(p.get("cx", width / 2.0))
    cy = float(p.get("cy", height / 2.0))
    if not (fx > 0 and fy > 0):
        raise DatasetError(f"{frame.where}: focal length must be positive")
    distortion = Distortion(*(float(p.get(k, 0.0)) for k in ("k1", "k2", "k3", "p1", "p2")))
    c2w = frame.c2w_gl @ GL_TO_CV
    camera = Camera(width, height, fx, fy, cx, cy, rigid_inverse(c2w))
    if distortion.is_identity:
        return camera, None
    key = (width, height, fx, fy, cx, cy, distortion)
    if key not in cache:
        cache[key] = Undistorter(width, height, fx, fy, cx, cy, distortion)
    return camera, cache[key]
