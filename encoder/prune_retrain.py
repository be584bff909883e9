"""The patch stage when it prunes: which patch Gaussians survive and, with retraining,
:mod:`.retraining` between pruning and layering. How many survive is :mod:`.sizing`'s to say (a
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
from .retraining.run import RetrainRun, retrain_patch
from .retraining.targets import PreparedTargets
from .sizing import Sizing, pruned_file
from .stages import EncodeRun, PatchChoice, SceneWriter, SketchOutcome


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
    return pruned_file(writer, PatchEncoder(config.patch, seed=config.seed, jobs=config.n_jobs), patch,
                       weights[sketch.patch_idx],
                       kept_count(len(patch), config.retrain.patch_downsample))


def encode_pruned_patch(run: EncodeRun, sketch: SketchOutcome, patch: GaussianCloud,
                        writer: SceneWriter, prepared: PreparedTargets | None,
                        weights: np.ndarray, sizing: Sizing) -> PatchChoice:
    """Prune (and retrain, when ``run.config.retrain`` is set) the ``patch`` the ``sketch``
    left, as many as ``sizing`` says (:func:`.sizing.sizing_for`). ``weights`` rank the whole
    scene's Gaussians (:func:`.retraining.targets.scene_weights` when retraining, the patch
    encoder's importance without); ``prepared`` holds the targets (retraining only)."""
    config = run.config
    encoder = PatchEncoder(config.patch, seed=config.seed, jobs=config.n_jobs)
    weights = weights[sketch.patch_idx]
    keep = _prune(run, patch, weights, writer, encoder, sizing, sketch.patch_idx)
    encoder = sizing.encoder_for(encoder)
    if config.retrain is None:
        return _sized_patch(run, patch, keep, weights, writer, encoder, sizing)
    retraining = RetrainRun(config, prepared.targets, writer, encoder, sizing, run.control,
                            _checkpointer(run), run.progress, run.times, prepared.estimate)
    choice = retrain_patch(retraining, patch, keep, weights[keep])
    return dataclasses.replace(choice, psnr_input=prepared.psnr_input)


def _prune(run: EncodeRun, patch: GaussianCloud, weights: np.ndarray, writer: SceneWriter,
           encoder: PatchEncoder, sizing: Sizing, patch_idx: np.ndarray) -> np.ndarray:
    """The survivors of ``patch`` (sorted rows), as many as the sizing plans."""
    config = run.config
    t = time.perf_counter()
    stage = run.progress("prune", None)
    keep = sizing.plan(patch, weights, writer, encoder, patch_idx)
    method = config.retrain.prune if config.retrain is not None else "importance"
    kept = select(method, len(patch), keep, config.seed, weights)
    stage.done(f"{len(kept)} of {len(patch)} patch Gaussians kept ({method})")
    run.times["prune"] = time.perf_counter() - t
    return kept


def _sized_patch(run: EncodeRun, patch: GaussianCloud, kept: np.ndarray, weights: np.ndarray,
                 writer: SceneWriter, encoder: PatchEncoder, sizing: Sizing) -> PatchChoice:
    """The survivors coded without retraining, trimmed when the file spills over the target."""
    t = time.perf_counter()
    stage = run.progress("patch", None)
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
    run.times["patch"] = time.perf_counter() - t
    return PatchChoice(encoding, kept, sizing=sizing.stats())


def _checkpointer(run: EncodeRun) -> Checkpointer | None:
    """The checkpoints of this run (None: none configured), fingerprinted by what it trains."""
    if run.control.checkpoint is None:
        return None
    # whether the end evaluates changes nothing trained: --resume may add or drop --no-eval
    settings = {k: v for k, v in run.config.to_json().items() if k != "evaluate"}
    dataset = "" if run.dataset is None else str(Path(run.dataset).resolve())
    return Checkpointer(Path(run.control.checkpoint), fingerprint(run.cloud, settings, dataset))
