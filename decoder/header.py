"""Reading and validating the header block (spec section 3, decoding steps 2-5).

Everything here works on the header alone, before any section is touched: a client that fetched only
the first ``header_size`` bytes can learn every byte range of the file.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from spcodec.codecs import crc32
from spcodec.container import (
    FIXED_HEADER_SIZE,
    LAYER_DTYPE,
    MAGIC,
    SECTION_DTYPE,
    SECTION_FLAG_REQUIRED,
    VERSION_MAJOR,
    FixedHeader,
    LayerKind,
    SectionType,
    header_size,
)
from spcodec.errors import ChecksumError, FormatError, TruncatedError, UnsupportedError
from spcodec.limits import Limits

#: Where each known section type may appear: "sketch" = layer 0, "first" = layer 1, "patch" =
#: every patch layer; and whether the type must be flagged required ([R-13], [R-14], [R-20]).
KNOWN_SECTIONS: dict[int, tuple[str, bool]] = {
    SectionType.METADATA: ("sketch", False),
    SectionType.SKETCH_CLUSTERS: ("sketch", True),
    SectionType.SKETCH_POSITIONS: ("sketch", True),
    SectionType.SKETCH_COEFFICIENTS: ("sketch", True),
    SectionType.PATCH_CODEBOOKS: ("first", True),
    SectionType.PATCH_POSITIONS: ("patch", True),
    SectionType.PATCH_ATTRIBUTES: ("patch", True),
    SectionType.PATCH_INDEX_CONTEXTS: ("first", True),
}
_MANDATORY = {
    "sketch": {SectionType.SKETCH_CLUSTERS, SectionType.SKETCH_POSITIONS,
               SectionType.SKETCH_COEFFICIENTS},
    "first": {SectionType.PATCH_CODEBOOKS, SectionType.PATCH_POSITIONS,
              SectionType.PATCH_ATTRIBUTES},
    "patch": {SectionType.PATCH_POSITIONS, SectionType.PATCH_ATTRIBUTES},
}


@dataclass(frozen=True)
class Section:
    """One table-of-contents entry."""

    index: int
    type: int
    codec: int
    flags: int
    layer: int
    offset: int
    stored_length: int
    raw_length: int
    crc32: int

    @property
    def required(self) -> bool:
        return bool(self.flags & SECTION_FLAG_REQUIRED)

    @property
    def end(self) -> int:
        return self.offset + self.stored_length

    @property
    def known(self) -> bool:
        return self.type in KNOWN_SECTIONS

    @property
    def type_name(self) -> str:
        try:
            return SectionType(self.type).name
        except ValueError:
            return f"UNKNOWN_0x{self.type:04X}"


@dataclass(frozen=True)
class Layer:
    """One layer-table entry plus the sections that belong to it."""

    index: int
    kind: LayerKind
    gaussian_count: int
    end_offset: int
    sections: tuple[Section, ...]

    def section(self, type_: SectionType) -> Section | None:
        for sec in self.sections:
            if sec.type == type_:
                return sec
        return None


@dataclass(frozen=True)
class Header:
    """The parsed and validated header block."""

    version: tuple[int, int]
    header_size: int
    sh_degree: int
    gaussian_count: int
    file_size: int
    layers: tuple[Layer, ...]
    sections: tuple[Section, ...]


def header_bytes_needed(data: bytes | memoryview) -> int | None:
    """How many bytes the header block needs, once the fixed header is present (else None)."""
    if len(data) < FIXED_HEADER_SIZE:
        return None
    head = FixedHeader.parse(bytes(data[:FIXED_HEADER_SIZE]))
    return int(head.header_size)


def read_header(data: bytes | memoryview, limits: Limits) -> Header:
    """Parse and validate the header block at the start of ``data`` (steps 2-5)."""
    if len(data) < len(MAGIC):
        if MAGIC.startswith(bytes(data)):
            raise TruncatedError("the data ends inside the file header")
        raise FormatError("not an spcodec file (bad magic)", "bad-magic")
    if bytes(data[:len(MAGIC)]) != MAGIC:
        raise FormatError("not an spcodec file (bad magic)", "bad-magic")
    if len(data) < FIXED_HEADER_SIZE:
        raise TruncatedError("the data ends inside the file header")
    head = FixedHeader.parse(bytes(data[:FIXED_HEADER_SIZE]))
    if head.version_major != VERSION_MAJOR:
        raise UnsupportedError(f"bitstream major version {head.version_major} is not supported "
                               f"(this decoder reads {VERSION_MAJOR}.x)")
    # Bound the header block before waiting for it or reading it ([R-60]).
    limits.check("layer count", head.layer_count, limits.max_layers)
    limits.check("section count", head.section_count, limits.max_sections)
    size = header_size(head.layer_count, head.section_count)
    if head.header_size != size:
        raise FormatError(f"header_size is {head.header_size}, but the tables need {size}",
                          "bad-layout")
    if len(data) < size:
        raise TruncatedError("the data ends inside the header block")
    block = bytes(data[:size])
    if crc32(block[:-4]) != int.from_bytes(block[-4:], "little"):
        raise ChecksumError("header CRC-32 mismatch", "header-crc")
    # Semantic checks only after the CRC, so corruption is reported as corruption ([R-8]).
    if head.flags != 0 or head.reserved != b"\0" * 7:
        raise FormatError("reserved header flags or bytes are not zero", "reserved-nonzero")
    if head.layer_count < 1 or head.section_count < 3:
        raise FormatError("a file needs at least one layer and the three sketch sections",
                          "bad-layout")
    if head.sh_degree > 3:
        raise FormatError(f"SH degree {head.sh_degree} is outside 0..3", "bad-value")
    limits.check("Gaussian count", head.gaussian_count, limits.max_gaussians)
    limits.check("file size", head.file_size, limits.max_file_bytes)
    limits.check_gaussian_density(head.gaussian_count, head.file_size)
    layer_rows = np.frombuffer(block, LAYER_DTYPE, head.layer_count, FIXED_HEADER_SIZE)
    toc_rows = np.frombuffer(block, SECTION_DTYPE, head.section_count,
                             FIXED_HEADER_SIZE + layer_rows.nbytes)
    sections = _read_sections(toc_rows, head, size, limits)
    layers = _read_layers(layer_rows, sections, head)
    return Header((head.version_major, head.version_minor), size, head.sh_degree,
                  head.gaussian_count, head.file_size, layers, sections)


def _read_sections(rows: np.ndarray, head, start: int, limits: Limits) -> tuple[Section, ...]:
    sections, offset, previous_layer = [], start, 0
    raw_total = 0
    for i, row in enumerate(rows):
        sec = Section(i, int(row["type"]), int(row["codec"]), int(row["flags"]), int(row["layer"]),
                      int(row["offset"]), int(row["stored_length"]), int(row["raw_length"]),
                      int(row["crc32"]))
        if row["reserved"] or row["reserved2"] or sec.flags & ~SECTION_FLAG_REQUIRED:
            raise FormatError(f"section {i} has reserved bits set", "reserved-nonzero")
        if sec.layer >= head.layer_count:
            raise FormatError(f"section {i} names layer {sec.layer} of {head.layer_count}",
                              "bad-layout")
        if sec.layer < previous_layer:
            raise FormatError(f"section {i} is out of layer order", "bad-layout")
        if sec.offset != offset:
            raise FormatError(f"section {i} starts at {sec.offset}, expected {offset} (sections "
                              f"must be contiguous and in table order)", "bad-layout")
        limits.check(f"section {i} raw length", sec.raw_length, limits.max_section_bytes)
        previous_layer, offset = sec.layer, sec.end
        raw_total += sec.raw_length
        sections.append(sec)
    if offset != head.file_size:
        raise FormatError(f"sections end at {offset}, file_size says {head.file_size}",
                          "bad-layout")
    limits.check_expansion(raw_total, head.file_size)
    return tuple(sections)


def _read_layers(rows: np.ndarray, sections: tuple[Section, ...], head) -> tuple[Layer, ...]:
    layers, total = [], 0
    for i, row in enumerate(rows):
        kind_id = int(row["kind"])
        if kind_id != (LayerKind.SKETCH if i == 0 else LayerKind.PATCH):
            raise FormatError(f"layer {i} has kind {kind_id}; layer 0 must be sketch (0) and "
                              f"later layers patch (1)", "bad-layout")
        if bytes(row["reserved"]) != b"\0\0\0":
            raise FormatError(f"layer {i} has reserved bytes set", "reserved-nonzero")
        own = tuple(s for s in sections if s.layer == i)
        if not own:
            raise FormatError(f"layer {i} has no sections", "missing-section")
        if int(row["end_offset"]) != own[-1].end:
            raise FormatError(f"layer {i} end_offset {int(row['end_offset'])} is not the end of its "
                              f"last section ({own[-1].end})", "bad-layout")
        if layers and own[-1].end <= layers[-1].end_offset:
            raise FormatError(f"layer {i} ends where layer {i - 1} does ({own[-1].end}): a layer "
                              "of zero bytes leaves a prefix's last layer ambiguous", "bad-layout")
        _check_layer_sections(i, own)
        total += int(row["gaussian_count"])
        layers.append(Layer(i, LayerKind(kind_id), int(row["gaussian_count"]),
                            int(row["end_offset"]), own))
    if total != head.gaussian_count:
        raise FormatError(f"layer Gaussian counts add up to {total}, the header says "
                          f"{head.gaussian_count}", "bad-layout")
    return tuple(layers)


def _check_layer_sections(index: int, sections: tuple[Section, ...]) -> None:
    place = "sketch" if index == 0 else ("first" if index == 1 else "patch")
    seen: set[int] = set()
    for sec in sections:
        if not sec.known:
            continue
        allowed_place, required = KNOWN_SECTIONS[sec.type]
        if allowed_place != place and not (allowed_place == "patch" and place == "first"):
            raise FormatError(f"{sec.type_name} may not appear in layer {index}", "bad-layout")
        if sec.required != required:
            raise FormatError(f"{sec.type_name} must be flagged "
                              f"{'required' if required else 'optional'}", "bad-layout")
        if sec.type in seen:
            raise FormatError(f"layer {index} holds {sec.type_name} twice", "duplicate-section")
        seen.add(sec.type)
    missing = _MANDATORY[place] - seen
    if missing:
        names = ", ".join(sorted(SectionType(t).name for t in missing))
        raise FormatError(f"layer {index} lacks {names}", "missing-section")
