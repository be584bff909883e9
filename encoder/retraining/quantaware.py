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

:class:`SnappedGaussians` brings the same idea forward into the retraining itself: after a
warm-up, free Gaussians are rendered through their codebooks (each attribute snapped to its
nearest entry, the gradient passed straight through to the free value), with the entries kept at
the weighted k-means centroids of the free values, so training learns values that survive
quantization instead of losing what k-means rounds away afterwards.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
import torch

from spcodec.attributes import OPACITY_MIN, PatchAttribute
from spcodec.cloud import GaussianCloud
from spcodec.imaging.render import GaussianParams
from spcodec.imaging.training.optim import FreeGaussians, LearningRates
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
    """``rounded`` in the forward pass (exactly: ``value - value`` is 0), the identity's gradient
    in the backward pass."""
    return rounded.detach() + (value - value.detach())


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


# ------------------------------------------------------------------ quantization-aware retraining
def coded_tensors(params: GaussianParams, attributes: list[PatchAttribute]
                  ) -> dict[PatchAttribute, torch.Tensor]:
    """Each attribute of ``params`` in its coded domain ([R-30]) as (n, width) tensors, the torch
    twin of :func:`spcodec.encoder.patch.coded_attributes` (differentiable)."""
    n = len(params)
    quats = params.quats / params.quats.norm(dim=1, keepdim=True).clamp_min(1e-12)
    sign = torch.where(quats[:, :1] < 0, -1.0, 1.0)
    out = {PatchAttribute.SCALE: params.scales, PatchAttribute.ROTATION: quats * sign,
           PatchAttribute.OPACITY: torch.sigmoid(params.opacities)[:, None],
           PatchAttribute.COLOR_DC: params.sh[:, 0, :]}
    first = 1
    for attr in attributes[4:]:
        count = attr.width // 3
        out[attr] = params.sh[:, first:first + count, :].reshape(n, attr.width)
        first += count
    return out


def from_coded(values: dict[PatchAttribute, torch.Tensor], means: torch.Tensor,
               attributes: list[PatchAttribute]) -> GaussianParams:
    """Renderer parameters from coded attribute values (the decoder's mappings, in torch)."""
    n = means.shape[0]
    opacity = values[PatchAttribute.OPACITY].reshape(n).clamp(OPACITY_MIN, 1 - OPACITY_MIN)
    bands = [values[a].reshape(n, a.width // 3, 3) for a in attributes[4:]]
    sh = torch.cat([values[PatchAttribute.COLOR_DC].reshape(n, 1, 3)] + bands, dim=1)
    return GaussianParams(means, values[PatchAttribute.SCALE].reshape(n, 3),
                          values[PatchAttribute.ROTATION].reshape(n, 4),
                          torch.log(opacity / (1 - opacity)), sh)


def nearest_entry(groups: torch.Tensor, entries: torch.Tensor) -> torch.Tensor:
    """Index (int64) of the nearest row of ``entries`` (k, d) for each row of ``groups`` (m, d)."""
    if entries.shape[1] == 1:  # one dimension: a search among the sorted midpoints
        order = torch.argsort(entries[:, 0])
        cuts = entries[order, 0]
        return order[torch.bucketize(groups[:, 0].contiguous(), (cuts[1:] + cuts[:-1]) / 2)]
    dist = (entries * entries).sum(dim=1)[None, :] - 2.0 * groups @ entries.T
    return dist.argmin(dim=1)


@dataclass
class Snap:
    """The codebooks free Gaussians are snapped to: float16-valued entries per attribute."""

    entries: dict[PatchAttribute, torch.Tensor]
    """(k, entry_dim) float32 tensors holding float16 values."""

    @classmethod
    def from_codebooks(cls, codebooks: list[Codebook], device: torch.device) -> "Snap":
        return cls({cb.attribute: torch.tensor(cb.entries.astype(np.float32), device=device)
                    for cb in codebooks})

    def codebooks(self) -> list[Codebook]:
        return [Codebook(a, e.cpu().numpy().astype(np.float16)) for a, e in self.entries.items()]

    def indices(self, values: dict[PatchAttribute, torch.Tensor]) -> dict[PatchAttribute,
                                                                          torch.Tensor]:
        """(n, groups) nearest-entry indices of every attribute of ``values``."""
        out = {}
        with torch.no_grad():
            for attr, entries in self.entries.items():
                n, dim = values[attr].shape[0], entries.shape[1]
                out[attr] = nearest_entry(values[attr].detach().reshape(-1, dim),
                                          entries).reshape(n, -1)
        return out

    def apply(self, values: dict[PatchAttribute, torch.Tensor],
              picked: dict[PatchAttribute, torch.Tensor] | None = None
              ) -> dict[PatchAttribute, torch.Tensor]:
        """Every value replaced by its entry, the gradient passed straight through: the nearest
        one, or the one ``picked`` says (indices from :meth:`indices` a few steps ago)."""
        picked = self.indices(values) if picked is None else picked
        return {attr: straight_through(v, self.entries[attr][picked[attr]].reshape(v.shape))
                for attr, v in values.items()}

    def refresh(self, values: dict[PatchAttribute, torch.Tensor], weights: torch.Tensor,
                rounds: int = 2) -> None:
        """Lloyd rounds from the current entries: each entry moves to the weighted mean of the
        groups nearest to it (an entry nobody picks stays), rounded to float16 as stored."""
        with torch.no_grad():
            for attr, entries in self.entries.items():
                dim = entries.shape[1]
                groups = values[attr].detach().reshape(-1, dim)
                w = weights.repeat_interleave(groups.shape[0] // weights.shape[0])
                for _ in range(rounds):
                    picked = nearest_entry(groups, entries)
                    mass = torch.zeros(len(entries), device=groups.device).index_add_(0, picked, w)
                    sums = torch.zeros_like(entries).index_add_(0, picked, groups * w[:, None])
                    moved = torch.where(mass[:, None] > 0, sums / mass.clamp_min(1e-30)[:, None],
                                        entries)
                    entries = moved.to(torch.float16).to(torch.float32)
                self.entries[attr] = entries


Quantizer = Callable[[GaussianCloud],
                     "tuple[np.ndarray | None, list[Codebook] | None, np.ndarray]"]
"""What :class:`SnappedGaussians` asks for when snapping starts: given the Gaussians as trained so
far, the rows to keep (None: all; rate control drops some here, while steps remain to adapt),
the codebooks of the kept rows (None: do not snap, train on freely) and their k-means weights
(n_kept,)."""


class SnappedGaussians:
    """Free Gaussians trained through their codebooks from step ``start`` on.

    Before ``start`` this is plain :class:`FreeGaussians`. At ``start`` it asks ``quantize`` for
    codebooks (and, under rate control, which rows survive); from then on every forward pass
    renders each attribute at its nearest entry and each position on the stored grid (both with a
    straight-through gradient to the free values, which keep learning), and every
    ``refresh_every`` steps the entries move to the weighted centroids of the values nearest
    them. The snapped values are exactly what a decoder would reconstruct from these codebooks.
    """

    def __init__(self, survivors: GaussianCloud, device: torch.device, rates: LearningRates,
                 extent: float, start: int, refresh_every: int, quantize: Quantizer,
                 position_bits: int = 16, reassign_every: int = 10) -> None:
        self.survivors, self.device, self.rates, self.extent = survivors, device, rates, extent
        self.start, self.refresh_every, self.quantize = start, refresh_every, quantize
        self.reassign_every = reassign_every
        self.picked: dict[PatchAttribute, torch.Tensor] | None = None
        """Each group's entry as last assigned: the nearest search (as costly as a render step on
        a patch of 33k SH 3 Gaussians) runs every ``reassign_every`` steps, values move little in
        between."""
        self.position_bits = position_bits
        self.attributes = PatchAttribute.for_sh_degree(survivors.sh_degree)
        self.free = FreeGaussians(survivors, device, rates, extent)
        self.rows: np.ndarray | None = None
        """Rows of ``survivors`` still trained (None: all)."""
        self.decided = False
        """Whether step ``start`` has passed: rows kept and snapping chosen or declined."""
        self.snap: Snap | None = None
        self.weights: torch.Tensor | None = None
        self.grid: tuple[torch.Tensor, float] | None = None

    @property
    def optimizer(self) -> torch.optim.Optimizer:
        return self.free.optimizer

    @property
    def snapping(self) -> bool:
        return self.snap is not None

    # ---------------------------------------------------------------------------- Fittable
    def params(self) -> GaussianParams:
        free = self.free.params()
        if self.snap is None:
            return free
        coded = coded_tensors(free, self.attributes)
        if self.picked is None:
            self.picked = self.snap.indices(coded)
        values = self.snap.apply(coded, self.picked)
        origin, step = self.grid
        means = free.means
        if step:
            cells = torch.round((means - origin) / step)
            means = straight_through(means, origin + cells * step)
        return from_coded(values, means, self.attributes)

    def before_step(self, step: int, total: int) -> None:
        if step == self.start and not self.decided:
            self._begin_snapping()
        elif self.snap is not None and step > self.start:
            if (step - self.start) % self.refresh_every == 0:
                self.snap.refresh(coded_tensors(self.free.params(), self.attributes),
                                  self.weights)
                self.picked = None
            elif (step - self.start) % self.reassign_every == 0:
                self.picked = None
        self.free.before_step(step, total)

    def state_dict(self) -> dict:
        state = {"free": self.free.state_dict(), "decided": torch.tensor(self.decided)}
        if self.rows is not None:
            state["rows"] = torch.as_tensor(self.rows)
        if self.snap is not None:
            state["entries"] = {a.name: e.clone() for a, e in self.snap.entries.items()}
            state["weights"] = self.weights.clone()
            if self.picked is not None:  # a resumed run goes on with the same assignment
                state["picked"] = {a.name: i.to(torch.int32) for a, i in self.picked.items()}
            state["grid"] = torch.cat([self.grid[0], torch.tensor([self.grid[1]],
                                                                  device=self.device)])
        return state

    def load_state_dict(self, state: dict) -> None:
        self.decided = bool(state.get("decided", False))
        if "rows" in state:
            self._keep(state["rows"].numpy())
        if "entries" in state:
            self.snap = Snap({a: state["entries"][a.name].to(self.device)
                              for a in self.attributes})
            self.weights = state["weights"].to(self.device)
            self.picked = None if "picked" not in state else {
                a: state["picked"][a.name].to(self.device, torch.int64) for a in self.attributes}
            grid = state["grid"].to(self.device)
            self.grid = (grid[:3], float(grid[3]))
        self.free.load_state_dict(state["free"])

    # ------------------------------------------------------------------------------ results
    def to_cloud(self) -> GaussianCloud:
        """The free values as trained (positions unrounded: the writer applies its own grid)."""
        return self.free.to_cloud()

    def quantized(self) -> tuple[list[Codebook], dict[PatchAttribute, np.ndarray]]:
        """The codebooks trained with and every Gaussian's indices into them (uint8)."""
        values = coded_tensors(self.free.params(), self.attributes)
        indices = self.snap.indices(values)
        return self.snap.codebooks(), {a: i.cpu().numpy().astype(np.uint8)
                                       for a, i in indices.items()}

    def kept_rows(self) -> np.ndarray:
        return np.arange(len(self.survivors)) if self.rows is None else self.rows

    # ---------------------------------------------------------------------------- helpers
    def _begin_snapping(self) -> None:
        rows, codebooks, weights = self.quantize(self.free.to_cloud())
        self.decided = True
        if rows is not None:
            self._keep(rows, carry=True)
        if codebooks is None:
            return
        self.snap = Snap.from_codebooks(codebooks, self.device)
        self.weights = torch.as_tensor(np.asarray(weights, np.float32), device=self.device)
        with torch.no_grad():
            means = self.free.tensors["means"]
            origin = means.min(dim=0).values
            span = float((means.max(dim=0).values - origin).max()) if len(means) else 0.0
        step = span / ((1 << self.position_bits) - 1) if self.position_bits else 0.0
        self.grid = (origin, step)

    def _keep(self, rows: np.ndarray, carry: bool = False) -> None:
        """Train only ``rows`` of the survivors from now on: a new optimizer over their values
        (``carry``: the values as trained so far, else as they were; a checkpoint then loads)."""
        rows = np.asarray(rows, np.int64)
        current = self.free.to_cloud() if carry else None
        base = self.kept_rows()
        self.rows = base[rows] if carry else rows
        cloud = current.subset(rows) if carry else self.survivors.subset(self.rows)
        self.free = FreeGaussians(cloud, self.device, self.rates, self.extent)


__all__ = ["CodebookGaussians", "EntryRates", "LearningRates", "SnappedGaussians", "Snap",
           "coded_tensors", "from_coded", "nearest_entry", "with_positions"]
