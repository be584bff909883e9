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
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import torch

from spcodec.cloud import GaussianCloud
from spcodec.imaging.cameras import Camera
from spcodec.imaging.importance import blend_weights
from spcodec.imaging.render import RenderSettings, resolve_device
from spcodec.imaging.training.checkpoint import Checkpointer, fingerprint
from spcodec.imaging.training.targets import Targets, check_targets, dataset_targets, distillation_targets
from spcodec.writer import WrittenFile

from .config import EncoderConfig, RetrainConfig
from .estimate import EvalShape, RunEstimate, duration, estimate_run
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
    estimate: RunEstimate
    """How long the whole encode takes here, as printed first (training corrects it)."""


@dataclass
class TargetSource:
    """Where the targets come from, known before any is rendered or read: the cameras (with
    whether each is a close crop) and, with ``--dataset``, the loaded dataset."""

    cameras: list[tuple[Camera, bool]]
    dataset: object | None = None


def prepare_targets(cloud: GaussianCloud, config: EncoderConfig, dataset: str | Path | None,
                    control: RunControl, progress: ProgressFactory,
                    times: dict[str, float]) -> PreparedTargets:
    """Estimate the whole run (printed first), then load or render the targets and check that
    they belong to ``cloud``."""
    t = time.perf_counter()
    stage = progress("estimate", None)
    device = resolve_device(control.device)
    source = target_source(cloud, config, dataset)
    background = DISTILLATION_BACKGROUND if dataset is None else _background(source.dataset)
    estimate = estimate_run(cloud, config.retrain, source.cameras,
                            config.render_settings(background, dataset is not None),
                            device, config.patch.layers,
                            evaluation_probe(cloud, config, source.dataset)
                            if config.evaluate else None)
    stage.done(estimate.line(config.retrain))
    times["estimate"] = time.perf_counter() - t

    t = time.perf_counter()
    views = len(source.cameras)
    stage = progress("targets", views if dataset is None else 2 * views)
    targets = build_targets(cloud, config, source, device, lambda: stage.update(1))
    settings = config.render_settings(targets.background, targets.mode == "dataset")
    psnr = targets.psnr_model if targets.psnr_model is not None else \
        check_targets(cloud, targets, settings, device, dataset, lambda: stage.update(1))
    stage.done(f"{len(targets.views)} {targets.mode} views, input at {psnr:.2f} dB")
    times["targets"] = time.perf_counter() - t
    return PreparedTargets(targets, settings, device, psnr, estimate)


def _background(dataset) -> tuple[float, float, float]:
    return tuple(float(c) for c in dataset.background)


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
        # whether the end evaluates changes nothing trained: --resume may add or drop --no-eval
        settings = {k: v for k, v in config.to_json().items() if k != "evaluate"}
        checkpointer = Checkpointer(Path(control.checkpoint), fingerprint(
            cloud, settings, "" if dataset is None else str(Path(dataset).resolve())))
    return _retrain(retrain, prepared.targets, writer, encoder, patch, kept, weights[kept],
                    sizing, config, control, checkpointer, progress, times, stats,
                    prepared.estimate)


def _retrain(retrain: RetrainConfig, targets: Targets, writer: SceneWriter,
             encoder: PatchEncoder, patch: GaussianCloud, kept: np.ndarray, weights: np.ndarray,
             sizing: Sizing, config: EncoderConfig, control: RunControl,
             checkpointer: Checkpointer | None, progress: ProgressFactory,
             times: dict[str, float], stats: dict, estimate: RunEstimate) -> PatchChoice:
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
    clock = TrainingClock((estimate.evaluation or 0.0) + estimate.fixed, estimate.step)
    report = progress("retrain", retrain.iterations)
    trained = stage.retrain(patch.subset(kept), train_stats,
                            _meter(report, clock, retrain.finish_iterations, estimate))
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


def target_source(cloud: GaussianCloud, config: EncoderConfig, dataset: str | Path | None
                  ) -> TargetSource:
    """The target cameras: the dataset's training views, or views sampled around ``cloud`` and
    close crops (cameras of the crop's pixels alone, :func:`~spcodec.imaging.views.close_crops`)."""
    views = config.retrain or _NO_RETRAIN
    if dataset is not None:
        from spcodec.imaging.datasets import load_dataset
        loaded = load_dataset(dataset, downscale=views.downscale)
        chosen = loaded.train[:views.max_views] if views.max_views else loaded.train
        return TargetSource([(v.camera, False) for v in chosen], loaded)
    from spcodec.imaging.views import close_crops, sample_views
    cameras = sample_views(cloud, views.views, resolution=(views.resolution, views.resolution),
                           split="train", up=config.up)
    crops = close_crops(cloud, views.close_views, views.close_distance, views.close_resolution,
                        views.close_crop, up=config.up) if views.close_views else []
    return TargetSource([(c, False) for c in cameras] + [(c, True) for c in crops])


def build_targets(cloud: GaussianCloud, config: EncoderConfig, source: TargetSource,
                  device, on_view: Callable[[], None] | None = None) -> Targets:
    """Dataset training images, or renders of ``cloud`` at ``source``'s cameras (``on_view``:
    called after each view)."""
    views = config.retrain or _NO_RETRAIN
    if source.dataset is not None:
        return dataset_targets(source.dataset, device, views.max_views, on_view)
    return distillation_targets(cloud, [c for c, crop in source.cameras if not crop],
                                config.render_settings(DISTILLATION_BACKGROUND), device,
                                [c for c, crop in source.cameras if crop], on_view)


def evaluation_probe(cloud: GaussianCloud, config: EncoderConfig, dataset
                     ) -> tuple[EvalShape, list[Camera], RenderSettings]:
    """What the closing evaluation (:func:`.pipeline.judge`) renders, for the estimate: its
    shape, one camera of each framing and the settings it renders with."""
    from spcodec.imaging.evaluate import EvalConfig
    from spcodec.imaging.views import ViewSamplingWarning, robust_bounds, sample_views

    judged = EvalConfig()
    if dataset is not None:
        test = dataset.test[:judged.max_views] if judged.max_views else dataset.test
        camera = (test or dataset.train)[0].camera
        return (EvalShape(len(test), ((1.0, camera.width),)), [camera],
                config.render_settings(_background(dataset), dataset=True))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ViewSamplingWarning)  # the evaluation itself says it
        bounds = robust_bounds(cloud)
        first = sample_views(cloud, judged.views, resolution=(judged.resolution,) * 2,
                             split="eval", seed=judged.seed, up=config.up, bounds=bounds)[0]
    zoom = judged.closeup_resolution / judged.resolution
    framings = ((1.0, judged.resolution),) + tuple(
        (d, judged.closeup_resolution) for d in judged.closeups)
    cameras = [first] + [first.scaled(zoom).dollied(bounds.centre, d) for d in judged.closeups]
    settings = RenderSettings(background=judged.background, antialiased=config.antialiased,
                              blur_variance=judged.blur_variance)
    return EvalShape(judged.views, framings), cameras, settings


CORRECT_AFTER = 50
"""Retraining steps after which their measured rate corrects the first estimate (one line)."""


@dataclass
class TrainingClock:
    """Times the training steps as they run, to tell how long every stage still to come takes
    (the rest of this one, the later training stages, and ``after``: the seconds of work after
    the last step, the closing evaluation's and the checks', as the first estimate put them).
    ``after`` scales as the steps run faster or slower than the probe's ``probe_step`` (the
    machine's load moves both alike)."""

    after: float = 0.0
    probe_step: float | None = None
    first: float | None = None
    """When the first step of this run ended (the rate counts the steps after it)."""
    steps: int = 0

    def tick(self) -> None:
        """One more step done."""
        if self.first is None:
            self.first = time.perf_counter()
        else:
            self.steps += 1

    @property
    def per_step(self) -> float:
        """Seconds per step so far (NaN before two)."""
        if not self.steps:
            return float("nan")
        return (time.perf_counter() - self.first) / self.steps

    def eta_all(self, left: int) -> float:
        """Seconds for ``left`` more steps and the work after them at the rate so far."""
        pace = self.per_step / self.probe_step if self.probe_step and self.steps else 1.0
        return left * self.per_step + self.after * pace


def correction_line(clock: TrainingClock, estimate: RunEstimate, left: int) -> str:
    """The first estimate corrected with the training steps' measured rate."""
    return (f"estimate corrected: {clock.steps} steps measured at {clock.per_step:.2f} s each "
            f"(the probe said {estimate.step:.2f} s): the rest of the encode takes about "
            f"{duration(clock.eta_all(left))}")


def _meter(stage, clock: TrainingClock, later: int = 0, estimate: RunEstimate | None = None):
    """A step callback that moves a progress stage, shows loss and PSNR and the ETA of all that
    is left (``later``: steps of the training stages after this one), starts a resumed run
    at its step, and after :data:`CORRECT_AFTER` steps says how ``estimate`` was off."""
    def on_step(report) -> None:
        if not on_step.seen and report.step > 1:
            stage.resumed(report.step - 1)
        on_step.seen = True
        clock.tick()
        left = report.total - report.step + later
        if estimate is not None and clock.steps == CORRECT_AFTER:
            stage.note(correction_line(clock, estimate, left))
        stage.update(1, loss=report.loss, psnr=report.psnr, eta_all=clock.eta_all(left))
    on_step.seen = False
    return on_step
