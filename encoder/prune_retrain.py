"""The patch stage when it prunes: which patch Gaussians survive and, with retraining, the
retrain stage between pruning and layering. How many survive is :mod:`.sizing`'s to say (a
factor, a target size or a target PSNR); this module asks it at each point of the stage.

The pipeline calls :func:`encode_pruned_patch` instead of a plain patch encode whenever
retraining or rate control is on. Without retraining, a target size still works: the least
important patch Gaussians are dropped until the file fits (quality falls faster than with
retraining, which is why retraining is the default).
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from spcodec.cloud import GaussianCloud
from spcodec.imaging.importance import blend_weights
from spcodec.imaging.render import RenderSettings, resolve_device
from spcodec.imaging.training.checkpoint import Checkpointer, fingerprint
from spcodec.imaging.training.targets import Targets, check_targets, dataset_targets, distillation_targets
from spcodec.writer import WrittenFile

from .config import EncoderConfig, RetrainConfig
from .nested import NestedEncoder, layer_priority, layers_of, nested_groups, prefix_ends, prefix_schedule
from .patch import PatchEncoder, PatchEncoding, Quantized, quantized_cloud
from .prune import kept_count, select
from .retrain import RetrainStage, RunControl, spread
from .sizing import Sizing, pruned_file
from .stages import ProgressFactory, SceneWriter, SketchOutcome

DISTILLATION_BACKGROUND = (0.0, 0.0, 0.0)
"""Background of distillation renders (the one ``spcodec eval --reference`` uses)."""

_NO_RETRAIN = RetrainConfig()
"""Where rate control without retraining takes its view settings from."""


@dataclass
class PatchChoice:
    """The pruned patch handed back to the pipeline."""

    encoding: PatchEncoding
    rows: np.ndarray
    """Indices into the patch cloud of the encoded Gaussians (``encoding.order`` indexes these)."""
    stats: dict


@dataclass
class PreparedTargets:
    """What pruning and retraining look at, made before any other work so that a bad dataset
    fails fast: the targets, how they are rendered, and the device."""

    targets: Targets
    settings: RenderSettings
    device: torch.device
    psnr_input: float
    """PSNR of the input model against its targets (the mismatch check's figure)."""
    seconds_per_render: float
    """Mean time of one render of the input at a target view (distillation: all of them,
    rendered twice; datasets: the check's one pass), what estimates of training time scale."""


def prepare_targets(cloud: GaussianCloud, config: EncoderConfig, dataset: str | Path | None,
                    control: RunControl, progress: ProgressFactory,
                    times: dict[str, float]) -> PreparedTargets:
    """Load or render the targets and check that they belong to ``cloud``."""
    t = time.perf_counter()
    stage = progress("targets", None)
    device = resolve_device(control.device)
    targets = build_targets(cloud, config, dataset, device)
    settings = config.render_settings(targets.background, targets.mode == "dataset")
    checked = time.perf_counter()
    psnr = check_targets(cloud, targets, settings, device, dataset)
    per_render = (time.perf_counter() - checked) / max(len(targets.views), 1)
    stage.done(f"{len(targets.views)} {targets.mode} views, input at {psnr:.2f} dB")
    times["targets"] = time.perf_counter() - t
    prepared = PreparedTargets(targets, settings, device, psnr, per_render)
    if config.retrain is not None:
        progress("estimate", None).done(estimate_line(config.retrain, prepared))
    return prepared


def scene_weights(cloud: GaussianCloud, config: EncoderConfig,
                  prepared: PreparedTargets) -> np.ndarray:
    """Blend weight (n,) of every Gaussian of the whole scene over spread training views: what
    pruning keeps, and what ranks sketch clusters for the cap on the sketch layer's share."""
    view_config = config.retrain or _NO_RETRAIN
    return blend_weights(cloud, spread(prepared.targets.whole_cameras,
                                       view_config.importance_views),
                         prepared.settings, prepared.device)


def factor_trial(sketch: SketchOutcome, patch: GaussianCloud, writer: SceneWriter,
                 config: EncoderConfig, weights: np.ndarray) -> WrittenFile | None:
    """The file with the patch pruned by the retrain config's factor and coded without
    retraining: the retrained file's layout to within the gains of training, cheap enough to size
    the sketch layer's share before training. With a target size, the sketch alone (the file's
    size is the target whatever the sketch keeps); None with a target PSNR (the size is what
    quality control finds) or without retraining."""
    if config.target_size is not None:
        return writer.write_file(None)
    if config.retrain is None or config.target_psnr is not None:
        return None
    return pruned_file(writer, PatchEncoder(config.patch, seed=config.seed), patch,
                       weights[sketch.patch_idx],
                       kept_count(len(patch), config.retrain.patch_downsample))


def encode_pruned_patch(cloud: GaussianCloud, sketch: SketchOutcome, patch: GaussianCloud,
                        writer: SceneWriter, config: EncoderConfig,
                        prepared: PreparedTargets | None, weights: np.ndarray,
                        dataset: str | Path | None, control: RunControl, sizing: Sizing,
                        progress: ProgressFactory, times: dict[str, float]) -> PatchChoice:
    """Prune (and retrain, when ``config.retrain`` is set) the patch, as many as ``sizing``
    says (:func:`.sizing.sizing_for`).
    ``weights`` rank the whole scene's Gaussians (:func:`scene_weights` when retraining, the
    patch encoder's importance without); ``prepared`` holds the targets (retraining only)."""
    retrain = config.retrain
    encoder = PatchEncoder(config.patch, seed=config.seed)
    stats: dict = {} if prepared is None else {"psnr_input": prepared.psnr_input}
    weights = weights[sketch.patch_idx]

    t = time.perf_counter()
    stage = progress("prune", None)
    keep = sizing.plan(patch, weights, writer, encoder, sketch.patch_idx)
    encoder = sizing.encoder_for(encoder)
    method = retrain.prune if retrain is not None else "importance"
    kept = select(method, len(patch), keep, config.seed, weights)
    stage.done(f"{len(kept)} of {len(patch)} patch Gaussians kept ({method})")
    times["prune"] = time.perf_counter() - t

    if retrain is None:
        t = time.perf_counter()
        stage = progress("patch", None)
        survivors, importance = patch.subset(kept), weights[kept]
        quantized = encoder.quantize(survivors, encoder.kmeans_weights(importance))
        encoding = encoder.layer(survivors, quantized, importance)
        if sizing.overflows(writer, encoding):
            # the plan landed within FIT_SLACK either side: trim the least important that spill
            top = sizing.fit(writer, encoder, survivors, quantized, importance)
            encoding = encoder.layer(survivors.subset(top), quantized.subset(top), importance[top])
            kept = kept[top]
            sizing.trimmed()
        stage.done(f"{len(kept)} Gaussians in {len(encoding.layers)} layers")
        times["patch"] = time.perf_counter() - t
        return PatchChoice(encoding, kept, {**stats, **sizing.stats()})
    checkpointer = None
    if control.checkpoint is not None:
        checkpointer = Checkpointer(Path(control.checkpoint), fingerprint(
            cloud, config.to_json(), "" if dataset is None else str(Path(dataset).resolve())))
    return _retrain(retrain, prepared.targets, writer, encoder, patch, kept, weights[kept],
                    sizing, config, control, checkpointer, progress, times, stats)


def _retrain(retrain: RetrainConfig, targets: Targets, writer: SceneWriter,
             encoder: PatchEncoder, patch: GaussianCloud, kept: np.ndarray, weights: np.ndarray,
             sizing: Sizing, config: EncoderConfig, control: RunControl,
             checkpointer: Checkpointer | None, progress: ProgressFactory,
             times: dict[str, float], stats: dict) -> PatchChoice:
    layers = encoder.config.layers
    layer_of = None  # nested: the layer of each survivor, fixed before training
    train_stats: dict = {"prune": retrain.prune}
    if retrain.nested:  # every step trains one layer prefix (encoder/nested.py)
        groups = nested_groups(weights, encoder)
        kept = kept[np.concatenate(groups)]
        layer_of = np.repeat(np.arange(len(groups)), [len(g) for g in groups])
        encoder = NestedEncoder(encoder.config, seed=config.seed, jobs=encoder.jobs)
        retrain = dataclasses.replace(retrain, snap_start=1.0)  # rows must stay put
        train_stats["nested_layers"] = np.cumsum([len(g) for g in groups]).tolist()
    stage = RetrainStage(retrain, targets, writer.decoded_sketch(), encoder, config.seed,
                         control, checkpointer,
                         settings=config.render_settings(targets.background,
                                                         targets.mode == "dataset"))
    if layer_of is not None:
        stage.visible = prefix_schedule(train_stats["nested_layers"], config.seed,
                                        retrain.nested_full_share)
    stage.fit_rows = sizing.snap_fit(writer, encoder)

    t = time.perf_counter()
    clock = TrainingClock()
    report = progress("retrain", retrain.iterations)
    trained = stage.retrain(patch.subset(kept), train_stats,
                            _meter(report, clock, retrain.finish_iterations))
    if stage.kept is not None:  # rate control dropped some when snapping started
        train_stats["fitted_when_snapping"] = {"from": len(kept), "to": len(stage.kept)}
        kept = kept[stage.kept]
    report.done(f"{len(kept)} patch Gaussians, {train_stats['psnr_before']:.2f} -> "
                f"{train_stats['psnr_retrained']:.2f} dB on the training views")
    times["retrain"] = time.perf_counter() - t

    t = time.perf_counter()
    report = progress("quantize", None)
    quantized, importance = stage.quantize(trained)
    if layer_of is not None:
        importance = layer_priority(importance, layer_of, layers)
    top = sizing.fit(writer, encoder, trained, quantized, importance)
    if top is not None:  # the most important that fit the size, or the fewest that reach
        trained, quantized, kept = trained.subset(top), quantized.subset(top), kept[top]
        importance = importance[top]
    entries = max((len(cb.entries) for cb in quantized.codebooks), default=0)
    report.done(f"{len(kept)} Gaussians, codebooks of up to {entries} entries")
    times["quantize"] = time.perf_counter() - t

    t = time.perf_counter()
    report = progress("finish", retrain.finish_iterations or None)
    if layer_of is not None:  # the layers rate or quality control left
        stage.visible = prefix_schedule(prefix_ends(importance, layers), config.seed + 1,
                                        retrain.nested_full_share)
    quantized, trained = stage.finish(trained, quantized, train_stats, _meter(report, clock))
    ranked = stage.rank(trained)
    importance = ranked if layer_of is None else \
        layer_priority(ranked, layers_of(importance, layers), layers)
    encoding = encoder.layer(trained, quantized, importance)
    # Trim the least important until the file fits as written: the finish can grow it, and the
    # metadata then records each prefix's PSNR, scored on what is left (without that table in
    # the fit, kacytran at SPZ/16 came out 23 bytes over: docs/LOG.md 13.20).
    prefix, scored = None, False
    while True:
        final = writer.with_prefix_psnr(prefix)
        if len(trained) > 1 and sizing.overflows(final, encoding):
            top = sizing.fit(final, encoder, trained, quantized, importance)
            trained, quantized, kept = trained.subset(top), quantized.subset(top), kept[top]
            importance = importance[top]
            encoding = encoder.layer(trained, quantized, importance)
            sizing.trimmed()
        elif scored:
            break
        prefix = _prefix_psnr(stage, trained, quantized, encoding.order) \
            if len(encoding.layers) > 1 else None
        scored = True
    if prefix:
        train_stats["prefix_psnr"] = prefix
    gain = train_stats.get("psnr_finished", train_stats["psnr_quantized"]) \
        - train_stats["psnr_quantized"]
    report.done(f"quantized {train_stats['psnr_quantized']:.2f} dB, finish {gain:+.2f} dB on the "
                "training views")
    times["finish"] = time.perf_counter() - t
    stats.update(sizing.stats(), retrain=train_stats)
    if checkpointer is not None:
        checkpointer.remove()
    return PatchChoice(encoding, kept, stats)


def _prefix_psnr(stage: RetrainStage, trained: GaussianCloud, quantized: Quantized,
                 order: list[np.ndarray]) -> list[dict]:
    """Mean PSNR on the training views of the sketch with each patch prefix that ends at a
    non-empty layer, as the file codes it (positions before their grid): ``{"layer": K,
    "psnr": dB}`` for the prefix of file layers 0..K. ``order`` holds each patch layer's rows
    of ``trained``, first layer first (:attr:`PatchEncoding.order`)."""
    coded = quantized_cloud(quantized, trained.means, trained.sh_degree)
    rows = np.zeros(0, np.int64)
    scores = []
    for k, members in enumerate(order):
        if len(members):
            rows = np.concatenate([rows, members])
            scores.append({"layer": k + 1, "psnr": round(stage.psnr(coded.subset(rows)), 3)})
    return scores


def build_targets(cloud: GaussianCloud, config: EncoderConfig, dataset: str | Path | None,
                  device) -> Targets:
    """Dataset training images, or renders of ``cloud`` at sampled training views."""
    views = config.retrain or _NO_RETRAIN
    if dataset is not None:
        from spcodec.imaging.datasets import load_dataset
        return dataset_targets(load_dataset(dataset, downscale=views.downscale), device,
                               views.max_views)
    from spcodec.imaging.views import close_crops, sample_views
    cameras = sample_views(cloud, views.views, resolution=(views.resolution, views.resolution),
                           split="train", up=config.up)
    crops = close_crops(cloud, views.close_views, views.close_distance, views.close_resolution,
                        views.close_crop, up=config.up) if views.close_views else []
    return distillation_targets(cloud, cameras, config.render_settings(DISTILLATION_BACKGROUND),
                                device, crops)


STEP_PER_TARGET_RENDER = 1.0
"""A training step costs about this many renders of the input at a target view (forward and
backward of the pruned patch, against a forward of the whole input): what the estimate printed
before retraining scales the targets' rendering time by. Measured on guitar: 0.7 s a step, 0.7 s
a target render, one torch thread."""

EVALUATION_STEPS = 60
"""The closing evaluation (8 views at 400x400 and 16 at 800x800, each of the file and the input)
costs about this many training steps."""


@dataclass
class TrainingClock:
    """Times the training steps as they run, to tell how long every stage still to come takes
    (the rest of this one, the later training stages, and the closing evaluation)."""

    started: float = field(default_factory=time.perf_counter)
    steps: int = 0

    def eta_all(self, left: int) -> float:
        """Seconds for ``left`` more steps and the evaluation at the rate so far."""
        self.steps += 1
        per_step = (time.perf_counter() - self.started) / self.steps
        return (left + EVALUATION_STEPS) * per_step


def estimate_line(retrain: RetrainConfig, prepared: PreparedTargets) -> str:
    """The one line printed before retraining starts: how long it will take here, and how to
    have a faster encode instead."""
    step = prepared.seconds_per_render * STEP_PER_TARGET_RENDER
    steps = retrain.iterations + retrain.finish_iterations
    total = (steps + EVALUATION_STEPS) * step

    def minutes(seconds: float) -> str:
        return f"{seconds / 60:.0f} min" if seconds >= 90 else f"{seconds:.0f} s"

    faster = ""
    if retrain.iterations > 1000:
        quick = (1000 + retrain.finish_iterations + EVALUATION_STEPS) * step
        faster = f"; --iterations 1000 takes about {minutes(quick)} for about 1 dB less"
    return (f"retraining takes about {minutes(total)} here ({retrain.iterations:,} + "
            f"{retrain.finish_iterations:,} steps at ~{step:.2f} s){faster}; --no-retrain takes "
            "seconds, for a larger file")


def _meter(stage, clock: TrainingClock, later: int = 0):
    """A step callback that moves a progress stage, shows loss and PSNR and the ETA of all that
    is left (``later``: steps of the training stages after this one), and starts a resumed run
    at its step."""
    def on_step(report) -> None:
        if not on_step.seen and report.step > 1:
            stage.resumed(report.step - 1)
        on_step.seen = True
        left = report.total - report.step + later
        stage.update(1, loss=report.loss, psnr=report.psnr, eta_all=clock.eta_all(left))
    on_step.seen = False
    return on_step
