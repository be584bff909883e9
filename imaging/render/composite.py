"""Front-to-back alpha blending of binned Gaussians, vectorized over tiles, pixels and Gaussians.

Work layout. Non-empty tiles are sorted by list length (longest first) and cut into batches of
similar tiles. Within a batch, each step blends the next ``chunk`` Gaussians of every tile still
running as dense ``(tiles, pixels, chunk)`` tensors (the chunk axis last, so the cumulative
products run over contiguous memory); the transmittance of every pixel is carried from one step
to the next, and tiles whose pixels have all stopped (or whose lists are exhausted) drop out.
``batch_elements`` caps ``tiles x pixels x chunk`` per step, which bounds the working memory
whatever the image size or scene.

Blending rule per pixel (INRIA forward kernel): for fragments in depth order,
``alpha = min(max_alpha, o * exp(-q/2))``; skip it when ``alpha < 1/255``; if
``T * (1 - alpha) < 1e-4`` the pixel stops and this fragment is not added; else add
``T * alpha * colour`` and set ``T *= 1 - alpha``. Because ``T`` only decreases, "stopped" equals
"the running product including this fragment is below 1e-4", which one cumulative product gives
for a whole chunk. The carried transmittance of a stopped pixel is set to 0 so it stays stopped.

CPU speed notes (measured, torch 2.13, one core): contiguous element-wise ops cost ~0.1 ns per
element, but products that underflow into denormal floats are 30x slower, as are boolean-mask
multiplies and ``torch.where`` with Python scalars. Hence the exponent is clamped at -20 (then
``o * exp`` is far below 1/255, so the fragment is skipped exactly as without the clamp), stopped
pixels carry an exact 0, and masks are applied with ``threshold``/``sign`` arithmetic.
A pass that only draws (no input needs a gradient: evaluations, judgements, previews) finds
the exponents as one batched product of per-pair coefficients (:func:`_alpha_drawn`), in
fewer passes over the fragments; a pass with gradients keeps the per-pixel arithmetic its
replayed backward repeats.

Gradients. ``BlendFunction`` stores no per-fragment tensor: backward replays the same steps
(identical inputs and arithmetic, so identical termination) and applies the closed-form
derivative of the blend front to back with a running prefix sum:

    dL/dalpha_k = T_k (c_k . g) - (S_k - gA T_N) / (1 - alpha_k),
    S_k = (C_out . g) - sum_{j<=k} T_j alpha_j (c_j . g),

with ``g`` the image gradient, ``gA`` the alpha gradient and ``T_N`` the final transmittance;
clamped, skipped and stopped fragments get none. Autograd would keep ~10 floats per (pixel,
fragment) pair (gigabytes on real scenes); the replay costs about one more forward.
``blend_autograd`` runs the same steps with plain out-of-place ops under autograd; it is the
oracle the tests compare the hand-written backward with.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache, partial
from typing import Callable, Iterator

import torch
import torch.nn.functional as F

from .binning import TileBins
from .settings import ALPHA_THRESHOLD, TRANSMITTANCE_THRESHOLD

# rows of the per-Gaussian field table: mean x, y; quadratic-form coefficients of the exponent
# (power = A dx^2 + B dx dy + C dy^2 = -q/2); opacity; colour r, g, b
_MX, _MY, _QA, _QB, _QC, _OP, _R, _G, _B = range(9)
_FIELDS = 9
_MIN_POWER = -20.0
"""Exponents are clamped here: exp(-20) < 1/255, so clamped fragments are skipped either way,
and exp never returns a denormal."""
_TINY = 1e-30
"""Opacities are floored here before their log (:func:`_alpha_drawn`): far below 1/255."""


@dataclass(frozen=True)
class BlendConfig:
    """Blending parameters: the alpha clamp, and the step shape (speed/memory only)."""

    max_alpha: float
    chunk: int
    batch_elements: int


@dataclass
class _Batch:
    """A batch of tiles: their ids, pixel centres (n, P), the chunk length of its steps, the
    tiles' centres (n, 2) and the basis ``(1, u, v, u^2, u v, v^2)`` (P, 6) of the pixel
    centres' offsets ``(u, v)`` from their tile's centre (the same for every tile), which a
    drawing pass's exponents and the backward's moments both use."""

    tiles: torch.Tensor
    px: torch.Tensor
    py: torch.Tensor
    chunk: int
    centres: torch.Tensor
    basis: torch.Tensor


@dataclass
class _Fragments:
    """One step: gathered Gaussian fields and (n, P, C) per-(tile, pixel, Gaussian) values."""

    gid: torch.Tensor  # (n, C) table columns (dummy column M for empty slots)
    g: torch.Tensor  # (9, n, C) gathered fields
    alpha_raw: torch.Tensor  # o * exp(max(power, -20)), before clamp and skip
    alpha: torch.Tensor  # clamped to max_alpha, 0 where skipped
    one_minus: torch.Tensor  # 1 - alpha
    t_excl: torch.Tensor  # transmittance before each fragment
    t_incl: torch.Tensor  # running product including each fragment
    weight: torch.Tensor  # T * alpha, 0 once the pixel stopped
    t_next: torch.Tensor  # (n, P) transmittance carried to the next step, 0 if stopped


FragmentFn = Callable[[torch.Tensor, torch.Tensor, "_Batch", torch.Tensor, torch.Tensor,
                       BlendConfig], _Fragments]
"""One step: (gathered fields, their table columns, the batch, its rows in this step, their
carried transmittance, config) to the step's fragments."""


def pack_gaussians(means2d: torch.Tensor, conics: torch.Tensor, opacities: torch.Tensor,
                   colors: torch.Tensor) -> torch.Tensor:
    """A (9, M + 1) field table, so a step gathers everything with one index; column M is a
    dummy with zero opacity that fills the empty slots of short tile lists."""
    quad = torch.stack([-0.5 * conics[:, 0], -conics[:, 1], -0.5 * conics[:, 2]], dim=0)
    table = torch.cat([means2d.T, quad, opacities[None], colors.T], dim=0)
    return torch.cat([table, table.new_zeros(_FIELDS, 1)], dim=1)


@lru_cache(maxsize=None)
def _below(value: float, dtype: torch.dtype) -> float:
    """The largest number of ``dtype`` below ``value``: ``threshold(x, _below(v), 0)`` keeps
    exactly the x >= v (F.threshold keeps x > its threshold)."""
    v = torch.tensor(value, dtype=dtype)
    return float(torch.nextafter(v, torch.zeros((), dtype=dtype)))


def _batches(bins: TileBins, pixels: int, config: BlendConfig,
             device: torch.device, dtype: torch.dtype) -> Iterator[_Batch]:
    """Non-empty tiles, longest lists first, grouped so one step stays under batch_elements."""
    counts = bins.counts
    order = torch.argsort(counts, descending=True, stable=True)
    nonempty = int((counts > 0).sum())
    order = order[:nonempty]
    counts_sorted = counts[order].tolist()
    side = bins.tile
    half = side / 2.0
    local = torch.arange(pixels, device=device)
    lx, ly = (local % side).to(dtype) + 0.5, (local // side).to(dtype) + 0.5
    u, v = lx - half, ly - half
    basis = torch.stack([torch.ones_like(u), u, v, u * u, u * v, v * v], dim=1)
    start = 0
    while start < nonempty:
        chunk = max(1, min(config.chunk, counts_sorted[start]))
        size = max(1, config.batch_elements // (chunk * pixels))
        tiles = order[start:start + size]
        ox, oy = (o.to(dtype) for o in bins.tile_origins(tiles))
        yield _Batch(tiles, ox[:, None] + lx, oy[:, None] + ly, chunk,
                     torch.stack([ox, oy], dim=1) + half, basis)
        start += size


def _gather(table: torch.Tensor, bins: TileBins, tiles: torch.Tensor, first: int,
            chunk: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Table columns for list positions ``first .. first+chunk-1`` of each tile.

    ``index_select`` rather than advanced indexing: 4x faster on the CPU for these shapes.
    """
    slots = first + torch.arange(chunk, device=tiles.device)
    filled = slots[None, :] < bins.counts.index_select(0, tiles)[:, None]
    index = (bins.starts.index_select(0, tiles)[:, None] + slots[None, :])
    index = index.clamp_max_(len(bins.gaussians) - 1).reshape(-1)
    dummy = table.shape[1] - 1
    gid = bins.gaussians.index_select(0, index).view(len(tiles), chunk)
    gid = gid.masked_fill_(~filled, dummy)
    return gid, table.index_select(1, gid.reshape(-1)).view(_FIELDS, len(tiles), chunk)


def _power(g: torch.Tensor, px: torch.Tensor, py: torch.Tensor) -> torch.Tensor:
    """The exponent of every gathered Gaussian at every pixel, ``(n, pixels, C)``, in fresh
    buffers the callers go on to change in place (the no-autograd steps)."""
    row = lambda k: g[k][:, None, :]  # noqa: E731  (n, 1, C) broadcast over pixels
    dx = px[:, :, None] - row(_MX)
    dy = py[:, :, None] - row(_MY)
    power = dx * row(_QA)
    power.addcmul_(dy, row(_QB)).mul_(dx)
    return power.addcmul_(dy.square_(), row(_QC))


def _alpha_exact(g: torch.Tensor, batch: _Batch, rows: torch.Tensor) -> torch.Tensor:
    """``opacity * exp(max(power, -20))`` per fragment, ``(n, P, C)``, from each pixel's own
    offset to the mean: the arithmetic of every pass that keeps gradients (the replayed
    backward must repeat its forward's rounding to end where it ended)."""
    power = _power(g, batch.px.index_select(0, rows), batch.py.index_select(0, rows))
    return power.clamp_min_(_MIN_POWER).exp_().mul_(g[_OP][:, None, :])


def _alpha_drawn(g: torch.Tensor, batch: _Batch, rows: torch.Tensor) -> torch.Tensor:
    """The same values for a pass that only draws, in fewer passes over the fragments.

    The exponent plus the log opacity is a quadratic in the pixel's offset from its tile's
    centre: its six coefficients are found per (tile, Gaussian) pair, P times fewer values
    than fragments, and one batched product with the batch's basis spreads them over the
    pixels, where per-fragment differences and products took six passes. The constant term
    is the exponent at the tile's centre, computed directly, so float32 rounding grows only
    with the tile's side (1e-6 of the image at 8 pixels). Where ``power + log(opacity)`` is
    under -20, so is the fragment's alpha under 1/255 either way: it is skipped, as in
    :func:`_alpha_exact`. An opacity of 0 (the dummy column) is floored before its log."""
    centres = batch.centres.index_select(0, rows)
    mx = g[_MX] - centres[:, :1]  # (n, C) means relative to the tile's centre
    my = g[_MY] - centres[:, 1:]
    qa, qb, qc = g[_QA], g[_QB], g[_QC]
    centre = qa * mx * mx + qb * mx * my + qc * my * my + torch.log(g[_OP].clamp_min(_TINY))
    slope_u = -(2.0 * qa * mx + qb * my)
    slope_v = -(qb * mx + 2.0 * qc * my)
    coefficients = torch.stack([centre, slope_u, slope_v, qa, qb, qc], dim=1)  # (n, 6, C)
    return torch.matmul(batch.basis, coefficients).clamp_min_(_MIN_POWER).exp_()


def _fragments_fast(g: torch.Tensor, gid: torch.Tensor, batch: _Batch, rows: torch.Tensor,
                    t_prev: torch.Tensor, config: BlendConfig, forward_only: bool = False,
                    alpha_of: Callable[[torch.Tensor, _Batch, torch.Tensor], torch.Tensor]
                    = _alpha_exact) -> _Fragments:
    """One step without autograd: in-place arithmetic on fresh buffers (see the speed notes).
    ``forward_only`` (a pass that keeps no fragments for a backward one) also clamps and weights
    in the alpha buffer, so only ``weight``, ``t_next``, ``g`` and ``gid`` of the result are
    meaningful then (the other fields alias them). ``alpha_of``: how the unclamped alphas are
    computed (:func:`_alpha_exact`, or :func:`_alpha_drawn` for a pass that only draws)."""
    dtype = t_prev.dtype
    n, pixels = t_prev.shape
    alpha_raw = alpha_of(g, batch, rows)
    clamped = alpha_raw.clamp_max_(config.max_alpha) if forward_only else \
        alpha_raw.clamp_max(config.max_alpha)
    alpha = F.threshold_(clamped, _below(ALPHA_THRESHOLD, dtype), 0.0)
    factors = t_prev.new_empty(n, pixels, alpha.shape[2] + 1)
    factors[:, :, 0] = t_prev
    one_minus = torch.sub(t_prev.new_ones(()), alpha, out=factors[:, :, 1:])
    products = torch.cumprod(factors, dim=2)
    t_excl, t_incl = products[:, :, :-1], products[:, :, 1:]
    stop = _below(TRANSMITTANCE_THRESHOLD, dtype)
    t_next = F.threshold(t_incl[:, :, -1], stop, 0.0)
    if bool((t_next == 0).any()):
        # some pixel stopped: zero its later weights; t_incl / (1 - alpha) == t_excl. (Its
        # products keep shrinking within this chunk and could in principle reach denormals
        # after ~17 more opaque fragments; none occurred in the benchmark scenes.)
        weight = F.threshold(t_incl, stop, 0.0).mul_(alpha).div_(one_minus)
    else:
        weight = alpha.mul_(t_excl) if forward_only else t_excl * alpha
    if forward_only:
        return _Fragments(gid, g, weight, weight, one_minus, t_excl, t_incl, weight, t_next)
    return _Fragments(gid, g, alpha_raw, alpha, one_minus, t_excl, t_incl, weight, t_next)


_fragments_forward = partial(_fragments_fast, forward_only=True)
_fragments_drawn = partial(_fragments_fast, forward_only=True, alpha_of=_alpha_drawn)


def _fragments_plain(g: torch.Tensor, gid: torch.Tensor, batch: _Batch, rows: torch.Tensor,
                     t_prev: torch.Tensor, config: BlendConfig) -> _Fragments:
    """The same step with out-of-place ops only, so autograd can differentiate it."""
    row = lambda k: g[k][:, None, :]  # noqa: E731
    dx = batch.px.index_select(0, rows)[:, :, None] - row(_MX)
    dy = batch.py.index_select(0, rows)[:, :, None] - row(_MY)
    power = dx * (row(_QA) * dx + row(_QB) * dy) + row(_QC) * (dy * dy)
    alpha_raw = torch.exp(power.clamp_min(_MIN_POWER)) * row(_OP)
    zero = alpha_raw.new_zeros(())
    alpha = torch.where(alpha_raw >= ALPHA_THRESHOLD, alpha_raw.clamp_max(config.max_alpha), zero)
    one_minus = 1.0 - alpha
    products = torch.cumprod(torch.cat([t_prev[:, :, None], one_minus], dim=2), dim=2)
    t_excl, t_incl = products[:, :, :-1], products[:, :, 1:]
    alive = t_incl >= TRANSMITTANCE_THRESHOLD
    weight = torch.where(alive, t_excl * alpha, zero)
    t_next = torch.where(alive[:, :, -1], t_incl[:, :, -1], zero)
    return _Fragments(gid, g, alpha_raw, alpha, one_minus, t_excl, t_incl, weight, t_next)


def _steps(table: torch.Tensor, bins: TileBins, batch: _Batch, config: BlendConfig,
           fragments: FragmentFn) -> Iterator[tuple[torch.Tensor, _Fragments]]:
    """The steps over one batch, as (rows of the batch, fragments); deterministic, so backward
    replays exactly the forward's steps. The carried transmittance is advanced here (keeping its
    autograd history under ``blend_autograd``); callers must not modify yielded tensors."""
    n = len(batch.tiles)
    t_run = batch.px.new_ones(n, batch.px.shape[1])
    rows = torch.arange(n, device=batch.tiles.device)
    counts = bins.counts[batch.tiles]
    first = 0
    while len(rows):
        gid, g = _gather(table, bins, batch.tiles.index_select(0, rows), first, batch.chunk)
        frag = fragments(g, gid, batch, rows, t_run.index_select(0, rows), config)
        yield rows, frag
        t_run = t_run.index_copy(0, rows, frag.t_next)
        first += batch.chunk
        more = (counts.index_select(0, rows) > first) & (frag.t_next.detach() > 0).any(dim=1)
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


def _rgb1(g: torch.Tensor) -> torch.Tensor:
    """(n, C, 4) colours with a ones column, so one bmm yields colour and accumulated alpha."""
    return torch.stack([g[_R], g[_G], g[_B], torch.ones_like(g[_R])], dim=2)


def _finish(acc: torch.Tensor, background: torch.Tensor, bins: TileBins, width: int,
            height: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Image (H, W, 3) with the background behind the remaining transmittance, and alpha."""
    alpha = acc[:, :, 3]
    color = acc[:, :, :3] + (1.0 - alpha)[:, :, None] * background
    return _to_image(color, bins, width, height), _to_image(alpha, bins, width, height)


def _blend_forward(table: torch.Tensor, bins: TileBins, config: BlendConfig,
                   fragments: FragmentFn = _fragments_forward) -> torch.Tensor:
    """Per-tile accumulated (r, g, b, alpha) before the background, (num_tiles, P, 4).
    ``fragments``: :data:`_fragments_forward` where a backward pass will replay the steps,
    :data:`_fragments_drawn` where none will."""
    pixels = bins.tile * bins.tile
    acc = table.new_zeros(bins.num_tiles, pixels, 4)
    for batch in _batches(bins, pixels, config, table.device, table.dtype):
        batch_acc = table.new_zeros(len(batch.tiles), pixels, 4)
        for rows, frag in _steps(table, bins, batch, config, fragments):
            contribution = torch.bmm(frag.weight, _rgb1(frag.g))
            batch_acc.index_copy_(0, rows, contribution.add_(batch_acc.index_select(0, rows)))
        acc[batch.tiles] = batch_acc
    return acc


class BlendFunction(torch.autograd.Function):
    """Blend with a replaying backward (see the module docstring)."""

    @staticmethod
    def forward(ctx, means2d: torch.Tensor, conics: torch.Tensor, opacities: torch.Tensor,
                colors: torch.Tensor, background: torch.Tensor, bins: TileBins,
                config: BlendConfig, width: int, height: int):
        table = pack_gaussians(means2d, conics, opacities, colors)
        drawn_only = not any(ctx.needs_input_grad)
        acc = _blend_forward(table, bins, config,
                             _fragments_drawn if drawn_only else _fragments_forward)
        image, alpha = _finish(acc, background, bins, width, height)
        ctx.save_for_backward(table, image, alpha)
        ctx.bins, ctx.config = bins, config
        return image, alpha

    @staticmethod
    def backward(ctx, grad_image: torch.Tensor, grad_alpha: torch.Tensor):
        table, image, alpha = ctx.saved_tensors
        grad = _blend_backward(table, ctx.bins, ctx.config, image, alpha, grad_image,
                               grad_alpha)[:, :-1]
        d_mean = grad[_MX:_MY + 1].T
        # the table holds (A, B, C) = (-a/2, -b, -c/2) of the conic (a, b, c)
        d_conic = (grad[_QA:_QC + 1] * grad.new_tensor([[-0.5], [-1.0], [-0.5]])).T
        d_opacity = grad[_OP]
        d_color = grad[_R:_B + 1].T
        return d_mean, d_conic, d_opacity, d_color, None, None, None, None, None


def _blend_backward(table: torch.Tensor, bins: TileBins, config: BlendConfig,
                    image: torch.Tensor, alpha: torch.Tensor, grad_image: torch.Tensor,
                    grad_alpha: torch.Tensor) -> torch.Tensor:
    """Gradient w.r.t. the field table (9, M + 1) by replaying the forward steps."""
    pixels = bins.tile * bins.tile
    out_tiles = _from_image(image, bins)
    g_tiles = _from_image(grad_image.contiguous(), bins)
    ga_tiles = _from_image(grad_alpha.contiguous(), bins)
    # S_k - gA T_N = rest - prefix_k, with rest = C_out . g - gA T_N per pixel
    rest_tiles = (out_tiles * g_tiles).sum(-1) - ga_tiles * (1.0 - _from_image(alpha, bins))
    grad = torch.zeros_like(table)
    for batch in _batches(bins, pixels, config, table.device, table.dtype):
        g_batch, rest = g_tiles[batch.tiles], rest_tiles[batch.tiles]
        centres = batch.centres
        # (n, 9, P): moment features in tile-local coordinates, then the image gradient
        lhs = torch.cat([batch.basis.T.expand(len(batch.tiles), -1, -1),
                         g_batch.transpose(1, 2)], dim=1)
        prefix = table.new_zeros(len(batch.tiles), pixels)
        for rows, frag in _steps(table, bins, batch, config, _fragments_fast):
            g_rows, lhs_rows, rest_rows, centre_rows = (
                t.index_select(0, rows) for t in (g_batch, lhs, rest, centres))
            grad_pairs = _pair_gradients(frag, g_rows, lhs_rows, rest_rows, prefix, rows,
                                         centre_rows, config)
            grad.index_add_(1, frag.gid.reshape(-1), grad_pairs.reshape(_FIELDS, -1))
    return grad


def _pair_gradients(frag: _Fragments, g_pix: torch.Tensor, lhs: torch.Tensor,
                    rest: torch.Tensor, prefix: torch.Tensor, rows: torch.Tensor,
                    centres: torch.Tensor, config: BlendConfig) -> torch.Tensor:
    """Gradient of one step w.r.t. each gathered (tile, Gaussian) pair, (9, n, C).

    Advances ``prefix`` (running sum of T alpha (c . g) per pixel) in place.
    """
    g = frag.g
    rgb_t = torch.stack([g[_R], g[_G], g[_B]], dim=1)  # (n, 3, C)
    cg = torch.bmm(g_pix, rgb_t)  # (n, P, C): c . g
    running = torch.cumsum(frag.weight * cg, dim=2).add_(prefix.index_select(0, rows)[:, :, None])
    prefix.index_copy_(0, rows, running[:, :, -1])
    # dL/dalpha = T cg - (rest - running) / (1 - alpha), built in place in `running`
    d_alpha = running.sub_(rest[:, :, None]).div_(frag.one_minus).addcmul_(frag.t_excl, cg)
    # gate: only blended (weight > 0) and unclamped (alpha_raw < max_alpha) fragments
    gate = (config.max_alpha - frag.alpha_raw).clamp_min_(0.0).sign_().mul_(
        torch.sign(frag.weight))
    # dL/dpower = dL/dalpha_raw * alpha_raw, since alpha_raw = o exp(power)
    d_power = d_alpha.mul_(frag.alpha_raw).mul_(gate)
    sums = torch.bmm(lhs[:, :6], d_power)  # (n, 6, C) moments of d_power over the pixels
    d_rgb = torch.bmm(lhs[:, 6:], frag.weight)  # (n, 3, C)
    m0, mx, my, mxx, mxy, myy = sums.unbind(1)
    u = g[_MX] - centres[:, :1]  # means in tile-local coordinates
    v = g[_MY] - centres[:, 1:]
    s_x = mx - u * m0  # sum d_power * dx with dx = pixel - mean
    s_y = my - v * m0
    s_xx = mxx - 2.0 * u * mx + u * u * m0
    s_xy = mxy - u * my - v * mx + u * v * m0
    s_yy = myy - 2.0 * v * my + v * v * m0
    opacity = g[_OP]
    d_opacity = m0 / torch.where(opacity > 0, opacity, torch.ones_like(opacity))
    return torch.cat([
        torch.stack([-(2.0 * g[_QA] * s_x + g[_QB] * s_y), -(g[_QB] * s_x + 2.0 * g[_QC] * s_y),
                     s_xx, s_xy, s_yy, d_opacity], dim=0),
        d_rgb.transpose(0, 1),
    ], dim=0)


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
    """The same blend differentiated by autograd (stores every intermediate; the tests' oracle
    for the replaying backward, and the baseline it is measured against)."""
    table = pack_gaussians(means2d, conics, opacities, colors)
    pixels = bins.tile * bins.tile
    acc = table.new_zeros(bins.num_tiles, pixels, 4)
    for batch in _batches(bins, pixels, config, table.device, table.dtype):
        batch_acc = table.new_zeros(len(batch.tiles), pixels, 4)
        for rows, frag in _steps(table, bins, batch, config, _fragments_plain):
            batch_acc = batch_acc.index_add(0, rows, torch.bmm(frag.weight, _rgb1(frag.g)))
        acc = acc.index_copy(0, batch.tiles, batch_acc)
    return _finish(acc, background, bins, width, height)
