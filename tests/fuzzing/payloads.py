"""Mutators of section payloads: the raw (decompressed) bytes edited field by field where the layout
is known, or the stored (compressed) bytes damaged; checksums repaired either way, so the damage
reaches the decompressors, Draco and the section parsers behind the CRCs."""

from __future__ import annotations

import struct

from spcodec.codecs import compress
from spcodec.container import Codec, PositionMode, SectionType
from spcodec.writer import SectionSpec

from .choosers import Chooser, chance, choice
from .edits import Field, array_fields, havoc, poke
from .seeds import SeedFile, copy_sections, pick_section, rebuild


def cluster_fields(raw: bytes) -> list[Field]:
    """SKETCH_CLUSTERS ([R-40]): the count, then each record's fields."""
    fields = [Field(0, "I")]
    count = (len(raw) - 4) // 40
    for i in range(min(count, 16)):
        base = 4 + 40 * i
        fields += [Field(base, "I"), Field(base + 4, "I")]
        fields += array_fields(base + 8, "f", 6)
        fields += array_fields(base + 32, "B", 8)
    return fields


def codebook_fields(raw: bytes) -> list[Field]:
    """PATCH_CODEBOOKS ([R-50]): attribute_count, then each codebook header and entries."""
    fields, pos = [Field(0, "B")], 1
    while pos + 4 <= len(raw):
        dim, count = raw[pos + 1], struct.unpack_from("<H", raw, pos + 2)[0]
        fields += [Field(pos, "B"), Field(pos + 1, "B"), Field(pos + 2, "H")]
        fields += array_fields(pos + 4, "e", count * dim, 8)
        pos += 4 + 2 * count * dim
    return fields


def position_fields(raw: bytes) -> list[Field]:
    """PATCH_POSITIONS ([R-53]): mode, reserved, QUANT16 origin/step, the first values."""
    fields = array_fields(0, "B", 4)
    mode = raw[0] if raw else 0
    if mode == PositionMode.QUANT16:
        return fields + array_fields(4, "f", 6) + array_fields(28, "H", 32)
    if mode == PositionMode.DRACO:
        return fields + [Field(4 + f.offset, f.fmt) for f in DRACO_FIELDS]
    return fields + array_fields(4, "f" if mode == PositionMode.FLOAT32 else "e", 32)


DRACO_FIELDS = [Field(5, "B"), Field(6, "B"), Field(7, "B"), Field(8, "B"), Field(9, "H"),
                Field(11, "i"), Field(15, "B"), Field(16, "B"), Field(17, "B"), Field(18, "B"),
                Field(19, "I")]
"""Draco header: version major/minor, encoder type, method, flags, then (point clouds without
metadata) the int32 point count and the first attribute-decoder bytes."""


def sketch_position_fields(seed: SeedFile) -> list[Field]:
    """Draco header fields of every blob in SKETCH_POSITIONS (blob starts from the cluster table)."""
    table = next(s.raw for s in seed.sections if s.type == SectionType.SKETCH_CLUSTERS)
    count = struct.unpack_from("<I", table, 0)[0]
    starts, pos = [], 0
    for i in range(count):
        length = struct.unpack_from("<I", table, 4 + 40 * i + 4)[0]
        if length:
            starts.append(pos)
            pos += length
    return [Field(s + f.offset, f.fmt) for s in starts for f in DRACO_FIELDS]


def layout_fields(seed: SeedFile, sec: SectionSpec) -> list[Field]:
    """Known fields of a section payload, or none (generic byte mutation only)."""
    if sec.type == SectionType.SKETCH_CLUSTERS:
        return cluster_fields(sec.raw)
    if sec.type == SectionType.PATCH_CODEBOOKS:
        return codebook_fields(sec.raw)
    if sec.type == SectionType.PATCH_POSITIONS:
        return position_fields(sec.raw)
    if sec.type == SectionType.SKETCH_POSITIONS:
        return sketch_position_fields(seed)
    if sec.type == SectionType.SKETCH_COEFFICIENTS:
        return array_fields(0, "e", len(sec.raw) // 2, 256)
    if sec.type == SectionType.PATCH_ATTRIBUTES:
        return array_fields(0, "B", len(sec.raw), 256)
    return []


def metadata_payload(ch: Chooser) -> bytes:
    """Hostile JSON-ish metadata: deep nesting, bad UTF-8, non-objects, huge numbers, NaN."""
    depth = choice(ch, [10, 1000, 5000, 100_000])
    options = [
        b"[" * depth + b"]" * depth,
        b'{"a":' * depth + b"1" + b"}" * depth,
        b"[" * depth,
        b"\xff\xfe{}",
        b'{"x": "\xed\xa0\x80"}',
        b"[1, 2, 3]",
        b"null",
        b'{"n": ' + b"9" * 10_000 + b"}",
        b'{"n": NaN, "i": Infinity}',
        b'{"s": "\\ud800"}',
        b"{" + b'"k":1,' * 1000 + b'"k":2}',
        b"",
        ch.blob(ch.integer(0, 64)),
    ]
    return choice(ch, options)


def recompress(sec: SectionSpec, raw: bytes) -> None:
    """Give a section a new raw payload, stored with the section's codec, lengths derived."""
    sec.raw = raw
    sec.stored = compress(Codec(sec.codec), raw, 1) if sec.codec in (1, 2) else raw
    sec.raw_length = None
    sec.crc = None


def mutate_payload(seed: SeedFile, seeds: list[SeedFile], ch: Chooser) -> bytes:
    """Edit a raw payload (structure-aware where the layout is known), recompress, repair CRCs."""
    sections = copy_sections(seed.sections)
    sec = sections[pick_section(seed, ch)]
    if sec.type == SectionType.METADATA and chance(ch, 60):
        raw = metadata_payload(ch)
    else:
        buf = bytearray(sec.raw)
        fields = layout_fields(seed, sec)
        if fields and chance(ch, 75):
            for _ in range(ch.integer(1, 3)):
                poke(buf, choice(ch, fields), ch)
            raw = bytes(buf)
        else:
            raw = havoc(bytes(buf), ch)
    recompress(sec, raw)
    return rebuild(seed, sections)


def mutate_stored(seed: SeedFile, seeds: list[SeedFile], ch: Chooser) -> bytes:
    """Edit a section's stored bytes and recompute its CRC: decompressors and Draco on garbage."""
    sections = copy_sections(seed.sections)
    sec = sections[pick_section(seed, ch)]
    sec.stored = havoc(sec.stored, ch)
    if chance(ch, 30):
        sec.raw_length = max(0, len(sec.raw) + ch.integer(-3, 3))
    else:
        sec.raw_length = len(sec.raw)
    return rebuild(seed, sections)
