"""What a training loop fits: posed target images, from a dataset or rendered from the original.

* **Distillation** (a PLY and nothing else): the original model is rendered at views sampled
  around it (:func:`~spcodec.imaging.views.sample_views`, split ``"train"``, which never shares a
  camera with the ``"eval"`` views that ``spcodec eval --reference`` judges by), and those renders
  are the targets; so are crops of closer views (:func:`~spcodec.imaging.views.close_crops`),
  where the detail a whole-scene view leaves below a pixel covers several.
* **Dataset** (``--dataset DIR``): the dataset's training images; its test split stays held out for
  evaluation.

Targets live on the training device as float32 (H, W, 3) tensors: a few dozen views of 400x400
take ~2 MB each.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Literal

import numpy as np
import torch

from spcodec.cloud import GaussianCloud
from spcodec.errors import UsageError

from ..cameras import Camera
from ..render import GaussianParams, RenderSettings, render
from .loss import psnr_of
from .optim import camera_extent

TargetMode = Literal["distillation", "dataset"]

MIN_VISIBLE_ALPHA = 0.01
"""Below this mean accumulated opacity over the training views, the cameras do not see the model."""


@dataclass
class TargetView:
    """One training view: its camera, target image and (optional) mask of valid pixels."""

    camera: Camera
    image: torch.Tensor
    mask: torch.Tensor | None = None
    crop: bool = False
    """A crop of a larger frame: it shows part of the scene, so it does not rank Gaussians."""


@dataclass
class Targets:
    """The training views of one run, their background colour and the scene extent they imply."""

    views: list[TargetView]
    background: tuple[float, float, float]
    mode: TargetMode
    psnr_model: float | None = None
    """Distillation: mean PSNR of the model the targets were rendered from, against them, taken
    from those renders (what :func:`check_targets` measures, without drawing them again)."""

    @property
    def cameras(self) -> list[Camera]:
        return [v.camera for v in self.views]

    @property
    def whole_cameras(self) -> list[Camera]:
        """The cameras of the views that show their whole frame (not crops): what blend weights
        rank Gaussians over, since a crop sees only some of them."""
        return [v.camera for v in self.views if not v.crop] or self.cameras

    @property
    def extent(self) -> float:
        """The spatial scale of position learning rates (see :func:`camera_extent`)."""
        return camera_extent(np.stack([c.position for c in self.cameras]))


def distillation_targets(original: GaussianCloud, cameras: list[Camera], settings: RenderSettings,
                         device: torch.device, crops: list[Camera] = (),
                         on_view: Callable[[], None] | None = None) -> Targets:
    """Renders of ``original`` at ``cameras`` (sampled "train" views) and at ``crops`` (close-up
    crops) as targets, each crop rendered as its own small camera (only its pixels).

    The same renders give the figures :func:`check_targets` would take from a second pass over
    the views (coverage, the model's PSNR against them): the targets are the model's renders, so
    that pass would draw the same images again. ``on_view`` is called after each view."""
    params = GaussianParams.from_cloud(original, device)
    views, alphas, psnrs = [], [], []
    with torch.no_grad():
        for camera, crop in [(c, False) for c in cameras] + [(c, True) for c in crops]:
            result = render(params, camera, settings)
            image = result.image.clamp(0.0, 1.0)
            alphas.append(float(result.alpha.mean()))
            psnrs.append(psnr_of(result.image, image))
            views.append(TargetView(camera, image.to(torch.float32), crop=crop))
            if on_view is not None:
                on_view()
    _refuse_unseen(alphas)
    return Targets(views, settings.background, "distillation",
                   float(np.mean(psnrs)) if psnrs else None)


def dataset_targets(dataset, device: torch.device, max_views: int | None = None,
                    on_view: Callable[[], None] | None = None) -> Targets:
    """The training split of a loaded :class:`~spcodec.imaging.datasets.Dataset` (``on_view``
    is called after each image is read)."""
    chosen = dataset.train[:max_views] if max_views else dataset.train
    if not chosen:
        raise UsageError(f"dataset {dataset.root} has no training views")
    views = []
    for view in chosen:
        image = torch.from_numpy(np.ascontiguousarray(view.load_image())).to(device)
        mask = view.valid_mask()
        views.append(TargetView(view.camera, image,
                                None if mask is None else torch.from_numpy(mask).to(device)))
        if on_view is not None:
            on_view()
    background = tuple(float(c) for c in dataset.background)
    return Targets(views, background, "dataset")


def check_targets(model: GaussianCloud, targets: Targets, settings: RenderSettings,
                  device: torch.device, source: str | None = None,
                  on_view: Callable[[], None] | None = None) -> float:
    """Refuse targets whose cameras do not see ``model`` (a UsageError when it covers less than
    :data:`MIN_VISIBLE_ALPHA` of their pixels on average: nothing could be trained), and warn
    when dataset images and model look unrelated before any training (the evaluation's
    :func:`~spcodec.imaging.evaluate.warn_if_mismatched`). Returns the mean PSNR of ``model``
    over the targets. ``on_view`` is called after each view rendered."""
    from ..evaluate import warn_if_mismatched

    params = GaussianParams.from_cloud(model, device)
    alphas, psnrs = [], []
    with torch.no_grad():
        for view in targets.views:
            result = render(params, view.camera, settings)
            alphas.append(float(result.alpha.mean()))
            psnrs.append(psnr_of(result.image, view.image))
            if on_view is not None:
                on_view()
    _refuse_unseen(alphas)
    psnr = float(np.mean(psnrs))
    if targets.mode == "dataset":
        warn_if_mismatched(psnr, source)
    return psnr


def _refuse_unseen(alphas: list[float]) -> None:
    """The UsageError of cameras that do not see the model (mean coverage ``alphas``)."""
    mean = float(np.mean(alphas)) if alphas else 0.0
    if mean < MIN_VISIBLE_ALPHA:
        raise UsageError(f"the training cameras do not see the model (it covers {mean:.2%} of "
                         "their pixels on average): are the dataset and the PLY of the same scene "
                         "and coordinate frame?")
