"""One loop for every optimization against target images, with parts of the scene held frozen.

:class:`FitLoop` renders ``frozen + model`` at one target view per step (views in a seeded
permutation per epoch, so step ``i`` always shows the same view whatever happened before: a
resumed run replays an uninterrupted one exactly), takes the 3DGS loss and steps the model's
optimizer. What is optimized is the model's business (:class:`Fittable`): free Gaussians during
retraining, codebook entries during the quantization-aware finish.

Stopping is cooperative: :meth:`FitLoop.run` returns after the step in progress when its
``stop`` event is set (``spcodec encode`` sets it on Ctrl-C), so a checkpoint never holds a
half-applied optimizer step.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field
from typing import Callable, Protocol

import numpy as np
import torch

from ..render import GaussianParams, RenderResult, RenderSettings, render
from .loss import DSSIM_WEIGHT, photometric_loss, psnr_of
from .targets import Targets, TargetView


class Fittable(Protocol):
    """What :class:`FitLoop` optimizes."""

    optimizer: torch.optim.Optimizer

    def params(self) -> GaussianParams:
        """The Gaussians to render, differentiable w.r.t. the optimized tensors."""

    def before_step(self, step: int, total: int) -> None:
        """Adjust rates (schedules) before step ``step`` of ``total``."""

    def state_dict(self) -> dict:
        """Every tensor and optimizer state needed to continue (for checkpoints)."""

    def load_state_dict(self, state: dict) -> None:
        ...


@dataclass
class StepReport:
    """What one step did: its index (1-based count of completed steps), loss and PSNR."""

    step: int
    total: int
    loss: float
    psnr: float


def join(frozen: GaussianParams | None, free: GaussianParams) -> GaussianParams:
    """The scene one step renders: the frozen Gaussians (no gradient) followed by the free ones."""
    if frozen is None or len(frozen) == 0:
        return free
    return GaussianParams(*(torch.cat([a, b], dim=0) for a, b in
                            zip(frozen.tensors(), free.tensors())))


def view_order(count: int, step: int, seed: int) -> int:
    """Index of the target view of step ``step``: epochs are seeded permutations of the views."""
    epoch, within = divmod(step, count)
    return int(np.random.default_rng([seed, epoch]).permutation(count)[within])


@dataclass
class FitLoop:
    """Optimize ``model`` for ``total`` steps against ``targets`` with ``frozen`` rendered too."""

    model: Fittable
    targets: Targets
    settings: RenderSettings
    total: int
    seed: int = 0
    frozen: GaussianParams | None = None
    dssim_weight: float = DSSIM_WEIGHT
    step: int = 0
    """Steps completed so far (restored from a checkpoint to resume)."""
    stop: threading.Event = field(default_factory=threading.Event)
    after_step: Callable[[int, RenderResult], None] | None = None
    """Called after each optimizer step with the count of completed steps and that step's render
    (its screen-position gradient still attached): adaptive density control hooks in here."""
    visible: Callable[[int], int | None] | None = None
    """How many of the model's Gaussians (its first ones) step ``step`` renders and trains (None:
    all): nested retraining trains every layer prefix of the file this way."""

    def view(self, step: int) -> TargetView:
        return self.targets.views[view_order(len(self.targets.views), step, self.seed)]

    def one_step(self) -> StepReport:
        """Render the next view, backpropagate the loss, step the optimizer."""
        target = self.view(self.step)
        self.model.before_step(self.step, self.total)
        params = self.model.params()
        count = None if self.visible is None else self.visible(self.step)
        if count is not None:
            params = params.head(count)
        result = render(join(self.frozen, params), target.camera, self.settings)
        loss = photometric_loss(result.image, target.image, target.mask, self.dssim_weight)
        self.model.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        self.model.optimizer.step()
        self.step += 1
        if self.after_step is not None:
            self.after_step(self.step, result)
        return StepReport(self.step, self.total, float(loss.detach()),
                          psnr_of(result.image, target.image))

    def run(self, on_step: Callable[[StepReport], None] | None = None) -> bool:
        """Step until ``total`` (True) or until ``stop`` is set (False, after a whole step)."""
        while self.step < self.total:
            if self.stop.is_set():
                return False
            report = self.one_step()
            if on_step is not None:
                on_step(report)
        return True

    def mean_psnr(self, params: GaussianParams | None = None, views: int = 8) -> float:
        """Mean PSNR of ``frozen + params`` (default: the model) over up to ``views`` targets,
        evenly spread (the iteration-0 check and reports)."""
        params = self.model.params() if params is None else params
        picks = np.linspace(0, len(self.targets.views) - 1, min(views, len(self.targets.views)))
        values = []
        with torch.no_grad():
            scene = join(self.frozen, params.detach())
            for i in np.unique(picks.round().astype(int)):
                target = self.targets.views[i]
                image = render(scene, target.camera, self.settings).image
                values.append(psnr_of(image, target.image))
        return float(np.mean(values))
