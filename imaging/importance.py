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

from concurrent.futures import ThreadPoolExecutor
from typing import Sequence

import numpy as np
import torch

from spcodec.cloud import GaussianCloud

from .cameras import Camera
from .render import GaussianParams, RenderSettings
from .render.binning import TRAINING_TILE, bin_gaussians
from .render.composite import BlendConfig, blend
from .render.projection import project
from .views import DEFAULT_UP, sample_views


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
                                 proj.extents, camera.width, camera.height,
                                 settings.tile_size or TRAINING_TILE)
            ones = torch.ones_like(proj.colors).requires_grad_(True)
            with torch.enable_grad():
                image, _ = blend(proj.means2d, proj.conics, proj.opacities, ones, background,
                                 bins, config, camera.width, camera.height)
                (grad,) = torch.autograd.grad(image[..., 0].sum(), ones)
            total.index_add_(0, proj.ids, grad[:, 0].to(torch.float64))
    return total.cpu().numpy()


def training_view_weights(cloud: GaussianCloud, views: int, resolution: tuple[int, int],
                          seed: int = 0, up: Sequence[float] | str = DEFAULT_UP,
                          jobs: int = 1) -> np.ndarray:
    """:func:`blend_weights` over ``views`` cameras of ``resolution`` (width, height) sampled
    around ``cloud`` from the *training* split, which never shares a position with ``eval``'s
    views, so an encoder that orders or weights by this measure is not tuned to its judge.

    Colours do not enter the measure, so it renders SH degree 0. A sampled view that fails its
    coverage check still counts (it sees less of the scene, which only weakens the measure): its
    warning is not shown to an encoder's user. The views are shared among ``jobs`` threads of one
    torch thread each (weights add over views): at these small resolutions the renderer's steps
    are too short to share, and on the 2-core machine torch's own two threads made it 3-4x slower
    in wall time whenever another process was busy (fourth_st, 8 views of 256x192: 4.8 s on one
    thread, 15-20 s on two).
    """
    cameras = sample_views(cloud, views, resolution, split="train", seed=seed, up=up, warn=False)
    params = GaussianParams.from_cloud(cloud)
    settings = RenderSettings(sh_degree=0, tile_size=2)  # 2 beats 4 by 15-20 % at these sizes
    parts = [cameras[k::jobs] for k in range(max(1, min(jobs, len(cameras))))]
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        if len(parts) == 1:
            return blend_weights(params, cameras, settings)
        with ThreadPoolExecutor(len(parts)) as pool:
            weights = list(pool.map(lambda part: blend_weights(params, part, settings), parts))
    finally:
        torch.set_num_threads(threads)
    return np.sum(weights, axis=0)  # in a fixed order: the same sum for any thread timing
