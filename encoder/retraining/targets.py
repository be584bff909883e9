"""What pruning and retraining look at: the target images (dataset training views or renders of
the input) and the blend weights of the whole scene over them.

They are made before any other work, so that a bad dataset fails fast, after the whole run's
estimate is printed (rendering them takes minutes).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import torch

from spcodec.cloud import GaussianCloud
from spcodec.imaging.cameras import Camera
from spcodec.imaging.importance import blend_weights
from spcodec.imaging.render import RenderSettings, resolve_device
from spcodec.imaging.training.targets import Targets, check_targets, dataset_targets, distillation_targets

from ..config import EncoderConfig, RetrainConfig
from ..estimate import EvalShape, RunEstimate, estimate_run
from ..stages import ProgressFactory
from .control import RunControl
from .stage import spread

DISTILLATION_BACKGROUND = (0.0, 0.0, 0.0)
"""Background of distillation renders (the one ``spcodec eval --reference`` uses)."""

_NO_RETRAIN = RetrainConfig()
"""Where rate control without retraining takes its view settings from."""

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
    from spcodec.imaging.views import robust_bounds, sample_views

    judged = EvalConfig()
    if dataset is not None:
        test = dataset.test[:judged.max_views] if judged.max_views else dataset.test
        camera = (test or dataset.train)[0].camera
        return (EvalShape(len(test), ((1.0, camera.width),)), [camera],
                config.render_settings(_background(dataset), dataset=True))
    bounds = robust_bounds(cloud)
    first = sample_views(cloud, judged.views, resolution=(judged.resolution,) * 2, split="eval",
                         seed=judged.seed, up=config.up, bounds=bounds,
                         warn=False)[0]  # the evaluation itself says it
    zoom = judged.closeup_resolution / judged.resolution
    framings = ((1.0, judged.resolution),) + tuple(
        (d, judged.closeup_resolution) for d in judged.closeups)
    cameras = [first] + [first.scaled(zoom).dollied(bounds.centre, d) for d in judged.closeups]
    settings = RenderSettings(background=judged.background, antialiased=config.antialiased,
                              blur_variance=judged.blur_variance)
    return EvalShape(judged.views, framings), cameras, settings
