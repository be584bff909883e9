"""Sketch encoding: accepted clusters -> Draco positions + float16 models fitted on decoded positions.

For each cluster the refinement accepted, positions go through Draco with the scene-wide
quantization step; the decoded points are matched back to their Gaussians; the models are refitted
on the *decoded* positions with those Gaussians' attributes (:func:`refit_or_keep`), and measured
through the decoder's own evaluation. A cluster whose models no longer meet the error threshold
after the positions moved returns to patch, as do Gaussians Draco would merge with another.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from spcodec.cloud import GaussianCloud
from spcodec.sections import SketchCluster

from .config import RefineConfig, SketchConfig
from .draco import encode_cluster, encode_ordered, grid_for, robust_diameter
from .morton import morton_codes
from .polyfit import AttributeScales, ClusterFit, coded_targets, refit_or_keep
from .refine import RefineResult

#: Mean Euclidean error of uniform quantization with step s, for a point uniform in its cell.
MEAN_ERROR_PER_STEP = 0.4803


@dataclass
class SketchEncoding:
    """The encoded clusters and where every input Gaussian went."""

    clusters: list[SketchCluster]
    fits: list[ClusterFit]
    sources: list[np.ndarray]
    """Per encoded cluster: input indices of its Gaussians in decoded (Draco) order."""
    to_patch: np.ndarray
    """Input indices sent back to patch by this stage (duplicates, clusters that failed)."""
    step: float
    diameter: float
    stats: dict[str, int] = field(default_factory=dict)


class SketchEncoder:
    """Encode the clusters of a :class:`RefineResult` (see the module docstring)."""

    def __init__(self, config: SketchConfig | None = None,
                 refine_config: RefineConfig | None = None) -> None:
        self.config = config or SketchConfig()
        self.refine_config = refine_config or RefineConfig()

    def quantization_step(self, cloud: GaussianCloud) -> tuple[float, float]:
        """The scene-wide Draco step and the robust diameter it was derived from."""
        diameter = robust_diameter(cloud.means.astype(np.float64))
        return self.config.position_error * diameter / MEAN_ERROR_PER_STEP, diameter

    def encode(self, cloud: GaussianCloud, refined: RefineResult, progress=None) -> SketchEncoding:
        step, diameter = self.quantization_step(cloud)
        out = SketchEncoding([], [], [], np.zeros(0, np.int64), step, diameter,
                             {"duplicates": 0, "rejected_clusters": 0, "rejected_gaussians": 0})
        if self.config.grouping == "run" and refined.clusters:
            done = self._encode_run(cloud, refined, step, out, progress)
            if done:
                return out
        return self._encode_per_cluster(cloud, refined, step, out, progress)

    # ------------------------------------------------------------------- one blob per cluster
    def _encode_per_cluster(self, cloud, refined, step, out, progress) -> SketchEncoding:
        back: list[np.ndarray] = []
        for members, fit in zip(refined.clusters, refined.fits):
            draco = encode_cluster(cloud.means[members], step, self.config.draco_compression_level)
            order, duplicates = members[draco.source], members[draco.dropped]
            new_fit = self._refit(cloud, order, draco.positions, fit, refined.scales)
            if progress is not None:
                progress(1)
            if new_fit is None:
                self._reject(out, members, back)
                continue
            self._accept(out, draco.blob, order, new_fit)
            out.stats["duplicates"] += len(duplicates)
            back.append(duplicates)
        out.to_patch = _sorted_union(back)
        return out

    # ------------------------------------------------------------ one blob for every cluster
    def _encode_run(self, cloud, refined, step, out, progress) -> bool:
        """All clusters in one order-preserving blob; False when Draco did not keep the order."""
        means = cloud.means.astype(np.float64)
        every = np.concatenate(refined.clusters)
        origin, bits = grid_for(means[every], step)
        rank = np.argsort(morton_codes(np.stack([means[m].mean(axis=0)
                                                 for m in refined.clusters])), kind="stable")
        members = [_morton_sorted(refined.clusters[i], means) for i in rank]
        fits = [refined.fits[i] for i in rank]
        level = self.config.draco_compression_level
        first = encode_ordered(means[np.concatenate(members)], step, origin, bits, level)
        if first is None:
            return False
        kept, back, offset = [], [], 0
        for m, fit in zip(members, fits):
            positions = first.positions[offset:offset + len(m)]
            offset += len(m)
            new_fit = self._refit(cloud, m, positions, fit, refined.scales)
            if progress is not None:
                progress(1)
            if new_fit is None:
                self._reject(out, m, back)
            else:
                kept.append((m, positions, new_fit))
        blob = first.blob
        if back:  # rebuild without the rejected clusters: same grid, so survivors decode alike
            final = encode_ordered(means[np.concatenate([k[0] for k in kept])], step, origin,
                                   bits, level) if kept else None
            if kept and (final is None or not np.array_equal(
                    final.positions, np.concatenate([k[1] for k in kept]))):
                return False
            blob = final.blob if kept else b""
        for i, (m, _, new_fit) in enumerate(kept):
            self._accept(out, blob if i == 0 else b"", m, new_fit)
        out.to_patch = _sorted_union(back)
        return True

    # ------------------------------------------------------------------------------ helpers
    def _refit(self, cloud: GaussianCloud, order: np.ndarray, positions: np.ndarray,
               fit: ClusterFit, scales: AttributeScales) -> ClusterFit | None:
        """Models refitted on decoded positions, or None when the cluster must return to patch."""
        if len(order) < self.refine_config.s_min:
            return None
        targets = coded_targets(cloud, order, sh_rest=self.refine_config.sh_rest_degree is not None)
        new_fit = refit_or_keep(fit, positions, targets, self.refine_config, scales)
        if new_fit.mse_combined > self.refine_config.tau_max * self.config.tau_tolerance:
            return None
        return new_fit

    @staticmethod
    def _accept(out: SketchEncoding, blob: bytes, order: np.ndarray, fit: ClusterFit) -> None:
        out.clusters.append(SketchCluster(blob, len(order), fit.frame.center,
                                          fit.frame.half_extent, fit.models))
        out.fits.append(fit)
        out.sources.append(order)

    @staticmethod
    def _reject(out: SketchEncoding, members: np.ndarray, back: list[np.ndarray]) -> None:
        out.stats["rejected_clusters"] += 1
        out.stats["rejected_gaussians"] += len(members)
        back.append(members)


def _morton_sorted(members: np.ndarray, means: np.ndarray) -> np.ndarray:
    """A cluster's members along a Morton curve, so consecutive deltas in the blob are small."""
    return members[np.argsort(morton_codes(means[members]), kind="stable")]


def _sorted_union(parts: list[np.ndarray]) -> np.ndarray:
    return np.sort(np.concatenate(parts)) if parts else np.zeros(0, np.int64)
