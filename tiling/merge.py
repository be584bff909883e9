"""Coarser levels of detail: a group of neighbouring Gaussians merged into one that keeps their
moments (the groups are chosen by :mod:`.grouping`).

A group becomes one Gaussian:

* weight ``w_i = opacity_i * area_i``, ``area`` the surface area of the ellipsoid of the scales
  (:func:`ellipsoid_area`). What a Gaussian puts into a picture is its opacity times its projected
  footprint, and a convex body's projected area averaged over all directions is a quarter of its
  surface area (Cauchy), so this is its contribution seen from anywhere. The volume, taken before,
  gave a flat Gaussian (most of a trained scene) almost no say in the merged colour and shape;
* mean and covariance from the weighted first and second moments,
  ``mu = sum w_i mu_i / W`` and ``Sigma = sum w_i (Sigma_i + (mu_i - mu)(mu_i - mu)^T) / W``;
  rotation and scales from the eigen-decomposition of ``Sigma``;
* colour and every SH coefficient: ``w``-weighted averages;
* opacity so that the merged footprint keeps the total weight, ``opacity = W / area``, capped
  below 1 (:data:`MAX_OPACITY`). The cap binds where opaque Gaussians overlap; there the weights
  do not add up in a picture (the front one hides the one behind), so the weight beyond the cap
  is mostly light that was never seen. Growing the footprint to keep it instead was tried and
  made the coarse levels blurrier, not better (docs/LOG.md, tilesets).

The spatial error of a merge (:func:`merge_groups`) is a high quantile of how far the Gaussians it
replaced moved, weighted by their weight (:data:`ERROR_QUANTILE`): how far the detail a viewer
sees moved, not the one stray Gaussian that moved furthest.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from spcodec.cloud import GaussianCloud

MAX_OPACITY = 0.9999
"""Cap on a merged Gaussian's opacity (its logit must stay finite)."""

ERROR_QUANTILE = 0.9
"""Share of the replaced weight whose move the spatial error bounds (:func:`weighted_quantile`)."""

AREA_EXPONENT = 1.6075
"""Exponent of Thomsen's formula for an ellipsoid's surface area (within 1.1 % for every shape)."""

MIN_OPACITY = 1e-12
"""Floor on a merged opacity (a group of fully transparent Gaussians has weight 0)."""

GroupSum = Callable[[np.ndarray, np.ndarray], np.ndarray]
"""``(values, share) -> (groups, columns)``: each group's share-weighted sum of its rows."""

MIN_VARIANCE = 1e-24
"""Floor on a merged covariance's eigenvalues (a single flat Gaussian has a zero one)."""


@dataclass
class MergedLevel:
    """A coarser level and what it cost."""

    cloud: GaussianCloud
    spatial_error: float
    """The :data:`ERROR_QUANTILE` quantile, by weight, of the distances from a merged centre to
    the centres it replaced (scene units)."""
    capped: int
    """Merged Gaussians whose opacity hit :data:`MAX_OPACITY` (their weight is not all kept)."""


def quat_to_matrix(quats: np.ndarray) -> np.ndarray:
    """(n, 3, 3) rotation matrices of (w, x, y, z) quaternions (normalized first)."""
    q = np.asarray(quats, np.float64)
    q = q / np.maximum(np.linalg.norm(q, axis=1, keepdims=True), 1e-30)
    w, x, y, z = q.T
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ], axis=1)


def matrix_to_quat(rot: np.ndarray) -> np.ndarray:
    """(n, 4) unit quaternions (w, x, y, z) of proper rotation matrices, from the largest of the
    four candidate components (numerically safe for every angle)."""
    m = np.asarray(rot, np.float64)
    trace = m[:, 0, 0] + m[:, 1, 1] + m[:, 2, 2]
    cand = np.stack([1 + trace, 1 + 2 * m[:, 0, 0] - trace, 1 + 2 * m[:, 1, 1] - trace,
                     1 + 2 * m[:, 2, 2] - trace], axis=1)
    best = np.argmax(cand, axis=1)
    big = 0.5 * np.sqrt(np.maximum(cand[np.arange(len(m)), best], 1e-30))
    q = np.empty((len(m), 4))
    s = 0.25 / big
    q[:, 0] = np.choose(best, [big, (m[:, 2, 1] - m[:, 1, 2]) * s, (m[:, 0, 2] - m[:, 2, 0]) * s,
                               (m[:, 1, 0] - m[:, 0, 1]) * s])
    q[:, 1] = np.choose(best, [(m[:, 2, 1] - m[:, 1, 2]) * s, big, (m[:, 0, 1] + m[:, 1, 0]) * s,
                               (m[:, 0, 2] + m[:, 2, 0]) * s])
    q[:, 2] = np.choose(best, [(m[:, 0, 2] - m[:, 2, 0]) * s, (m[:, 0, 1] + m[:, 1, 0]) * s, big,
                               (m[:, 1, 2] + m[:, 2, 1]) * s])
    q[:, 3] = np.choose(best, [(m[:, 1, 0] - m[:, 0, 1]) * s, (m[:, 0, 2] + m[:, 2, 0]) * s,
                               (m[:, 1, 2] + m[:, 2, 1]) * s, big])
    return q * np.where(q[:, :1] < 0, -1.0, 1.0)


def covariances(cloud: GaussianCloud) -> np.ndarray:
    """(n, 3, 3) world covariances ``R diag(s^2) R^T`` in float64."""
    rot = quat_to_matrix(cloud.quats)
    scaled = rot * np.exp(2.0 * cloud.scales.astype(np.float64))[:, None, :]
    cov = np.empty_like(rot)
    for r in range(3):  # written out: einsum and batched matmul spend their time per 3x3 matrix
        for c in range(r, 3):
            cov[:, r, c] = cov[:, c, r] = (scaled[:, r, 0] * rot[:, c, 0] + scaled[:, r, 1] * rot[:, c, 1]
                                           + scaled[:, r, 2] * rot[:, c, 2])
    return cov


def ellipsoid_area(log_scales: np.ndarray) -> np.ndarray:
    """Surface area of the ellipsoids of semi-axes ``exp(log_scales)`` (Thomsen's formula),
    float64. Products are formed in log space, so scales of 1e-10 do not underflow."""
    p = AREA_EXPONENT * np.asarray(log_scales, np.float64)
    pairs = np.stack([p[:, 0] + p[:, 1], p[:, 0] + p[:, 2], p[:, 1] + p[:, 2]], axis=1)
    top = pairs.max(axis=1, keepdims=True)
    mean = np.exp(pairs - top).mean(axis=1)
    return 4.0 * np.pi * np.exp((top[:, 0] + np.log(mean)) / AREA_EXPONENT)


def weights(cloud: GaussianCloud) -> np.ndarray:
    """Each Gaussian's weight: opacity times the surface area of its ellipsoid (float64)."""
    alpha = 1.0 / (1.0 + np.exp(-cloud.opacities.astype(np.float64)))
    return alpha * ellipsoid_area(cloud.scales)


def fit_opacity(total: np.ndarray, log_scales: np.ndarray) -> np.ndarray:
    """The opacity that gives a Gaussian of ``log_scales`` the weight ``total``, kept within
    ``[MIN_OPACITY, MAX_OPACITY]`` (see the module docstring for why the cap stays)."""
    return np.clip(total / ellipsoid_area(log_scales), MIN_OPACITY, MAX_OPACITY)


def weighted_quantile(values: np.ndarray, weight: np.ndarray, q: float) -> float:
    """The smallest value below which at least ``q`` of the total weight lies (0 when empty)."""
    if len(values) == 0:
        return 0.0
    order = np.argsort(values)
    cumulative = np.cumsum(weight[order])
    if cumulative[-1] <= 0:
        return float(values[order[-1]])
    return float(values[order[min(np.searchsorted(cumulative, q * cumulative[-1]), len(order) - 1)]])


def merge_groups(cloud: GaussianCloud, labels: np.ndarray, count: int) -> MergedLevel:
    """One Gaussian per group ``0..count-1`` of ``labels`` (see the module docstring)."""
    order = np.argsort(labels, kind="stable")
    starts = np.flatnonzero(np.diff(labels[order], prepend=-1))
    if len(starts) != count:
        raise ValueError(f"labels must name every group 0..{count - 1} at least once")

    def group_sum(values: np.ndarray, share: np.ndarray) -> np.ndarray:
        """Share-weighted sums per group: the rows sorted by group, each group's run added up in
        row order (as ``np.add.at`` adds, ~20x slower)."""
        flat = values.reshape(len(values), -1)[order].astype(np.float64) * share[order, None]
        return np.add.reduceat(flat, starts, axis=0)

    merged, w, offset, alpha = _merge(cloud, labels, count, group_sum)
    moved = np.linalg.norm(offset, axis=1)
    return MergedLevel(merged, weighted_quantile(moved, w, ERROR_QUANTILE),
                       int((alpha >= MAX_OPACITY).sum()))


def merge_pairs(cloud: GaussianCloud, first: np.ndarray, second: np.ndarray) -> GaussianCloud:
    """:func:`merge_groups` of groups of one or two: group ``g`` is ``first[g]`` and, where
    ``second[g] >= 0``, ``second[g] > first[g]``. Bit for bit the same Gaussians, for a pairing
    round's intermediate level: a sum of two products needs no sort of the rows, and the
    round's level needs no spatial error."""
    count = len(first)
    labels = np.empty(len(cloud), np.int64)
    labels[first] = np.arange(count)
    pair = np.flatnonzero(second >= 0)
    later = second[pair]
    labels[later] = pair

    def group_sum(values: np.ndarray, share: np.ndarray) -> np.ndarray:
        """The first member's product plus the second's (two terms add up the same in any
        order, so this is :func:`merge_groups`' sum exactly)."""
        flat = values.reshape(len(values), -1)
        out = flat[first].astype(np.float64) * share[first, None]
        out[pair] += flat[later].astype(np.float64) * share[later, None]
        return out

    return _merge(cloud, labels, count, group_sum)[0]


def _merge(cloud: GaussianCloud, labels: np.ndarray, count: int, group_sum: GroupSum
           ) -> tuple[GaussianCloud, np.ndarray, np.ndarray, np.ndarray]:
    """The merged Gaussians of the groups ``group_sum`` adds up (the module docstring), with
    the members' weights, their offsets from their merged centres and the merged opacities."""
    w = weights(cloud)
    total = np.bincount(labels, w, count)
    share = w / total[labels]

    def average(values: np.ndarray) -> np.ndarray:
        return group_sum(values, share).reshape((count,) + values.shape[1:])

    mean = average(cloud.means)
    offset = cloud.means.astype(np.float64) - mean[labels]
    second = covariances(cloud) + offset[:, :, None] * offset[:, None, :]
    cov = average(second)
    cov = 0.5 * (cov + cov.transpose(0, 2, 1))
    var, vec = np.linalg.eigh(cov)
    var = np.maximum(var, MIN_VARIANCE)
    vec[:, :, 2] *= np.sign(np.linalg.det(vec))[:, None]  # a proper rotation
    log_scales = 0.5 * np.log(var)
    alpha = fit_opacity(total, log_scales)
    merged = GaussianCloud(means=mean, scales=log_scales, quats=matrix_to_quat(vec),
                           opacities=np.log(alpha / (1.0 - alpha)), sh_dc=average(cloud.sh_dc),
                           sh_rest=average(cloud.sh_rest))
    return merged, w, offset, alpha
