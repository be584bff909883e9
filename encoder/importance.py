"""How much each Gaussian contributes to the image: its blending weight accumulated over views.

A Gaussian's weight in one pixel is ``T * alpha``, the share of that pixel's colour it supplies
(transmittance in front of it times its own opacity there). Summed over the pixels of a set of
views it measures what the Gaussian does for the picture, which is what LightGaussian and
Reduced-3DGS prune by and what a streaming viewer wants first. Opacity times footprint area (the
proxy the no-retrain encoder used before) cannot see occlusion: a large Gaussian hidden behind a
wall scores high there and zero here.

The weight comes out of the renderer's own backward pass: with every colour set to 1, the
derivative of an image channel's sum with respect to a Gaussian's colour is exactly the sum over
pixels of its ``T * alpha``. So the measure follows the renderer's blending rules (alpha clamp,
1/255 skip, early termination) with no second implementation of them.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
import torch

from spcodec.cloud import GaussianCloud

from .cameras import Camera
from .render import GaussianParams, RenderSettings
from .render.binning import bin_gaussians
from .render.composite import BlendConfig, blend
from .render.projection import project


def blend_weights(scene: GaussianCloud | GaussianParams, cameras: Sequence[Camera],
                  settings: RenderSettings | None = None,
                  device: torch.device | str = "cpu") -> np.ndarray:
    """Per-Gaussian sum of ``T * alpha`` over every pixel of ``cameras`` (float64, shape (N,)).

    A Gaussian no camera sees scores 0. The sum is in pixels: divide by the number of pixels of
    all views for the mean share of the image a Gaussian supplies.
    """
    settings = settings or RenderSettings()
    if isinstance(scene, GaussianCloud):
        params = GaussianParams.from_cloud(scene, device)
    else:
        params = scene.detach()
    total = torch.zeros(len(params), dtype=torch.float64, device=params.device)
    if len(params) == 0:
        return total.cpu().numpy()
    config = BlendConfig(settings.max_alpha, settings.chunk_size, settings.batch_elements)
    background = torch.zeros(3, dtype=params.means.dtype, device=params.device)
    with torch.no_grad():
        for camera in cameras:
            proj = project(params, camera, settings)
            if len(proj.ids) == 0:
                continue
            bins = bin_gaussians(proj.pixel_boxes, proj.depths, proj.means2d, proj.conics,
                                 proj.extents, camera.width, camera.height, settings.tile_size)
            ones = torch.ones_like(proj.colors).requires_grad_(True)
            with torch.enable_grad():
                image, _ = blend(proj.means2d, proj.conics, proj.opacities, ones, background,
                                 bins, config, camera.width, camera.height)
                (grad,) = torch.autograd.grad(image[..., 0].sum(), ones)
            total.index_add_(0, proj.ids, grad[:, 0].to(torch.float64))
    return total.cpu().numpy()
