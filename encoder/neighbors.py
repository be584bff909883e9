"""Chunked, memory-bounded spatial neighbour search for the encoder (numpy + scipy only).

Categorization needs, for every Gaussian, all Gaussians whose centre lies within a radius. For a
scene of millions of Gaussians the full list of such pairs does not fit comfortably in memory, so
:func:`iter_radius_pairs` yields it one chunk of query points at a time; callers reduce each chunk
(counts, nearest hits, forest edges) before the next one is produced.

Two details keep the results exact and independent of how the work is chunked:

* The KD-tree is queried with a slightly enlarged radius and every candidate is then re-tested with
  one fixed formula (:func:`squared_distances`, float64). Whether a pair at exactly the radius is a
  neighbour therefore never depends on the tree's internal arithmetic - it matters for real scenes,
  whose positions often lie on a quantization grid, where such ties are common.
* Chunks are runs of a Morton (Z-order) sort of the points, so each chunk is spatially compact and
  its dual-tree query touches few tree nodes. The order only affects speed, never the pairs found.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterator

import numpy as np
from scipy.spatial import cKDTree

from .morton import morton_order

RADIUS_SLACK = 1e-6
"""Relative enlargement of the KD-tree query radius before the exact re-test (see module doc)."""


@dataclass(frozen=True)
class RadiusPairs:
    """Ordered pairs (row, col), row != col, whose centres are within the radius; one chunk's worth.

    ``rows`` are the chunk's query points and ``cols`` any point of the scene, both as indices into
    the original point array. A symmetric pair {a, b} shows up as (a, b) in a's chunk and as (b, a)
    in b's chunk, so every chunk sees the complete neighbourhood of each of its rows. Distances
    are not carried: most consumers need none, and :func:`squared_distances` gives them exactly
    for the subset that does.
    """

    rows: np.ndarray
    """(E,) int64 index of the query point."""
    cols: np.ndarray
    """(E,) int64 index of the neighbour."""

    def select(self, mask: np.ndarray) -> "RadiusPairs":
        """The pairs where ``mask`` is True."""
        return RadiusPairs(self.rows[mask], self.cols[mask])


def squared_distances(points: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Squared Euclidean distances between ``points[a]`` and ``points[b]`` (float64).

    The single definition of "spatial distance" used for every neighbour decision, evaluated as
    ``(dx * dx + dy * dy) + dz * dz`` so that a reference implementation decides ties at the radius
    identically. (``np.take`` because fancy indexing of a 2-D array is an order of magnitude
    slower for millions of indices.)
    """
    diff = np.take(points, a, axis=0) - np.take(points, b, axis=0)
    return rowwise_dot(diff, diff)


def rowwise_dot(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``u[:, 0] * v[:, 0] + u[:, 1] * v[:, 1] + u[:, 2] * v[:, 2]``, summed in exactly that order.

    Spelled out (rather than ``einsum``, whose summation order may vary with SIMD paths) so that
    a plain scalar reference computes bit-identical values.
    """
    return u[:, 0] * v[:, 0] + u[:, 1] * v[:, 1] + u[:, 2] * v[:, 2]


def iter_radius_pairs(points: np.ndarray, radius: float, chunk_size: int,
                      tree: cKDTree | None = None) -> Iterator[RadiusPairs]:
    """Yield, chunk by chunk, all ordered pairs (i, j), i != j, with ``|p_i - p_j| <= radius``.

    Every point is a row of exactly one chunk. Memory per chunk is proportional to ``chunk_size``
    times the mean number of points within ``radius``; nothing is kept between chunks.

    Args:
        points: (N, 3) float64 positions.
        radius: the inclusive distance bound, in the units of ``points``.
        chunk_size: number of query points per chunk.
        tree: a ``cKDTree`` already built on ``points`` (built here when omitted).
    """
    if chunk_size < 1:
        raise ValueError(f"chunk_size must be positive, got {chunk_size}")
    n = points.shape[0]
    if n == 0:
        return
    tree = cKDTree(points) if tree is None else tree
    outer = radius * (1.0 + RADIUS_SLACK) + np.finfo(np.float64).tiny
    inner = radius * (1.0 - RADIUS_SLACK)
    order = morton_order(points)
    for start in range(0, n, chunk_size):
        chunk = order[start:start + chunk_size]
        found = cKDTree(points[chunk]).sparse_distance_matrix(tree, outer, output_type="ndarray")
        rows = chunk[found["i"]]
        cols = found["j"].astype(np.int64, copy=False)
        keep = rows != cols
        # The tree's distance decides all but the pairs in a thin band around the radius, which
        # are re-tested with the reference formula (module docstring).
        band = keep & (found["v"] > inner)
        keep[band] = squared_distances(points, rows[band], cols[band]) <= radius * radius
        yield RadiusPairs(rows[keep], cols[keep])


def knn_distance_quantile(points: np.ndarray, k: int, quantile: float, sample_size: int,
                          rng: np.random.Generator, tree: cKDTree | None = None) -> float:
    """A quantile of the distance from a point to its k-th nearest other point.

    This is the scene's typical local spacing and sets the spatial scale of categorization in
    whatever units the scene uses. For large scenes it is estimated from ``sample_size`` random
    query points (still searched against the whole scene, so distances are exact for them).
    Returns 0.0 for fewer than two points; ``k`` is lowered to ``N - 1`` for tiny scenes.
    """
    n = points.shape[0]
    if n < 2:
        return 0.0
    k = min(k, n - 1)
    tree = cKDTree(points) if tree is None else tree
    queries = points if n <= sample_size else points[rng.choice(n, sample_size, replace=False)]
    dist, _ = tree.query(queries, k=[k + 1])  # the closest hit is the point itself
    return float(np.quantile(dist[:, 0], quantile))
