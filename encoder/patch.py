"""Patch Gaussians without retraining: importance layers, codebooks (k-means) and uint8 indices.

Following Reduced-3DGS, as the paper does: every attribute except the position is replaced by an
index into a codebook of at most 256 float16 entries, trained with k-means; positions are not
codebook-quantized (that costs too much quality) but stored per Gaussian (QUANT16 by default: 16-bit
fixed point, delta-coded along a Morton curve, which beats the paper's float16 in both size and
precision). Gaussians are split into layers of decreasing importance so that a prefix of the file
shows the Gaussians that matter most.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from spcodec.attributes import PatchAttribute, canonical_rotation, encode_opacity
from spcodec.cloud import GaussianCloud
from spcodec.container import MAX_CODEBOOK_ENTRIES, Codec
from spcodec.decoder.layers import fill_patch_attributes
from spcodec.imaging.views import DEFAULT_UP, robust_bounds
from spcodec.index_contexts import IndexContext
from spcodec.sections import Codebook, PatchPositions, pack_positions
from spcodec.writer import PatchLayer

from . import codebook_fits
from .config import DEFAULT_POSITION_BITS, RETRAINED_POSITION_BITS, PatchConfig, codebook_entries
from .contexts import choose_index_contexts
from .draco import encode_as_set, encode_ordered, grid_for
from .ecvq import ecvq_refine, with_zero_entry
from .kmeans import exhaustive_codebook, nearest, sampled_codebook
from .morton import morton_codes
from .threads import default_jobs, map_tasks


def coded_attributes(cloud: GaussianCloud) -> dict[PatchAttribute, np.ndarray]:
    """Each patch attribute in its coded domain ([R-30]) as (N, width) float64."""
    out = {
        PatchAttribute.SCALE: cloud.scales.astype(np.float64),
        PatchAttribute.ROTATION: canonical_rotation(cloud.quats),
        PatchAttribute.OPACITY: encode_opacity(cloud.opacities)[:, None],
        PatchAttribute.COLOR_DC: cloud.sh_dc.astype(np.float64),
    }
    for attr in PatchAttribute.for_sh_degree(cloud.sh_degree)[4:]:
        # the width, not -1: a patch of no Gaussians (all sketch) has no size to infer it from
        rest = cloud.sh_rest[:, attr.sh_slice, :]
        out[attr] = rest.reshape(len(cloud), attr.width).astype(np.float64)
    return out


def footprint_importance(cloud: GaussianCloud) -> np.ndarray:
    """A visibility proxy: opacity times the area of the two largest axes' 1-sigma ellipse."""
    scales = np.sort(cloud.scales.astype(np.float64), axis=1)
    return encode_opacity(cloud.opacities) * np.exp(scales[:, 1] + scales[:, 2])


def split_layers(score: np.ndarray, fractions: tuple[float, ...], layers: int) -> list[np.ndarray]:
    """Indices of each layer: by decreasing score, sized by ``fractions`` (renormalized)."""
    order = np.argsort(-score, kind="stable")
    weights = np.asarray((list(fractions) + [fractions[-1]] * layers)[:layers], np.float64)
    bounds = np.round(np.cumsum(weights / weights.sum()) * len(score)).astype(np.int64)
    bounds[-1] = len(score)
    return [order[a:b] for a, b in zip(np.concatenate([[0], bounds[:-1]]), bounds)]


MAX_GRID_EXPONENT = 24
""":func:`input_grid` looks for grids of steps down to 2^-24 (SPZ stores positions on 2^-12)."""


def input_grid(xyz: np.ndarray, bits: int) -> np.ndarray | None:
    """The step per axis of a power-of-two grid that every position already lies on, when that
    grid is no finer than ``bits`` over the layer's box and has at most 65,536 levels per axis
    (QUANT16 then stores the positions exactly, in fewer levels than asked); None otherwise.

    Inputs decoded from SPZ sit on a grid of 2^-12 (fourth_st: about 1,200 levels per axis):
    coding them on a grid of their own box at 16 or 18 bits moves every one of them a little
    (fourth_st at 18 bits: 69.7 dB in the viewer for positions alone, docs/LOG.md 14.4)."""
    xyz = np.asarray(xyz, np.float64)
    if len(xyz) == 0 or not np.isfinite(xyz).all():
        return None
    span = xyz.max(axis=0) - xyz.min(axis=0)
    asked = max(float(span.max()), 1e-30) / ((1 << bits) - 1)

    def on_grid(values: np.ndarray, exponent: int) -> bool:
        scaled = values * 2.0 ** exponent
        return bool(np.array_equal(scaled, np.round(scaled)))

    steps = np.zeros(3)
    for axis in range(3):
        values = xyz[:, axis]
        if not on_grid(values, MAX_GRID_EXPONENT):  # trained positions: one pass, then out
            return None
        exponent = next(e for e in range(MAX_GRID_EXPONENT + 1) if on_grid(values, e))
        steps[axis] = 2.0 ** -exponent
    if np.any(span / steps > 0xFFFF) or np.any(steps < asked):
        return None
    return steps


def retrained_position_bits(cloud: GaussianCloud) -> int:
    """Bits of a retrained patch's positions: :data:`RETRAINED_POSITION_BITS` over the scene's
    robust extent (the box sampled views and close-ups frame, :func:`robust_bounds`), one more per
    doubling of the whole box beyond it, at most :data:`DEFAULT_POSITION_BITS`. Draco's grid spans
    a layer's whole box, so a few far outliers would otherwise coarsen the grid of everything
    else."""
    box = float(np.ptp(cloud.means.astype(np.float64), axis=0).max()) if len(cloud) else 0.0
    if not box > 0:
        return RETRAINED_POSITION_BITS
    bounds = robust_bounds(cloud)
    extra = max(0, int(round(np.log2(box / float((bounds.hi - bounds.lo).max())))))
    return min(DEFAULT_POSITION_BITS, RETRAINED_POSITION_BITS + extra)


@dataclass
class StoredPositions:
    """A layer's stored positions and the input rows in the order they are stored ([R-100])."""

    positions: PatchPositions
    order: np.ndarray


def _in_input_order(positions: PatchPositions, n: int) -> StoredPositions:
    return StoredPositions(positions, np.arange(n, dtype=np.int64))


def _draco_coding(xyz: np.ndarray, step: float, origin: np.ndarray, bits: int,
                  set_saving: float | None) -> StoredPositions | None:
    """Draco's coding of the grid: its kd-tree coding (the layer reordered as Draco decodes it,
    :func:`.draco.encode_as_set`) where that saves at least ``set_saving`` bits per point over
    the sequential coding (None: never), whose blobs decode faster; else the sequential coding.
    None when Draco does not keep the points."""
    encoded = encode_ordered(xyz, step, origin, bits)
    if encoded is None:
        return None
    unordered = None if set_saving is None else encode_as_set(xyz, encoded, step, origin, bits)
    if unordered is not None and \
            8 * (len(encoded.blob) - len(unordered.blob)) >= set_saving * len(xyz):
        return StoredPositions(PatchPositions.draco(unordered.blob, unordered.positions),
                               unordered.order)
    return _in_input_order(PatchPositions.draco(encoded.blob, encoded.positions), len(xyz))


def on_input_grid(xyz: np.ndarray, steps: np.ndarray, mode: str, set_saving: float | None = 0.0
                  ) -> StoredPositions:
    """Positions that lie on the power-of-two grid of ``steps`` (:func:`input_grid`), stored on it.

    QUANT16 (delta-coded along the Morton order, then the section's codec) decodes them bit for
    bit. In draco mode, Draco's coding of the same grid (:func:`_draco_coding`) is tried too and
    the smaller stored section kept: on fourth_st sequential Draco takes 232 kB where QUANT16
    takes 311 kB, and decodes at most 4.4e-7 off (Draco dequantizes in binary32: under a
    hundredth of the grid's step, yet 0.2-0.45 dB in the viewer at fourth_st's transparent point,
    where co-located Gaussians of different layers then sort differently, docs/LOG.md 21.1)."""
    xyz64 = np.asarray(xyz, np.float64)
    exact = _in_input_order(PatchPositions.quant16(xyz, steps, xyz64.min(axis=0)), len(xyz))
    if mode != "draco" or not np.all(steps == steps[0]):
        return exact
    origin, bits = grid_for(xyz64, float(steps[0]))
    draco = _draco_coding(xyz, float(steps[0]), origin, bits, set_saving)
    # Draco's binary32 grid must stay well inside the input's cells
    if draco is None or np.abs(draco.positions.decode() - xyz64[draco.order]).max() > steps[0] / 16:
        return exact
    stored = [len(zlib.compress(pack_positions(c.positions))) for c in (draco, exact)]
    return draco if stored[0] < stored[1] else exact


def encode_positions(xyz: np.ndarray, mode: str, bits: int = DEFAULT_POSITION_BITS,
                     set_saving: float | None = 0.0) -> StoredPositions:
    """Positions of one layer in the configured mode, and the order they are stored in.

    In draco mode Draco's sequential coding (input order) is kept, or its kd-tree coding (Draco's
    order) where that saves at least ``set_saving`` bits per point (None: never); draco falls back
    to quant16 if Draco does not keep the points, which the encoder checks by decoding. In draco
    and quant16 modes, positions already on a coarser grid than ``bits`` asks for are stored on it
    (:func:`input_grid`, :func:`on_input_grid`)."""
    n = len(xyz)
    if mode in ("draco", "quant16") and n:
        grid = input_grid(xyz, bits)
        if grid is not None:
            return on_input_grid(xyz, grid, mode, set_saving)
    if mode == "draco":
        xyz = np.asarray(xyz, np.float64)
        if n == 0:
            return _in_input_order(PatchPositions.draco(b"", np.zeros((0, 3), np.float32)), 0)
        origin, _ = grid_for(xyz, 1.0)
        span = float((xyz.max(axis=0) - origin).max())
        step = max(span, 1e-30) / ((1 << bits) - 1)
        draco = _draco_coding(xyz, step, origin, bits, set_saving)
        if draco is not None:
            return draco
        mode, bits = "quant16", min(bits, 16)
    if mode == "float16":
        return _in_input_order(PatchPositions.float16(xyz), n)
    if mode == "float32":
        return _in_input_order(PatchPositions.float32(xyz), n)
    if mode != "quant16":
        raise ValueError(f"unknown position mode {mode!r}")
    if not 1 <= bits <= 16:
        raise ValueError("position_bits must be in 1..16")
    xyz = np.asarray(xyz, np.float64)
    if n == 0:
        return _in_input_order(PatchPositions.quant16(xyz, 1.0, np.zeros(3)), 0)
    lo = xyz.min(axis=0).astype(np.float32)
    span = xyz.max(axis=0) - lo.astype(np.float64)
    levels = (1 << bits) - 1
    # The step is rounded to float32 upward so every position stays within the 16-bit range.
    step = np.maximum(np.nextafter((span / levels).astype(np.float32), np.float32(np.inf)),
                      np.float32(1e-30))
    return _in_input_order(PatchPositions.quant16(xyz, step, lo), n)


def train_codebook(values: np.ndarray, entry_dim: int, size: int, weights: np.ndarray | None,
                   config: PatchConfig, seed: int) -> np.ndarray:
    """At most ``size`` float16 entries for the attribute's entry_dim-wide groups (k-means)."""
    n, width = values.shape
    groups = values.reshape(n * (width // entry_dim), entry_dim)
    w = None if weights is None else np.repeat(weights, width // entry_dim)
    if config.kmeans == "exhaustive":
        return exhaustive_codebook(groups, w, size, seed, config.kmeans_samples,
                                   config.kmeans_iterations)
    if config.kmeans != "sampled":
        raise ValueError(f"unknown k-means trainer {config.kmeans!r}: use sampled or exhaustive")
    return sampled_codebook(groups, w, size, seed, samples=config.kmeans_samples,
                            iterations=config.kmeans_iterations)


def assign(values: np.ndarray, entries: np.ndarray) -> np.ndarray:
    """Index (n, groups) uint8 of the nearest float16 entry for each group."""
    n, width = values.shape
    dim = entries.shape[1]
    return nearest(values.reshape(n * (width // dim), dim), entries).reshape(n, width // dim)


ROTATION_SCALES = np.geomspace(0.55, 1.0, 64)
"""Multiples of a unit quaternion that scalar rotation codebooks try (:func:`assign_rotation`);
1.0 is among them, so no Gaussian ends farther from its rotation than with plain nearest
entries. 256 multiples over the same range cut the rms angle error by at most 5 % more (guitar;
0.2 % on fourth_st) for four times the work."""


def assign_rotation(values: np.ndarray, entries: np.ndarray) -> np.ndarray:
    """Indices (n, 4) uint8 of unit quaternions ``values`` into a scalar (D = 1) codebook.

    A decoder divides the coded quaternion by its norm ([R-31]), so every positive multiple of a
    quaternion codes the same rotation; the four components are each rounded to the nearest
    entry at every multiple in :data:`ROTATION_SCALES`, and each Gaussian keeps the multiple
    whose rounded quaternion points closest to its own (the first, on a tie). The search is a
    finer grid of directions for free: the rms angle error falls 1.7x on fourth_st and 2.6x on
    guitar against rounding the unit quaternion itself (docs/LOG.md 14.4).

    From one multiple to the next most components round to the same entry, and a Gaussian whose
    four did not change cannot point closer than it already did: only the components whose value
    crossed a midpoint are rounded again (:class:`_Rounding`), and only their Gaussians judged.
    The arithmetic of each judgement is the plain search's, so the indices are the same."""
    q = np.asarray(values, np.float64)
    flat = entries.astype(np.float64)[:, 0]
    order = np.argsort(flat, kind="stable")
    sorted_entries = flat[order]
    rounding = _Rounding(sorted_entries, (q * ROTATION_SCALES[0]).reshape(-1))
    best = np.full(len(q), -1.0)
    out = np.zeros(q.shape, np.uint8)
    rows = np.arange(len(q))
    changed = np.zeros(len(q), bool)
    for k, scale in enumerate(ROTATION_SCALES):
        if k:  # the Gaussians with a component rounded to another entry than at the last scale
            changed[:] = False
            changed[rounding.move_to((q * scale).reshape(-1)) // q.shape[1]] = True
            rows = np.flatnonzero(changed)
        idx = rounding.idx.reshape(q.shape)[rows]
        coded = sorted_entries[idx]
        norm = np.linalg.norm(coded, axis=1)
        cosine = np.abs((coded * q[rows]).sum(axis=1)) / np.where(norm > 0, norm, np.inf)
        better = cosine > best[rows]
        best[rows[better]] = cosine[better]
        out[rows[better]] = order[idx[better]]
    return out


class _Rounding:
    """Each of a flat array of values rounded to the nearest entry of a sorted scalar codebook,
    kept while the values move: the index is the count of midpoints below the value, as
    ``np.searchsorted`` (left) gives it. The midpoints either side of each value's entry are
    kept with it, so a move costs two comparisons per value, and a walk over the midpoints
    crossed only for the values that crossed one."""

    def __init__(self, sorted_entries: np.ndarray, values: np.ndarray) -> None:
        midpoints = (sorted_entries[1:] + sorted_entries[:-1]) / 2.0
        self.above = np.append(midpoints, np.inf)  # above[i]: the midpoint over entry i
        self.below = np.insert(midpoints, 0, -np.inf)  # below[i]: the midpoint under entry i
        self.idx = np.searchsorted(midpoints, values)
        self.upper, self.lower = self.above[self.idx], self.below[self.idx]

    def move_to(self, values: np.ndarray) -> np.ndarray:
        """Round ``values`` (as many as before); returns the positions whose entry changed.
        NaN compares false both ways, so it stays where searchsorted put it, as it would."""
        moved = np.flatnonzero((self.upper < values) | (self.lower >= values))
        v, idx = values[moved], self.idx[moved]
        while True:
            up, down = self.above[idx] < v, self.below[idx] >= v
            if not (up.any() or down.any()):
                break
            idx += up.astype(idx.dtype) - down
        self.idx[moved] = idx
        self.upper[moved], self.lower[moved] = self.above[idx], self.below[idx]
        return moved


def assign_attribute(attribute: PatchAttribute, values: np.ndarray,
                     entries: np.ndarray) -> np.ndarray:
    """Indices of ``values`` (an attribute's coded values) into ``entries``: the nearest entry
    per group, except for scalar rotation codebooks (:func:`assign_rotation`)."""
    if attribute is PatchAttribute.ROTATION and entries.shape[1] == 1:
        return assign_rotation(values, entries)
    return assign(values, entries)


def final_codebook(attr: PatchAttribute, values: np.ndarray, entries: np.ndarray,
                   weights: np.ndarray | None, bit_cost: float = 0.0, iterations: int = 3,
                   zero_entry: bool = False) -> tuple[Codebook, np.ndarray]:
    """The codebook of trained ``entries`` and the indices of ``values`` (an attribute's coded
    values): with an exact zero entry for an SH band when ``zero_entry``; nearest entries
    (:func:`assign_attribute`) when ``bit_cost`` is 0, else ECVQ's (:mod:`.ecvq`), which also
    moves the entries. Scalar rotation codebooks keep their own search: ECVQ's error is not the
    angle a decoder sees after normalizing."""
    keep = None
    if zero_entry and attr >= PatchAttribute.SH_BAND_1 and len(values):
        entries, keep = with_zero_entry(entries)
    scalar_rotation = attr is PatchAttribute.ROTATION and entries.shape[1] == 1
    if bit_cost <= 0 or len(values) == 0 or scalar_rotation:
        return Codebook(attr, entries), assign_attribute(attr, values, entries)
    n, width = values.shape
    dim = entries.shape[1]
    groups = values.reshape(n * (width // dim), dim)
    w = None if weights is None else np.repeat(np.asarray(weights, np.float64), width // dim)
    entries, idx = ecvq_refine(groups, entries, w, bit_cost, iterations, keep)
    return Codebook(attr, entries), idx.reshape(n, width // dim)


@dataclass
class Quantized:
    """A patch cloud's attributes as codebooks and indices, before it is split into layers.

    ``indices[attr]`` is uint8 (n, groups): row ``i`` holds Gaussian ``i``'s entry for each of the
    attribute's ``entry_dim``-wide groups, in the order of the cloud that was quantized.
    """

    codebooks: list[Codebook]
    indices: dict[PatchAttribute, np.ndarray]

    def __len__(self) -> int:
        return len(next(iter(self.indices.values()))) if self.indices else 0

    def subset(self, rows: np.ndarray) -> "Quantized":
        """The same codebooks with the indices of ``rows`` only (in that order)."""
        return Quantized(self.codebooks, {a: idx[rows] for a, idx in self.indices.items()})


def dequantize(quantized: Quantized) -> dict[PatchAttribute, np.ndarray]:
    """The attribute values the indices select, (n, width) float32, in the coded domain of
    :mod:`spcodec.attributes` (the domain of :func:`coded_attributes`): the values a decoder looks
    up before its per-attribute mappings (rotation normalization, opacity logit)."""
    out = {}
    for cb in quantized.codebooks:
        idx = quantized.indices[cb.attribute]
        out[cb.attribute] = cb.entries.astype(np.float32)[idx].reshape(len(idx), cb.attribute.width)
    return out


def quantized_cloud(quantized: Quantized, means: np.ndarray, sh_degree: int) -> GaussianCloud:
    """The cloud a decoder reconstructs from ``quantized``, at ``means`` taken as they are (the
    decoder's own lookups and mappings, so it equals the decoded patch Gaussians but for the
    position coding)."""
    cloud = GaussianCloud.zeros(len(means), sh_degree)
    cloud.means[:] = means
    fill_patch_attributes({a: idx.T for a, idx in quantized.indices.items()}, quantized.codebooks,
                          cloud)
    return cloud


@dataclass
class PatchEncoding:
    """Result of :meth:`PatchEncoder.layer` and :meth:`PatchEncoder.encode`."""

    codebooks: list[Codebook]
    layers: list[PatchLayer]
    order: list[np.ndarray]
    """For each layer, the indices (into the input cloud) of its Gaussians in stored order."""
    index_contexts: bool = False
    """Whether the file may code index columns given earlier ones (``PatchConfig.index_contexts``:
    the writer of the file chooses them, knowing its codec)."""
    jobs: int | None = None
    """Threads that choose the contexts (None: the cores available), as the encoder's."""
    _chosen: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    def contexts_for(self, codec: Codec, level: int | None) -> list[IndexContext]:
        """The context records for a file of this encoding written with ``codec`` at ``level``
        (empty when contexts are off or none pays), chosen once per codec and level: a file is
        written several times (trial sizes, the final file) from one encoding."""
        if not self.index_contexts:
            return []
        key = (int(codec), level)
        if key not in self._chosen:
            layers = self.layers if sum(map(len, self.layers)) else []
            self._chosen[key] = choose_index_contexts(self.codebooks, layers, codec, level,
                                                      jobs=self.jobs)
        return self._chosen[key]


class PatchEncoder:
    """Codebooks + indices + positions for patch Gaussians, in importance layers.

    The steps are separately callable so that a retraining loop can run them in its own order
    (for example: quantize, fine-tune the codebook entries with the indices fixed, re-assign,
    fine-tune again, then layer)::

        enc = PatchEncoder(config, seed)
        q = enc.quantize(cloud)                   # codebooks (k-means) and indices
        q.indices = enc.assign(cloud, q.codebooks)  # indices against given codebooks
        out = enc.layer(cloud, q, importance)     # layers, positions coded (in their order)
        out = enc.encode(cloud)                   # all of the above, importance measured
    """

    def __init__(self, config: PatchConfig | None = None, seed: int = 0,
                 jobs: int | None = None) -> None:
        self.config = config or PatchConfig()
        self.seed = seed
        #: Threads for codebook training, assignment and importance (None: the cores available).
        self.jobs = jobs

    def entry_dim(self, attr: PatchAttribute) -> int:
        """The configured entry dimension of ``attr``, checked against its width."""
        dim = self.config.entry_dims.get(attr.name, attr.width)
        if dim < 1 or attr.width % dim:
            raise ValueError(f"entry dimension {dim} does not divide {attr.name}'s width")
        return dim

    def quantize(self, cloud: GaussianCloud, weights: np.ndarray | None = None) -> Quantized:
        """Train one codebook per attribute (k-means, seeded) and assign every Gaussian to it.

        ``weights`` (n,) weight each Gaussian's samples in k-means, so entries go where they are
        seen (None: unweighted). Deterministic for a given seed, config and input.
        """
        cfg = self.config
        if cfg.codebook_size > MAX_CODEBOOK_ENTRIES or cfg.codebook_size < 1:
            raise ValueError(f"codebook_size must be in 1..{MAX_CODEBOOK_ENTRIES}")
        if cfg.groups_per_entry is not None and not cfg.groups_per_entry > 0:
            raise ValueError("groups_per_entry must be > 0 or None")
        if weights is not None and np.shape(weights) != (len(cloud),):
            raise ValueError(f"weights must have shape ({len(cloud)},), got {np.shape(weights)}")
        values = coded_attributes(cloud)
        seeds = {attr: self.seed + 7919 * i for i, attr in enumerate(values)}
        weights_digest = codebook_fits.digest(None if weights is None else np.asarray(weights))

        def train(attr: PatchAttribute) -> tuple[Codebook, np.ndarray]:
            dim = self.entry_dim(attr)
            if len(cloud) == 0:
                return self._entries_and_indices(attr, values[attr], np.zeros((1, dim), np.float16),
                                                 weights)
            size = codebook_entries(cfg, len(cloud), attr.width // dim)
            if cfg.entry_counts and attr.name in cfg.entry_counts:
                size = max(1, min(size, cfg.entry_counts[attr.name]))
            # everything the fit reads: a size target's trials and its final file repeat fits
            key = (int(attr), dim, size, seeds[attr], cfg.kmeans, cfg.kmeans_samples,
                   cfg.kmeans_iterations, self.bit_cost(attr), cfg.ecvq_iterations,
                   cfg.sh_zero_entry, codebook_fits.digest(values[attr]), weights_digest)
            return codebook_fits.RECENT(key, lambda: self._entries_and_indices(
                attr, values[attr], train_codebook(values[attr], dim, size, weights, cfg, seeds[attr]),
                weights))

        done = dict(zip(values, self._map(train, list(values))))
        return Quantized([done[a][0] for a in values], {a: done[a][1] for a in values})

    def bit_cost(self, attr: PatchAttribute) -> float:
        """ECVQ's weighted error per index bit for ``attr`` (0: nearest entries)."""
        cfg = self.config
        if not cfg.ecvq or not cfg.ecvq_bit_costs:
            return 0.0
        return float(cfg.ecvq_bit_costs.get(attr.name, 0.0))

    def _entries_and_indices(self, attr: PatchAttribute, values: np.ndarray, entries: np.ndarray,
                             weights: np.ndarray | None) -> tuple[Codebook, np.ndarray]:
        cfg = self.config
        return final_codebook(attr, values, entries, weights, self.bit_cost(attr),
                              cfg.ecvq_iterations, cfg.sh_zero_entry)

    def assign(self, cloud: GaussianCloud, codebooks: list[Codebook]
               ) -> dict[PatchAttribute, np.ndarray]:
        """Indices (uint8, (n, groups) per attribute) of the nearest entry of ``codebooks`` for
        every group of every Gaussian of ``cloud``; the codebooks must cover the cloud's SH
        degree exactly."""
        expected = PatchAttribute.for_sh_degree(cloud.sh_degree)
        if [cb.attribute for cb in codebooks] != expected:
            raise ValueError(f"codebooks for {[cb.attribute.name for cb in codebooks]}, the cloud "
                             f"needs {[a.name for a in expected]}")
        values = coded_attributes(cloud)
        indices = self._map(lambda cb: assign_attribute(cb.attribute, values[cb.attribute],
                                                        cb.entries), codebooks)
        return {cb.attribute: idx for cb, idx in zip(codebooks, indices)}

    def _map(self, fn, attributes: list) -> list:
        """``fn`` over per-attribute tasks on :attr:`jobs` threads, widest attributes first, each
        on one BLAS/OpenMP thread (:func:`.threads.map_tasks`): whole attributes keep two cores
        busy, where the libraries' own fine-grained threads stalled whenever another process ran
        (fourth_st's codebooks: 5.2-6.4 s on one thread, 7.4-9.6 s on two). Results do not
        depend on the number of threads."""
        def width(item) -> int:
            return (item.attribute if isinstance(item, Codebook) else item).width

        return map_tasks(fn, attributes, self.jobs, cost=width)

    def layer(self, cloud: GaussianCloud, quantized: Quantized, importance: np.ndarray
              ) -> PatchEncoding:
        """Split ``cloud`` (with its ``quantized`` attributes) into layers of decreasing
        ``importance`` (n,), sized by the config; positions coded (:meth:`layer_groups`)."""
        cfg = self.config
        if np.shape(importance) != (len(cloud),) or len(quantized) != len(cloud):
            raise ValueError("cloud, quantized and importance must describe the same Gaussians")
        return self.layer_groups(cloud, quantized,
                                 split_layers(importance, cfg.layer_fractions, cfg.layers))

    def layer_groups(self, cloud: GaussianCloud, quantized: Quantized,
                     groups: list[np.ndarray]) -> PatchEncoding:
        """The encoding whose layers hold ``groups`` (indices into ``cloud``, first layer first);
        Morton order within a layer (or the order Draco's kd-tree coding decodes), positions
        coded."""
        cfg = self.config
        layers, orders = [], []
        for members in groups:
            if len(members):
                members = members[np.argsort(morton_codes(cloud.means[members].astype(np.float64)),
                                             kind="stable")]
            stored = encode_positions(cloud.means[members], cfg.position_mode,
                                      cfg.stored_position_bits, cfg.set_coding_saving)
            members = members[stored.order]
            layers.append(PatchLayer(stored.positions, quantized.subset(members).indices))
            orders.append(members)
        return PatchEncoding(quantized.codebooks, layers, orders, cfg.index_contexts, self.jobs)

    def measure_importance(self, cloud: GaussianCloud,
                           up: Sequence[float] | str = DEFAULT_UP) -> np.ndarray:
        """Importance (n,) float64 of every Gaussian of ``cloud`` by the configured measure.

        Pass the whole scene when the patch is part of one (sketch Gaussians occlude patch
        Gaussians) and take the patch's rows. ``up``: the scene's up axis (the encode's
        ``--up``), which places the views' orbit as a viewer's.
        """
        cfg = self.config
        if cfg.importance == "footprint" or len(cloud) == 0:
            return footprint_importance(cloud)
        if cfg.importance != "blend":
            raise ValueError(f"unknown importance {cfg.importance!r}: use blend or footprint")
        from spcodec.imaging.importance import training_view_weights

        return training_view_weights(cloud, cfg.importance_views, cfg.importance_resolution,
                                     seed=self.seed, up=up, jobs=self.jobs or default_jobs())

    def kmeans_weights(self, importance: np.ndarray) -> np.ndarray | None:
        """k-means weights from importance: mean 1 plus the configured floor (None: unweighted)."""
        importance = np.asarray(importance, np.float64)
        mean = importance.mean() if len(importance) else 0.0
        if not self.config.weighted_kmeans or not mean > 0:
            return None
        return importance / mean + self.config.kmeans_weight_floor

    def encode(self, cloud: GaussianCloud, importance: np.ndarray | None = None) -> PatchEncoding:
        """:meth:`quantize` then :meth:`layer`. ``importance`` (n,) orders the layers and weights
        k-means (None: :meth:`measure_importance` of ``cloud``)."""
        if importance is None:
            importance = self.measure_importance(cloud)
        importance = np.asarray(importance, np.float64)
        return self.layer(cloud, self.quantize(cloud, self.kmeans_weights(importance)), importance)
