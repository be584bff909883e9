"""The encoder pipeline: categorize -> refine -> sketch -> patch -> bitstream.

``encode(cloud, config)`` runs the stages in order, each a small object configured by its part of
:class:`EncoderConfig`, and returns the file bytes together with everything a report needs: where
every input Gaussian went, sizes per section, timings, and the error of the decoded sketch
attributes against the originals (measured by decoding the file just written, with the decoder).
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from spcodec.attributes import decode_rotation
from spcodec.cloud import GaussianCloud
from spcodec.container import Codec
from spcodec.decoder import decode_layers
from spcodec.errors import FormatError, UsageError
from spcodec.imaging.cache import default_cache_dir
from spcodec.imaging.evaluate import EvalConfig, evaluate_against_dataset, evaluate_against_reference
from spcodec.writer import EncodedScene, WriteOptions, WrittenFile

from .categorize import categorize
from .config import DEFAULT_POSITION_BITS, EncoderConfig, PatchConfig
from .patch import PatchEncoder, PatchEncoding, retrained_position_bits
from .prune_retrain import encode_pruned_patch, factor_trial
from .refine import RefineResult, refine
from .retraining.control import RunControl
from .retraining.targets import PreparedTargets, prepare_targets, scene_weights
from .sizing import Sizing, sized_encode, sizing_for
from .sketch import SketchEncoder
from .stages import EncodeRun, PatchChoice, ProgressFactory, SceneWriter, SketchOutcome, silent
from .statistics import Closeup, EncodeStats, Quality, SketchStats, SkippedEvaluation


@dataclass
class EncodeResult:
    """The file and the record of how it was made."""

    data: bytes
    scene: EncodedScene
    source_index: np.ndarray
    """For each Gaussian of the decoded file (in file order), the index of the input Gaussian."""
    stats: EncodeStats


def validate_input(cloud: GaussianCloud) -> None:
    """One-line errors for inputs the encoder cannot take."""
    if len(cloud) == 0:
        raise UsageError("the scene has no Gaussians to encode")
    cloud.check_finite()
    if cloud.sh_degree > 3:  # pragma: no cover - GaussianCloud already enforces 0..3
        raise FormatError("SH degree above 3", "ply-invalid")


def with_position_bits(config: EncoderConfig, cloud: GaussianCloud) -> EncoderConfig:
    """``config`` with the patch position precision settled: as given, or by default 16 bits of
    a layer's box, and for a retrained patch the coarser grid its budget buys more Gaussians with
    (:func:`.patch.retrained_position_bits`). Settled once, so training, rate control, the writer
    and the file's metadata all see the same number."""
    if config.patch.position_bits is not None:
        return config
    bits = DEFAULT_POSITION_BITS if config.retrain is None else retrained_position_bits(cloud)
    return dataclasses.replace(config, patch=dataclasses.replace(config.patch, position_bits=bits))


def settled_config(cloud: GaussianCloud, config: EncoderConfig | None,
                   dataset: str | Path | None) -> EncoderConfig:
    """``config`` checked against the input and with everything chosen by default settled once
    (seed, position bits, low-pass), so that the file's metadata and a checkpoint's fingerprint
    name what was used; one-line errors for what cannot be encoded."""
    config = (config or EncoderConfig()).seeded()
    validate_input(cloud)
    config = with_position_bits(config, cloud)
    config = dataclasses.replace(config, blur_variance=config.low_pass(dataset is not None))
    if dataset is not None and config.retrain is None:
        raise UsageError("a dataset is only used for retraining: drop it or enable retraining")
    if config.codec.upper() not in Codec.__members__:
        raise UsageError(f"unknown codec {config.codec!r}: use zlib or zstd")
    if config.target_size is not None and config.target_psnr is not None:
        raise UsageError("give one target: a size or a PSNR")
    return config


def encode(cloud: GaussianCloud, config: EncoderConfig | None = None,
           progress: ProgressFactory = silent, source_name: str | None = None,
           dataset: str | Path | None = None, control: RunControl | None = None) -> EncodeResult:
    """Encode ``cloud`` into a bitstream.

    With ``config.retrain`` set, the patch is pruned and retrained against ``dataset``'s training
    images (a folder the dataset loaders read) or, without one, against renders of ``cloud``
    itself (distillation); ``control`` carries the device, checkpoints and the stop request.
    ``config.target_size`` turns on rate control (:mod:`.ratecontrol`), ``config.target_psnr``
    quality control (:mod:`.qualitycontrol`).
    """
    config = settled_config(cloud, config, dataset)
    pruned = sized_encode(config)
    if pruned:
        control = control or RunControl()
        control.check_checkpoint()
    run = EncodeRun(cloud, config, progress, dataset=dataset, control=control)
    prepared = None
    if config.retrain is not None:  # only training needs targets (rendering them takes minutes)
        prepared = prepare_targets(cloud, config, dataset, control, progress, run.times)
    refined, found = refine_sketch(cloud, config, progress, run.times)
    sketch = encode_sketch(cloud, refined, found, config, progress, run.times)
    writer = scene_writer(cloud.sh_degree, sketch, config, source_name)
    importance = None if prepared is not None else measure_importance(run)
    if not pruned:
        made = encode_whole_patch(run, refined, found, sketch, writer, importance)
    else:
        weights = importance if prepared is None else scene_weights(cloud, config, prepared)
        made = encode_pruned(run, refined, found, sketch, writer, weights, prepared)
    stats = made.stats(cloud, run.times)
    if config.retrain is not None or config.target_psnr is not None:
        closing_evaluation(run, made.written.data, stats)
    return EncodeResult(made.written.data, made.writer.scene(made.patch), made.source_index(),
                        stats)


@dataclass
class Encoded:
    """The file an encode made and what it was made of: the sketch and writer it ended with,
    the patch encoding, and which rows of the sketch's patch Gaussians the patch holds."""

    sketch: SketchOutcome
    writer: SceneWriter
    patch: PatchEncoding
    rows: np.ndarray
    written: WrittenFile
    choice: PatchChoice | None = None
    """The pruned patch's record (None: every patch Gaussian was coded)."""

    def source_index(self) -> np.ndarray:
        """For each Gaussian of the file, in file order, the index of the input Gaussian."""
        sketch, patch_idx = self.sketch, self.sketch.patch_idx[self.rows]
        if not (sketch.sources or len(patch_idx)):
            return np.zeros(0, np.int64)
        return np.concatenate(sketch.sources + [patch_idx[o] for o in self.patch.order]
                              ).astype(np.int64)

    def stats(self, cloud: GaussianCloud, times: dict[str, float]) -> EncodeStats:
        """The record of the file, with the sketch's errors measured on the file itself."""
        layout, data, choice = self.written.layout, self.written.data, self.choice
        stats = EncodeStats(
            gaussians=len(cloud), sketch_gaussians=int(sum(map(len, self.sketch.sources))),
            patch_gaussians=len(self.rows),
            patch_layers=len(self.writer.scene(self.patch).patch_layers),
            sketch=self.sketch.stats, bytes=len(data), sections=layout.section_bytes(),
            layer_ends=list(layout.stored_ends()), seconds=times)
        if choice is not None:
            stats.psnr_input, stats.sizing, stats.retrain = \
                choice.psnr_input, choice.sizing, choice.retrain
        stats.sketch_error = sketch_error(data, cloud, self.source_index(), stats.sketch_gaussians)
        return stats


def scene_writer(sh_degree: int, sketch: SketchOutcome, config: EncoderConfig,
                 source_name: str | None) -> SceneWriter:
    """The writer of this encode's file: the sketch and the metadata fixed, any patch; each file
    it writes records the box of its own Gaussians (``bounds``, for a viewer's first framing)."""
    metadata = {"encoder": "spcodec", "version": _version(), "source": source_name,
                "up": config.up, "settings": config.to_json()}
    return SceneWriter(sh_degree, sketch.clusters, metadata,
                       WriteOptions(codec=Codec[config.codec.upper()], gzip=config.gzip,
                                    bounds=True))


def measure_importance(run: EncodeRun) -> np.ndarray:
    """The patch encoder's importance of every Gaussian of the whole scene (the sketch
    occludes): what orders the layers and ranks sketch clusters without retraining."""
    t = time.perf_counter()
    stage = run.progress("importance", None)
    importance = PatchEncoder(run.config.patch, seed=run.config.seed,
                              jobs=run.config.n_jobs).measure_importance(run.cloud, run.config.up)
    stage.done(_importance_summary(run.config.patch))
    run.times["importance"] = time.perf_counter() - t
    return importance


def encode_whole_patch(run: EncodeRun, refined: RefineResult | None, found: int,
                       sketch: SketchOutcome, writer: SceneWriter, importance: np.ndarray
                       ) -> Encoded:
    """Every Gaussian the sketch leaves coded as patch, the sketch capped to its share of the
    file that makes (each trial file of the cap is a full encode, and the last one is kept)."""
    patch_encoder = PatchEncoder(run.config.patch, seed=run.config.seed, jobs=run.config.n_jobs)
    last: list[Encoded] = []

    def encoded(part: SketchOutcome, part_writer: SceneWriter) -> WrittenFile:
        patch, written = _encode_patch(run.cloud, part, part_writer, importance, patch_encoder,
                                       run.progress, run.times)
        last.append(Encoded(part, part_writer, patch, np.arange(len(part.patch_idx)), written))
        return written

    sketch, writer = _cap_sketch(run, refined, found, sketch, writer, importance, encoded)
    if not last or last[-1].sketch is not sketch:
        encoded(sketch, writer)
    return last[-1]


def encode_pruned(run: EncodeRun, refined: RefineResult | None, found: int,
                  sketch: SketchOutcome, writer: SceneWriter, weights: np.ndarray,
                  prepared: PreparedTargets | None) -> Encoded:
    """The patch pruned (and retrained) to what the sizing says, the sketch capped to its share
    of the file the prune factor makes before training (whose layout the retrained file keeps:
    same count, same codebook settings), and dropped when the file is better without it."""
    cloud, config = run.cloud, run.config
    sketch, writer = _cap_sketch(
        run, refined, found, sketch, writer, weights,
        lambda part, part_writer: factor_trial(part, cloud.subset(part.patch_idx), part_writer,
                                               config, weights),
        file_size=config.target_size)
    sizing = sizing_for(config, cloud, run.control.device)
    choice = encode_pruned_patch(run, sketch, cloud.subset(sketch.patch_idx), writer, prepared,
                                 weights, sizing)
    if sketch.clusters and sizing.drops_sketch(cloud, sketch, writer, choice.encoding):
        sketch, writer, choice = encode_without_sketch(run, found, writer, weights, prepared,
                                                       sizing)
    writer = writer.with_prefix_psnr(None if choice.retrain is None else choice.retrain.prefix_psnr)
    written = _write(writer, choice.encoding, run.progress, run.times)
    return Encoded(sketch, writer, choice.encoding, choice.rows, written, choice)


def encode_without_sketch(run: EncodeRun, found: int, writer: SceneWriter, weights: np.ndarray,
                          prepared: PreparedTargets | None, sizing: Sizing
                          ) -> tuple[SketchOutcome, SceneWriter, PatchChoice]:
    """The pruned encode made again with every Gaussian patch, for a sketch whose models cost
    more picture than their bytes buy as precision; the new sizing inherits what the first one
    measured of the scene."""
    config = run.config
    sketch = encode_sketch(run.cloud, None, found, config, run.progress, run.times)
    sketch.stats.dropped_for_precision = True
    writer = dataclasses.replace(writer, sketch=[])
    again = sizing_for(config, run.cloud, run.control.device)
    again.inherit(sizing)
    choice = encode_pruned_patch(run, sketch, run.cloud, writer, prepared, weights, again)
    return sketch, writer, choice


def closing_evaluation(run: EncodeRun, data: bytes, stats: EncodeStats) -> None:
    """Judge the written file as ``spcodec eval`` would (``stats.quality``), or, with the
    evaluation turned off, record the ``eval`` options that measure it later."""
    config = run.config
    if not config.evaluate:
        stats.evaluation = SkippedEvaluation(eval_options(config, run.dataset))
        return
    t = time.perf_counter()
    stage = run.progress("evaluate", None)
    stats.quality = quality = judge(data, run.cloud, config, run.dataset, run.control,
                                    run.progress)
    closer = "".join(f", {c.psnr:.2f} dB at {c.distance:g} of the distance"
                     for c in quality.closeups)
    stage.done(f"PSNR {quality.psnr:.2f} dB, SSIM {quality.ssim:.4f}{closer} against "
               f"{quality.against}")
    run.times["evaluate"] = time.perf_counter() - t


def judge(data: bytes, original: GaussianCloud, config: EncoderConfig,
          dataset: str | Path | None, control: RunControl | None,
          progress: ProgressFactory = silent) -> Quality:
    """Quality of the written file as ``spcodec eval`` measures it: against the dataset's test
    images at the low-pass retraining used (``eval --blur-variance`` gives the same figure), or
    against renders of the original at the held-out sampled views and their close-ups (with
    the encode's ``up`` and ``antialiased``, eval's defaults otherwise), so the two commands
    report the same figures. ``progress`` shows each framing's bar and ETA."""
    device = control.device if control is not None else "auto"
    decoded = decode_layers(data).cloud
    if dataset is not None:
        low_pass = config.low_pass(dataset=True)  # the one it trained with
        report = evaluate_against_dataset(decoded, Path(dataset), EvalConfig(
            downscale=config.retrain.downscale, device=device, blur_variance=low_pass,
            progress=progress))
        against = f"the test images of {dataset} (low-pass {low_pass:g} px^2)"
    else:
        # eval's render cache: the quality target's judge stored the original's close-ups there,
        # and a later `spcodec eval --reference` reuses what this judgement renders
        report = evaluate_against_reference(decoded, original, EvalConfig(
            device=device, up=config.up, antialiased=config.antialiased, progress=progress,
            cache=default_cache_dir()))
        against = "renders of the original at held-out views"
    doc = report.to_json()
    closeups = [Closeup(c["distance"], c["psnr"], c["ssim"], c["width"], c["height"])
                for c in doc.get("closeups", [])]
    return Quality(doc["psnr"], doc["ssim"], doc["lpips"], doc["views"], doc["width"],
                   doc["height"], closeups, against)


def eval_options(config: EncoderConfig, dataset: str | Path | None) -> list[str]:
    """The ``spcodec eval OUT.spc`` options that measure what :func:`judge` would have (the
    file stores ``up``): ``--reference INPUT`` is the caller's to add without a dataset."""
    if dataset is not None:
        return ["--dataset", str(dataset), "--downscale", str(config.retrain.downscale),
                "--blur-variance", f"{config.low_pass(dataset=True):g}"]
    return ["--antialiased"] if config.antialiased else []


def refine_sketch(cloud: GaussianCloud, config: EncoderConfig, progress: ProgressFactory,
                  times: dict[str, float]) -> tuple[RefineResult | None, int]:
    """Categorize and refine: the sketch clusters accepted and how many categorization found
    (None and 0 when ``use_sketch`` is off)."""
    if not config.use_sketch:
        return None, 0
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
    return refined, found


def encode_sketch(cloud: GaussianCloud, refined: RefineResult | None, found: int,
                  config: EncoderConfig, progress: ProgressFactory, times: dict[str, float]
                  ) -> SketchOutcome:
    """Encode the refined clusters as sketch (nothing without them)."""
    if refined is None:
        return SketchOutcome([], [], np.arange(len(cloud)), SketchStats(0, 0))
    t = time.perf_counter()
    stage = progress("sketch", len(refined.clusters))
    sketch = SketchEncoder(config.sketch, config.refine).encode(cloud, refined, stage.update)
    patch_idx = np.sort(np.concatenate([refined.patch, sketch.to_patch]))
    stage.done(f"{len(sketch.clusters)} clusters, {sum(map(len, sketch.sources))} Gaussians "
               f"(Draco step {sketch.step:.3g}, {sketch.stats['rejected_clusters']} clusters "
               f"and {sketch.stats['duplicates']} duplicates back to patch)")
    times["sketch"] = times.get("sketch", 0.0) + time.perf_counter() - t
    stats = SketchStats(found, len(refined.clusters), clusters_encoded=len(sketch.clusters),
                        draco_step=sketch.step, scene_diameter=sketch.diameter,
                        counts=dict(sketch.stats),
                        refine={"patch_by_reason": refined.stats.patch_by_reason,
                                "splits": refined.stats.splits, "fits": refined.stats.fits})
    return SketchOutcome(sketch.clusters, sketch.sources, patch_idx, stats)


def _encode_patch(cloud: GaussianCloud, sketch: SketchOutcome, writer: SceneWriter,
                  importance: np.ndarray, patch_encoder: PatchEncoder,
                  progress: ProgressFactory, times: dict[str, float]
                  ) -> tuple[PatchEncoding, WrittenFile]:
    """No-retrain patch layers of the Gaussians the sketch left, and the file they make."""
    patch_idx = sketch.patch_idx
    t = time.perf_counter()
    stage = progress("patch", None)
    patch = patch_encoder.encode(cloud.subset(patch_idx), importance[patch_idx])
    stage.done(f"{len(patch_idx)} Gaussians in {len(patch.layers)} layers")
    times["patch"] = times.get("patch", 0.0) + time.perf_counter() - t
    return patch, _write(writer, patch, progress, times)


def _write(writer: SceneWriter, patch: PatchEncoding, progress: ProgressFactory,
           times: dict[str, float]) -> WrittenFile:
    t = time.perf_counter()
    stage = progress("write", None)
    written = writer.write_file(patch)
    stage.done(f"{written.size} bytes")
    times["write"] = times.get("write", 0.0) + time.perf_counter() - t
    return written


def _cap_sketch(run: EncodeRun, refined: RefineResult | None, found: int,
                sketch: SketchOutcome, writer: SceneWriter, importance: np.ndarray,
                file_of: Callable[[SketchOutcome, SceneWriter], WrittenFile | None],
                file_size: int | None = None) -> tuple[SketchOutcome, SceneWriter]:
    """Move the sketch clusters of least ``importance`` per Gaussian to the patch until the
    sketch layer of ``file_of(sketch, writer)`` (None: nothing to judge) ends within
    ``config.max_sketch_share`` of it, or of ``file_size`` when rate control will make the file
    that size whatever the sketch keeps: the sketch and its writer."""
    config, moved = run.config, 0
    while refined is not None and sketch.clusters and config.max_sketch_share is not None:
        written = file_of(sketch, writer)
        keep = None if written is None else \
            _clusters_to_keep(written, refined, importance, config.max_sketch_share, file_size)
        if keep is None:
            break
        before = len(refined.patch)
        refined = _keep_clusters(refined, keep)
        moved += len(refined.patch) - before
        sketch = encode_sketch(run.cloud, refined, found, config, run.progress, run.times)
        writer = dataclasses.replace(writer, sketch=sketch.clusters)
    sketch.stats.moved_to_patch_for_share = moved
    return sketch, writer


def _clusters_to_keep(written: WrittenFile, refined: RefineResult, importance: np.ndarray,
                      max_share: float, file_size: int | None = None) -> list[int] | None:
    """Which refined clusters to keep as sketch so that the sketch layer ends within
    ``max_share`` of the file, or of ``file_size`` when that is fixed (None: it already does).

    The clusters that do least for the picture (lowest mean importance) go to the patch first.
    How many: with the sketch layer's fixed part H (header, metadata), sketch bytes S over K
    Gaussians, and patch bytes P at p per Gaussian, keeping a fraction f of the sketch gives a
    layer of H + fS in a file of H + fS + P + (1 - f)Kp (or of ``file_size``: rate control
    fills the rest with patch); solve for the share, with a 3 % margin for the difference
    between this estimate and the encoded result.
    """
    layout = written.layout
    end, total = layout.layer_ends[0], layout.file_size
    if layout.stored_ends()[0] <= max_share * (file_size or written.size):
        return None
    sketch_bytes = sum(sec.length for sec in layout.sections if sec.type.startswith("SKETCH"))
    fixed, count = end - sketch_bytes, layout.layer_gaussians[0]
    share = 0.97 * max_share
    if file_size is not None:
        fraction = (share * file_size - fixed) / max(sketch_bytes, 1)
    else:
        patch_bytes, patch_count = total - end, sum(layout.layer_gaussians) - count
        per_patch = patch_bytes / patch_count if patch_count else sketch_bytes / max(count, 1)
        fraction = (share * (fixed + patch_bytes + count * per_patch) - fixed) / \
            (sketch_bytes * (1 - share) + share * count * per_patch)
    sizes = np.array([len(c) for c in refined.clusters])
    density = np.array([importance[c].mean() for c in refined.clusters])
    order = np.argsort(-density, kind="stable")
    kept = order[np.cumsum(sizes[order]) <= max(fraction, 0.0) * sizes.sum()]
    return sorted(int(i) for i in kept) if len(kept) < len(sizes) else None


def _keep_clusters(refined: RefineResult, keep: list[int]) -> RefineResult:
    """``refined`` with only the clusters ``keep``; the others join its patch set."""
    kept = set(keep)
    dropped = [c for i, c in enumerate(refined.clusters) if i not in kept]
    patch = np.sort(np.concatenate([refined.patch, *dropped])) if dropped else refined.patch
    return dataclasses.replace(refined, clusters=[refined.clusters[i] for i in keep],
                               fits=[refined.fits[i] for i in keep], patch=patch)


def _importance_summary(patch: PatchConfig) -> str:
    if patch.importance != "blend":
        return f"{patch.importance} proxy"
    width, height = patch.importance_resolution
    return f"blend weights over {patch.importance_views} training views of {width}x{height}"


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
