"""Patch Gaussians without retraining: importance layers, codebooks (k-means) and uint8 indices.

Following Reduced-3DGS, as the paper does: every attribute except the position is replaced by an
index into a codebook of at most 256 float16 entries, trained with k-means; positions are not
codebook-quantized (that costs too much quality) but stored per Gaussian (QUANT16 by default: 16-bit
fixed point, delta-coded along a Morton curve, which beats the paper's float16 in both size and
precision). Gaussians are split into layers of decreasing importance so that a prefix of the file
shows the Gaussians that matter most.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from spcodec.attributes import PatchAttribute, canonical_rotation, encode_opacity
from spcodec.cloud import GaussianCloud
from spcodec.container import MAX_CODEBOOK_ENTRIES
from spcodec.decoder.layers import fill_patch_attributes
from spcodec.sections import Codebook, PatchPositions
from spcodec.writer import PatchLayer

from .draco import encode_ordered, grid_for
from .morton import morton_codes

_ASSIGN_CHUNK = 1 << 15


@dataclass
class PatchConfig:
    """Parameters of the patch encoder; defaults follow the paper unless a comment says why not."""

    #: Entries per codebook (the paper and Reduced-3DGS: 256, i.e. one-byte indices).
    codebook_size: int = 256
    #: Entry dimension per attribute: the attribute's components are split into groups of this
    #: size, one index per group (the format allows any divisor of the width, from scalar to full
    #: vector quantization). The defaults (preset "balanced") quantize scale per axis and rotation
    #: per pair of components: without retraining, whole-vector codebooks of 256 entries for these
    #: geometric attributes cost 5-12 dB on scenes of many small Gaussians (Mip-Splatting donut:
    #: 28.5 dB with vectors, 40.7 dB per axis/pair). Colour DC is a vector; each SH band is one
    #: vector (3 indices for SH degree 3), which on fourth_st saves 27 % for 7 dB less than one
    #: index per RGB coefficient (15 indices). See encoder/presets.py for the measured table.
    entry_dims: dict[str, int] = field(default_factory=lambda: {
        "SCALE": 1, "ROTATION": 2, "OPACITY": 1, "COLOR_DC": 3,
        "SH_BAND_1": 9, "SH_BAND_2": 15, "SH_BAND_3": 21,
    })
    #: How positions are stored: "draco" (order-preserving Draco, the smallest), "quant16" (16-bit
    #: fixed point, delta-coded), "float16" (the paper's) or "float32" (lossless).
    position_mode: str = "draco"
    #: For draco and quant16: bits of precision over the layer's bounding box (quant16: <= 16).
    position_bits: int = 16
    #: Number of patch layers (>= 1).
    layers: int = 3
    #: Share of the patch Gaussians in each layer, most important first (renormalized). The first
    #: layer is small so a streaming client sees the most important Gaussians early.
    layer_fractions: tuple[float, ...] = (0.2, 0.3, 0.5)
    #: k-means: at most this many samples train a codebook (the rest are only assigned).
    kmeans_samples: int = 200_000
    #: k-means iterations (Lloyd) and restarts.
    kmeans_iterations: int = 60
    kmeans_restarts: int = 1
    #: Weight k-means samples by importance, so codebook entries go where they are visible.
    weighted_kmeans: bool = True


def coded_attributes(cloud: GaussianCloud) -> dict[PatchAttribute, np.ndarray]:
    """Each patch attribute in its coded domain ([R-30]) as (N, width) float64."""
    out = {
        PatchAttribute.SCALE: cloud.scales.astype(np.float64),
        PatchAttribute.ROTATION: canonical_rotation(cloud.quats),
        PatchAttribute.OPACITY: encode_opacity(cloud.opacities)[:, None],
        PatchAttribute.COLOR_DC: cloud.sh_dc.astype(np.float64),
    }
    for attr in PatchAttribute.for_sh_degree(cloud.sh_degree)[4:]:
        out[attr] = cloud.sh_rest[:, attr.sh_slice, :].reshape(len(cloud), -1).astype(np.float64)
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


def encode_positions(xyz: np.ndarray, mode: str, bits: int = 16) -> PatchPositions:
    """Positions of one layer in the configured mode (draco falls back to quant16 if Draco does not
    keep the order, which the encoder checks by decoding)."""
    if mode == "draco":
        xyz = np.asarray(xyz, np.float64)
        if len(xyz) == 0:
            return PatchPositions.draco(b"", np.zeros((0, 3), np.float32))
        origin, _ = grid_for(xyz, 1.0)
        span = float((xyz.max(axis=0) - origin).max())
        step = max(span, 1e-30) / ((1 << bits) - 1)
        encoded = encode_ordered(xyz, step, origin, bits)
        if encoded is not None:
            return PatchPositions.draco(encoded.blob, encoded.positions)
        mode, bits = "quant16", min(bits, 16)
    if mode == "float16":
        return PatchPositions.float16(xyz)
    if mode == "float32":
        return PatchPositions.float32(xyz)
    if mode != "quant16":
        raise ValueError(f"unknown position mode {mode!r}")
    if not 1 <= bits <= 16:
        raise ValueError("position_bits must be in 1..16")
    xyz = np.asarray(xyz, np.float64)
    if len(xyz) == 0:
        return PatchPositions.quant16(xyz, 1.0, np.zeros(3))
    lo = xyz.min(axis=0).astype(np.float32)
    span = xyz.max(axis=0) - lo.astype(np.float64)
    levels = (1 << bits) - 1
    # The step is rounded to float32 upward so every position stays within the 16-bit range.
    step = np.maximum(np.nextafter((span / levels).astype(np.float32), np.float32(np.inf)),
                      np.float32(1e-30))
    return PatchPositions.quant16(xyz, step, lo)


def train_codebook(values: np.ndarray, entry_dim: int, size: int, weights: np.ndarray | None,
                   config: PatchConfig, seed: int) -> np.ndarray:
    """k-means centroids (<= size, float16) of the attribute's entry_dim-wide groups."""
    from sklearn.cluster import KMeans

    n, width = values.shape
    groups = values.reshape(n * (width // entry_dim), entry_dim)
    w = None if weights is None else np.repeat(weights, width // entry_dim)
    rng = np.random.default_rng(seed)
    if len(groups) > config.kmeans_samples:
        pick = np.sort(rng.choice(len(groups), config.kmeans_samples, replace=False))
        groups, w = groups[pick], None if w is None else w[pick]
    distinct = np.unique(groups.astype(np.float16), axis=0)
    if len(distinct) <= size:  # few distinct values: store them exactly
        return distinct
    km = KMeans(n_clusters=size, n_init=config.kmeans_restarts, max_iter=config.kmeans_iterations,
                random_state=seed)
    km.fit(groups, sample_weight=w)
    return np.unique(km.cluster_centers_.astype(np.float16), axis=0)


def assign(values: np.ndarray, entries: np.ndarray) -> np.ndarray:
    """Index (n, groups) uint8 of the nearest float16 entry for each group, in chunks."""
    n, width = values.shape
    dim = entries.shape[1]
    groups = values.reshape(n * (width // dim), dim)
    book = entries.astype(np.float64)
    book_sq = (book ** 2).sum(axis=1)
    out = np.empty(len(groups), np.uint8)
    for start in range(0, len(groups), _ASSIGN_CHUNK):
        block = groups[start:start + _ASSIGN_CHUNK]
        dist = book_sq[None, :] - 2.0 * block @ book.T
        out[start:start + _ASSIGN_CHUNK] = np.argmin(dist, axis=1)
    return out.reshape(n, width // dim)


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


class PatchEncoder:
    """Codebooks + indices + positions for patch Gaussians, in importance layers.

    The steps are separately callable so that a retraining loop can run them in its own order
    (for example: quantize, fine-tune the codebook entries with the indices fixed, re-assign,
    fine-tune again, then layer)::

        enc = PatchEncoder(config, seed)
        q = enc.quantize(cloud)                   # codebooks (k-means) and indices
        q.indices = enc.assign(cloud, q.codebooks)  # indices against given codebooks
        out = enc.layer(cloud, q, importance)     # layers, Morton order within, positions coded
        out = enc.encode(cloud)                   # all of the above with the default importance
    """

    def __init__(self, config: PatchConfig | None = None, seed: int = 0) -> None:
        self.config = config or PatchConfig()
        self.seed = seed

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
        if weights is not None and np.shape(weights) != (len(cloud),):
            raise ValueError(f"weights must have shape ({len(cloud)},), got {np.shape(weights)}")
        values = coded_attributes(cloud)
        codebooks = []
        for i, (attr, vals) in enumerate(values.items()):
            dim = self.entry_dim(attr)
            if len(cloud) == 0:
                entries = np.zeros((1, dim), np.float16)
            else:
                entries = train_codebook(vals, dim, cfg.codebook_size, weights, cfg,
                                         self.seed + 7919 * i)
            codebooks.append(Codebook(attr, entries))
        return Quantized(codebooks, self._assign_values(values, codebooks))

    def assign(self, cloud: GaussianCloud, codebooks: list[Codebook]
               ) -> dict[PatchAttribute, np.ndarray]:
        """Indices (uint8, (n, groups) per attribute) of the nearest entry of ``codebooks`` for
        every group of every Gaussian of ``cloud``; the codebooks must cover the cloud's SH
        degree exactly."""
        expected = PatchAttribute.for_sh_degree(cloud.sh_degree)
        if [cb.attribute for cb in codebooks] != expected:
            raise ValueError(f"codebooks for {[cb.attribute.name for cb in codebooks]}, the cloud "
                             f"needs {[a.name for a in expected]}")
        return self._assign_values(coded_attributes(cloud), codebooks)

    @staticmethod
    def _assign_values(values: dict[PatchAttribute, np.ndarray], codebooks: list[Codebook]
                       ) -> dict[PatchAttribute, np.ndarray]:
        return {cb.attribute: assign(values[cb.attribute], cb.entries) for cb in codebooks}

    def layer(self, cloud: GaussianCloud, quantized: Quantized, importance: np.ndarray
              ) -> PatchEncoding:
        """Split ``cloud`` (with its ``quantized`` attributes) into layers of decreasing
        ``importance`` (n,), sized by the config; Morton order within a layer; positions coded."""
        cfg = self.config
        if np.shape(importance) != (len(cloud),) or len(quantized) != len(cloud):
            raise ValueError("cloud, quantized and importance must describe the same Gaussians")
        layers, orders = [], []
        for members in split_layers(importance, cfg.layer_fractions, cfg.layers):
            if len(members):
                members = members[np.argsort(morton_codes(cloud.means[members].astype(np.float64)),
                                             kind="stable")]
            positions = encode_positions(cloud.means[members], cfg.position_mode,
                                         cfg.position_bits)
            layers.append(PatchLayer(positions, quantized.subset(members).indices))
            orders.append(members)
        return PatchEncoding(quantized.codebooks, layers, orders)

    def encode(self, cloud: GaussianCloud, importance: np.ndarray | None = None) -> PatchEncoding:
        """:meth:`quantize` then :meth:`layer`. ``importance`` (n,) orders the layers and, with
        ``weighted_kmeans``, weights k-means (None: the :func:`footprint_importance` proxy)."""
        if importance is None:
            importance = footprint_importance(cloud)
        importance = np.asarray(importance, np.float64)
        mean = importance.mean() if len(cloud) else 0.0
        weights = importance / mean if self.config.weighted_kmeans and mean > 0 else None
        return self.layer(cloud, self.quantize(cloud, weights), importance)
