"""Tile binning: which Gaussians each screen tile must blend, in front-to-back order.

The image is cut into ``tile x tile`` squares. Each visible Gaussian is listed in every tile its
pixel box touches; the lists are sorted by camera depth of the mean (stable, so equal depths keep
input order). Everything here is integer bookkeeping without gradients, O(pairs log pairs).
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


def bin_gaussians(pixel_boxes: torch.Tensor, depths: torch.Tensor, width: int, height: int,
                  tile: int) -> TileBins:
    """Bin Gaussians with inclusive pixel boxes (M, 4) = (col0, col1, row0, row1) into tiles.

    Pairs are generated front to back, then stably sorted by tile id; int32 keys and
    ``index_select`` halve the CPU time of this step against int64 and advanced indexing.
    """
    device = pixel_boxes.device
    tiles_x, tiles_y = math.ceil(width / tile), math.ceil(height / tile)
    order = torch.argsort(depths, stable=True)
    boxes = pixel_boxes.index_select(0, order).to(torch.int32)
    tx0, tx1 = boxes[:, 0] // tile, boxes[:, 1] // tile
    ty0, ty1 = boxes[:, 2] // tile, boxes[:, 3] // tile
    nx = tx1 - tx0 + 1
    per_gaussian = nx * (ty1 - ty0 + 1)
    total = int(per_gaussian.sum())

    owner = torch.repeat_interleave(torch.arange(len(order), device=device), per_gaussian,
                                    output_size=total)
    first_pair = torch.cumsum(per_gaussian, 0, dtype=torch.int32) - per_gaussian
    local = torch.arange(total, device=device, dtype=torch.int32)
    local -= first_pair.index_select(0, owner)
    owner_nx = nx.index_select(0, owner)
    row_in_box = torch.div(local, owner_nx, rounding_mode="floor")
    tile_ids = ty0.index_select(0, owner).add_(row_in_box).mul_(tiles_x)
    tile_ids += tx0.index_select(0, owner).add_(local.sub_(row_in_box.mul_(owner_nx)))
    # pairs were generated front to back, so a stable sort by tile keeps depth order per tile
    tile_ids, perm = torch.sort(tile_ids, stable=True)
    gaussians = order.index_select(0, owner.index_select(0, perm))
    counts = torch.bincount(tile_ids, minlength=tiles_x * tiles_y)
    starts = torch.cumsum(counts, 0) - counts
    return TileBins(gaussians, starts, counts, tiles_x, tiles_y, tile)
