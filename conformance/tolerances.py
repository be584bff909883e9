"""Per-vector output tolerances, computed from the file by the spec's rule ([R-96]).

Patch rows are exact, save rotations and opacities (1 ulp). Sketch rows are evaluated polynomials:
another decoder may sum a model's terms in another order, so its coded value may differ from ours
by up to ``1e-6 * (1 + S)``, with ``S`` the sum of the absolute values of the model's terms at that
point. This module computes that bound for every sketch Gaussian and carries it through the
mappings of section 5: unchanged for scales, colours and SH rest, divided by the quaternion's norm
for rotations ([R-31]), multiplied by the logit's slope for opacities ([R-32]). The vector's
tolerance for a property group is the largest bound over its sketch rows.
"""

from __future__ import annotations

import math

import numpy as np

from spcodec.attributes import OPACITY_MIN, QUAT_MIN_NORM, SketchAttribute
from spcodec.codecs import gunzip, is_gzip
from spcodec.container import SH_REST_ABSENT
from spcodec.decoder.header import read_header
from spcodec.decoder.layers import load_layer, prepare_sketch_layer
from spcodec.limits import DEFAULT_LIMITS
from spcodec.polynomial import features, monomial_count, normalize_positions

from .manifest import EXACT, Tolerance

CODED_TOLERANCE = 1e-6
"""The relative part of the spec's bound on sketch coded values ([R-96])."""

ONE_ULP = Tolerance(0.0, 1)
PATCH = {"xyz": EXACT, "f_dc": EXACT, "f_rest": EXACT, "scale": EXACT, "rot": ONE_ULP,
         "opacity": ONE_ULP}
"""Patch rows: exact conversions, rotations and opacities within 1 ulp ([R-96])."""

_GROUP = {SketchAttribute.SCALE: "scale", SketchAttribute.COLOR_DC: "f_dc",
          SketchAttribute.SH_REST: "f_rest"}


class ThresholdError(ValueError):
    """A sketch coded value lies within the tolerance of a mapping's threshold, where the spec
    bounds nothing: a vector must not contain one."""


def tolerances(data: bytes, sketch_rows: int) -> dict[str, dict[str, Tolerance]]:
    """The tolerances of a file's decodes: sketch rows from its models, patch rows fixed."""
    sketch = sketch_tolerances(data) if sketch_rows else {g: EXACT for g in PATCH}
    return {"sketch": sketch, "patch": dict(PATCH)}


def sketch_tolerances(data: bytes) -> dict[str, Tolerance]:
    """Tolerances of the sketch rows of ``data`` (a valid layer 0 is assumed)."""
    values, slack = coded_bounds(data)
    out = {"xyz": EXACT}
    for attribute, group in _GROUP.items():
        bound = float(slack[attribute].max()) if attribute in slack and slack[attribute].size else 0.0
        out[group] = Tolerance(_ceil(bound), 1)
    out["rot"] = Tolerance(_ceil(_rotation_bound(values[SketchAttribute.ROTATION],
                                                 slack[SketchAttribute.ROTATION])), 1)
    out["opacity"] = Tolerance(_ceil(_opacity_bound(values[SketchAttribute.OPACITY][:, 0],
                                                    slack[SketchAttribute.OPACITY][:, 0])), 1)
    return out


def coded_bounds(data: bytes) -> tuple[dict, dict]:
    """Per sketch Gaussian and model output: the coded value and ``1e-6 * (1 + S)``."""
    inner = gunzip(data, DEFAULT_LIMITS.max_file_bytes).inner if is_gzip(data) else data
    header = read_header(inner, DEFAULT_LIMITS)
    plan = prepare_sketch_layer(load_layer(inner, header.layers[0], DEFAULT_LIMITS), header,
                                DEFAULT_LIMITS)
    records = plan.layout.records
    owner = np.repeat(np.arange(len(records)), records["point_count"].astype(np.int64))
    points = np.concatenate(plan.points)
    x = normalize_positions(points, records["center"][owner], records["half_extent"][owner])
    words = np.frombuffer(plan.coefficients, "<f2")
    degrees = records["degrees"].astype(np.int64)
    values, slack = {}, {}
    for attribute in SketchAttribute:
        outputs = attribute.outputs(plan.sh_degree)
        v, s = np.zeros((len(x), outputs)), np.zeros((len(x), outputs))
        for degree in np.unique(degrees[:, attribute]):
            if degree == SH_REST_ABSENT:
                continue
            rows = np.flatnonzero(degrees[owner, attribute] == degree)
            size = monomial_count(int(degree)) * outputs
            start = plan.layout.coefficient_offsets[owner[rows], attribute] // 2
            coeffs = words[start[:, None] + np.arange(size)].astype(np.float64)
            terms = features(x[rows], int(degree))[:, :, None] * \
                coeffs.reshape(len(rows), -1, outputs)
            v[rows] = terms.sum(axis=1)
            s[rows] = CODED_TOLERANCE * (1 + np.abs(terms).sum(axis=1))
        values[attribute], slack[attribute] = v, s
    return values, slack


def _rotation_bound(q: np.ndarray, slack: np.ndarray) -> float:
    """How far q / |q| can move when each component moves by its slack ([R-31])."""
    if not len(q):
        return 0.0
    norm = np.linalg.norm(q, axis=1)
    moved = np.linalg.norm(slack, axis=1)
    if np.any(norm - moved <= QUAT_MIN_NORM):
        raise ThresholdError("a coded sketch rotation lies within its tolerance of the identity "
                             "threshold of [R-31]")
    return float(np.max(2 * moved / (norm - moved)))


def _opacity_bound(a: np.ndarray, slack: np.ndarray) -> float:
    """How far logit(clamp(a)) can move when a moves by its slack ([R-32]): the slack times the
    logit's steepest slope over the clamped interval."""
    if not len(a):
        return 0.0
    lo = np.clip(a - slack, OPACITY_MIN, 1 - OPACITY_MIN)
    hi = np.clip(a + slack, OPACITY_MIN, 1 - OPACITY_MIN)

    def slope(v: np.ndarray) -> np.ndarray:
        return 1.0 / (v * (1.0 - v))
    return float(np.max(slack * np.maximum(slope(lo), slope(hi))))


def _ceil(value: float) -> float:
    """``value`` rounded up to three significant digits (short, stable numbers in the manifest)."""
    if value <= 0:
        return 0.0
    exponent = math.floor(math.log10(value)) - 2
    return float(f"{math.ceil(value / 10.0 ** exponent * (1 + 1e-12)) * 10.0 ** exponent:.3g}")
