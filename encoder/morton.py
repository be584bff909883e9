"""Z-order (Morton) codes: a space-filling curve that keeps nearby points nearby in a sequence.

Used to chunk neighbour queries (spatially compact chunks), to order patch layers and sketch runs
(small deltas between consecutive positions compress well).
"""

from __future__ import annotations

import numpy as np

_BITS = 21
"""Bits per axis: 3 x 21 = 63 bits fit in a uint64."""


def morton_codes(points: np.ndarray) -> np.ndarray:
    """uint64 codes of ``points`` (N, 3) on a 2^21 grid over their bounding cube."""
    points = np.asarray(points, dtype=np.float64)
    if len(points) == 0:
        return np.zeros(0, np.uint64)
    lo = points.min(axis=0)
    span = float(np.max(points.max(axis=0) - lo))
    scale = ((1 << _BITS) - 1) / span if span > 0 else 0.0
    cells = np.floor((points - lo) * scale).astype(np.uint64)
    code = np.zeros(len(points), np.uint64)
    for axis in range(3):
        code |= _spread_bits(cells[:, axis]) << np.uint64(axis)
    return code


def morton_order(points: np.ndarray) -> np.ndarray:
    """A permutation sorting ``points`` along the curve; ties keep index order (deterministic)."""
    return np.argsort(morton_codes(points), kind="stable").astype(np.int64)


def _spread_bits(v: np.ndarray) -> np.ndarray:
    """Insert two zero bits between consecutive bits of 21-bit integers (Morton interleaving)."""
    v = v & np.uint64(0x1FFFFF)
    for shift, mask in ((32, 0x1F00000000FFFF), (16, 0x1F0000FF0000FF), (8, 0x100F00F00F00F00F),
                        (4, 0x10C30C30C30C30C3), (2, 0x1249249249249249)):
        v = (v | (v << np.uint64(shift))) & np.uint64(mask)
    return v
