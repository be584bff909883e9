"""One retraining run of the pruned patch: retrain, quantize, the quantization-aware finish and
the trim that makes the file fit, asking :mod:`spcodec.encoder.sizing` how many to keep at each
point, then the patch layers (nested or not) the file stores.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from spcodec.cloud import GaussianCloud
from spcodec.imaging.training.checkpoint import Checkpointer
from spcodec.imaging.training.targets import Targets

from ..config import EncoderConfig
from ..estimate import RunEstimate
from ..patch import PatchEncoder, PatchEncoding, Quantized, quantized_cloud
from ..sizing import Sizing
from ..stages import PatchChoice, ProgressFactory, SceneWriter
from ..statistics import RetrainStats
from .clock import TrainingClock, meter
from .control import RunControl
from .nested import NestedLayers, layer_priority, layers_of
from .stage import RetrainStage


@dataclass
class RetrainRun:
    """What one retraining run works with, fixed for the run: the encode's settings, the targets,
    the writer that makes its file, the (plain) patch encoder, the sizing it asks, how the run is
    controlled and checkpointed, and where it reports progress, stage times and the first
    estimate it corrects."""

    config: EncoderConfig
    targets: Targets
    writer: SceneWriter
    encoder: PatchEncoder
    sizing: Sizing
    control: RunControl
    checkpointer: Checkpointer | None
    progress: ProgressFactory
    times: dict[str, float]
    estimate: RunEstimate

    def stage(self, encoder: PatchEncoder, nested: NestedLayers | None) -> RetrainStage:
        """The retraining stage of this run, with ``encoder`` (nested: the one of ``nested``)."""
        config, targets = self.config, self.targets
        return RetrainStage(config.retrain, targets, self.writer.decoded_sketch(), encoder,
                            config.seed, self.control, self.checkpointer,
                            settings=config.render_settings(targets.background,
                                                            targets.mode == "dataset"),
                            fit_rows=self.sizing.snap_fit(self.writer, encoder), nested=nested)


@dataclass
class Survivors:
    """The patch Gaussians a run carries from one step to the next: the cloud, its quantization
    (None before quantizing), its importance and its rows in the patch cloud."""

    cloud: GaussianCloud
    quantized: Quantized | None
    importance: np.ndarray | None
    rows: np.ndarray

    def subset(self, top: np.ndarray) -> Survivors:
        return Survivors(self.cloud.subset(top),
                         None if self.quantized is None else self.quantized.subset(top),
                         None if self.importance is None else self.importance[top],
                         self.rows[top])


def retrain_patch(run: RetrainRun, patch: GaussianCloud, kept: np.ndarray, weights: np.ndarray
                  ) -> PatchChoice:
    """Retrain the survivors ``kept`` of ``patch`` (ranked by ``weights``) and encode them as the
    file's patch layers, as many as ``run.sizing`` lets through."""
    retrain = run.config.retrain
    train_stats = RetrainStats(retrain.prune, estimate=run.estimate.seconds())
    encoder, nested = run.encoder, None
    if retrain.nested:  # every step trains one layer prefix (:mod:`.nested`)
        nested, order = NestedLayers.plan(weights, encoder, run.config.seed,
                                          retrain.nested_full_share)
        kept, encoder = kept[order], nested.encoder(encoder)
        train_stats.nested_layers = nested.ends
    stage = run.stage(encoder, nested)
    clock = TrainingClock((run.estimate.evaluation or 0.0) + run.estimate.fixed, run.estimate.step)
    survivors = _train(run, stage, patch, kept, train_stats, clock)
    survivors = _quantize(run, stage, encoder, survivors, nested)
    encoding, survivors = _finish(run, stage, encoder, survivors, nested, train_stats, clock)
    if run.checkpointer is not None:
        run.checkpointer.remove()
    return PatchChoice(encoding, survivors.rows, sizing=run.sizing.stats(), retrain=train_stats)


def _train(run: RetrainRun, stage: RetrainStage, patch: GaussianCloud, kept: np.ndarray,
           train_stats: RetrainStats, clock: TrainingClock) -> Survivors:
    """Retrain the rows ``kept`` of ``patch``; rate control may drop some when snapping starts."""
    retrain = run.config.retrain
    t = time.perf_counter()
    report = run.progress("retrain", retrain.iterations)
    trained = stage.retrain(patch.subset(kept), train_stats,
                            meter(report, clock, retrain.finish_iterations, run.estimate))
    if stage.kept is not None:  # rate control dropped some when snapping started
        train_stats.fitted_when_snapping = (len(kept), len(stage.kept))
        kept = kept[stage.kept]
    report.done(f"{len(kept)} patch Gaussians, {train_stats.psnr_before:.2f} -> "
                f"{train_stats.psnr_retrained:.2f} dB on the training views")
    run.times["retrain"] = time.perf_counter() - t
    return Survivors(trained, None, None, kept)


def _quantize(run: RetrainRun, stage: RetrainStage, encoder: PatchEncoder, survivors: Survivors,
              nested: NestedLayers | None) -> Survivors:
    """Quantize the trained survivors and keep those the sizing fits (nested: earlier layers
    first, their importance then a layer priority)."""
    t = time.perf_counter()
    report = run.progress("quantize", None)
    quantized, importance = stage.quantize(survivors.cloud)
    if nested is not None:
        importance = layer_priority(importance, nested.layer_of, encoder.config.layers)
    survivors = Survivors(survivors.cloud, quantized, importance, survivors.rows)
    top = run.sizing.fit(run.writer, encoder, survivors.cloud, quantized, importance)
    if top is not None:  # the most important that fit the size, or the fewest that reach
        survivors = survivors.subset(top)
    entries = max((len(cb.entries) for cb in survivors.quantized.codebooks), default=0)
    report.done(f"{len(survivors.rows)} Gaussians, codebooks of up to {entries} entries")
    run.times["quantize"] = time.perf_counter() - t
    return survivors


def _finish(run: RetrainRun, stage: RetrainStage, encoder: PatchEncoder, survivors: Survivors,
            nested: NestedLayers | None, train_stats: RetrainStats, clock: TrainingClock
            ) -> tuple[PatchEncoding, Survivors]:
    """The quantization-aware finish, the layers, and the trim that makes the file fit with
    its per-prefix PSNR table."""
    layers = encoder.config.layers
    t = time.perf_counter()
    report = run.progress("finish", run.config.retrain.finish_iterations or None)
    quantized, trained = stage.finish(survivors.cloud, survivors.quantized, train_stats,
                                      meter(report, clock), priority=survivors.importance)
    ranked = stage.rank(trained)
    importance = ranked if nested is None else \
        layer_priority(ranked, layers_of(survivors.importance, layers), layers)
    survivors = Survivors(trained, quantized, importance, survivors.rows)
    encoding, survivors = _fit_written(run, stage, encoder, survivors, train_stats)
    report.done(f"quantized {train_stats.psnr_quantized:.2f} dB, finish "
                f"{train_stats.finish_gain:+.2f} dB on the "
                "training views")
    run.times["finish"] = time.perf_counter() - t
    return encoding, survivors


def _fit_written(run: RetrainRun, stage: RetrainStage, encoder: PatchEncoder,
                 survivors: Survivors, train_stats: RetrainStats) -> tuple[PatchEncoding, Survivors]:
    """Trim the least important until the file fits as written: the finish can grow it, and the
    metadata then records each prefix's PSNR, scored on what is left (without that table in
    the fit, kacytran at SPZ/16 came out 23 bytes over: docs/LOG.md 13.20)."""
    s = survivors
    encoding = encoder.layer(s.cloud, s.quantized, s.importance)
    prefix, scored = None, False
    while True:
        final = run.writer.with_prefix_psnr(prefix)
        if len(s.cloud) > 1 and run.sizing.overflows(final, encoding):
            s = s.subset(run.sizing.fit(final, encoder, s.cloud, s.quantized, s.importance))
            encoding = encoder.layer(s.cloud, s.quantized, s.importance)
            run.sizing.trimmed()
        elif scored:
            break
        prefix = _prefix_psnr(stage, s.cloud, s.quantized, encoding.order) \
            if len(encoding.layers) > 1 else None
        scored = True
    if prefix:
        train_stats.prefix_psnr = prefix
    return encoding, s


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
