"""Tile binning: every (pixel, Gaussian) fragment that passes the alpha test is listed, in depth
order, and the per-row spans list fewer pairs than the pixel boxes."""

from __future__ import annotations

import math

import numpy as np
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from spcodec.imaging.render.binning import bin_gaussians
from spcodec.imaging.render.projection import footprint_extent, pixel_range
from spcodec.imaging.render.settings import ALPHA_THRESHOLD

WIDTH, HEIGHT = 61, 47


def _footprints(seed: int, count: int, stretch: float):
    """Random screen-space Gaussians (means, conics, opacities) as the projection makes them:
    elongated up to ``stretch`` times, at any angle, some reaching past the image."""
    rng = np.random.default_rng(seed)
    means = rng.uniform([-10, -10], [WIDTH + 10, HEIGHT + 10], (count, 2))
    angle = rng.uniform(0, math.pi, count)
    major = rng.uniform(0.3, 12.0, count)
    minor = major / rng.uniform(1.0, stretch, count)
    cos, sin = np.cos(angle), np.sin(angle)
    a = major**2 * cos**2 + minor**2 * sin**2 + 0.3
    c = major**2 * sin**2 + minor**2 * cos**2 + 0.3
    b = (major**2 - minor**2) * cos * sin
    det = a * c - b * b
    conics = np.stack([c / det, -b / det, a / det], axis=1)
    opacities = rng.uniform(0.002, 1.0, count)
    depths = rng.uniform(1.0, 5.0, count)
    return (torch.tensor(means, dtype=torch.float32), torch.tensor(conics, dtype=torch.float32),
            torch.tensor(opacities, dtype=torch.float32), torch.tensor(depths, dtype=torch.float32),
            torch.tensor(np.stack([a, c], axis=1), dtype=torch.float32))


def _binned(seed: int, count: int, stretch: float, tile: int):
    means, conics, opacities, depths, diag = _footprints(seed, count, stretch)
    extents = footprint_extent(opacities)
    col0, col1 = pixel_range(means[:, 0], extents * diag[:, 0].sqrt(), WIDTH)
    row0, row1 = pixel_range(means[:, 1], extents * diag[:, 1].sqrt(), HEIGHT)
    keep = torch.nonzero((col0 <= col1) & (row0 <= row1) & (opacities >= ALPHA_THRESHOLD))[:, 0]
    boxes = torch.stack([col0, col1, row0, row1], dim=1)[keep]
    bins = bin_gaussians(boxes, depths[keep], means[keep], conics[keep], extents[keep], WIDTH,
                         HEIGHT, tile)
    return bins, means[keep], conics[keep], opacities[keep], depths[keep], boxes


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**31), st.integers(1, 60), st.floats(1.0, 40.0), st.sampled_from([1, 4, 16]))
def test_every_fragment_that_passes_the_alpha_test_is_listed_in_depth_order(
        seed: int, count: int, stretch: float, tile: int) -> None:
    bins, means, conics, opacities, depths, boxes = _binned(seed, count, stretch, tile)
    ys, xs = np.mgrid[0:HEIGHT, 0:WIDTH]
    px, py = torch.tensor(xs + 0.5), torch.tensor(ys + 0.5)
    per_tile = {t: bins.gaussians[int(bins.starts[t]):int(bins.starts[t] + bins.counts[t])]
                for t in range(bins.num_tiles)}
    tile_of = (py.long() // tile) * bins.tiles_x + (px.long() // tile)
    for g in range(len(means)):
        a, b, c = conics[g].double()
        dx, dy = px - means[g, 0].double(), py - means[g, 1].double()
        alpha = opacities[g].double() * torch.exp(-0.5 * (a * dx * dx + 2 * b * dx * dy + c * dy * dy))
        for t in torch.unique(tile_of[alpha >= ALPHA_THRESHOLD]).tolist():
            assert g in per_tile[t].tolist(), (g, t)
    for listed in per_tile.values():
        assert torch.all(depths[listed][1:] >= depths[listed][:-1])
    # never more pairs than the tiles of the pixel boxes
    box_tiles = ((boxes[:, 1] // tile - boxes[:, 0] // tile + 1)
                 * (boxes[:, 3] // tile - boxes[:, 2] // tile + 1)).sum()
    assert len(bins.gaussians) <= int(box_tiles)


def test_the_spans_drop_the_tiles_a_thin_diagonal_gaussian_misses() -> None:
    """A long thin Gaussian across the image's diagonal: its box is the whole image, its list
    a band of tiles along the diagonal."""
    angle = math.atan2(HEIGHT, WIDTH)
    major, minor = 30.0, 0.5
    cos, sin = math.cos(angle), math.sin(angle)
    a = major**2 * cos**2 + minor**2 * sin**2
    c = major**2 * sin**2 + minor**2 * cos**2
    b = (major**2 - minor**2) * cos * sin
    det = a * c - b * b
    conics = torch.tensor([[c / det, -b / det, a / det]], dtype=torch.float32)
    extents = footprint_extent(torch.tensor([0.9]))
    boxes = torch.tensor([[0, WIDTH - 1, 0, HEIGHT - 1]])
    bins = bin_gaussians(boxes, torch.tensor([1.0]), torch.tensor([[WIDTH / 2, HEIGHT / 2]]),
                         conics, extents, WIDTH, HEIGHT, 4)
    assert 0 < len(bins.gaussians) < bins.num_tiles / 3
