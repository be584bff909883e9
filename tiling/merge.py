"""Coarser levels of detail: neighbouring Gaussians merged into one that keeps their moments.

A group of neighbours (``branching`` of them, found by median splits, so a level has
``ceil(n / branching)`` Gaussians) becomes one Gaussian:

* weight ``w_i = opacity_i * volume_i`` (``volume = sx * sy * sz``, proportional to the integral
  of the Gaussian's density: what it contributes to the picture);
* mean and covariance from the weighted first and second moments,
  ``mu = sum w_i mu_i / W`` and ``Sigma = sum w_i (Sigma_i + (mu_i - mu)(mu_i - mu)^T) / W``;
  rotation and scales from the eigen-decomposition of ``Sigma``;
* colour and every SH coefficient: ``w``-weighted averages;
* opacity so that the merged footprint keeps the total weight, ``opacity = W / volume``, capped
  below 1 (:data:`MAX_OPACITY`): where the cap binds, the weight is the only moment not kept.

The spatial error of a merge is the largest distance from a merged Gaussian's centre to the
centre of a Gaussian it replaced: how far any detail moved (:func:`merge_level`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from spcodec.cloud import GaussianCloud

from .partition import median_split

MAX_OPACITY = 0.9999
"""Cap on a merged Gaussian's opacity (its logit must stay finite)."""

MIN_VARIANCE = 1e-24
"""Floor on a merged covariance's eigenvalues (a single flat Gaussian has a zero one)."""


@dataclass
class MergedLevel:
    """A coarser level and what it cost."""

    cloud: GaussianCloud
    spatial_error: float
    """Largest distance from a merged centre to a centre it replaced (scene units)."""
    capped: int
    """Merged Gaussians whose opacity hit :data:`MAX_OPACITY` (their weight is not kept)."""


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
    var = np.exp(2.0 * cloud.scales.astype(np.float64))
    return np.einsum("nij,nj,nkj->nik", rot, var, rot)


def weights(cloud: GaussianCloud) -> np.ndarray:
    """Each Gaussian's weight: opacity times volume ``sx * sy * sz`` (float64)."""
    alpha = 1.0 / (1.0 + np.exp(-cloud.opacities.astype(np.float64)))
    return alpha * np.exp(cloud.scales.astype(np.float64).sum(axis=1))


def neighbour_groups(means: np.ndarray, size: int) -> tuple[np.ndarray, int]:
    """A group number per Gaussian: ``ceil(n / size)`` groups of at most ``size`` neighbours, cut
    by median splits (each cut leaves a multiple of ``size`` on its left, so groups are full)."""
    labels = np.empty(len(means), np.int64)
    stack, group = [np.arange(len(means))], 0
    while stack:
        index = stack.pop()
        if len(index) <= size:
            labels[index] = group
            group += 1
            continue
        groups = -(-len(index) // size)
        stack.extend(median_split(means, index, size * (-(-groups // 2))))
    return labels, group


def merge_groups(cloud: GaussianCloud, labels: np.ndarray, count: int) -> MergedLevel:
    """One Gaussian per group ``0..count-1`` of ``labels`` (see the module docstring)."""
    w = weights(cloud)
    total = np.bincount(labels, w, count)
    share = w / total[labels]

    def average(values: np.ndarray) -> np.ndarray:
        flat = values.reshape(len(values), -1).astype(np.float64) * share[:, None]
        out = np.zeros((count, flat.shape[1]))
        np.add.at(out, labels, flat)
        return out.reshape((count,) + values.shape[1:])

    mean = average(cloud.means)
    offset = cloud.means.astype(np.float64) - mean[labels]
    second = covariances(cloud) + offset[:, :, None] * offset[:, None, :]
    cov = average(second)
    cov = 0.5 * (cov + cov.transpose(0, 2, 1))
    var, vec = np.linalg.eigh(cov)
    var = np.maximum(var, MIN_VARIANCE)
    vec[:, :, 2] *= np.sign(np.linalg.det(vec))[:, None]  # a proper rotation
    log_scales = 0.5 * np.log(var)
    alpha = np.minimum(total / np.exp(log_scales.sum(axis=1)), MAX_OPACITY)
    moved = np.linalg.norm(offset, axis=1)
    merged = GaussianCloud(means=mean, scales=log_scales, quats=matrix_to_quat(vec),
                           opacities=np.log(alpha / (1.0 - alpha)), sh_dc=average(cloud.sh_dc),
                           sh_rest=average(cloud.sh_rest))
    return MergedLevel(merged, float(moved.max()) if len(moved) else 0.0,
                       int((alpha >= MAX_OPACITY).sum()))


def merge_level(cloud: GaussianCloud, branching: int) -> MergedLevel:
    """``cloud`` reduced ``branching`` times by merging groups of neighbours."""
    labels, count = neighbour_groups(cloud.means.astype(np.float64), branching)
    return merge_groups(cloud, labels, count)
