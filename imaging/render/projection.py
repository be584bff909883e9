"""Per-Gaussian work of the torch renderer: culling, EWA projection to screen space and colour.

Everything here is vectorized over Gaussians and differentiable by ordinary autograd; it costs
O(N) and is small next to the per-pixel blending (see ``composite.py``).

Conventions (INRIA 3DGS / gsplat 1.5, checked against their sources):

* covariance ``R S S^T R^T`` with ``S = diag(exp(scales))`` and ``R`` from the normalised wxyz
  quaternion, rotated into the camera and projected with the perspective Jacobian at the mean;
  ``x/z`` and ``y/z`` are clamped to the image's half-extent plus 30 % of the half-FOV tangent
  (gsplat's form, equal to INRIA's ``1.3 * tan(fov/2)`` for a centred principal point), and the
  clamp also stops the gradient as in both references;
* ``settings.blur_variance`` px^2 (default 0.3) added to the 2D covariance; in antialiased mode
  the opacity is multiplied by ``sqrt(det(cov) / det(cov + blur I))`` (Mip-Splatting);
* a Gaussian reaches the pixels whose centres lie in the box that bounds its ellipse
  ``opacity * exp(-q / 2) >= 1/255`` (gsplat 1.5's opacity-aware extent). Outside that box no pixel
  passes the 1/255 test, so the box only culls and never changes a pixel: the image equals the
  per-pixel definition exactly and does not depend on the tile size. (INRIA's ``3 sigma`` box of
  the larger eigenvalue, applied per 16-pixel tile, drops some fragments above 1/255 and makes
  the image depend on the tiling.)
* culled: camera depth ``z <= near_plane``, degenerate 2D covariance, opacity below 1/255, or a
  box that contains no pixel centre of the image.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from ..cameras import Camera
from .params import GaussianParams
from .settings import ALPHA_THRESHOLD, RenderSettings
from .sh import sh_to_rgb

_BOX_MARGIN = 0.01
"""Pixels added around each footprint box so float rounding can only add candidate pixels (which
the per-pixel 1/255 test then rejects), never drop one."""


@dataclass(frozen=True)
class CameraTensors:
    """A Camera's pose as tensors on the renderer's device and dtype, intrinsics as floats."""

    rotation: torch.Tensor  # (3, 3) world-to-camera
    translation: torch.Tensor  # (3,)
    position: torch.Tensor  # (3,) camera centre in world coordinates
    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int

    @classmethod
    def from_camera(cls, camera: Camera, device: torch.device,
                    dtype: torch.dtype) -> "CameraTensors":
        def t(a):
            return torch.as_tensor(a, dtype=dtype, device=device)

        return cls(t(camera.rotation), t(camera.translation), t(camera.position),
                   float(camera.fx), float(camera.fy), float(camera.cx), float(camera.cy),
                   int(camera.width), int(camera.height))


@dataclass
class Projection:
    """The visible Gaussians in screen space, ready for binning and blending.

    ``ids`` (M,) index the input Gaussians; ``means2d`` (M, 2) in pixels; ``conics`` (M, 3) the
    entries (a, b, c) of the inverse blurred 2D covariance [[a, b], [b, c]]; ``opacities`` (M,)
    after sigmoid (and compensation); ``colors`` (M, 3); ``depths`` (M,) camera z (detached);
    ``pixel_boxes`` (M, 4) int64 inclusive pixel ranges (col0, col1, row0, row1) clipped to the
    image, each non-empty; ``extents`` (M,) the Mahalanobis radius of the 1/255 contour
    (detached); ``radii`` (M,) the larger half-side in pixels of the box around that contour
    (detached; the screen size adaptive density control prunes by).
    """

    ids: torch.Tensor
    means2d: torch.Tensor
    conics: torch.Tensor
    opacities: torch.Tensor
    colors: torch.Tensor
    depths: torch.Tensor
    pixel_boxes: torch.Tensor
    extents: torch.Tensor
    radii: torch.Tensor


def rotation_entries(quats: torch.Tensor) -> list[list[torch.Tensor]]:
    """Rotation matrices of wxyz quaternions (N, 4), normalised first, as 3x3 nested lists of
    (N,) tensors: per-entry vectors keep every op contiguous, which on the CPU is several times
    faster (forward and backward) than (N, 3, 3) tensors with broadcasting."""
    q = quats / quats.norm(dim=1, keepdim=True)
    w, x, y, z = q.unbind(1)
    return [
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ]


def footprint_extent(opacities: torch.Tensor) -> torch.Tensor:
    """Mahalanobis radius k where ``opacity * exp(-k^2 / 2) = 1/255`` (0 when opacity < 1/255)."""
    ratio = (opacities / ALPHA_THRESHOLD).clamp_min(1.0)
    return torch.sqrt(2.0 * torch.log(ratio))


def pixel_range(center: torch.Tensor, radius: torch.Tensor, size: int
                ) -> tuple[torch.Tensor, torch.Tensor]:
    """Inclusive first/last pixel index whose centre (i + 0.5) lies within ``center +- radius``.

    The range is empty (first > last) when no pixel centre of ``[0, size)`` is covered.
    """
    lo = (center - radius - 0.5 - _BOX_MARGIN).clamp(-1.0, float(size))
    hi = (center + radius - 0.5 + _BOX_MARGIN).clamp(-1.0, float(size))
    first = torch.ceil(lo).long().clamp_min(0)
    last = torch.floor(hi).long().clamp_max(size - 1)
    return first, last


def project(params: GaussianParams, camera: Camera, settings: RenderSettings) -> Projection:
    """Cull, project and colour the Gaussians for one camera (differentiable w.r.t. params)."""
    cam = CameraTensors.from_camera(camera, params.device, params.means.dtype)
    means_cam = params.means @ cam.rotation.T + cam.translation
    in_front = torch.nonzero(means_cam[:, 2].detach() > settings.near_plane).squeeze(1)

    front = ((lambda t: t) if len(in_front) == len(params)  # noqa: E731
             else (lambda t: t[in_front]))
    mean2d, cov2d_raw = _ewa_project(front(means_cam), front(params.quats),
                                     front(params.scales), cam)
    a_raw, b, c_raw = cov2d_raw.unbind(1)
    a, c = a_raw + settings.blur_variance, c_raw + settings.blur_variance
    det = a * c - b * b
    opacity = torch.sigmoid(front(params.opacities))
    if settings.antialiased:
        det_raw = a_raw * c_raw - b * b
        opacity = opacity * torch.sqrt((det_raw / det).clamp_min(1e-30))

    with torch.no_grad():
        extent = footprint_extent(opacity)
        ok = torch.isfinite(det) & (det > 0) & (opacity >= ALPHA_THRESHOLD)
        ok &= torch.isfinite(mean2d).all(dim=1)
        safe_a = torch.where(ok, a, torch.ones_like(a))
        safe_c = torch.where(ok, c, torch.ones_like(c))
        half_x, half_y = extent * torch.sqrt(safe_a), extent * torch.sqrt(safe_c)
        col0, col1 = pixel_range(mean2d[:, 0], half_x, cam.width)
        row0, row1 = pixel_range(mean2d[:, 1], half_y, cam.height)
        ok &= (col0 <= col1) & (row0 <= row1)
        keep = torch.nonzero(ok).squeeze(1)
        boxes = torch.stack([col0, col1, row0, row1], dim=1)[keep]
        radii = torch.maximum(half_x, half_y)[keep]

    # whole scene in view (the common case): skip the gathers and their backward scatters
    pick = (lambda t: t) if len(keep) == len(in_front) else (lambda t: t[keep])  # noqa: E731
    ids = in_front[keep]
    everything = len(ids) == len(params)
    a, b, c, det = pick(a), pick(b), pick(c), pick(det)
    conics = torch.stack([c / det, -b / det, a / det], dim=1)
    degree = params.sh_degree if settings.sh_degree is None else min(settings.sh_degree,
                                                                      params.sh_degree)
    means = params.means if everything else params.means[ids]
    sh = params.sh if everything else params.sh[ids]
    dirs = means - cam.position
    dirs = dirs / dirs.norm(dim=1, keepdim=True)
    colors = sh_to_rgb(sh, dirs, degree)
    return Projection(
        ids=ids,
        means2d=pick(mean2d),
        conics=conics,
        opacities=pick(opacity),
        colors=colors,
        depths=means_cam[ids, 2].detach(),
        pixel_boxes=boxes,
        extents=pick(extent),
        radii=radii,
    )


def _ewa_project(means_cam: torch.Tensor, quats: torch.Tensor, scales: torch.Tensor,
                 cam: CameraTensors) -> tuple[torch.Tensor, torch.Tensor]:
    """Screen means (M, 2) and un-blurred 2D covariances (M, 3) as (xx, xy, yy).

    ``cov2d = B B^T`` with ``B = J W R S`` (Jacobian, world-to-camera rotation, Gaussian rotation,
    scales), which never forms the 3x3 covariance. Written entry by entry on (M,) vectors with
    the camera's numbers as Python floats (see ``rotation_entries``).
    """
    x, y, z = means_cam.unbind(1)
    inv_z = 1.0 / z
    tan_x, tan_y = 0.5 * cam.width / cam.fx, 0.5 * cam.height / cam.fy
    lim_x_pos = (cam.width - cam.cx) / cam.fx + 0.3 * tan_x
    lim_x_neg = cam.cx / cam.fx + 0.3 * tan_x
    lim_y_pos = (cam.height - cam.cy) / cam.fy + 0.3 * tan_y
    lim_y_neg = cam.cy / cam.fy + 0.3 * tan_y
    tx = torch.clamp(x * inv_z, -lim_x_neg, lim_x_pos)
    ty = torch.clamp(y * inv_z, -lim_y_neg, lim_y_pos)

    # rows of J W: J = [[fx/z, 0, -fx tx/z], [0, fy/z, -fy ty/z]] (tx, ty already divided by z)
    w = cam.rotation.tolist()
    fx_z, fy_z = cam.fx * inv_z, cam.fy * inv_z
    jw0 = [fx_z * (w[0][k] - tx * w[2][k]) for k in range(3)]
    jw1 = [fy_z * (w[1][k] - ty * w[2][k]) for k in range(3)]
    rot = rotation_entries(quats)
    s = torch.exp(scales).unbind(1)
    cov_xx = cov_xy = cov_yy = None
    for j in range(3):  # column j of R S
        m = [rot[k][j] * s[j] for k in range(3)]
        b0 = jw0[0] * m[0] + jw0[1] * m[1] + jw0[2] * m[2]
        b1 = jw1[0] * m[0] + jw1[1] * m[1] + jw1[2] * m[2]
        terms = (b0 * b0, b0 * b1, b1 * b1)
        if cov_xx is None:
            cov_xx, cov_xy, cov_yy = terms
        else:
            cov_xx, cov_xy, cov_yy = cov_xx + terms[0], cov_xy + terms[1], cov_yy + terms[2]
    cov = torch.stack([cov_xx, cov_xy, cov_yy], dim=1)
    mean2d = torch.stack([cam.fx * x * inv_z + cam.cx, cam.fy * y * inv_z + cam.cy], dim=1)
    return mean2d, cov
