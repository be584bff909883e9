"""How long a retrained encode will take here, measured before any long stage starts.

A retrained encode spends its time in three places: rendering the training targets, the training
steps (retraining and the quantization-aware finish, with the renders that check and rank them),
and the closing evaluation. A few seconds of probing (more on a loaded machine) measure what
each costs per unit on this machine and this scene (renders of the input at target views and
close crops, a few training steps of a pruned subset, a render at a sampled and at a close-up
evaluation view), and the counts the configuration sets scale them: the first line a retrained
encode prints is the whole run's estimate, stage by stage. The training probe stands in for the
pruned patch before the sketch exists, and a shared machine's load moves every figure, so the
first training steps correct it (one line, :func:`.retraining.clock.correction_line`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np
import torch

from spcodec.cloud import GaussianCloud
from spcodec.imaging.cameras import Camera
from spcodec.imaging.render import GaussianParams, RenderSettings, render
from spcodec.imaging.training.loop import FitLoop
from spcodec.imaging.training.optim import FreeGaussians, camera_extent
from spcodec.imaging.training.targets import Targets, TargetView

from .config import RetrainConfig
from .prune import kept_count

PROBE_RENDERS = 2
"""Target views (and as many crops) the probe times, spread since views differ in cost, after
one of each it does not time: the first renders of a size run slower (the C library's
allocator adapts to the renderer's large temporaries), up to twice a run's mean."""

PROBE_STEPS = 4
"""Training steps the probe times, after one it does not (the first allocates its buffers)."""

CHECK_RENDERS = 7 * 8
"""Renders of the pruned scene that check training, besides its steps: seven mean PSNRs over
8 training views (before, snapped, retrained, quantized, finished, the quantization loss twice)."""

RANKINGS = 3
"""Blend-weight passes over the importance views during training (snapping, quantizing, the
finish's order), each about one render of the pruned scene per view."""

PREFIX_VIEWS = 8
"""Views of each layer prefix's PSNR (the file's metadata), per patch layer."""


@dataclass(frozen=True)
class EvalShape:
    """The closing evaluation's framings: views, and each framing's (distance, side in pixels)."""

    views: int = 8
    framings: tuple[tuple[float, int], ...] = ((1.0, 400), (0.5, 800), (0.25, 800))


@dataclass
class RunEstimate:
    """Seconds each stage of a retrained encode should take here."""

    targets: float
    training: float
    """Retraining and finish steps, and the renders that check and rank them."""
    evaluation: float | None
    """None: the encode skips it (``--no-eval``)."""
    step: float
    """Seconds of one training step, as probed (or as measured, once corrected)."""
    steps: int
    """Retraining and finish steps together."""
    fixed: float
    """The training stage's seconds that are not steps."""

    @property
    def total(self) -> float:
        return self.targets + self.training + (self.evaluation or 0.0)

    def seconds(self) -> dict:
        """Each stage's seconds and the total, as statistics record them."""
        return {"targets": self.targets, "training": self.training,
                "evaluation": self.evaluation, "total": self.total}

    def corrected(self, step: float) -> "RunEstimate":
        """The estimate with ``step`` seconds per training step (as the first steps measure)."""
        return replace(self, training=self.steps * step + self.fixed, step=step)

    def line(self, retrain: RetrainConfig) -> str:
        """The first line of a retrained encode: the whole run, stage by stage, and the ways to
        a faster encode."""
        evaluation = "evaluation skipped" if self.evaluation is None else \
            f"evaluation {duration(self.evaluation)}"
        faster = ""
        if retrain.iterations > 1000:
            quick = replace(self, steps=1000 + retrain.finish_iterations).corrected(self.step)
            faster = f"; --iterations 1000: about {duration(quick.total)}, about 1 dB less"
        if self.evaluation is not None:
            faster += "; --no-eval skips the evaluation"
        return (f"this encode takes about {duration(self.total)} here: targets "
                f"{duration(self.targets)}, retraining + finish {duration(self.training)} "
                f"({self.steps:,} steps at ~{self.step:.2f} s), {evaluation} (measured per "
                "stage on this machine; corrected once training runs). Fast: --no-retrain, seconds "
                f"to a minute, for a larger file{faster}")


def duration(seconds: float) -> str:
    """``95 s``, ``12 min``, ``1 h 05 min``: to the precision an estimate has."""
    if seconds < 90:
        return f"{seconds:.0f} s"
    minutes = int(round(seconds / 60))
    return f"{minutes} min" if minutes < 60 else f"{minutes // 60} h {minutes % 60:02d} min"


def estimate_run(cloud: GaussianCloud, retrain: RetrainConfig, targets: list[tuple[Camera, bool]],
                 settings: RenderSettings, device: torch.device, layers: int,
                 evaluation: tuple[EvalShape, list[Camera], RenderSettings] | None
                 ) -> RunEstimate:
    """Probe this machine and scene and scale to the whole run.

    ``targets``: the target cameras with whether each is a crop (distillation renders each
    once; a dataset's images are read and each checked by one render, the reading not probed);
    ``evaluation``: the evaluation's shape, one camera per framing and its render settings, or
    None when it is skipped."""
    params = GaussianParams.from_cloud(cloud, device)
    whole = [c for c, crop in targets if not crop]
    crops = [c for c, crop in targets if crop]
    probe_whole, probe_crops = _spread(whole, PROBE_RENDERS), _spread(crops, PROBE_RENDERS)
    with torch.no_grad():
        for camera in probe_whole[:1] + probe_crops[:1]:  # a size's first render costs more
            render(params, camera, settings)
        images, per_whole = _rendered(params, probe_whole, settings, crop=False)
        crop_images, per_crop = _rendered(params, probe_crops, settings, crop=True)
    images += crop_images
    targets_seconds = len(whole) * per_whole + len(crops) * per_crop

    survivors = _pruned_stand_in(cloud, retrain.patch_downsample)
    step = _step_seconds(survivors, images, settings, device)
    pruned = GaussianParams.from_cloud(survivors, device)
    with torch.no_grad():
        t = time.perf_counter()
        for camera, _, _ in images[:max(len(probe_whole), 1)]:
            render(pruned, camera, settings)
        per_pruned = (time.perf_counter() - t) / max(len(probe_whole), 1)
    fixed = (CHECK_RENDERS + RANKINGS * retrain.importance_views + PREFIX_VIEWS * layers) \
        * per_pruned + retrain.importance_views * per_whole  # and the scene's blend weights
    steps = retrain.iterations + retrain.finish_iterations
    evaluation_seconds = None
    if evaluation is not None:
        evaluation_seconds = _evaluation_seconds(params, *evaluation)
    return RunEstimate(targets_seconds, steps * step + fixed, evaluation_seconds, step, steps,
                       fixed)


def _rendered(params: GaussianParams, cameras: list[Camera], settings: RenderSettings,
              crop: bool) -> tuple[list[tuple[Camera, torch.Tensor, bool]], float]:
    """Renders of ``params`` at ``cameras`` as probe targets, and the mean seconds of one."""
    start = time.perf_counter()
    images = [(c, render(params, c, settings).image.clamp(0, 1), crop) for c in cameras]
    return images, (time.perf_counter() - start) / max(len(cameras), 1)


def _spread(items: list, count: int) -> list:
    if len(items) <= count:
        return list(items)
    return [items[i] for i in np.linspace(0, len(items) - 1, count).round().astype(int)]


def _pruned_stand_in(cloud: GaussianCloud, downsample: float) -> GaussianCloud:
    """As many of ``cloud``'s Gaussians as pruning keeps, the most opaque: what a training step
    renders (the sketch is not known yet; its Gaussians would be rendered too)."""
    keep = kept_count(len(cloud), downsample)
    rows = np.sort(np.argsort(-cloud.activated_opacity(), kind="stable")[:keep])
    return cloud.subset(rows)


def _step_seconds(survivors: GaussianCloud, images: list[tuple[Camera, torch.Tensor, bool]],
                  settings: RenderSettings, device: torch.device) -> float:
    """Mean seconds of a training step of ``survivors`` over the probe's views, whole and crops
    alike (training draws from both)."""
    views = [TargetView(camera, image, crop=crop) for camera, image, crop in images]
    extent = camera_extent(np.stack([v.camera.position for v in views]))
    model = FreeGaussians(survivors, device, extent=extent)
    loop = FitLoop(model, Targets(views, settings.background, "distillation"), settings,
                   total=PROBE_STEPS + 1)
    loop.one_step()
    start = time.perf_counter()
    loop.run()
    return (time.perf_counter() - start) / PROBE_STEPS


def _evaluation_seconds(params: GaussianParams, shape: EvalShape, cameras: list[Camera],
                        settings: RenderSettings) -> float:
    """The evaluation renders the input and the file at every view of every framing and scores
    each pair. Probed: the input at one view of the first framing and of the next, at full size
    (a render's cost grows faster than its pixels), further framings costing what the second
    does. The file costs what the input does: retraining covers the same pixels with fewer,
    larger Gaussians (a pruned but untrained stand-in renders faster than the file will)."""
    from spcodec.imaging.metrics import image_metrics

    per_view = []
    with torch.no_grad():
        for camera in cameras[:2]:
            start = time.perf_counter()
            reference = render(params, camera, settings).image.clamp(0, 1).cpu().numpy()
            drawn = time.perf_counter() - start
            start = time.perf_counter()
            image_metrics(reference, reference)
            per_view.append(2 * drawn + time.perf_counter() - start)
    per_view += per_view[-1:] * (len(cameras) - len(per_view))
    return sum(per_view) * shape.views
