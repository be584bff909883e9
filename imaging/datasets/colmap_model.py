"""Readers for COLMAP sparse models (cameras, images, points3D) in the binary and the text format.

Layouts (from COLMAP's documentation of its output format; all binary values little-endian):

* ``cameras.bin``: u64 count, then per camera: i32 id, i32 model id, u64 width, u64 height,
  f64 params[n(model)].  ``cameras.txt``: ``ID MODEL_NAME WIDTH HEIGHT PARAMS...``.
* ``images.bin``: u64 count, then per image: i32 id, f64 qw qx qy qz, f64 tx ty tz, i32 camera id,
  NUL-terminated name, u64 n2d, n2d x (f64 x, f64 y, i64 point3D id).  ``images.txt``: two lines
  per image, ``ID QW QX QY QZ TX TY TZ CAMERA_ID NAME`` then the 2D points (possibly empty).
* ``points3D.bin``: u64 count, then per point: u64 id, f64 xyz, u8 rgb, f64 error, u64 track
  length, length x (i32 image id, i32 point2D index).  ``points3D.txt``: ``ID X Y Z R G B ERROR
  TRACK...``.

(q, t) is the world-to-camera rotation (Hamilton quaternion, w first) and translation in COLMAP's
camera frame, which is OpenCV's (x right, y down, z forward).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .base import DatasetError

# model id -> (name, parameter count), for every model COLMAP defines, so that a binary file with a
# model we cannot undistort is still parsed and the error names the model.
CAMERA_MODELS: dict[int, tuple[str, int]] = {
    0: ("SIMPLE_PINHOLE", 3), 1: ("PINHOLE", 4), 2: ("SIMPLE_RADIAL", 4), 3: ("RADIAL", 5),
    4: ("OPENCV", 8), 5: ("OPENCV_FISHEYE", 8), 6: ("FULL_OPENCV", 12), 7: ("FOV", 5),
    8: ("SIMPLE_RADIAL_FISHEYE", 4), 9: ("RADIAL_FISHEYE", 5), 10: ("THIN_PRISM_FISHEYE", 12),
    11: ("RAD_TAN_THIN_PRISM_FISHEYE", 16),
}
MODEL_PARAM_COUNTS = {name: count for name, count in CAMERA_MODELS.values()}


@dataclass(frozen=True)
class ColmapCamera:
    camera_id: int
    model: str
    width: int
    height: int
    params: tuple[float, ...]


@dataclass(frozen=True)
class ColmapImage:
    image_id: int
    qvec: np.ndarray  # (4,) w, x, y, z
    tvec: np.ndarray  # (3,)
    camera_id: int
    name: str
    xys: np.ndarray  # (n, 2) observed (distorted) pixel positions
    point3d_ids: np.ndarray  # (n,) int64, -1 where the observation has no 3D point

    def world_to_camera(self) -> np.ndarray:
        """4x4 world-to-camera matrix from the stored quaternion and translation."""
        w2c = np.eye(4)
        w2c[:3, :3] = quaternion_to_matrix(self.qvec)
        w2c[:3, 3] = self.tvec
        return w2c


@dataclass(frozen=True)
class ColmapPoints:
    ids: np.ndarray  # (n,) int64
    xyz: np.ndarray  # (n, 3) float64
    rgb: np.ndarray  # (n, 3) uint8
    error: np.ndarray  # (n,) float64 mean reprojection error in pixels


def quaternion_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrix of a (w, x, y, z) quaternion, normalized first."""
    w, x, y, z = np.asarray(q, dtype=np.float64) / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


# ------------------------------------------------------------------------------------------ binary
class _Reader:
    """Sequential little-endian reader that reports truncation as a one-line DatasetError."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.data = path.read_bytes()
        self.pos = 0

    def take(self, fmt: str) -> tuple:
        size = struct.calcsize(fmt)
        if self.pos + size > len(self.data):
            raise DatasetError(f"{self.path}: truncated COLMAP binary file at byte {self.pos}")
        values = struct.unpack_from(fmt, self.data, self.pos)
        self.pos += size
        return values

    def array(self, dtype: np.dtype, count: int) -> np.ndarray:
        dtype = np.dtype(dtype)
        size = dtype.itemsize * count
        if count < 0 or self.pos + size > len(self.data):
            raise DatasetError(f"{self.path}: truncated COLMAP binary file at byte {self.pos}")
        out = np.frombuffer(self.data, dtype=dtype, count=count, offset=self.pos)
        self.pos += size
        return out

    def cstring(self) -> str:
        end = self.data.find(b"\x00", self.pos)
        if end < 0:
            raise DatasetError(f"{self.path}: truncated COLMAP binary file (unterminated name)")
        raw = self.data[self.pos:end]
        self.pos = end + 1
        try:
            return raw.decode("utf-8")
        except UnicodeDecodeError:
            raise DatasetError(f"{self.path}: image name at byte {self.pos} is not UTF-8") from None

    def check_count(self, count: int, min_record: int) -> None:
        if count * min_record > len(self.data) - self.pos:
            raise DatasetError(f"{self.path}: declares {count} records, more than the file holds")

    def finish(self) -> None:
        if self.pos != len(self.data):
            raise DatasetError(f"{self.path}: {len(self.data) - self.pos} unexpected bytes after "
                               "the last record")


def read_cameras_binary(path: Path) -> dict[int, ColmapCamera]:
    reader = _Reader(path)
    (count,) = reader.take("<Q")
    reader.check_count(count, 24)
    cameras = {}
    for _ in range(count):
        camera_id, model_id, width, height = reader.take("<iiQQ")
        if model_id not in CAMERA_MODELS:
            raise DatasetError(f"{path}: camera {camera_id} has unknown COLMAP model id {model_id}")
        name, n_params = CAMERA_MODELS[model_id]
        params = reader.take(f"<{n_params}d")
        cameras[camera_id] = ColmapCamera(camera_id, name, int(width), int(height), params)
    reader.finish()
    return cameras


_POINT2D = np.dtype([("x", "<f8"), ("y", "<f8"), ("id", "<i8")])


def read_images_binary(path: Path) -> dict[int, ColmapImage]:
    reader = _Reader(path)
    (count,) = reader.take("<Q")
    reader.check_count(count, 73)
    images = {}
    for _ in range(count):
        image_id, qw, qx, qy, qz, tx, ty, tz, camera_id = reader.take("<i7di")
        name = reader.cstring()
        (n2d,) = reader.take("<Q")
        points = reader.array(_POINT2D, n2d)
        images[image_id] = ColmapImage(
            image_id, np.array([qw, qx, qy, qz]), np.array([tx, ty, tz]), camera_id, name,
            np.stack([points["x"], points["y"]], axis=1), points["id"].astype(np.int64))
    reader.finish()
    return images


def read_points_binary(path: Path) -> ColmapPoints:
    reader = _Reader(path)
    (count,) = reader.take("<Q")
    reader.check_count(count, 51)
    ids = np.empty(count, np.int64)
    xyz = np.empty((count, 3))
    rgb = np.empty((count, 3), np.uint8)
    error = np.empty(count)
    for i in range(count):
        pid, x, y, z, r, g, b, err, track = reader.take("<Q3d3BdQ")
        reader.array(np.dtype("<i4"), 2 * track)  # the track (image id, 2D index) pairs: unused
        ids[i], xyz[i], rgb[i], error[i] = pid, (x, y, z), (r, g, b), err
    reader.finish()
    return ColmapPoints(ids, xyz, rgb, error)


# -------------------------------------------------------------------------------------------- text
def _data_lines(path: Path, keep_empty: bool = False) -> list[tuple[int, str]]:
    """(line number, text) of the non-comment lines; empty ones only if ``keep_empty``."""
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise DatasetError(f"{path}: not a UTF-8 text file") from None
    lines = []
    for number, line in enumerate(text.splitlines(), start=1):
        stripped = line.strip()
        if stripped.startswith("#") or (not stripped and not keep_empty):
            continue
        lines.append((number, stripped))
    return lines


def _bad_line(path: Path, number: int, what: str) -> DatasetError:
    return DatasetError(f"{path}:{number}: cannot parse {what}")


def read_cameras_text(path: Path) -> dict[int, ColmapCamera]:
    cameras = {}
    for number, line in _data_lines(path):
        fields = line.split()
        try:
            camera_id, model = int(fields[0]), fields[1]
            width, height = int(fields[2]), int(fields[3])
            params = tuple(float(v) for v in fields[4:])
        except (IndexError, ValueError):
            raise _bad_line(path, number, "a camera line") from None
        expected = MODEL_PARAM_COUNTS.get(model)
        if expected is not None and expected != len(params):
            raise DatasetError(f"{path}:{number}: camera model {model} needs {expected} "
                               f"parameters, found {len(params)}")
        cameras[camera_id] = ColmapCamera(camera_id, model, width, height, params)
    return cameras


def read_images_text(path: Path) -> dict[int, ColmapImage]:
    lines = _data_lines(path, keep_empty=True)
    # An image's 2D-point line may be empty, so lines are paired from each header onwards; trailing
    # blank lines at the end of the file are harmless.
    while lines and not lines[-1][1]:
        lines.pop()
    images = {}
    index = 0
    while index < len(lines):
        number, header = lines[index]
        if not header:  # stray blank line between records
            index += 1
            continue
        fields = header.split()
        try:
            image_id = int(fields[0])
            qvec = np.array([float(v) for v in fields[1:5]])
            tvec = np.array([float(v) for v in fields[5:8]])
            camera_id = int(fields[8])
            name = header.split(None, 9)[9]
        except (IndexError, ValueError):
            raise _bad_line(path, number, "an image line") from None
        points_line = lines[index + 1][1] if index + 1 < len(lines) else ""
        values = points_line.split()
        if len(values) % 3:
            raise _bad_line(path, lines[index + 1][0], "the 2D points of an image")
        try:
            table = np.array([float(v) for v in values]).reshape(-1, 3)
        except ValueError:
            raise _bad_line(path, lines[index + 1][0], "the 2D points of an image") from None
        if qvec.shape != (4,) or tvec.shape != (3,):
            raise _bad_line(path, number, "an image line")
        images[image_id] = ColmapImage(image_id, qvec, tvec, camera_id, name, table[:, :2],
                                       table[:, 2].astype(np.int64))
        index += 2
    return images


def read_points_text(path: Path) -> ColmapPoints:
    ids, xyz, rgb, error = [], [], [], []
    for number, line in _data_lines(path):
        fields = line.split()
        try:
            ids.append(int(fields[0]))
            xyz.append([float(v) for v in fields[1:4]])
            rgb.append([int(v) for v in fields[4:7]])
            error.append(float(fields[7]))
        except (IndexError, ValueError):
            raise _bad_line(path, number, "a 3D point line") from None
    return ColmapPoints(np.array(ids, np.int64), np.array(xyz, np.float64).reshape(-1, 3),
                        np.array(rgb, np.uint8).reshape(-1, 3), np.array(error, np.float64))


# -------------------------------------------------------------------------------------- the model
@dataclass(frozen=True)
class ColmapModel:
    cameras: dict[int, ColmapCamera]
    images: dict[int, ColmapImage]
    points: ColmapPoints | None


def find_model_folder(root: Path) -> Path | None:
    """``sparse/0``, ``sparse`` or ``root`` itself, whichever holds cameras + images files."""
    for folder in (root / "sparse" / "0", root / "sparse", root):
        if _has(folder, "cameras") and _has(folder, "images"):
            return folder
    return None


def _has(folder: Path, stem: str) -> bool:
    return (folder / f"{stem}.bin").is_file() or (folder / f"{stem}.txt").is_file()


def read_model(folder: Path) -> ColmapModel:
    """Read a model, preferring the binary files when both formats are present."""
    def pick(stem: str) -> tuple[Path, bool] | None:
        for ext, binary in ((".bin", True), (".txt", False)):
            path = folder / f"{stem}{ext}"
            if path.is_file():
                return path, binary
        return None

    found_cameras, found_images = pick("cameras"), pick("images")
    if found_cameras is None or found_images is None:
        raise DatasetError(f"COLMAP model folder {folder} lacks cameras.bin/.txt or "
                           "images.bin/.txt")
    cam_path, cam_bin = found_cameras
    img_path, img_bin = found_images
    cameras = read_cameras_binary(cam_path) if cam_bin else read_cameras_text(cam_path)
    images = read_images_binary(img_path) if img_bin else read_images_text(img_path)
    points = None
    found_points = pick("points3D")
    if found_points is not None:
        pts_path, pts_bin = found_points
        points = read_points_binary(pts_path) if pts_bin else read_points_text(pts_path)
    return ColmapModel(cameras, images, points)
