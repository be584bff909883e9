"""The bitstream's binary structures, defined once with construct and used to parse and to build.

Each definition carries the number of the spec section that is normative for it
(``spec/bitstream-v1.md``). Fixed-size records that can occur many times (layer table, table of
contents, cluster records) are also read as numpy structured arrays whose dtype is *derived* from the
construct definition by :func:`record_dtype`, so the layout still lives in one place while large tables
parse at numpy speed.

All integers and floats are little-endian ([R-2]).
"""

from __future__ import annotations

import enum

import numpy as np
from construct import (
    Array,
    Bytes,
    Construct,
    Float32l,
    FormatField,
    GreedyBytes,
    Int8ul,
    Int16ul,
    Int32ul,
    Int64ul,
    Pass,
    Struct,
    Switch,
    this,
)

# --------------------------------------------------------------------------------- 3. File header
MAGIC = b"\x89SPC\r\n\x1a\n"
"""First 8 bytes of every spcodec file ([R-3])."""

GZIP_MAGIC = b"\x1f\x8b"
"""First 2 bytes of the optional gzip wrapper ([R-80])."""

VERSION_MAJOR = 1
VERSION_MINOR = 0
"""The minor version a file gets unless it uses a later feature ([R-92]: the oldest that
expresses it)."""
PREVIEW_MINOR = 1
"""The minor version that added the ``PREVIEW`` section (spec 7.4): files that carry one say 1.1."""
CONTEXTS_MINOR = 2
"""The minor version that added ``PATCH_INDEX_CONTEXTS`` (spec 7.5): files that carry it say 1.2."""

# spec 3.1 - fixed header, 48 bytes
FixedHeader = Struct(
    "magic" / Bytes(8),
    "version_major" / Int16ul,
    "version_minor" / Int16ul,
    "flags" / Int32ul,
    "header_size" / Int32ul,
    "layer_count" / Int16ul,
    "section_count" / Int16ul,
    "sh_degree" / Int8ul,
    "reserved" / Bytes(7),
    "gaussian_count" / Int64ul,
    "file_size" / Int64ul,
)
FIXED_HEADER_SIZE = FixedHeader.sizeof()

# spec 3.2 - layer table entry, 16 bytes
LayerEntry = Struct(
    "kind" / Int8ul,
    "reserved" / Bytes(3),
    "gaussian_count" / Int32ul,
    "end_offset" / Int64ul,
)

# spec 3.3 - table of contents entry, 40 bytes
SectionEntry = Struct(
    "type" / Int16ul,
    "codec" / Int8ul,
    "flags" / Int8ul,
    "layer" / Int16ul,
    "reserved" / Int16ul,
    "offset" / Int64ul,
    "stored_length" / Int64ul,
    "raw_length" / Int64ul,
    "crc32" / Int32ul,
    "reserved2" / Int32ul,
)

# spec 3.4 - the whole header block: fixed header, layer table, TOC, then the header CRC-32
HeaderBlock = Struct(
    "header" / FixedHeader,
    "layers" / Bytes(this.header.layer_count * LayerEntry.sizeof()),
    "sections" / Bytes(this.header.section_count * SectionEntry.sizeof()),
    "header_crc" / Int32ul,
)


def header_size(layer_count: int, section_count: int) -> int:
    """Size in bytes of the header block for the given table sizes ([R-6])."""
    return (FIXED_HEADER_SIZE + layer_count * LayerEntry.sizeof()
            + section_count * SectionEntry.sizeof() + 4)


class LayerKind(enum.IntEnum):
    """spec 3.2 - what a layer holds."""

    SKETCH = 0
    PATCH = 1


class SectionType(enum.IntEnum):
    """spec 4.1 - section type ids."""

    METADATA = 0x0001
    PREVIEW = 0x0002
    SKETCH_CLUSTERS = 0x0010
    SKETCH_POSITIONS = 0x0011
    SKETCH_COEFFICIENTS = 0x0012
    PATCH_CODEBOOKS = 0x0020
    PATCH_POSITIONS = 0x0021
    PATCH_ATTRIBUTES = 0x0022
    PATCH_INDEX_CONTEXTS = 0x0023


class Codec(enum.IntEnum):
    """spec 4.2 - section codec ids."""

    NONE = 0
    ZLIB = 1
    ZSTD = 2


SECTION_FLAG_REQUIRED = 0x01
"""TOC flag bit 0: a decoder that does not know the section type must reject the layer ([R-21])."""

# ------------------------------------------------------------------------- 6. Sketch sections
# spec 6.1 - one record per cluster, 40 bytes
ClusterRecord = Struct(
    "point_count" / Int32ul,
    "draco_length" / Int32ul,
    "center" / Array(3, Float32l),
    "half_extent" / Array(3, Float32l),
    "degrees" / Array(5, Int8ul),
    "reserved" / Bytes(3),
)

SketchClustersPayload = Struct(
    "cluster_count" / Int32ul,
    "records" / GreedyBytes,
)

SH_REST_ABSENT = 0xFF
"""Degree byte meaning "this cluster has no SH-rest model" (its SH rest decodes to zero) ([R-45])."""

# ------------------------------------------------------------------------- 7. Patch sections
# spec 7.1 - codebooks
CodebookEntry = Struct(
    "attribute" / Int8ul,
    "entry_dim" / Int8ul,
    "entry_count" / Int16ul,
    "entries" / Bytes(this.entry_count * this.entry_dim * 2),
)
PatchCodebooksPayload = Struct(
    "attribute_count" / Int8ul,
    "codebooks" / Array(this.attribute_count, CodebookEntry),
)

MAX_CODEBOOK_ENTRIES = 256


class PositionMode(enum.IntEnum):
    """spec 7.2 - how a patch layer stores positions."""

    FLOAT16 = 0
    QUANT16 = 1
    FLOAT32 = 2
    DRACO = 3


# spec 7.2 - QUANT16 parameters: position = origin + q * step, per axis
Quant16Params = Struct(
    "origin" / Array(3, Float32l),
    "step" / Array(3, Float32l),
)
PatchPositionsPayload = Struct(
    "mode" / Int8ul,
    "reserved" / Bytes(3),
    "params" / Switch(this.mode, {PositionMode.QUANT16: Quant16Params}, default=Pass),
    "data" / GreedyBytes,
)

# spec 7.3 - patch attributes: nothing but uint8 index columns
PatchAttributesPayload = Struct("indices" / GreedyBytes)


# spec 7.4 - the preview (1.1): a whole small file embedded in an optional section of layer 0
PreviewPayload = Struct(
    "takeover_layer" / Int16ul,
    "reserved" / Int16ul,
    "file" / GreedyBytes,
)
PREVIEW_PREFIX_SIZE = 4
"""Bytes of the preview payload before the embedded file."""


# --------------------------------------------------------------------------------- helpers
_NUMPY_CODES = {"B": "u1", "H": "u2", "I": "u4", "L": "u4", "Q": "u8", "e": "f2", "f": "f4", "d": "f8",
                "b": "i1", "h": "i2", "i": "i4", "l": "i4", "q": "i8"}


def _field_dtype(sub: Construct) -> np.dtype | tuple:
    """numpy dtype of one fixed-size construct field (unwrapping the ``"name" / field`` rename)."""
    while type(sub).__name__ == "Renamed":
        sub = sub.subcon
    if isinstance(sub, Array):
        return (_field_dtype(sub.subcon), sub.count)
    if isinstance(sub, FormatField):
        return np.dtype(sub.fmtstr[0] + _NUMPY_CODES[sub.fmtstr[1]])
    if type(sub).__name__ == "Bytes":
        return np.dtype(f"V{sub.sizeof()}")
    raise TypeError(f"no numpy dtype for {sub!r}")


def record_dtype(struct: Struct) -> np.dtype:
    """A numpy structured dtype with exactly the layout of a fixed-size construct ``Struct``."""
    fields = []
    for sub in struct.subcons:
        dt = _field_dtype(sub)
        fields.append((sub.name, dt[0], (dt[1],)) if isinstance(dt, tuple) else (sub.name, dt))
    dtype = np.dtype(fields)
    if dtype.itemsize != struct.sizeof():  # pragma: no cover - guards the derivation itself
        raise AssertionError(f"derived dtype size {dtype.itemsize} != {struct.sizeof()}")
    return dtype


LAYER_DTYPE = record_dtype(LayerEntry)
SECTION_DTYPE = record_dtype(SectionEntry)
CLUSTER_DTYPE = record_dtype(ClusterRecord)
