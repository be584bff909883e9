"""Vectors of spec 1.1: the ``PREVIEW`` section (7.4), which decoding the scene never reads.

What a decoder's scene decode must do with a preview is [R-102]: check its CRC and nothing else,
so 1.0 decoders (to which it is an optional section of an unknown type) and 1.1 decoders agree on
every input. Decoding the preview itself ([R-103]) is a separate, optional feature that the
runner's decode interface does not reach; the reference and JavaScript decoders' own tests check
it on ``preview-section``.
"""

from __future__ import annotations

import struct

from spcodec.container import Codec, PositionMode, SectionType
from spcodec.writer import Preview, SectionSpec

from . import scenes
from .declare import invalid, valid
from .forge import Draft


def preview_file() -> bytes:
    """A small whole 1.0 file to embed: two clusters and one patch layer, SH 1."""
    return Draft.of(scenes.scene(40, 1, [4, 3], [PositionMode.QUANT16], 5)).build()


def scene_draft(seed: int) -> Draft:
    """The scene a preview is added to: metadata, sketch and two patch layers, SH 1."""
    scene = scenes.scene(seed, 1, [5, 4], [PositionMode.QUANT16, PositionMode.FLOAT16], 6,
                         metadata={"generator": "spcodec conformance"})
    return Draft.of(scene)


def preview_section(payload: bytes, codec: Codec = Codec.NONE, layer: int = 0) -> SectionSpec:
    return SectionSpec(SectionType.PREVIEW, layer, payload, codec, required=False)


def with_preview(seed: int = 41) -> Draft:
    """The scene with a valid preview right after its metadata, taking over at layer 1."""
    draft = scene_draft(seed)
    draft.sections.insert(1, preview_section(Preview(preview_file(), 1).payload()))
    return draft


@valid("preview-section",
       "Version 1.1: a preview (a whole small file, takeover at layer 1) between the metadata and "
       "the sketch; the scene and its prefixes decode as they would without it",
       ["R-102", "R-20", "R-92", "R-11", "R-104"], prefixes=True)
def preview_valid() -> bytes:
    return with_preview().build()


@valid("preview-sections-never-read",
       "PREVIEW sections that are not previews a decoder could show: a payload of 3 bytes, one "
       "with reserved bits, takeover and gzip magic wrong, a second in layer 0, one in layer 2, "
       "one with the unknown codec 7; the scene decodes all the same",
       ["R-102", "R-20", "R-22"])
def preview_never_read() -> bytes:
    draft = scene_draft(42)
    junk = struct.pack("<HH", 9, 1) + b"\x1f\x8b not a file"
    draft.sections.insert(1, preview_section(b"\x00\x01\x02"))
    draft.sections.insert(2, preview_section(junk, Codec.ZLIB))
    draft.insert_after_layer(2, preview_section(Preview(preview_file(), 0).payload(),
                                                layer=2))
    draft.insert_after_layer(1, SectionSpec(SectionType.PREVIEW, 1, b"", 7, required=False,
                                            stored=b"\x07" * 5))
    return draft.build()


@invalid("section-crc-preview", "The preview section's CRC does not match: the layer holding it "
         "does not decode, though the scene never reads the preview", "section-crc",
         ["R-7", "R-102"])
def preview_crc() -> bytes:
    draft = with_preview(43)
    draft.sections[1].crc = 0
    return draft.build()
