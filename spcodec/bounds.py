"""The box of a whole scene, for the metadata's ``bounds`` key ([R-71]).

A viewer frames its camera before the last layer arrives, from layer 0's bytes; layer 0 may hold
one corner of the scene (a retrained file's sketch), so the file says where all of it lies. The
box is of the positions every decoder computes, in the file's own coordinates (before any up-axis
rotation), rounded outward so it still holds every one of them. Beside the full box, a robust one
(the 2nd..98th percentile of each axis) is what the viewer frames: far floaters fall outside it,
as they fall outside the box it computes from decoded centres when a file gives none.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from fractions import Fraction
from functools import lru_cache

import numpy as np

from .container import CLUSTER_DTYPE
from .draco_io import decode_points
from .sections import PatchPositions, SketchCluster, draco_runs

ROBUST_PERCENTILES = (2, 98)
"""The percentiles of each axis the robust box spans (the viewer's framing rule)."""

SIGNIFICANT_DIGITS = 4
"""Decimal places are chosen so that a step is a thousandth of the box's largest side or less."""


def scene_positions(sketch: Iterable[SketchCluster], patches: Iterable[PatchPositions]) -> np.ndarray:
    """(N, 3) float32: every position a decoder computes, the sketch's and every patch layer's."""
    parts = [_sketch_positions(_draco_blobs(list(sketch))), *(p.decode() for p in patches if len(p))]
    return np.concatenate(parts)


def _draco_blobs(clusters: list[SketchCluster]) -> tuple[tuple[bytes, int], ...]:
    """Each Draco blob of the sketch with its point count, grouped as a decoder groups them
    (:func:`.sections.draco_runs`, [R-47])."""
    records = np.zeros(len(clusters), dtype=CLUSTER_DTYPE)
    records["point_count"] = [c.point_count for c in clusters]
    records["draco_length"] = [len(c.draco) for c in clusters]
    positions = b"".join(c.draco for c in clusters)
    return tuple((positions[r.start:r.stop], r.points) for r in draco_runs(records) if r.points)


@lru_cache(maxsize=2)
def _sketch_positions(blobs: tuple[tuple[bytes, int], ...]) -> np.ndarray:
    """The sketch's decoded points: an encoder writes the same sketch in every trial file it
    sizes, so the last ones are kept (a blob's hash is computed once, then cached by Python)."""
    points = np.concatenate([decode_points(blob, count, f"sketch Draco blob {i}")
                             for i, (blob, count) in enumerate(blobs)] or [np.zeros((0, 3), np.float32)])
    points.flags.writeable = False
    return points


def scene_bounds(positions: np.ndarray) -> dict | None:
    """The metadata value for ``positions`` (N, 3): ``{"min", "max", "robust": {"min", "max",
    "percentiles"}}``, each corner a list of three numbers rounded outward; None when no position
    is finite (nothing to frame)."""
    xyz = np.asarray(positions)
    xyz = xyz.astype(np.float64) if not np.issubdtype(xyz.dtype, np.floating) else xyz
    xyz = xyz.reshape(-1, 3)
    xyz = xyz[np.isfinite(xyz).all(axis=1)]
    if not len(xyz):
        return None
    n = len(xyz)
    # the viewer's rule on sorted values: index floor(p (n - 1)) for the low end, ceil for the high
    ranks = [0, math.floor(ROBUST_PERCENTILES[0] / 100 * (n - 1)),
             math.ceil(ROBUST_PERCENTILES[1] / 100 * (n - 1)), n - 1]
    # one partial sort per axis finds all four (a percentile over the (N, 3) array is 4x slower)
    lo, robust_lo, robust_hi, hi = np.array([np.partition(column, ranks)[ranks]
                                             for column in np.ascontiguousarray(xyz.T)],
                                            np.float64).T
    places = decimal_places(float((hi - lo).max()), float(np.abs(np.stack([lo, hi])).max()))
    return {"min": round_down(lo, places), "max": round_up(hi, places),
            "robust": {"min": round_down(robust_lo, places), "max": round_up(robust_hi, places),
                       "percentiles": list(ROBUST_PERCENTILES)}}


def decimal_places(extent: float, magnitude: float) -> int:
    """Decimal places that keep :data:`SIGNIFICANT_DIGITS` digits of ``extent`` (of
    ``magnitude`` when the box is a point, of 1 when that is 0 too); may be negative."""
    scale = extent if extent > 0 else (magnitude if magnitude > 0 else 1.0)
    return SIGNIFICANT_DIGITS - 1 - math.floor(math.log10(scale))


def round_down(values: Iterable[float], places: int) -> list[float]:
    """Each value rounded down to ``places`` decimals: never above it, less than a step below."""
    return [_rounded(float(v), places, math.floor) for v in values]


def round_up(values: Iterable[float], places: int) -> list[float]:
    """Each value rounded up to ``places`` decimals: never below it, less than a step above."""
    return [_rounded(float(v), places, math.ceil) for v in values]


def _rounded(value: float, places: int, direction) -> float:
    """``value``'s shortest decimal (its ``repr``, which reads back as ``value``) moved to the grid
    of ``10**-places`` by ``direction`` (floor or ceil) in exact arithmetic, then read as the
    nearest float: reading is monotonic, so the result stays on the side of ``value`` the grid
    number is on (or equals it), and it prints as that short decimal."""
    scale = Fraction(10) ** places
    return float(Fraction(direction(Fraction(repr(value)) * scale)) / scale)
