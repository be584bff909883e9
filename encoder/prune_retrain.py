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
from pathlib import Path

import numpy as np

from spcodec.cloud import GaussianCloud
from spcodec.imaging.training.checkpoint import Checkpointer, fingerprint
from spcodec.writer import WrittenFile

from .config import EncoderConfig
from .patch import PatchEncoder
from .prune import kept_count, select
from .retraining.control import RunControl
from .retraining.run import RetrainRun, retrain_patch
from .retraining.targets import PreparedTargets
from .sizing import Sizing, pruned_file
from .stages import PatchChoice, ProgressFactory, SceneWriter, SketchOutcome


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
        return PatchChoice(encoding, kept, sizing=sizing.stats())
    checkpointer = None
    if control.checkpoint is not None:
        # whether the end evaluates changes nothing trained: --resume may add or drop --no-eval
        settings = {k: v for k, v in config.to_json().items() if k != "evaluate"}
        checkpointer = Checkpointer(Path(control.checkpoint), fingerprint(
            cloud, settings, "" if dataset is None else str(Path(dataset).resolve())))
    run = RetrainRun(config, prepared.targets, writer, encoder, sizing, control, checkpointer,
                     progress, times, prepared.estimate)
    choice = retrain_patch(run, patch, kept, weights[kept])
    return dataclasses.replace(choice, psnr_input=prepared.psnr_input)
