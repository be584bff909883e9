"""Turning one layer's sections into Gaussians (spec decoding steps 6-9).

Every section is CRC-checked on its stored bytes before it reaches a decompressor, and inflated into
exactly its declared raw length; every count read from a payload is checked against the payload's
own length before an array is sized from it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from spcodec.attributes import (
    PatchAttribute,
    SketchAttribute,
    decode_opacity,
    decode_rotation,
)
from spcodec.cloud import SH_REST_COUNTS, GaussianCloud
from spcodec.codecs import crc32, decompress
from spcodec.container import SH_REST_ABSENT, SectionType
from spcodec.draco_io import decode_points
from spcodec.errors import ChecksumError, FormatError
from spcodec.limits import Limits
from spcodec.polynomial import features, monomial_count, normalize_positions
from spcodec.sections import (
    Codebook,
    IndexContext,
    PatchPositions,
    SketchLayout,
    parse_codebooks,
    parse_index_contexts,
    parse_indices,
    parse_positions,
    parse_sketch,
    read_coefficients,
)

from .header import Header, Layer, Section

_ROWS_PER_CHUNK = 1 << 15


def stored_bytes(data: bytes | memoryview, section: Section) -> memoryview:
    """A section's stored bytes, CRC-checked ([R-7])."""
    stored = memoryview(data)[section.offset:section.end]
    if len(stored) != section.stored_length:
        raise FormatError(f"section {section.index} ({section.type_name}) is cut short",
                          "truncated")
    if crc32(stored) != section.crc32:
        raise ChecksumError(f"section {section.index} ({section.type_name}) CRC-32 mismatch")
    return stored


def section_payload(data: bytes | memoryview, section: Section) -> bytes:
    """CRC-check and inflate one section ([R-7], [R-24])."""
    return decompress(section.codec, stored_bytes(data, section), section.raw_length)


Payloads = dict[int, bytes]
"""A layer's known sections, inflated, by section type."""


def load_layer(data: bytes | memoryview, layer: Layer, limits: Limits) -> Payloads:
    """Decoding step 7 for one layer, in the spec's order: reject unknown required sections,
    verify the CRC of *every* section (unknown optional ones included), then inflate the known
    ones ([R-7], [R-20]..[R-24]). So a CRC mismatch anywhere in the layer is reported before a
    decompression failure of another of its sections, and no parser sees unverified bytes."""
    for sec in layer.sections:
        if not sec.known and sec.required:
            raise FormatError(f"layer {layer.index} holds required section type 0x{sec.type:04X}, "
                              f"unknown to this decoder", "unknown-required-section")
    meta = layer.section(SectionType.METADATA)
    if meta is not None:
        limits.check("metadata length", meta.raw_length, limits.max_metadata_bytes)
    stored = [(sec, stored_bytes(data, sec)) for sec in layer.sections]
    # Metadata is inflated for integrity only: its content is ignorable ([R-70]).
    return {sec.type: decompress(sec.codec, raw, sec.raw_length) for sec, raw in stored
            if sec.known}


# ----------------------------------------------------------------------------- sketch layer
@dataclass
class SketchPlan:
    """Layer 0 parsed and validated, with its Draco points decoded: everything but evaluation.

    The output is allocated only from a plan, so its size comes from points that exist, not
    from a count that a header or cluster table merely claims.
    """

    layout: SketchLayout
    points: list[np.ndarray]
    """Decoded points of each Draco run, in run order."""
    coefficients: bytes
    sh_degree: int

    @property
    def gaussian_count(self) -> int:
        return int(sum(len(p) for p in self.points))


def prepare_sketch_layer(payloads: Payloads, header: Header, limits: Limits) -> SketchPlan:
    """Parse layer 0's loaded payloads and decode its Draco blobs ([R-40]..[R-47])."""
    table = payloads[SectionType.SKETCH_CLUSTERS]
    draco = payloads[SectionType.SKETCH_POSITIONS]
    coeffs = payloads[SectionType.SKETCH_COEFFICIENTS]
    sh = header.sh_degree
    layout = parse_sketch(table, len(draco), len(coeffs), header.layers[0].gaussian_count, sh,
                          limits)
    points = [decode_points(draco[run.start:run.stop], run.points, f"sketch Draco blob {b}")
              for b, run in enumerate(layout.runs)]
    return SketchPlan(layout, points, coeffs, sh)


MAX_NORMALIZED = 2.0
"""Largest |normalized coordinate| a sketch cluster may have ([R-42])."""

SMALL_CLUSTER = 32
"""Clusters of fewer points are evaluated together, and term by term (see fill_sketch_layer)."""
_BATCH_ROWS = 1 << 15
_BATCH_COEFFICIENTS = 1 << 21


def fill_sketch_layer(plan: SketchPlan, out: GaussianCloud) -> None:
    """Evaluate every cluster's models at its points and write the Gaussians into ``out``.

    A cluster of SMALL_CLUSTER points or more is evaluated on its own, one matrix product per
    model. Smaller clusters are evaluated together, by attribute and degree, with the sum taken
    term by term in monomial order: a loop over clusters costs ~50 us a cluster, and fuzzing
    showed a 1.4 KB file of 100 000 one-point clusters (identical records compress away, Draco
    stores identical points in a few bytes) taking 5.6 s; the limits admit 4 million clusters.
    :func:`evaluate_models` sums small clusters in the same order, so the encoder, which
    predicts the decoder's output with it, stays bit-exact.
    """
    counts = plan.layout.records["point_count"].astype(np.int64)
    starts = np.concatenate([[0], np.cumsum(counts)])
    points = np.concatenate(plan.points) if plan.points else np.zeros((0, 3), np.float32)
    out.means[:] = points
    for c in np.flatnonzero(counts >= SMALL_CLUSTER):
        rows = np.arange(starts[c], starts[c + 1])
        _fill_clusters(plan, np.array([c]), rows, points, out)
    small = np.flatnonzero(counts < SMALL_CLUSTER)
    for first in range(0, len(small), _BATCH_ROWS // SMALL_CLUSTER):
        batch = small[first:first + _BATCH_ROWS // SMALL_CLUSTER]
        _fill_clusters(plan, batch, _rows_of(batch, counts[batch], starts), points, out)


def _rows_of(clusters: np.ndarray, counts: np.ndarray, starts: np.ndarray) -> np.ndarray:
    """Output rows of the given clusters' Gaussians, cluster by cluster, without a Python loop."""
    before = np.concatenate([[0], np.cumsum(counts)[:-1]])
    return np.repeat(starts[clusters] - before, counts) + np.arange(int(counts.sum()))


def _fill_clusters(plan: SketchPlan, clusters: np.ndarray, rows: np.ndarray, points: np.ndarray,
                   out: GaussianCloud) -> None:
    """Evaluate and write the given clusters, whose Gaussians are ``rows`` in cluster order."""
    records = plan.layout.records[clusters]
    owner = np.repeat(np.arange(len(clusters)), records["point_count"].astype(np.int64))
    x = normalize_positions(points[rows], records["center"][owner],
                            records["half_extent"][owner])
    if len(x) and np.abs(x).max() > MAX_NORMALIZED:
        bad = int(clusters[owner[np.argmax(np.abs(x).max(axis=1))]])
        raise FormatError(f"cluster {bad}: a position lies outside twice its frame ([R-42])",
                          "bad-value")
    with np.errstate(over="ignore", invalid="ignore"):
        if len(clusters) == 1:
            c = int(clusters[0])
            values = evaluate_models(x, {a: read_coefficients(plan.coefficients, plan.layout, c, a,
                                                               plan.sh_degree)
                                         for a in SketchAttribute})
        else:
            values = _evaluate_together(plan, clusters, owner, x)
    check_model_values(values, clusters[owner])
    fill_cluster(out, rows, values, plan.sh_degree)


def _evaluate_together(plan: SketchPlan, clusters: np.ndarray, owner: np.ndarray,
                       x: np.ndarray) -> dict[SketchAttribute, np.ndarray]:
    """Every model of many small clusters, grouped by attribute and degree (float64 values)."""
    degrees = plan.layout.records["degrees"][clusters].astype(np.int64)
    values = {}
    for attr in SketchAttribute:
        present = degrees[:, attr] != SH_REST_ABSENT
        if not present.any():
            continue
        v = np.zeros((x.shape[0], attr.outputs(plan.sh_degree)))
        for d in np.unique(degrees[present, attr]):
            members = np.flatnonzero(degrees[:, attr] == d)
            size = monomial_count(int(d)) * v.shape[1]
            step = max(1, _BATCH_COEFFICIENTS // size)
            for first in range(0, len(members), step):
                _evaluate_members(plan, clusters, members[first:first + step], owner, x, attr,
                                  int(d), v)
        values[attr] = v
    return values


def _evaluate_members(plan: SketchPlan, clusters: np.ndarray, members: np.ndarray,
                      owner: np.ndarray, x: np.ndarray, attr: SketchAttribute, degree: int,
                      v: np.ndarray) -> None:
    """One attribute's models of degree ``degree`` for some clusters, into their rows of ``v``."""
    slot = np.full(len(clusters), -1)
    slot[members] = np.arange(len(members))
    local = slot[owner]
    idx = np.flatnonzero(local >= 0)
    coeffs = gather_coefficients(plan, clusters[members], attr, degree)
    v[idx] = sum_in_monomial_order(features(x[idx], degree), coeffs, local[idx])


def gather_coefficients(plan: SketchPlan, clusters: np.ndarray, attr: SketchAttribute,
                        degree: int) -> np.ndarray:
    """(clusters, M(d), outputs) float64 coefficient matrices of clusters sharing a degree."""
    shape = (monomial_count(degree), attr.outputs(plan.sh_degree))
    words = np.frombuffer(plan.coefficients, dtype="<f2")
    start = plan.layout.coefficient_offsets[clusters, attr] // 2
    coeffs = words[start[:, None] + np.arange(shape[0] * shape[1])].astype(np.float64)
    finite = np.isfinite(coeffs).all(axis=1)
    if not finite.all():
        cluster = int(clusters[np.argmin(finite)])
        raise FormatError(f"cluster {cluster} has a non-finite {attr.name} coefficient",
                          "bad-value")
    return coeffs.reshape(len(clusters), *shape)


def sum_in_monomial_order(phi: np.ndarray, coeffs: np.ndarray,
                          local: np.ndarray | None = None) -> np.ndarray:
    """``sum_m phi[:, m] * coeffs[m]`` in binary64, term by term in monomial order ([R-43]).

    ``coeffs`` is one (M, outputs) matrix, or a stack of them with ``local`` giving each row's
    matrix. Each output element is the same sequence of roundings however the rows are batched.
    """
    acc = np.zeros((phi.shape[0], coeffs.shape[-1]))
    for m in range(phi.shape[1]):
        acc += phi[:, m:m + 1] * (coeffs[m] if local is None else coeffs[local, m])
    return acc


_FLOAT32_MAX = float(np.finfo(np.float32).max)


def check_model_values(values: dict[SketchAttribute, np.ndarray], row_cluster: np.ndarray) -> None:
    """Refuse clusters whose models evaluate to values no float32 parameter can hold ([R-34]).

    Finite coefficients and frames can still overflow: a tiny half extent makes the normalized
    positions huge, and a degree-10 monomial of them is not finite in binary64. Rotations and
    opacities only need finite coded values (they are normalized or clamped); the other
    parameters are stored as they are, so they must also fit in binary32. ``row_cluster`` names
    each row's cluster, for the message.
    """
    for attribute, v in values.items():
        finite = np.isfinite(v).all(axis=1)
        if not finite.all():
            raise FormatError(f"cluster {int(row_cluster[np.argmin(finite)])}: the "
                              f"{attribute.name} model is not finite at its points", "bad-value")
        if attribute in (SketchAttribute.ROTATION, SketchAttribute.OPACITY) or not v.size:
            continue
        fits = (np.abs(v) <= _FLOAT32_MAX).all(axis=1)
        if not fits.all():
            raise FormatError(f"cluster {int(row_cluster[np.argmin(fits)])}: the "
                              f"{attribute.name} model overflows float32", "bad-value")


def evaluate_models(x: np.ndarray, models: dict[SketchAttribute, np.ndarray | None]
                    ) -> dict[SketchAttribute, np.ndarray]:
    """Evaluate every present model at normalized positions ``x`` sharing one feature matrix.

    Because the monomial order is graded, a model of degree d uses the first M(d) feature columns
    of the highest-degree matrix ([R-41], [R-43]). Results are float64 (n, outputs). ``x`` holds
    the whole cluster: one of fewer than SMALL_CLUSTER points is summed term by term, exactly as
    :func:`fill_sketch_layer` sums small clusters together.
    """
    present = {a: np.asarray(c, dtype=np.float64) for a, c in models.items() if c is not None}
    top = max(_degree(c) for c in present.values())
    out = {a: np.empty((x.shape[0], c.shape[1])) for a, c in present.items()}
    small = x.shape[0] < SMALL_CLUSTER  # summed as fill_sketch_layer sums small clusters
    for start in range(0, x.shape[0], _ROWS_PER_CHUNK):
        stop = min(start + _ROWS_PER_CHUNK, x.shape[0])
        phi = features(x[start:stop], top)
        for a, c in present.items():
            m = phi[:, :c.shape[0]]
            out[a][start:stop] = sum_in_monomial_order(m, c) if small else m @ c
    return out


def fill_cluster(out: GaussianCloud, rows: slice | np.ndarray,
                 values: dict[SketchAttribute, np.ndarray],
                 sh_degree: int) -> None:
    """Write evaluated models into the output arrays in the coded->parameter mapping ([R-30])."""
    out.scales[rows] = values[SketchAttribute.SCALE]
    out.quats[rows] = decode_rotation(values[SketchAttribute.ROTATION])
    out.opacities[rows] = decode_opacity(values[SketchAttribute.OPACITY][:, 0])
    out.sh_dc[rows] = values[SketchAttribute.COLOR_DC]
    rest = values.get(SketchAttribute.SH_REST)
    if rest is not None:
        out.sh_rest[rows] = rest.reshape(-1, SH_REST_COUNTS[sh_degree], 3)


def _degree(coeffs: np.ndarray) -> int:
    for d in range(11):
        if monomial_count(d) == coeffs.shape[0]:
            return d
    raise AssertionError("validated coefficient matrix has no degree")  # pragma: no cover


# ------------------------------------------------------------------------------ patch layers
def read_codebooks(payloads: Payloads, header: Header) -> list[Codebook]:
    """The codebooks carried by layer 1, from its loaded payloads ([R-50])."""
    return parse_codebooks(payloads[SectionType.PATCH_CODEBOOKS], header.sh_degree)


def read_index_contexts(payloads: Payloads, codebooks: list[Codebook]) -> list[IndexContext]:
    """The context records of layer 1 (spec 7.5), which serve every patch layer; none when the
    file has no PATCH_INDEX_CONTEXTS section."""
    raw = payloads.get(SectionType.PATCH_INDEX_CONTEXTS)
    return [] if raw is None else parse_index_contexts(raw, codebooks)


@dataclass
class PatchPlan:
    """A patch layer's positions and index columns, validated against their actual bytes."""

    index: int
    positions: PatchPositions
    columns: dict[PatchAttribute, np.ndarray]

    @property
    def gaussian_count(self) -> int:
        return len(self.positions)


def prepare_patch_layer(payloads: Payloads, header: Header, index: int,
                        codebooks: list[Codebook],
                        contexts: list[IndexContext] | None = None) -> PatchPlan:
    """Parse one patch layer's loaded payloads ([R-52]..[R-58], [R-107])."""
    n = header.layers[index].gaussian_count
    positions = parse_positions(payloads[SectionType.PATCH_POSITIONS], n)
    columns = parse_indices(payloads[SectionType.PATCH_ATTRIBUTES], n, codebooks, contexts)
    return PatchPlan(index, positions, columns)


def fill_patch_layer(plan: PatchPlan, codebooks: list[Codebook], out: GaussianCloud) -> None:
    """Positions plus codebook lookups into ``out`` ([R-56])."""
    out.means[:] = plan.positions.decode()
    fill_patch_attributes(plan.columns, codebooks, out)


def fill_patch_attributes(columns: dict[PatchAttribute, np.ndarray], codebooks: list[Codebook],
                          out: GaussianCloud) -> None:
    """Every attribute but the position from index columns ((groups, n) uint8 per attribute)."""
    n = len(out)
    targets = {PatchAttribute.SCALE: out.scales, PatchAttribute.ROTATION: out.quats,
               PatchAttribute.OPACITY: out.opacities[:, None], PatchAttribute.COLOR_DC: out.sh_dc}
    for cb in codebooks:
        values = gather(cb, columns[cb.attribute])
        if cb.attribute == PatchAttribute.ROTATION and cb.entry_dim != 4:
            values = decode_rotation(values)
        if cb.attribute in targets:
            targets[cb.attribute][:] = values
        else:
            out.sh_rest[:, cb.attribute.sh_slice, :] = values.reshape(n, cb.attribute.width // 3, 3)


def gather(codebook: Codebook, columns: np.ndarray) -> np.ndarray:
    """Look up every index group and lay the entries side by side: (n, width) float32.

    Per-entry mappings are applied to the codebook before the lookup (rotations normalized when one
    entry is a whole quaternion, opacities turned into logits), which gives the same values as
    applying them per Gaussian at a fraction of the cost. ``np.take`` on the transposed index
    columns writes the (n, groups, dim) result in one contiguous pass.
    """
    entries = codebook.entries.astype(np.float32)
    if codebook.attribute == PatchAttribute.ROTATION and codebook.entry_dim == 4:
        entries = decode_rotation(entries)
    elif codebook.attribute == PatchAttribute.OPACITY:
        entries = decode_opacity(entries[:, 0])[:, None]
    groups, n = columns.shape
    return np.take(entries, columns.T, axis=0).reshape(n, groups * entries.shape[1])
