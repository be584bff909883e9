"""The cost of merging two Gaussians, for millions of candidate pairs at a time.

What the cost means is told in :mod:`.grouping`: the Kullback-Leibler divergence from the pair
(the two-component mixture) to the one merged Gaussian with its mean and covariance, taken at
each component's six sigma points, plus a weighted squared distance over every SH coefficient.
This module is how it is computed fast enough that a tileset's coarse levels cost little next to
encoding them (a coarse level of a 500 k-Gaussian node took longer than its encode before).

* Every per-Gaussian quantity the cost reads (centre, whitening and scaled axes, log
  determinant, colour) is worked out once per Gaussian and stored as one float32 row
  (:func:`gaussian_table`), so a block of pairs is two row gathers, not a dozen.
* The 3x3 products are written out over columns (structure of arrays): numpy's batched matmul
  and logaddexp spend most of their time per tiny matrix, not per number.
* The KL sum is rearranged so the constants cancel before rounding: with ``x`` a component's log
  density at its own sigma points (each the same) and ``y_k`` the other's there,
  ``mean_k logaddexp(x, y_k) = x + mean_k softplus(y_k - x)``, and the ``x`` terms, the
  merged Gaussian's entropy and ``log 2 pi`` add up to
  ``pi log pi + pj log pj + (logdet_merged - pi logdet_i - pj logdet_j) / 2``. Two copies then
  cost exactly what rounding leaves of ``pi log pi + pi log(1/pi)``: 0 to float32 precision.
"""

from __future__ import annotations

import numpy as np

from spcodec.cloud import GaussianCloud

from .merge import quat_to_matrix, weights

APPEARANCE_COST = 0.25
"""Weight of the colour distance (SH units squared) against the divergence (nats); chosen, like
the neighbour count in :mod:`.grouping`, by the coarse levels' PSNR in a third-party renderer
(docs/LOG.md)."""

THINNEST = 1e-3
"""Floor of a Gaussian's shortest axis, as a share of its longest, in the divergence only: a flat
Gaussian has a vanishing axis, and the divergence from or to it would be set by that rounding
error rather than by the shape. Relative, so the cost does not depend on scene units."""

BLOCK = 8192
"""Pairs costed at a time: the two gathered blocks of rows stay in cache (a row is ~300 bytes
with SH degree 3), where one pass per operation over millions of pairs went to main memory."""

# columns of a row of gaussian_table
MEAN, WHITEN, AXES, LOGDET, COLOUR = 0, 3, 12, 21, 22
"""Column offsets: centre (3), whitening ``R / sd`` (9, row-major), scaled axes
``R sqrt(3 var)`` (9, row-major), log determinant (1), colour (the rest)."""

SYMMETRIC = ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))
"""The entries of a symmetric 3x3 matrix that determine it."""


def gaussian_table(cloud: GaussianCloud) -> np.ndarray:
    """One float32 row per Gaussian holding everything :func:`pair_costs` reads of it.

    Only centre differences, ratios of sizes and colour differences enter the cost, so float32
    serves wherever the scene lies and whatever its units (the merged covariance's determinant is
    taken relative to one component's, see :func:`shape_costs`).
    """
    n = len(cloud)
    rot = quat_to_matrix(cloud.quats)
    var = np.exp(2.0 * cloud.scales.astype(np.float64))
    var = np.maximum(var, THINNEST ** 2 * var.max(axis=1, keepdims=True))
    colour = np.concatenate([cloud.sh_dc.reshape(n, -1), cloud.sh_rest.reshape(n, -1)], axis=1)
    table = np.empty((n, COLOUR + colour.shape[1]), np.float32)
    table[:, MEAN:WHITEN] = cloud.means
    table[:, WHITEN:AXES] = (rot / np.sqrt(var)[:, None, :]).reshape(n, 9)
    table[:, AXES:LOGDET] = (rot * np.sqrt(3.0 * var)[:, None, :]).reshape(n, 9)
    table[:, LOGDET] = np.log(var).sum(axis=1)
    table[:, COLOUR:] = colour
    return table


def pair_costs(cloud: GaussianCloud, i: np.ndarray, j: np.ndarray) -> np.ndarray:
    """The cost (float64) of merging ``i[k]`` with ``j[k]``, for every k."""
    table, w = gaussian_table(cloud), weights(cloud)
    cost = np.empty(len(i))
    for lo in range(0, len(i), BLOCK):
        a, b = i[lo:lo + BLOCK], j[lo:lo + BLOCK]
        rows_a, rows_b = table[a], table[b]
        share = np.clip(w[a] / np.maximum(w[a] + w[b], 1e-300), 1e-6, 1.0 - 1e-6).astype(np.float32)
        colour = rows_a[:, COLOUR:] - rows_b[:, COLOUR:]
        # the shape columns one contiguous array each: a strided column costs every operation
        shape_a, shape_b = (np.ascontiguousarray(rows[:, :COLOUR].T) for rows in (rows_a, rows_b))
        cost[lo:lo + BLOCK] = (shape_costs(shape_a, shape_b, share)
                               + APPEARANCE_COST * np.einsum("pk,pk->p", colour, colour))
    return cost


def shape_costs(a: np.ndarray, b: np.ndarray, pi: np.ndarray) -> np.ndarray:
    """The divergence from each mixture ``pi N_a + (1 - pi) N_b`` to its merged Gaussian; ``a``
    and ``b`` are blocks of :func:`gaussian_table` rows, transposed (one column per pair).

    The merged covariance's log determinant is taken in ``b``'s whitened frame, where ``b`` is
    the identity: ``logdet_b + log det(pi S_a + pj I + pi pj u u^T)``. Two copies then give
    ``det(I)`` and cost 0 to rounding, where the determinant of the merged covariance itself,
    near-singular for flat Gaussians, lost up to 1e-4 nats in float32.
    """
    pj = 1 - pi
    delta = a[MEAN:WHITEN] - b[MEAN:WHITEN]
    log_pi, log_pj = np.log(pi), np.log(pj)
    u, v = _whitened(a, b, delta)
    pi3, pipj = pi / 3, pi * pj
    m = {(r, c): pi3 * (v[0][r] * v[0][c] + v[1][r] * v[1][c] + v[2][r] * v[2][c]) + pipj * u[r] * u[c]
         for r, c in SYMMETRIC}
    xx, yy, zz = m[0, 0] + pj, m[1, 1] + pj, m[2, 2] + pj
    xy, xz, yz = m[0, 1], m[0, 2], m[1, 2]
    det = xx * (yy * zz - yz * yz) - xy * (xy * zz - yz * xz) + xz * (xy * yz - yy * xz)
    merged_logdet = b[LOGDET] + np.log(np.maximum(det, 1e-30))
    # y_k - x at a's sigma points: log(pj / pi) - (logdet_b - logdet_a) / 2 + (3 - quad_k) / 2
    base_a = log_pj - log_pi - 0.5 * (b[LOGDET] - a[LOGDET]) + 1.5
    base_b = log_pi - log_pj - 0.5 * (a[LOGDET] - b[LOGDET]) + 1.5
    soft_a = _mean_softplus(base_a, _sigma_quad(u, v))
    soft_b = _mean_softplus(base_b, _sigma_quad(*_whitened(b, a, -delta)))
    return (pi * log_pi + pj * log_pj + 0.5 * (merged_logdet - pi * a[LOGDET] - pj * b[LOGDET])
            + pi * soft_a + pj * soft_b)


def _whitened(a: np.ndarray, b: np.ndarray, offset: np.ndarray) -> tuple[list, list]:
    """``a``'s centre offset (``offset = mu_a - mu_b``) and scaled axes in ``b``'s whitened frame:
    ``u = W_b^T offset`` and ``v_k = W_b^T A_a,k``, as ``u[r]`` and ``v[k][r]`` (each (P,))."""
    wb = b[WHITEN:AXES]  # row-major: wb[3 c + r] is component c of b's axis r over its sd
    ax = a[AXES:LOGDET]
    u = [wb[r] * offset[0] + wb[3 + r] * offset[1] + wb[6 + r] * offset[2] for r in range(3)]
    v = [[wb[r] * ax[k] + wb[3 + r] * ax[3 + k] + wb[6 + r] * ax[6 + k] for r in range(3)]
         for k in range(3)]
    return u, v


def _sigma_quad(u: list, v: list) -> tuple[np.ndarray, np.ndarray]:
    """Squared Mahalanobis distances under ``b`` of ``a``'s six sigma points (see
    :func:`_whitened`), ``|u|^2 + |v_k|^2 +- 2 u.v_k``: ``(|u|^2 + |v_k|^2, 2 u.v_k)``, each
    (3, P)."""
    uu = u[0] * u[0] + u[1] * u[1] + u[2] * u[2]
    base = [uu + vk[0] * vk[0] + vk[1] * vk[1] + vk[2] * vk[2] for vk in v]
    cross = [2 * (u[0] * vk[0] + u[1] * vk[1] + u[2] * vk[2]) for vk in v]
    return np.stack(base), np.stack(cross)


def _mean_softplus(base: np.ndarray, quad: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """Mean over the six sigma points of ``softplus(base - quad_k / 2)``, ``quad_k`` each point's
    squared distance (``s +- c`` for ``quad = (s, c)``)."""
    s, c = quad
    t = np.concatenate([base - 0.5 * (s + c), base - 0.5 * (s - c)])
    return (np.maximum(t, 0) + np.log1p(np.exp(-np.abs(t)))).mean(axis=0)
