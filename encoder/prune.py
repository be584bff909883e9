"""Which patch Gaussians survive pruning: a uniform random sample (the paper's), the most
important by blend weight (LightGaussian, Reduced-3DGS), or a sample drawn in proportion to blend
weight, between the two: the large Gaussians a picture rests on are nearly always kept, and a
share of the small ones that carry fine texture survives with them, which ranking drops first.

All three keep ``round(n / factor)`` Gaussians (at least one when there are any), returned as sorted
indices so the survivors keep their input order.
"""

from __future__ import annotations

import numpy as np

from .config import PruneMethod


def kept_count(n: int, factor: float) -> int:
    """Survivors of a downsample by ``factor`` (>= 1)."""
    if factor < 1:
        raise ValueError(f"downsample factor must be >= 1, got {factor}")
    return 0 if n == 0 else max(1, int(round(n / factor)))


def prune_uniform(n: int, keep: int, seed: int) -> np.ndarray:
    """``keep`` of ``n`` indices drawn uniformly without replacement (seeded), sorted."""
    rng = np.random.default_rng([seed, 0x5EED])
    return np.sort(rng.choice(n, size=min(keep, n), replace=False)).astype(np.int64)


def prune_by_importance(weights: np.ndarray, keep: int) -> np.ndarray:
    """Indices of the ``keep`` largest weights (ties by index), sorted."""
    order = np.argsort(-np.asarray(weights, np.float64), kind="stable")
    return np.sort(order[:keep]).astype(np.int64)


def prune_sampled(weights: np.ndarray, keep: int, seed: int) -> np.ndarray:
    """``keep`` indices drawn without replacement with probability proportional to ``weights``
    (seeded; Gumbel top-k: the ``keep`` largest of log weight plus Gumbel noise), sorted. Zero
    weights come last, in random order."""
    w = np.asarray(weights, np.float64)
    rng = np.random.default_rng([seed, 0x5A3D])
    gumbel = -np.log(-np.log(rng.uniform(np.finfo(np.float64).tiny, 1.0, len(w))))
    keys = np.where(w > 0, np.log(np.where(w > 0, w, 1.0)) + gumbel, -np.inf)
    order = np.lexsort((gumbel, keys))[::-1]  # largest key first; zero weights by their noise
    return np.sort(order[:keep]).astype(np.int64)


def select(method: PruneMethod, n: int, keep: int, seed: int,
           weights: np.ndarray | None = None) -> np.ndarray:
    """The survivors by ``method`` (weights are required for "importance" and "sampled")."""
    if method not in ("importance", "sampled", "uniform"):
        raise ValueError(f"unknown prune method {method!r}: use 'importance', 'sampled' or "
                         "'uniform'")
    if method == "uniform":
        return prune_uniform(n, keep, seed)
    if weights is None:
        raise ValueError(f"{method} pruning needs blend weights")
    if method == "sampled":
        return prune_sampled(weights, keep, seed)
    return prune_by_importance(weights, keep)
