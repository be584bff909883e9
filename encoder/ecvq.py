"""Entropy-constrained assignment of codebook indices (ECVQ; Chou, Lookabaugh and Gray, 1989).

Nearest-entry assignment ignores that entries differ in what their index costs: the writer
Huffman-codes each index column, so a frequent entry's index takes fewer bits. ECVQ assigns each
group ``x_i`` (weight ``w_i``) to ``argmin_k w_i |x_i - c_k|^2 + bit_cost * L_k``, where ``L_k`` is
entry ``k``'s code length in bits (``-log2 p_k`` of the current histogram), then re-estimates the
lengths and moves each entry to the weighted mean of its groups, in turn. Each step lowers the
Lagrangian (weighted error + ``bit_cost`` * index bits), so the histogram grows more skewed and
the Huffman code shorter, for the error the cost allows. No format change: the same codebooks and
index columns, only other indices.

``bit_cost`` is in units of the weighted squared error one index bit is worth. The precision
search (:mod:`.allocation`) measures each codebook option again with ECVQ at a few such costs
(``AllocationConfig.ecvq_strengths``), priced in bytes and predicted image MSE like every other
option, so its one Lagrange multiplier chooses both the codebooks' shapes and the assignment.

An entry fixed at exact zero (``keep``) is how a Gaussian drops an SH band: a Gaussian whose
view dependence does not pay for its bits lands on that (frequent, so cheap) entry, which a
decoder looks up like any other.
"""

from __future__ import annotations

import numpy as np

from .kmeans import nearest

_CHUNK = 4096
"""Rows per cost block: 4096 x 256 float64 costs stay within a few megabytes."""


def code_lengths(indices: np.ndarray, size: int) -> np.ndarray:
    """Bits (size,) of each entry's index under an ideal code for the histogram of ``indices``:
    ``-log2 p``. An unused entry counts half a use, so it costs more than any used entry but
    stays finite (ECVQ may still move a group there when its error saves enough)."""
    counts = np.bincount(np.asarray(indices).ravel(), minlength=size)[:size].astype(np.float64)
    total = max(float(counts.sum()), 1.0)
    return np.log2(total / np.maximum(counts, 0.5))


def lagrangian(groups: np.ndarray, entries: np.ndarray, weights: np.ndarray, indices: np.ndarray,
               bit_cost: float, lengths: np.ndarray) -> float:
    """Sum over groups of ``w |x - c|^2 + bit_cost * L``: what :func:`ecvq_assign` minimizes."""
    groups = np.asarray(groups, np.float64)
    chosen = np.asarray(entries, np.float64)[indices]
    error = (np.asarray(weights, np.float64) * ((groups - chosen) ** 2).sum(axis=1)).sum()
    return float(error + bit_cost * np.asarray(lengths, np.float64)[indices].sum())


def ecvq_assign(groups: np.ndarray, entries: np.ndarray, weights: np.ndarray, bit_cost: float,
                lengths: np.ndarray) -> np.ndarray:
    """Index (uint8) per row of ``groups`` (m, dim) minimizing ``w |x - c_k|^2 + bit_cost * L_k``
    over the ``entries`` (<= 256 rows); ``bit_cost`` 0 is :func:`nearest` itself."""
    if bit_cost < 0 or not np.isfinite(bit_cost):
        raise ValueError(f"bit_cost must be finite and >= 0, got {bit_cost}")
    if bit_cost == 0:
        return nearest(groups, entries)
    if len(entries) > 256:
        raise ValueError(f"{len(entries)} entries do not fit uint8 indices")
    book = np.asarray(entries, np.float64)
    origin = book.mean(axis=0)  # errors relative to the entries' spread, not their magnitude
    book = book - origin
    book_t = np.ascontiguousarray(book.T)
    book_sq = (book ** 2).sum(axis=1)
    rate = bit_cost * np.asarray(lengths, np.float64)
    values = np.asarray(groups, np.float64)
    w = np.asarray(weights, np.float64)
    out = np.empty(len(values), np.uint8)
    for start in range(0, len(values), _CHUNK):
        block = values[start:start + _CHUNK] - origin
        dist = book_sq - 2.0 * (block @ book_t) + (block ** 2).sum(axis=1, keepdims=True)
        np.maximum(dist, 0.0, out=dist)
        dist *= w[start:start + _CHUNK, None]
        dist += rate
        out[start:start + _CHUNK] = dist.argmin(axis=1)
    return out


def weighted_centroids(groups: np.ndarray, weights: np.ndarray, indices: np.ndarray,
                       entries: np.ndarray, keep: np.ndarray | None = None) -> np.ndarray:
    """Each entry moved to the weighted mean of its groups, as float16; entries with no weight
    and those flagged in ``keep`` (size,) stay where they are."""
    entries = np.asarray(entries)
    size, dim = entries.shape
    idx = np.asarray(indices, np.int64)
    w = np.asarray(weights, np.float64)
    mass = np.bincount(idx, weights=w, minlength=size)
    sums = np.stack([np.bincount(idx, weights=w * groups[:, j], minlength=size)
                     for j in range(dim)], axis=1)
    moved = entries.astype(np.float64).copy()
    free = mass > 0
    if keep is not None:
        free &= ~keep
    moved[free] = sums[free] / mass[free, None]
    return moved.astype(np.float16)


def ecvq_refine(groups: np.ndarray, entries: np.ndarray, weights: np.ndarray | None,
                bit_cost: float, iterations: int, keep: np.ndarray | None = None
                ) -> tuple[np.ndarray, np.ndarray]:
    """(entries, indices) after ``iterations`` rounds of code lengths, ECVQ assignment and
    centroids, starting from nearest assignment to ``entries``; ends on an assignment, so the
    indices match the entries returned. Deterministic (no randomness)."""
    groups = np.asarray(groups, np.float64)
    w = np.ones(len(groups)) if weights is None else np.asarray(weights, np.float64)
    entries = np.asarray(entries, np.float16)
    indices = nearest(groups, entries)
    if bit_cost == 0 or len(groups) == 0:
        return entries, indices
    for _ in range(iterations):
        lengths = code_lengths(indices, len(entries))
        indices = ecvq_assign(groups, entries, w, bit_cost, lengths)
        entries = weighted_centroids(groups, w, indices, entries, keep)
    lengths = code_lengths(indices, len(entries))
    return entries, ecvq_assign(groups, entries, w, bit_cost, lengths)


def with_zero_entry(entries: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``entries`` with an exact zero row (the one nearest zero replaced by it when all 256 are
    used and none is zero), and a mask (size,) flagging it."""
    entries = np.asarray(entries, np.float16)
    zero = ~entries.any(axis=1)
    if zero.any():
        return entries, zero
    if len(entries) < 256:
        entries = np.concatenate([entries, np.zeros((1, entries.shape[1]), np.float16)])
    else:
        entries = entries.copy()
        entries[int(np.argmin((entries.astype(np.float64) ** 2).sum(axis=1)))] = 0
    return entries, ~entries.any(axis=1)
