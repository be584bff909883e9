"""The quantization-aware finish: fine-tune codebook entries through the renderer, indices fixed.

After retraining, k-means replaces every patch attribute by its nearest codebook entry; the image
then loses what the rounding costs. This stage renders the *decoded* patch (each Gaussian's
attributes looked up from the codebooks by its fixed indices) and optimizes the entries
themselves, so each entry moves to where it serves its Gaussians best in the picture rather than
in attribute space. Midway, every Gaussian's indices are re-assigned once to the nearest of the
moved entries (its retrained values decide), and the second half adapts the entries to that.

What it optimizes is exactly what the file stores: entries pass through float16 and positions
through the 16-bit grid over the patch's bounding box on the way to the renderer, both with a
straight-through gradient. (A layer's own position grid is at least as fine, so stored positions
are within half a grid step of what was trained.)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from spcodec.attributes import OPACITY_MIN, PatchAttribute
from spcodec.cloud import GaussianCloud
from spcodec.imaging.render import GaussianParams
from spcodec.imaging.training.optim import LearningRates
from spcodec.sections import Codebook


@dataclass(frozen=True)
class EntryRates:
    """Adam rates of codebook entries per attribute, in the coded domain ([R-30])."""

    scale: float = 5e-3
    rotation: float = 1e-3
    #: Opacity entries are activated values in [0, 1] (a logit step of 2.5e-2 moves an opacity
    #: of 0.5 by about 6e-3).
    opacity: float = 5e-3
    sh_dc: float = 2.5e-3
    sh_rest: float = 1.25e-4

    def for_attribute(self, attr: PatchAttribute) -> float:
        return {PatchAttribute.SCALE: self.scale, PatchAttribute.ROTATION: self.rotation,
                PatchAttribute.OPACITY: self.opacity,
                PatchAttribute.COLOR_DC: self.sh_dc}.get(attr, self.sh_rest)


def straight_through(value: torch.Tensor, rounded: torch.Tensor) -> torch.Tensor:
    """``rounded`` in the forward pass, the identity's gradient in the backward pass."""
    return value + (rounded - value).detach()


def half_precision(value: torch.Tensor) -> torch.Tensor:
    return straight_through(value, value.to(torch.float16).to(value.dtype))


class CodebookGaussians:
    """Patch Gaussians as codebook entries plus fixed uint8 indices; entries and positions learn.

    ``indices[attr]`` is (n, groups) as the bitstream stores it; ``positions_bits`` sets the grid
    positions are rounded to in the forward pass (0: no rounding).
    """

    def __init__(self, positions: np.ndarray, codebooks: list[Codebook],
                 indices: dict[PatchAttribute, np.ndarray], sh_degree: int,
                 device: torch.device | str, entry_rates: EntryRates = EntryRates(),
                 position_rate: float = 0.0, position_bits: int = 16) -> None:
        self.device, self.sh_degree, self.n = torch.device(device), sh_degree, len(positions)
        self.attributes = [cb.attribute for cb in codebooks]
        self.entries = {cb.attribute: torch.tensor(cb.entries.astype(np.float32),
                                                   device=self.device).requires_grad_(True)
                        for cb in codebooks}
        self.indices = {a: torch.as_tensor(indices[a].astype(np.int64), device=self.device)
                        for a in self.attributes}
        xyz = torch.tensor(np.asarray(positions, np.float32), device=self.device)
        self.means = xyz.clone().requires_grad_(position_rate > 0)
        lo = xyz.min(dim=0).values if self.n else torch.zeros(3, device=self.device)
        span = (xyz.max(dim=0).values - lo).max() if self.n else torch.tensor(0.0)
        self.grid_origin = lo
        self.grid_step = float(span) / ((1 << position_bits) - 1) if position_bits else 0.0
        groups = [{"params": [self.entries[a]], "lr": entry_rates.for_attribute(a),
                   "name": a.name} for a in self.attributes]
        if position_rate > 0:
            groups.append({"params": [self.means], "lr": position_rate, "name": "means"})
        self.optimizer = torch.optim.Adam(groups, lr=0.0, eps=1e-15)

    # ---------------------------------------------------------------------------- Fittable
    def params(self) -> GaussianParams:
        values = {a: self._lookup(a) for a in self.attributes}
        n = self.n
        opacity = values[PatchAttribute.OPACITY].reshape(n).clamp(OPACITY_MIN, 1 - OPACITY_MIN)
        bands = [values[a].reshape(n, a.width // 3, 3) for a in self.attributes
                 if a > PatchAttribute.COLOR_DC]
        sh = torch.cat([values[PatchAttribute.COLOR_DC].reshape(n, 1, 3)] + bands, dim=1)
        return GaussianParams(self._positions(), values[PatchAttribute.SCALE].reshape(n, 3),
                              values[PatchAttribute.ROTATION].reshape(n, 4),
                              torch.log(opacity / (1 - opacity)), sh)

    def before_step(self, step: int, total: int) -> None:
        pass

    def state_dict(self) -> dict:
        return {"entries": {a.name: t.detach().clone() for a, t in self.entries.items()},
                "indices": {a.name: t.clone() for a, t in self.indices.items()},
                "means": self.means.detach().clone(), "optimizer": self.optimizer.state_dict()}

    def load_state_dict(self, state: dict) -> None:
        with torch.no_grad():
            for a in self.attributes:
                self.entries[a].copy_(state["entries"][a.name])
                self.indices[a] = state["indices"][a.name].to(self.device)
            self.means.copy_(state["means"])
        self.optimizer.load_state_dict(state["optimizer"])

    # ------------------------------------------------------------------------------ access
    def _lookup(self, attr: PatchAttribute) -> torch.Tensor:
        """(n, width) attribute values: the float16 entries gathered by index groups."""
        entries = half_precision(self.entries[attr])
        return entries[self.indices[attr]].reshape(self.n, -1)

    def _positions(self) -> torch.Tensor:
        if not self.grid_step:
            return self.means
        cells = torch.round((self.means - self.grid_origin) / self.grid_step)
        return straight_through(self.means, self.grid_origin + cells * self.grid_step)

    def clamp_entries(self) -> None:
        """Keep opacity entries inside [0, 1], where the coded domain lives."""
        with torch.no_grad():
            if PatchAttribute.OPACITY in self.entries:
                self.entries[PatchAttribute.OPACITY].clamp_(0.0, 1.0)

    def codebooks(self) -> list[Codebook]:
        """The entries as the file stores them (float16)."""
        return [Codebook(a, self.entries[a].detach().cpu().numpy().astype(np.float16))
                for a in self.attributes]

    def index_arrays(self) -> dict[PatchAttribute, np.ndarray]:
        return {a: t.cpu().numpy().astype(np.uint8) for a, t in self.indices.items()}

    def set_indices(self, indices: dict[PatchAttribute, np.ndarray]) -> None:
        self.indices = {a: torch.as_tensor(indices[a].astype(np.int64), device=self.device)
                        for a in self.attributes}

    def positions(self) -> np.ndarray:
        """Trained positions (unrounded: the writer applies its own grid)."""
        return self.means.detach().cpu().numpy().astype(np.float32)


def with_positions(cloud: GaussianCloud, means: np.ndarray) -> GaussianCloud:
    """``cloud`` with its positions replaced (the finish may move positions)."""
    arrays = cloud.arrays()
    arrays["means"] = means
    return GaussianCloud(**arrays)


__all__ = ["CodebookGaussians", "EntryRates", "LearningRates", "with_positions"]
