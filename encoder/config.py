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
    component, which the polynomial models downstream could not fit. On fourth_st (131k) they
    cluster 32.6 % into 280 clusters, the largest 4.3 % of the scene; one step tighter on any
    threshold (eps_s_factor 1.0, eps_d 0.025, eps_c 0.05, min_samples 10) drops the clustered
    share to 10-15 %, one step looser (2.0, 0.1, 0.15, 3) grows the largest cluster to 10-31 %,
    and all three eps loosened merge 81 % of the scene into a single cluster. Biker reacts the
    same way, more mildly (54 % clustered, largest 2.9 %). Synthetic curves (make_scene, seeds
    0-2) are recovered with precision >= 0.999 and recall >= 0.96 at every one of those settings,
    so the synthetic scenes do not constrain the choice; the real ones do. Reproduce with
    ``python bench/bench_categorize.py --sweep``.
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
    44 coefficients), which a handful of Gaussians cannot amortize; on fourth_st, 5 instead of 20
    keeps 6x more clusters for only 9 percentage points more clustered Gaussians."""
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
    four attributes): 0.1 ~ an RMS error of 32% of each attribute's scene-wide spread. The paper
    gives no value. Real captures are noisy at the finest scale (on fourth_st a Gaussian's nearest
    neighbour differs in log scale / rotation by ~0.9 / 0.5 of the scene variance), so the sketch
    share depends strongly on tau (bench/bench_refine.py sweeps it); 0.1 is a fidelity-first
    default for the orchestrator to revisit with a rendering measurement."""

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
    cluster), so lambda only decides how far below tau to go. On biker, 2e-3 / 1e-2 / 5e-2 gave
    5.9 / 4.5 / 3.2 coefficient bytes per sketch Gaussian at about the same sketch share and
    median MSE_combined 0.060 / 0.067 / 0.079 (Draco positions cost ~3-4 B): 1e-2 is the middle."""
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
    paper's choice). Measured on fourth_st (tau_max 0.4, 12k sketch Gaussians, renders against the
    original at 8 views): no model 37.47 dB; degree <= 0 37.82 dB for +10 KB; <= 1 38.00 dB for
    +37 KB; <= 2 38.11 dB for +70 KB. Higher bands are not smooth in position, but a per-cluster
    constant or plane recovers half the loss at a better rate than any codebook knob, so <= 1."""
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
    whose size is off by 1%; with the floor and k = 1.5 nothing within ~0.3 (35% in size) of the
    quartiles is ever flagged. On make_scene curves without the floor, 10-30% of well-modelled
    Gaussians were flagged."""
    iqr_quantity: str = "residual"
    """What the fences are put on, per axis: 'residual' = decoded minus original log scale (how
    wrong the decoded size is), 'decoded' = the decoded log scale itself (the paper's literal
    wording). Default 'residual': on biker the 'decoded' rule moved 8.5% of sketch Gaussians whose
    scale error was no larger than the rest's (a smooth model's extremes are merely the cluster's
    periphery), while the paper's stated aim is to drop *badly modelled* (too long / too thin)
    Gaussians, which is what the residual rule selects, injected outliers included."""

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
    #: instead of one per cluster: about half the size on clusters of a few dozen Gaussians);
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
6 layers holds 4.8 % of the patch, of 8 layers 2 %."""


RETRAINED_PATCH_LAYERS = 6
"""Patch layers of a retrained encode (``--nested`` or not) unless ``--patch-layers`` says
otherwise; ``PatchConfig.layers`` (3) stays the no-retrain default. A streaming viewer gets a
prefix at 10, 15, 22, 32, 46 and 68 % of the bytes instead of 10, 17 and 33 %, each about as good
as the three-layer file's prefix near its size, and the full file keeps its picture: guitar at a
quarter of SPZ's bytes, PlayCanvas orbit / close 42.68 / 37.07 dB at 360,070 B against 42.71 /
37.03 at 355,651 B (a Draco cloud and a zlib stream more per layer; docs/RESULTS.md 15.2, 15.3)."""


RETRAINED_MAX_SKETCH_SHARE = 0.025
"""``EncoderConfig.max_sketch_share`` of a retrained encode (``preset_config(..., retrain=True)``).
Retraining fills the room with patch Gaussians that serve the picture better than the sketch's
polynomial models, and a small sketch moves every layer prefix earlier: guitar at a quarter of
SPZ's bytes, 3000 steps, PlayCanvas orbit / close, the file 42.93 / 37.23 dB against 42.68 /
37.07 with a tenth, the first picture at 2.6 % of the bytes instead of 9.5 %, each later prefix
15-24 kB earlier at the same picture; donut +0.21 / +0.23 dB, biker -0.04 / +0.05, kacytran
0 / -0.48 (its fortieth holds no cluster; docs/RESULTS.md 15.4, 13.13). ``--no-retrain`` keeps
``max_sketch_share``'s tenth."""


VIEWER_BLUR_VARIANCE = 0.075
"""The low-pass the PlayCanvas engine draws with (it adds 0.3 in half-pixel units: 0.075 px^2,
``../shared/tools/viewer-render/README.md``), and the encoder's default. A larger one (INRIA's 0.3)
hides in training exactly the fine texture that pruning and distillation lose, which a viewer then
shows: at a quarter of SPZ's bytes, 1000 steps, PlayCanvas orbit / close-up went from 0.3 to 0.075
px^2 guitar +0.1 / +0.8 dB, fourth_st +0.9 / +0.9, donut +0.2 / +0.1 (docs/RESULTS.md 13.9)."""

DATASET_BLUR_VARIANCE = 0.3
"""The low-pass of an encode retraining against a dataset's images: INRIA's, the one a model
trained on those images was made with and that test PSNR renders with. lego (nerf_synthetic,
66,731 Gaussians trained at 0.3): the model itself scores 31.59 dB on its test images at 0.3 and
26.47 at the viewer's 0.075; its patch pruned to a quarter and retrained at 0.3 scores 31.64 dB,
retrained at 0.075 27.24 (both judged at 0.3; docs/RESULTS.md 13.18). The file's report judges
at the low-pass it trained with, so the two never disagree."""

TARGET_GROUPS_PER_ENTRY = 32
"""``PatchConfig.groups_per_entry`` under ``--target-size``, where bytes the codebooks leave go to
more Gaussians. kacytran (SH 3) at a quarter of SPZ's bytes, 1000 steps, PlayCanvas orbit / close:
36.76 / 33.43 dB at 47,016 B with 256 entries per codebook (25 kB of codebooks, 1,173 patch
Gaussians), 38.07 / 35.42 dB at 43,731 B with this rule (7.8 kB, 2,336 Gaussians); docs/RESULTS.md
13.8. Scenes whose patch keeps more than 8,192 Gaussians keep 256 entries for every attribute."""


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
grid. At 16 bits positions were 30-40 % of a patch at a quarter of SPZ's size (32-40 bits per
Gaussian); at 12 bits 19-27, and the bytes saved keep 10-18 % more Gaussians: up to +1.3 dB
(donut) in PlayCanvas, on no shared scene a loss at either framing (docs/RESULTS.md 13.10)."""


@dataclass
class PatchConfig:
    """Parameters of the patch encoder; defaults follow the paper unless a comment says why not."""

    #: Entries per codebook (the paper and Reduced-3DGS: 256, i.e. one-byte indices), at most.
    codebook_size: int = 256
    #: Fewer entries for few Gaussians: a codebook gets at most one entry per this many of the
    #: groups it codes (and at least ``min_codebook_entries``); None: always ``codebook_size``.
    #: At a small target the fixed 256 entries cost more than the Gaussians they serve: kacytran
    #: (SH 3) at a quarter of SPZ's bytes kept 1,173 patch Gaussians beside 25 kB of codebooks,
    #: 52 % of the file. See :func:`codebook_entries`.
    groups_per_entry: float | None = None
    #: The floor of the rule above.
    min_codebook_entries: int = 16
    #: Apply the rule above as if this many Gaussians were quantized (None: as many as are).
    #: Rate control fixes it at its planned count before retraining, so the codebooks it sized
    #: the file with are the ones written even when the retrained patch ends with fewer
    #: Gaussians (without it kacytran's SPZ/4 file ended 6.2 % under its target).
    codebooks_sized_for: int | None = None
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
    #: Entries per codebook for some attributes (by name), at most ``codebook_size`` and the
    #: rule above; the rate-distortion search (encoder/allocation.py) sets them. None: none.
    entry_counts: dict[str, int] | None = None
    #: How positions are stored: "draco" (order-preserving Draco, the smallest), "quant16" (16-bit
    #: fixed point, delta-coded), "float16" (the paper's) or "float32" (lossless).
    position_mode: str = "draco"
    #: For draco and quant16: bits of precision over the layer's bounding box (quant16: <= 16).
    #: None: :data:`DEFAULT_POSITION_BITS`, except for a retrained patch, where the encoder takes
    #: :data:`RETRAINED_POSITION_BITS` over the scene's robust extent (see that constant).
    position_bits: int | None = None
    #: Number of patch layers (>= 1).
    layers: int = 3
    #: Share of the patch Gaussians in each layer, most important first (renormalized). The first
    #: layer (7 %, with the codebooks) completes within 10 % of the file, a streaming viewer's
    #: first picture when there is no sketch; the first two (23.5 %) end before 30 % of the file
    #: with a sketch layer of 6 % (guitar). A fourth layer costs about 1 % in size (each layer
    #: codes its positions on its own): docs/RESULTS.md, section 7. Other layer counts on the
    #: command line take :func:`geometric_fractions` (each layer 1.5 times the one before).
    layer_fractions: tuple[float, ...] = (0.07, 0.165, 0.765)
    #: Codebook trainer (encoder/kmeans.py): "sampled" (exact in one dimension, weight-proportional
    #: samples for vectors) or "exhaustive" (the previous scikit-learn k-means++ on uniform
    #: samples: 5-20x slower for codebooks as good; kept for comparisons).
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
    #: "footprint", opacity times footprint area (no rendering, but blind to occlusion).
    importance: str = "blend"
    #: Views (training split, never eval's) and their (width, height) for "blend".
    importance_views: int = 6
    importance_resolution: tuple[int, int] = (256, 192)

    @property
    def stored_position_bits(self) -> int:
        """The position precision written: ``position_bits``, or its default when unset."""
        return DEFAULT_POSITION_BITS if self.position_bits is None else self.position_bits


@dataclass
class AllocationConfig:
    """How the rate-distortion search of the patch's precision measures its options
    (encoder/allocation.py; recorded in the file's metadata). It runs for a no-retrain
    ``target_size`` that the preset's own file does not already fill (encoder/sizing.py)."""

    #: Patch Gaussians the options are measured on (a uniform sample, seeded).
    sample: int = 16_384
    #: Entry counts tried for every entry dimension (the format allows 1..256).
    entry_counts: tuple[int, ...] = (256, 128, 64, 32, 16)
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
    #: preset's grid.
    position_bits: tuple[int, ...] = (12, 13, 14, 15, 16)

    def framing_weights(self) -> dict[str, float]:
        """Each framing's weight in the distortion, by the names the search's framings carry."""
        return {"orbit": 1.0, "close": self.close_weight}

    def to_json(self) -> dict:
        return dataclasses.asdict(self)


@dataclass
class RetrainConfig:
    """Settings of the retraining stage (stored in the file's metadata)."""

    #: Keep ``1 / patch_downsample`` of the patch Gaussians (the paper sweeps 1..20; 1 = keep all).
    patch_downsample: float = 4.0
    #: How survivors are chosen: "importance" (largest blend weight over the training views),
    #: "sampled" (random in proportion to it) or "uniform" (random, the paper's). Importance
    #: stays the default: sampled won 1.7 / 1.9 dB on donut at SPZ/8, tied on guitar, fourth_st
    #: and biker and lost up to 0.9 on kacytran; uniform lost 3.2 on kacytran (RESULTS 13.19).
    prune: PruneMethod = "importance"
    #: Optimizer steps of the retraining, one training view each.
    iterations: int = 3000
    #: Adam rates per attribute (the 3DGS defaults; positions scaled by the camera extent).
    rates: LearningRates = field(default_factory=LearningRates)
    #: Distillation: how many training views are sampled around the original, and their side.
    #: 96 whole views and 96 close crops rather than 48 and 48: with 48 of each, 3000 steps
    #: learn the views rather than the scene (biker at SPZ/4 scored 0.2-0.3 dB less in
    #: PlayCanvas than at 1000 steps); twice the views gained biker +0.4 / +0.9 dB and fourth_st
    #: +0.2 / +0.3 (orbit / close) for 0.5-1.5 more minutes of target rendering, the step cost
    #: unchanged (docs/RESULTS.md 13.11).
    views: int = 96
    resolution: int = 400
    #: Distillation close-ups: this many more training views from ``close_distance`` times as
    #: far (0.5: half way to the scene), ``close_resolution`` pixels across, each trained as a
    #: crop of ``close_crop`` pixels around a point of the scene (a crop costs its pixels, not
    #: the frame's). Whole-scene views leave fine texture below a pixel: trained on them alone,
    #: guitar's close-up lost 2.2 dB more in PlayCanvas (docs/RESULTS.md section 13). 0: none.
    close_views: int = 96
    close_distance: float = 0.5
    #: Close frames of 400 pixels (at the 50-degree field of view), cut into 256-pixel crops:
    #: at 800 each crop framed a third of the view's width and its pixels were 0.64 of a pixel
    #: of a viewer's 512-pixel close-up, detail no framing shows; at 512 every scene at SPZ/4
    #: gained at both framings (biker +1.8 / +1.8 dB in PlayCanvas), and at 400 (two thirds
    #: of the width, pixels between the viewer's orbit and close-up) all five gained again
    #: (+0.2 to +0.9 / +0.05 to +0.5 dB over 512): docs/RESULTS.md 13.15. A crop costs the
    #: same pixels at any of them.
    close_resolution: int = 400
    close_crop: int = 256
    #: Dataset mode: image downscale factor, and at most this many training views (None: all of
    #: the training split).
    downscale: int = 1
    max_views: int | None = None
    #: Steps of the quantization-aware finish (0: off) and when its one re-assignment happens.
    finish_iterations: int = 600
    reassign_at: float = 0.5
    #: Training views (evenly spread) over which blend weights rank Gaussians for pruning/layers.
    importance_views: int = 16
    #: Quantization-aware retraining: from this share of ``iterations`` on, the patch trains
    #: through its codebooks (each attribute snapped to its nearest entry and positions to the
    #: stored grid, gradients passed straight through; encoder/quantaware.py). Under rate control
    #: the count is fitted to the target at that step, while steps remain to adapt. 1.0: train
    #: unquantized and quantize afterwards.
    snap_start: float = 0.3
    #: Steps between moves of the snapped entries to their groups' weighted centroids.
    snap_refresh_every: int = 100
    #: Snap only when quantizing at ``snap_start`` costs the training views at least this many
    #: dB; below it, training goes on freely and the finish tunes the codebooks. Snapping gained
    #: 0.3 dB in PlayCanvas on fourth_st (SH 3, 4.4 dB lost to codebooks) and lost 0.3 dB on
    #: guitar (SH 0, 1.4 dB lost): docs/RESULTS.md section 13.
    snap_min_loss: float = 2.5
    #: Nested retraining (encoder/nested.py): the patch layers are fixed before training and
    #: every step trains one layer prefix (sketch and layers 1..k), the whole file at
    #: ``nested_full_share`` of the steps, so that every prefix is a trained scene for a
    #: progressive viewer (plain retraining optimizes the full file only). Snapping is off.
    nested: bool = False
    #: Three quarters is the knee of guitar's trade-off at 3000 steps (docs/RESULTS.md 15.2):
    #: against a half the full file gains 0.9 dB in PlayCanvas for 0.2-1.2 dB of the prefixes;
    #: at seven eighths the full file is within 0.5 dB of a plain file of its size, but its
    #: prefixes are no better than the plain file's own at the same bytes.
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
    #: Section codec: "zlib" (the paper's; every decoder has it) or "zstd" (optional, faster).
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
    #: allows, encoder/ratecontrol.py) by choosing how many patch
    #: Gaussians survive pruning (None: the size follows from the settings). ``--target-size``
    #: also sets ``patch.groups_per_entry`` to :data:`TARGET_GROUPS_PER_ENTRY`;
    #: ``encoder.presets.sized`` sets both for a library caller.
    target_size: int | None = None
    #: Quality control: the smallest file whose close-up PSNR (``spcodec eval``'s views at half
    #: their distance) reaches this many dB, again by choosing how many patch Gaussians survive
    #: (encoder/qualitycontrol.py; None: off). Exclusive with ``target_size``.
    target_psnr: float | None = None
    #: The sketch layer, a streaming viewer's first picture, ends within this share of the file:
    #: when it would not, the sketch clusters of least importance per Gaussian go to the patch
    #: (None: no limit). With retraining the share is judged before training, on the file the
    #: prune factor makes; with ``target_size``, of the target (left alone, a small target was
    #: all sketch: guitar at 50 kB, 10,350 sketch Gaussians and 2 patch); not with ``target_psnr``.
    #: Retrained encodes (``preset_config(..., retrain=True)``) use
    #: :data:`RETRAINED_MAX_SKETCH_SHARE` instead.
    max_sketch_share: float | None = 0.1
    #: The rate-distortion search of the patch's precision (codebook shape and size per
    #: attribute) for a no-retrain ``target_size``: every Gaussian kept wherever some precision
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
