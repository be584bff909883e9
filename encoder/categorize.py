"""Multi-criteria DBSCAN: the first encoder stage, finding candidate sketch clusters.

Paper section "Categorizing Sketch and Patch Gaussians". Gaussian j is a *neighbour* of Gaussian i
when all three criteria hold:

* spatial:   ``|mu_i - mu_j| <= eps_s`` (world units);
* direction: ``d_dir(n_i, n_j) <= eps_d``, with ``n`` the principal axis (the world-space direction
  of the local axis with the largest scale) and ``d_dir`` defined in :func:`direction_distance`;
* colour:    ``|c_i - c_j| <= eps_c``, ``c = cloud.rgb()`` (the SH DC colour, RGB in [0, 1]).

The relation is symmetric, and a Gaussian is always its own neighbour (as in scikit-learn's
DBSCAN, ``min_samples`` counts the point itself). Core points have at least ``min_samples``
neighbours; clusters are the connected components of the graph of core points joined by the
neighbour relation; a non-core point with a core neighbour (a *border* point) joins the cluster of
its spatially nearest core neighbour (ties: lowest index), the rest is noise (label -1). Clusters
with fewer than ``min_cluster_size`` members then become noise too, and the survivors are numbered
0, 1, ... in the order of their smallest member index, so labels are canonical.

Scale: neighbour search is a chunked KD-tree radius query (:mod:`spcodec.encoder.neighbors`) with
the direction and colour criteria applied vectorized to each chunk's candidate pairs. Two passes
over the chunks keep memory bounded by the chunk size rather than the scene size: the first counts
neighbours (which fixes the core points), the second reduces each chunk's core-core edges to a
spanning forest and records each border point's nearest core. One global connected-components
call on the forest edges then labels the clusters.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable, Iterator

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from spcodec.attributes import canonical_rotation
from spcodec.cloud import GaussianCloud

from .config import CategorizeConfig, DirectionMetric
from .neighbors import (
    RadiusPairs,
    iter_radius_pairs,
    knn_distance_quantile,
    rowwise_dot,
    squared_distances,
)


# ------------------------------------------------------------------------------- per-Gaussian
def principal_axes(cloud: GaussianCloud) -> np.ndarray:
    """(N, 3) float64 unit vectors: each Gaussian's longest local axis rotated into world space.

    The quaternion is normalized first (a zero quaternion means the identity, as in the decoder);
    a tie between equal largest scales picks the first such axis.
    """
    quats = canonical_rotation(cloud.quats)
    longest = np.argmax(cloud.scales, axis=1)
    axes = np.empty((len(cloud), 3), np.float64)
    for k in range(3):
        selected = longest == k
        axes[selected] = _rotation_column(quats[selected], k)
    return axes / np.linalg.norm(axes, axis=1, keepdims=True)


def _rotation_column(quats: np.ndarray, k: int) -> np.ndarray:
    """Column ``k`` of the rotation matrices of unit quaternions (w, x, y, z): the image of the
    local axis ``k`` in world space."""
    w, x, y, z = quats.T
    if k == 0:
        return np.stack([1 - 2 * (y * y + z * z), 2 * (x * y + w * z), 2 * (x * z - w * y)], axis=1)
    if k == 1:
        return np.stack([2 * (x * y - w * z), 1 - 2 * (x * x + z * z), 2 * (y * z + w * x)], axis=1)
    return np.stack([2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)], axis=1)


def direction_distance(a: np.ndarray, b: np.ndarray, metric: DirectionMetric = "axis"
                       ) -> np.ndarray:
    """Direction distance between unit vectors ``a`` and ``b`` (rows), in [0, 1].

    ``"signed"`` is the paper's formula ``1 - (cos + 1) / 2 = (1 - cos) / 2``: 0 for equal vectors,
    1 for opposite ones. ``"axis"`` is ``(1 - |cos|) / 2``: the same formula after flipping ``b`` to
    the side of ``a``, so it agrees with the paper for axes within 90 degrees and ranges over
    [0, 0.5].

    The axis form is the default because a principal *axis* has no sign: the ellipsoids of ``v``
    and ``-v`` are identical (a 180-degree turn about a minor axis maps one onto the other), and
    which sign a trained Gaussian's rotation produces is an accident of optimization. (Negating
    the quaternion, q -> -q, does not flip the axis: both metrics are blind to it.) Measured with
    ``bench/bench_categorize.py --metrics`` and otherwise default settings:

    * fourth_st: 48.7 % of the spatial neighbours with near-parallel axes (|cos| >= 0.9) point
      opposite ways, i.e. signs are random; "signed" clusters 12.3 % of the Gaussians, "axis"
      32.6 %. On biker (5.5 % opposite) the two agree (52.9 % against 54.4 %): the axis form
      costs nothing where signs happen to be coherent.
    * synthetic curves (make_scene, 5 seeds) with half of the axes negated: "signed" recall drops
      from 0.997 to 0.899 and each curve splits into sign classes (48.6 clusters instead of 14.4,
      adjusted Rand index against the curves 0.48 instead of 0.98); "axis" is unchanged.
    """
    cos = np.clip(rowwise_dot(a, b), -1.0, 1.0)
    if metric == "axis":
        cos = np.abs(cos)
    elif metric != "signed":
        raise ValueError(f"unknown direction metric {metric!r}")
    return (1.0 - cos) / 2.0


def resolve_eps_s(points: np.ndarray, config: CategorizeConfig,
                  tree: cKDTree | None = None) -> float:
    """The spatial radius: ``config.eps_s`` if set, else derived from k-NN spacing (see config)."""
    if config.eps_s is not None:
        return float(config.eps_s)
    rng = np.random.default_rng(config.random_state)
    spacing = knn_distance_quantile(points, config.eps_s_knn, config.eps_s_quantile,
                                    config.eps_s_sample, rng, tree)
    return config.eps_s_factor * spacing


# --------------------------------------------------------------------------------- the graph
@dataclass(frozen=True)
class _AttributeCriteria:
    """The non-spatial neighbour criteria, applied to candidate pairs."""

    axes: np.ndarray
    rgb: np.ndarray
    eps_d: float
    eps_c: float
    metric: DirectionMetric

    def accept(self, pairs: RadiusPairs) -> RadiusPairs:
        """The pairs that also satisfy the direction and colour criteria."""
        r, c = pairs.rows, pairs.cols
        colour = np.take(self.rgb, r, axis=0) - np.take(self.rgb, c, axis=0)
        ok = rowwise_dot(colour, colour) <= self.eps_c * self.eps_c
        r, c = r[ok], c[ok]
        ok_dir = direction_distance(np.take(self.axes, r, axis=0), np.take(self.axes, c, axis=0),
                                    self.metric) <= self.eps_d
        ok[ok] = ok_dir
        return pairs.select(ok)


def _neighbour_pairs(points: np.ndarray, eps_s: float, criteria: _AttributeCriteria,
                     chunk_size: int, tree: cKDTree) -> Iterator[RadiusPairs]:
    """Chunks of ordered neighbour pairs (i != j) satisfying all three criteria."""
    for pairs in iter_radius_pairs(points, eps_s, chunk_size, tree):
        yield criteria.accept(pairs)


def _count_neighbours(pair_chunks: Iterable[RadiusPairs], n: int) -> np.ndarray:
    """Neighbour count per point, the point itself included (pass 1)."""
    counts = np.ones(n, np.int64)
    for pairs in pair_chunks:
        counts += np.bincount(pairs.rows, minlength=n)
    return counts


def _components(a: np.ndarray, b: np.ndarray, n: int) -> np.ndarray:
    """Connected-component id of each of ``n`` nodes of the undirected graph with edges (a, b).

    Boolean weights: repeated edges then merge to True instead of summing (and possibly wrapping
    around to an explicit zero in a small integer type).
    """
    graph = coo_matrix((np.ones(a.size, bool), (a, b)), shape=(n, n))
    return connected_components(graph, directed=False)[1]


def _spanning_forest(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Edges (node, root) connecting the same node sets as the edges (a, b), at most one per node.

    Reduces a chunk's core-core edges before they are kept, so memory grows with the number of
    core points rather than with the number of neighbour pairs.
    """
    if a.size == 0:
        return a, b
    nodes, local = np.unique(np.concatenate([a, b]), return_inverse=True)
    component = _components(local[:a.size], local[a.size:], nodes.size)
    _, first = np.unique(component, return_index=True)  # nodes are sorted: first = smallest
    root = nodes[first[component]]
    keep = nodes != root
    return nodes[keep], root[keep]


def _nearest_per_row(pairs: RadiusPairs, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each distinct row, its spatially nearest column (ties: lowest column index)."""
    sq_dist = squared_distances(points, pairs.rows, pairs.cols)
    order = np.lexsort((pairs.cols, sq_dist, pairs.rows))
    rows = pairs.rows[order]
    first = np.flatnonzero(np.r_[True, rows[1:] != rows[:-1]]) if rows.size else rows
    return rows[first], pairs.cols[order][first]


def _link_clusters(pair_chunks: Iterable[RadiusPairs], core: np.ndarray, points: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Pass 2: core-core forest edges and, per point, its nearest core neighbour (-1: none)."""
    n = core.size
    nearest_core = np.full(n, -1, np.int64)
    forest_a, forest_b = [], []
    for pairs in pair_chunks:
        core_row, core_col = core[pairs.rows], core[pairs.cols]
        both = core_row & core_col & (pairs.rows < pairs.cols)
        a, b = _spanning_forest(pairs.rows[both], pairs.cols[both])
        forest_a.append(a)
        forest_b.append(b)
        rows, cols = _nearest_per_row(pairs.select(~core_row & core_col), points)
        nearest_core[rows] = cols
    a = np.concatenate(forest_a) if forest_a else np.zeros(0, np.int64)
    b = np.concatenate(forest_b) if forest_b else np.zeros(0, np.int64)
    return np.stack([a, b]), nearest_core


def _raw_labels(forest: np.ndarray, nearest_core: np.ndarray, core: np.ndarray) -> np.ndarray:
    """Cluster ids (arbitrary non-negative numbers) for cores and borders, -1 for noise."""
    component = _components(forest[0], forest[1], core.size)
    labels = np.where(core, component, -1).astype(np.int64)
    border = ~core & (nearest_core >= 0)
    labels[border] = component[nearest_core[border]]
    return labels


def canonical_labels(raw: np.ndarray, min_cluster_size: int) -> np.ndarray:
    """Drop clusters smaller than ``min_cluster_size`` and renumber the rest 0, 1, ... by their
    smallest member index; ``raw`` holds arbitrary non-negative ids and -1 for noise."""
    labels = np.full(raw.size, -1, np.int64)
    members = np.flatnonzero(raw >= 0)
    if members.size == 0:
        return labels
    _, first, inverse, sizes = np.unique(raw[members], return_index=True, return_inverse=True,
                                         return_counts=True)
    kept = np.flatnonzero(sizes >= min_cluster_size)
    new_id = np.full(sizes.size, -1, np.int64)
    new_id[kept[np.argsort(members[first[kept]])]] = np.arange(kept.size)
    labels[members] = new_id[inverse]
    return labels


# ----------------------------------------------------------------------------------- the API
class MultiCriteriaDBSCAN:
    """DBSCAN over Gaussians with spatial, direction and colour criteria (module docstring).

    scikit-learn conventions: the constructor only stores its argument, :meth:`fit` returns
    ``self`` and sets the learned attributes (trailing underscore):

    * ``labels_`` (N,) int64 - cluster per Gaussian, -1 for noise;
    * ``core_sample_mask_`` (N,) bool - density core points (before ``min_cluster_size``, so a
      core of a dropped cluster is True here with label -1);
    * ``n_clusters_`` - number of clusters;
    * ``eps_s_`` - the spatial radius used, in scene units (resolved from k-NN spacing by default).
    """

    def __init__(self, config: CategorizeConfig | None = None) -> None:
        self.config = config

    def fit(self, cloud: GaussianCloud) -> "MultiCriteriaDBSCAN":
        """Cluster ``cloud``; returns ``self``."""
        config = self.config if self.config is not None else CategorizeConfig()
        points = cloud.means.astype(np.float64)
        if not np.isfinite(points).all():
            raise ValueError("Gaussian centres must be finite to be clustered")
        n = points.shape[0]
        tree = cKDTree(points)
        self.eps_s_ = resolve_eps_s(points, config, tree)
        criteria = _AttributeCriteria(principal_axes(cloud), cloud.rgb().astype(np.float64),
                                      config.eps_d, config.eps_c, config.direction_metric)

        def chunks() -> Iterator[RadiusPairs]:  # recomputed per pass instead of held in memory
            return _neighbour_pairs(points, self.eps_s_, criteria, config.chunk_size, tree)

        core = _count_neighbours(chunks(), n) >= config.min_samples  # pass 1
        forest, nearest_core = _link_clusters(chunks(), core, points)  # pass 2
        self.labels_ = canonical_labels(_raw_labels(forest, nearest_core, core),
                                        config.min_cluster_size)
        self.core_sample_mask_ = core
        self.n_clusters_ = int(self.labels_.max()) + 1 if n else 0
        return self

    def fit_predict(self, cloud: GaussianCloud) -> np.ndarray:
        """``fit(cloud).labels_``."""
        return self.fit(cloud).labels_


def categorize(cloud: GaussianCloud, config: CategorizeConfig | None = None) -> np.ndarray:
    """Cluster labels of ``cloud`` (-1 = noise, i.e. patch candidates); see the module docstring."""
    return MultiCriteriaDBSCAN(config).fit(cloud).labels_
