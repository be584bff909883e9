"""Which Gaussians a coarser level merges: rounds of greedy pairing of the cheapest neighbours.

A level keeps ``ceil(n / branching)`` Gaussians. Each round pairs Gaussians with one of their
:data:`NEIGHBOURS` nearest, cheapest pair first, each Gaussian in at most one pair, and merges the
pairs (:func:`.merge.merge_groups`); rounds repeat on the merged Gaussians until the count is
reached, so a group is whatever chain of pairs ended in one Gaussian. The last round stops at the
count exactly. The level itself is then merged once from the finer Gaussians with the composed
groups (moments compose, so this is the same as merging round by round, without the rounds'
rounding).

The cost of merging ``i`` and ``j`` is the weighted variance the pair adds (Ward's criterion),
``w_i w_j / (w_i + w_j) * (|mu_i - mu_j|^2 + COLOUR_COST * |c_i - c_j|^2 * (s_i^2 + s_j^2))``:
faint or small Gaussians close together go first (a faint one joining a large one costs its own
small weight: the large one hardly changes), and two large opaque ones are merged last, which
fixed groups of ``branching`` neighbours could not do (they merged whatever lay together); a
colour difference costs in proportion to the pair's size, over which merging smears it.
"""

from __future__ import annotations

import numpy as np

from spcodec.cloud import GaussianCloud

from .merge import MergedLevel, merge_groups, weights

NEIGHBOURS = 8
"""Candidate partners per Gaussian in a round."""

COLOUR_COST = 0.25
"""Weight of the DC colour difference against the distance in a pair's cost (see above; chosen by
the coarse levels' PSNR in a third-party renderer, docs/LOG.md)."""


def pair_costs(cloud: GaussianCloud) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(i, j, cost)`` of every candidate pair ``i < j`` (neighbours of one another)."""
    means = cloud.means.astype(np.float64)
    n = len(means)
    k = min(NEIGHBOURS + 1, n)
    from scipy.spatial import cKDTree  # the encoder's extra: decode and info never load it

    _, near = cKDTree(means).query(means, k=k)
    near = np.asarray(near).reshape(n, k)
    # every column: with duplicate centres a Gaussian need not be first in its own list
    i, j = np.repeat(np.arange(n), k), near.ravel()
    keep = (j < n) & (i != j)
    i, j = np.minimum(i[keep], j[keep]), np.maximum(i[keep], j[keep])
    pairs = np.unique(np.stack([i, j], axis=1), axis=0)
    i, j = pairs[:, 0], pairs[:, 1]
    w = weights(cloud)
    colour = cloud.sh_dc.astype(np.float64)
    size = np.exp(2.0 * cloud.scales.astype(np.float64)).sum(axis=1)
    spread = ((means[i] - means[j]) ** 2).sum(axis=1) \
        + COLOUR_COST * ((colour[i] - colour[j]) ** 2).sum(axis=1) * (size[i] + size[j])
    return i, j, w[i] * w[j] / np.maximum(w[i] + w[j], 1e-300) * spread


def pair_round(cloud: GaussianCloud, merges: int) -> tuple[np.ndarray, int]:
    """Group labels after at most ``merges`` disjoint pairs, cheapest first (at least one when
    the cloud has two Gaussians)."""
    n = len(cloud)
    i, j, cost = pair_costs(cloud)
    order = np.argsort(cost, kind="stable")
    used = bytearray(n)
    partner = np.arange(n)
    done = 0
    for a, b in zip(i[order].tolist(), j[order].tolist()):
        if done >= merges:
            break
        if used[a] or used[b]:
            continue
        used[a] = used[b] = 1
        partner[b] = a
        done += 1
    _, labels = np.unique(partner, return_inverse=True)
    return labels, n - done


def pair_groups(cloud: GaussianCloud, target: int) -> tuple[np.ndarray, int]:
    """A group number per Gaussian of ``cloud``, ``target`` groups in all (or ``len(cloud)`` if
    fewer), by rounds of :func:`pair_round`."""
    labels, current, count = np.arange(len(cloud)), cloud, len(cloud)
    while count > max(target, 1):
        round_labels, merged = pair_round(current, count - max(target, 1))
        labels = round_labels[labels]
        current, count = merge_groups(current, round_labels, merged).cloud, merged
    return labels, count


def merge_level(cloud: GaussianCloud, branching: int) -> MergedLevel:
    """``cloud`` reduced ``branching`` times: ``ceil(n / branching)`` merged Gaussians."""
    labels, count = pair_groups(cloud, -(-len(cloud) // branching))
    return merge_groups(cloud, labels, count)
