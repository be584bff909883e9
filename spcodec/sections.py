"""Section payloads: typed objects, their serialization, and the checks a decoder applies to them.

The writer turns already-encoded components into raw payloads with the ``pack_*`` functions; the
decoder turns raw payloads back into the same objects with the ``parse_*`` functions, which enforce
every structural requirement of spec sections 6 and 7 before any array sized from the file is
allocated. Nothing here compresses or decompresses (that is :mod:`spcodec.codecs`), and nothing here
evaluates polynomials or runs Draco (that is the decoder).
"""

from __future__ import annotations

import io
from dataclasses import dataclass, field

import numpy as np
from construct import ConstructError

from .attributes import PatchAttribute, SketchAttribute
from .container import (
    CLUSTER_DTYPE,
    MAX_CODEBOOK_ENTRIES,
    SH_REST_ABSENT,
    ClusterRecord,
    PatchCodebooksPayload,
    PatchPositionsPayload,
    PositionMode,
    SketchClustersPayload,
)
from .draco_io import decode_points
from .errors import FormatError
from .index_contexts import IndexContext, column_entries, parse_contexts, resolve_ranks
from .limits import Limits
from .polynomial import MAX_DEGREE, monomial_count

# ============================================================================ sketch (spec 6)


@dataclass
class SketchCluster:
    """One encoded sketch cluster: its share of a Draco blob plus float16 polynomial models ([R-40]).

    ``draco`` is the blob that starts with this cluster, or ``b""`` when the cluster's points
    continue the previous cluster's blob ([R-47]).
    """

    draco: bytes
    point_count: int
    center: np.ndarray
    half_extent: np.ndarray
    models: dict[SketchAttribute, np.ndarray] = field(default_factory=dict)
    """Coefficient matrices (M(d), outputs) as float16; SH_REST may be absent."""

    def degree(self, attribute: SketchAttribute) -> int:
        """Polynomial degree of a model, or SH_REST_ABSENT."""
        coeffs = self.models.get(attribute)
        if coeffs is None:
            return SH_REST_ABSENT
        for d in range(MAX_DEGREE + 1):
            if monomial_count(d) == coeffs.shape[0]:
                return d
        raise ValueError(f"{coeffs.shape[0]} coefficients match no polynomial degree")


@dataclass
class DracoRun:
    """One Draco blob of SKETCH_POSITIONS and the consecutive clusters whose points it holds."""

    start: int
    stop: int
    """Byte range of the blob in the SKETCH_POSITIONS payload."""
    first_cluster: int
    end_cluster: int
    """Clusters first_cluster .. end_cluster - 1 share the blob, in that order."""
    points: int


@dataclass
class SketchLayout:
    """The parsed cluster table: per-cluster counts, frames, degrees and byte ranges."""

    records: np.ndarray
    """Structured array with CLUSTER_DTYPE fields."""
    runs: list[DracoRun]
    coefficient_offsets: np.ndarray
    """(clusters, 5) byte offsets of each model in the coefficient section (-1 where absent)."""


def coefficient_bytes(degree: int, attribute: SketchAttribute, sh_degree: int) -> int:
    """Stored size of one model ([R-44])."""
    if degree == SH_REST_ABSENT:
        return 0
    return 2 * monomial_count(degree) * attribute.outputs(sh_degree)


def pack_sketch(clusters: list[SketchCluster], sh_degree: int) -> tuple[bytes, bytes, bytes]:
    """Raw payloads of SKETCH_CLUSTERS, SKETCH_POSITIONS and SKETCH_COEFFICIENTS."""
    records = np.zeros(len(clusters), dtype=CLUSTER_DTYPE)
    coeff_parts: list[bytes] = []
    for i, cl in enumerate(clusters):
        records[i]["point_count"] = cl.point_count
        records[i]["draco_length"] = len(cl.draco)
        records[i]["center"] = np.asarray(cl.center, np.float32)
        records[i]["half_extent"] = np.asarray(cl.half_extent, np.float32)
        for attr in SketchAttribute:
            degree = cl.degree(attr)
            records[i]["degrees"][attr] = degree
            if degree == SH_REST_ABSENT:
                if attr is not SketchAttribute.SH_REST:
                    raise ValueError(f"cluster {i} lacks a {attr.name} model")
                continue
            coeffs = np.asarray(cl.models[attr])
            if coeffs.shape != (monomial_count(degree), attr.outputs(sh_degree)):
                raise ValueError(f"cluster {i} {attr.name} model has shape {coeffs.shape}")
            coeff_parts.append(coeffs.astype("<f2").tobytes())
    table = SketchClustersPayload.build(dict(cluster_count=len(clusters),
                                             records=records.tobytes()))
    return table, b"".join(cl.draco for cl in clusters), b"".join(coeff_parts)


def parse_sketch(table: bytes, positions_length: int, coefficients_length: int,
                 gaussian_count: int, sh_degree: int, limits: Limits) -> SketchLayout:
    """Parse and validate the cluster table against the other two sketch sections ([R-46])."""
    payload = _parse(SketchClustersPayload, table, "SKETCH_CLUSTERS")
    count = payload.cluster_count
    limits.check("cluster count", count, limits.max_clusters)
    if len(payload.records) != count * ClusterRecord.sizeof():
        raise FormatError(f"cluster table holds {len(payload.records)} record bytes for {count} "
                          f"clusters", "bad-section")
    rec = np.frombuffer(payload.records, dtype=CLUSTER_DTYPE)
    if count == 0:
        if gaussian_count or positions_length or coefficients_length:
            raise FormatError("an empty cluster table with non-empty sketch data", "bad-section")
        return SketchLayout(rec, [], np.zeros((0, 5), np.int64))
    if np.frombuffer(rec["reserved"].tobytes(), np.uint8).any():
        raise FormatError("a cluster record's reserved bytes are not zero", "reserved-nonzero")
    if np.any(rec["point_count"] == 0) or rec["draco_length"][0] == 0:
        raise FormatError("a cluster has zero points, or the first cluster starts no Draco blob",
                          "bad-value")
    if not (np.isfinite(rec["center"]).all() and np.isfinite(rec["half_extent"]).all()
            and (rec["half_extent"] > 0).all()):
        raise FormatError("a cluster frame is not finite or has a non-positive half extent",
                          "bad-value")
    degrees = rec["degrees"].astype(np.int64)
    if (degrees[:, :4] > MAX_DEGREE).any():
        raise FormatError(f"a polynomial degree exceeds {MAX_DEGREE}", "bad-value")
    rest = degrees[:, 4]
    if sh_degree == 0 and (rest != SH_REST_ABSENT).any():
        raise FormatError("an SH-rest model in a scene of SH degree 0", "bad-value")
    if ((rest > MAX_DEGREE) & (rest != SH_REST_ABSENT)).any():
        raise FormatError(f"an SH-rest degree is neither 0..{MAX_DEGREE} nor 255", "bad-value")
    if int(rec["point_count"].sum(dtype=np.int64)) != gaussian_count:
        raise FormatError("cluster point counts do not add up to the sketch layer's Gaussian "
                          "count", "bad-section")
    runs = draco_runs(rec)
    if (runs[-1].stop if runs else 0) != positions_length:
        raise FormatError("Draco blob lengths do not add up to the SKETCH_POSITIONS length",
                          "bad-section")
    sizes = np.zeros((count, 5), np.int64)
    for attr in SketchAttribute:
        d = degrees[:, attr]
        m = (d + 1) * (d + 2) * (d + 3) // 6
        sizes[:, attr] = np.where(d == SH_REST_ABSENT, 0, 2 * m * attr.outputs(sh_degree))
    flat = np.concatenate([[0], np.cumsum(sizes.ravel())])
    if flat[-1] != coefficients_length:
        raise FormatError("model sizes do not add up to the SKETCH_COEFFICIENTS length",
                          "bad-section")
    offsets = np.where(sizes > 0, flat[:-1].reshape(count, 5), -1)
    return SketchLayout(rec, runs, offsets)


def draco_runs(records: np.ndarray) -> list[DracoRun]:
    """Group clusters into blobs: a non-zero draco_length starts a blob, zero continues it."""
    lengths = records["draco_length"].astype(np.int64)
    counts = records["point_count"].astype(np.int64)
    starts = np.flatnonzero(lengths > 0)
    ends = np.append(starts[1:], len(records))
    byte_ends = np.cumsum(lengths[starts])
    return [DracoRun(int(b - lengths[a]), int(b), int(a), int(e), int(counts[a:e].sum()))
            for a, e, b in zip(starts, ends, byte_ends)]


def read_coefficients(coefficients: bytes, layout: SketchLayout, cluster: int,
                      attribute: SketchAttribute, sh_degree: int) -> np.ndarray | None:
    """One model's float16 coefficient matrix (M(d), outputs), or None when absent."""
    start = int(layout.coefficient_offsets[cluster, attribute])
    if start < 0:
        return None
    degree = int(layout.records["degrees"][cluster][attribute])
    shape = (monomial_count(degree), attribute.outputs(sh_degree))
    coeffs = np.frombuffer(coefficients, dtype="<f2", count=shape[0] * shape[1],
                           offset=start).reshape(shape)
    if not np.isfinite(coeffs).all():
        raise FormatError(f"cluster {cluster} has a non-finite {attribute.name} coefficient",
                          "bad-value")
    return coeffs


# ============================================================================= patch (spec 7)


@dataclass
class Codebook:
    """A codebook for one patch attribute: ``entries`` is (entry_count, entry_dim) float16."""

    attribute: PatchAttribute
    entries: np.ndarray

    @property
    def entry_dim(self) -> int:
        return int(self.entries.shape[1])

    @property
    def groups(self) -> int:
        """Indices per Gaussian: the attribute's components split into entry_dim-wide groups."""
        return self.attribute.width // self.entry_dim


def pack_codebooks(codebooks: list[Codebook]) -> bytes:
    """Raw PATCH_CODEBOOKS payload ([R-50])."""
    return PatchCodebooksPayload.build(dict(
        attribute_count=len(codebooks),
        codebooks=[dict(attribute=int(cb.attribute), entry_dim=cb.entry_dim,
                        entry_count=cb.entries.shape[0],
                        entries=np.asarray(cb.entries).astype("<f2").tobytes())
                   for cb in codebooks],
    ))


def parse_codebooks(raw: bytes, sh_degree: int) -> list[Codebook]:
    """Parse and validate PATCH_CODEBOOKS ([R-50], [R-51])."""
    payload = _parse(PatchCodebooksPayload, raw, "PATCH_CODEBOOKS", exact=True)
    expected = PatchAttribute.for_sh_degree(sh_degree)
    ids = [cb.attribute for cb in payload.codebooks]
    if ids != [int(a) for a in expected]:
        raise FormatError(f"codebooks are for attributes {ids}, expected {[int(a) for a in expected]}"
                          f" for SH degree {sh_degree}", "bad-section")
    out = []
    for cb in payload.codebooks:
        attr = PatchAttribute(cb.attribute)
        if cb.entry_dim == 0 or attr.width % cb.entry_dim:
            raise FormatError(f"{attr.name} codebook entry dimension {cb.entry_dim} does not divide "
                              f"{attr.width}", "bad-value")
        if not 1 <= cb.entry_count <= MAX_CODEBOOK_ENTRIES:
            raise FormatError(f"{attr.name} codebook has {cb.entry_count} entries, allowed 1.."
                              f"{MAX_CODEBOOK_ENTRIES}", "bad-value")
        entries = np.frombuffer(cb.entries, dtype="<f2").reshape(cb.entry_count, cb.entry_dim)
        if not np.isfinite(entries).all():
            raise FormatError(f"{attr.name} codebook has a non-finite entry", "bad-value")
        out.append(Codebook(attr, entries))
    return out


def index_groups(codebooks: list[Codebook]) -> int:
    """Index bytes per Gaussian in a PATCH_ATTRIBUTES section."""
    return sum(cb.groups for cb in codebooks)


def pack_indices(indices: dict[PatchAttribute, np.ndarray], codebooks: list[Codebook]) -> bytes:
    """Raw PATCH_ATTRIBUTES payload: index columns in codebook order, group by group ([R-52])."""
    columns = []
    for cb in codebooks:
        idx = np.asarray(indices[cb.attribute], dtype=np.uint8)
        if idx.ndim == 1:
            idx = idx[:, None]
        if idx.shape[1] != cb.groups:
            raise ValueError(f"{cb.attribute.name} indices have {idx.shape[1]} groups, "
                             f"expected {cb.groups}")
        if idx.size and int(idx.max()) >= cb.entries.shape[0]:
            raise ValueError(f"{cb.attribute.name} index out of codebook range")
        columns.append(np.ascontiguousarray(idx.T))
    return b"".join(c.tobytes() for c in columns)


def parse_indices(raw: bytes, count: int, codebooks: list[Codebook],
                  contexts: list[IndexContext] | None = None) -> dict[PatchAttribute, np.ndarray]:
    """Index columns per attribute as (groups, count) uint8 arrays; validates range ([R-52]).

    With ``contexts`` (spec 7.5) the stored target columns are ranks, range-checked like indices
    and then resolved into indices ([R-107])."""
    groups = index_groups(codebooks)
    if len(raw) != count * groups:
        raise FormatError(f"PATCH_ATTRIBUTES holds {len(raw)} bytes, expected {count} Gaussians "
                          f"x {groups} indices", "bad-section")
    flat = np.frombuffer(raw, dtype=np.uint8).reshape(groups, count)
    out, row = {}, 0
    for cb in codebooks:
        block = flat[row:row + cb.groups]
        row += cb.groups
        if count and cb.entries.shape[0] < MAX_CODEBOOK_ENTRIES and \
                int(block.max()) >= cb.entries.shape[0]:
            raise FormatError(f"a {cb.attribute.name} index exceeds the codebook's "
                              f"{cb.entries.shape[0]} entries", "bad-value")
        out[cb.attribute] = block
    if contexts:
        flat, row = resolve_ranks(flat, contexts), 0
        for cb in codebooks:
            out[cb.attribute] = flat[row:row + cb.groups]
            row += cb.groups
    return out


# spec 7.5 - PATCH_INDEX_CONTEXTS (1.2): u8 count, then per record u8 target, u8 context and a
# u8[E_context][E_target] table; its sizes depend on the codebooks, so it is parsed by hand
# (spcodec/index_contexts.py) rather than with a construct definition.
def parse_index_contexts(raw: bytes, codebooks: list[Codebook]) -> list[IndexContext]:
    """Parse and validate PATCH_INDEX_CONTEXTS against the codebooks' columns ([R-105])."""
    return parse_contexts(raw, codebook_columns(codebooks))


def codebook_columns(codebooks: list[Codebook]) -> np.ndarray:
    """Entry count of every index column in [R-52] order."""
    return column_entries([cb.entries.shape[0] for cb in codebooks], [cb.groups for cb in codebooks])


@dataclass
class PatchPositions:
    """Positions of one patch layer in one of the four stored modes ([R-53]..[R-55])."""

    mode: PositionMode
    data: np.ndarray
    """(N, 3): float16 for FLOAT16, uint16 quantized values for QUANT16, float32 for FLOAT32 and
    for DRACO (the decoded positions)."""
    origin: np.ndarray | None = None
    step: np.ndarray | None = None
    blob: bytes | None = None
    """The Draco blob (DRACO mode)."""

    def __len__(self) -> int:
        return int(self.data.shape[0])

    @classmethod
    def draco(cls, blob: bytes, decoded: np.ndarray) -> "PatchPositions":
        """A Draco point cloud whose decode order is the layer's order, with its decoded points."""
        return cls(PositionMode.DRACO, np.asarray(decoded, np.float32), blob=bytes(blob))

    @classmethod
    def float16(cls, xyz: np.ndarray) -> "PatchPositions":
        """The paper's half-float positions."""
        return cls(PositionMode.FLOAT16, np.asarray(xyz, dtype=np.float16))

    @classmethod
    def float32(cls, xyz: np.ndarray) -> "PatchPositions":
        """Lossless positions."""
        return cls(PositionMode.FLOAT32, np.asarray(xyz, dtype=np.float32))

    @classmethod
    def quant16(cls, xyz: np.ndarray, step: float | np.ndarray,
                origin: np.ndarray | None = None) -> "PatchPositions":
        """Uniform quantization with the given step per axis (absolute error <= step / 2)."""
        xyz = np.asarray(xyz, dtype=np.float64)
        lo = xyz.min(axis=0) if origin is None and len(xyz) else np.zeros(3)
        lo = np.asarray(lo if origin is None else origin, np.float32)
        step32 = np.broadcast_to(np.asarray(step, np.float32), (3,)).copy()
        q = np.round((xyz - lo.astype(np.float64)) / step32.astype(np.float64))
        if len(q) and (q.min() < 0 or q.max() > 0xFFFF):
            raise ValueError("positions span more than 65535 quantization steps")
        return cls(PositionMode.QUANT16, q.astype(np.uint16), lo, step32)

    def decode(self) -> np.ndarray:
        """(N, 3) float32 positions, as every decoder must compute them ([R-55])."""
        if self.mode == PositionMode.QUANT16:
            q = self.data.astype(np.float64)
            return (self.origin.astype(np.float64) + q * self.step.astype(np.float64)).astype(np.float32)
        return self.data.astype(np.float32)


def _zigzag_delta(q: np.ndarray) -> np.ndarray:
    """Column-wise wrap-around deltas of uint16 values, zigzag-mapped to uint16."""
    prev = np.vstack([np.zeros((1, q.shape[1]), np.uint16), q[:-1]])
    delta = (q.astype(np.int32) - prev.astype(np.int32)) & 0xFFFF
    signed = delta.astype(np.uint16).view(np.int16).astype(np.int32)
    return ((signed << 1) ^ (signed >> 31)).astype(np.uint16)


def _undo_zigzag_delta(z: np.ndarray) -> np.ndarray:
    z = z.astype(np.int64)
    delta = (z >> 1) ^ -(z & 1)
    return (np.cumsum(delta, axis=0) & 0xFFFF).astype(np.uint16)


def pack_positions(pos: PatchPositions) -> bytes:
    """Raw PATCH_POSITIONS payload; columns stored x, then y, then z ([R-53])."""
    if pos.mode == PositionMode.DRACO:
        return PatchPositionsPayload.build(dict(mode=int(pos.mode), reserved=b"\0\0\0",
                                                params=None, data=pos.blob))
    if pos.mode == PositionMode.QUANT16:
        data = _zigzag_delta(pos.data).T.astype("<u2")
        params = dict(origin=[float(v) for v in pos.origin], step=[float(v) for v in pos.step])
    else:
        dtype = "<f2" if pos.mode == PositionMode.FLOAT16 else "<f4"
        data, params = pos.data.T.astype(dtype), None
    return PatchPositionsPayload.build(dict(mode=int(pos.mode), reserved=b"\0\0\0", params=params,
                                            data=np.ascontiguousarray(data).tobytes()))


def parse_positions(raw: bytes, count: int) -> PatchPositions:
    """Parse and validate PATCH_POSITIONS for a layer of ``count`` Gaussians ([R-53]..[R-55])."""
    payload = _parse(PatchPositionsPayload, raw, "PATCH_POSITIONS")
    if payload.reserved != b"\0\0\0":
        raise FormatError("PATCH_POSITIONS reserved bytes are not zero", "reserved-nonzero")
    try:
        mode = PositionMode(payload.mode)
    except ValueError:
        raise FormatError(f"unknown patch position mode {payload.mode}", "bad-value") from None
    if mode == PositionMode.DRACO:
        if count == 0:  # no Draco point cloud has zero points ([R-58])
            if payload.data:
                raise FormatError(f"PATCH_POSITIONS holds {len(payload.data)} Draco bytes for a "
                                  f"layer of 0 Gaussians", "bad-section")
            return PatchPositions(mode, np.zeros((0, 3), np.float32), blob=b"")
        points = decode_points(payload.data, count, "patch positions")
        return PatchPositions(mode, points, blob=bytes(payload.data))
    width = 4 if mode == PositionMode.FLOAT32 else 2
    if len(payload.data) != count * 3 * width:
        raise FormatError(f"PATCH_POSITIONS holds {len(payload.data)} data bytes for {count} "
                          f"Gaussians in mode {mode.name}", "bad-section")
    if mode == PositionMode.QUANT16:
        origin = np.array(payload.params.origin, np.float32)
        step = np.array(payload.params.step, np.float32)
        if not (np.isfinite(origin).all() and np.isfinite(step).all() and (step >= 0).all()):
            raise FormatError("QUANT16 origin or step is not finite and non-negative", "bad-value")
        extreme = origin.astype(np.float64) + 0xFFFF * step.astype(np.float64)
        with np.errstate(over="ignore"):
            rounded = extreme.astype(np.float32)  # binary64 -> binary32, as decoding does
        if not np.isfinite(rounded).all():
            raise FormatError("QUANT16 positions can overflow float32", "bad-value")
        z = np.frombuffer(payload.data, dtype="<u2").reshape(3, count).T
        return PatchPositions(mode, _undo_zigzag_delta(z), origin, step)
    dtype = "<f2" if mode == PositionMode.FLOAT16 else "<f4"
    data = np.frombuffer(payload.data, dtype=dtype).reshape(3, count).T
    if not np.isfinite(data).all():
        raise FormatError("a patch position is not finite", "bad-value")
    return PatchPositions(mode, data)


# ============================================================================ shared helpers
def _parse(struct, raw: bytes, name: str, exact: bool = False):
    """Parse with construct, turning any construct failure into FormatError('bad-section')."""
    stream = io.BytesIO(raw)
    try:
        parsed = struct.parse_stream(stream)
    except (ConstructError, ValueError, OverflowError) as exc:
        raise FormatError(f"{name} payload is malformed ({exc.__class__.__name__})",
                          "bad-section") from None
    if exact and stream.tell() != len(raw):
        raise FormatError(f"{name} payload has {len(raw) - stream.tell()} trailing bytes",
                          "bad-section")
    return parsed
