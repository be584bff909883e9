"""Sketch positions through Draco, and the correspondence between decoded and input points.

Draco's point-cloud coder reorders points and merges exactly coincident ones, so after encoding a
cluster the encoder decodes the blob, as any decoder will, and matches each decoded point to the
input Gaussian it came from. The polynomial models are then fitted on the *decoded* positions with
the matched Gaussians' attributes, so the encoder measures exactly what a decoder produces.

Quantization uses one absolute step for the whole scene, chosen from a precision target relative to
the scene's robust diameter: every cluster gets the same positional accuracy whatever its size.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

MAX_DRACO_BITS = 30


def robust_diameter(means: np.ndarray, percentile: float = 0.5) -> float:
    """Diagonal of the box between the ``percentile`` and ``100 - percentile`` positions.

    Trained scenes carry far-away floaters; a plain bounding box would make every relative target
    needlessly loose.
    """
    if len(means) == 0:
        return 1.0
    lo = np.percentile(means, percentile, axis=0)
    hi = np.percentile(means, 100.0 - percentile, axis=0)
    diameter = float(np.linalg.norm(hi - lo))
    return diameter if diameter > 0 else float(np.linalg.norm(means.max(0) - means.min(0))) or 1.0


@dataclass
class DracoCluster:
    """One cluster's Draco blob and how its decoded points map to the input."""

    blob: bytes
    positions: np.ndarray
    """(n, 3) float32 decoded positions, in the order a decoder returns them."""
    source: np.ndarray
    """(n,) indices into the input points: decoded point i came from input point source[i]."""
    dropped: np.ndarray
    """Indices of input points not represented (exact duplicates of a kept point)."""


def unique_rows(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Indices of the first occurrence of each distinct row, and of the repeated rows."""
    _, first = np.unique(np.ascontiguousarray(points), axis=0, return_index=True)
    keep = np.sort(first)
    repeated = np.setdiff1d(np.arange(len(points)), keep, assume_unique=True)
    return keep, repeated


def quantization_bits(extent: float, step: float) -> int:
    """Bits so that ``2**bits - 1`` steps cover ``extent``."""
    if extent <= 0:
        return 1
    return min(MAX_DRACO_BITS, max(1, math.ceil(math.log2(extent / step + 1.0))))


def encode_cluster(points: np.ndarray, step: float, compression_level: int = 10) -> DracoCluster:
    """Draco-encode ``points`` with the given absolute quantization step, decode, and match."""
    import DracoPy

    points = np.asarray(points, dtype=np.float32)
    keep, repeated = unique_rows(points)
    kept = points[keep]
    lo = kept.min(axis=0)
    extent = float((kept.max(axis=0) - lo).max())
    bits = quantization_bits(extent, step)
    span = step * ((1 << bits) - 1)
    blob = DracoPy.encode(kept, quantization_bits=bits, compression_level=compression_level,
                          quantization_range=max(span, extent, 1e-30),
                          quantization_origin=lo.astype(np.float64).tolist())
    decoded = np.asarray(DracoPy.decode(blob).points, dtype=np.float32).reshape(-1, 3)
    if len(decoded) != len(kept):  # pragma: no cover - would be a Draco behaviour change
        raise RuntimeError(f"Draco returned {len(decoded)} of {len(kept)} distinct points")
    match = match_points(kept, decoded)
    return DracoCluster(blob, decoded, keep[match], repeated)


def match_points(original: np.ndarray, decoded: np.ndarray) -> np.ndarray:
    """A one-to-one map ``m`` with ``decoded[i]`` close to ``original[m[i]]``.

    Each decoded point lies within half a quantization cell of its source. Nearest neighbours
    settle almost every point at once; the rare conflicts (sources closer than a cell) are resolved
    greedily among a few candidates, closest pairs first.
    """
    from scipy.spatial import cKDTree

    n = len(original)
    if n == 0:
        return np.zeros(0, np.int64)
    k = min(8, n)
    dist, cand = cKDTree(original).query(decoded, k=k)
    dist, cand = dist.reshape(n, k), cand.reshape(n, k)
    first = cand[:, 0]
    counts = np.bincount(first, minlength=n)
    result = np.where(counts[first] == 1, first, -1)
    taken = np.zeros(n, bool)
    taken[result[result >= 0]] = True
    pending = np.flatnonzero(result < 0)
    for i in pending[np.argsort(dist[pending, 0], kind="stable")]:
        free = cand[i][~taken[cand[i]]]
        if len(free):
            result[i] = free[0]
            taken[free[0]] = True
    rest = np.flatnonzero(result < 0)
    if len(rest):  # candidates exhausted: pair the leftovers by brute force, nearest first
        sources = np.flatnonzero(~taken)
        d = np.linalg.norm(decoded[rest, None, :] - original[None, sources, :], axis=2)
        for row in np.argsort(d.min(axis=1), kind="stable"):
            col = int(np.argmin(d[row]))
            result[rest[row]] = sources[col]
            d[:, col] = np.inf
    return result


@dataclass
class OrderedBlob:
    """An order-preserving Draco blob and the positions a decoder gets from it, in input order."""

    blob: bytes
    positions: np.ndarray


def grid_for(points: np.ndarray, step: float) -> tuple[np.ndarray, int]:
    """Origin and bit depth of a quantization grid with ``step`` covering ``points``."""
    lo = np.asarray(points, np.float64).min(axis=0)
    extent = float((np.asarray(points, np.float64).max(axis=0) - lo).max())
    return lo, quantization_bits(extent, step)


def encode_ordered(points: np.ndarray, step: float, origin: np.ndarray, bits: int,
                   compression_level: int = 10) -> OrderedBlob | None:
    """Draco sequential coding on a fixed grid; None if the decoded order does not match the input.

    A fixed grid (origin, step, bits) gives every point the same decoded position whichever other
    points share the blob, so a blob can be rebuilt without some clusters and the survivors' models
    stay valid.
    """
    import DracoPy

    points = np.asarray(points, dtype=np.float32)
    if len(points) == 0:
        return OrderedBlob(b"", np.zeros((0, 3), np.float32))
    blob = DracoPy.encode(points, quantization_bits=bits, compression_level=compression_level,
                          preserve_order=True, quantization_range=step * ((1 << bits) - 1),
                          quantization_origin=np.asarray(origin, np.float64).tolist())
    decoded = np.asarray(DracoPy.decode(blob).points, dtype=np.float32).reshape(-1, 3)
    if decoded.shape != points.shape:
        return None
    if np.abs(decoded.astype(np.float64) - points).max(initial=0.0) > 0.51 * step * 1.0001 + \
            1e-6 * float(np.abs(points).max(initial=0.0)):
        return None
    return OrderedBlob(blob, decoded)


@dataclass
class SetBlob:
    """A kd-tree Draco blob of a layer's positions as a set, and how its points map to the input."""

    blob: bytes
    positions: np.ndarray
    """(n, 3) float32 decoded positions, in the order a decoder returns them (the layer's order)."""
    order: np.ndarray
    """(n,) input rows in that order: decoded point i is input point ``order[i]``."""


def encode_as_set(points: np.ndarray, ordered: OrderedBlob, step: float, origin: np.ndarray,
                  bits: int, compression_level: int = 10) -> SetBlob | None:
    """Draco's kd-tree coding of the grid that ``ordered`` (the same points, sequential) uses.

    A layer's order is free ([R-58]): coding positions as a set spends no bits on their order, 14 %
    fewer bytes on real trained scenes at 14 bits. Both of Draco's modes quantize alike, so the
    decoded points are the sequential blob's decoded points in another order; pairing equal rows
    gives the exact permutation. Draco's kd-tree coder merges coincident inputs (not points that
    merely share a cell), so twins go in a few units in the last place apart (:func:`apart`); None
    when Draco merged points all the same or the two codings disagree.
    """
    import DracoPy

    points = np.asarray(points, dtype=np.float32)
    if len(points) == 0:
        return None
    blob = DracoPy.encode(apart(points), quantization_bits=bits, compression_level=compression_level,
                          preserve_order=False, quantization_range=step * ((1 << bits) - 1),
                          quantization_origin=np.asarray(origin, np.float64).tolist())
    decoded = np.asarray(DracoPy.decode(blob).points, dtype=np.float32).reshape(-1, 3)
    if decoded.shape != points.shape:
        return None
    by_row = np.lexsort(ordered.positions.T[::-1])
    by_decoded = np.lexsort(decoded.T[::-1])
    if not np.array_equal(ordered.positions[by_row], decoded[by_decoded]):
        return None
    order = np.empty(len(points), np.int64)
    order[by_decoded] = by_row
    return SetBlob(blob, decoded, order)


def apart(points: np.ndarray) -> np.ndarray:
    """``points`` (float32) with every repeat of a row moved along x by as many units in the last
    place as earlier copies it has: no two rows coincide, and each stays in its grid cell unless
    it sat on a cell's edge (then the pairing of :func:`encode_as_set` notices). Rows compare as
    their 12 bytes (one sort, no copy when nothing repeats: the common case)."""
    points = np.ascontiguousarray(points, dtype=np.float32)
    rows = points.view(np.dtype((np.void, 12))).ravel()
    order = np.argsort(rows, kind="stable")
    repeat = rows[order[1:]] == rows[order[:-1]]
    if not repeat.any():
        return points
    first = np.concatenate([[True], ~repeat])
    group_start = np.flatnonzero(first)[np.cumsum(first) - 1]
    copy = np.empty(len(points), np.int32)
    copy[order] = np.arange(len(points)) - group_start
    out = points.copy()
    x = out[:, 0].view(np.int32)
    x += copy  # adjacent binary32 values for finite x away from the largest
    return out
