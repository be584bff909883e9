"""Precision by rate and distortion: which codebook each patch attribute gets (issue 37).

Every patch attribute (scale, rotation, opacity, colour DC, each SH band) can be coded from
whole-vector codebooks down to one index per component, with up to 256 entries. Each such
*option* has a rate (the order-0 entropy of its index columns, within 1 % of the per-column
Huffman code the writer uses, plus the codebook's float16 entries) and a distortion: the image
MSE it adds, predicted by the linearized renderer (:mod:`spcodec.imaging.sensitivity`) at
eval's two framings, the sampled views and half their distance. Both are measured on a uniform
sample of the patch and scaled to all of it.

Distortions of different attributes add (their errors are independent), so one Lagrange
multiplier ``lam`` chooses every attribute's option at once: the one minimizing
``distortion + lam * bytes``. Sweeping ``lam`` traces the scene's rate-distortion curve, and a
size target is the point of it whose predicted bytes fit (:meth:`PrecisionSearch.for_bytes`).

Positions are options too (:func:`position_options`): each grid (bits over a layer's box) costs
the bytes its real Draco write takes, and its distortion is rendered, not predicted: moving a
Gaussian across its footprint's cut-off is a step the linearized renderer cannot see (it
underestimates position error 2-20x, docs/LOG.md 17.1).
"""

from __future__ import annotations

import dataclasses
import zlib
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from spcodec.attributes import PatchAttribute
from spcodec.cloud import GaussianCloud
from spcodec.decoder.layers import fill_patch_attributes
from spcodec.imaging.sensitivity import Sensitivity
from spcodec.sections import Codebook, pack_positions

from .codebook_fits import digest
from .config import AllocationConfig, EncoderConfig, PatchConfig
from .kmeans import codebook_ladder
from .morton import morton_codes
from .patch import coded_attributes, encode_positions, final_codebook, input_grid, train_codebook
from .recent import Recent
from .threads import map_tasks

LADDERS: dict[str, tuple[int, ...]] = {
    "SCALE": (3, 1), "ROTATION": (4, 2, 1), "OPACITY": (1,), "COLOR_DC": (3, 1),
    "SH_BAND_1": (9, 3, 1), "SH_BAND_2": (15, 3, 1), "SH_BAND_3": (21, 3, 1)}
"""Entry dimensions an attribute may take, coarsest first: the whole vector, one index per
colour triplet or quaternion pair, one per component."""


@dataclass(frozen=True)
class Option:
    """One way to code one attribute, measured."""

    attribute: str
    entry_dim: int
    entries: int
    index_bits: float
    """Bits per Gaussian of its index columns (order-0 entropy)."""
    codebook_bytes: int
    distortion: float
    """Predicted image MSE the option adds over the whole patch (both framings, weighted)."""
    bit_cost: float = 0.0
    """ECVQ's cost per index bit (:mod:`.ecvq`, in the k-means objective's units); 0: nearest
    entries."""
    zero_entry: bool = False
    """Whether the codebook holds the exact zero entry of an SH band (``sh_zero_entry``)."""

    def bytes_for(self, count: int) -> float:
        return count * self.index_bits / 8 + self.codebook_bytes

    @property
    def key(self) -> tuple:
        return (self.attribute, self.entry_dim, self.entries, self.bit_cost)

    def describe(self) -> dict:
        out = {"entry_dim": self.entry_dim, "entries": self.entries}
        return {**out, "ecvq_bit_cost": self.bit_cost} if self.bit_cost > 0 else out


@dataclass(frozen=True)
class PositionOption:
    """One grid for the patch's positions, measured on a real write and real renders."""

    bits: int
    bits_per_gaussian: float
    """Stored bits per Gaussian of the positions' section (Draco, then zlib), all three axes."""
    distortion: float
    """Rendered image MSE the grid adds (both framings, weighted), in the units of
    :class:`Option`'s."""
    attribute: str = "POSITION"

    def bytes_for(self, count: int) -> float:
        return count * self.bits_per_gaussian / 8

    @property
    def key(self) -> tuple:
        return (self.attribute, self.bits)

    def describe(self) -> dict:
        return {"bits": self.bits}


@dataclass(frozen=True)
class Allocation:
    """One option per attribute, and what they cost together for ``count`` Gaussians."""

    options: dict[str, Option | PositionOption]
    count: int

    @property
    def bytes(self) -> float:
        return sum(o.bytes_for(self.count) for o in self.options.values())

    @property
    def distortion(self) -> float:
        return sum(o.distortion for o in self.options.values())

    def patch_config(self, base: PatchConfig) -> PatchConfig:
        """``base`` with these entry dimensions and, per attribute, these entry counts (and,
        when positions were searched too, this grid)."""
        codebooks = {a: o for a, o in self.options.items() if isinstance(o, Option)}
        grid = self.options.get("POSITION")
        return dataclasses.replace(
            base, entry_dims={a: o.entry_dim for a, o in codebooks.items()},
            entry_counts={a: o.entries for a, o in codebooks.items()},
            position_bits=base.position_bits if grid is None else grid.bits,
            **self._ecvq(base))

    def _ecvq(self, base: PatchConfig) -> dict:
        """The ECVQ fields of the patch config: the chosen options' costs per bit, when any
        chose ECVQ (else ``base``'s own)."""
        codebooks = [(a, o) for a, o in self.options.items() if isinstance(o, Option)]
        costs = {a: o.bit_cost for a, o in codebooks if o.bit_cost > 0}
        zero = base.sh_zero_entry or any(o.zero_entry for _, o in codebooks)
        return {"ecvq": True, "ecvq_bit_costs": costs, "sh_zero_entry": zero} if costs else \
            {"sh_zero_entry": zero}

    def describe(self) -> dict:
        return {a: o.describe() for a, o in self.options.items()}


@dataclass
class PrecisionSearch:
    """Every option of every attribute of a patch, measured once; allocations chosen from them."""

    options: dict[str, list[Option | PositionOption]]
    count: int
    config: AllocationConfig = field(default_factory=AllocationConfig)

    @classmethod
    def measure(cls, patch: GaussianCloud, sensitivity: dict[str, Sensitivity],
                weights: np.ndarray | None, base: PatchConfig, seed: int,
                config: AllocationConfig | None = None, jobs: int | None = None
                ) -> "PrecisionSearch":
        """Measure every option on a sample of ``patch``. ``sensitivity`` maps each framing
        ("orbit", "close") to the patch's :class:`Sensitivity`; ``weights`` weight k-means as the
        patch encoder does. Attributes are measured on ``jobs`` threads
        (:func:`.threads.map_tasks`); the options do not depend on how many."""
        config = config or AllocationConfig()
        n = len(patch)
        rng = np.random.default_rng([seed, 0xA110C])
        rows = np.sort(rng.choice(n, min(n, config.sample), replace=False)) if n else \
            np.zeros(0, np.int64)
        sample = patch.subset(rows)
        scale = n / max(len(rows), 1)
        framing = {name: s.subset(rows) for name, s in sensitivity.items()}
        weight = config.linearized_weights()
        sample_weights = None if weights is None else np.asarray(weights)[rows]
        if config.ecvq_strengths:  # ECVQ can then drop an SH band per Gaussian
            base = dataclasses.replace(base, sh_zero_entry=True)
        whole = coded_attributes(patch) if len(rows) < n else None
        coded = list(enumerate(coded_attributes(sample).items()))

        def attribute_options(task: tuple[int, tuple[PatchAttribute, np.ndarray]]
                              ) -> list[Option]:
            index, (attr, values) = task
            out: list[Option] = []
            for dim in LADDERS[attr.name]:
                sizes = entry_choices(values, None if whole is None else whole[attr], dim,
                                      config.entry_counts)
                books = _codebooks(values, dim, sizes, sample_weights, base, seed + 7919 * index)
                exact = sizes[0] if sizes[0] < max(config.entry_counts) else 0
                for entries in sizes:
                    asked = entries if entries == exact else len(books[entries])
                    out += _measure_options(sample, attr, values, books[entries], asked,
                                            sample_weights, base, framing, weight, scale,
                                            config.ecvq_strengths)
            return out

        measured = map_tasks(attribute_options, coded, jobs, cost=lambda t: t[1][0].width)
        options = {attr.name: opts for (_, (attr, _)), opts in zip(coded, measured)}
        return cls(options, n, config)

    def rescaled(self, count: int) -> "PrecisionSearch":
        """This search for a patch of ``count`` Gaussians of the same scene: every option's
        bits per Gaussian as measured, its distortion (a sum over the patch's Gaussians) in
        proportion to the count. What a size target re-encoding without its sketch asks: the
        sketch's Gaussians join the patch, and measuring every option again on nearly the same
        patch would double the search for a choice the real trial writes correct anyway."""
        factor = count / max(self.count, 1)
        options = {name: [dataclasses.replace(o, distortion=o.distortion * factor) for o in opts]
                   for name, opts in self.options.items()}
        return dataclasses.replace(self, options=options, count=count)

    def with_positions(self, options: list[PositionOption]) -> "PrecisionSearch":
        """This search with the grids of :func:`position_options` among its choices."""
        return dataclasses.replace(self, options={**self.options, "POSITION": list(options)})

    def matching(self, entry_dims: dict[str, int], position_bits: int | None = None
                 ) -> Allocation:
        """The allocation of whole codebooks (the most entries) at ``entry_dims`` and the grid
        of ``position_bits`` (the finest measured when not among them): a preset's precision,
        measured like every other option."""
        chosen = {}
        for name, opts in self.options.items():
            if name == "POSITION":
                same = [o for o in opts if o.bits == position_bits]
                chosen[name] = same[0] if same else max(opts, key=lambda o: o.bits)
                continue
            dim = entry_dims.get(name, max(o.entry_dim for o in opts))
            nearest = [o for o in opts if o.bit_cost == 0]
            same = [o for o in nearest if o.entry_dim == dim] or nearest
            chosen[name] = max(same, key=lambda o: o.entries)
        return Allocation(chosen, self.count)

    def at(self, lam: float, count: int | None = None) -> Allocation:
        """The allocation minimizing distortion + ``lam`` * bytes for ``count`` Gaussians."""
        count = self.count if count is None else count
        return Allocation({a: min(opts, key=lambda o: o.distortion + lam * o.bytes_for(count))
                           for a, opts in self.options.items()}, count)

    def curve(self, count: int | None = None) -> list[Allocation]:
        """Every allocation some ``lam`` chooses, smallest first (the lower convex hull)."""
        lams = np.concatenate([[0.0], np.geomspace(1e-14, 1e2, 400), [np.inf]])
        seen, out = set(), []
        for lam in lams:
            allocation = self.at(float(lam) if np.isfinite(lam) else 1e30, count)
            key = tuple(sorted(o.key for o in allocation.options.values()))
            if key not in seen:
                seen.add(key)
                out.append(allocation)
        return sorted(out, key=lambda a: a.bytes)

    def slope_at(self, allocation: Allocation) -> float:
        """Distortion saved per byte by the next larger allocation on the curve (0 at its top):
        what a byte spent elsewhere costs at ``allocation``."""
        larger = [a for a in self.curve(allocation.count) if a.bytes > allocation.bytes]
        if not larger:
            return 0.0
        step = min(larger, key=lambda a: a.bytes)
        return max(allocation.distortion - step.distortion, 0.0) / (step.bytes - allocation.bytes)

    def for_bytes(self, budget: float, count: int | None = None) -> Allocation | None:
        """The least-distortion allocation whose attribute bytes fit ``budget`` (None when even
        the smallest does not): the best point of the curve under it, then single-attribute
        upgrades, best distortion saved per byte first, while they fit (the curve's points
        can lie several percent apart; the upgrades fill the gap)."""
        fitting = [a for a in self.curve(count) if a.bytes <= budget]
        if not fitting:
            return None
        best = min(fitting, key=lambda a: a.distortion)
        while True:
            upgrades = []
            for name, options in self.options.items():
                current = best.options[name]
                for option in options:
                    extra = option.bytes_for(best.count) - current.bytes_for(best.count)
                    saved = current.distortion - option.distortion
                    if extra > 0 and saved > 0 and best.bytes + extra <= budget:
                        upgrades.append((saved / extra, name, option))
            if not upgrades:
                return best
            _, name, option = max(upgrades, key=lambda u: u[0])
            best = Allocation({**best.options, name: option}, best.count)


def _codebooks(coded: np.ndarray, dim: int, sizes: list[int], weights: np.ndarray | None,
               base: PatchConfig, seed: int) -> dict[int, np.ndarray]:
    """{size: trained entries} of ``coded``'s ``dim``-wide groups at each of ``sizes``: one
    :func:`~.kmeans.codebook_ladder` (one draw; the larger vector codebooks warm-started from
    the largest) with the sampled trainer, else one training per size as the encoder trains."""
    if base.kmeans != "sampled":
        return {size: train_codebook(coded, dim, size, weights, base, seed) for size in sizes}
    n, width = coded.shape
    groups = coded.reshape(n * (width // dim), dim)
    w = None if weights is None else np.repeat(weights, width // dim)
    return codebook_ladder(groups, w, sizes, seed, samples=base.kmeans_samples,
                           iterations=base.kmeans_iterations)


def _measure_options(sample: GaussianCloud, attr: PatchAttribute, coded: np.ndarray,
                     trained: np.ndarray, entries: int, weights: np.ndarray | None,
                     base: PatchConfig,
                     framing: dict[str, Sensitivity], weight: dict[str, float], scale: float,
                     strengths: tuple[float, ...] = ()) -> list[Option]:
    """A codebook of ``attr`` trained on the sample, with nearest indices and then ECVQ's at
    each of ``strengths`` (a bit costs that many times the nearest indices' mean weighted error
    per group): each its index bits and the image MSE its values predict over the framings,
    scaled from the sample to the whole patch. The ECVQ variants compete in the search like any
    other option, so one multiplier picks both the codebook and how hard ECVQ trades.
    ``entries`` is the count the encoder asks again on the whole patch: the trained count, or
    every distinct value of the whole patch where that fits (the sample's codebook then holds
    only the sample's, :func:`entry_choices`)."""
    dim = trained.shape[1]
    codebook, idx = final_codebook(attr, coded, trained, weights, 0.0, base.ecvq_iterations,
                                   base.sh_zero_entry)
    zero = base.sh_zero_entry and attr >= PatchAttribute.SH_BAND_1
    out = [_option(sample, attr, codebook, idx, 0.0, framing, weight, scale, zero, entries)]
    if attr is PatchAttribute.ROTATION and dim == 1:
        return out  # scalar rotations keep their own search (final_codebook)
    per_group = _weighted_error(coded, codebook.entries, idx, weights) / max(idx.size, 1)
    for strength in strengths:
        cost = strength * per_group
        if cost > 0:
            book, ecvq_idx = final_codebook(attr, coded, trained, weights, cost,
                                            base.ecvq_iterations, base.sh_zero_entry)
            out.append(_option(sample, attr, book, ecvq_idx, cost, framing, weight, scale, zero,
                               entries))
    return out


def _option(sample: GaussianCloud, attr: PatchAttribute, codebook: Codebook, idx: np.ndarray,
            bit_cost: float, framing: dict[str, Sensitivity], weight: dict[str, float],
            scale: float, zero_entry: bool, trained: int) -> Option:
    """The measured option of ``codebook`` and the sample's indices ``idx`` into it; ``trained``
    entries were asked of k-means (the zero entry, when added, is not among them: an encoder
    given this option's count adds it again)."""
    changed = sample.subset(np.arange(len(sample)))
    fill_patch_attributes({attr: idx.T}, [codebook], changed)
    part = _SENSITIVITY_PART.get(attr.name, "sh")
    mse = sum(weight.get(name, 1.0) * float(s.mse(sample, changed, only=part).sum())
              for name, s in framing.items())
    entries = codebook.entries
    return Option(attr.name, entries.shape[1], trained, _index_bits(idx), int(entries.size * 2),
                  mse * scale, bit_cost, zero_entry)


_SENSITIVITY_PART = {"SCALE": "scales", "ROTATION": "quats", "OPACITY": "opacities"}
"""The :class:`Sensitivity` terms a codebook option of each attribute moves (colour DC and the
SH bands: "sh"); an option's distortion sums those alone, the rest unchanged by it."""


def _weighted_error(coded: np.ndarray, codebook: np.ndarray, indices: np.ndarray,
                    weights: np.ndarray | None) -> float:
    """The k-means objective of ``indices``: each group's squared error in the coded domain
    times its Gaussian's weight (1 when unweighted), summed."""
    n, width = coded.shape
    chosen = codebook.astype(np.float64)[indices].reshape(n, width)
    error = ((coded - chosen) ** 2).sum(axis=1)
    return float(error.sum() if weights is None else (np.asarray(weights) * error).sum())


def entry_choices(sample: np.ndarray, whole: np.ndarray | None, dim: int,
                  counts: tuple[int, ...]) -> list[int]:
    """Entry counts to measure at ``dim``, largest first: each of ``counts``, capped at the
    distinct groups of the whole patch (``whole``; the sample when None) when they fit a codebook.

    The cap is counted on the whole patch, not the sample the options are measured on: a scene
    decoded from an 8-bit format (SPZ) has a few hundred distinct values per attribute, and a
    sample misses the rare ones (fourth_st: 86 of 92 scales, 153 of 170 colours). Capped at the
    sample's count, the option looked exact on the sample but merged the rare values in the file,
    often those of the largest Gaussians (docs/LOG.md 21.1)."""
    distinct = _distinct(sample, dim)
    if whole is not None and distinct <= max(counts):  # else the whole patch has more still
        distinct = _distinct(whole, dim)
    return sorted({min(c, distinct) for c in counts}, reverse=True)


def _distinct(coded: np.ndarray, dim: int) -> int:
    """How many distinct ``dim``-wide groups the values hold, compared as float16 (a codebook
    needs no more). Groups of up to four are packed into one 64-bit key each (-0 made +0, as
    float comparison has it): a 1-D sort, where ``np.unique(axis=0)`` sorts rows at many times
    the cost."""
    groups = coded.reshape(-1, dim).astype(np.float16) + np.float16(0.0)
    if dim > 4:
        return max(1, len(np.unique(groups, axis=0)))
    bits = groups.view(np.uint16).astype(np.uint64)
    keys = bits[:, 0].copy()
    for k in range(1, dim):
        keys = (keys << np.uint64(16)) | bits[:, k]
    return max(1, len(np.unique(keys)))


def _index_bits(indices: np.ndarray) -> float:
    """Bits per row of ``indices`` (n, groups): each column's order-0 entropy."""
    n = len(indices)
    if n == 0:
        return 0.0
    bits = 0.0
    for column in indices.T:
        counts = np.bincount(column)
        p = counts[counts > 0] / n
        bits -= float((p * np.log2(p)).sum())
    return bits


POSITION_RENDERS = (0, 3)
"""Which of the distinct grids that move the input (coarsest first; past the last: the last)
:func:`position_options` renders to calibrate :func:`displacement_model`; every other grid's
distortion is predicted. The coarsest anchors the quadratic term, three bits finer the linear
one, near the grids size targets choose (12-14 bits on the shared scenes)."""


def position_options(scene: GaussianCloud, rows: np.ndarray, config: EncoderConfig,
                     allocation: AllocationConfig, device: str = "auto",
                     reference: dict[str, list[np.ndarray]] | None = None
                     ) -> list[PositionOption]:
    """Every grid of ``allocation.position_bits`` for the patch Gaussians at ``rows`` of
    ``scene``: the bytes of their positions written at it (one layer, Morton order, the
    configured mode), and the MSE of ``scene`` rendered with them moved to it, against
    ``scene`` as it is (``reference``: :func:`framing_renders` of it, when already made), at
    :func:`training_framings`. The writer's layers each span their own box, which the real
    trial writes of a size target measure.

    Rendering costs as much as the rest of the search, so only the grids of
    :data:`POSITION_RENDERS` are rendered; the others take :func:`displacement_model`'s
    prediction from their measured displacement. A grid that stores the input exactly (inputs
    already on a grid, :func:`.patch.input_grid`) adds no error and is not rendered; grids
    that decode alike share one measurement."""
    rows = np.asarray(rows, np.int64)
    order = rows[np.argsort(morton_codes(scene.means[rows].astype(np.float64)), kind="stable")]
    original = scene.means[order].astype(np.float64)
    grids = []  # (bits, bits per Gaussian, decoded positions in input order, their digest)
    on_grid: dict[tuple, tuple] = {}  # grids that store the input on its own grid: one write
    for bits in allocation.position_bits:
        own = input_grid(original, bits) if config.patch.position_mode in ("draco", "quant16") \
            else None
        if own is not None and tuple(own) in on_grid:
            grids.append((bits, *on_grid[tuple(own)]))
            continue
        stored = encode_positions(scene.means[order], config.patch.position_mode, bits,
                                  config.patch.set_coding_saving)
        decoded = np.empty_like(scene.means[order])
        decoded[stored.order] = stored.positions.decode()
        size = len(zlib.compress(pack_positions(stored.positions)))
        grids.append((bits, 8.0 * size / max(len(rows), 1), decoded, digest(decoded)))
        if own is not None:
            on_grid[tuple(own)] = grids[-1][1:]
    moved = {key: decoded for _, _, decoded, key in grids}  # distinct decodings, coarsest first
    shift = {key: float(np.sqrt(np.mean(np.sum((decoded - original) ** 2, axis=1))))
             if len(original) else 0.0 for key, decoded in moved.items()}
    off = sorted((key for key in moved if shift[key] > 0), key=lambda key: -shift[key])
    chosen = {off[min(i, len(off) - 1)] for i in POSITION_RENDERS} if off else set()
    rendered = _rendered_mse(scene, order, {key: moved[key] for key in off if key in chosen},
                             config, allocation, device, reference)
    model = displacement_model([(shift[key], mse) for key, mse in rendered.items()])
    distortion = {key: rendered[key] if key in rendered else model(shift[key]) for key in moved}
    return [PositionOption(bits, size, distortion[key]) for bits, size, _, key in grids]


def displacement_model(measured: list[tuple[float, float]]) -> Callable[[float], float]:
    """``shift -> MSE``: the rendered error of moving every Gaussian by an RMS ``shift``, as
    ``a * shift + b * shift**2`` (a, b >= 0) through the ``measured`` (shift, MSE) pairs.

    A small move of a Gaussian changes its smooth footprint by the square of the move, and its
    cut-off edge (where the renderer stops drawing it) by the move itself; on the shared scenes
    a grid one bit finer cut the rendered MSE 2-4x, between the two. Fitted per scene, so the
    Gaussians' sizes and colours are in the two coefficients."""
    points = [(s, d) for s, d in measured if s > 0]
    if not points:
        return lambda shift: 0.0
    x = np.array([[s, s * s] for s, _ in points])
    y = np.array([d for _, d in points])
    coef, *_ = np.linalg.lstsq(x, y, rcond=None)
    if coef.min() < 0:  # one term alone: the better of the two least-squares fits
        fits = []
        for k in (0, 1):
            single = np.zeros(2)
            single[k] = np.dot(x[:, k], y) / np.dot(x[:, k], x[:, k])
            fits.append(single)
        coef = min(fits, key=lambda c: float(np.sum((x @ c - y) ** 2)))
    a, b = float(coef[0]), float(coef[1])
    return lambda shift: a * shift + b * shift * shift


def _rendered_mse(scene: GaussianCloud, order: np.ndarray, moved: dict[bytes, np.ndarray],
                  config: EncoderConfig, allocation: AllocationConfig, device: str,
                  reference: dict[str, list[np.ndarray]] | None) -> dict[bytes, float]:
    """{key: the weighted MSE of ``scene`` rendered with the Gaussians at ``order`` moved to
    those positions, against ``reference``} at :func:`training_framings`."""
    from spcodec.imaging.render import GaussianParams, render_image, resolve_device

    if not moved:
        return {}
    if reference is None:
        reference = framing_renders(scene, config, allocation, device)
    device = resolve_device(device)
    settings = config.render_settings((0.0, 0.0, 0.0))
    framings = training_framings(scene, config, allocation)
    weight = allocation.framing_weights()
    out = {}
    for key, positions in moved.items():
        cloud = scene.subset(np.arange(len(scene)))
        cloud.means[order] = positions
        params = GaussianParams.from_cloud(cloud, device)
        out[key] = sum(weight.get(name, 1.0) * float(np.mean(
            [np.mean((render_image(params, c, settings) - r) ** 2)
             for c, r in zip(framings[name], reference[name])])) for name in framings)
    return out


def framing_renders(scene: GaussianCloud, config: EncoderConfig, allocation: AllocationConfig,
                    device: str = "auto") -> dict[str, list[np.ndarray]]:
    """``scene`` rendered at each of :func:`training_framings`: the reference that rendered
    options, and a size target's comparison of its candidate files, are measured against."""
    from spcodec.imaging.render import GaussianParams, render_image, resolve_device

    settings = config.render_settings((0.0, 0.0, 0.0))
    params = GaussianParams.from_cloud(scene, resolve_device(device))  # once, not per camera
    return {name: [render_image(params, c, settings) for c in cameras]
            for name, cameras in training_framings(scene, config, allocation).items()}


def training_framings(cloud: GaussianCloud, config: EncoderConfig,
                      allocation: AllocationConfig) -> dict[str, list]:
    """The search's cameras: ``allocation.views`` training views (eval's held-out views are never
    looked at) at the sampled framing ("orbit") and at half its distance ("close").

    Placing views checks each one's coverage of the scene, which costs most of a second on a
    100 k-Gaussian scene, and a size target asks for the same views four times (sensitivity,
    reference renders, position grids, the render comparison): they are remembered by the
    content they are placed from."""
    key = (digest(cloud.means), digest(cloud.scales), digest(cloud.opacities), repr(config.up),
           config.seed, allocation.views, allocation.resolution)
    framings = _FRAMINGS.get_or_make(key, lambda: _placed_framings(cloud, config, allocation))
    # copies: a camera's pose is an array, which no caller may change in the memory
    return {name: [dataclasses.replace(c, world_to_camera=c.world_to_camera.copy()) for c in cameras]
            for name, cameras in framings.items()}


_FRAMINGS: Recent[dict[str, list]] = Recent(8)
"""Recent :func:`training_framings`, by the cloud's content."""


def _placed_framings(cloud: GaussianCloud, config: EncoderConfig,
                     allocation: AllocationConfig) -> dict[str, list]:
    """The search's views. Where none of a view's tries covers enough of the picture (a flat,
    wide scene seen from its orbit: a city's coarse tileset nodes) the best try is kept without
    a warning, as the importance measure's are: a user can do nothing about the encoder's own
    views, and a city's tileset build printed it once for each node searched."""
    from spcodec.imaging.views import robust_bounds, sample_views

    size = (allocation.resolution, allocation.resolution)
    bounds = robust_bounds(cloud)
    orbit = sample_views(cloud, allocation.views, resolution=size, split="train", up=config.up,
                         seed=config.seed, bounds=bounds, warn=False)
    return {"orbit": orbit, "close": [c.dollied(bounds.centre, 0.5) for c in orbit]}


def patch_sensitivity(patch: GaussianCloud, config: EncoderConfig, allocation: AllocationConfig,
                      device: str = "auto"
                      ) -> tuple[dict[str, Sensitivity], dict[str, list[np.ndarray]]]:
    """The patch's :class:`Sensitivity` at each of :func:`training_framings`, and its pictures
    there (what :func:`framing_renders` returns, from the same forward passes)."""
    from spcodec.imaging.render import resolve_device
    from spcodec.imaging.sensitivity import render_sensitivity

    settings = config.render_settings((0.0, 0.0, 0.0))
    device = resolve_device(device)
    sensitivity, pictures = {}, {}
    for name, cameras in training_framings(patch, config, allocation).items():
        pictures[name] = []
        sensitivity[name] = render_sensitivity(patch, cameras, settings, allocation.probes,
                                               device, config.seed, pictures[name])
    return sensitivity, pictures
