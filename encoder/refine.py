"""Polynomial-regression refinement of clusters into sketch and patch Gaussians (paper sections
"Adaptive Polynomial Regression-Based Refinement", "Iterative Cluster Splitting" and
"Post-processing and Outlier Removal").

Input: a cloud and cluster labels from categorization (``-1`` = noise). Output
(:class:`RefineResult`): accepted sketch clusters (index arrays into the cloud) with their float16
models, and the patch indices. Every input Gaussian ends up exactly once in one or the other.

Per cluster (a *node* of the splitting tree):

1. fewer than ``s_min`` Gaussians -> patch;
2. fit models (:func:`~spcodec.encoder.polyfit.fit_cluster`); if the decoded ``MSE_combined <=
   tau_max`` the node is accepted, then cleaned by the IQR filter (:func:`iqr_filter`);
3. otherwise, at depth ``t_max`` -> patch (so *every* accepted cluster meets tau_max);
4. otherwise, if the node is a part whose own models do not beat its parent's models on the same
   Gaussians by ``min_split_gain`` -> patch (splitting is not isolating anything coherent: the
   Gaussians are noise at this scale, and recursing to ``s_min`` would only cost fits);
5. otherwise split by K-means on ``F = [beta * R || (1 - beta) * X]`` (``R`` = absolute normalized
   residuals of the four combined attributes, ``X`` = positions centred on the box and divided by
   its largest half extent, so the split sees the cluster's true shape) into
   ``k = clamp(ceil(MSE / tau_max), 2, min(k_max, n // s_min))`` parts: a cluster just over the
   threshold is halved, one several times over it is cut into up to ``k_max``; each part is a new
   node one level deeper.

Nodes are independent, so they run in a process pool as a work queue (a split submits its
children), largest first. Each node's outcome is a pure function of its indices, the
configuration and the scene-wide scales, BLAS and OpenMP are held to one thread per worker, and
accepted clusters are ordered by their position in the splitting tree, so the result does not depend
on ``n_jobs`` or on completion order.
"""

from __future__ import annotations

import math
import multiprocessing
import time
from collections import deque
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from spcodec.attributes import SketchAttribute, decode_rotation, encode_opacity
from spcodec.cloud import GaussianCloud

from .config import RefineConfig
from .polyfit import (
    COMBINED_ATTRIBUTES,
    AttributeScales,
    ClusterFit,
    align_quaternions,
    attribute_errors,
    fit_cluster_detailed,
    refit_or_keep,
)
from .threads import default_jobs

__all__ = ["RefineConfig", "RefineResult", "RefineStats", "refine", "iqr_filter", "iqr_outliers"]


# ------------------------------------------------------------------------------------ results
PATCH_REASONS = ("noise", "small", "depth", "no_gain", "unsplittable", "iqr")
"""Why Gaussians went to patch: unclustered, cluster/part below s_min, still failing at t_max,
failing part no better than its parent (min_split_gain), K-means could not split a failing node,
IQR outliers (or a cluster the IQR step emptied)."""


@dataclass
class RefineStats:
    """Counts and timings of one refinement run."""

    input_clusters: int = 0
    accepted_clusters: int = 0
    sketch_gaussians: int = 0
    patch_gaussians: int = 0
    patch_by_reason: dict[str, int] = field(default_factory=lambda: dict.fromkeys(PATCH_REASONS, 0))
    fits: int = 0
    """Model fits run (nodes plus IQR refits)."""
    splits: int = 0
    """Nodes split by K-means."""
    iqr_refits: int = 0
    iqr_dropped_clusters: int = 0
    """Accepted clusters the IQR step sent wholly to patch (too few survivors, or no model of the
    survivors meeting tau_max)."""
    max_depth: int = 0
    coefficient_bytes: int = 0
    seconds: dict[str, float] = field(default_factory=dict)
    """'total' and 'setup' wall time; 'nodes_cpu' CPU time of node processing summed over workers
    (the machine-independent part: on a shared machine wall time also measures the neighbours)."""


@dataclass
class RefineResult:
    """Outcome of :func:`refine`: sketch clusters with their models, and the patch set."""

    clusters: list[np.ndarray]
    """int64 indices into the cloud, ascending within each cluster; ordered by splitting tree."""
    fits: list[ClusterFit]
    """The models of each cluster, fitted at the cloud's positions."""
    patch: np.ndarray
    """int64 ascending indices of every Gaussian not in a sketch cluster."""
    scales: AttributeScales
    """The scene-wide scales the normalized errors used (reuse them when refitting on
    Draco-decoded positions, so thresholds keep their meaning)."""
    stats: RefineStats


# ------------------------------------------------------------------------------------ targets
@dataclass
class _SceneArrays:
    """Coded-domain attributes of the whole scene, gathered per node (sign alignment of rotations
    is per node, so it is redone for every subset)."""

    positions: np.ndarray
    scales: np.ndarray
    quats: np.ndarray
    opacity: np.ndarray
    dc: np.ndarray
    rest: np.ndarray | None

    @classmethod
    def from_cloud(cls, cloud: GaussianCloud, with_rest: bool) -> "_SceneArrays":
        rest = None
        if with_rest and cloud.sh_rest.shape[1]:
            rest = cloud.sh_rest.reshape(len(cloud), -1)
        return cls(cloud.means, cloud.scales, decode_rotation(cloud.quats),
                   encode_opacity(cloud.opacities)[:, None], cloud.sh_dc, rest)

    def targets(self, idx: np.ndarray) -> dict[SketchAttribute, np.ndarray]:
        out = {
            SketchAttribute.SCALE: self.scales[idx].astype(np.float64),
            SketchAttribute.ROTATION: align_quaternions(self.quats[idx]),
            SketchAttribute.OPACITY: self.opacity[idx],
            SketchAttribute.COLOR_DC: self.dc[idx].astype(np.float64),
        }
        if self.rest is not None:
            out[SketchAttribute.SH_REST] = self.rest[idx].astype(np.float64)
        return out


@dataclass
class _Context:
    """Everything a node needs besides its indices (shipped once per worker)."""

    scene: _SceneArrays
    config: RefineConfig
    scales: AttributeScales


_WORKER: _Context | None = None
_THREAD_LIMIT = None


def _init_worker(ctx: _Context) -> None:
    """Pool initializer: keep the scene and hold BLAS/OpenMP to one thread (determinism, and no
    oversubscription when every core already runs a worker)."""
    global _WORKER, _THREAD_LIMIT
    from threadpoolctl import threadpool_limits
    _WORKER = ctx
    _THREAD_LIMIT = threadpool_limits(limits=1)


# ------------------------------------------------------------------------------------- nodes
@dataclass
class _NodeResult:
    """What one node produced: accepted clusters, patch pieces, children to process."""

    key: tuple[int, ...]
    accepted: list[tuple[np.ndarray, ClusterFit]] = field(default_factory=list)
    patch: list[tuple[np.ndarray, str]] = field(default_factory=list)
    children: list[tuple[tuple[int, ...], np.ndarray, float]] = field(default_factory=list)
    """(key, indices, this node's MSE_combined on the part) of each part to process next."""
    fits: int = 0
    split: bool = False
    iqr_refits: int = 0
    iqr_dropped: bool = False
    seconds: float = 0.0


def _process_node(key: tuple[int, ...], idx: np.ndarray, parent_mse: float = np.inf
                  ) -> _NodeResult:
    """Fit one node and decide: accept (then IQR), patch, or split into children.

    ``key`` is the node's path in the splitting tree (root label, then part numbers), which also
    orders the final clusters; ``parent_mse`` the parent's MSE_combined on these Gaussians.
    """
    t0 = time.process_time()
    ctx = _WORKER
    assert ctx is not None, "worker not initialized"
    cfg = ctx.config
    out = _NodeResult(key)
    depth = len(key) - 1
    if idx.size < cfg.s_min:
        out.patch.append((idx, "small"))
        out.seconds = time.process_time() - t0
        return out
    positions = ctx.scene.positions[idx]
    targets = ctx.scene.targets(idx)
    fit, res = fit_cluster_detailed(positions, targets, cfg, ctx.scales)
    out.fits += 1
    if fit.mse_combined <= cfg.tau_max:
        _accept(out, idx, positions, targets, fit, res, ctx)
    elif depth >= cfg.t_max:
        out.patch.append((idx, "depth"))
    elif cfg.min_split_gain is not None and \
            fit.mse_combined > parent_mse * (1.0 - cfg.min_split_gain):
        out.patch.append((idx, "no_gain"))
    else:
        parts = split_node(positions, res, fit, ctx.scales, cfg)
        if len(parts) < 2:
            out.patch.append((idx, "unsplittable"))
        else:
            out.split = True
            out.children = [(key + (j,), idx[p], _part_error(res, p, ctx)) for j, p in
                            enumerate(parts)]
    out.seconds = time.process_time() - t0
    return out


def _part_error(res: dict[SketchAttribute, np.ndarray], part: np.ndarray, ctx: _Context) -> float:
    """MSE_combined of the parent's models on one part's Gaussians: the baseline the part's own
    models must beat by ``min_split_gain`` (comparing with the parent's whole-cluster error would
    penalize exactly the part that holds the parent's worst region)."""
    sub = {a: r[part] for a, r in res.items()}
    return attribute_errors(sub, ctx.scales, ctx.config.weights)[2]


def _accept(out: _NodeResult, idx: np.ndarray, positions: np.ndarray,
            targets: dict[SketchAttribute, np.ndarray], fit: ClusterFit,
            res: dict[SketchAttribute, np.ndarray], ctx: _Context) -> None:
    """Accept a node, after moving its IQR outliers to patch."""
    if ctx.config.iqr_k is None:
        out.accepted.append((idx, fit))
        return
    keep, kept_fit, refits = iqr_filter(positions, targets, fit, res[SketchAttribute.SCALE],
                                        ctx.config, ctx.scales)
    out.fits += refits
    out.iqr_refits += refits
    if (~keep).any():
        out.patch.append((idx[~keep], "iqr"))
    if kept_fit is not None:
        out.accepted.append((idx[keep], kept_fit))
    else:
        out.iqr_dropped = True


# ----------------------------------------------------------------------------------- splitting
def choose_k(mse_combined: float, n: int, config: RefineConfig) -> int:
    """Parts of a split: ``clamp(ceil(MSE / tau_max), 2, min(k_max, n // s_min))``.

    The paper allows k in [2, min(4, ceil(MSE / tau) + 1)]; taking ``ceil(MSE / tau)`` inside that
    range maps severity to k (just over tau -> 2 halves, 3x over -> 3, 4x+ -> 4), and capping by
    ``n // s_min`` avoids making parts that are doomed to be too small (but never below 2).
    """
    severity = math.ceil(mse_combined / config.tau_max) if np.isfinite(mse_combined) else \
        config.k_max
    upper = max(2, min(config.k_max, n // max(config.s_min, 1)))
    return int(min(max(severity, 2), upper))


def split_features(positions: np.ndarray, res: dict[SketchAttribute, np.ndarray], fit: ClusterFit,
                   scales: AttributeScales, beta: float) -> np.ndarray:
    """``F = [beta * R || (1 - beta) * X]`` for K-means (see the module docstring)."""
    r = np.concatenate([np.abs(res[a]) / scales.values[a] for a in COMBINED_ATTRIBUTES], axis=1)
    center = fit.frame.center.astype(np.float64)
    x = (positions.astype(np.float64) - center) / float(fit.frame.half_extent.max())
    feats = np.concatenate([beta * r, (1.0 - beta) * x], axis=1)
    return np.nan_to_num(feats, nan=0.0, posinf=1e6, neginf=-1e6)


def split_node(positions: np.ndarray, res: dict[SketchAttribute, np.ndarray], fit: ClusterFit,
               scales: AttributeScales, config: RefineConfig) -> list[np.ndarray]:
    """K-means parts of a failing node, as ascending local index arrays (empty parts dropped)."""
    from sklearn.cluster import KMeans

    n = positions.shape[0]
    k = choose_k(fit.mse_combined, n, config)
    feats = split_features(positions, res, fit, scales, config.beta)
    train = feats
    if n > config.kmeans_max_samples:
        rng = np.random.default_rng(config.random_state)
        train = feats[np.sort(rng.choice(n, config.kmeans_max_samples, replace=False))]
    if np.unique(train, axis=0).shape[0] < k:
        return []
    km = KMeans(n_clusters=k, n_init=config.kmeans_n_init, random_state=config.random_state)
    km.fit(train)
    labels = km.labels_ if train is feats else km.predict(feats)
    parts = [np.flatnonzero(labels == j) for j in range(k)]
    return [p for p in parts if p.size]


# --------------------------------------------------------------------------------------- IQR
def iqr_outliers(values: np.ndarray, k: float, min_spread: float = 0.0) -> np.ndarray:
    """Rows with any column outside Tukey's fences ``[Q1 - k IQR, Q3 + k IQR]`` (per column), the
    IQR floored at ``min_spread``."""
    v = np.asarray(values, dtype=np.float64).reshape(values.shape[0], -1)
    if v.shape[0] == 0:
        return np.zeros(0, dtype=bool)
    q1, q3 = np.percentile(v, [25.0, 75.0], axis=0)
    spread = np.maximum(q3 - q1, min_spread)
    return ((v < q1 - k * spread) | (v > q3 + k * spread)).any(axis=1)


def iqr_filter(positions: np.ndarray, targets: dict[SketchAttribute, np.ndarray], fit: ClusterFit,
               scale_residuals: np.ndarray, config: RefineConfig, scales: AttributeScales
               ) -> tuple[np.ndarray, ClusterFit | None, int]:
    """Move a cluster's scale IQR outliers out, and re-model what is left.

    ``scale_residuals`` (n, 3) are decoded minus original log scales (the SCALE entry of
    :func:`~spcodec.encoder.polyfit.residuals`); the fences go on them or on the decoded log
    scales per ``config.iqr_quantity``. Scope is per cluster: the failure targeted is a cluster's
    own model misrepresenting some of its Gaussians (overshoot at its ends, or a Gaussian far from
    its neighbours' size), which is extreme relative to that cluster but would hide among other
    clusters' legitimately different sizes and errors in scene-wide quartiles.

    Survivors are refit (their bounding box, hence frame, changed, and the outliers no longer pull
    the fit) with :func:`~spcodec.encoder.polyfit.refit_or_keep`: the refit if it meets tau_max,
    else the original models if they meet it on the survivors, else the cluster goes to patch.
    Fewer than ``s_min`` survivors also go to patch. One pass: the refit's own outliers are not
    hunted again.

    Returns ``(keep mask, fit of the kept Gaussians or None, number of refits run)``; the mask is
    all False when the whole cluster goes to patch.
    """
    values = scale_residuals
    if config.iqr_quantity == "decoded":
        values = targets[SketchAttribute.SCALE] + scale_residuals
    n = positions.shape[0]
    out_mask = iqr_outliers(values, config.iqr_k if config.iqr_k is not None else np.inf,
                            config.iqr_min_spread)
    if not out_mask.any():
        return np.ones(n, dtype=bool), fit, 0
    keep = ~out_mask
    if keep.sum() < config.s_min:
        return np.zeros(n, dtype=bool), None, 0
    kept = refit_or_keep(fit, positions[keep], {a: v[keep] for a, v in targets.items()}, config,
                         scales)
    if kept.mse_combined <= config.tau_max:
        return keep, kept, 1
    return np.zeros(n, dtype=bool), None, 1


# -------------------------------------------------------------------------------------- driver
def _roots(labels: np.ndarray) -> list[tuple[tuple[int, ...], np.ndarray]]:
    """One node per non-negative label, indices ascending, keyed by label."""
    clustered = np.flatnonzero(labels >= 0)
    if clustered.size == 0:
        return []
    order = clustered[np.argsort(labels[clustered], kind="stable")]
    values, starts = np.unique(labels[order], return_index=True)
    groups = np.split(order, starts[1:])
    return [((int(v),), g) for v, g in zip(values, groups)]


def _run_serial(ctx: _Context, roots: list) -> list[_NodeResult]:
    from threadpoolctl import threadpool_limits

    global _WORKER
    previous, _WORKER = _WORKER, ctx
    results: list[_NodeResult] = []
    queue = deque(roots)
    try:
        with threadpool_limits(limits=1):
            while queue:
                r = _process_node(*queue.popleft())
                results.append(r)
                queue.extend(r.children)
    finally:
        _WORKER = previous
    return results


_BATCH_POINTS = 8192
_BATCH_NODES = 64


def _process_batch(nodes: list[tuple]) -> list[_NodeResult]:
    """Several small nodes in one task: a task costs ~1 ms of pickling and queueing in the parent,
    as much as fitting a small node."""
    return [_process_node(*node) for node in nodes]


def _take_batch(todo: deque) -> list[tuple]:
    """Pop nodes off the front until the batch holds enough points or nodes."""
    batch, points = [], 0
    while todo and points < _BATCH_POINTS and len(batch) < _BATCH_NODES:
        node = todo.popleft()
        batch.append(node)
        points += node[1].size
    return batch


def _run_pool(ctx: _Context, roots: list, n_jobs: int) -> list[_NodeResult]:
    """Work queue over a process pool: at most ``2 * n_jobs`` batches in flight (keeps workers fed
    without flooding the pipes), results collected through a completion queue in O(1) each."""
    import queue

    import sklearn.cluster  # noqa: F401 - imported once here, inherited by forked workers

    methods = multiprocessing.get_all_start_methods()
    mp_ctx = multiprocessing.get_context("fork" if "fork" in methods else None)
    todo = deque(sorted(roots, key=lambda r: -r[1].size))
    finished: queue.SimpleQueue = queue.SimpleQueue()
    results: list[_NodeResult] = []
    in_flight = 0
    with ProcessPoolExecutor(n_jobs, mp_context=mp_ctx, initializer=_init_worker,
                             initargs=(ctx,)) as pool:
        while todo or in_flight:
            while todo and in_flight < 2 * n_jobs:
                future = pool.submit(_process_batch, _take_batch(todo))
                future.add_done_callback(finished.put)
                in_flight += 1
            batch = finished.get().result()
            in_flight -= 1
            for r in batch:
                results.append(r)
                todo.extend(r.children)
    return results


def refine(cloud: GaussianCloud, labels: np.ndarray, config: RefineConfig | None = None,
           n_jobs: int | None = None, scales: AttributeScales | None = None) -> RefineResult:
    """Refine clusters into accepted sketch clusters with models, and patch (module docstring).

    ``labels`` (N,) int: cluster id per Gaussian, negative = noise. ``n_jobs`` worker processes
    (default: the cores available; 1 runs in this process). ``scales`` defaults to
    :meth:`AttributeScales.from_cloud` of ``cloud``.
    """
    t0 = time.perf_counter()
    cfg = RefineConfig() if config is None else config
    labels = np.asarray(labels)
    if labels.shape != (len(cloud),):
        raise ValueError(f"labels have shape {labels.shape}, expected ({len(cloud)},)")
    if scales is None:
        scales = AttributeScales.from_cloud(cloud, sh_rest=cfg.sh_rest_degree is not None)
    ctx = _Context(_SceneArrays.from_cloud(cloud, cfg.sh_rest_degree is not None), cfg, scales)
    roots = _roots(labels.astype(np.int64))
    jobs = default_jobs() if n_jobs is None else max(1, int(n_jobs))
    t1 = time.perf_counter()
    if jobs == 1 or len(roots) <= 1:
        results = _run_serial(ctx, roots)
    else:
        results = _run_pool(ctx, roots, min(jobs, len(roots)))
    result = _assemble(results, labels, scales, len(roots))
    result.stats.seconds.update(setup=t1 - t0, total=time.perf_counter() - t0)
    return result


def _assemble(results: list[_NodeResult], labels: np.ndarray, scales: AttributeScales,
              input_clusters: int) -> RefineResult:
    """Order accepted clusters by tree key, gather patch indices, and count."""
    stats = RefineStats(input_clusters=input_clusters)
    accepted: list[tuple[tuple[int, ...], np.ndarray, ClusterFit]] = []
    patch_parts = [np.flatnonzero(labels < 0).astype(np.int64)]
    stats.patch_by_reason["noise"] = int(patch_parts[0].size)
    node_seconds = 0.0
    for r in results:
        accepted.extend((r.key, idx, fit) for idx, fit in r.accepted)
        for idx, reason in r.patch:
            patch_parts.append(idx)
            stats.patch_by_reason[reason] += int(idx.size)
        stats.fits += r.fits
        stats.splits += int(r.split)
        stats.iqr_refits += r.iqr_refits
        stats.iqr_dropped_clusters += int(r.iqr_dropped)
        stats.max_depth = max(stats.max_depth, len(r.key) - 1)
        node_seconds += r.seconds
    accepted.sort(key=lambda a: a[0])
    clusters = [idx.astype(np.int64) for _, idx, _ in accepted]
    fits = [fit for _, _, fit in accepted]
    patch = np.sort(np.concatenate(patch_parts)).astype(np.int64)
    stats.accepted_clusters = len(clusters)
    stats.sketch_gaussians = int(sum(c.size for c in clusters))
    stats.patch_gaussians = int(patch.size)
    stats.coefficient_bytes = int(sum(f.coefficient_bytes() for f in fits))
    stats.seconds["nodes_cpu"] = node_seconds
    return RefineResult(clusters, fits, patch, scales, stats)
