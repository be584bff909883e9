"""Every knob of the encoder: one documented dataclass per stage, and :class:`EncoderConfig` of them all.

The stages (categorize, refine, sketch, patch, prune and retrain) and the pipeline that runs them
take their settings from here, and this module imports none of them, so the configuration sits
below every stage and no stage needs another (or the pipeline) to know its own settings.
``EncoderConfig.to_json()`` is what the file's metadata records.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Literal

import numpy as np

from spcodec.imaging.training.rates import LearningRates

if TYPE_CHECKING:  # the renderer loads torch; the configuration must not
    from spcodec.imaging.render import RenderSettings

DirectionMetric = Literal["axis", "signed"]
"""How categorization compares principal axes (see ``categorize.direction_distance``)."""

PruneMethod = Literal["importance", "sampled", "uniform"]
"""Which patch Gaussians survive pruning (see :mod:`.prune`)."""


@dataclass(frozen=True)
class CategorizeConfig:
    """Parameters of the multi-criteria DBSCAN. Defaults work for scenes in any unit.

    The paper gives no numeric thresholds. The defaults sit where real captures cluster a good
    share of their Gaussians into many mid-sized clusters without percolating into one giant
    component, which the polynomial models downstream could not fit; one step tighter or looser
    on any threshold does one or the other on fourth_st and biker, while synthetic curves are
    recovered at every such setting, so only the real scenes constrain the choice (DECISIONS
    D-1). Reproduce with ``python bench/bench_categorize.py --sweep``.
    """

    eps_s: float | None = None
    """Spatial radius in scene units. ``None`` (default) derives it from the scene as
    ``eps_s_factor`` times the ``eps_s_quantile`` of the distance to the ``eps_s_knn``-th nearest
    neighbour, because scenes come in arbitrary units (a 0.3-unit object, a 300-unit street) and
    only their own point spacing says what "near" means."""
    eps_s_factor: float = 1.5
    """Multiplier of the reference k-NN distance (unitless). 1.5 gives a Gaussian of typical
    density some 35 spatial candidates (measured on fourth_st and biker), a margin over
    ``min_samples`` for the candidates that the direction and colour criteria remove."""
    eps_s_knn: int = 10
    """``k`` of the reference k-NN distance (count, the point itself not counted). Twice
    ``min_samples``: a neighbourhood, not the nearest neighbour, whose distance is dominated by
    duplicated and quantized positions."""
    eps_s_quantile: float = 0.5
    """Which quantile of the k-NN distances is the reference (in [0, 1]). The median ignores both
    sparse background floaters and densely duplicated clumps."""
    eps_s_sample: int = 200_000
    """At most this many random query points estimate the k-NN quantile (count): the median's
    rank is then right to about 0.1 %, at a cost that stays flat for huge scenes."""
    eps_d: float = 0.05
    """Direction threshold, unitless in [0, 1] on the paper's scale ``(1 - cos) / 2``: 0.05 admits
    principal axes up to 25.8 degrees apart (|cos| >= 0.9), loose enough for curved edges."""
    eps_c: float = 0.1
    """Colour threshold, Euclidean RGB distance in [0, 1] units (about 15/255 per channel when
    all three differ equally): separates distinct surfaces meeting at an edge."""
    direction_metric: DirectionMetric = "axis"
    """``"axis"`` (default): sign-free ``(1 - |cos|) / 2``; ``"signed"``: the paper's literal
    ``(1 - cos) / 2``. See :func:`direction_distance` for the measurements behind the default."""
    min_samples: int = 5
    """Neighbours that make a core point (count, the point itself included as in scikit-learn,
    whose default of 5 this is)."""
    min_cluster_size: int = 20
    """Clusters with fewer members (cores plus borders) become noise (count). A sketch cluster
    pays for a Draco stream and polynomial models (a linear model of the 11 base outputs alone is
    44 coefficients), which a handful of Gaussians cannot amortize: a smaller minimum multiplies
    the clusters for few more clustered Gaussians (DECISIONS D-2)."""
    chunk_size: int = 8192
    """Query points per chunk of the neighbour search (count). Sets the working memory, about
    100 bytes per candidate pair (some 30 MB at the default eps_s); results do not depend on it.
    On fourth_st chunks of 2k-8k were also the fastest (cache locality)."""
    random_state: int | None = 0
    """Seed of the k-NN sample when the scene has more than ``eps_s_sample`` points."""

    def __post_init__(self) -> None:
        if self.eps_s is not None and not (np.isfinite(self.eps_s) and self.eps_s >= 0):
            raise ValueError(f"eps_s must be finite and >= 0 or None, got {self.eps_s}")
        _check_range("eps_d", self.eps_d, 0.0, 1.0)
        _check_range("eps_s_quantile", self.eps_s_quantile, 0.0, 1.0)
        if not (np.isfinite(self.eps_c) and self.eps_c >= 0):
            raise ValueError(f"eps_c must be finite and >= 0, got {self.eps_c}")
        if not (np.isfinite(self.eps_s_factor) and self.eps_s_factor > 0):
            raise ValueError(f"eps_s_factor must be positive, got {self.eps_s_factor}")
        if self.direction_metric not in ("axis", "signed"):
            raise ValueError(f"direction_metric must be 'axis' or 'signed', "
                             f"got {self.direction_metric!r}")
        for name in ("eps_s_knn", "eps_s_sample", "min_samples", "min_cluster_size", "chunk_size"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")


def _check_range(name: str, value: float, lo: float, hi: float) -> None:
    if not lo <= value <= hi:
        raise ValueError(f"{name} must be in [{lo}, {hi}], got {value}")


@dataclass(frozen=True)
class RefineConfig:
    """Every knob of model fitting and refinement, with its unit and the reason for its default."""

    # ---- error measure
    weights: tuple[float, float, float, float] = (0.25, 0.25, 0.25, 0.25)
    """Weights of scale, rotation, opacity, colour-DC normalized MSE in MSE_combined (paper: equal
    0.25). Unitless."""
    tau_max: float = 0.1
    """Threshold on MSE_combined (unitless: squared error / scene robust variance, averaged over the
    four attributes): 0.1 ~ an RMS error of a third of each attribute's scene-wide spread. The
    paper gives no value. Real captures are noisy at the finest scale, so the sketch share depends
    strongly on tau (bench/bench_refine.py sweeps it); 0.1 is a fidelity-first default
    (DECISIONS D-3)."""

    # ---- degree search
    min_degree: int = 0
    """Lowest degree tried. 0 (a per-cluster constant) is allowed because it is the cheapest model
    and is often enough for opacity or colour of a small cluster."""
    max_degree: int = 10
    """Highest degree tried (paper: grid search over [1, 10]; 10 is the format's maximum)."""
    degree_lambda: float = 1e-2
    """Rate-distortion multiplier: a degree is worth its bytes if it lowers ``weight * nMSE`` by at
    least ``degree_lambda`` per coefficient byte per Gaussian. Unit: normalized MSE per
    (byte/Gaussian); e.g. in a 1000-point cluster one more colour degree (~60 bytes) must buy 6e-4
    of weighted error. tau_max is still met whenever possible (lambda is lowered for that
    cluster), so lambda only decides how far below tau to go; 1e-2 is the middle of the trade
    measured on biker (DECISIONS D-4)."""
    min_points_per_coefficient: float = 3.0
    """A degree is admissible only when n >= this * M(d): fewer points would make the model cost
    more than ~1 byte per output per Gaussian (a codebook index) and merely interpolate."""
    ridge: float = 1e-7
    """Ridge strength relative to n on every coefficient but the intercept (features are in
    [-1, 1]). Small enough not to bias well-posed fits, large enough to stop the huge cancelling
    coefficients an ill-conditioned monomial fit produces, which float16 cannot represent."""
    frame_floor: float = 1e-2
    """Each half extent is at least this fraction of the largest one, so a flat axis is not
    stretched to [-1, 1] (there the fit would chase position noise). Unitless."""
    sh_rest_degree: int | None = 1
    """Highest degree of the optional SH-rest model (selected with the same cost, capped here and
    by max_degree); None = no model, so sketch Gaussians decode with zero higher SH bands (the
    paper's choice). Higher bands are not smooth in position, but a per-cluster constant or plane
    recovers half the loss of dropping them at a better rate than any codebook knob, so <= 1
    (DECISIONS D-5)."""
    sh_rest_weight: float = 0.25
    """Weight of the SH-rest normalized MSE in its own degree cost (it is not part of
    MSE_combined). 0.25 puts it on the footing of each of the four combined attributes."""

    # ---- splitting
    beta: float = 0.5
    """Weight of the residuals against positions in the K-means features (paper's beta). 0.5:
    residuals (normalized, ~sqrt(tau) and above in failing clusters) and positions (in [-1, 1])
    then pull comparably, so parts are spatially coherent yet separate differently-modelled
    Gaussians."""
    k_max: int = 4
    """Most parts one split makes (paper: k <= 4)."""
    s_min: int = 32
    """Smallest sketch cluster, Gaussians. Below it the fixed costs (cluster record, Draco header,
    >= 4 models) outweigh the ~10 bytes per Gaussian sketch saves over patch."""
    t_max: int = 6
    """Deepest split level. A node still failing tau_max at this depth goes to patch (never
    accepted over the threshold). 6 levels allow parts of 1/64 .. 1/4096 of a cluster, far below
    s_min for all but huge clusters, so it only stops pathological recursions."""
    min_split_gain: float | None = 0.1
    """A part that still fails tau_max goes to patch ('no_gain') unless its own models' MSE_combined
    is at least this fraction below that of its parent's models on the same Gaussians (0: not
    worse). Splitting is meant to isolate coherent sub-regions;
    when parts are as badly modelled as the whole, the cluster is noise at this scale, and
    recursing to s_min would multiply fits ~2n/s_min times for clusters that end in patch anyway
    (on real scenes this bounds refinement cost). None disables the test."""
    kmeans_n_init: int = 1
    """K-means restarts with k-means++ seeding (fixed for determinism). 1 is scikit-learn's own
    'auto' choice for k-means++ and, with k <= 4 in ~15 dimensions, restarts rarely change the
    split while each costs as much as a model fit on small nodes."""
    kmeans_max_samples: int = 20000
    """K-means is fit on at most this many Gaussians of a node (a fixed-seed subsample) and then
    assigns all of them; bounds the cost of huge clusters without changing small ones."""
    random_state: int = 0
    """Seed of K-means and of its subsample, so results are reproducible."""

    # ---- IQR post-processing
    iqr_k: float | None = 1.5
    """Tukey fence multiplier: a Gaussian of an accepted cluster whose ``iqr_quantity`` (any of
    the three axes) lies outside [Q1 - k IQR, Q3 + k IQR] of its cluster goes to patch. 1.5 is
    Tukey's standard value (the paper's 'IQR method'). None disables the post-processing."""
    iqr_min_spread: float = 0.2
    """Floor on the IQR the fences are built from, in log-scale units (0.2 = a factor 1.22). In a
    cluster modelled almost perfectly the residual IQR is ~0 and plain fences would flag Gaussians
    whose size is barely off; with the floor and k = 1.5 nothing within ~0.3 in log scale of the
    quartiles is ever flagged (DECISIONS D-6)."""
    iqr_quantity: str = "residual"
    """What the fences are put on, per axis: 'residual' = decoded minus original log scale (how
    wrong the decoded size is), 'decoded' = the decoded log scale itself (the paper's literal
    wording). Default 'residual': a smooth model's extremes are merely the cluster's periphery,
    while the paper's stated aim is to drop *badly modelled* (too long / too thin) Gaussians,
    which is what the residual rule selects, injected outliers included (DECISIONS D-6)."""

    def __post_init__(self) -> None:
        if len(self.weights) != 4 or min(self.weights) < 0:
            raise ValueError("weights must be four non-negative numbers")
        if not 0 <= self.min_degree <= self.max_degree <= 10:
            raise ValueError("need 0 <= min_degree <= max_degree <= 10")
        if self.sh_rest_degree is not None and not 0 <= self.sh_rest_degree <= 10:
            raise ValueError("sh_rest_degree must be None or 0..10")
        if not 0.0 <= self.beta <= 1.0:
            raise ValueError("beta must lie in [0, 1]")
        if self.min_split_gain is not None and not self.min_split_gain < 1.0:
            raise ValueError("min_split_gain must be None or < 1")
        if self.tau_max <= 0 or self.s_min < 1 or self.t_max < 0 or self.k_max < 2:
            raise ValueError("need tau_max > 0, s_min >= 1, t_max >= 0, k_max >= 2")
        if self.min_points_per_coefficient <= 0 or self.ridge < 0 or self.frame_floor <= 0:
            raise ValueError("need min_points_per_coefficient > 0, ridge >= 0, frame_floor > 0")
        if self.kmeans_n_init < 1 or self.kmeans_max_samples < self.k_max:
            raise ValueError("need kmeans_n_init >= 1 and kmeans_max_samples >= k_max")
        if (self.iqr_k is not None and self.iqr_k < 0) or self.iqr_min_spread < 0:
            raise ValueError("iqr_k must be None or >= 0, iqr_min_spread >= 0")
        if self.iqr_quantity not in ("residual", "decoded"):
            raise ValueError("iqr_quantity must be 'residual' or 'decoded'")


@dataclass
class SketchConfig:
    """Parameters of sketch position coding and of the final acceptance of clusters."""

    #: Target mean position error of sketch Gaussians, relative to the scene's robust diameter
    #: (the paper reports a mean error below 0.04 %). The Draco quantization step is derived from
    #: it; smaller targets cost about 3 bits per point per halving.
    position_error: float = 3e-4
    #: Draco compression level (0..10; 10 is the smallest output, still fast for point clouds).
    draco_compression_level: int = 10
    #: "run": all clusters share one order-preserving Draco blob on a scene-wide grid (one header
    #: instead of one per cluster, DECISIONS D-7);
    #: "per_cluster": one kd-tree blob per cluster (best for clusters of thousands).
    grouping: str = "run"
    #: A cluster whose models, refitted on decoded positions, exceed tau_max by more than this
    #: factor goes back to patch (refits move the error a little either way; 1.0 is strict).
    tau_tolerance: float = 1.05

    def __post_init__(self) -> None:
        if not 0 < self.position_error < 1:
            raise ValueError("position_error must lie in (0, 1)")
        if not 0 <= self.draco_compression_level <= 10:
            raise ValueError("draco_compression_level must be in 0..10")
        if self.tau_tolerance < 1:
            raise ValueError("tau_tolerance must be >= 1")
        if self.grouping not in ("run", "per_cluster"):
            raise ValueError("grouping must be 'run' or 'per_cluster'")


LAYER_RATIO = 1.5
"""Each patch layer of ``--patch-layers N`` (other than the default 3) holds this many times the
Gaussians of the one before: a viewer refines in steps of equal relative size, and the first of
6 layers holds about a twentieth of the patch, of 8 layers a fiftieth."""


RETRAINED_PATCH_LAYERS = 6
"""Patch layers of a retrained encode (``--nested`` or not) unless ``--patch-layers`` says
otherwise; ``PatchConfig.layers`` (3) stays the no-retrain default. A streaming viewer gets
twice the refinement steps, each prefix about as good as the three-layer file's prefix near its
size, and the full file keeps its picture (DECISIONS D-23)."""


RETRAINED_MAX_SKETCH_SHARE = 0.025
"""``EncoderConfig.max_sketch_share`` of a retrained encode (``preset_config(..., retrain=True)``).
Retraining fills the room with patch Gaussians that serve the picture better than the sketch's
polynomial models, and a small sketch moves every layer prefix earlier (DECISIONS D-24).
``--no-retrain`` keeps ``max_sketch_share``'s tenth."""


VIEWER_BLUR_VARIANCE = 0.075
"""The low-pass the PlayCanvas engine draws with (it adds 0.3 in half-pixel units: 0.075 px^2,
``../shared/tools/viewer-render/README.md``), and the encoder's default. A larger one (INRIA's 0.3)
hides in training exactly the fine texture that pruning and distillation lose, which a viewer then
shows (DECISIONS D-19)."""

DATASET_BLUR_VARIANCE = 0.3
"""The low-pass of an encode retraining against a dataset's images: INRIA's, the one a model
trained on those images was made with and that test PSNR renders with; retrained at the viewer's
low-pass, lego's file scores far lower on its test images (DECISIONS D-20). The file's report
judges at the low-pass it trained with, so the two never disagree."""

TARGET_GROUPS_PER_ENTRY = 32
"""``PatchConfig.groups_per_entry`` under ``--target-size``, where bytes the codebooks leave go to
more Gaussians: on a small patch the rule doubles the Gaussians a target holds (DECISIONS D-22).
Scenes whose patch keeps more than 8,192 Gaussians keep 256 entries for every attribute."""


def codebook_entries(config: "PatchConfig", gaussians: int, groups_per_gaussian: int) -> int:
    """Entries of the codebook of an attribute with ``groups_per_gaussian`` vectors a Gaussian,
    for ``gaussians`` Gaussians (or ``config.codebooks_sized_for``), under ``config``'s rule."""
    if config.groups_per_entry is None:
        return config.codebook_size
    if config.codebooks_sized_for is not None:
        gaussians = config.codebooks_sized_for
    by_count = int(gaussians * groups_per_gaussian // config.groups_per_entry)
    return max(1, min(config.codebook_size, max(config.min_codebook_entries, by_count)))


def geometric_fractions(layers: int, ratio: float = LAYER_RATIO) -> tuple[float, ...]:
    """Shares of ``layers`` patch layers, each ``ratio`` times the one before, summing to 1."""
    if layers < 1 or ratio <= 0:
        raise ValueError("layers must be >= 1 and ratio > 0")
    shares = [ratio ** k for k in range(layers)]
    return tuple(share / sum(shares) for share in shares)


DEFAULT_POSITION_BITS = 16
"""Patch positions without retraining: 16 bits of each layer's box (1/65,535 of its extent)."""

RETRAINED_POSITION_BITS = 12
"""Patch positions of a retrained (pruned to a budget) file: 12 bits of the scene's robust extent,
more where outliers stretch the box (``encoder.patch.retrained_position_bits``). Every shared
scene's box spans about 1,000 pixels of a viewer's close-up (PlayCanvas at half the orbit distance,
512 px), so 12 bits place a Gaussian within a quarter of a pixel there, and training learns the
grid; the bytes saved keep more Gaussians, with no loss at either framing on any shared scene
(DECISIONS D-21)."""


@dataclass
class PatchConfig:
    """Parameters of the patch encoder; defaults follow the paper unless a comment says why not."""

    #: Entries per codebook (the paper and Reduced-3DGS: 256, i.e. one-byte indices), at most.
    codebook_size: int = 256
    #: Fewer entries for few Gaussians: a codebook gets at most one entry per this many of the
    #: groups it codes (and at least ``min_codebook_entries``); None: always ``codebook_size``.
    #: At a small target the fixed 256 entries cost more than the Gaussians they serve
    #: (DECISIONS D-22). See :func:`codebook_entries`.
    groups_per_entry: float | None = None
    #: The floor of the rule above.
    min_codebook_entries: int = 16
    #: Apply the rule above as if this many Gaussians were quantized (None: as many as are).
    #: Rate control fixes it at its planned count before retraining, so the codebooks it sized
    #: the file with are the ones written even when the retrained patch ends with fewer
    #: Gaussians (without it a small file lands well under its target: DECISIONS D-22).
    codebooks_sized_for: int | None = None
    #: Entry dimension per attribute: the attribute's components are split into groups of this
    #: size, one index per group (the format allows any divisor of the width, from scalar to full
    #: vector quantization). The defaults (preset "balanced") quantize scale per axis and rotation
    #: per pair of components: without retraining, whole-vector codebooks of 256 entries for these
    #: geometric attributes cost most on scenes of many small Gaussians. Colour DC is a vector;
    #: each SH band is one vector (3 indices for SH degree 3 instead of 15 for one index per RGB
    #: coefficient), much smaller for a moderate loss (DECISIONS D-8; encoder/presets.py).
    entry_dims: dict[str, int] = field(default_factory=lambda: {
        "SCALE": 1, "ROTATION": 2, "OPACITY": 1, "COLOR_DC": 3,
        "SH_BAND_1": 9, "SH_BAND_2": 15, "SH_BAND_3": 21,
    })
    #: Entries per codebook for some attributes (by name), at most ``codebook_size`` and the
    #: rule above; the rate-distortion search (encoder/allocation.py) sets them. None: none.
    entry_counts: dict[str, int] | None = None
    #: How positions are stored: "draco" (Draco, the smallest: DECISIONS D-9),
    #: "quant16" (16-bit fixed point, delta-coded), "float16" (the paper's) or "float32" (lossless).
    position_mode: str = "draco"
    #: For draco and quant16: bits of precision over the layer's bounding box (quant16: <= 16).
    #: None: :data:`DEFAULT_POSITION_BITS`, except for a retrained patch, where the encoder takes
    #: :data:`RETRAINED_POSITION_BITS` over the scene's robust extent (see that constant).
    position_bits: int | None = None
    #: In draco mode, code a layer's positions as a set (Draco's kd-tree mode, the layer in
    #: Draco's order, [R-58]) where that saves at least this many bits per Gaussian over
    #: sequential coding, whose blobs decode faster; None: never (DECISIONS D-29).
    set_coding_saving: float | None = 2.0
    #: Number of patch layers (>= 1).
    layers: int = 3
    #: Share of the patch Gaussians in each layer, most important first (renormalized). The first
    #: layer (with the codebooks) completes within a tenth of the file, a streaming viewer's
    #: first picture when there is no sketch, and the first two end before 30 percent of it with
    #: guitar's sketch; each further layer codes its positions on its own (DECISIONS D-10). Other
    #: layer counts on the command line take :func:`geometric_fractions` (each layer 1.5 times
    #: the one before).
    layer_fractions: tuple[float, ...] = (0.07, 0.165, 0.765)
    #: Codebook trainer (encoder/kmeans.py): "sampled" (exact in one dimension, weight-proportional
    #: samples for vectors) or "exhaustive" (the previous scikit-learn k-means++ on uniform
    #: samples: several times slower for codebooks as good, DECISIONS D-11; kept for comparisons).
    kmeans: str = "sampled"
    #: k-means samples per vector codebook (sampled: draws; exhaustive: at most this many groups).
    kmeans_samples: int = 65_536
    #: k-means (Lloyd) iterations at most.
    kmeans_iterations: int = 40
    #: Weight k-means samples by importance, so codebook entries go where they are visible.
    weighted_kmeans: bool = True
    #: With weighted k-means, every Gaussian weighs at least this share of the mean importance,
    #: so Gaussians the sampled views miss (seen from elsewhere) still get entries near them.
    kmeans_weight_floor: float = 0.1
    #: What ranks Gaussians into layers and weights k-means: "blend", the blending weight each
    #: accumulates over ``importance_views`` sampled training views (imaging/importance.py), or
    #: "footprint", opacity times footprint area (no rendering, but blind to occlusion;
    #: DECISIONS D-10).
    importance: str = "blend"
    #: Views (training split, never eval's) and their (width, height) for "blend".
    importance_views: int = 6
    importance_resolution: tuple[int, int] = (256, 192)
    #: Code index columns given earlier ones where that makes the file smaller (format 1.2's
    #: PATCH_INDEX_CONTEXTS, chosen by measurement in encoder/contexts.py); False: 1.0 coding.
    index_contexts: bool = True
    #: Entropy-constrained assignment (encoder/ecvq.py): each group goes to the entry minimizing
    #: its weighted error plus a cost per index bit, the entries re-estimated in turn, so the
    #: index histogram grows skewed and its Huffman code shorter. Only where ``ecvq_bit_costs``
    #: names the attribute; False: nearest entries (DECISIONS D-27).
    ecvq: bool = False
    #: ECVQ's cost per index bit of each attribute, by name, in the k-means objective's units
    #: (importance-weighted squared error in the coded domain); the precision search sets it
    #: from the ECVQ options it chose (``AllocationConfig.ecvq_strengths``). None or absent:
    #: nearest entries.
    ecvq_bit_costs: dict[str, float] | None = None
    #: Rounds of code lengths, assignment and centroids.
    ecvq_iterations: int = 3
    #: Every SH band's codebook holds an exact zero entry: under ECVQ a Gaussian whose view
    #: dependence does not pay for its bits lands there and drops that band, an SH degree per
    #: Gaussian (DECISIONS D-27). The precision search sets it with its ECVQ options.
    sh_zero_entry: bool = False

    @property
    def stored_position_bits(self) -> int:
        """The position precision written: ``position_bits``, or its default when unset."""
        return DEFAULT_POSITION_BITS if self.position_bits is None else self.position_bits


@dataclass
class AllocationConfig:
    """How the rate-distortion search of the patch's precision measures its options
    (encoder/allocation.py; recorded in the file's metadata). It runs for a no-retrain
    ``target_size`` that the preset's own file does not already fill, and with no target for a
    no-retrain preset that may prune, spending the bytes it predicts for the preset's codebook
    shapes (encoder/sizing.py, DECISIONS D-33, D-34)."""

    #: Patch Gaussians the options are measured on (a uniform sample, seeded).
    sample: int = 16_384
    #: Entry counts tried for every entry dimension (the format allows 1..256). The ladder
    #: reaches down to 4 with positions to 10 bits, so that every Gaussian can stay at sizes
    #: where pruning would otherwise start (DECISIONS D-28).
    entry_counts: tuple[int, ...] = (256, 128, 64, 32, 16, 8, 4)
    #: Training views (never eval's) the sensitivity is taken at, at the sampled framing and
    #: at half its distance, and their side in pixels.
    views: int = 4
    resolution: int = 256
    #: Random projections per view for the sensitivity.
    probes: int = 1
    #: Weight of the close framing's MSE against the sampled framing's in the distortion.
    close_weight: float = 1.0
    #: Grids (bits over a layer's box) the patch's positions may take; each is written and
    #: rendered (encoder/allocation.py, position_options). Empty: positions stay at the
    #: preset's grid (DECISIONS D-28).
    position_bits: tuple[int, ...] = (10, 11, 12, 13, 14, 15, 16)
    #: ECVQ variants of every codebook option (encoder/ecvq.py): for each strength, the same
    #: codebook with indices assigned at a cost per index bit of that many times its nearest
    #: indices' mean weighted error per group, measured like every option, so the multiplier
    #: that picks the codebooks also picks how hard each trades error for bits; with any, every
    #: SH band's codebook holds an exact zero entry. Empty: nearest entries only (DECISIONS D-27).
    #: (0.3, 1.0, 3.0) is the measured setting; off by default until the size target's trial
    #: writes predict ECVQ's skewed index columns (their Huffman code is longer than the
    #: entropy the options are priced at).
    ecvq_strengths: tuple[float, ...] = ()

    #: Factor on the linearized renderer's predictions (codebook options, the sketch's error),
    #: which put them on the scale of rendered MSE, the scale position options are measured
    #: on: it underestimated codebook options' rendered MSE 1.5x on average on guitar and
    #: fourth_st (docs/LOG.md 17.1).
    linearized_gain: float = 1.5

    def framing_weights(self) -> dict[str, float]:
        """Each framing's weight in the distortion, by the names the search's framings carry."""
        return {"orbit": 1.0, "close": self.close_weight}

    def linearized_weights(self) -> dict[str, float]:
        """:meth:`framing_weights` for predictions of the linearized renderer, times
        :attr:`linearized_gain`."""
        return {name: w * self.linearized_gain for name, w in self.framing_weights().items()}

    def to_json(self) -> dict:
        return dataclasses.asdict(self)


@dataclass
class RetrainConfig:
    """Settings of the retraining stage (stored in the file's metadata)."""

    #: Keep ``1 / patch_downsample`` of the patch Gaussians (the paper sweeps 1..20; 1 = keep all).
    patch_downsample: float = 4.0
    #: How survivors are chosen: "importance" (largest blend weight over the training views),
    #: "sampled" (random in proportion to it) or "uniform" (random, the paper's). Importance
    #: stays the default: each alternative won on one scene and lost on another (DECISIONS D-13).
    prune: PruneMethod = "importance"
    #: Optimizer steps of the retraining, one training view each (DECISIONS D-14).
    iterations: int = 3000
    #: Adam rates per attribute (the 3DGS defaults; positions scaled by the camera extent).
    rates: LearningRates = field(default_factory=LearningRates)
    #: Distillation: how many training views are sampled around the original, and their side.
    #: 96 whole views and 96 close crops rather than 48 and 48: with 48 of each, 3000 steps
    #: learn the views rather than the scene; twice the views cost only more target rendering,
    #: the step cost unchanged (DECISIONS D-15).
    views: int = 96
    resolution: int = 400
    #: Distillation close-ups: this many more training views from ``close_distance`` times as
    #: far (0.5: half way to the scene), ``close_resolution`` pixels across, each trained as a
    #: crop of ``close_crop`` pixels around a point of the scene (a crop costs its pixels, not
    #: the frame's). Whole-scene views leave fine texture below a pixel, which a viewer's
    #: close-up shows (DECISIONS D-16). 0: none.
    close_views: int = 96
    close_distance: float = 0.5
    #: Close frames of 400 pixels (at the 50-degree field of view), cut into 256-pixel crops:
    #: at 800 each crop framed a third of the view's width and its pixels were 0.64 of a pixel
    #: of a viewer's 512-pixel close-up, detail no framing shows; at 400 a crop frames two thirds
    #: of the width, at pixels between the viewer's orbit and close-up (DECISIONS D-17). A crop
    #: costs the same pixels at any of them.
    close_resolution: int = 400
    close_crop: int = 256
    #: Dataset mode: image downscale factor, and at most this many training views (None: all of
    #: the training split).
    downscale: int = 1
    max_views: int | None = None
    #: Steps of the quantization-aware finish (0: off) and when its one re-assignment happens
    #: (DECISIONS D-14).
    finish_iterations: int = 600
    reassign_at: float = 0.5
    #: Training views (evenly spread) over which blend weights rank Gaussians for pruning/layers.
    importance_views: int = 16
    #: Quantization-aware retraining: from this share of ``iterations`` on, the patch trains
    #: through its codebooks (each attribute snapped to its nearest entry and positions to the
    #: stored grid, gradients passed straight through; encoder/retraining/quantaware.py). Under rate control
    #: the count is fitted to the target at that step, while steps remain to adapt. 1.0: train
    #: unquantized and quantize afterwards.
    snap_start: float = 0.3
    #: Steps between moves of the snapped entries to their groups' weighted centroids.
    snap_refresh_every: int = 100
    #: Snap only when quantizing at ``snap_start`` costs the training views at least this many
    #: dB; below it, training goes on freely and the finish tunes the codebooks. Snapping
    #: pays where the codebooks cost much (fourth_st, SH 3) and loses where they cost little
    #: (guitar, SH 0): DECISIONS D-18.
    snap_min_loss: float = 2.5
    #: Nested retraining (encoder/retraining/nested.py): the patch layers are fixed before training and
    #: every step trains one layer prefix (sketch and layers 1..k), the whole file at
    #: ``nested_full_share`` of the steps, so that every prefix is a trained scene for a
    #: progressive viewer (plain retraining optimizes the full file only). Snapping is off.
    nested: bool = False
    #: Three quarters is the knee of guitar's trade-off at 3000 steps between the full file and
    #: its prefixes (DECISIONS D-25).
    nested_full_share: float = 0.75

    def __post_init__(self) -> None:
        if self.patch_downsample < 1:
            raise ValueError(f"patch_downsample must be >= 1, got {self.patch_downsample}")
        if self.iterations < 0 or self.finish_iterations < 0:
            raise ValueError("iterations must be >= 0")
        if self.views < 1 or self.resolution < 8 or self.importance_views < 1:
            raise ValueError("views and importance_views must be >= 1 and resolution >= 8")
        if self.close_views < 0 or not 0 < self.close_distance <= 1 or \
                not 8 <= self.close_crop <= self.close_resolution:
            raise ValueError("close_views must be >= 0, close_distance in (0, 1] and close_crop "
                             "in 8..close_resolution")
        if self.downscale < 1 or (self.max_views is not None and self.max_views < 1):
            raise ValueError("downscale and max_views must be >= 1")
        if not 0 < self.reassign_at < 1:
            raise ValueError("reassign_at must lie in (0, 1)")
        if not 0 <= self.nested_full_share <= 1:
            raise ValueError("nested_full_share must lie in [0, 1]")
        if not 0 <= self.snap_start <= 1 or self.snap_refresh_every < 1:
            raise ValueError("snap_start must lie in [0, 1] and snap_refresh_every be >= 1")

    @property
    def snap_step(self) -> int | None:
        """The retraining step at which snapping starts (None: it never does)."""
        return None if self.snap_start >= 1 else int(round(self.snap_start * self.iterations))


@dataclass
class EncoderConfig:
    """Every parameter of an encode. Stage configs are documented field by field above.

    ``seed`` overrides the stages' own random states, so one number makes the encode reproducible.
    """

    categorize: CategorizeConfig = field(default_factory=CategorizeConfig)
    refine: RefineConfig = field(default_factory=RefineConfig)
    sketch: SketchConfig = field(default_factory=SketchConfig)
    patch: PatchConfig = field(default_factory=PatchConfig)
    #: Seed of every random choice (k-NN sampling, K-means, codebook training).
    seed: int = 0
    #: Worker processes for refinement (None: the available cores). How the work runs, not what
    #: it makes (refinement gives the same clusters for any count), so it is left out of
    #: :meth:`to_json`: the file's metadata and a checkpoint's fingerprint do not depend on it.
    n_jobs: int | None = None
    #: False encodes every Gaussian as patch (the baseline without structure).
    use_sketch: bool = True
    #: Section codec: "zlib" (the paper's; every decoder has it) or "zstd" (optional;
    #: DECISIONS D-12).
    codec: str = "zlib"
    #: Wrap the file in gzip (the paper's final step; a few percent smaller).
    gzip: bool = False
    #: How the scene is viewed: its up axis (for sampled views, as ``spcodec eval --up``; "-y"
    #: suits COLMAP-derived scenes, "+z" z-up ones) and whether it renders with Mip-Splatting's
    #: antialiased opacity (models trained that way). Distillation, importance, judging and the
    #: file's metadata (for viewers) use them.
    up: str = "-y"
    antialiased: bool = False
    #: The screen-space low-pass (px^2) the encoder renders with (distillation targets, the
    #: trained model, importance) and, against a dataset, judges the written file with. None
    #: picks by the targets (:meth:`low_pass`): the viewer's :data:`VIEWER_BLUR_VARIANCE` when
    #: distilling, :data:`DATASET_BLUR_VARIANCE` against a dataset's images.
    blur_variance: float | None = None
    #: Prune and retrain the patch (None: the no-retrain encoder). See :mod:`.retrain`.
    retrain: "RetrainConfig | None" = None
    #: Rate control: a file of at most this many bytes (within 1 % under it where the patch
    #: allows, encoder/ratecontrol.py, DECISIONS D-26) by choosing how many patch
    #: Gaussians survive pruning (None: the size follows from the settings). ``--target-size``
    #: also sets ``patch.groups_per_entry`` to :data:`TARGET_GROUPS_PER_ENTRY`;
    #: ``encoder.presets.sized`` sets both for a library caller.
    target_size: int | None = None
    #: Quality control: the smallest file whose close-up PSNR (``spcodec eval``'s views at half
    #: their distance) reaches this many dB, again by choosing how many patch Gaussians survive
    #: (encoder/qualitycontrol.py; None: off). Exclusive with ``target_size``.
    target_psnr: float | None = None
    #: Judge the written file at the end of a retrained or ``target_psnr`` encode, as
    #: ``spcodec eval`` does (the stats' "quality"); False (``--no-eval``) saves that time, and
    #: ``spcodec eval OUT.spc --reference IN.ply`` gives the same figures later.
    evaluate: bool = True
    #: The sketch layer, a streaming viewer's first picture, ends within this share of the file
    #: (DECISIONS D-10):
    #: when it would not, the sketch clusters of least importance per Gaussian go to the patch
    #: (None: no limit). With retraining the share is judged before training, on the file the
    #: prune factor makes; with ``target_size``, of the target (left alone, a small target was
    #: all sketch: guitar at 50 kB, 10,350 sketch Gaussians and 2 patch); not with ``target_psnr``.
    #: Retrained encodes (``preset_config(..., retrain=True)``) use
    #: :data:`RETRAINED_MAX_SKETCH_SHARE` instead.
    max_sketch_share: float | None = 0.1
    #: The rate-distortion search of the patch's precision (codebook shape and size per
    #: attribute) for a no-retrain ``target_size``, or with no target the preset's own bytes
    #: (``preset_config`` sets it, DECISIONS D-33): every Gaussian kept wherever some precision
    #: fits them all (None: off, the preset's precision and pruning).
    allocation: AllocationConfig | None = None
    #: Never drop a Gaussian (``--preset transparent``): a target size it cannot meet with every
    #: Gaussian kept is refused, naming the size it needs, rather than met by pruning.
    keep_all: bool = False

    def seeded(self) -> "EncoderConfig":
        """A copy whose stage configs carry ``seed``."""
        return dataclasses.replace(
            self,
            categorize=dataclasses.replace(self.categorize, random_state=self.seed),
            refine=dataclasses.replace(self.refine, random_state=self.seed),
        )

    def low_pass(self, dataset: bool) -> float:
        """The low-pass (px^2) of an encode retraining against a dataset's images (``dataset``)
        or against renders of its input: ``blur_variance`` when set, else by the targets."""
        if self.blur_variance is not None:
            return self.blur_variance
        return DATASET_BLUR_VARIANCE if dataset else VIEWER_BLUR_VARIANCE

    def render_settings(self, background: tuple[float, float, float],
                        dataset: bool = False) -> RenderSettings:
        """How training and judging render this scene, against a dataset's images or not
        (imported here: the renderer needs torch, and the configuration must not load it)."""
        from spcodec.imaging.render import RenderSettings

        return RenderSettings(background=background, antialiased=self.antialiased,
                              blur_variance=self.low_pass(dataset))

    def to_json(self) -> dict:
        """Plain JSON-ready settings (stored in the file's metadata and fingerprinting a
        checkpoint), without ``n_jobs``: the same settings on more workers make the same file."""
        settings = dataclasses.asdict(self)
        del settings["n_jobs"]
        return settings
