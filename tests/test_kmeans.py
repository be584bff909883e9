"""Codebook training (encoder/kmeans.py): exact scalar k-means, sampled vector k-means, assignment."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import example, given
from hypothesis import strategies as st

from spcodec.encoder.kmeans import codebook_ladder, exhaustive_codebook, nearest, sampled_codebook


def distortion(groups: np.ndarray, weights: np.ndarray, entries: np.ndarray) -> float:
    book = entries.astype(np.float64)
    dist = ((groups[:, None, :] - book[None]) ** 2).sum(axis=2).min(axis=1)
    return float((weights * dist).sum() / weights.sum())


def mixture(n: int, dim: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Clustered points and heavy-tailed weights, like SH bands weighted by blend weights."""
    rng = np.random.default_rng(seed)
    centres = rng.normal(0, 1, (40, dim))
    points = centres[rng.integers(0, 40, n)] + rng.normal(0, 0.15, (n, dim))
    return points, rng.pareto(1.5, n) + 0.01


@given(st.integers(1, 600), st.integers(1, 256), st.integers(0, 2**31))
def test_scalar_codebooks_are_lloyd_fixed_points(n: int, size: int, seed: int) -> None:
    rng = np.random.default_rng(seed)
    values = rng.normal(0, 1, (n, 1)) * rng.choice([0.01, 1.0, 50.0])
    weights = rng.exponential(size=n)
    entries = sampled_codebook(values, weights, size, seed)
    assert entries.dtype == np.float16 and entries.shape[1] == 1 and 1 <= len(entries) <= size
    assert np.all(np.diff(entries[:, 0].astype(np.float64)) > 0)  # sorted, distinct
    distinct = np.unique(values.astype(np.float16))
    if len(distinct) <= size:  # few values: stored exactly
        np.testing.assert_array_equal(entries[:, 0], distinct)
        return
    # every entry is (to float16 precision) the weighted mean of the values nearest to it. Rounding
    # the converged entries to float16 moves the cell boundaries by up to half a float16 step,
    # which can move a value to the next cell: cells with a value that close to a boundary are
    # not held to the fixed point.
    book = entries[:, 0].astype(np.float64)
    cell = nearest(values, entries)
    mids = (book[1:] + book[:-1]) / 2.0
    step = np.spacing(np.abs(entries[:, 0])).astype(np.float64)
    near = np.abs(values[:, 0, None] - mids[None, :]) <= np.maximum(step[1:], step[:-1])[None, :]
    unsure = np.zeros(len(book), bool)
    for j in np.nonzero(near.any(axis=0))[0]:
        unsure[j] = unsure[j + 1] = True
    for k in np.unique(cell):
        if unsure[k]:
            continue
        mine = cell == k
        mean = np.average(values[mine, 0], weights=weights[mine])
        assert abs(mean - book[k]) <= 2e-3 * max(abs(mean), 1e-3) + 1e-7


def test_scalar_codebook_beats_scikit_learn() -> None:
    rng = np.random.default_rng(4)
    values = np.concatenate([rng.normal(-6, 0.5, 30000), rng.normal(-3, 1.0, 50000)])[:, None]
    weights = rng.pareto(1.5, len(values)) + 0.01
    ours = distortion(values, weights, sampled_codebook(values, weights, 256, 0))
    theirs = distortion(values, weights, exhaustive_codebook(values, weights, 256, 0))
    assert ours <= theirs * 1.01


@pytest.mark.parametrize("dim", [2, 9])
def test_vector_codebook_matches_exhaustive_k_means(dim: int) -> None:
    points, weights = mixture(20000, dim, seed=dim)
    ours = distortion(points, weights, sampled_codebook(points, weights, 64, 1, samples=8192))
    theirs = distortion(points, weights, exhaustive_codebook(points, weights, 64, 1))
    assert ours <= theirs * 1.05
    # and weight moves entries: with all weight on one half, that half is coded far better
    half = points[:, 0] > np.median(points[:, 0])
    heavy = sampled_codebook(points, np.where(half, 1.0, 1e-6), 64, 1, samples=8192)
    light = sampled_codebook(points, np.where(half, 1e-6, 1.0), 64, 1, samples=8192)
    ones = np.ones(half.sum())
    assert distortion(points[half], ones, heavy) < 0.5 * distortion(points[half], ones, light)


def test_few_distinct_vectors_are_kept_exactly_and_weights_may_vanish() -> None:
    rng = np.random.default_rng(0)
    table = rng.normal(0, 1, (200, 3)).astype(np.float16)
    groups = table[rng.integers(0, 200, 5000)].astype(np.float64)
    entries = sampled_codebook(groups, np.zeros(5000), 256, 0)  # all-zero weights: unweighted
    np.testing.assert_array_equal(entries, np.unique(table, axis=0))
    points, _ = mixture(3000, 4, seed=1)
    sparse = np.zeros(3000)
    sparse[:10] = 1.0  # weight on fewer groups than entries: a uniform sample fills in
    entries = sampled_codebook(points, sparse, 256, 0, samples=4096)
    assert len(entries) > 200
    with pytest.raises(ValueError, match="weights"):
        sampled_codebook(points, -np.ones(3000), 256, 0)


def test_sampled_codebook_is_deterministic_for_a_seed() -> None:
    points, weights = mixture(6000, 3, seed=2)
    a = sampled_codebook(points, weights, 128, 7, samples=4096)
    np.testing.assert_array_equal(a, sampled_codebook(points, weights, 128, 7, samples=4096))
    assert not np.array_equal(a, sampled_codebook(points, weights, 128, 8, samples=4096))


@given(st.integers(1, 4), st.integers(1, 256), st.integers(0, 2**31),
       st.sampled_from([0.01, 1.0, 100.0]), st.sampled_from([0.0, 1e3]))
def test_nearest_is_the_brute_force_nearest(dim: int, size: int, seed: int, spread: float,
                                            offset: float) -> None:
    rng = np.random.default_rng(seed)
    entries = (offset + spread * rng.normal(size=(size, dim))).astype(np.float16)
    groups = offset + spread * rng.normal(size=(300, dim))
    got = nearest(groups, entries)
    dist = ((groups[:, None, :] - entries.astype(np.float64)[None]) ** 2).sum(axis=2)
    chosen = dist[np.arange(len(groups)), got]
    if dim == 1:  # exact
        np.testing.assert_array_equal(chosen, dist.min(axis=1))
    else:  # float32 rounding relative to the spread may only swap near-ties
        np.testing.assert_allclose(chosen, dist.min(axis=1), rtol=1e-4,
                                   atol=1e-5 * spread ** 2 * dim)
    with pytest.raises(ValueError, match="uint8"):
        nearest(groups, np.zeros((257, dim)))


LADDER = (256, 128, 64, 32, 16, 8, 4)


@pytest.mark.parametrize("dim", [1, 3, 9])
def test_a_codebook_ladder_starts_from_the_trainers_own_largest_codebook(dim: int) -> None:
    """The largest codebook is sampled_codebook's (same draw, same seeding); scalar codebooks are
    its own at every size (the ladder only shares their sort)."""
    points, weights = mixture(12_000, dim, seed=dim)
    ladder = codebook_ladder(points, weights, LADDER, seed=3, samples=8192)
    np.testing.assert_array_equal(ladder[256], sampled_codebook(points, weights, 256, 3, samples=8192))
    if dim == 1:
        for size in LADDER:
            np.testing.assert_array_equal(ladder[size], sampled_codebook(points, weights, size, 3))


@pytest.mark.parametrize("dim", [3, 9])
def test_warm_started_smaller_codebooks_are_as_good_as_fresh_ones(dim: int) -> None:
    """Each smaller vector codebook, merged from the next larger and refined 10 iterations, has
    at most 8 % more weighted error than one trained from scratch at its size (k-means++ and 40
    iterations): the precision search prices every option by such codebooks."""
    points, weights = mixture(12_000, dim, seed=10 + dim)
    ladder = codebook_ladder(points, weights, LADDER, seed=5, samples=8192)
    for size in LADDER[1:]:
        fresh = sampled_codebook(points, weights, size, 5, samples=8192)
        ours, theirs = distortion(points, weights, ladder[size]), distortion(points, weights, fresh)
        assert ours <= theirs * 1.08, (size, ours, theirs)


@given(st.integers(1, 3000), st.sampled_from([1, 2, 3]),
       st.lists(st.integers(1, 256), min_size=1, max_size=5), st.integers(0, 2**31))
@example(3000, 1, [17], 1)  # -0.0 and +0.0 among rounded values: numpy's float16 sort misorders
def test_a_codebook_ladder_gives_each_size_at_most_that_many_distinct_entries(
        n: int, dim: int, sizes: list[int], seed: int) -> None:
    rng = np.random.default_rng(seed)
    points = np.round(rng.normal(0, 1, (n, dim)), int(rng.integers(0, 4)))  # few or many values
    weights = rng.exponential(size=n)
    ladder = codebook_ladder(points, weights, sizes, seed, samples=2048, init_samples=512)
    assert sorted(ladder) == sorted(set(sizes))
    distinct = np.unique(points.astype(np.float16), axis=0)
    for size, entries in ladder.items():
        assert entries.dtype == np.float16 and entries.shape[1] == dim
        assert 1 <= len(entries) <= size
        assert len(np.unique(entries, axis=0)) == len(entries)
        if len(distinct) <= size:  # few values: stored exactly
            np.testing.assert_array_equal(entries, distinct)


def test_a_codebook_ladder_is_deterministic_for_a_seed() -> None:
    points, weights = mixture(6000, 3, seed=2)
    a = codebook_ladder(points, weights, (64, 16, 4), 7, samples=4096)
    b = codebook_ladder(points, weights, (64, 16, 4), 7, samples=4096)
    assert all(np.array_equal(a[s], b[s]) for s in a)
    c = codebook_ladder(points, weights, (64, 16, 4), 8, samples=4096)
    assert not all(np.array_equal(a[s], c[s]) for s in a)
