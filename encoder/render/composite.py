"""Front-to-back alpha blending of binned Gaussians, vectorized over tiles, Gaussians and pixels.

Work layout. Non-empty tiles are sorted by list length (longest first) and processed in batches
of similar tiles. Within a batch, depth chunks of ``chunk`` Gaussians are blended per step as
dense ``(tiles, chunk, pixels)`` tensors; the transmittance of every pixel is carried from one
chunk to the next, and tiles whose pixels have all terminated (or whose lists are exhausted) drop
out of later steps. ``batch_elements`` caps ``tiles x chunk x pixels`` per step, which bounds the
working memory whatever the image size or scene.

Blending rule per pixel (INRIA forward kernel): for fragments in depth order,
``alpha = min(max_alpha, o * exp(-q/2))``; skip it when ``alpha < 1/255``; if
``T * (1 - alpha) < 1e-4`` the pixel stops and this fragment is not added; else add
``T * alpha * colour`` and set ``T *= 1 - alpha``. Because ``T`` only decreases, "stopped" equals
"the running product including this fragment is below 1e-4", which a cumulative product gives
for a whole chunk at once. The running product (``t_run``) keeps multiplying after a stop, so a
pixel that stopped stays stopped in later chunks.

Gradients. ``BlendFunction`` stores no per-fragment tensor: backward replays the same steps
(identical inputs, identical arithmetic, so identical termination) and applies the closed-form
derivative of the blend, going front to back with a running prefix sum:

    dL/dalpha_k = T_k (c_k . g) - (S_k - gA T_N) / (1 - alpha_k),
    S_k = (C_out . g) - sum_{j<=k} T_j alpha_j (c_j . g),

with ``g`` the image gradient, ``gA`` the alpha gradient and ``T_N`` the final transmittance.
Storing autograd's intermediates would take ~10 floats per (pixel, fragment) pair (gigabytes on
real scenes); the replay costs about one more forward. ``blend_autograd`` is the same computation
left to autograd, kept as the oracle the tests compare the hand-written backward against.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterator

import torch

from .binning import TileBins
from .settings import ALPHA_THRESHOLD, TRANSMITTANCE_THRESHOLD

# columns of the packed per-Gaussian table: mean x, y; quadratic-form coefficients of the
# exponent (A, B, C with power = A dx^2 + B dx dy + C dy^2); opacity; colour r, g, b
_MX, _MY, _QA, _QB, _QC, _OP, _RGB = 0, 1, 2, 3, 4, 5, 6
_PACKED_COLUMNS = 9


@dataclass(frozen=True)
class BlendConfig:
    """Blending parameters: the alpha clamp, and the step shape (speed/memory only)."""

    max_alpha: float
    chunk: int
    batch_elements: int


@dataclass
class _Batch:
    """A batch of tiles: their ids, pixel centres (n, P) and the chunk length of its steps."""

    tiles: torch.Tensor
    px: torch.Tensor
    py: torch.Tensor
    chunk: int


@dataclass
class _Fragments:
    """One step's per-(tile, Gaussian, pixel) quantities."""

    gid: torch.Tensor  # (n, C) packed-table rows (dummy row M for empty slots)
    g: torch.Tensor  # (n, C, 9) gathered packed rows
    dx: torch.Tensor  # (n, C, P)
    dy: torch.Tensor
    alpha_raw: torch.Tensor  # o * exp(power), before clamp and skip
    alpha: torch.Tensor  # clamped, 0 where skipped
    t_excl: torch.Tensor  # transmittance before each fragment
    t_incl: torch.Tensor  # running product including each fragment
    weight: torch.Tensor  # T * alpha, 0 after the pixel stopped


def pack_gaussians(means2d: torch.Tensor, conics: torch.Tensor, opacities: torch.Tensor,
                   colors: torch.Tensor) -> torch.Tensor:
    """One (M + 1, 9) table so a step gathers all it needs with one index; row M is a dummy with
    zero opacity that fills the empty slots of short tile lists."""
    quad = torch.stack([-0.5 * conics[:, 0], -conics[:, 1], -0.5 * conics[:, 2]], dim=1)
    table = torch.cat([means2d, quad, opacities[:, None], colors], dim=1)
    return torch.cat([table, table.new_zeros(1, _PACKED_COLUMNS)], dim=0)


def _batches(bins: TileBins, pixels: int, config: BlendConfig,
             device: torch.device, dtype: torch.dtype) -> Iterator[_Batch]:
    """Non-empty tiles, longest lists first, grouped so one step stays under batch_elements."""
    counts = bins.counts
    order = torch.argsort(counts, descending=True, stable=True)
    nonempty = int((counts > 0).sum())
    order = order[:nonempty]
    counts_sorted = counts[order].tolist()
    side = bins.tile
    local = torch.arange(pixels, device=device)
    lx, ly = (local % side).to(dtype) + 0.5, (local // side).to(dtype) + 0.5
    start = 0
    while start < nonempty:
        chunk = max(1, min(config.chunk, counts_sorted[start]))
        size = max(1, config.batch_elements // (chunk * pixels))
        tiles = order[start:start + size]
        ox, oy = bins.tile_origins(tiles)
        yield _Batch(tiles, ox.to(dtype)[:, None] + lx, oy.to(dtype)[:, None] + ly, chunk)
        start += size


def _gather(packed: torch.Tensor, bins: TileBins, tiles: torch.Tensor, first: int,
            chunk: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Rows of the packed table for list positions ``first .. first+chunk-1`` of each tile."""
    slots = first + torch.arange(chunk, device=tiles.device)
    filled = slots[None, :] < bins.counts[tiles][:, None]
    index = (bins.starts[tiles][:, None] + slots[None, :]).clamp_max(len(bins.gaussians) - 1)
    dummy = packed.shape[0] - 1
    gid = torch.where(filled, bins.gaussians[index], torch.full_like(index, dummy))
    return gid, packed[gid]


def _fragments(packed: torch.Tensor, bins: TileBins, batch: _Batch, rows: torch.Tensor,
               first: int, t_run: torch.Tensor, config: BlendConfig) -> _Fragments:
    """Alpha, transmittance and blend weight of one depth chunk for the tiles ``rows`` of a batch.

    Written with out-of-place ops only so that autograd can differentiate it (``blend_autograd``).
    """
    gid, g = _gather(packed, bins, batch.tiles[rows], first, batch.chunk)
    px, py = batch.px[rows][:, None, :], batch.py[rows][:, None, :]
    dx = px - g[:, :, _MX, None]
    dy = py - g[:, :, _MY, None]
    qa, qb, qc = g[:, :, _QA, None], g[:, :, _QB, None], g[:, :, _QC, None]
    power = dx * (qa * dx + qb * dy) + qc * (dy * dy)
    alpha_raw = torch.exp(power) * g[:, :, _OP, None]
    alpha = torch.where(alpha_raw >= ALPHA_THRESHOLD, alpha_raw.clamp_max(config.max_alpha),
                        torch.zeros((), dtype=alpha_raw.dtype, device=alpha_raw.device))
    t_prev = t_run[:, None, :]
    t_incl = torch.cumprod(1.0 - alpha, dim=1) * t_prev
    t_excl = torch.cat([t_prev, t_incl[:, :-1]], dim=1)
    weight = t_excl * alpha
    if bool((t_incl[:, -1] < TRANSMITTANCE_THRESHOLD).any()):
        weight = torch.where(t_incl >= TRANSMITTANCE_THRESHOLD, weight,
                             torch.zeros((), dtype=weight.dtype, device=weight.device))
    return _Fragments(gid, g, dx, dy, alpha_raw, alpha, t_excl, t_incl, weight)


def _steps(packed: torch.Tensor, bins: TileBins, batch: _Batch, config: BlendConfig
           ) -> Iterator[tuple[torch.Tensor, _Fragments]]:
    """The steps over one batch, as (rows of the batch, fragments); deterministic, so backward
    can replay exactly the forward's steps. The running transmittance is advanced here (keeping
    its autograd history for ``blend_autograd``); callers must not modify yielded tensors.
    """
    n = len(batch.tiles)
    t_run = batch.px.new_ones(n, batch.px.shape[1])
    rows = torch.arange(n, device=batch.tiles.device)
    counts = bins.counts[batch.tiles]
    first = 0
    while len(rows):
        frag = _fragments(packed, bins, batch, rows, first, t_run[rows], config)
        yield rows, frag
        t_last = frag.t_incl[:, -1]
        t_run = t_run.index_copy(0, rows, t_last)
        first += batch.chunk
        more = (counts[rows] > first) & (t_last.detach() >= TRANSMITTANCE_THRESHOLD).any(dim=1)
        rows = rows[more]


def _to_image(tiles: torch.Tensor, bins: TileBins, width: int, height: int) -> torch.Tensor:
    """(num_tiles, P, ...) per-tile values to an (H, W, ...) image."""
    t = bins.tile
    extra = tiles.shape[2:]
    grid = tiles.reshape(bins.tiles_y, bins.tiles_x, t, t, *extra).transpose(1, 2)
    return grid.reshape(bins.tiles_y * t, bins.tiles_x * t, *extra)[:height, :width]


def _from_image(image: torch.Tensor, bins: TileBins) -> torch.Tensor:
    """Inverse of ``_to_image`` (zero outside the image): (H, W, ...) to (num_tiles, P, ...)."""
    t = bins.tile
    h, w = image.shape[:2]
    extra = image.shape[2:]
    full = image.new_zeros(bins.tiles_y * t, bins.tiles_x * t, *extra)
    full[:h, :w] = image
    grid = full.reshape(bins.tiles_y, t, bins.tiles_x, t, *extra).transpose(1, 2)
    return grid.reshape(bins.num_tiles, t * t, *extra)


def _blend_forward(packed: torch.Tensor, bins: TileBins, config: BlendConfig
                   ) -> torch.Tensor:
    """Per-tile accumulated (r, g, b, alpha) before the background, (num_tiles, P, 4)."""
    pixels = bins.tile * bins.tile
    acc = packed.new_zeros(bins.num_tiles, pixels, 4)
    ones = packed.new_ones(1, 1, 1)
    for batch in _batches(bins, pixels, config, packed.device, packed.dtype):
        batch_acc = packed.new_zeros(len(batch.tiles), pixels, 4)
        for rows, frag in _steps(packed, bins, batch, config):
            rgba = torch.cat([frag.g[:, :, _RGB:], ones.expand(*frag.g.shape[:2], 1)], dim=2)
            batch_acc.index_add_(0, rows, torch.bmm(frag.weight.transpose(1, 2), rgba))
        acc[batch.tiles] = batch_acc
    return acc


def _finish(acc: torch.Tensor, background: torch.Tensor, bins: TileBins, width: int,
            height: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Image (H, W, 3) with the background behind the remaining transmittance, and alpha."""
    alpha = acc[:, :, 3]
    color = acc[:, :, :3] + (1.0 - alpha)[:, :, None] * background
    return _to_image(color, bins, width, height), _to_image(alpha, bins, width, height)


class BlendFunction(torch.autograd.Function):
    """Blend with a replaying backward (see the module docstring)."""

    @staticmethod
    def forward(ctx, means2d: torch.Tensor, conics: torch.Tensor, opacities: torch.Tensor,
                colors: torch.Tensor, background: torch.Tensor, bins: TileBins,
                config: BlendConfig, width: int, height: int):
        packed = pack_gaussians(means2d, conics, opacities, colors)
        acc = _blend_forward(packed, bins, config)
        image, alpha = _finish(acc, background, bins, width, height)
        ctx.save_for_backward(packed, image, alpha, background)
        ctx.bins, ctx.config = bins, config
        return image, alpha

    @staticmethod
    def backward(ctx, grad_image: torch.Tensor, grad_alpha: torch.Tensor):
        packed, image, alpha, background = ctx.saved_tensors
        grad_packed = _blend_backward(packed, ctx.bins, ctx.config, image, alpha,
                                      grad_image, grad_alpha)[:-1]
        d_mean = grad_packed[:, _MX:_MY + 1]
        # the table holds (A, B, C) = (-a/2, -b, -c/2) of the conic (a, b, c)
        d_conic = grad_packed[:, _QA:_QC + 1] * grad_packed.new_tensor([-0.5, -1.0, -0.5])
        d_opacity = grad_packed[:, _OP]
        d_color = grad_packed[:, _RGB:]
        return d_mean, d_conic, d_opacity, d_color, None, None, None, None, None


def _blend_backward(packed: torch.Tensor, bins: TileBins, config: BlendConfig,
                    image: torch.Tensor, alpha: torch.Tensor, grad_image: torch.Tensor,
                    grad_alpha: torch.Tensor) -> torch.Tensor:
    """Gradient w.r.t. the packed table (M + 1, 9) by replaying the forward steps."""
    pixels = bins.tile * bins.tile
    out_tiles = _from_image(image, bins)
    t_final_tiles = 1.0 - _from_image(alpha, bins)
    g_tiles = _from_image(grad_image.contiguous(), bins)
    ga_tiles = _from_image(grad_alpha.contiguous(), bins)
    # (S_k - gA T_N) = rest - prefix_k with rest = C_out . g - gA T_N per pixel
    rest_tiles = (out_tiles * g_tiles).sum(-1) - ga_tiles * t_final_tiles
    grad = torch.zeros_like(packed)
    for batch in _batches(bins, pixels, config, packed.device, packed.dtype):
        g_batch, rest = g_tiles[batch.tiles], rest_tiles[batch.tiles]
        half = bins.tile / 2.0
        ox, oy = bins.tile_origins(batch.tiles)
        cx_tile, cy_tile = ox.to(packed.dtype) + half, oy.to(packed.dtype) + half
        lx, ly = batch.px - cx_tile[:, None], batch.py - cy_tile[:, None]
        features = torch.stack([torch.ones_like(lx), lx, ly, lx * lx, lx * ly, ly * ly], dim=2)
        prefix = packed.new_zeros(len(batch.tiles), pixels)
        for rows, frag in _steps(packed, bins, batch, config):
            g_rows = g_batch[rows]
            grad_pair = _pair_gradients(frag, g_rows, rest[rows], prefix, rows, features[rows],
                                        cx_tile[rows], cy_tile[rows], config)
            grad.index_add_(0, frag.gid.reshape(-1), grad_pair.reshape(-1, _PACKED_COLUMNS))
    return grad


def _pair_gradients(frag: _Fragments, g_pix: torch.Tensor, rest: torch.Tensor,
                    prefix: torch.Tensor, rows: torch.Tensor, features: torch.Tensor,
                    cx_tile: torch.Tensor, cy_tile: torch.Tensor, config: BlendConfig
                    ) -> torch.Tensor:
    """Gradient of one step w.r.t. each gathered (tile, Gaussian) row, (n, C, 9).

    Advances ``prefix`` (the running sum of T alpha (c . g) per pixel) in place.
    """
    rgb = frag.g[:, :, _RGB:]
    cg = torch.bmm(rgb, g_pix.transpose(1, 2))  # (n, C, P): c . g
    running = torch.cumsum(frag.weight * cg, dim=1) + prefix[rows][:, None, :]
    prefix.index_copy_(0, rows, running[:, -1])
    d_alpha = frag.t_excl * cg - (rest[:, None, :] - running) / (1.0 - frag.alpha)
    passes = ((frag.alpha_raw >= ALPHA_THRESHOLD) & (frag.alpha_raw <= config.max_alpha)
              & (frag.t_incl >= TRANSMITTANCE_THRESHOLD))
    # d power = dL/d alpha_raw * alpha_raw, since alpha_raw = o exp(power)
    d_power = torch.where(passes, d_alpha * frag.alpha_raw, torch.zeros_like(d_alpha))
    m = torch.bmm(d_power, features)  # (n, C, 6) moments in tile-local coordinates
    m0, mx, my, mxx, mxy, myy = m.unbind(2)
    u = frag.g[:, :, _MX] - cx_tile[:, None]
    v = frag.g[:, :, _MY] - cy_tile[:, None]
    s_x = mx - u * m0  # sum d_power * dx, dx = pixel - mean
    s_y = my - v * m0
    s_xx = mxx - 2.0 * u * mx + u * u * m0
    s_xy = mxy - u * my - v * mx + u * v * m0
    s_yy = myy - 2.0 * v * my + v * v * m0
    qa, qb, qc = frag.g[:, :, _QA], frag.g[:, :, _QB], frag.g[:, :, _QC]
    opacity = frag.g[:, :, _OP]
    d_opacity = torch.where(opacity > 0, m0 / torch.where(opacity > 0, opacity, 1.0),
                            torch.zeros_like(m0))
    d_rgb = torch.bmm(frag.weight, g_pix)  # (n, C, 3)
    return torch.cat([
        torch.stack([-(2.0 * qa * s_x + qb * s_y), -(qb * s_x + 2.0 * qc * s_y),
                     s_xx, s_xy, s_yy, d_opacity], dim=2),
        d_rgb,
    ], dim=2)


def blend(means2d: torch.Tensor, conics: torch.Tensor, opacities: torch.Tensor,
          colors: torch.Tensor, background: torch.Tensor, bins: TileBins, config: BlendConfig,
          width: int, height: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Blend projected Gaussians into an (H, W, 3) image and (H, W) alpha (replaying backward)."""
    return BlendFunction.apply(means2d, conics, opacities, colors, background, bins, config,
                               width, height)


def blend_autograd(means2d: torch.Tensor, conics: torch.Tensor, opacities: torch.Tensor,
                   colors: torch.Tensor, background: torch.Tensor, bins: TileBins,
                   config: BlendConfig, width: int, height: int
                   ) -> tuple[torch.Tensor, torch.Tensor]:
    """The same blend differentiated by autograd (stores every intermediate; for testing and
    for measuring what the replaying backward saves)."""
    packed = pack_gaussians(means2d, conics, opacities, colors)
    pixels = bins.tile * bins.tile
    acc = packed.new_zeros(bins.num_tiles, pixels, 4)
    ones = packed.new_ones(1, 1, 1)
    for batch in _batches(bins, pixels, config, packed.device, packed.dtype):
        batch_acc = packed.new_zeros(len(batch.tiles), pixels, 4)
        for rows, frag in _steps(packed, bins, batch, config):
            rgba = torch.cat([frag.g[:, :, _RGB:], ones.expand(*frag.g.shape[:2], 1)], dim=2)
            batch_acc = batch_acc.index_add(0, rows, torch.bmm(frag.weight.transpose(1, 2), rgba))
        acc = acc.index_copy(0, batch.tiles, batch_acc)
    return _finish(acc, background, bins, width, height)
