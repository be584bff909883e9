"""The one camera type shared by datasets, sampled views and the renderers (numpy only).

Conventions (those of COLMAP, the INRIA 3DGS code and gsplat):

* ``world_to_camera`` is a 4x4 rigid transform to camera coordinates with x right, y down and
  z forward (OpenCV); a point is visible when its camera z is positive.
* Pinhole intrinsics ``fx, fy, cx, cy`` in pixels: a camera point (x, y, z) lands at the continuous
  image coordinate ``(fx * x / z + cx, fy * y / z + cy)``; pixel (row r, column c) covers
  [c, c+1) x [r, r+1) and its centre is (c + 0.5, r + 0.5).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np


@dataclass(frozen=True)
class Camera:
    """A pinhole camera: image size, intrinsics and world-to-camera pose."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    world_to_camera: np.ndarray = field(repr=False)
    name: str = ""

    def __post_init__(self) -> None:
        w2c = np.asarray(self.world_to_camera, dtype=np.float64)
        if w2c.shape != (4, 4) or not np.isfinite(w2c).all():
            raise ValueError("world_to_camera must be a finite 4x4 matrix")
        object.__setattr__(self, "world_to_camera", w2c)
        if self.width <= 0 or self.height <= 0 or self.fx <= 0 or self.fy <= 0:
            raise ValueError(f"camera {self.name!r} has a non-positive size or focal length")

    @property
    def intrinsics(self) -> np.ndarray:
        """The 3x3 matrix K."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def rotation(self) -> np.ndarray:
        """World-to-camera rotation R (3x3)."""
        return self.world_to_camera[:3, :3]

    @property
    def translation(self) -> np.ndarray:
        """World-to-camera translation t (3,)."""
        return self.world_to_camera[:3, 3]

    @property
    def position(self) -> np.ndarray:
        """Camera centre in world coordinates, ``-R^T t``."""
        return -self.rotation.T @ self.translation

    @property
    def fov_x(self) -> float:
        return 2.0 * math.atan(self.width / (2.0 * self.fx))

    @property
    def fov_y(self) -> float:
        return 2.0 * math.atan(self.height / (2.0 * self.fy))

    def scaled(self, factor: float) -> "Camera":
        """The same view at ``factor`` times the resolution (e.g. 0.5 for --downscale 2)."""
        width = max(1, int(round(self.width * factor)))
        height = max(1, int(round(self.height * factor)))
        sx, sy = width / self.width, height / self.height
        return replace(self, width=width, height=height, fx=self.fx * sx, fy=self.fy * sy,
                       cx=self.cx * sx, cy=self.cy * sy)

    def dollied(self, towards: np.ndarray, factor: float) -> "Camera":
        """The same view direction from ``factor`` times the distance to the point ``towards``
        (0.5: halfway there), orientation and intrinsics unchanged: a viewer's zoom by walking."""
        if not factor > 0:
            raise ValueError(f"a dolly factor must be positive, got {factor}")
        towards = np.asarray(towards, dtype=np.float64)
        eye = towards + factor * (self.position - towards)
        w2c = self.world_to_camera.copy()
        w2c[:3, 3] = -self.rotation @ eye
        return replace(self, world_to_camera=w2c)

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Image coordinates (n, 2) and camera depths (n,) of world points (n, 3)."""
        # a contiguous matrix: numpy multiplies by a strided 3x3 view 20x slower (no BLAS)
        cam = points @ np.ascontiguousarray(self.rotation.T) + self.translation
        z = cam[:, 2]
        safe = np.where(np.abs(z) < 1e-12, 1e-12, z)
        uv = np.stack([self.fx * cam[:, 0] / safe + self.cx, self.fy * cam[:, 1] / safe + self.cy],
                      axis=1)
        return uv, z

    @classmethod
    def look_at(cls, eye: np.ndarray, target: np.ndarray, up: np.ndarray, width: int, height: int,
                fov_y: float, name: str = "") -> "Camera":
        """A camera at ``eye`` looking at ``target``, with ``up`` pointing up in the image.

        ``fov_y`` is the vertical field of view in radians; the principal point is the image centre.
        """
        eye, target, up = (np.asarray(v, dtype=np.float64) for v in (eye, target, up))
        forward = target - eye
        forward /= np.linalg.norm(forward)
        right = np.cross(forward, up)
        if np.linalg.norm(right) < 1e-9:  # up parallel to the view direction: pick another
            right = np.cross(forward, np.array([1.0, 0.0, 0.0]) if abs(forward[0]) < 0.9
                             else np.array([0.0, 0.0, 1.0]))
        right /= np.linalg.norm(right)
        down = np.cross(forward, right)
        rot = np.stack([right, down, forward])  # rows: camera x, y, z axes in world coordinates
        w2c = np.eye(4)
        w2c[:3, :3] = rot
        w2c[:3, 3] = -rot @ eye
        focal = 0.5 * height / math.tan(0.5 * fov_y)
        return cls(width, height, focal, focal, width / 2.0, height / 2.0, w2c, name)
