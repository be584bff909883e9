"""Differentiable 3DGS rendering for spcodec: a pure-PyTorch tiled renderer and a gsplat backend.

Public API (the only names other modules should rely on)::

    params = GaussianParams.from_cloud(cloud, device, requires_grad=True)
    result = render(params, camera, RenderSettings(background=(1, 1, 1)), backend="auto")
    result.image (H, W, 3), result.alpha (H, W), result.visible (N,), result.radii (N,)
    result.means2d_grad()                  # (N, 2) d loss / d screen position, after backward
    img = render_image(cloud, camera)      # numpy float32 (H, W, 3) in [0, 1]
    dev = resolve_device("auto")           # cuda when torch sees a GPU, else cpu

Torch is imported here and by what trains with it (the encoder, :mod:`spcodec.imaging.training`),
never by the decoder or the format layer.
"""

from .api import picture, render, render_image, resolve_backend, resolve_device
from .params import GaussianParams
from .settings import RenderResult, RenderSettings

__all__ = [
    "GaussianParams",
    "RenderResult",
    "RenderSettings",
    "picture",
    "render",
    "render_image",
    "resolve_backend",
    "resolve_device",
]
