"""Building files that break exactly one rule: through the writer, or by editing bytes.

A :class:`Draft` is a file kept as its section and layer specifications (``spcodec.writer``), so a
defect can be put into one payload, codec or table field and everything else (offsets, lengths,
CRCs) derived as a writer would. Defects that live below the writer (a header field after the CRC
was computed, a flipped byte, a cut) are byte edits of an assembled file: :func:`poke` writes a
field and, unless told not to, repairs the header CRC so that the edit is the only defect.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field

from spcodec.codecs import crc32
from spcodec.container import FIXED_HEADER_SIZE, Codec, SectionType, header_size
from spcodec.writer import EncodedScene, LayerSpec, SectionSpec, assemble, scene_sections


@dataclass
class Draft:
    """A file as its parts. ``build`` keeps every section's codec as given (no fallback to codec
    none), so a vector's codecs are what its definition says."""

    sections: list[SectionSpec]
    layers: list[LayerSpec]
    sh_degree: int
    header: dict = field(default_factory=dict)
    """Fixed-header fields to override (the header CRC is computed over them)."""

    @classmethod
    def of(cls, scene: EncodedScene, codec: Codec = Codec.ZLIB) -> "Draft":
        sections, layers = scene_sections(scene, codec)
        return cls(sections, layers, scene.sh_degree)

    def insert_after_layer(self, layer: int, section: SectionSpec) -> None:
        """Add ``section`` at the end of ``layer``'s sections."""
        at = max(i for i, s in enumerate(self.sections) if s.layer == layer) + 1
        self.sections.insert(at, section)

    def set_codec(self, codec: Codec) -> None:
        """Store every section with ``codec`` (even where it does not make the section smaller)."""
        for sec in self.sections:
            sec.codec = codec

    def build(self) -> bytes:
        return assemble(self.sections, self.layers, self.sh_degree,
                        header_overrides=self.header or None, store_when_larger=False)


# ----------------------------------------------------------------------------- byte edits
def counts(data: bytes) -> tuple[int, int]:
    """(layer_count, section_count) from an assembled file's fixed header."""
    return struct.unpack_from("<HH", data, 20)


def layer_entry(layer: int) -> int:
    """Offset of layer ``layer``'s entry in the layer table."""
    return FIXED_HEADER_SIZE + 16 * layer


def toc_entry(data: bytes, index: int) -> int:
    """Offset of section ``index``'s entry in the table of contents."""
    layers, _ = counts(data)
    return FIXED_HEADER_SIZE + 16 * layers + 40 * index


def section_span(data: bytes, index: int) -> tuple[int, int]:
    """Start and end of section ``index``'s stored bytes."""
    entry = toc_entry(data, index)
    offset, length = struct.unpack_from("<QQ", data, entry + 8)
    return offset, offset + length


def repair_header_crc(data: bytes) -> bytes:
    """Recompute the header CRC where the layer and section counts say it is ([R-8])."""
    size = header_size(*counts(data))
    buf = bytearray(data)
    struct.pack_into("<I", buf, size - 4, crc32(bytes(buf[:size - 4])))
    return bytes(buf)


def poke(data: bytes, offset: int, fmt: str, value, repair: bool = True) -> bytes:
    """Write ``value`` as struct format ``fmt`` (little-endian) at ``offset``; then repair the
    header CRC unless ``repair`` is False or the edit moved where the CRC lives."""
    buf = bytearray(data)
    struct.pack_into("<" + fmt, buf, offset, value)
    out = bytes(buf)
    return repair_header_crc(out) if repair else out


def flip(data: bytes, offset: int, mask: int = 0x01) -> bytes:
    """``data`` with one byte changed (no checksum repaired: the change is the defect)."""
    buf = bytearray(data)
    buf[offset] ^= mask
    return bytes(buf)


def metadata(text: bytes, codec: Codec = Codec.ZLIB) -> SectionSpec:
    """A METADATA section holding ``text``."""
    return SectionSpec(SectionType.METADATA, 0, text, codec, required=False)
