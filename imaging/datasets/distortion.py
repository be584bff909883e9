"""Lens distortion (the OpenCV/COLMAP radial-tangential model) and image undistortion, numpy only.

Model, on normalized camera coordinates (x, y) = (X/Z, Y/Z), with r2 = x^2 + y^2::

    radial = k1 r2 + k2 r2^2 + k3 r2^3
    xd = x (1 + radial) + 2 p1 x y + p2 (r2 + 2 x^2)
    yd = y (1 + radial) + p1 (r2 + 2 y^2) + 2 p2 x y

and the distorted pixel is (fx xd + cx, fy yd + cy). COLMAP's SIMPLE_RADIAL (k), RADIAL (k1, k2)
and OPENCV (k1, k2, p1, p2) and instant-ngp's k1/k2/p1/p2 are all special cases.

**Undistortion choice: keep the size and the intrinsics.** The undistorted image has the same
width, height, fx, fy, cx, cy as the distorted one, with zero distortion. Each output pixel centre
is mapped through the *forward* model to where that ray landed in the captured image, and the
captured image is sampled there bilinearly (no inversion is needed for this direction). Output
pixels whose ray falls outside the captured image (slivers at the corners for k > 0) are filled by
clamping to the nearest edge pixel and flagged invalid in :meth:`Undistorter.valid_mask`, so a
metric can leave them out. For our real data the invalid area is tiny (beer, k ~ 0.05: < 1%; fox:
~0%), and keeping the size avoids changing the cameras that poses were estimated with. The inverse
model (:meth:`Distortion.undistort_points`, Newton iterations) is used to map distorted
observations to ideal pinhole ones (e.g. COLMAP 2D points, or synthesizing distorted test images).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class Distortion:
    """Radial (k1, k2, k3) and tangential (p1, p2) coefficients of the OpenCV model."""

    k1: float = 0.0
    k2: float = 0.0
    k3: float = 0.0
    p1: float = 0.0
    p2: float = 0.0

    @property
    def is_identity(self) -> bool:
        return self.k1 == 0.0 and self.k2 == 0.0 and self.k3 == 0.0 and self.p1 == 0.0 \
            and self.p2 == 0.0

    def distort_points(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Ideal normalized coordinates -> distorted normalized coordinates (the forward model)."""
        r2 = x * x + y * y
        radial = r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3))
        xy = x * y
        xd = x * (1.0 + radial) + 2.0 * self.p1 * xy + self.p2 * (r2 + 2.0 * x * x)
        yd = y * (1.0 + radial) + self.p1 * (r2 + 2.0 * y * y) + 2.0 * self.p2 * xy
        return xd, yd

    def _jacobian(self, x: np.ndarray, y: np.ndarray):
        r2 = x * x + y * y
        radial = r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3))
        d_radial = self.k1 + r2 * (2.0 * self.k2 + 3.0 * self.k3 * r2)  # d radial / d r2
        a = 1.0 + radial + 2.0 * x * x * d_radial + 2.0 * self.p1 * y + 6.0 * self.p2 * x
        b = 2.0 * x * y * d_radial + 2.0 * self.p1 * x + 2.0 * self.p2 * y  # both off-diagonals
        d = 1.0 + radial + 2.0 * y * y * d_radial + 6.0 * self.p1 * y + 2.0 * self.p2 * x
        return a, b, d

    def undistort_points(self, xd: np.ndarray, yd: np.ndarray, iterations: int = 30,
                         tolerance: float = 1e-12) -> tuple[np.ndarray, np.ndarray]:
        """Invert the model by Newton's method, starting from the distorted coordinates.

        Converges in a few steps for the mild distortions of real lenses; points where the model
        is not invertible (far outside the calibrated field) keep their last iterate.
        """
        xd = np.asarray(xd, dtype=np.float64)
        yd = np.asarray(yd, dtype=np.float64)
        if self.is_identity:
            return xd.copy(), yd.copy()
        x, y = xd.copy(), yd.copy()
        for _ in range(iterations):
            fx, fy = self.distort_points(x, y)
            ex, ey = fx - xd, fy - yd
            if np.max(np.abs(ex), initial=0.0) < tolerance and \
                    np.max(np.abs(ey), initial=0.0) < tolerance:
                break
            a, b, d = self._jacobian(x, y)
            det = a * d - b * b
            det = np.where(np.abs(det) < 1e-12, 1e-12, det)
            x = x - (d * ex - b * ey) / det
            y = y - (a * ey - b * ex) / det
        return x, y


def bilinear_sample(image: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Sample ``image`` (H, W, C) at continuous pixel coordinates (pixel centres at +0.5).

    Coordinates outside the image are clamped to the edge pixels.
    """
    h, w = image.shape[:2]
    col = np.clip(u - 0.5, 0.0, w - 1.0)
    row = np.clip(v - 0.5, 0.0, h - 1.0)
    c0 = np.minimum(np.floor(col).astype(np.int64), max(w - 2, 0))
    r0 = np.minimum(np.floor(row).astype(np.int64), max(h - 2, 0))
    c1 = np.minimum(c0 + 1, w - 1)
    r1 = np.minimum(r0 + 1, h - 1)
    fc = (col - c0).astype(np.float32)[..., None]
    fr = (row - r0).astype(np.float32)[..., None]
    top = image[r0, c0] * (1.0 - fc) + image[r0, c1] * fc
    bottom = image[r1, c0] * (1.0 - fc) + image[r1, c1] * fc
    return (top * (1.0 - fr) + bottom * fr).astype(image.dtype, copy=False)


@dataclass(eq=False)
class Undistorter:
    """Turns images of one distorted camera into images of the same-size pinhole camera.

    The sampling map is built on first use and, with ``keep_maps`` (the default), cached, so views
    sharing a camera (fox: one camera for 67 images) pay for it once. Loaders turn caching off for
    a camera that only one view uses (beer: 71 cameras), where keeping 71 maps of 7 MB would only
    cost memory.
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    distortion: Distortion
    keep_maps: bool = True
    _maps: tuple[np.ndarray, np.ndarray, np.ndarray] | None = field(default=None, repr=False)

    def _build_maps(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        maps = self._maps
        if maps is None:
            u = (np.arange(self.width, dtype=np.float64) + 0.5 - self.cx) / self.fx
            v = (np.arange(self.height, dtype=np.float64) + 0.5 - self.cy) / self.fy
            x, y = np.meshgrid(u, v)
            xd, yd = self.distortion.distort_points(x, y)
            src_u = xd * self.fx + self.cx
            src_v = yd * self.fy + self.cy
            valid = (src_u >= 0.0) & (src_u <= self.width) & (src_v >= 0.0) & \
                (src_v <= self.height)
            maps = (src_u.astype(np.float32), src_v.astype(np.float32), valid)
            if self.keep_maps:
                self._maps = maps
        return maps

    def undistort(self, image: np.ndarray) -> np.ndarray:
        """The pinhole image (same size) of a captured, distorted image."""
        if image.shape[:2] != (self.height, self.width):
            raise ValueError(f"image is {image.shape[1]}x{image.shape[0]}, the camera is "
                             f"{self.width}x{self.height}")
        src_u, src_v, _ = self._build_maps()
        return bilinear_sample(image, src_u, src_v)

    def valid_mask(self) -> np.ndarray:
        """(H, W) bool: output pixels whose ray lands inside the captured image."""
        return self._build_maps()[2]
