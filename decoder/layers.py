"""Turning one layer's sections into Gaussians (spec decoding steps 7-9).

Decoding a layer has two steps. *Reading* checks the layer's integrity (unknown required sections,
then the CRC of every section, in table order), inflates each section into exactly its declared raw
length, parses it, decodes its Draco blobs and checks every value range. Only then is the output
*filled*: the caller allocates it after the read has tied the layer's Gaussian count to bytes that
are actually present, so a small hostile file cannot make the decoder allocate for a count it only
declares ([R-60]).
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
from spcodec.container import SectionType
from spcodec.draco_io import decode_points
from spcodec.errors import ChecksumError, FormatError
from spcodec.limits import Limits
from spcodec.polynomial import features, monomial_count, normalize_positions
from spcodec.sections import (
    Codebook,
    parse_codebooks,
    parse_indices,
    parse_positions,
    parse_sketch,
    read_coefficients,
)

from .header import Header, Layer, Section

_ROWS_PER_CHUNK = 1 << 15
MAX_NORMALIZED = 2.0
"""Largest |normalized coordinate| a sketch cluster may have ([R-42])."""


def check_layer_integrity(layer: Layer, data: bytes | memoryview) -> None:
    """Reject unknown required sections, then verify every section's CRC ([R-7], [R-20], [R-21])."""
    for sec in layer.sections:
        if not sec.known and sec.required:
            raise FormatError(f"layer {layer.index} holds required section type 0x{sec.type:04X}, "
                              f"unknown to this decoder", "unknown-required-section")
    view = memoryview(data)
    for sec in layer.sections:
        stored = view[sec.offset:sec.end]
        if len(stored) != sec.stored_length:
            raise FormatError(f"section {sec.index} ({sec.type_name}) is cut short", "truncated")
        if crc32(stored) != sec.crc32:
            raise ChecksumError(f"section {sec.index} ({sec.type_name}) CRC-32 mismatch")


def section_payload(data: bytes | memoryview, section: Section) -> bytes:
    """Inflate one section whose CRC was verified by :func:`check_layer_integrity` ([R-24])."""
    stored = memoryview(data)[section.offset:section.end]
    return decompress(section.codec, stored, section.raw_length)


# ----------------------------------------------------------------------------- sketch layer
@dataclass
class SketchCluster:
    """One validated cluster: its decoded positions, normalized positions and models."""

    points: np.ndarray
    normalized: np.ndarray
    models: dict[SketchAttribute, np.ndarray | None]


def read_sketch_layer(data: bytes | memoryview, header: Header,
                      limits: Limits) -> list[SketchCluster]:
    """Layer 0, read and validated: every cluster's positions and models, in table order."""
    layer = header.layers[0]
    check_layer_integrity(layer, data)
    meta = layer.section(SectionType.METADATA)
    if meta is not None:
        limits.check("metadata length", meta.raw_length, limits.max_metadata_bytes)
        section_payload(data, meta)  # integrity only: the content is ignorable ([R-70])
    table = section_payload(data, layer.section(SectionType.SKETCH_CLUSTERS))
    draco = section_payload(data, layer.section(SectionType.SKETCH_POSITIONS))
    coeffs = section_payload(data, layer.section(SectionType.SKETCH_COEFFICIENTS))
    sh = header.sh_degree
    plan = parse_sketch(table, len(draco), len(coeffs), layer.gaussian_count, sh, limits)
    clusters = []
    for b, run in enumerate(plan.runs):
        points = decode_points(draco[run.start:run.stop], run.points, f"sketch Draco blob {b}")
        offset = 0
        for c in range(run.first_cluster, run.end_cluster):
            rec = plan.records[c]
            mine = points[offset:offset + int(rec["point_count"])]
            offset += len(mine)
            x = normalize_positions(mine, rec["center"], rec["half_extent"])
            if len(x) and np.abs(x).max() > MAX_NORMALIZED:
                raise FormatError(f"cluster {c}: a position lies outside twice its frame",
                                  "bad-value")
            models = {a: read_coefficients(coeffs, plan, c, a, sh) for a in SketchAttribute}
            clusters.append(SketchCluster(mine, x, models))
    return clusters


def fill_sketch_layer(clusters: list[SketchCluster], sh_degree: int, out: GaussianCloud) -> None:
    """Evaluate every cluster's models into ``out`` ([R-41]..[R-44], [R-48])."""
    start = 0
    for cluster in clusters:
        rows = slice(start, start + len(cluster.points))
        out.means[rows] = cluster.points
        fill_cluster(out, rows, evaluate_models(cluster.normalized, cluster.models), sh_degree)
        start = rows.stop


def evaluate_models(x: np.ndarray, models: dict[SketchAttribute, np.ndarray | None]
                    ) -> dict[SketchAttribute, np.ndarray]:
    """Evaluate every present model at normalized positions ``x`` sharing one feature matrix.

    Because the monomial order is graded, a model of degree d uses the first M(d) feature columns
    of the highest-degree matrix ([R-41], [R-43]). Results are float64 (n, outputs).
    """
    present = {a: np.asarray(c, dtype=np.float64) for a, c in models.items() if c is not None}
    top = max(_degree(c) for c in present.values())
    out = {a: np.empty((x.shape[0], c.shape[1])) for a, c in present.items()}
    for start in range(0, x.shape[0], _ROWS_PER_CHUNK):
        stop = min(start + _ROWS_PER_CHUNK, x.shape[0])
        phi = features(x[start:stop], top)
        for a, c in present.items():
            out[a][start:stop] = phi[:, :c.shape[0]] @ c
    return out


def fill_cluster(out: GaussianCloud, rows: slice, values: dict[SketchAttribute, np.ndarray],
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
@dataclass
class PatchData:
    """One validated patch layer: decoded positions and index columns."""

    positions: np.ndarray
    columns: dict[PatchAttribute, np.ndarray]


def read_codebooks(data: bytes | memoryview, header: Header) -> list[Codebook]:
    """The codebooks carried by layer 1 ([R-50]); layer 1's integrity must have been checked."""
    return parse_codebooks(section_payload(data, header.layers[1].section(
        SectionType.PATCH_CODEBOOKS)), header.sh_degree)


def read_patch_layer(data: bytes | memoryview, header: Header, index: int,
                     codebooks: list[Codebook] | None) -> tuple[PatchData, list[Codebook]]:
    """A patch layer read and validated (codebooks are read from layer 1 when not given yet)."""
    layer = header.layers[index]
    check_layer_integrity(layer, data)
    if codebooks is None:
        codebooks = read_codebooks(data, header)
    n = layer.gaussian_count
    positions = parse_positions(section_payload(data, layer.section(SectionType.PATCH_POSITIONS)), n)
    columns = parse_indices(section_payload(data, layer.section(SectionType.PATCH_ATTRIBUTES)), n,
                            codebooks)
    return PatchData(positions.decode(), columns), codebooks


def fill_patch_layer(patch: PatchData, codebooks: list[Codebook], out: GaussianCloud) -> None:
    """Positions plus codebook lookups into ``out`` ([R-56])."""
    n = len(patch.positions)
    out.means[:] = patch.positions
    targets = {PatchAttribute.SCALE: out.scales, PatchAttribute.ROTATION: out.quats,
               PatchAttribute.OPACITY: out.opacities[:, None], PatchAttribute.COLOR_DC: out.sh_dc}
    for cb in codebooks:
        values = gather(cb, patch.columns[cb.attribute])
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
