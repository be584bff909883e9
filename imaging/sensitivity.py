"""How much each parameter of each Gaussian moves the picture: the renderer linearized.

For a small change ``delta`` of the parameters, the rendered image changes by about ``J delta``,
and its mean squared error is ``delta^T J^T J delta / pixels``. Quantization errors of different
Gaussians and parameters are nearly uncorrelated, so the diagonal of ``J^T J`` predicts it:
``sum(F * delta**2)``. The diagonal comes from squared gradients of random projections of the
image (for r ~ N(0, I), E[(J^T r)^2] = diag(J^T J)), a few backward passes per view.

Measured against renders of hybrids (``bench/bench_distortion_model.py``, docs/LOG.md 17.1):
within a factor of about two for codebook-quantized scales, rotations, opacities and colours, and
an underestimate for position grids, whose error moves the 1/255 cut-off of each Gaussian's
footprint (a step the linearization cannot see).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
import torch

from spcodec.cloud import GaussianCloud

from .cameras import Camera
from .render import GaussianParams, RenderSettings, picture, render

PARTS = ("means", "scales", "quats", "opacities", "sh")
"""The parameters :class:`Sensitivity` holds, in the order :meth:`Sensitivity.mse` sums them."""


@dataclass
class Sensitivity:
    """diag(J^T J) per pixel and channel, for each parameter of each Gaussian (arrays in the
    cloud's own parametrization: means (n, 3), log-scales (n, 3), quaternions (n, 4), opacity
    logits (n,), SH (n, K, 3) with the DC first). Kept in float32, the renderer's precision:
    :meth:`mse` computes in float64, so nothing is lost, and a search over a scene of SH 3 holds
    half of 944 bytes a Gaussian (docs/LOG.md 26.4)."""

    means: np.ndarray
    scales: np.ndarray
    quats: np.ndarray
    opacities: np.ndarray
    sh: np.ndarray

    def mse(self, original: GaussianCloud, changed: GaussianCloud,
            only: str | None = None) -> np.ndarray:
        """Predicted image MSE (n,) each Gaussian's change adds; quaternions are compared as the
        rotation they code (sign and norm aligned with the original's). ``only`` (one of
        :data:`PARTS`) sums that parameter's terms alone, for a change known to touch no other
        (a codebook option of one attribute: the others' terms are exact zeros, or for the
        quaternion, rounding noise the same for every option)."""
        terms = {
            "means": lambda: self.means * _sq(changed.means - original.means),
            "scales": lambda: self.scales * _sq(changed.scales - original.scales),
            "quats": lambda: self.quats * _sq(aligned_quat_delta(changed.quats, original.quats)),
            "opacities": lambda: (self.opacities
                                  * _sq(changed.opacities - original.opacities))[:, None],
            "sh": lambda: (self.sh * _sq(np.concatenate(
                [changed.sh_dc[:, None] - original.sh_dc[:, None],
                 changed.sh_rest - original.sh_rest], axis=1))).reshape(len(original), -1)}
        names = PARTS if only is None else (only,)
        return sum(terms[name]().sum(axis=1) for name in names)

    def subset(self, rows: np.ndarray) -> "Sensitivity":
        return Sensitivity(self.means[rows], self.scales[rows], self.quats[rows],
                           self.opacities[rows], self.sh[rows])


def aligned_quat_delta(changed: np.ndarray, original: np.ndarray) -> np.ndarray:
    """``changed`` as a quaternion of ``original``'s norm and sign, minus ``original``: a decoder
    normalizes quaternions, and q and -q are one rotation."""
    qc, qo = np.asarray(changed, np.float64), np.asarray(original, np.float64)
    norm = np.linalg.norm(qc, axis=1, keepdims=True)
    unit = qc / np.where(norm > 0, norm, 1.0)
    sign = np.where((unit * qo).sum(axis=1, keepdims=True) < 0, -1.0, 1.0)
    return unit * sign * np.linalg.norm(qo, axis=1, keepdims=True) - qo


def _sq(delta: np.ndarray) -> np.ndarray:
    return np.asarray(delta, np.float64) ** 2


def render_sensitivity(cloud: GaussianCloud, cameras: Sequence[Camera],
                       settings: RenderSettings | None = None, samples: int = 1,
                       device: str | torch.device = "cpu", seed: int = 0,
                       pictures: list[np.ndarray] | None = None) -> Sensitivity:
    """:class:`Sensitivity` of ``cloud`` averaged over ``cameras`` (``samples`` random
    projections each, seeded). ``pictures``, when given, receives each camera's picture as
    :func:`~spcodec.imaging.render.render_image` returns it (the same values): the forward
    pass the sensitivity takes anyway."""
    settings = settings or RenderSettings()
    params = GaussianParams.from_cloud(cloud, device, requires_grad=True)
    tensors = params.tensors()
    total = [torch.zeros_like(t) for t in tensors]
    generator = torch.Generator(device=params.device).manual_seed(seed)
    pixels = 0
    for camera in cameras:
        for sample in range(samples):
            image = render(params, camera, settings).image
            if pictures is not None and sample == 0:
                pictures.append(picture(image))
            probe = torch.randn(image.shape, generator=generator, device=image.device)
            grads = torch.autograd.grad((image * probe).sum(), tensors, allow_unused=True)
            for acc, grad in zip(total, grads):
                if grad is not None:
                    acc += grad.detach() ** 2
        pixels += camera.width * camera.height * 3
    scale = 1.0 / max(pixels * samples, 1)
    arrays = [(t * scale).cpu().numpy().astype(np.float32) for t in total]
    return Sensitivity(*arrays)
