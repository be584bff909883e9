"""The pure-PyTorch renderer: projection, tile binning and blending on any torch device."""

from __future__ import annotations

from typing import Literal

import torch

from ..cameras import Camera
from .binning import bin_gaussians, choose_tile
from .composite import BlendConfig, blend, blend_autograd
from .params import GaussianParams
from .projection import project
from .settings import RenderResult, RenderSettings, retain_means2d_grad


def render_torch(params: GaussianParams, camera: Camera, settings: RenderSettings,
                 backward: Literal["replay", "autograd"] = "replay") -> RenderResult:
    """Render one view with the torch renderer, differentiable w.r.t. every parameter.

    ``backward="replay"`` (default) uses the memory-light hand-written blend backward;
    ``"autograd"`` lets autograd store the blend's intermediates (tests and measurements only).
    """
    proj = project(params, camera, settings)
    n = len(params)
    if len(proj.ids) == n:  # nothing culled: ids are 0..n-1 in order
        means2d = retain_means2d_grad(proj.means2d)
        drawn = means2d
    else:  # scatter to one row per Gaussian (whose gradient adaptive density control reads)
        means2d = retain_means2d_grad(
            proj.means2d.new_zeros(n, 2).index_copy(0, proj.ids, proj.means2d))
        drawn = means2d[proj.ids]
    gradients = torch.is_grad_enabled() and any(t.requires_grad for t in params.tensors())
    tile = settings.tile_size or choose_tile(proj.pixel_boxes, gradients)
    bins = bin_gaussians(proj.pixel_boxes, proj.depths, proj.means2d.detach(),
                         proj.conics.detach(), proj.extents, camera.width, camera.height, tile)
    background = torch.tensor(settings.background, dtype=params.means.dtype,
                              device=params.device)
    config = BlendConfig(settings.max_alpha, settings.chunk_size, settings.batch_elements)
    blend_fn = blend if backward == "replay" else blend_autograd
    image, alpha = blend_fn(drawn, proj.conics, proj.opacities, proj.colors, background,
                            bins, config, camera.width, camera.height)
    visible = torch.zeros(n, dtype=torch.bool, device=params.device)
    visible[proj.ids] = True
    radii = proj.radii.new_zeros(n).index_copy(0, proj.ids, proj.radii)
    return RenderResult(image=image, alpha=alpha, visible=visible, radii=radii, means2d=means2d)
