"""Scenes shared by the benchmarks: the real ones under $SPCODEC_DATA and tiled enlargements."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Iterator

import numpy as np
from scipy.spatial import cKDTree

from spcodec import GaussianCloud, read_ply

REAL = {
    "fourth_st": "pdal_fourth_st_spz/fourth_st_inria.ply",
    "biker": "playcanvas_biker_guitar/biker_from_spz_inria.ply",
    "donut": "v3dg_donut_mipsplatting/fused.ply",
    "guitar": "playcanvas_biker_guitar/guitar_inria.ply",
    "kacytran": "kacytran_try_sh3/point_cloud_iteration_7000.ply",
}
UP = {"donut": "+z"}
"""The up axis of the real scenes whose up is not the encoder's default (-y)."""
TILED = {  # name: (real scene tiled, Gaussians)
    "500k": ("fourth_st", 500_000), "1M": ("fourth_st", 1_000_000),
    "biker-500k": ("biker", 500_000), "biker-1M": ("biker", 1_000_000),
}


def data_dir() -> Path:
    """``$SPCODEC_DATA``, else the first ``shared/data`` found beside or above the repository."""
    if "SPCODEC_DATA" in os.environ:
        return Path(os.environ["SPCODEC_DATA"])
    repo = Path(__file__).resolve().parents[1]
    for parent in repo.parents:
        if (parent / "shared" / "data").is_dir():
            return parent / "shared" / "data"
    return repo.parent / "shared" / "data"


def tiled_scene(base: GaussianCloud, n: int, seed: int = 0) -> GaussianCloud:
    """``n`` Gaussians: jittered copies of ``base`` side by side on a grid, the last one partial.

    Copies do not overlap (grid pitch 1.05 x the bounding box), so the local density, and hence
    the per-Gaussian work of the neighbour search, is that of the real scene. Each copy's centres
    are jittered by a quarter of the median nearest-neighbour spacing and its colours slightly, so
    copies are not bit-identical (which would make ties and duplicates unrealistically common).
    """
    return GaussianCloud.concat(list(tiled_copies(base, n, seed)))


def tiled_copies(base: GaussianCloud, n: int, seed: int = 0) -> Iterator[GaussianCloud]:
    """The copies :func:`tiled_scene` concatenates, one at a time (the last cut to reach ``n``),
    so a scene larger than memory can be written copy by copy."""
    rng = np.random.default_rng(seed)
    means = base.means.astype(np.float64)
    extent = means.max(axis=0) - means.min(axis=0)
    spacing = float(np.median(cKDTree(means).query(means, k=[2])[0]))
    copies = -(-n // len(base))
    side = int(np.ceil(copies ** (1 / 3)))
    for k in range(copies):
        cell = np.array([k % side, (k // side) % side, k // (side * side)])
        part = base.subset(slice(None))
        part.means = (means + cell * extent * 1.05
                      + rng.normal(0, 0.25 * spacing, means.shape)).astype(np.float32)
        part.sh_dc = (part.sh_dc + rng.normal(0, 0.01, part.sh_dc.shape)).astype(np.float32)
        yield part.subset(slice(0, n - k * len(base)))


CITY_BASES = ("fourth_st", "biker", "guitar", "kacytran")
"""Shared scenes with one up axis (-y) that :func:`city_scene` lays out as blocks."""


def city_scene(bases: list[GaussianCloud], n: int, seed: int = 0) -> GaussianCloud:
    """``n`` Gaussians laid out like a city: copies of ``bases`` (the scenes drawn at random) on a
    square grid in the ground plane (x, z; the bases' up axis is y), each turned by a random
    angle about the up axis and set on the ground, with streets between blocks (pitch 1.2 x the
    largest base's footprint). Unlike :func:`tiled_scene`'s cube of one scene, the layout is
    flat and mixed, as a captured city is: many blocks side by side, of unequal density.
    SH is padded to the highest degree among the bases drawn.
    """
    return GaussianCloud.concat(list(city_blocks(bases, n, seed)))


def city_blocks(bases: list[GaussianCloud], n: int, seed: int = 0) -> Iterator[GaussianCloud]:
    """The blocks :func:`city_scene` concatenates, one at a time (the last cut to reach ``n``),
    each with the SH degree of the whole city, so a city larger than memory can be written
    block by block."""
    rng = np.random.default_rng(seed)
    extents = [b.means.max(axis=0) - b.means.min(axis=0) for b in bases]
    pitch = 1.2 * max(float(np.hypot(e[0], e[2])) for e in extents)
    sizes = np.array([len(b) for b in bases])
    picks: list[int] = []
    while sizes[picks].sum() < n:
        picks.append(int(rng.integers(len(bases))))
    degree = max(bases[p].sh_degree for p in picks)
    side = int(np.ceil(np.sqrt(len(picks))))
    written = 0
    for k, pick in enumerate(picks):
        part = bases[pick].subset(slice(None))
        means = part.means.astype(np.float64)
        centre = 0.5 * (means.min(axis=0) + means.max(axis=0))
        angle = rng.uniform(0, 2 * np.pi)
        c, s = np.cos(angle), np.sin(angle)
        turn = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
        ground = centre[1] - means[:, 1].max()  # y is down: the block's largest y on the ground
        part.means = ((means - centre) @ turn.T + [(k % side) * pitch, ground, (k // side) * pitch]
                      ).astype(np.float32)
        # turning the block turns every Gaussian's orientation with it (not its SH: view-dependent
        # colour is off in turned blocks, which changes nothing the tiling measures)
        half = angle / 2
        turn_q = np.array([np.cos(half), 0.0, np.sin(half), 0.0])
        part.quats = quat_multiply(turn_q, part.quats.astype(np.float64)).astype(np.float32)
        if part.sh_degree != degree:
            part = part.with_sh_degree(degree)
        part = part.subset(slice(0, n - written))
        written += len(part)
        yield part


def quat_multiply(q: np.ndarray, quats: np.ndarray) -> np.ndarray:
    """``q * quats[i]`` for (w, x, y, z) quaternions: ``quats`` turned by ``q``."""
    w0, x0, y0, z0 = q
    w, x, y, z = quats.T
    return np.stack([w0 * w - x0 * x - y0 * y - z0 * z, w0 * x + x0 * w + y0 * z - z0 * y,
                     w0 * y - x0 * z + y0 * w + z0 * x, w0 * z + x0 * y - y0 * x + z0 * w], axis=1)


def load_scene(name: str) -> GaussianCloud:
    """A named benchmark scene (see the module docstring)."""
    if name in REAL:
        return read_ply(data_dir() / REAL[name])
    base, n = TILED[name]
    return tiled_scene(read_ply(data_dir() / REAL[base]), n)
