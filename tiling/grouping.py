"""Which Gaussians a coarser level merges: rounds of greedy pairing of the cheapest neighbours.

A level keeps ``ceil(n / branching)`` Gaussians. Each round pairs Gaussians with one of their
:data:`NEIGHBOURS` nearest, cheapest pair first, each Gaussian in at most one pair, and merges the
pairs (:func:`.merge.merge_groups`); rounds repeat on the merged Gaussians until the count is
reached, so a group is whatever chain of pairs ended in one Gaussian. The last round stops at the
count exactly. The level itself is then merged once from the finer Gaussians with the composed
groups (moments compose, so this is the same as merging round by round, without the rounds'
rounding).

The cost of merging ``i`` and ``j`` says how badly one Gaussian stands for the pair, in shape and
in appearance, whatever their size:

* shape: the Kullback-Leibler divergence from the pair (the two-component mixture, weighted by
  :func:`.merge.weights`) to the merged Gaussian (the one with the mixture's mean and covariance,
  which :func:`.merge.merge_groups` makes), :func:`shape_cost`. It is 0 for two copies and grows
  as the pair stops looking like one ellipsoid: side by side along their thin axis, crossed, far
  apart for their size. It is in nats, so a pair of small Gaussians is judged like a large one;
* appearance: the squared distance between the two colours over every SH coefficient
  (:func:`appearance_cost`): what merging averages away.

An earlier cost, the weighted variance the pair adds (Ward's criterion on centre distance plus a
DC colour term), merged faint and small Gaussians first whatever their shapes, and left coarse
levels 0.5-1.3 dB short of PlayCanvas splat-transform's decimation, which pairs by a cost of this
kind (docs/LOG.md, tilesets).
"""

from __future__ import annotations

import numpy as np

from spcodec.cloud import GaussianCloud

from .merge import MergedLevel, merge_groups, quat_to_matrix, weights

NEIGHBOURS = 16
"""Candidate partners per Gaussian in a round."""

APPEARANCE_COST = 0.25
"""Weight of :func:`appearance_cost` (SH units squared) against :func:`shape_cost` (nats); chosen,
like :data:`NEIGHBOURS`, by the coarse levels' PSNR in a third-party renderer (docs/LOG.md)."""

THINNEST = 1e-3
"""Floor of a Gaussian's shortest axis, as a share of its longest, in :func:`shape_cost` only:
a flat Gaussian has a vanishing axis, and the divergence from or to it would be set by that
rounding error rather than by the shape. Relative, so the cost does not depend on scene units."""

COST_BLOCK = 1 << 16
"""Pairs costed at a time (bounds the temporary arrays of a node of millions of Gaussians)."""

LOG_2PI = float(np.log(2.0 * np.pi))


def candidate_pairs(means: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(i, j)``, ``i < j``, of every Gaussian and each of its :data:`NEIGHBOURS` nearest."""
    n = len(means)
    k = min(NEIGHBOURS + 1, n)
    from scipy.spatial import cKDTree  # the encoder's extra: decode and info never load it

    _, near = cKDTree(means).query(means, k=k)
    near = np.asarray(near).reshape(n, k)
    # every column: with duplicate centres a Gaussian need not be first in its own list
    i, j = np.repeat(np.arange(n), k), near.ravel()
    keep = (j < n) & (i != j)
    key = np.sort(np.minimum(i[keep], j[keep]) * n + np.maximum(i[keep], j[keep]))
    key = key[np.concatenate([[True], key[1:] != key[:-1]])]  # each pair once (mutual neighbours)
    return key // n, key % n


def shape_cost(means: np.ndarray, rot: np.ndarray, var: np.ndarray, cov: np.ndarray, w: np.ndarray,
               i: np.ndarray, j: np.ndarray) -> np.ndarray:
    """KL divergence from the mixture of Gaussians ``i`` and ``j`` to their merged Gaussian.

    ``rot`` holds each Gaussian's axes as columns, ``var`` its variances along them, ``cov`` its
    covariance, ``w`` its weight (the mixture's proportions). ``KL(p || q) = E_p[log p] + H(q)``:
    ``q`` has ``p``'s mean and covariance, so ``E_p[-log q]`` is exactly ``q``'s entropy.
    ``E_p[log p]`` has no closed form; it is taken at each component's six sigma points (its
    centre plus or minus ``sqrt(3)`` standard deviations along each axis), which integrate every
    polynomial of degree three exactly, so the estimate is deterministic and 0 for two copies.
    Only centre differences and ratios of sizes enter, so float32 arrays serve (as
    :func:`pair_costs` passes, for speed) wherever the scene lies and whatever its units.
    """
    pi = np.clip(w[i] / np.maximum(w[i] + w[j], 1e-300), 1e-6, 1.0 - 1e-6).astype(means.dtype)
    pj = 1 - pi
    delta = means[i] - means[j]
    merged = (pi[:, None, None] * cov[i] + pj[:, None, None] * cov[j]
              + (pi * pj)[:, None, None] * delta[:, :, None] * delta[:, None, :])
    unit = (merged[:, 0, 0] + merged[:, 1, 1] + merged[:, 2, 2]) / 3
    merged_logdet = np.log(np.maximum(_det3(merged / unit[:, None, None]), 1e-30)) + 3 * np.log(unit)
    entropy = 0.5 * (3.0 * LOG_2PI + merged_logdet + 3.0)
    own_i, own_j = _log_density_at_sigma_points(delta, rot, var, i, j)
    return (pi * _mean_log_mixture(np.log(pi), own_i[0], np.log(pj), own_i[1])
            + pj * _mean_log_mixture(np.log(pj), own_j[0], np.log(pi), own_j[1]) + entropy)


def _det3(m: np.ndarray) -> np.ndarray:
    """Determinants of (P, 3, 3) matrices, written out (a batched LU costs several times more)."""
    return (m[:, 0, 0] * (m[:, 1, 1] * m[:, 2, 2] - m[:, 1, 2] * m[:, 2, 1])
            - m[:, 0, 1] * (m[:, 1, 0] * m[:, 2, 2] - m[:, 1, 2] * m[:, 2, 0])
            + m[:, 0, 2] * (m[:, 1, 0] * m[:, 2, 1] - m[:, 1, 1] * m[:, 2, 0]))


def _log_density_at_sigma_points(delta: np.ndarray, rot: np.ndarray, var: np.ndarray, i: np.ndarray,
                                 j: np.ndarray) -> tuple[tuple, tuple]:
    """Log densities of each component at the other's and at its own six sigma points:
    ``((log N_i, log N_j) at i's points, (log N_j, log N_i) at j's points)``, each (P,) or (P, 6);
    ``delta`` is ``mu_i - mu_j``.

    At a Gaussian's own sigma points the Mahalanobis distance is 3 everywhere. At ``a``'s point
    ``mu_a + s sqrt(3) sd_a,k axis_a,k`` seen from ``b``, with ``u`` the centre offset and ``V``
    ``a``'s scaled axes, both in ``b``'s whitened frame, it is ``|u|^2 + 2 s u.V_k + |V_k|^2``.
    """
    logdet = np.log(var).sum(axis=1)

    def across(a: np.ndarray, b: np.ndarray, offset: np.ndarray) -> np.ndarray:
        sd_b = np.sqrt(var[b])
        to_b = rot[b].transpose(0, 2, 1)
        u = (to_b @ offset[:, :, None])[:, :, 0] / sd_b
        v = (to_b @ rot[a]) * (np.sqrt(3 * var[a])[:, None, :] / sd_b[:, :, None])
        base = (u * u).sum(axis=1)[:, None] + (v * v).sum(axis=1)
        cross = 2 * (u[:, None, :] @ v)[:, 0, :]
        quad = np.concatenate([base + cross, base - cross], axis=1)
        return -0.5 * (3.0 * LOG_2PI + logdet[b][:, None] + quad)

    def own(a: np.ndarray) -> np.ndarray:
        return -0.5 * (3.0 * LOG_2PI + logdet[a] + 3.0)

    return (own(i), across(i, j, delta)), (own(j), across(j, i, -delta))


def _mean_log_mixture(log_p_own: np.ndarray, own: np.ndarray, log_p_other: np.ndarray,
                      other: np.ndarray) -> np.ndarray:
    """Mean over the six points of ``log(p_own N_own + p_other N_other)``."""
    return np.logaddexp((log_p_own + own)[:, None], log_p_other[:, None] + other).mean(axis=1)


def appearance_cost(colour: np.ndarray, i: np.ndarray, j: np.ndarray) -> np.ndarray:
    """Squared distance between the colours (every SH coefficient) of ``i`` and ``j``."""
    return ((colour[i] - colour[j]) ** 2).sum(axis=1)


def pair_costs(cloud: GaussianCloud) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(i, j, cost)`` of every candidate pair ``i < j`` (see the module docstring)."""
    means = cloud.means.astype(np.float32)
    i, j = candidate_pairs(means)
    rot = quat_to_matrix(cloud.quats)
    var = np.exp(2.0 * cloud.scales.astype(np.float64))
    var = np.maximum(var, THINNEST ** 2 * var.max(axis=1, keepdims=True))
    cov = ((rot * var[:, None, :]) @ rot.transpose(0, 2, 1)).astype(np.float32)
    rot, var, w = rot.astype(np.float32), var.astype(np.float32), weights(cloud)
    n = len(cloud)
    colour = np.concatenate([cloud.sh_dc.reshape(n, -1), cloud.sh_rest.reshape(n, -1)], axis=1)
    cost = np.empty(len(i))
    for lo in range(0, len(i), COST_BLOCK):
        a, b = i[lo:lo + COST_BLOCK], j[lo:lo + COST_BLOCK]
        cost[lo:lo + COST_BLOCK] = (shape_cost(means, rot, var, cov, w, a, b)
                                    + APPEARANCE_COST * appearance_cost(colour, a, b))
    return i, j, cost


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
