"""Which Gaussians a coarser level merges: rounds of greedy pairing of the cheapest neighbours.

A level keeps ``ceil(n / branching)`` Gaussians. Each round pairs Gaussians with one of their
:data:`NEIGHBOURS` nearest, cheapest pair first, each Gaussian in at most one pair, and merges the
pairs (:func:`.merge.merge_pairs`, bit for bit :func:`.merge.merge_groups`); rounds repeat on the
merged Gaussians until the count is reached, so a group is whatever chain of pairs ended in one
Gaussian. The last round stops at the count exactly. The level itself is then merged once from
the finer Gaussians with the composed groups (moments compose, so this is the same as merging
round by round, without the rounds' rounding).

The cost of merging ``i`` and ``j`` says how badly one Gaussian stands for the pair, in shape and
in appearance, whatever their size (:mod:`.pair_cost` computes it):

* shape: the Kullback-Leibler divergence from the pair (the two-component mixture, weighted by
  :func:`.merge.weights`) to the merged Gaussian (the one with the mixture's mean and covariance,
  which :func:`.merge.merge_groups` makes). It is 0 for two copies and grows as the pair stops
  looking like one ellipsoid: side by side along their thin axis, crossed, far apart for their
  size. It is in nats, so a pair of small Gaussians is judged like a large one. ``E_p[log p]``
  of the mixture has no closed form; it is taken at each component's six sigma points (its
  centre plus or minus ``sqrt(3)`` standard deviations along each axis), which integrate every
  polynomial of degree three exactly, so the estimate is deterministic and 0 for two copies;
* appearance: the squared distance between the two colours over every SH coefficient: what
  merging averages away.

The greedy pairing (:func:`greedy_pairs`) is the same as walking the pairs cheapest first and
taking each whose Gaussians are both free, done in whole-array steps: a pair that is the
cheapest left at both its Gaussians is one the walk takes (nothing cheaper can claim either), so
each step takes all such pairs at once and drops the pairs they block.

An earlier cost, the weighted variance the pair adds (Ward's criterion on centre distance plus a
DC colour term), merged faint and small Gaussians first whatever their shapes, and left coarse
levels 0.5-1.3 dB short of PlayCanvas splat-transform's decimation, which pairs by a cost of this
kind (docs/LOG.md, tilesets).
"""

from __future__ import annotations

import numpy as np

from spcodec.cloud import GaussianCloud

from .merge import MergedLevel, merge_groups, merge_pairs
from .pair_cost import pair_costs

NEIGHBOURS = 16
"""Candidate partners per Gaussian in a round."""

WALK_BELOW = 4096
"""Pairs left below which :func:`greedy_pairs` walks them one by one: a whole-array step costs a
pass over every pair left, and the last steps take only a few each."""


def candidate_pairs(means: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(i, j)``, ``i < j``, of every Gaussian and each of its :data:`NEIGHBOURS` nearest, in
    ascending order of ``(i, j)``."""
    n = len(means)
    k = min(NEIGHBOURS + 1, n)
    from scipy.spatial import cKDTree  # the encoder's extra: decode and info never load it

    tree = cKDTree(means)
    # queried in the tree's own order, so that neighbouring queries walk the same nodes (each
    # query's answer does not depend on the others: the same lists, a fifth less time)
    _, found = tree.query(means[tree.indices], k=k)
    near = np.empty((n, k), np.int64)
    near[tree.indices] = np.asarray(found).reshape(n, k)
    key = np.concatenate([_later_keys(near), _earlier_keys(near)])
    key.sort(kind="stable")  # two sorted runs: a merge of them, not a sort of all the keys
    key = key[np.concatenate([[True], key[1:] != key[:-1]])]  # each pair once (mutual neighbours)
    return key // n, key % n


def _later_keys(near: np.ndarray) -> np.ndarray:
    """Keys ``i * n + j`` of the pairs ``(i, j)`` with ``j`` in ``i``'s list and ``j > i``,
    ascending: each row's later neighbours sorted within the row (every column is read: with
    duplicate centres a Gaussian need not be first in its own list)."""
    n = len(near)
    rows = np.arange(n)[:, None]
    later = np.where((near > rows) & (near < n), near, n)
    later.sort(axis=1)
    kept = later < n
    return np.repeat(np.arange(n), kept.sum(axis=1)) * n + later[kept]


def _earlier_keys(near: np.ndarray) -> np.ndarray:
    """Keys ``j * n + i`` of the pairs ``(j, i)`` with ``j`` in ``i``'s list and ``j < i``,
    ascending."""
    n = len(near)
    rows = np.arange(n)[:, None]
    earlier = near < rows
    key = near[earlier] * n + np.broadcast_to(rows, near.shape)[earlier]
    key.sort()
    return key


def greedy_pairs(i: np.ndarray, j: np.ndarray, cost: np.ndarray, n: int, limit: int,
                 walk_below: int = WALK_BELOW) -> np.ndarray:
    """Positions in ``(i, j)`` of the pairs taken by walking them cheapest first (ties in list
    order) and taking each whose two Gaussians (of ``n``) are both still free, stopping after
    ``limit`` pairs; ascending by cost.

    Done in steps (see the module docstring), with no sort of all the pairs: a step finds, for
    every Gaussian, its cheapest pair left (the first in the list among equal costs). Once fewer
    than ``walk_below`` pairs are left, the walk itself finishes them. Both are the walk: the
    pairs a step takes are the walk's, and every pair the walk takes is free of all the pairs
    taken before it; the walk's first ``limit`` pairs are its ``limit`` cheapest.
    """
    a, b, c, e = i, j, cost, np.arange(len(i))
    taken = np.zeros(n, bool)
    chosen = []
    while len(e) > walk_below:
        low = np.full(n, np.inf)
        np.minimum.at(low, a, c)
        np.minimum.at(low, b, c)
        at_a, at_b = c == low[a], c == low[b]
        first = np.full(n, len(i))
        np.minimum.at(first, a[at_a], e[at_a])
        np.minimum.at(first, b[at_b], e[at_b])
        step = at_a & at_b & (first[a] == e) & (first[b] == e)
        chosen.append(e[step])
        taken[a[step]] = True
        taken[b[step]] = True
        free = ~(taken[a] | taken[b])
        a, b, c, e = a[free], b[free], c[free], e[free]
    walked = []
    for k in np.argsort(c, kind="stable").tolist():
        x, y = int(a[k]), int(b[k])
        if not (taken[x] or taken[y]):
            taken[x] = taken[y] = True
            walked.append(int(e[k]))
    picked = np.concatenate(chosen + [np.array(walked, dtype=np.int64)])
    return picked[np.lexsort((picked, cost[picked]))][:limit]


def pair_round(cloud: GaussianCloud, merges: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """At most ``merges`` disjoint pairs, cheapest first (at least one when the cloud has two
    Gaussians), as ``(labels, first, second)``: each Gaussian's group, numbered by its first
    member, and each group's members (``second`` -1 for a Gaussian left alone)."""
    n = len(cloud)
    i, j = candidate_pairs(cloud.means.astype(np.float32))
    taken = greedy_pairs(i, j, pair_costs(cloud, i, j), n, merges)
    alone = np.ones(n, bool)
    alone[j[taken]] = False  # i < j: the pair is numbered by i
    first = np.flatnonzero(alone)
    group = np.cumsum(alone) - 1
    labels = group.copy()
    labels[j[taken]] = group[i[taken]]
    second = np.full(len(first), -1, np.int64)
    second[group[i[taken]]] = j[taken]
    return labels, first, second


def pair_groups(cloud: GaussianCloud, target: int) -> tuple[np.ndarray, int]:
    """A group number per Gaussian of ``cloud``, ``target`` groups in all (or ``len(cloud)`` if
    fewer), by rounds of :func:`pair_round`."""
    labels, current, count = np.arange(len(cloud)), cloud, len(cloud)
    while count > max(target, 1):
        round_labels, first, second = pair_round(current, count - max(target, 1))
        labels = round_labels[labels]
        current, count = merge_pairs(current, first, second), len(first)
    return labels, count


def merge_level(cloud: GaussianCloud, branching: int) -> MergedLevel:
    """``cloud`` reduced ``branching`` times: ``ceil(n / branching)`` merged Gaussians."""
    labels, count = pair_groups(cloud, -(-len(cloud) // branching))
    return merge_groups(cloud, labels, count)
