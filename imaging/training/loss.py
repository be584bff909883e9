"""The photometric loss of 3DGS training: ``(1 - lambda) L1 + lambda (1 - SSIM)``, lambda = 0.2."""

from __future__ import annotations

import math

import torch

from ..metrics import ssim_torch

DSSIM_WEIGHT = 0.2
"""lambda of the 3DGS loss (INRIA and gsplat default)."""


def photometric_loss(image: torch.Tensor, target: torch.Tensor, mask: torch.Tensor | None = None,
                     dssim_weight: float = DSSIM_WEIGHT) -> torch.Tensor:
    """Loss of an (H, W, 3) render against its target; ``mask`` (H, W) bool limits it to pixels
    with captured data (both images are zeroed outside, so SSIM sees the same border)."""
    if mask is not None:
        keep = mask[..., None].to(image.dtype)
        image, target = image * keep, target * keep
        l1 = (image - target).abs().sum() / (keep.sum() * 3).clamp_min(1.0)
    else:
        l1 = (image - target).abs().mean()
    if dssim_weight == 0:
        return l1
    ssim = ssim_torch(target.permute(2, 0, 1), image.permute(2, 0, 1))
    return (1.0 - dssim_weight) * l1 + dssim_weight * (1.0 - ssim)


def psnr_of(image: torch.Tensor, target: torch.Tensor) -> float:
    """PSNR in dB of a render (clamped to [0, 1]) against its target, for progress reports."""
    mse = float(((image.detach().clamp(0, 1) - target) ** 2).mean())
    return 10.0 * math.log10(1.0 / max(mse, 1e-12))
