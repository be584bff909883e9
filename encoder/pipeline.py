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
from pathlib import Path
from typing import TYPE_CHECKING, Callable

import numpy as np

from spcodec.attributes import decode_rotation
from spcodec.cloud import GaussianCloud
from spcodec.container import Codec
from spcodec.decoder import decode_layers, inspect
from spcodec.errors import FormatError, UsageError
from spcodec.writer import EncodedScene, WriteOptions, build_bitstream

from .categorize import CategorizeConfig, categorize
from .patch import PatchConfig, PatchEncoder, PatchEncoding
from .refine import RefineConfig, refine
from .sketch import SketchConfig, SketchEncoder

if TYPE_CHECKING:
    from .retrain import RetrainConfig, RunControl

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
    #: Prune and retrain the patch (None: the no-retrain encoder). See encoder/retrain.py.
    retrain: "RetrainConfig | None" = None
    #: Rate control: aim the file at this many bytes (within 5 %) by choosing how many patch
    #: Gaussians survive pruning (None: the size follows from the settings).
    target_size: int | None = None

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
    """Progress of one stage; the default prints nothing. ``update`` may carry figures to show
    (training steps pass ``loss`` and ``psnr``)."""

    def update(self, count: int = 1, **figures: float) -> None:  # pragma: no cover - trivial
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
           progress: ProgressFactory = _silent, source_name: str | None = None,
           dataset: str | Path | None = None, control: "RunControl | None" = None) -> EncodeResult:
    """Encode ``cloud`` into a bitstream.

    With ``config.retrain`` set, the patch is pruned and retrained against ``dataset``'s training
    images (a folder the dataset loaders read) or, without one, against renders of ``cloud``
    itself (distillation); ``control`` carries the device, checkpoints and the stop request.
    ``config.target_size`` turns on rate control (:mod:`.ratecontrol`).
    """
    config = (config or EncoderConfig()).seeded()
    validate_input(cloud)
    if dataset is not None and config.retrain is None:
        raise UsageError("a dataset is only used for retraining: drop it or enable retraining")
    try:
        codec = Codec[config.codec.upper()]
    except KeyError:
        raise UsageError(f"unknown codec {config.codec!r}: use zlib or zstd") from None
    times: dict[str, float] = {}
    prepared = None
    if config.retrain is not None or config.target_size is not None:
        from .prune_retrain import prepare_targets
        from .retrain import RunControl

        control = control or RunControl()
        control.check_checkpoint()
        prepared = prepare_targets(cloud, config, dataset, control, progress, times)
    sketch = encode_sketch(cloud, config, progress, times)
    metadata = {"encoder": "spcodec", "version": _version(), "source": source_name,
                "settings": config.to_json()}
    writer = SceneWriter(cloud.sh_degree, sketch.clusters, metadata,
                         WriteOptions(codec=codec, gzip=config.gzip))
    patch_cloud = cloud.subset(sketch.patch_idx)
    extra: dict = {}
    if prepared is None:
        t = time.perf_counter()
        stage = progress("patch", None)
        patch = PatchEncoder(config.patch, seed=config.seed).encode(patch_cloud)
        rows = np.arange(len(patch_cloud))
        stage.done(f"{len(patch_cloud)} Gaussians in {len(patch.layers)} layers")
        times["patch"] = time.perf_counter() - t
    else:
        from .prune_retrain import encode_pruned_patch

        choice = encode_pruned_patch(cloud, sketch, patch_cloud, writer, config, prepared,
                                     dataset, control, progress, times)
        patch, rows, extra = choice.encoding, choice.rows, choice.stats

    t = time.perf_counter()
    stage = progress("write", None)
    data = writer.write(patch)
    patch_idx = sketch.patch_idx[rows]
    source = np.concatenate(sketch.sources + [patch_idx[o] for o in patch.order]).astype(np.int64) \
        if (sketch.sources or len(patch_idx)) else np.zeros(0, np.int64)
    stage.done(f"{len(data)} bytes")
    times["write"] = time.perf_counter() - t

    stats = {
        "gaussians": len(cloud), "sketch_gaussians": int(sum(map(len, sketch.sources))),
        "patch_gaussians": int(len(patch_idx)), "patch_layers": len(writer.scene(patch).patch_layers),
        "sketch": sketch.stats, "bytes": len(data), "sections": section_sizes(data),
        "seconds": times, **extra,
    }
    stats["sketch_error"] = sketch_error(data, cloud, source, stats["sketch_gaussians"])
    if config.retrain is not None:
        t = time.perf_counter()
        stage = progress("evaluate", None)
        stats["quality"] = judge(data, cloud, config.retrain, dataset, control)
        stage.done(f"PSNR {stats['quality']['psnr']:.2f} dB, SSIM {stats['quality']['ssim']:.4f} "
                   f"against {stats['quality']['against']}")
        times["evaluate"] = time.perf_counter() - t
    return EncodeResult(data, writer.scene(patch), source, stats)


def judge(data: bytes, original: GaussianCloud, retrain: "RetrainConfig",
          dataset: str | Path | None, control: "RunControl | None") -> dict:
    """Quality of the written file as ``spcodec eval`` measures it with its defaults: against the
    dataset's test images, or against renders of the original at the held-out sampled views
    (with the encode's ``up`` and ``antialiased``), so the two commands report the same PSNR."""
    from .evaluate import EvalConfig, evaluate_against_dataset, evaluate_against_reference

    device = control.device if control is not None else "auto"
    decoded = decode_layers(data).cloud
    if dataset is not None:
        report = evaluate_against_dataset(decoded, Path(dataset), EvalConfig(
            downscale=retrain.downscale, device=device))
        against = f"the test images of {dataset}"
    else:
        report = evaluate_against_reference(decoded, original, EvalConfig(
            device=device, up=retrain.up, antialiased=retrain.antialiased))
        against = "renders of the original at held-out views"
    doc = report.to_json()
    return {"psnr": doc["psnr"], "ssim": doc["ssim"], "lpips": doc["lpips"],
            "views": doc["views"], "width": doc["width"], "height": doc["height"],
            "against": against}


@dataclass
class SketchOutcome:
    """The sketch stage's result: encoded clusters and where every input Gaussian went."""

    clusters: list
    sources: list[np.ndarray]
    """Per encoded cluster, the indices of its input Gaussians in stored order."""
    patch_idx: np.ndarray
    """Sorted indices of the input Gaussians left to the patch."""
    stats: dict


def encode_sketch(cloud: GaussianCloud, config: EncoderConfig, progress: ProgressFactory,
                  times: dict[str, float]) -> SketchOutcome:
    """Categorize, refine and encode the sketch (nothing when ``use_sketch`` is off)."""
    if not config.use_sketch:
        return SketchOutcome([], [], np.arange(len(cloud)),
                             {"clusters_found": 0, "clusters_accepted": 0})
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
    patch_idx = np.sort(np.concatenate([refined.patch, sketch.to_patch]))
    stage.done(f"{len(sketch.clusters)} clusters, {sum(map(len, sketch.sources))} Gaussians "
               f"(Draco step {sketch.step:.3g}, {sketch.stats['rejected_clusters']} clusters "
               f"and {sketch.stats['duplicates']} duplicates back to patch)")
    times["sketch"] = time.perf_counter() - t
    stats = {"clusters_found": found, "clusters_accepted": len(refined.clusters),
             "clusters_encoded": len(sketch.clusters), "draco_step": sketch.step,
             "scene_diameter": sketch.diameter, **sketch.stats,
             "refine": {"patch_by_reason": refined.stats.patch_by_reason,
                        "splits": refined.stats.splits, "fits": refined.stats.fits}}
    return SketchOutcome(sketch.clusters, sketch.sources, patch_idx, stats)


@dataclass
class SceneWriter:
    """Writes the file of one scene for any patch encoding (the sketch and metadata are fixed),
    so rate control can size trial files exactly as the final one."""

    sh_degree: int
    sketch: list
    metadata: dict
    options: WriteOptions

    def scene(self, patch: PatchEncoding | None) -> EncodedScene:
        if patch is None:
            return EncodedScene(self.sh_degree, self.sketch, [], [], self.metadata)
        layers = patch.layers if sum(map(len, patch.layers)) else []
        return EncodedScene(self.sh_degree, self.sketch, patch.codebooks, layers, self.metadata)

    def write(self, patch: PatchEncoding | None) -> bytes:
        return build_bitstream(self.scene(patch), self.options)

    def decoded_sketch(self) -> GaussianCloud:
        """The sketch exactly as a decoder will see it (layer 0 of a sketch-only file)."""
        return decode_layers(self.write(None), max_layer=0).cloud


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
