"""The gsplat backend (CUDA only): the same view and output conventions as the torch renderer.

gsplat is imported lazily so that spcodec works without it. Written against gsplat 1.5.x's
``gsplat.rasterization``: activated scales and opacities, SH coefficients (N, K, 3) with
``sh_degree``, world-to-camera ``viewmats`` and intrinsics ``Ks`` per camera, ``eps2d`` the 2D
low-pass, ``rasterize_mode`` classic or antialiased. Differences from the torch renderer that
gsplat does not let us configure: its per-fragment alpha clamp is 0.999 (``max_alpha`` is ignored;
set ``max_alpha=GSPLAT_MAX_ALPHA`` for a like-for-like torch render), it stops a pixel when
``T * (1 - alpha) <= 1e-4`` rather than ``< 1e-4``, and it keeps (``visible``) Gaussians whose
integer-rounded box touches the image without covering a pixel centre. ``tile_size``,
``chunk_size`` and ``batch_elements`` only concern the torch renderer.
"""

from __future__ import annotations

import importlib
from functools import lru_cache
from types import ModuleType

import torch

from ..cameras import Camera
from .params import GaussianParams
from .settings import RenderResult, RenderSettings, retain_means2d_grad

GSPLAT_MAX_ALPHA = 0.999
"""The alpha clamp hard-coded in gsplat's CUDA rasterizer."""


@lru_cache(maxsize=1)
def gsplat_problem() -> str | None:
    """Why the gsplat backend cannot run here (one line), or None when it can (cached: neither
    CUDA nor the installed packages change within a process)."""
    if not torch.cuda.is_available():
        return f"torch.cuda.is_available() is False (torch {torch.__version__})"
    try:
        importlib.import_module("gsplat")
    except Exception as exc:  # ImportError, or a broken CUDA extension build
        detail = " ".join(str(exc).split())[:200]
        return f"gsplat does not import ({type(exc).__name__}: {detail}); pip install gsplat"
    return None


def _gsplat() -> ModuleType:
    problem = gsplat_problem()
    if problem is not None:
        raise RuntimeError(f"the gsplat backend is unavailable: {problem}")
    return importlib.import_module("gsplat")


def render_gsplat(params: GaussianParams, camera: Camera, settings: RenderSettings
                  ) -> RenderResult:
    """Render one view with ``gsplat.rasterization`` (params must live on a CUDA device)."""
    gsplat = _gsplat()
    if params.device.type != "cuda":
        raise RuntimeError(f"the gsplat backend needs CUDA tensors, parameters are on "
                           f"{params.device}")
    colors, alphas, meta = gsplat.rasterization(**gsplat_arguments(params, camera, settings))
    return result_from_gsplat(colors, alphas, meta, params.means.dtype)


def gsplat_arguments(params: GaussianParams, camera: Camera, settings: RenderSettings
                     ) -> dict:
    """Keyword arguments of ``gsplat.rasterization`` (1.5.x) for one camera.

    gsplat takes activated scales and opacities, unnormalised wxyz quaternions, SH coefficients
    (N, K, 3) with ``sh_degree`` (it uses the first (d+1)^2), and batched cameras: world-to-camera
    ``viewmats`` (1, 4, 4), intrinsics ``Ks`` (1, 3, 3), ``backgrounds`` (1, 3).
    """
    device, dtype = params.device, torch.float32
    degree = params.sh_degree if settings.sh_degree is None else min(settings.sh_degree,
                                                                      params.sh_degree)
    return dict(
        means=params.means.to(dtype),
        quats=params.quats.to(dtype),
        scales=torch.exp(params.scales.to(dtype)),
        opacities=torch.sigmoid(params.opacities.to(dtype)),
        colors=params.sh[:, :(degree + 1) ** 2].to(dtype),
        viewmats=torch.as_tensor(camera.world_to_camera, dtype=dtype, device=device)[None],
        Ks=torch.as_tensor(camera.intrinsics, dtype=dtype, device=device)[None],
        width=camera.width,
        height=camera.height,
        near_plane=settings.near_plane,
        eps2d=settings.blur_variance,
        sh_degree=degree,
        packed=False,
        backgrounds=torch.tensor([settings.background], dtype=dtype, device=device),
        render_mode="RGB",
        rasterize_mode="antialiased" if settings.antialiased else "classic",
    )


def result_from_gsplat(colors: torch.Tensor, alphas: torch.Tensor, meta: dict,
                       dtype: torch.dtype) -> RenderResult:
    """Our RenderResult from gsplat's (1, H, W, 3) colours, (1, H, W, 1) alphas and metadata.

    ``meta["radii"]`` is (1, N, 2) int in gsplat 1.5 (per-axis), (1, N) before; a Gaussian is
    visible when any radius is positive, and its radius is the larger one. ``meta["means2d"]``
    (1, N, 2) is the screen-position tensor gsplat's rasterizer consumed (unpacked mode), so its
    retained gradient is d loss / d means2d (as gsplat's own densification strategy reads it).
    """
    radii = meta["radii"][0]
    visible = (radii > 0).any(dim=-1) if radii.dim() == 2 else radii > 0
    radius = radii.max(dim=-1).values if radii.dim() == 2 else radii
    return RenderResult(image=colors[0].to(dtype), alpha=alphas[0, :, :, 0].to(dtype),
                        visible=visible, radii=radius.to(dtype),
                        means2d=retain_means2d_grad(meta["means2d"]))
