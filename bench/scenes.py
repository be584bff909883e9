"""Scenes shared by the benchmarks: the real ones under $SPCODEC_DATA and tiled enlargements."""

from __future__ import annotations

import os
from pathlib import Path

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
    rng = np.random.default_rng(seed)
    means = base.means.astype(np.float64)
    extent = means.max(axis=0) - means.min(axis=0)
    spacing = float(np.median(cKDTree(means).query(means, k=[2])[0]))
    copies = -(-n // len(base))
    side = int(np.ceil(copies ** (1 / 3)))
    parts = []
    for k in range(copies):
        cell = np.array([k % side, (k // side) % side, k // (side * side)])
        part = base.subset(slice(None))
        part.means = (means + cell * extent * 1.05
                      + rng.normal(0, 0.25 * spacing, means.shape)).astype(np.float32)
        part.sh_dc = (part.sh_dc + rng.normal(0, 0.01, part.sh_dc.shape)).astype(np.float32)
        parts.append(part)
    return GaussianCloud.concat(parts).subset(slice(0, n))


def load_scene(name: str) -> GaussianCloud:
    """A named benchmark scene (see the module docstring)."""
    if name in REAL:
        return read_ply(data_dir() / REAL[name])
    base, n = TILED[name]
    return tiled_scene(read_ply(data_dir() / REAL[base]), n)
