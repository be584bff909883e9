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

from .draco import encode_cluster, robust_diameter
from .polyfit import AttributeScales, ClusterFit, coded_targets, refit_or_keep
from .refine import RefineConfig, RefineResult

#: Mean Euclidean error of uniform quantization with step s, for a point uniform in its cell.
MEAN_ERROR_PER_STEP = 0.4803


@dataclass
class SketchConfig:
    """Parameters of sketch position coding and of the final acceptance of clusters."""

    #: Target mean position error of sketch Gaussians, relative to the scene's robust diameter
    #: (the paper reports a mean error below 0.04 %). The Draco quantization step is derived from
    #: it; smaller targets cost about 3 bits per point per halving.
    position_error: float = 3e-4
    #: Draco compression level (0..10; 10 is the smallest output, still fast for point clouds).
    draco_compression_level: int = 10
    #: A cluster whose models, refitted on decoded positions, exceed tau_max by more than this
    #: factor goes back to patch (refits move the error a little either way; 1.0 is strict).
    tau_tolerance: float = 1.05

    def __post_init__(self) -> None:
        if not 0 < self.position_error < 1:
            raise ValueError("position_error must lie in (0, 1)")
        if not 0 <= self.draco_compression_level <= 10:
            raise ValueError("draco_compression_level must be in 0..10")
        if self.tau_tolerance < 1:
            raise ValueError("tau_tolerance must be >= 1")


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
        sh_rest = self.refine_config.sh_rest_degree is not None
        out = SketchEncoding([], [], [], np.zeros(0, np.int64), step, diameter,
                             {"duplicates": 0, "rejected_clusters": 0, "rejected_gaussians": 0})
        back: list[np.ndarray] = []
        for members, fit in zip(refined.clusters, refined.fits):
            encoded = self._encode_one(cloud, members, fit, refined.scales, step, sh_rest)
            if progress is not None:
                progress(1)
            if encoded is None:
                out.stats["rejected_clusters"] += 1
                out.stats["rejected_gaussians"] += len(members)
                back.append(members)
                continue
            cluster, new_fit, order, duplicates = encoded
            out.clusters.append(cluster)
            out.fits.append(new_fit)
            out.sources.append(order)
            out.stats["duplicates"] += len(duplicates)
            back.append(duplicates)
        out.to_patch = np.sort(np.concatenate(back)) if back else np.zeros(0, np.int64)
        return out

    def _encode_one(self, cloud: GaussianCloud, members: np.ndarray, fit: ClusterFit,
                    scales: AttributeScales, step: float, sh_rest: bool):
        draco = encode_cluster(cloud.means[members], step, self.config.draco_compression_level)
        order = members[draco.source]
        duplicates = members[draco.dropped]
        if len(order) < self.refine_config.s_min:
            return None
        targets = coded_targets(cloud, order, sh_rest=sh_rest)
        new_fit = refit_or_keep(fit, draco.positions, targets, self.refine_config, scales)
        if new_fit.mse_combined > self.refine_config.tau_max * self.config.tau_tolerance:
            return None
        cluster = SketchCluster(draco.blob, len(order), new_fit.frame.center,
                                new_fit.frame.half_extent, new_fit.models)
        return cluster, new_fit, order, duplicates
