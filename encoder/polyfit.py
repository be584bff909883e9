"""Per-cluster polynomial models of position for sketch Gaussians (encoder side).

A sketch cluster stores, per attribute, float16 coefficients of a polynomial in the cluster's
normalized positions (spec section 6.3, :mod:`spcodec.polynomial`). This module turns the Gaussians
of one cluster into such models:

1. **Targets** (:func:`coded_targets`): the attributes in the coded domain of
   :mod:`spcodec.attributes` - log scales, unit quaternions sign-aligned within the cluster,
   activated opacity, SH DC and optionally SH rest.
2. **Frame** (:func:`cluster_frame`): center = bounding-box midpoint, half extent = half the box
   per axis, both float32 because that is what the cluster record stores, with a floor so a flat
   axis does not stretch noise to [-1, 1].
3. **Least squares for every degree at once**: one pass over the data accumulates the Gram
   matrix ``G = Phi^T Phi`` and ``B = Phi^T Y`` at the highest admissible degree. Because the
   monomial order is graded, the degree-d problem is the leading ``M(d) x M(d)`` block, and
   because the leading block of a Cholesky factor is the Cholesky factor of the leading block, a
   single factorization of ``G + ridge`` solves every degree (two triangular products each). The
   ridge keeps coefficients small: float16 punishes large cancelling coefficients far more than
   float64 does.
4. **float16-aware errors without touching the data again**: the squared error of *any* coefficient
   matrix ``C`` is ``y^T y - 2 C^T B + C^T G C`` column-wise, so the error of the float16-rounded
   coefficients of every degree costs O(M^2) per degree, not O(n M).
5. **Degree choice** (:func:`select_degrees`): per attribute, minimize
   ``w_a * nMSE_a(d) + lambda * bytes_a(d) / n`` (a rate-distortion Lagrangian in "normalized MSE
   per coefficient byte per Gaussian"). If that misses the cluster threshold tau_max although a
   costlier choice would meet it, lambda is lowered step by step until it does.
6. **Verification with the decoder's code** (:func:`decode_cluster`): the chosen float16 models are
   evaluated with :func:`spcodec.decoder.layers.evaluate_models` and written with
   :func:`~spcodec.decoder.layers.fill_cluster`, exactly as a decoder does (opacity clamp,
   quaternion normalization included); every error this module reports is measured on that output.

Error measures (see :class:`AttributeScales`):

* ``mse[a]`` - coded domain, the paper's ``1/n sum_i ||a_hat_i - a_i||^2`` (summed over the
  attribute's components).
* ``nmse[a]`` - normalized: ``mse[a]`` divided by the attribute's scene-wide robust variance summed
  over its components. Unitless; 1.0 means "an error as large as the spread of that attribute over
  the whole scene", so one threshold means the same for every attribute and every scene.
* ``mse_combined`` - ``sum_a w_a * nmse[a]`` over scale, rotation, opacity and colour (w_a = 0.25 in
  the paper). SH rest is reported but not part of it (the paper models colour as DC only).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.linalg

from spcodec.attributes import SketchAttribute, canonical_rotation, decode_rotation, encode_opacity
from spcodec.cloud import SH_REST_COUNTS, GaussianCloud, sh_degree_for_rest_count
from spcodec.decoder.layers import evaluate_models, fill_cluster
from spcodec.polynomial import MAX_DEGREE, features, monomial_count, normalize_positions

from .config import RefineConfig

COMBINED_ATTRIBUTES = (SketchAttribute.SCALE, SketchAttribute.ROTATION, SketchAttribute.OPACITY,
                       SketchAttribute.COLOR_DC)
"""The four attributes MSE_combined is made of, in the order of ``RefineConfig.weights``."""

ROBUST_SIGMA_PER_IQR = 1.0 / 1.3489795003921634
"""IQR -> standard deviation of a normal distribution; makes the robust spread a 'sigma'."""

_ROWS_PER_CHUNK = 1 << 15
_LAMBDA_STEPS = (1.0, 0.25, 0.0625, 0.015625, 0.00390625, 0.0)
"""Multipliers of lambda tried, in order, when the lambda-optimal degrees miss tau_max."""


# ------------------------------------------------------------------------------ normalization
@dataclass(frozen=True)
class AttributeScales:
    """Scene-wide robust spread of each attribute, the unit of the normalized errors.

    ``values[a]`` is the root mean square over the attribute's components of each component's
    robust standard deviation (IQR / 1.349), computed in the coded domain over the whole scene
    (rotations as unit quaternions with w >= 0). ``nmse = mse / (outputs * values[a]**2)`` is then
    "squared error over scene variance", like 1 - R^2 at scene level. Robust (IQR) rather than
    plain std because real scenes have heavy tails (huge background splats) that would inflate a
    plain std and make every error look small.
    """

    values: dict[SketchAttribute, float]

    @classmethod
    def unit(cls) -> "AttributeScales":
        """Scales of 1: normalized errors equal coded errors divided by the component count."""
        return cls({a: 1.0 for a in SketchAttribute})

    @classmethod
    def from_cloud(cls, cloud: GaussianCloud, sh_rest: bool = True,
                   floor: float = 1e-2) -> "AttributeScales":
        """Measure the scales on a whole scene. ``sh_rest=False`` skips the SH-rest scale (left at
        1), the costliest one, when it will not be used.

        ``floor`` (coded units) bounds each scale from below, for scenes in which an attribute
        barely varies (a straight line's rotation, SH rest all zero): without it float16 rounding
        alone (~2e-4 on a unit quaternion) would count as a huge normalized error. 0.01 is ~1% in
        size, ~1 degree of rotation, 0.01 of opacity, 0.003 of RGB: below what anyone would call
        scene spread, and far below every real scene's values (>= 0.04)."""
        coded = {
            SketchAttribute.SCALE: cloud.scales,
            SketchAttribute.ROTATION: canonical_rotation(cloud.quats),
            SketchAttribute.OPACITY: encode_opacity(cloud.opacities)[:, None],
            SketchAttribute.COLOR_DC: cloud.sh_dc,
        }
        if sh_rest and cloud.sh_rest.shape[1]:
            coded[SketchAttribute.SH_REST] = cloud.sh_rest.reshape(len(cloud), -1)
        values = {a: 1.0 for a in SketchAttribute}
        if len(cloud) == 0:
            return cls(values)
        for attr, data in coded.items():
            q1, q3 = np.percentile(np.asarray(data, np.float64), [25.0, 75.0], axis=0)
            sigma = (q3 - q1) * ROBUST_SIGMA_PER_IQR
            values[attr] = max(float(np.sqrt(np.mean(sigma ** 2))), floor)
        return cls(values)

    def variance(self, attribute: SketchAttribute, outputs: int) -> float:
        """Scene variance summed over an attribute's components: the nmse denominator."""
        return outputs * self.values[attribute] ** 2


# ------------------------------------------------------------------------------------ targets
def align_quaternions(quats: np.ndarray) -> np.ndarray:
    """Unit quaternions sign-aligned to the hemisphere of the cluster's dominant rotation.

    ``q`` and ``-q`` are the same rotation, so a model may fit either; what it cannot fit is a sign
    that flips between neighbours. The naive ``w >= 0`` rule flips wherever w crosses 0, which
    happens inside perfectly smooth clusters. Aligning every quaternion with the dominant
    eigenvector of ``sum q q^T`` (the rotation average of Markley et al.) moves the cut as far from
    the data as possible: it only lands inside a cluster whose rotations span more than 90 degrees
    of quaternion angle, which refinement then splits. The dominant vector's sign is fixed (largest
    component positive) so the result is deterministic.
    """
    q = decode_rotation(quats).astype(np.float64)
    if q.shape[0] == 0:
        return q
    _, vectors = np.linalg.eigh(q.T @ q)
    dominant = vectors[:, -1]
    if dominant[np.argmax(np.abs(dominant))] < 0:
        dominant = -dominant
    return np.where((q @ dominant)[:, None] < 0, -q, q)


def coded_targets(cloud: GaussianCloud, indices: np.ndarray | None = None,
                  sh_rest: bool = False) -> dict[SketchAttribute, np.ndarray]:
    """The attributes of a cluster in the coded domain, float64 (n, outputs) each.

    ``sh_rest`` adds the SH_REST target (coefficient-major then channel, as the decoder reshapes
    it); it is ignored for scenes of SH degree 0.
    """
    sub = cloud if indices is None else cloud.subset(np.asarray(indices))
    out = {
        SketchAttribute.SCALE: sub.scales.astype(np.float64),
        SketchAttribute.ROTATION: align_quaternions(sub.quats),
        SketchAttribute.OPACITY: encode_opacity(sub.opacities)[:, None],
        SketchAttribute.COLOR_DC: sub.sh_dc.astype(np.float64),
    }
    if sh_rest and sub.sh_rest.shape[1]:
        out[SketchAttribute.SH_REST] = sub.sh_rest.reshape(len(sub), -1).astype(np.float64)
    return out


# -------------------------------------------------------------------------------------- frame
@dataclass(frozen=True)
class Frame:
    """A cluster's normalization frame, as the cluster record stores it (float32)."""

    center: np.ndarray
    half_extent: np.ndarray

    def normalize(self, positions: np.ndarray) -> np.ndarray:
        """Normalized positions, with the decoder's own function."""
        return normalize_positions(positions, self.center, self.half_extent)


def cluster_frame(positions: np.ndarray, relative_floor: float) -> Frame:
    """Bounding-box frame with each half extent floored at ``relative_floor`` times the largest.

    The floor matters for flat or line-like clusters: without it, an axis a few float32 ulps thick
    would be stretched to [-1, 1] and the fit would chase position noise along it. An absolute floor
    (a few float32 ulps of the coordinates) keeps a single point or coincident points valid.
    """
    p = np.asarray(positions, dtype=np.float64)
    lo, hi = p.min(axis=0), p.max(axis=0)
    center = ((lo + hi) / 2).astype(np.float32)
    half = (hi - lo) / 2
    absolute = 1e-6 * (1.0 + float(np.abs(p).max()))
    half = np.maximum(half, max(relative_floor * float(half.max()), absolute))
    half32 = half.astype(np.float32)
    return Frame(center, np.maximum(half32, np.float32(absolute)))


# ------------------------------------------------------------------------------ fit products
@dataclass
class ClusterFit:
    """The models of one cluster and what they cost and achieve.

    Errors are measured on the decoder's output for these exact float16 models at the positions the
    fit was given (see the module docstring for the three error measures).
    """

    frame: Frame
    models: dict[SketchAttribute, np.ndarray]
    """float16 (M(d), outputs) per attribute; SH_REST only when modelled."""
    degrees: dict[SketchAttribute, int]
    mse: dict[SketchAttribute, float]
    nmse: dict[SketchAttribute, float]
    mse_combined: float
    point_count: int
    notes: dict[str, float] = field(default_factory=dict)
    """Diagnostics: predicted (Gram-based) combined error, lambda multiplier used."""

    def coefficient_bytes(self) -> int:
        """Bytes the coefficients take in the file ([R-44]): 2 per float16."""
        return int(sum(2 * c.size for c in self.models.values()))


@dataclass
class _Moments:
    """Sufficient statistics of a least-squares problem at one maximum degree."""

    gram: np.ndarray
    cross: np.ndarray
    sq: np.ndarray
    n: int


def max_admissible_degree(n: int, config: RefineConfig, cap: int | None = None) -> int:
    """The highest degree with at least ``min_points_per_coefficient`` points per coefficient.

    Fewer points than that would make the model cost more bytes per Gaussian than a codebook index
    and the fit merely interpolate; degree 0 (the mean) is always allowed.
    """
    top = min(config.max_degree if cap is None else cap, MAX_DEGREE)
    best = 0
    for d in range(top + 1):
        if monomial_count(d) * config.min_points_per_coefficient <= n:
            best = d
    return best


def _moments(x: np.ndarray, y: np.ndarray, degree: int) -> _Moments:
    """Accumulate ``Phi^T Phi``, ``Phi^T Y`` and column sums of ``Y^2`` in bounded-memory chunks."""
    m = monomial_count(degree)
    gram = np.zeros((m, m))
    cross = np.zeros((m, y.shape[1]))
    for start in range(0, x.shape[0], _ROWS_PER_CHUNK):
        stop = start + _ROWS_PER_CHUNK
        phi = features(x[start:stop], degree)
        gram += phi.T @ phi
        cross += phi.T @ y[start:stop]
    return _Moments(gram, cross, np.einsum("ij,ij->j", y, y), x.shape[0])


def _cholesky(gram: np.ndarray, ridge: float, n: int) -> np.ndarray:
    """Lower Cholesky factor of ``G + ridge * n * diag(0, 1, 1, ...)``; the ridge grows tenfold
    until the factorization succeeds (a numerically singular Gram matrix, e.g. coincident
    points)."""
    m = gram.shape[0]
    penalty = np.ones(m)
    penalty[0] = 0.0
    alpha = ridge * max(n, 1)
    scale = max(float(np.trace(gram)) / m, 1e-300)
    for _ in range(30):
        try:
            return scipy.linalg.cholesky(gram + np.diag(alpha * penalty), lower=True,
                                         check_finite=False)
        except np.linalg.LinAlgError:
            alpha = max(alpha * 10.0, 1e-12 * scale)
            penalty[0] = 1.0  # a constant column that is itself degenerate (n = 0) needs it too
    raise np.linalg.LinAlgError("Gram matrix could not be regularized")  # pragma: no cover


def _inverse_factor(chol: np.ndarray) -> np.ndarray:
    """Inverse of the lower Cholesky factor. Its leading blocks are the inverses of the factor's
    leading blocks (both are lower triangular), so one inversion serves every degree, and
    ``L^-1 B`` computed once holds every degree's forward substitution in its leading rows."""
    inverse, info = scipy.linalg.lapack.dtrtri(chol, lower=1)
    if info != 0:  # pragma: no cover - a successful Cholesky factor has a positive diagonal
        raise np.linalg.LinAlgError("singular Cholesky factor")
    return inverse


def _squared_errors(coeffs: np.ndarray, mom: _Moments) -> np.ndarray:
    """Per-column sum of squared residuals of ``Phi[:, :m] @ coeffs``, from the moments alone."""
    m = coeffs.shape[0]
    fit = np.einsum("ij,ij->j", coeffs, mom.gram[:m, :m] @ coeffs)
    sse = mom.sq - 2.0 * np.einsum("ij,ij->j", coeffs, mom.cross[:m]) + fit
    return np.maximum(sse, 0.0)


def _column_slices(attributes: dict[SketchAttribute, np.ndarray]) -> dict[SketchAttribute, slice]:
    """Where each attribute's outputs sit in the stacked target matrix."""
    out, start = {}, 0
    for attr in sorted(attributes):
        width = attributes[attr].shape[1]
        out[attr] = slice(start, start + width)
        start += width
    return out


# ------------------------------------------------------------------------------ degree choice
@dataclass
class DegreeTable:
    """Candidate models of every degree and their predicted normalized errors."""

    coefficients: list[np.ndarray]
    """float16 (M(d), all outputs) for d = 0..top (may hold inf where float16 overflowed; such a
    degree's errors are inf, so it is never chosen)."""
    nmse: dict[SketchAttribute, np.ndarray]
    """Predicted normalized MSE per attribute and degree (inf where a degree is unusable)."""
    n: int


def degree_table(x: np.ndarray, attributes: dict[SketchAttribute, np.ndarray],
                 config: RefineConfig, scales: AttributeScales) -> DegreeTable:
    """Fit every admissible degree, round to float16 and predict each attribute's error."""
    n = x.shape[0]
    slices = _column_slices(attributes)
    y = np.concatenate([attributes[a] for a in sorted(attributes)], axis=1)
    top = max_admissible_degree(n, config)
    mom = _moments(x, y, top)
    inverse = _inverse_factor(_cholesky(mom.gram, config.ridge, n))
    forward = inverse @ mom.cross
    coefficients: list[np.ndarray] = []
    nmse = {a: np.full(top + 1, np.inf) for a in attributes}
    for d in range(top + 1):
        m = monomial_count(d)
        c16 = (inverse[:m, :m].T @ forward[:m]).astype(np.float16)
        coefficients.append(c16)
        sse = _squared_errors(c16.astype(np.float64), mom)
        for attr, cols in slices.items():
            if np.isfinite(c16[:, cols]).all():
                denom = n * scales.variance(attr, attributes[attr].shape[1])
                nmse[attr][d] = float(sse[cols].sum()) / max(denom, 1e-300)
    return DegreeTable(coefficients, nmse, n)


def _weight(attr: SketchAttribute, config: RefineConfig) -> float:
    if attr is SketchAttribute.SH_REST:
        return config.sh_rest_weight
    return config.weights[COMBINED_ATTRIBUTES.index(attr)]


def _degree_bytes(outputs: int, degree: np.ndarray) -> np.ndarray:
    """Coefficient bytes of models of the given degrees (vectorized [R-44])."""
    return 2 * outputs * (degree + 1) * (degree + 2) * (degree + 3) // 6


def _choose(table: DegreeTable, attributes: dict[SketchAttribute, np.ndarray],
            config: RefineConfig, lam: float) -> dict[SketchAttribute, int]:
    """Per attribute, the degree minimizing ``w * nmse + lam * bytes / n`` (ties: lower degree)."""
    chosen = {}
    for attr, errors in table.nmse.items():
        cap = config.max_degree if attr is not SketchAttribute.SH_REST else config.sh_rest_degree
        hi = min(cap, len(errors) - 1)
        lo = min(config.min_degree, hi)  # an SH-rest cap below min_degree wins
        degrees = np.arange(lo, hi + 1)
        bytes_per_point = _degree_bytes(attributes[attr].shape[1], degrees) / table.n
        cost = _weight(attr, config) * errors[lo:hi + 1] + lam * bytes_per_point
        chosen[attr] = int(lo + np.argmin(cost))
    return chosen


def _predicted_combined(table: DegreeTable, degrees: dict[SketchAttribute, int],
                        config: RefineConfig) -> float:
    return float(sum(config.weights[i] * table.nmse[a][degrees[a]]
                     for i, a in enumerate(COMBINED_ATTRIBUTES)))


def select_degrees(table: DegreeTable, attributes: dict[SketchAttribute, np.ndarray],
                   config: RefineConfig) -> tuple[dict[SketchAttribute, int], float]:
    """Lambda-optimal degrees, lowering lambda only as far as needed to meet tau_max.

    Returns the degrees and the lambda multiplier used. When even lambda = 0 misses tau_max the
    lambda-optimal choice is returned unchanged: the cluster fails either way, and refinement
    splits it on the residuals of a model that is not needlessly expensive.
    """
    first = _choose(table, attributes, config, config.degree_lambda)
    if _predicted_combined(table, first, config) <= config.tau_max:
        return first, 1.0
    if _predicted_combined(table, _choose(table, attributes, config, 0.0), config) > \
            config.tau_max:
        return first, 1.0
    for step in _LAMBDA_STEPS[1:]:
        degrees = _choose(table, attributes, config, config.degree_lambda * step)
        if _predicted_combined(table, degrees, config) <= config.tau_max:
            return degrees, step
    return first, 1.0  # pragma: no cover - the last step is lambda = 0, checked above


# ------------------------------------------------------------------------------ decode + errors
def decode_cluster(frame: Frame, models: dict[SketchAttribute, np.ndarray], positions: np.ndarray
                   ) -> dict[SketchAttribute, np.ndarray]:
    """What a decoder produces for these models, mapped back to the coded domain (float64).

    Runs the decoder's :func:`evaluate_models` and :func:`fill_cluster` into a scratch cloud, then
    reads the result back as log scales, unit quaternions, activated opacity, DC and SH rest, so the
    comparison with the targets includes the opacity clamp and the quaternion normalization.
    """
    n = positions.shape[0]
    rest = models.get(SketchAttribute.SH_REST)
    sh_degree = 0 if rest is None else sh_degree_for_rest_count(rest.shape[1] // 3)
    values = evaluate_models(frame.normalize(positions), dict(models))
    scratch = GaussianCloud.zeros(n, sh_degree)
    fill_cluster(scratch, slice(0, n), values, sh_degree)
    out = {
        SketchAttribute.SCALE: scratch.scales.astype(np.float64),
        SketchAttribute.ROTATION: scratch.quats.astype(np.float64),
        SketchAttribute.OPACITY: encode_opacity(scratch.opacities)[:, None],
        SketchAttribute.COLOR_DC: scratch.sh_dc.astype(np.float64),
    }
    if rest is not None:
        out[SketchAttribute.SH_REST] = scratch.sh_rest.reshape(n, -1).astype(np.float64)
    return out


def residuals(decoded: dict[SketchAttribute, np.ndarray],
              attributes: dict[SketchAttribute, np.ndarray]) -> dict[SketchAttribute, np.ndarray]:
    """Decoded minus target per attribute; rotations compared up to sign (q and -q are one
    rotation, so a decoded quaternion on the far side of the sphere is not an error)."""
    out = {}
    for attr, target in attributes.items():
        if attr not in decoded:
            continue
        value = decoded[attr]
        if attr is SketchAttribute.ROTATION:
            flip = np.einsum("ij,ij->i", value, target) < 0
            value = np.where(flip[:, None], -value, value)
        out[attr] = value - target
    return out


def attribute_errors(res: dict[SketchAttribute, np.ndarray], scales: AttributeScales,
                     weights: tuple[float, float, float, float]
                     ) -> tuple[dict[SketchAttribute, float], dict[SketchAttribute, float], float]:
    """(coded MSE, normalized MSE, MSE_combined) from residuals (module docstring)."""
    mse, nmse = {}, {}
    for attr, r in res.items():
        n = max(r.shape[0], 1)
        mse[attr] = float(np.einsum("ij,ij->", r, r)) / n
        nmse[attr] = mse[attr] / max(scales.variance(attr, r.shape[1]), 1e-300)
    combined = float(sum(w * nmse[a] for w, a in zip(weights, COMBINED_ATTRIBUTES)))
    return mse, nmse, combined


def models_for(table: DegreeTable, attributes: dict[SketchAttribute, np.ndarray],
               degrees: dict[SketchAttribute, int]) -> dict[SketchAttribute, np.ndarray]:
    """Cut each attribute's float16 model of its chosen degree out of the stacked solution."""
    slices = _column_slices(attributes)
    return {a: np.ascontiguousarray(table.coefficients[d][:, slices[a]])
            for a, d in degrees.items()}


# ------------------------------------------------------------------------------------- entry
def fit_cluster_detailed(positions: np.ndarray, attributes: dict[SketchAttribute, np.ndarray],
                         config: RefineConfig, scales: AttributeScales | None = None
                         ) -> tuple[ClusterFit, dict[SketchAttribute, np.ndarray]]:
    """:func:`fit_cluster` that also returns the per-Gaussian residuals (decoded - target), which
    refinement needs for splitting and outlier removal."""
    scales = AttributeScales.unit() if scales is None else scales
    attributes = _checked(positions, attributes, config)
    frame = cluster_frame(positions, config.frame_floor)
    x = frame.normalize(positions)
    table = degree_table(x, attributes, config, scales)
    degrees, step = select_degrees(table, attributes, config)
    models = models_for(table, attributes, degrees)
    res = residuals(decode_cluster(frame, models, positions), attributes)
    mse, nmse, combined = attribute_errors(res, scales, config.weights)
    fit = ClusterFit(frame, models, degrees, mse, nmse, combined, int(positions.shape[0]),
                     {"predicted_combined": _predicted_combined(table, degrees, config),
                      "lambda_multiplier": step})
    return fit, res


def fit_cluster(positions: np.ndarray, attributes: dict[SketchAttribute, np.ndarray],
                config: RefineConfig, scales: AttributeScales | None = None) -> ClusterFit:
    """Fit float16 polynomial models of position for one cluster and measure them as decoded.

    ``positions`` (n, 3) are the positions the decoder will see (Draco-decoded in the final
    encoding); ``attributes`` the coded-domain targets (:func:`coded_targets`), row-aligned with
    them. SH_REST is modelled when present in ``attributes`` and ``config.sh_rest_degree`` is not
    None. ``scales`` defines the normalized errors (unit scales when omitted).
    """
    return fit_cluster_detailed(positions, attributes, config, scales)[0]


def remeasure(fit: ClusterFit, positions: np.ndarray,
              attributes: dict[SketchAttribute, np.ndarray], config: RefineConfig,
              scales: AttributeScales | None = None) -> ClusterFit:
    """The same frame and models, with errors measured (decoder code) at other positions.

    The frame needs no change: the format only asks for a positive half extent, and positions a
    little outside [-1, 1] (Draco rounding, or a subset's box) evaluate the same polynomials.
    """
    scales = AttributeScales.unit() if scales is None else scales
    attributes = _checked(positions, attributes, config)
    res = residuals(decode_cluster(fit.frame, fit.models, positions), attributes)
    mse, nmse, combined = attribute_errors(res, scales, config.weights)
    return ClusterFit(fit.frame, fit.models, fit.degrees, mse, nmse, combined,
                      int(positions.shape[0]), dict(fit.notes))


def refit_or_keep(fit: ClusterFit, positions: np.ndarray,
                  attributes: dict[SketchAttribute, np.ndarray], config: RefineConfig,
                  scales: AttributeScales | None = None) -> ClusterFit:
    """Models for a cluster whose positions or membership changed since ``fit`` was made.

    Use it after IQR removal and, in the final encoding, with the Draco-decoded positions (and the
    attributes permuted to Draco's point order). A fresh fit is preferred when it meets tau_max
    (new frame, degrees chosen by the cost for these points); otherwise the given models are kept
    when, re-measured here, they meet it: a fresh fit can miss where the old one did not, because
    fewer points admit lower degrees (``min_points_per_coefficient``). When neither meets tau_max
    the one with the lower MSE_combined is returned and the caller decides.
    """
    refit = fit_cluster(positions, attributes, config, scales)
    if refit.mse_combined <= config.tau_max:
        return refit
    old = remeasure(fit, positions, attributes, config, scales)
    if old.mse_combined <= config.tau_max or old.mse_combined < refit.mse_combined:
        return old
    return refit


def _checked(positions: np.ndarray, attributes: dict[SketchAttribute, np.ndarray],
             config: RefineConfig) -> dict[SketchAttribute, np.ndarray]:
    """Validate shapes; drop SH_REST when the configuration does not model it."""
    n = positions.shape[0]
    if positions.ndim != 2 or positions.shape[1] != 3 or n == 0:
        raise ValueError(f"positions must be a non-empty (n, 3) array, got {positions.shape}")
    missing = [a.name for a in COMBINED_ATTRIBUTES if a not in attributes]
    if missing:
        raise ValueError(f"missing targets for {', '.join(missing)}")
    out = {}
    for attr, value in attributes.items():
        value = np.asarray(value, dtype=np.float64)
        if attr is SketchAttribute.SH_REST and (config.sh_rest_degree is None
                                                or value.shape[-1] == 0):
            continue
        if value.ndim != 2 or value.shape[0] != n:
            raise ValueError(f"{attr.name} targets have shape {value.shape}, expected ({n}, k)")
        if attr is SketchAttribute.SH_REST:
            if value.shape[1] % 3 or value.shape[1] // 3 not in SH_REST_COUNTS.values():
                raise ValueError(f"SH_REST targets have {value.shape[1]} columns")
        elif value.shape[1] != attr.outputs(0):
            raise ValueError(f"{attr.name} targets have {value.shape[1]} columns")
        if not np.isfinite(value).all():
            raise ValueError(f"{attr.name} targets are not finite")
        out[attr] = value
    return out
