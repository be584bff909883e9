"""Render options and results shared by both backends (the torch CPU renderer and gsplat)."""

from __future__ import annotations

from dataclasses import dataclass

import torch

NEAR_PLANE = 0.01
"""Default near plane in world units along camera z: gsplat's default, small enough for scenes
measured in metres or in the ~0.2-unit scenes of our test data, large enough to keep x/z finite."""

MAX_ALPHA = 0.99
"""Per-fragment opacity clamp of the INRIA kernel (gsplat's CUDA kernel hard-codes 0.999)."""

ALPHA_THRESHOLD = 1.0 / 255.0
"""Fragments below this opacity are skipped (both references)."""

TRANSMITTANCE_THRESHOLD = 1e-4
"""A pixel stops at the first fragment that would drive its transmittance below this value."""

BLUR_VARIANCE = 0.3
"""Screen-space low-pass: pixels^2 added to both diagonal entries of every 2D covariance."""


@dataclass(frozen=True)
class RenderSettings:
    """How to render; the defaults reproduce the INRIA/gsplat "classic" image.

    ``tile_size``, ``chunk_size`` and ``batch_elements`` only trade speed for memory in the torch
    renderer: the image does not depend on them (beyond float rounding). ``max_alpha`` exists so
    the torch renderer can be compared with gsplat (0.999) like for like; keep 0.99 otherwise.
    """

    background: tuple[float, float, float] = (0.0, 0.0, 0.0)
    antialiased: bool = False
    """Mip-Splatting / gsplat ``rasterize_mode="antialiased"`` opacity compensation."""
    blur_variance: float = BLUR_VARIANCE
    """The screen-space low-pass in px^2 (INRIA and gsplat: 0.3). Viewers differ: PlayCanvas adds
    0.3 in half-pixel units, i.e. 0.075 px^2 (docs/LOG.md, section 13); this lets the
    renderers be compared like for like."""
    near_plane: float = NEAR_PLANE
    sh_degree: int | None = None
    """Render with at most this SH degree (None: the scene's own degree)."""
    max_alpha: float = MAX_ALPHA
    tile_size: int | None = None
    """Square screen tiles (pixels per side) used to bin Gaussians in the torch renderer; None
    picks per pass and view (:func:`.binning.choose_tile`). Small tiles waste fewer (pixel,
    Gaussian) evaluations on the CPU, where there is no warp to fill; large ones make fewer
    (tile, Gaussian) pairs to list and sort, which matters where footprints are large."""
    chunk_size: int = 32
    """Gaussians per tile blended in one vectorized step (transmittance carries across steps)."""
    batch_elements: int = 1 << 22
    """Upper bound on tiles x chunk x pixels per step: bounds the renderer's working memory."""

    def __post_init__(self) -> None:
        if len(self.background) != 3:
            raise ValueError("background must have 3 components")
        if (self.tile_size is not None and self.tile_size < 1) or self.chunk_size < 1 \
                or self.batch_elements < 1:
            raise ValueError("tile_size, chunk_size and batch_elements must be positive")
        if not 0.0 < self.max_alpha < 1.0:
            raise ValueError("max_alpha must lie in (0, 1)")
        if self.near_plane <= 0.0:
            raise ValueError("near_plane must be positive")
        if self.sh_degree is not None and not 0 <= self.sh_degree <= 3:
            raise ValueError("sh_degree must be None or 0..3")
        if not self.blur_variance >= 0:
            raise ValueError("blur_variance must be >= 0")


@dataclass
class RenderResult:
    """A rendered view. Tensors live on the device of the parameters.

    ``image`` (H, W, 3) linear colour, not clamped (values slightly above 1 are possible);
    ``alpha`` (H, W) accumulated opacity ``1 - final transmittance``;
    ``visible`` (N,) bool, the Gaussians that survived culling (in front of the near plane, with
    a screen footprint that reaches a pixel centre), e.g. to restrict optimizer updates;
    ``radii`` (N,) screen radius in pixels of each Gaussian's footprint (the larger half-side of
    the box its rasterizer draws it in), 0 where culled;
    ``means2d`` the screen positions in pixels the rasterizer consumed: (N, 2) from the torch
    renderer (rows of culled Gaussians are 0), gsplat's own (1, N, 2) tensor from gsplat. When
    the parameters require gradients it retains its gradient, so after ``backward()``
    :meth:`means2d_grad` gives d loss / d means2d, what adaptive density control accumulates.
    """

    image: torch.Tensor
    alpha: torch.Tensor
    visible: torch.Tensor
    radii: torch.Tensor
    means2d: torch.Tensor

    def means2d_grad(self) -> torch.Tensor | None:
        """(N, 2) gradient of the loss w.r.t. the screen positions in pixels (0 for culled
        Gaussians), or None before ``backward()`` or when nothing required gradients."""
        grad = self.means2d.grad
        return None if grad is None else grad.reshape(-1, 2)


def retain_means2d_grad(means2d: torch.Tensor) -> torch.Tensor:
    """Keep the gradient of a non-leaf screen-position tensor (no-op when it has none)."""
    if means2d.requires_grad:
        means2d.retain_grad()
    return means2d
