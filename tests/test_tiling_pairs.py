"""The fast pairing of a tileset's coarse levels against plain references: the pair cost against
the divergence written out per pair in float64, the stepwise greedy pairing against the
one-pair-at-a-time walk, the sorted merge sums against ``np.add.at``."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from spcodec.cloud import GaussianCloud
from spcodec.tiling.grouping import NEIGHBOURS, candidate_pairs, greedy_pairs, pair_round
from spcodec.tiling.merge import merge_groups, merge_pairs, quat_to_matrix, weights
from spcodec.tiling.pair_cost import APPEARANCE_COST, THINNEST, pair_costs

LOG_2PI = np.log(2.0 * np.pi)


def reference_cost(cloud: GaussianCloud, i: int, j: int) -> float:
    """The merge cost of one pair, from its definition, in float64: KL(mixture || merged) with
    ``E[log mixture]`` at each component's six sigma points, plus the weighted colour distance."""
    rot = quat_to_matrix(cloud.quats[[i, j]])
    var = np.exp(2.0 * cloud.scales[[i, j]].astype(np.float64))
    var = np.maximum(var, THINNEST ** 2 * var.max(axis=1, keepdims=True))
    cov = [rot[k] @ np.diag(var[k]) @ rot[k].T for k in range(2)]
    mu = cloud.means[[i, j]].astype(np.float64)
    w = weights(cloud)[[i, j]]
    p = np.clip(w[0] / (w[0] + w[1]), 1e-6, 1 - 1e-6)
    share = (p, 1 - p)
    d = mu[0] - mu[1]
    merged = p * cov[0] + (1 - p) * cov[1] + p * (1 - p) * np.outer(d, d)
    entropy = 0.5 * (3 * LOG_2PI + np.linalg.slogdet(merged)[1] + 3)

    def log_density(k: int, x: np.ndarray) -> float:
        off = x - mu[k]
        return -0.5 * (3 * LOG_2PI + np.linalg.slogdet(cov[k])[1] + off @ np.linalg.solve(cov[k], off))

    mixture_log = 0.0
    for k in range(2):
        points = [mu[k] + s * np.sqrt(3 * var[k][a]) * rot[k][:, a] for a in range(3) for s in (1, -1)]
        mixture_log += share[k] * np.mean([np.logaddexp(np.log(share[0]) + log_density(0, x),
                                                        np.log(share[1]) + log_density(1, x))
                                           for x in points])
    colour = np.concatenate([cloud.sh_dc.reshape(len(cloud), -1), cloud.sh_rest.reshape(len(cloud), -1)], 1)
    return mixture_log + entropy + APPEARANCE_COST * float(((colour[i] - colour[j]) ** 2).sum())


def random_cloud(rng: np.random.Generator, n: int, spread: float) -> GaussianCloud:
    return GaussianCloud(means=rng.normal(0, spread, (n, 3)), scales=rng.uniform(-5, -1, (n, 3)),
                         quats=rng.normal(size=(n, 4)), opacities=rng.normal(0, 2, n),
                         sh_dc=rng.normal(0, 0.5, (n, 3)), sh_rest=rng.normal(0, 0.1, (n, 3, 3)))


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2 ** 16), spread=st.sampled_from([0.01, 0.1, 0.3]),
       shift=st.floats(-100, 100), log_units=st.floats(-3, 3))
def test_pair_cost_equals_its_definition_in_float64(seed, spread, shift, log_units):
    """Every candidate pair of random Gaussians (crossed, flat, far apart for their size),
    anywhere and in any units: the float32 block computation within float32's rounding of the
    float64 definition (costs here are 0.01-100 nats)."""
    rng = np.random.default_rng(seed)
    cloud = random_cloud(rng, 30, spread)
    factor = float(np.exp(log_units))
    cloud = GaussianCloud(means=factor * cloud.means + shift, scales=cloud.scales + log_units,
                          quats=cloud.quats, opacities=cloud.opacities, sh_dc=cloud.sh_dc,
                          sh_rest=cloud.sh_rest)
    i, j = candidate_pairs(cloud.means.astype(np.float32))
    fast = pair_costs(cloud, i, j)
    want = np.array([reference_cost(cloud, a, b) for a, b in zip(i, j)])
    # the centres are float32: a shift of 100 leaves ~1e-5 of them, relative to spreads of 0.01
    rounding = 1e-5 * (1 + abs(shift)) / (spread * factor)
    np.testing.assert_allclose(fast, want, rtol=2e-3, atol=2e-3 + 50 * rounding)


def walk(i: np.ndarray, j: np.ndarray, cost: np.ndarray, n: int, limit: int) -> np.ndarray:
    """The greedy pairing one pair at a time: cheapest first, ties in list order."""
    used = np.zeros(n, bool)
    out = []
    for k in np.argsort(cost, kind="stable"):
        if len(out) >= limit:
            break
        if not (used[i[k]] or used[j[k]]):
            used[i[k]] = used[j[k]] = True
            out.append(k)
    return np.array(out, dtype=np.int64)


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2 ** 16), n=st.integers(2, 400), levels=st.sampled_from([3, 50, 0]),
       share=st.floats(0.05, 1.0), steps=st.booleans())
def test_greedy_pairs_is_the_one_at_a_time_walk(seed, n, levels, share, steps):
    """Random graphs, costs with many ties (a few levels) or none, any limit; with the stepwise
    part on (the walk taking over below 0 pairs) and off (the walk doing everything)."""
    rng = np.random.default_rng(seed)
    m = int(rng.integers(1, 6 * n))
    a, b = rng.integers(0, n, m), rng.integers(0, n, m)
    keep = a != b
    i, j = np.minimum(a, b)[keep], np.maximum(a, b)[keep]
    cost = rng.integers(0, levels, len(i)).astype(float) if levels else rng.random(len(i))
    limit = max(1, int(share * n / 2))
    got = greedy_pairs(i, j, cost, n, limit, walk_below=0 if steps else 10 ** 9)
    np.testing.assert_array_equal(got, walk(i, j, cost, n, limit))


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2 ** 16), n=st.integers(1, 300), groups=st.integers(1, 300))
def test_merge_sums_equal_np_add_at(seed, n, groups):
    """The sorted, run-by-run sums of the merge add in the order ``np.add.at`` does: the same
    merged means and colours to the last bit."""
    rng = np.random.default_rng(seed)
    cloud = random_cloud(rng, n, 0.3)
    count = min(groups, n)
    labels = np.concatenate([np.arange(count), rng.integers(0, count, n - count)])
    rng.shuffle(labels)
    w = weights(cloud)
    share = w / np.bincount(labels, w, count)[labels]
    want = np.zeros((count, 3))
    np.add.at(want, labels, cloud.means.astype(np.float64) * share[:, None])
    merged = merge_groups(cloud, labels, count).cloud
    np.testing.assert_array_equal(merged.means, want.astype(merged.means.dtype))  # the cloud keeps float32
    rest = np.zeros((count, 9))
    np.add.at(rest, labels, cloud.sh_rest.reshape(n, 9).astype(np.float64) * share[:, None])
    np.testing.assert_array_equal(merged.sh_rest.reshape(count, 9), rest.astype(merged.sh_rest.dtype))


def test_merge_rejects_labels_that_leave_a_group_empty():
    cloud = random_cloud(np.random.default_rng(0), 4, 0.3)
    with pytest.raises(ValueError, match="every group"):
        merge_groups(cloud, np.array([0, 0, 2, 2]), 3)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2 ** 16), n=st.integers(2, 400), copies=st.integers(0, 3))
def test_candidate_pairs_are_every_neighbour_pair_once_in_order(seed, n, copies):
    """Against the plain construction: each Gaussian's nearest (queried in input order), every
    ``(min, max)`` key sorted and each kept once; clouds with repeated centres included, where
    a Gaussian need not be first in its own list."""
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(seed)
    means = rng.normal(0, 1, (n, 3)).astype(np.float32)
    for _ in range(copies):
        means[rng.integers(0, n, n // 3)] = means[rng.integers(0, n, n // 3)]
    k = min(NEIGHBOURS + 1, n)
    near = np.asarray(cKDTree(means).query(means, k=k)[1]).reshape(n, k)
    pairs = {(min(a, int(b)), max(a, int(b))) for a in range(n) for b in near[a] if b != a and b < n}
    want = np.array(sorted(pairs), dtype=np.int64).reshape(-1, 2)
    i, j = candidate_pairs(means)
    np.testing.assert_array_equal(np.stack([i, j], axis=1), want)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2 ** 16), n=st.integers(2, 300), share=st.floats(0.0, 1.0))
def test_merge_pairs_is_merge_groups_to_the_last_bit(seed, n, share):
    """Disjoint pairs and singles, as a pairing round makes them: the pair merge gives the
    general merge's Gaussians exactly (a round's level feeds the next round's costs)."""
    rng = np.random.default_rng(seed)
    cloud = random_cloud(rng, n, 0.3)
    order = rng.permutation(n)
    pairs = int(share * (n // 2))
    a, b = order[:pairs], order[pairs:2 * pairs]
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    alone = np.ones(n, bool)
    alone[hi] = False
    first = np.flatnonzero(alone)
    group = np.cumsum(alone) - 1
    labels = group.copy()
    labels[hi] = group[lo]
    second = np.full(len(first), -1, np.int64)
    second[group[lo]] = hi
    got, want = merge_pairs(cloud, first, second), merge_groups(cloud, labels, len(first)).cloud
    for name in ("means", "scales", "quats", "opacities", "sh_dc", "sh_rest"):
        np.testing.assert_array_equal(getattr(got, name), getattr(want, name), err_msg=name)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2 ** 16), n=st.integers(2, 300), share=st.floats(0.0, 1.0))
def test_pair_round_names_each_group_by_its_members(seed, n, share):
    """A round's labels, first and second members agree: groups numbered by their first
    members in order, a second member later than its first, every Gaussian in one group."""
    cloud = random_cloud(np.random.default_rng(seed), n, 0.3)
    labels, first, second = pair_round(cloud, max(1, int(share * n / 2)))
    count = len(first)
    assert np.all(np.diff(first) > 0)
    np.testing.assert_array_equal(labels[first], np.arange(count))
    paired = second >= 0
    assert np.all(second[paired] > first[paired])
    np.testing.assert_array_equal(labels[second[paired]], np.flatnonzero(paired))
    assert np.bincount(labels, minlength=count).sum() == n
    assert len(np.union1d(first, second[paired])) == n
