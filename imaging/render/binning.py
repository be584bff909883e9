"""Tile binning: which Gaussians each screen tile must blend, in front-to-back order.

The image is cut into ``tile x tile`` squares. Each visible Gaussian is listed in the tiles its
1/255 ellipse may reach; the lists are sorted by camera depth of the mean (stable, so equal
depths keep input order). Nothing here needs gradients.

The tiles are found one row of tiles at a time. With ``conic = (a, b, c)`` and ``q = a dx^2 +
2 b dx dy + c dy^2``, the ellipse ``q <= E^2`` (``E`` the extent: the Mahalanobis radius of the
1/255 contour) spans, at height ``dy``, the ``dx`` between ``(-b dy -+ sqrt(a E^2 - det dy^2)) /
a``. Its right edge is concave in ``dy``, so over the band of a tile row's pixel centres it is
furthest right at the band's height nearest the ellipse's rightmost point (``dy = -b x_max /
c``); likewise on the left. The tiles of the row whose pixel-centre columns meet that span are
listed, within the Gaussian's pixel box. Every pixel centre whose fragment passes the alpha
test lies inside the ellipse, hence inside its row's span, so no list misses a Gaussian that
draws there (the extent is widened by a margin so that rounding may only add tiles); a listed
pair that draws nothing is skipped by the blend's alpha test. Per row rather than per (tile,
Gaussian) pair, so the pairs come out in one pass with no per-pair test.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch


@dataclass
class TileBins:
    """Per-tile Gaussian lists in CSR form.

    ``gaussians`` (K,) indices into the projected Gaussians, grouped by tile and front-to-back
    within a tile; tile ``t`` owns ``gaussians[starts[t] : starts[t] + counts[t]]``.
    ``tiles_x``/``tiles_y`` tiles across/down; ``tile`` pixels per side.
    """

    gaussians: torch.Tensor
    starts: torch.Tensor
    counts: torch.Tensor
    tiles_x: int
    tiles_y: int
    tile: int

    @property
    def num_tiles(self) -> int:
        return self.tiles_x * self.tiles_y

    def tile_origins(self, tiles: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Pixel column and row of the top-left pixel of each tile in ``tiles``."""
        return (tiles % self.tiles_x) * self.tile, (tiles // self.tiles_x) * self.tile


_EXTENT_MARGIN = (1e-4, 1e-3)
"""The extent is widened to ``E (1 + 1e-4) + 1e-3`` before the spans are computed."""

_SPAN_MARGIN = 1e-2
"""Pixels added on both sides of every row's span (float32 rounding of the span's terms)."""


TRAINING_TILE = 4
"""The tile of a pass that keeps gradients: its replayed backward does several times the
forward's work per (pixel, Gaussian) evaluation, so it pays to waste fewer of them (8 took
13-58 % longer forward and backward on five scenes at 256 and 800 pixels; docs/LOG.md 29.1)."""

DRAWING_TILES = (4, 8)
"""The tiles a pass that only draws chooses between (:func:`choose_tile`)."""

PAIR_RATIO = 3.0
"""A drawing pass takes 8-pixel tiles where its Gaussians' pixel boxes meet more than this
many times as many 4-pixel tiles as 8-pixel ones (about 1 for footprints under a tile, 4 for
footprints many tiles wide: then the pairs to list, sort and gather outweigh the pixels
evaluated in vain). Over 60 views of five scenes (training views at 256 pixels, close-ups at
400 and 800) the faster tile changed between 2.7 and 3.0; fitted on four scenes, the
threshold cost the fifth at most 0.8 % over the faster tile of each view, where 8 alone cost up
to 27 % and 4 alone up to 84 % (``bench_render.py --drawing-tiles``; docs/LOG.md 29.1)."""


def tile_pairs(pixel_boxes: torch.Tensor, tile: int) -> int:
    """How many (tile, Gaussian) pairs the pixel boxes ``(M, 4)`` (col0, col1, row0, row1,
    inclusive) meet at a tile side of ``tile`` (an upper bound of the binned pairs)."""
    boxes = pixel_boxes.to(torch.int64) // tile
    return int(((boxes[:, 1] - boxes[:, 0] + 1) * (boxes[:, 3] - boxes[:, 2] + 1)).sum())


def choose_tile(pixel_boxes: torch.Tensor, gradients: bool) -> int:
    """The tile side for a pass over these pixel boxes: :data:`TRAINING_TILE` for one that keeps
    gradients; for one that only draws, the larger of :data:`DRAWING_TILES` where the boxes
    meet more than :data:`PAIR_RATIO` times as many small tiles as large ones."""
    if gradients or len(pixel_boxes) == 0:
        return TRAINING_TILE
    small, large = DRAWING_TILES
    pairs_small, pairs_large = tile_pairs(pixel_boxes, small), tile_pairs(pixel_boxes, large)
    return large if pairs_small > PAIR_RATIO * pairs_large else small


def bin_gaussians(pixel_boxes: torch.Tensor, depths: torch.Tensor, means2d: torch.Tensor,
                  conics: torch.Tensor, extents: torch.Tensor, width: int, height: int,
                  tile: int) -> TileBins:
    """Bin Gaussians into tiles (all inputs detached; see the module docstring).

    ``pixel_boxes`` (M, 4) inclusive (col0, col1, row0, row1); ``depths`` (M,); ``means2d``
    (M, 2); ``conics`` (M, 3) as (a, b, c); ``extents`` (M,) Mahalanobis radii. Pairs are
    generated front to back, then stably sorted by tile id (int16 or int32 keys).
    """
    device = pixel_boxes.device
    tiles_x, tiles_y = math.ceil(width / tile), math.ceil(height / tile)
    order = torch.argsort(depths, stable=True)
    boxes = pixel_boxes.index_select(0, order).to(torch.int32)
    ty0, ty1 = boxes[:, 2] // tile, boxes[:, 3] // tile
    rows_per = ty1 - ty0 + 1
    total_rows = int(rows_per.sum())
    row_owner = torch.repeat_interleave(torch.arange(len(order), device=device), rows_per,
                                        output_size=total_rows)
    first_row = torch.cumsum(rows_per, 0, dtype=torch.int32) - rows_per
    row_y = torch.arange(total_rows, device=device, dtype=torch.int32)
    row_y -= first_row.index_select(0, row_owner)
    row_y += ty0.index_select(0, row_owner)
    gaussian = order.index_select(0, row_owner)
    x_first = (boxes[:, 0] // tile).long().index_select(0, row_owner)
    x_last = (boxes[:, 1] // tile).long().index_select(0, row_owner)
    # a box one tile wide keeps its tile in every row (a span could drop only a row's one pair)
    wide = torch.nonzero(x_last > x_first).squeeze(1)
    if len(wide):
        first, last = _row_spans(row_y.index_select(0, wide), gaussian.index_select(0, wide),
                                 means2d, conics, extents, tile)
        x_first.index_copy_(0, wide, torch.maximum(first, x_first.index_select(0, wide)))
        x_last.index_copy_(0, wide, torch.minimum(last, x_last.index_select(0, wide)))
    per_row = (x_last - x_first + 1).clamp_min_(0)
    total = int(per_row.sum())
    # the tile id of a pair is its row's first tile id plus its place in the row
    first_pair = torch.cumsum(per_row, 0) - per_row
    base = row_y.long().mul_(tiles_x).add_(x_first).sub_(first_pair)
    tile_ids = torch.repeat_interleave(base, per_row, output_size=total)
    tile_ids += torch.arange(total, device=device)
    owners = torch.repeat_interleave(gaussian, per_row, output_size=total)
    # pairs were generated front to back, so a stable sort by tile keeps depth order per tile;
    # int16 keys sort 1.7x faster than int32 when the tile count allows
    narrow = torch.int16 if tiles_x * tiles_y <= torch.iinfo(torch.int16).max else torch.int32
    tile_ids, perm = torch.sort(tile_ids.to(narrow), stable=True)
    gaussians = owners.index_select(0, perm)
    counts = torch.bincount(tile_ids.long(), minlength=tiles_x * tiles_y)
    starts = torch.cumsum(counts, 0) - counts
    return TileBins(gaussians, starts, counts, tiles_x, tiles_y, tile)


def _row_spans(row_y: torch.Tensor, gaussian: torch.Tensor, means2d: torch.Tensor,
               conics: torch.Tensor, extents: torch.Tensor, tile: int
               ) -> tuple[torch.Tensor, torch.Tensor]:
    """First and last tile column (int64) whose pixel centres may meet Gaussian ``gaussian``'s
    ellipse within tile row ``row_y``, per row (first > last when none may)."""
    pick = lambda t: t.index_select(0, gaussian).to(torch.float64)  # noqa: E731
    a, b, c = (pick(conics[:, k]) for k in range(3))
    scale, shift = _EXTENT_MARGIN
    limit = pick(extents * (1.0 + scale) + shift).square_()  # E^2
    det = (a * c - b * b).clamp_min_(1e-300)
    # the band of the row's pixel-centre heights, relative to the mean, within the ellipse's
    y_reach = torch.sqrt(a * limit / det)
    top = row_y.to(torch.float64) * tile + 0.5 - pick(means2d[:, 1])
    lo = torch.maximum(top, -y_reach)
    hi = torch.minimum(top + (tile - 1), y_reach)
    turn = b * torch.sqrt(limit / (c * det))  # |dy| of the leftmost / rightmost point
    y_right = torch.minimum(torch.maximum(-turn, lo), hi)
    y_left = torch.minimum(torch.maximum(turn, lo), hi)
    half = lambda y: torch.sqrt((a * limit - det * y * y).clamp_min(0.0))  # noqa: E731
    mean_x = pick(means2d[:, 0])
    right = mean_x + (half(y_right) - b * y_right) / a + _SPAN_MARGIN
    left = mean_x - (half(y_left) + b * y_left) / a - _SPAN_MARGIN
    # tile column t holds pixel centres t*tile + 0.5 .. t*tile + tile - 0.5
    first = torch.ceil((left - (tile - 0.5)) / tile)
    last = torch.floor((right - 0.5) / tile)
    empty = lo > hi + _SPAN_MARGIN
    last = torch.where(empty, first - 1, last)
    bound = float(1 << 30)
    return (first.clamp(-bound, bound).to(torch.int64),
            last.clamp(-bound, bound).to(torch.int64))
