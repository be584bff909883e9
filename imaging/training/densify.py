"""Adaptive density control of vanilla 3DGS training: grow Gaussians where the image needs them,
drop the transparent and the oversized ones.

The rule is that of the 3DGS paper (Kerbl et al. 2023, section 5.2) as the INRIA code and gsplat's
default strategy run it:

* **Statistics.** After every step, each Gaussian the view drew adds the norm of its view-space
  positional gradient (d loss / d screen position, measured in normalized device coordinates, so
  pixels times half the image size: the threshold then means the same at any resolution) and
  one to its count; its largest screen radius is kept too.
* **Densify** every ``every`` steps from ``start`` to ``stop``: a Gaussian whose mean gradient
  reaches ``grad_threshold`` is under-reconstructed. Small ones (largest scale at most
  ``percent_dense`` of the scene extent) are **cloned** (an exact copy, which the optimizer then
  pulls apart); large ones are **split** into ``split_into`` children drawn from the Gaussian
  itself, their scales divided by ``split_scale_divisor`` (INRIA's ``0.8 * N``).
* **Prune** at the same time: opacity below ``min_opacity``, and after the first periodic
  opacity reset (step ``reset_every``) also a screen radius above ``max_screen_radius`` pixels
  (since the last densification) or a world scale above ``max_world_scale`` times the extent.
* **Reset opacities** to at most ``reset_opacity`` every ``reset_every`` steps (and at ``start``
  when ``reset_at_start``, which INRIA does for white backgrounds), so floaters must earn their
  opacity back or be pruned.

Every change keeps the optimizer aligned with the tensors: appended Gaussians get zero Adam
moments, removed ones take their moments with them, a reset zeroes the opacity moments
(:func:`append_gaussians`, :func:`keep_gaussians`, :func:`reset_opacities`).

The defaults are those of a 30,000-step run; :meth:`DensifyConfig.scaled` shrinks every step
count in proportion for a shorter run (as gsplat's ``steps_scaler`` does).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import torch

from ..render import RenderResult
from ..render.projection import rotation_entries
from .optim import FreeGaussians

REFERENCE_ITERATIONS = 30_000
"""The run length the default schedule was made for (INRIA and gsplat)."""


@dataclass(frozen=True)
class DensifyConfig:
    """When and how adaptive density control acts; steps count completed optimizer steps."""

    #: Mean view-space gradient norm (NDC units) from which a Gaussian is densified.
    grad_threshold: float = 0.0002
    #: Densify at every multiple of ``every`` after ``start`` and before ``stop``.
    start: int = 500
    stop: int = 15_000
    every: int = 100
    #: Opacity reset period (while densifying), and whether one also happens at ``start``.
    reset_every: int = 3_000
    reset_at_start: bool = False
    reset_opacity: float = 0.01
    #: Pruned when less opaque than this.
    min_opacity: float = 0.005
    #: Clone when the largest scale is at most this fraction of the extent, else split.
    percent_dense: float = 0.01
    split_into: int = 2
    split_scale_divisor: float = 1.6
    #: After step ``reset_every``, pruned when larger on screen (pixels) or in the world
    #: (x extent); None turns the screen rule off.
    max_screen_radius: float | None = 20.0
    max_world_scale: float = 0.1

    def __post_init__(self) -> None:
        if min(self.start, self.stop, self.every, self.reset_every) < 0 or self.every == 0 \
                or self.reset_every == 0:
            raise ValueError("densification steps must be non-negative, every/reset_every > 0")
        if self.split_into < 1 or self.split_scale_divisor <= 0:
            raise ValueError("split_into must be >= 1 and split_scale_divisor positive")

    def scaled(self, iterations: int) -> "DensifyConfig":
        """The same schedule for a run of ``iterations`` steps: start, stop, every and
        reset_every times ``iterations / 30000`` (at least 1 step each); thresholds unchanged."""
        factor = iterations / REFERENCE_ITERATIONS

        def steps(value: int) -> int:
            return max(1, round(value * factor))

        return replace(self, start=steps(self.start), stop=steps(self.stop),
                       every=steps(self.every), reset_every=steps(self.reset_every))


@dataclass(frozen=True)
class DensifyEvent:
    """What one densification did (counts of Gaussians)."""

    step: int
    cloned: int
    split: int
    pruned: int
    total: int


class Densifier:
    """Accumulates the statistics of :class:`FreeGaussians` over steps and densifies, prunes and
    resets opacities on schedule. Call :meth:`after_step` after every optimizer step (it fits
    :class:`~spcodec.imaging.training.loop.FitLoop`'s ``after_step`` hook via a lambda)."""

    def __init__(self, config: DensifyConfig, extent: float, seed: int = 0) -> None:
        self.config, self.extent = config, float(extent)
        self.generator = torch.Generator().manual_seed(seed)
        self.grad_sum = self.count = self.max_radius = None
        self.events: list[DensifyEvent] = []
        self.resets: list[int] = []

    def reset_statistics(self, n: int, device: torch.device) -> None:
        self.grad_sum = torch.zeros(n, device=device)
        self.count = torch.zeros(n, device=device)
        self.max_radius = torch.zeros(n, device=device)

    def observe(self, result: RenderResult) -> None:
        """Add one render's view-space gradients (NDC) and radii of the Gaussians it drew."""
        grad = result.means2d_grad()
        if grad is None:
            raise ValueError("the render has no screen-position gradient: call backward() first")
        n = grad.shape[0]
        if self.grad_sum is None or self.grad_sum.shape[0] != n:
            if self.grad_sum is not None:
                raise ValueError(f"the render has {n} Gaussians, the statistics "
                                 f"{self.grad_sum.shape[0]}: densify through this object only")
            self.reset_statistics(n, grad.device)
        height, width = result.image.shape[:2]
        half = grad.new_tensor([width / 2.0, height / 2.0])
        seen = result.visible
        with torch.no_grad():
            self.grad_sum[seen] += (grad[seen] * half).norm(dim=1)
            self.count[seen] += 1
            self.max_radius[seen] = torch.maximum(self.max_radius[seen],
                                                  result.radii[seen].to(self.max_radius.dtype))

    def after_step(self, model: FreeGaussians, step: int, result: RenderResult) -> None:
        """The schedule, after ``step`` completed steps whose last render was ``result``."""
        c = self.config
        if step >= c.stop:
            return
        self.observe(result)
        if step > c.start and step % c.every == 0:
            self.densify(model, step)
        if step % c.reset_every == 0 or (c.reset_at_start and step == c.start):
            reset_opacities(model, c.reset_opacity)
            self.resets.append(step)

    def densify(self, model: FreeGaussians, step: int) -> DensifyEvent:
        """Clone, split and prune now (see the module docstring); statistics start over."""
        c = self.config
        t = model.tensors
        n = len(model)
        if self.grad_sum is None:
            self.reset_statistics(n, t["means"].device)
        with torch.no_grad():
            mean_grad = self.grad_sum / self.count.clamp_min(1)
            grow = mean_grad >= c.grad_threshold
            largest = t["scales"].max(dim=1).values.exp()
            small = largest <= c.percent_dense * self.extent
            clone, split = grow & small, grow & ~small
            grown = {name: torch.cat([value[clone], part])
                     for (name, value), part in zip(t.items(), self.split_children(model, split)
                                                    .values())}
            append_gaussians(model, grown)
            added = len(model) - n
            remove = torch.cat([split, split.new_zeros(added)])
            remove |= torch.sigmoid(model.tensors["opacities"]) < c.min_opacity
            if step > c.reset_every:  # INRIA: oversized ones go after the first periodic reset
                largest = model.tensors["scales"].max(dim=1).values.exp()
                remove |= largest > c.max_world_scale * self.extent
                if c.max_screen_radius is not None:
                    radius = torch.cat([self.max_radius, self.max_radius.new_zeros(added)])
                    remove |= radius > c.max_screen_radius
            keep_gaussians(model, ~remove)
        event = DensifyEvent(step, int(clone.sum()), int(split.sum()),
                             int(remove.sum()) - int(split.sum()), len(model))
        self.events.append(event)
        self.reset_statistics(len(model), t["means"].device)
        return event

    def split_children(self, model: FreeGaussians, split: torch.Tensor
                       ) -> dict[str, torch.Tensor]:
        """``split_into`` children of every Gaussian in ``split``: positions drawn from the
        Gaussian (its scales, rotated), scales divided by ``split_scale_divisor``, the rest
        copied."""
        c = self.config
        parents = {name: value.detach()[split] for name, value in model.tensors.items()}
        children = {name: value.repeat_interleave(c.split_into, dim=0)
                    for name, value in parents.items()}
        stds = children["scales"].exp()
        local = torch.randn(stds.shape, generator=self.generator).to(stds) * stds
        rot = rotation_entries(children["quats"])
        offset = torch.stack([sum(rot[i][j] * local[:, j] for j in range(3)) for i in range(3)],
                             dim=1)
        children["means"] = children["means"] + offset
        children["scales"] = children["scales"] - math.log(c.split_scale_divisor)
        return children


# ------------------------------------------------------------------------ optimizer surgery
def _replace(model: FreeGaussians, name: str, value: torch.Tensor, moments) -> None:
    """Swap tensor ``name`` for the leaf ``value`` everywhere the model and its Adam hold it;
    ``moments(old_moment)`` gives each per-Gaussian optimizer state entry its new value."""
    old = model.tensors[name]
    new = value.detach().requires_grad_(True)
    for group in model.optimizer.param_groups:
        group["params"] = [new if p is old else p for p in group["params"]]
    state = model.optimizer.state.pop(old, None)
    if state is not None:
        model.optimizer.state[new] = {
            key: moments(entry) if torch.is_tensor(entry) and entry.dim() > 0
            and entry.shape[0] == old.shape[0] else entry
            for key, entry in state.items()}
    model.tensors[name] = new


def append_gaussians(model: FreeGaussians, new: dict[str, torch.Tensor]) -> None:
    """Add Gaussians (one tensor per attribute, same layout as ``model.tensors``) after the
    existing ones; their Adam moments start at zero."""
    for name, value in new.items():
        old = model.tensors[name]
        extra = value.shape[0]
        _replace(model, name, torch.cat([old.detach(), value.to(old)]),
                 lambda m, k=extra: torch.cat([m, m.new_zeros((k,) + m.shape[1:])]))


def keep_gaussians(model: FreeGaussians, keep: torch.Tensor) -> None:
    """Keep only the Gaussians where the (N,) bool ``keep`` is true, with their Adam moments."""
    for name in list(model.tensors):
        _replace(model, name, model.tensors[name].detach()[keep], lambda m: m[keep])


def reset_opacities(model: FreeGaussians, ceiling: float) -> None:
    """Lower every opacity to at most ``ceiling`` and zero the opacity's Adam moments."""
    logits = model.tensors["opacities"].detach()
    limit = math.log(ceiling / (1.0 - ceiling))
    _replace(model, "opacities", logits.clamp_max(limit), torch.zeros_like)
