"""Codebook training for patch attributes: weighted k-means fast enough to run in every encode.

A codebook holds at most 256 float16 entries; k-means places them where the (weighted) groups of an
attribute lie. Scikit-learn's k-means with k-means++ on 200,000 samples took 10 of 13.5 s of a
no-retrain encode of fourth_st, half of it in the k-means++ seeding. Two changes make it cheap
without making the codebooks worse:

* **Scalar codebooks** (entry dimension 1: scales per axis, opacity) are solved exactly in one
  dimension: with the values sorted once, a Lloyd iteration is ``k`` binary searches for the
  midpoints between entries and prefix-sum differences for the weighted means, O(k log n), so
  it runs to convergence on every value with no sampling. It starts from greedy k-means++ on the
  distinct float16 values (with their summed weights).
* **Vector codebooks** train on a sample of ``samples`` draws made in proportion to the weights,
  each drawn group weighted by how often it was drawn. Its unweighted objective estimates the
  weighted objective over every group without bias, and the few heavy groups that dominate that
  objective are always in it (a uniform sample of the same size misses them and ends 2-5 %
  worse). k-means++ seeds on a sub-sample of ``init_samples``; scikit-learn's Lloyd iterations
  (compiled, threaded) finish on the whole sample.

An attribute with at most ``size`` distinct float16 values (scenes decoded from 8-bit formats
such as SPZ) keeps them exactly. :func:`exhaustive_codebook` is the previous trainer, kept for
comparisons (``bench/bench_encode.py --kmeans exhaustive``).
"""

from __future__ import annotations

from typing import Iterable

import numpy as np

_ASSIGN_CHUNK = 4096
"""Rows per distance block in :func:`nearest`: 4096 x 256 float32 distances stay in cache."""


def nearest(groups: np.ndarray, entries: np.ndarray) -> np.ndarray:
    """Index (uint8) of the nearest of ``entries`` (<= 256 rows) for each row of ``groups``.

    One dimension: binary search among the midpoints of the sorted entries (exact). More: squared
    distances expanded as ``|e|^2 - 2 g.e`` in float32 BLAS, after moving the origin to the mean
    entry so the rounding error is relative to the spread of the values, not their magnitude;
    only entries equally near to within that rounding can swap.
    """
    if len(entries) > 256:
        raise ValueError(f"{len(entries)} entries do not fit uint8 indices")
    book = np.asarray(entries, np.float64)
    values = np.asarray(groups)
    if book.shape[1] == 1:
        order = np.argsort(book[:, 0], kind="stable")
        sorted_book = book[order, 0]
        cut = np.searchsorted((sorted_book[1:] + sorted_book[:-1]) / 2.0, values[:, 0])
        return order[cut].astype(np.uint8)
    origin = book.mean(axis=0)
    book = book - origin
    book_t = np.ascontiguousarray(book.T, np.float32)
    book_sq = (book ** 2).sum(axis=1).astype(np.float32)
    out = np.empty(len(values), np.uint8)
    for start in range(0, len(values), _ASSIGN_CHUNK):
        block = (values[start:start + _ASSIGN_CHUNK] - origin).astype(np.float32)
        dist = block @ book_t
        dist *= -2.0
        dist += book_sq
        out[start:start + _ASSIGN_CHUNK] = dist.argmin(axis=1)
    return out


def sampled_codebook(groups: np.ndarray, weights: np.ndarray | None, size: int, seed: int,
                   samples: int = 65_536, init_samples: int = 8192, iterations: int = 40
                   ) -> np.ndarray:
    """At most ``size`` float16 entries (rows, sorted and distinct) for ``groups`` (m, dim).

    ``weights`` (m,) >= 0 weight each group (None: all 1). Deterministic for a given seed.
    """
    groups = np.asarray(groups, np.float64)
    weights = _check_weights(weights, len(groups))
    distinct = _distinct_rows(groups.astype(np.float16), size)
    if distinct is not None:
        return distinct
    rng = np.random.default_rng(seed)
    if groups.shape[1] == 1:
        return _unique_rows(_kmeans_1d(groups[:, 0], weights, size, rng)[:, None])
    return _unique_rows(_kmeans_sampled(groups, weights, size, rng, samples, init_samples,
                                        iterations, seed))


def codebook_ladder(groups: np.ndarray, weights: np.ndarray | None, sizes: Iterable[int],
                    seed: int, samples: int = 65_536, init_samples: int = 8192,
                    iterations: int = 40, refine_iterations: int = 10) -> dict[int, np.ndarray]:
    """Codebooks of each of ``sizes`` entries for the same ``groups``: {size: entries}.

    The precision search wants one attribute at many sizes (256 down to 4). Training each vector
    codebook from scratch repeats the draw, the k-means++ seeding and up to 40 Lloyd iterations
    per size. Here one sample is drawn; the largest codebook is exactly
    :func:`sampled_codebook`'s, and each smaller one of at least :data:`WARM_START` entries
    starts from the largest merged: its entries, weighted by the sample mass they hold,
    clustered to the smaller size (a problem of at most 256 points), then ``refine_iterations``
    Lloyd iterations on the sample. Merged seeds already sit where the mass is, so few
    iterations reach the error of a fresh start (within a few per cent either way). Smaller
    ones start fresh on the same sample, and scalar codebooks are :func:`sampled_codebook`'s
    own with one sort shared (merged seeds trap the exact 1-D Lloyd in worse optima than its
    greedy seeding). Deterministic for a seed.
    """
    groups = np.asarray(groups, np.float64)
    weights = _check_weights(weights, len(groups))
    order = sorted({int(s) for s in sizes}, reverse=True)
    if not order:
        return {}
    if order[-1] < 1:
        raise ValueError(f"codebook sizes must be >= 1, got {order[-1]}")
    out: dict[int, np.ndarray] = {}
    distinct = _distinct_rows(groups.astype(np.float16), order[0])
    if distinct is not None:
        out.update({s: distinct for s in order if s >= len(distinct)})
        order = [s for s in order if s < len(distinct)]
        if not order:
            return out
    if groups.shape[1] == 1:
        scalar = _Sorted1d(groups[:, 0], weights)
        for size in order:
            seeds = _greedy_seeds_1d(scalar.distinct, scalar.mass, size, np.random.default_rng(seed))
            out[size] = _unique_rows(scalar.lloyd(seeds)[:, None])
        return out
    trainer = _LadderSampled(groups, weights, np.random.default_rng(seed), samples)
    largest = trainer.first(order[0], init_samples, iterations, seed)
    out[order[0]] = _unique_rows(largest)
    for size in order[1:]:
        centres = trainer.smaller(largest, size, refine_iterations, seed) if size >= WARM_START \
            else trainer.fresh(size, init_samples, iterations, seed)
        out[size] = _unique_rows(centres)
    return out


WARM_START = 64
"""Smallest vector codebook :func:`codebook_ladder` warm-starts: below it a fresh start costs
little (k-means++ and Lloyd scale with the entries), and merged seeds of a few entries fell into
optima up to 14 % worse than k-means++'s on a 40-cluster mixture, at 8 and at 32 entries."""


class _Sorted1d:
    """Scalar values sorted once, with the prefix sums every 1-D Lloyd iteration reads."""

    def __init__(self, values: np.ndarray, weights: np.ndarray) -> None:
        self.distinct, inverse = np.unique(values.astype(np.float16).astype(np.float64),
                                           return_inverse=True)
        self.mass = np.bincount(inverse.ravel(), weights=weights, minlength=len(self.distinct))
        order = np.argsort(values, kind="stable")
        self.x = values[order]
        w = weights[order]
        self.cum_w = np.concatenate([[0.0], np.cumsum(w)])
        self.cum_wx = np.concatenate([[0.0], np.cumsum(w * self.x)])

    def lloyd(self, seeds: np.ndarray) -> np.ndarray:
        return _lloyd_1d(np.sort(seeds), self.x, self.cum_w, self.cum_wx)


class _LadderSampled:
    """Vector codebooks of one weight-proportional sample (drawn once, as
    :func:`_kmeans_sampled` draws it)."""

    def __init__(self, groups: np.ndarray, weights: np.ndarray, rng: np.random.Generator,
                 samples: int) -> None:
        self.groups, self.weights, self.rng, self.samples = groups, weights, rng, samples
        self.points: np.ndarray | None = None

    def first(self, k: int, init_samples: int, iterations: int, seed: int) -> np.ndarray:
        """``k`` centres as :func:`_kmeans_sampled` trains them, keeping its sample."""
        self.points, self.mass = _weighted_sample(self.groups, self.weights, k, self.rng,
                                                  self.samples)
        return self.fresh(k, init_samples, iterations, seed)

    def fresh(self, k: int, init_samples: int, iterations: int, seed: int) -> np.ndarray:
        """``k`` centres trained from k-means++ seeds on the same sample."""
        if len(self.points) <= k:
            return self.points
        return _kmeans_plusplus_fit(self.points, self.mass, k, self.rng, init_samples,
                                    iterations, seed)

    def smaller(self, centres: np.ndarray, size: int, iterations: int, seed: int) -> np.ndarray:
        """``size`` centres from ``centres`` merged by the sample mass each holds, then
        ``iterations`` Lloyd iterations on the sample."""
        from sklearn.cluster import KMeans

        if len(self.points) <= size:
            return self.points
        held = np.bincount(nearest(self.points, centres), weights=self.mass,
                           minlength=len(centres))
        seeds = _merge(centres, held, size, seed)
        km = KMeans(n_clusters=len(seeds), init=seeds, n_init=1, max_iter=iterations,
                    random_state=seed)
        km.fit(self.points, sample_weight=self.mass)
        return km.cluster_centers_


def _merge(centres: np.ndarray, mass: np.ndarray, size: int, seed: int) -> np.ndarray:
    """At most ``size`` seeds from ``centres`` (m, dim) weighted by ``mass``: weighted k-means
    of the centres themselves (entries that hold no mass are dropped first)."""
    from sklearn.cluster import KMeans, kmeans_plusplus
    from threadpoolctl import threadpool_limits

    held = mass > 0
    centres, mass = np.asarray(centres, np.float64)[held], mass[held]
    if len(centres) <= size:
        return centres
    with threadpool_limits(limits=1, user_api="blas"):
        init, _ = kmeans_plusplus(centres, size, sample_weight=mass, random_state=seed)
    km = KMeans(n_clusters=size, init=init, n_init=1, max_iter=100, random_state=seed)
    km.fit(centres, sample_weight=mass)
    return km.cluster_centers_


def exhaustive_codebook(groups: np.ndarray, weights: np.ndarray | None, size: int, seed: int,
                        samples: int = 200_000, iterations: int = 60) -> np.ndarray:
    """The previous trainer: scikit-learn k-means (greedy k-means++) on up to ``samples`` groups
    drawn uniformly, weighted; 5-20x slower than :func:`sampled_codebook`, for comparisons."""
    from sklearn.cluster import KMeans

    weights = None if weights is None else np.asarray(weights, np.float64)
    rng = np.random.default_rng(seed)
    if len(groups) > samples:
        pick = np.sort(rng.choice(len(groups), samples, replace=False))
        groups, weights = groups[pick], None if weights is None else weights[pick]
    distinct = np.unique(groups.astype(np.float16), axis=0)
    if len(distinct) <= size:
        return distinct
    km = KMeans(n_clusters=size, n_init=1, max_iter=iterations, random_state=seed)
    km.fit(groups, sample_weight=weights)
    return np.unique(km.cluster_centers_.astype(np.float16), axis=0)


def _check_weights(weights: np.ndarray | None, m: int) -> np.ndarray:
    if weights is None:
        return np.ones(m)
    weights = np.asarray(weights, np.float64)
    if weights.shape != (m,) or not np.isfinite(weights).all() or (weights < 0).any():
        raise ValueError(f"weights must be {m} finite values >= 0")
    return weights if weights.sum() > 0 else np.ones(m)


def _distinct_rows(rows: np.ndarray, limit: int) -> np.ndarray | None:
    """The sorted distinct rows of a float16 array if there are at most ``limit``, else None
    (a prefix is checked first, so the common case costs little)."""
    if len(_unique_rows(rows[:4 * limit + 1])) > limit:
        return None
    distinct = _unique_rows(rows)
    return distinct if len(distinct) <= limit else None


def _unique_rows(rows: np.ndarray) -> np.ndarray:
    """Distinct float16 rows in ascending lexicographic order (as ``np.unique(axis=0)``).

    Zeros are made positive first: numpy 2.4's float16 sort leaves -0.0 interleaved with the
    negatives when +0.0 is also present, so the 1-D unique kept repeats (a hypothesis test of
    the ladder found it: -1, -0, -1, -0 ...); the two zeros decode alike."""
    rows = np.asarray(rows).astype(np.float16) + np.float16(0.0)
    if rows.shape[1] == 1:  # the 1-D sort is several times faster than the row-wise one
        return np.unique(rows[:, 0])[:, None]
    return np.unique(rows, axis=0)


def _kmeans_1d(values: np.ndarray, weights: np.ndarray, k: int, rng: np.random.Generator
               ) -> np.ndarray:
    """Weighted Lloyd iterations in one dimension to convergence (see the module docstring)."""
    scalar = _Sorted1d(values, weights)
    return scalar.lloyd(_greedy_seeds_1d(scalar.distinct, scalar.mass, k, rng))


def _lloyd_1d(centres: np.ndarray, x: np.ndarray, cum_w: np.ndarray, cum_wx: np.ndarray
              ) -> np.ndarray:
    """Weighted Lloyd iterations from sorted ``centres`` over sorted values ``x`` (with the
    prefix sums of their weights and weighted values) until no centre moves."""
    for _ in range(1000):  # converges in tens of iterations; the bound only guards against cycles
        cuts = np.searchsorted(x, (centres[1:] + centres[:-1]) / 2.0)
        lo, hi = np.concatenate([[0], cuts]), np.concatenate([cuts, [len(x)]])
        mass_in = cum_w[hi] - cum_w[lo]
        moved = centres.copy()
        full = mass_in > 0
        moved[full] = (cum_wx[hi] - cum_wx[lo])[full] / mass_in[full]
        if np.array_equal(moved, centres):
            break
        centres = moved
    return centres


def _greedy_seeds_1d(points: np.ndarray, mass: np.ndarray, k: int, rng: np.random.Generator,
                     trials: int = 8) -> np.ndarray:
    """Greedy k-means++ seeds among ``points`` (1-D, with masses): each new seed is the best of
    ``trials`` candidates drawn in proportion to mass times squared distance to the seeds."""
    seeds = [points[rng.choice(len(points), p=mass / mass.sum())]]
    dist = (points - seeds[0]) ** 2
    for _ in range(1, min(k, len(points))):
        cum = np.cumsum(dist * mass)
        if cum[-1] <= 0:
            break
        cand = np.minimum(np.searchsorted(cum, rng.uniform(0.0, cum[-1], trials)), len(points) - 1)
        trial = np.minimum(dist[None, :], (points[None, :] - points[cand][:, None]) ** 2)
        best = int(np.argmin(trial @ mass))
        seeds.append(points[cand[best]])
        dist = trial[best]
    return np.array(seeds)


def _kmeans_sampled(groups: np.ndarray, weights: np.ndarray, k: int, rng: np.random.Generator,
                    samples: int, init_samples: int, iterations: int, seed: int) -> np.ndarray:
    """k-means on a weight-proportional sample (see the module docstring)."""
    points, mass = _weighted_sample(groups, weights, k, rng, samples)
    return points if len(points) <= k else \
        _kmeans_plusplus_fit(points, mass, k, rng, init_samples, iterations, seed)


def _weighted_sample(groups: np.ndarray, weights: np.ndarray, k: int, rng: np.random.Generator,
                     samples: int) -> tuple[np.ndarray, np.ndarray]:
    """``samples`` draws in proportion to weight, as (distinct groups drawn, times drawn)."""
    drawn = rng.choice(len(groups), samples, replace=True, p=weights / weights.sum())
    rows, counts = np.unique(drawn, return_counts=True)
    if len(rows) < 4 * k:  # weight on too few groups to place k entries: add a uniform sample
        extra = rng.choice(len(groups), min(len(groups), samples), replace=False)
        rows = np.unique(np.concatenate([rows, extra]))
        counts = np.bincount(drawn, minlength=len(groups))[rows] + 1.0
    return groups[rows], counts.astype(np.float64)


def _kmeans_plusplus_fit(points: np.ndarray, mass: np.ndarray, k: int, rng: np.random.Generator,
                         init_samples: int, iterations: int, seed: int) -> np.ndarray:
    """``k`` centres of weighted ``points``: k-means++ seeds from a subsample, then Lloyd."""
    from sklearn.cluster import KMeans, kmeans_plusplus
    from threadpoolctl import threadpool_limits

    sub = np.sort(rng.choice(len(points), min(init_samples, len(points)), replace=False))
    with threadpool_limits(limits=1, user_api="blas"):  # its many small products: threads stall
        init, _ = kmeans_plusplus(points[sub], k, sample_weight=mass[sub], random_state=seed)
    km = KMeans(n_clusters=k, init=init, n_init=1, max_iter=iterations, random_state=seed)
    km.fit(points, sample_weight=mass)
    return km.cluster_centers_
