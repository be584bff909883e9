"""The encoder pipeline: categorize -> refine -> sketch -> patch -> bitstream.

``encode(cloud, config)`` runs the stages in order, each a small object configured by its part of
:class:`EncoderConfig`, and returns the file bytes together with everything a report needs: where
every input Gaussian went, sizes per section, timings, and the error of the decoded sketch
attributes against the originals (measured by decoding the file just written, with the decoder).
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from spcodec.attributes import decode_rotation
from spcodec.cloud import GaussianCloud
from spcodec.container import Codec
from spcodec.decoder import decode_layers, inspect
from spcodec.errors import FormatError, UsageError
from spcodec.writer import EncodedScene, WriteOptions, build_bitstream

from .categorize import CategorizeConfig, categorize
from .patch import PatchConfig, PatchEncoder
from .refine import RefineConfig, refine
from .sketch import SketchConfig, SketchEncoder

ProgressFactory = Callable[[str, int | None], "Stage"]


@dataclass
class EncoderConfig:
    """Every parameter of an encode. Stage configs are documented field by field in their modules.

    ``seed`` overrides the stages' own random states, so one number makes the encode reproducible.
    """

    categorize: CategorizeConfig = field(default_factory=CategorizeConfig)
    refine: RefineConfig = field(default_factory=RefineConfig)
    sketch: SketchConfig = field(default_factory=SketchConfig)
    patch: PatchConfig = field(default_factory=PatchConfig)
    #: Seed of every random choice (k-NN sampling, K-means, codebook training).
    seed: int = 0
    #: Worker processes for refinement (None: the available cores).
    n_jobs: int | None = None
    #: False encodes every Gaussian as patch (the baseline without structure).
    use_sketch: bool = True
    #: Section codec: "zlib" (the paper's; every decoder has it) or "zstd" (optional, faster).
    codec: str = "zlib"
    #: Wrap the file in gzip (the paper's final step; a few percent smaller).
    gzip: bool = False

    def seeded(self) -> "EncoderConfig":
        """A copy whose stage configs carry ``seed``."""
        return dataclasses.replace(
            self,
            categorize=dataclasses.replace(self.categorize, random_state=self.seed),
            refine=dataclasses.replace(self.refine, random_state=self.seed),
        )

    def to_json(self) -> dict:
        """Plain JSON-ready settings (stored in the file's metadata)."""
        return dataclasses.asdict(self)


@dataclass
class EncodeResult:
    """The file and the record of how it was made."""

    data: bytes
    scene: EncodedScene
    source_index: np.ndarray
    """For each Gaussian of the decoded file (in file order), the index of the input Gaussian."""
    stats: dict


class Stage:
    """Progress of one stage; the default prints nothing."""

    def update(self, count: int = 1) -> None:  # pragma: no cover - trivial
        pass

    def done(self, summary: str = "") -> None:  # pragma: no cover - trivial
        pass


def _silent(name: str, total: int | None) -> Stage:
    return Stage()


def validate_input(cloud: GaussianCloud) -> None:
    """One-line errors for inputs the encoder cannot take."""
    if len(cloud) == 0:
        raise UsageError("the scene has no Gaussians to encode")
    cloud.check_finite()
    if cloud.sh_degree > 3:  # pragma: no cover - GaussianCloud already enforces 0..3
        raise FormatError("SH degree above 3", "ply-invalid")


def encode(cloud: GaussianCloud, config: EncoderConfig | None = None,
           progress: ProgressFactory = _silent, source_name: str | None = None) -> EncodeResult:
    """Encode ``cloud`` into a bitstream (without retraining)."""
    config = (config or EncoderConfig()).seeded()
    validate_input(cloud)
    try:
        codec = Codec[config.codec.upper()]
    except KeyError:
        raise UsageError(f"unknown codec {config.codec!r}: use zlib or zstd") from None
    times: dict[str, float] = {}
    n = len(cloud)

    sketch_idx: list[np.ndarray] = []
    sketch_clusters, patch_idx = [], np.arange(n)
    sketch_stats: dict = {"clusters_found": 0, "clusters_accepted": 0}
    if config.use_sketch:
        t = time.perf_counter()
        stage = progress("categorize", None)
        labels = categorize(cloud, config.categorize)
        found = int(labels.max()) + 1 if len(labels) else 0
        stage.done(f"{found} clusters, {(labels >= 0).mean():.1%} of Gaussians clustered")
        times["categorize"] = time.perf_counter() - t

        t = time.perf_counter()
        stage = progress("refine", None)
        refined = refine(cloud, labels, config.refine, n_jobs=config.n_jobs)
        stage.done(f"{len(refined.clusters)} clusters accepted, "
                   f"{refined.stats.sketch_gaussians} sketch Gaussians")
        times["refine"] = time.perf_counter() - t

        t = time.perf_counter()
        stage = progress("sketch", len(refined.clusters))
        sketch = SketchEncoder(config.sketch, config.refine).encode(cloud, refined, stage.update)
        sketch_clusters, sketch_idx = sketch.clusters, sketch.sources
        patch_idx = np.sort(np.concatenate([refined.patch, sketch.to_patch]))
        stage.done(f"{len(sketch.clusters)} clusters, {sum(map(len, sketch_idx))} Gaussians "
                   f"(Draco step {sketch.step:.3g}, {sketch.stats['rejected_clusters']} clusters "
                   f"and {sketch.stats['duplicates']} duplicates back to patch)")
        times["sketch"] = time.perf_counter() - t
        sketch_stats = {"clusters_found": found, "clusters_accepted": len(refined.clusters),
                        "clusters_encoded": len(sketch.clusters), "draco_step": sketch.step,
                        "scene_diameter": sketch.diameter, **sketch.stats,
                        "refine": {"patch_by_reason": refined.stats.patch_by_reason,
                                   "splits": refined.stats.splits, "fits": refined.stats.fits}}

    t = time.perf_counter()
    stage = progress("patch", None)
    patch_cloud = cloud.subset(patch_idx)
    patch = PatchEncoder(config.patch, seed=config.seed).encode(patch_cloud)
    stage.done(f"{len(patch_idx)} Gaussians in {len(patch.layers)} layers")
    times["patch"] = time.perf_counter() - t

    t = time.perf_counter()
    stage = progress("write", None)
    metadata = {"encoder": "spcodec", "version": _version(), "source": source_name,
                "settings": config.to_json()}
    scene = EncodedScene(cloud.sh_degree, sketch_clusters, patch.codebooks,
                         patch.layers if len(patch_idx) else [], metadata)
    data = build_bitstream(scene, WriteOptions(codec=codec, gzip=config.gzip))
    source = np.concatenate(sketch_idx + [patch_idx[o] for o in patch.order]).astype(np.int64) \
        if (sketch_idx or len(patch_idx)) else np.zeros(0, np.int64)
    stage.done(f"{len(data)} bytes")
    times["write"] = time.perf_counter() - t

    stats = {
        "gaussians": n, "sketch_gaussians": int(sum(map(len, sketch_idx))),
        "patch_gaussians": int(len(patch_idx)), "patch_layers": len(scene.patch_layers),
        "sketch": sketch_stats, "bytes": len(data), "sections": section_sizes(data),
        "seconds": times,
    }
    stats["sketch_error"] = sketch_error(data, cloud, source, stats["sketch_gaussians"])
    return EncodeResult(data, scene, source, stats)


def section_sizes(data: bytes) -> dict[str, int]:
    """Stored bytes per section type (summed over layers)."""
    out: dict[str, int] = {}
    for sec in inspect(data).to_json()["sections"]:
        out[sec["type"]] = out.get(sec["type"], 0) + sec["length"]
    return out


def sketch_error(data: bytes, cloud: GaussianCloud, source: np.ndarray, count: int) -> dict:
    """Errors of the decoded sketch Gaussians against their originals (decoding layer 0)."""
    if count == 0:
        return {}
    decoded = decode_layers(data, max_layer=0).cloud
    orig = cloud.subset(source[:count])
    dq = decode_rotation(decoded.quats).astype(np.float64)
    oq = decode_rotation(orig.quats).astype(np.float64)
    angle = np.degrees(2 * np.arccos(np.clip(np.abs((dq * oq).sum(axis=1)), 0.0, 1.0)))
    diameter = float(np.linalg.norm(np.percentile(cloud.means, 99.5, axis=0)
                                    - np.percentile(cloud.means, 0.5, axis=0))) or 1.0
    position = np.linalg.norm(decoded.means - orig.means, axis=1) / diameter

    def summary(values: np.ndarray) -> dict[str, float]:
        return {"mean": float(values.mean()), "median": float(np.median(values)),
                "p95": float(np.percentile(values, 95)), "max": float(values.max())}

    return {
        "position_rel_diameter": summary(position),
        "log_scale_abs": summary(np.abs(decoded.scales - orig.scales).ravel()),
        "rotation_deg": summary(angle),
        "opacity_abs": summary(np.abs(decoded.activated_opacity() - orig.activated_opacity())),
        "color_dc_abs": summary(np.abs(decoded.rgb() - orig.rgb()).ravel()),
    }


def _version() -> str:
    from spcodec import __version__
    return __version__
