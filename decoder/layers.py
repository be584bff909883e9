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
from spcodec.container import SectionType
from spcodec.draco_io import decode_points
from spcodec.errors import ChecksumError, FormatError
from spcodec.limits import Limits
from spcodec.polynomial import features, monomial_count, normalize_positions
from spcodec.sections import (
    Codebook,
    PatchPositions,
    SketchLayout,
    parse_codebooks,
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


def fill_sketch_layer(plan: SketchPlan, out: GaussianCloud) -> None:
    """Evaluate every cluster's models at its points and write the Gaussians into ``out``."""
    records, sh = plan.layout.records, plan.sh_degree
    starts = np.concatenate([[0], np.cumsum(records["point_count"], dtype=np.int64)])
    for run, points in zip(plan.layout.runs, plan.points):
        offset = 0
        for c in range(run.first_cluster, run.end_cluster):
            rec = records[c]
            count = int(rec["point_count"])
            mine = points[offset:offset + count]
            offset += count
            models = {a: read_coefficients(plan.coefficients, plan.layout, c, a, sh)
                      for a in SketchAttribute}
            with np.errstate(over="ignore", invalid="ignore"):
                values = evaluate_models(normalize_positions(mine, rec["center"],
                                                             rec["half_extent"]), models)
            check_model_values(values, c)
            rows = slice(int(starts[c]), int(starts[c]) + count)
            out.means[rows] = mine
            fill_cluster(out, rows, values, sh)


_FLOAT32_MAX = float(np.finfo(np.float32).max)


def check_model_values(values: dict[SketchAttribute, np.ndarray], cluster: int) -> None:
    """Refuse a cluster whose models evaluate to values no float32 parameter can hold ([R-34]).

    Finite coefficients and frames can still overflow: a tiny half extent makes the normalized
    positions huge, and a degree-10 monomial of them is not finite in binary64. Rotations and
    opacities only need finite coded values (they are normalized or clamped); the other
    parameters are stored as they are, so they must also fit in binary32.
    """
    for attribute, v in values.items():
        if not np.isfinite(v).all():
            raise FormatError(f"cluster {cluster}: the {attribute.name} model is not finite at "
                              f"the cluster's points", "bad-value")
        if attribute not in (SketchAttribute.ROTATION, SketchAttribute.OPACITY) and \
                v.size and float(np.abs(v).max()) > _FLOAT32_MAX:
            raise FormatError(f"cluster {cluster}: the {attribute.name} model overflows float32",
                              "bad-value")


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
def read_codebooks(payloads: Payloads, header: Header) -> list[Codebook]:
    """The codebooks carried by layer 1, from its loaded payloads ([R-50])."""
    return parse_codebooks(payloads[SectionType.PATCH_CODEBOOKS], header.sh_degree)


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
                        codebooks: list[Codebook]) -> PatchPlan:
    """Parse one patch layer's loaded payloads ([R-52]..[R-58])."""
    n = header.layers[index].gaussian_count
    positions = parse_positions(payloads[SectionType.PATCH_POSITIONS], n)
    columns = parse_indices(payloads[SectionType.PATCH_ATTRIBUTES], n, codebooks)
    return PatchPlan(index, positions, columns)


def fill_patch_layer(plan: PatchPlan, codebooks: list[Codebook], out: GaussianCloud) -> None:
    """Positions plus codebook lookups into ``out`` ([R-56])."""
    n = plan.gaussian_count
    out.means[:] = plan.positions.decode()
    targets = {PatchAttribute.SCALE: out.scales, PatchAttribute.ROTATION: out.quats,
               PatchAttribute.OPACITY: out.opacities[:, None], PatchAttribute.COLOR_DC: out.sh_dc}
    for cb in codebooks:
        values = gather(cb, plan.columns[cb.attribute])
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
