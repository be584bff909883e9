"""A Gaussian as one float32 row: the flat layout that leaves are spilled in and merged from.

Columns: ``means`` 3, ``scales`` 3, ``quats`` 4, ``opacities`` 1, ``sh_dc`` 3, then ``sh_rest``
coefficient-major (K x 3). One 2-D array per leaf is the cheapest thing to append to, memory-map
and hash; :class:`~spcodec.cloud.GaussianCloud` is what the encoder and the merge take.
"""

from __future__ import annotations

import numpy as np

from spcodec.cloud import SH_REST_COUNTS, GaussianCloud

FIXED_COLUMNS = 14
"""Columns before the higher SH coefficients."""


def row_width(sh_degree: int) -> int:
    """Floats per Gaussian at SH degree ``sh_degree``."""
    return FIXED_COLUMNS + 3 * SH_REST_COUNTS[sh_degree]


def cloud_to_rows(cloud: GaussianCloud) -> np.ndarray:
    """``cloud`` as an (n, row_width) float32 array."""
    n = len(cloud)
    return np.concatenate([cloud.means, cloud.scales, cloud.quats, cloud.opacities[:, None],
                           cloud.sh_dc, cloud.sh_rest.reshape(n, -1)], axis=1).astype(np.float32)


def rows_to_cloud(rows: np.ndarray) -> GaussianCloud:
    """The cloud held by rows made by :func:`cloud_to_rows` (copies)."""
    rows = np.asarray(rows, np.float32)
    k = (rows.shape[1] - FIXED_COLUMNS) // 3
    return GaussianCloud(means=rows[:, 0:3], scales=rows[:, 3:6], quats=rows[:, 6:10],
                         opacities=rows[:, 10], sh_dc=rows[:, 11:14],
                         sh_rest=rows[:, 14:].reshape(len(rows), k, 3))
