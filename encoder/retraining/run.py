"""One retraining run of the pruned patch: retrain, quantize, the quantization-aware finish and
the trim that makes the file fit, asking :mod:`spcodec.encoder.sizing` how many to keep at each
point, then the patch layers (nested or not) the file stores.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from spcodec.cloud import GaussianCloud
from spcodec.imaging.training.checkpoint import Checkpointer
from spcodec.imaging.training.targets import Targets

from ..config import EncoderConfig, RetrainConfig
from ..estimate import RunEstimate
from ..patch import PatchEncoder, Quantized, quantized_cloud
from ..sizing import Sizing
from ..stages import PatchChoice, ProgressFactory, SceneWriter
from .clock import TrainingClock, meter
from .control import RunControl
from .nested import NestedEncoder, layer_priority, layers_of, nested_groups, prefix_ends, prefix_schedule
from .stage import RetrainStage


def retrain_patch(retrain: RetrainConfig, targets: Targets, writer: SceneWriter,
             encoder: PatchEncoder, patch: GaussianCloud, kept: np.ndarray, weights: np.ndarray,
             sizing: Sizing, config: EncoderConfig, control: RunControl,
             checkpointer: Checkpointer | None, progress: ProgressFactory,
             times: dict[str, float], stats: dict, estimate: RunEstimate) -> PatchChoice:
    layers = encoder.config.layers
    layer_of = None  # nested: the layer of each survivor, fixed before training
    train_stats: dict = {"prune": retrain.prune}
    if retrain.nested:  # every step trains one layer prefix (:mod:`.nested`)
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
                            meter(report, clock, retrain.finish_iterations, estimate))
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
    quantized, trained = stage.finish(trained, quantized, train_stats, meter(report, clock))
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
