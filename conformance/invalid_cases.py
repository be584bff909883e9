"""Invalid vectors: files every conforming decoder must reject, each with the code it must report.

Each file carries one defect, put into an otherwise valid file through the writer (a payload, a
codec, a table field) or by editing its bytes with the checksums repaired, so that the defect is
what the decoder meets. The few that cannot (a claim beyond a limit that no small file can honour)
list the other codes a decoder may report. Past fuzzing findings that a file can express are here
(see ``vectors/invalid/README.md``).
"""

from __future__ import annotations

import gzip
import struct
import zlib
from functools import lru_cache

import numpy as np

from spcodec.codecs import crc32, gzip_wrap, read_gzip_layer_ends
from spcodec.container import Codec, LayerKind, PositionMode, SectionType
from spcodec.polynomial import monomial_count
from spcodec.writer import EncodedScene, LayerSpec, SectionSpec, assemble, layer_end_offsets

from . import scenes
from .declare import invalid
from .forge import (
    Draft,
    flip,
    layer_entry,
    metadata,
    poke,
    section_span,
    toc_entry,
)

T = SectionType
META, CLUSTERS, SKETCH_POS, COEFFS, BOOKS, POS1, ATTR1, POS2, ATTR2 = range(9)
"""Section indices of the base file."""


@lru_cache(maxsize=None)
def _base_scene(sh_degree: int = 1, modes: tuple[PositionMode, ...] = (PositionMode.QUANT16,
                                                                        PositionMode.FLOAT16)
                ) -> EncodedScene:
    """SH 1 (by default): a kd-tree cluster, two clusters sharing a sequential blob; two patch
    layers of six Gaussians; metadata. About 1.5 KB."""
    return scenes.scene(100 + sh_degree, sh_degree, [6, 4, 5], list(modes), 6, runs=[1, 2],
                        entries=4, metadata={"generator": "spcodec conformance"})


def base(sh_degree: int = 1, modes: tuple[PositionMode, ...] = (PositionMode.QUANT16,
                                                                 PositionMode.FLOAT16),
         codec: Codec = Codec.ZLIB) -> Draft:
    """A fresh, editable draft of a base file (sections as the writer lays them out)."""
    return Draft.of(_base_scene(sh_degree, modes), codec)


def base_bytes(**kwargs) -> bytes:
    return base(**kwargs).build()


def edit_raw(draft: Draft, index: int, edit) -> Draft:
    """Replace section ``index``'s payload by ``edit(bytearray)`` (recompressed, CRC derived)."""
    sec = draft.sections[index]
    buf = bytearray(sec.raw)
    result = edit(buf)
    sec.raw = bytes(buf if result is None else result)
    sec.stored = None
    return draft


def record(i: int) -> int:
    """Offset of cluster record ``i`` in the SKETCH_CLUSTERS payload."""
    return 4 + 40 * i


# ======================================================================== bad-magic
@invalid("magic-high-bit-cleared", "The magic's first byte with its eighth bit cleared, as a "
         "7-bit transfer leaves it", "bad-magic", ["R-3"])
def magic_high_bit() -> bytes:
    return flip(base_bytes(), 0, 0x80)


@invalid("magic-line-endings-converted", "The magic's CR LF turned into LF, as a text-mode "
         "transfer does", "bad-magic", ["R-3"])
def magic_crlf() -> bytes:
    data = base_bytes()
    return data[:4] + b"\n" + data[6:]


@invalid("short-not-magic", "Three bytes that do not start the magic", "bad-magic", ["R-3"])
def short_not_magic() -> bytes:
    return b"PK\x03"


@invalid("gzip-bomb-of-zeros", "A gzip member of 8 MiB of zeros (8 KB stored): no magic inside",
         "bad-magic", ["R-3", "R-80", "R-84"])
def gzip_zeros() -> bytes:
    return gzip.compress(b"\0" * (8 << 20), 9, mtime=0)


# ============================================================== unsupported-version
@invalid("version-major-2", "version_major 2 (header CRC repaired)", "unsupported-version",
         ["R-5", "R-91"])
def version_2() -> bytes:
    return poke(base_bytes(), 8, "H", 2)


@invalid("version-major-0", "version_major 0 (header CRC repaired)", "unsupported-version",
         ["R-5", "R-91"])
def version_0() -> bytes:
    return poke(base_bytes(), 8, "H", 0)


# ================================================================= reserved-nonzero
@invalid("header-flags-set", "The fixed header's flags are 1", "reserved-nonzero", ["R-5"])
def header_flags() -> bytes:
    return poke(base_bytes(), 12, "I", 1)


@invalid("header-reserved-set", "The last reserved byte of the fixed header is 1",
         "reserved-nonzero", ["R-5"])
def header_reserved() -> bytes:
    return poke(base_bytes(), 31, "B", 1)


@invalid("layer-reserved-set", "A reserved byte of layer 1's table entry is 1", "reserved-nonzero",
         ["R-9"])
def layer_reserved() -> bytes:
    data = base_bytes()
    return poke(data, layer_entry(1) + 2, "B", 1)


@invalid("toc-flag-bit-set", "Bit 1 of a section's flags is set", "reserved-nonzero", ["R-15"])
def toc_flags() -> bytes:
    draft = base()
    draft.sections[CLUSTERS].flags = 0x03
    return draft.build()


@invalid("toc-reserved-set", "A section's reserved u16 is 1", "reserved-nonzero", ["R-15"])
def toc_reserved() -> bytes:
    draft = base()
    draft.sections[COEFFS].reserved = 1
    return draft.build()


@invalid("toc-reserved2-set", "A section's reserved2 u32 is 0x80000000", "reserved-nonzero",
         ["R-15"])
def toc_reserved2() -> bytes:
    data = base_bytes()
    return poke(data, toc_entry(data, POS2) + 36, "I", 0x80000000)


@invalid("cluster-reserved-set", "A cluster record's reserved bytes are not zero",
         "reserved-nonzero", ["R-45"])
def cluster_reserved() -> bytes:
    return edit_raw(base(), CLUSTERS, lambda b: b.__setitem__(record(1) + 38, 1)).build()


@invalid("positions-reserved-set", "A PATCH_POSITIONS payload's reserved bytes are not zero",
         "reserved-nonzero", ["R-53"])
def positions_reserved() -> bytes:
    return edit_raw(base(), POS1, lambda b: b.__setitem__(2, 9)).build()


# ======================================================================== truncated
@invalid("empty-input", "Zero bytes", "truncated", ["R-3", "R-12"])
def empty_input() -> bytes:
    return b""


@invalid("magic-prefix", "The first five bytes of the magic", "truncated", ["R-3", "R-12"])
def magic_prefix() -> bytes:
    return base_bytes()[:5]


@invalid("gzip-first-byte", "The single byte 1F", "truncated", ["R-3"])
def gzip_first_byte() -> bytes:
    return b"\x1f"


@invalid("gzip-magic-only", "The two bytes 1F 8B: a gzip header cut before it holds any inner "
         "byte", "truncated", ["R-3", "R-81"])
def gzip_magic_only() -> bytes:
    return b"\x1f\x8b"


@invalid("gzip-cut-in-header", "A gzip-wrapped file cut inside the FEXTRA field of its header",
         "truncated", ["R-3", "R-81"])
def gzip_cut_header() -> bytes:
    return _wrapped()[:15]


@invalid("cut-in-fixed-header", "A file cut after 30 bytes, inside the fixed header", "truncated",
         ["R-12"])
def cut_fixed_header() -> bytes:
    return base_bytes()[:30]


@invalid("cut-in-header-block", "A file cut 10 bytes before the end of its header block",
         "truncated", ["R-12"])
def cut_header_block() -> bytes:
    data = base_bytes()
    return data[:section_span(data, 0)[0] - 10]


@invalid("cut-inside-layer-1", "A file cut in the middle of layer 1; layer 0 decodes with "
         "--max-layer 0", "truncated", ["R-11", "R-12"], max_layers=(0, 1))
def cut_layer_1() -> bytes:
    data = base_bytes()
    start, end = layer_end_offsets(data)[:2]
    return data[:(start + end) // 2]


@invalid("cut-one-byte-short", "A file missing its last byte; layers 0 and 1 decode with "
         "--max-layer", "truncated", ["R-12"], max_layers=(1, 2))
def cut_last_byte() -> bytes:
    return base_bytes()[:-1]


@invalid("gzip-cut-inside-layer", "A gzip-wrapped file cut inside layer 2's deflate data",
         "truncated", ["R-81", "R-12"], max_layers=(1, 2))
def gzip_cut_layer() -> bytes:
    wrapped = _wrapped()
    ends = read_gzip_layer_ends(wrapped)
    return wrapped[:(ends[1] + ends[2]) // 2]


def _wrapped() -> bytes:
    inner = base_bytes()
    return gzip_wrap(inner, layer_end_offsets(inner))


# ==================================================================== trailing-data
@invalid("trailing-zero-byte", "One zero byte after file_size; also with --max-layer 0",
         "trailing-data", ["R-4"], max_layers=(0,))
def trailing_byte() -> bytes:
    return base_bytes() + b"\0"


@invalid("trailing-second-file", "A second copy of the file after the first", "trailing-data",
         ["R-4"])
def trailing_copy() -> bytes:
    return base_bytes() * 2


@invalid("gzip-second-member", "A second gzip member after the wrapper; also with --max-layer 0",
         "trailing-data", ["R-82"], max_layers=(0,))
def gzip_second_member() -> bytes:
    return _wrapped() + gzip.compress(b"x", 9, mtime=0)


@invalid("gzip-inflates-past-file-size", "A gzip member holding a valid file followed by 8 MiB "
         "of zeros (8 KB stored)", "trailing-data", ["R-84", "R-4"])
def gzip_past_file_size() -> bytes:
    return gzip.compress(base_bytes() + b"\0" * (8 << 20), 9, mtime=0)


# ======================================================================= header-crc
@invalid("header-crc-wrong", "The stored header CRC with one bit flipped", "header-crc", ["R-8"])
def header_crc() -> bytes:
    data = base_bytes()
    return flip(data, section_span(data, 0)[0] - 2, 0x10)


@invalid("header-field-changed", "A layer's end_offset changed without repairing the header CRC",
         "header-crc", ["R-8"])
def header_field() -> bytes:
    data = base_bytes()
    return poke(data, layer_entry(1) + 8, "Q",
                struct.unpack_from("<Q", data, layer_entry(1) + 8)[0] + 1, repair=False)


# ====================================================================== section-crc
@invalid("section-crc-sketch-clusters", "A byte of the cluster table's zlib data changed: its "
         "CRC fails, and it must be reported so, not as a decompression failure", "section-crc",
         ["R-7"])
def section_crc_clusters() -> bytes:
    data = base_bytes()
    start, end = section_span(data, CLUSTERS)
    return flip(data, (start + end) // 2, 0xFF)


@invalid("section-crc-patch-layer-2", "A byte of layer 2's attributes changed; layers 0 and 1 "
         "decode with --max-layer", "section-crc", ["R-7"], max_layers=(1, 2))
def section_crc_layer_2() -> bytes:
    data = base_bytes()
    return flip(data, section_span(data, ATTR2)[0], 0x01)


@invalid("section-crc-optional-unknown", "An optional section of unknown type in layer 1 whose "
         "CRC does not match: skipped sections are CRC-checked too", "section-crc",
         ["R-7", "R-20"], max_layers=(0, 1))
def section_crc_optional() -> bytes:
    draft = base()
    draft.insert_after_layer(1, SectionSpec(0x7F00, 1, b"skip me", Codec.NONE, required=False,
                                            crc=0x12345678))
    return draft.build()


@invalid("section-crc-metadata", "The metadata section's CRC does not match", "section-crc",
         ["R-7", "R-70"])
def section_crc_metadata() -> bytes:
    draft = base()
    draft.sections[META].crc = 0
    return draft.build()


# =================================================================== limit-exceeded
@invalid("gaussian-density", "1 000 001 Gaussians (all present) in a 10 KB file: more than "
         "max(1 000 000, 64 x file_size)", "limit-exceeded", ["R-61"])
def gaussian_density() -> bytes:
    from spcodec.attributes import PatchAttribute
    from spcodec.sections import Codebook, PatchPositions
    from spcodec.writer import PatchLayer

    n = 1_000_001
    books = [Codebook(a, np.zeros((1, a.width), np.float16)) for a in PatchAttribute.for_sh_degree(0)]
    books[1].entries[0, 0] = 1.0
    books[2].entries[0, 0] = 0.5
    indices = {cb.attribute: np.zeros((n, 1), np.uint8) for cb in books}
    layer = PatchLayer(PatchPositions.float16(np.zeros((n, 3))), indices)
    return Draft.of(EncodedScene(0, [], books, [layer])).build()


@invalid("expansion-beyond-1024x", "An optional section whose zstd data inflates to 64 MiB + 1 "
         "byte (declared honestly) in a 3 KB file: more than max(64 MiB, 1024 x file_size)",
         "limit-exceeded", ["R-61", "R-60"], max_layers=(0,))
def expansion() -> bytes:
    draft = base()
    draft.insert_after_layer(0, SectionSpec(0x7F00, 0, b"\0" * ((64 << 20) + 1), Codec.ZSTD,
                                            required=False))
    return draft.build()


@invalid("metadata-over-16-mib", "A metadata section of 16 MiB + 1 byte (zlib, 16 KB stored), "
         "checked before it is inflated", "limit-exceeded", ["R-60", "R-70"])
def metadata_limit() -> bytes:
    draft = base()
    draft.sections[META] = metadata(b" " * ((16 << 20) + 1))
    return draft.build()


@invalid("layer-count-over-limit", "1025 layers (1023 of them empty patch layers), gzip-wrapped "
         "to keep the 100 KB header small", "limit-exceeded", ["R-60"], max_layers=(0,))
def too_many_layers() -> bytes:
    scene = _base_scene()
    draft = Draft.of(EncodedScene(1, scene.sketch, scene.codebooks, scene.patch_layers[:1]))
    empty = bytes([PositionMode.FLOAT16, 0, 0, 0])
    for k in range(2, 1025):
        draft.sections.append(SectionSpec(T.PATCH_POSITIONS, k, empty, Codec.NONE))
        draft.sections.append(SectionSpec(T.PATCH_ATTRIBUTES, k, b"", Codec.NONE))
        draft.layers.append(LayerSpec(LayerKind.PATCH, 0))
    inner = draft.build()
    return gzip_wrap(inner, [])


@invalid("section-count-over-limit", "4097 sections (4090 empty optional ones), gzip-wrapped",
         "limit-exceeded", ["R-60"], max_layers=(0,))
def too_many_sections() -> bytes:
    draft = base()
    filler = [SectionSpec(0x7F00, 0, b"", Codec.NONE, required=False)
              for _ in range(4097 - len(draft.sections))]
    draft.sections[COEFFS + 1:COEFFS + 1] = filler
    return gzip_wrap(draft.build(), [])


@invalid("cluster-count-claim", "The cluster table claims 2^32 - 1 clusters but holds three",
         "limit-exceeded", ["R-60", "R-62"], also_accepted=("bad-section",))
def cluster_count_claim() -> bytes:
    return edit_raw(base(), CLUSTERS, lambda b: struct.pack_into("<I", b, 0, 0xFFFFFFFF)).build()


@invalid("section-raw-length-claim", "An optional section in layer 2 declaring a raw length of "
         "2^31 + 1 bytes; limits apply to every table entry, whatever its layer and type",
         "limit-exceeded", ["R-60", "R-61"], max_layers=(0,))
def raw_length_claim() -> bytes:
    draft = base()
    draft.insert_after_layer(2, SectionSpec(0x7F00, 2, b"8 bytes!", Codec.NONE, required=False,
                                            raw_length=(1 << 31) + 1))
    return draft.build()


@invalid("layer-count-claim-density", "Layer 2 claims 60 000 000 Gaussians (the header's total "
         "agrees) in a 1.5 KB file (a fuzzing finding: 14 GB were allocated)", "limit-exceeded",
         ["R-61", "R-62"], also_accepted=("bad-section",))
def layer_claim_density() -> bytes:
    draft = base()
    draft.layers[2].gaussian_count = 60_000_000
    return draft.build()


@invalid("codebook-entries-claim", "A codebook claiming 65535 entries of 255 components",
         "bad-section", ["R-50", "R-51", "R-62"], also_accepted=("bad-value",))
def codebook_claim() -> bytes:
    def claim(b):
        b[2] = 255
        struct.pack_into("<H", b, 3, 0xFFFF)
    return edit_raw(base(), BOOKS, claim).build()


# ======================================================================= bad-layout
@invalid("header-size-wrong", "header_size 4 more than the tables need", "bad-layout", ["R-6"])
def header_size_wrong() -> bytes:
    data = base_bytes()
    return poke(data, 16, "I", struct.unpack_from("<I", data, 16)[0] + 4)


@invalid("no-layers", "A layer_count of 0 (header_size and offsets consistent with it)",
         "bad-layout", ["R-6"])
def no_layers() -> bytes:
    draft = base()
    return assemble(draft.sections, [], draft.sh_degree, store_when_larger=False)


@invalid("two-sections", "A section_count of 2: layer 0 without its coefficients", "bad-layout",
         ["R-6"], also_accepted=("missing-section",))
def two_sections() -> bytes:
    scene = _base_scene()
    draft = Draft.of(EncodedScene(1, scene.sketch))
    draft.sections = [s for s in draft.sections if s.type != T.SKETCH_COEFFICIENTS]
    return draft.build()


@invalid("sections-overlap", "Section 2 starts one byte before section 1 ends", "bad-layout",
         ["R-4"])
def sections_overlap() -> bytes:
    data = base_bytes()
    entry = toc_entry(data, SKETCH_POS) + 8
    return poke(data, entry, "Q", struct.unpack_from("<Q", data, entry)[0] - 1)


@invalid("sections-gap", "One byte between sections 3 and 4", "bad-layout", ["R-4"])
def sections_gap() -> bytes:
    data = base_bytes()
    entry = toc_entry(data, BOOKS) + 8
    return poke(data, entry, "Q", struct.unpack_from("<Q", data, entry)[0] + 1)


@invalid("section-beyond-file", "The last section's offset 100 bytes past the end of the file",
         "bad-layout", ["R-4"])
def section_beyond() -> bytes:
    data = base_bytes()
    entry = toc_entry(data, ATTR2) + 8
    return poke(data, entry, "Q", len(data) + 100)


@invalid("file-size-too-large", "file_size 10 bytes more than where the last section ends",
         "bad-layout", ["R-4"])
def file_size_large() -> bytes:
    data = base_bytes()
    return poke(data, 40, "Q", len(data) + 10)


@invalid("section-length-wraps", "A stored_length of 2^64 - 16: offset + length wraps around "
         "64 bits to land before the section", "bad-layout", ["R-2", "R-4"])
def length_wraps() -> bytes:
    data = base_bytes()
    return poke(data, toc_entry(data, COEFFS) + 16, "Q", (1 << 64) - 16)


@invalid("layer-1-kind-sketch", "Layer 1 has kind 0 (sketch)", "bad-layout", ["R-9"])
def layer_kind() -> bytes:
    data = base_bytes()
    return poke(data, layer_entry(1), "B", 0)


@invalid("layer-0-kind-patch", "Layer 0 has kind 1 (patch)", "bad-layout", ["R-9"])
def layer_0_kind() -> bytes:
    data = base_bytes()
    return poke(data, layer_entry(0), "B", 1)


@invalid("layer-counts-dont-add-up", "The header's gaussian_count is one less than the layers' "
         "sum", "bad-layout", ["R-9"])
def counts_sum() -> bytes:
    data = base_bytes()
    return poke(data, 32, "Q", struct.unpack_from("<Q", data, 32)[0] - 1)


@invalid("layer-end-offset-wrong", "Layer 1's end_offset one byte before its last section ends",
         "bad-layout", ["R-9"])
def end_offset_wrong() -> bytes:
    data = base_bytes()
    entry = layer_entry(1) + 8
    return poke(data, entry, "Q", struct.unpack_from("<Q", data, entry)[0] - 1)


@invalid("section-layer-out-of-range", "The last section names layer 3 of a 3-layer file",
         "bad-layout", ["R-10"])
def layer_out_of_range() -> bytes:
    data = base_bytes()
    return poke(data, toc_entry(data, ATTR2) + 4, "H", 3)


@invalid("section-layer-decreasing", "Layer 2's positions stored between layer 1's positions and "
         "attributes (each layer still complete)", "bad-layout", ["R-10"])
def layer_decreasing() -> bytes:
    draft = base()
    s = draft.sections
    s[ATTR1], s[POS2] = s[POS2], s[ATTR1]
    return draft.build()


@invalid("codebooks-in-layer-2", "A copy of PATCH_CODEBOOKS in layer 2", "bad-layout", ["R-13"])
def codebooks_layer_2() -> bytes:
    draft = base()
    draft.insert_after_layer(2, SectionSpec(T.PATCH_CODEBOOKS, 2, draft.sections[BOOKS].raw))
    return draft.build()


@invalid("metadata-in-layer-1", "A METADATA section in layer 1", "bad-layout", ["R-13"])
def metadata_layer_1() -> bytes:
    draft = base()
    section = metadata(b"{}")
    section.layer = 1
    draft.insert_after_layer(1, section)
    return draft.build()


@invalid("required-flag-cleared", "SKETCH_CLUSTERS flagged optional", "bad-layout", ["R-14"])
def required_cleared() -> bytes:
    draft = base()
    draft.sections[CLUSTERS].required = False
    return draft.build()


@invalid("metadata-flagged-required", "METADATA flagged required", "bad-layout", ["R-14"])
def metadata_required() -> bytes:
    draft = base()
    draft.sections[META].required = True
    return draft.build()


# ==================================================================== unknown-codec
@invalid("unknown-codec-3", "The coefficient section has codec id 3", "unknown-codec", ["R-22"])
def codec_3() -> bytes:
    draft = base()
    sec = draft.sections[COEFFS]
    sec.codec, sec.stored = 3, sec.raw
    return draft.build()


@invalid("unknown-codec-in-layer-2", "Layer 2's attributes have codec id 255; layers 0 and 1 "
         "decode with --max-layer", "unknown-codec", ["R-22"], max_layers=(1, 2))
def codec_255() -> bytes:
    draft = base()
    sec = draft.sections[ATTR2]
    sec.codec, sec.stored = 255, sec.raw
    return draft.build()


# ========================================================= unknown-required-section
@invalid("unknown-required-section-layer-2", "A required section of unknown type in layer 2; "
         "layers 0 and 1 decode with --max-layer", "unknown-required-section", ["R-21"],
         max_layers=(1, 2))
def unknown_required_2() -> bytes:
    draft = base()
    draft.insert_after_layer(2, SectionSpec(0x7F00, 2, b"future", Codec.NONE))
    return draft.build()


@invalid("unknown-required-section-layer-0", "A required section of unknown type in layer 0",
         "unknown-required-section", ["R-21"], max_layers=(0,))
def unknown_required_0() -> bytes:
    draft = base()
    draft.insert_after_layer(0, SectionSpec(0x7F01, 0, b"future", Codec.NONE))
    return draft.build()


# =================================================================== missing-section
@invalid("layer-without-sections", "A fourth layer, of zero Gaussians, with no section; its "
         "end_offset (where the header block ends) is neither the end of a section of its own "
         "nor after the third layer's, so either code", "missing-section", ["R-9"],
         also_accepted=("bad-layout",))
def layer_without_sections() -> bytes:
    draft = base()
    draft.layers.append(LayerSpec(LayerKind.PATCH, 0))
    return draft.build()


@invalid("sketch-coefficients-missing", "Layer 0 without SKETCH_COEFFICIENTS", "missing-section",
         ["R-13"])
def coefficients_missing() -> bytes:
    draft = base()
    del draft.sections[COEFFS]
    return draft.build()


@invalid("codebooks-missing", "Layer 1 without PATCH_CODEBOOKS", "missing-section", ["R-13"])
def codebooks_missing() -> bytes:
    draft = base()
    del draft.sections[BOOKS]
    return draft.build()


@invalid("patch-attributes-missing", "Layer 2 without PATCH_ATTRIBUTES", "missing-section",
         ["R-13"], max_layers=(1,))
def attributes_missing() -> bytes:
    draft = base()
    del draft.sections[ATTR2]
    return draft.build()


# ================================================================= duplicate-section
@invalid("sketch-clusters-twice", "Two SKETCH_CLUSTERS sections in layer 0", "duplicate-section",
         ["R-13"])
def clusters_twice() -> bytes:
    draft = base()
    draft.sections.insert(COEFFS + 1, SectionSpec(T.SKETCH_CLUSTERS, 0, draft.sections[CLUSTERS].raw))
    return draft.build()


@invalid("metadata-twice", "Two METADATA sections in layer 0", "duplicate-section", ["R-13"])
def metadata_twice() -> bytes:
    draft = base()
    draft.sections.insert(1, metadata(b"{}"))
    return draft.build()


@invalid("patch-positions-twice", "Two PATCH_POSITIONS sections in layer 2", "duplicate-section",
         ["R-13"], max_layers=(1,))
def positions_twice() -> bytes:
    draft = base()
    draft.insert_after_layer(2, SectionSpec(T.PATCH_POSITIONS, 2, draft.sections[POS2].raw))
    return draft.build()


# ============================================================== decompression-failed
def _stored(index: int, stored: bytes, codec: Codec = Codec.ZLIB, raw_length: int | None = None,
            draft: Draft | None = None) -> bytes:
    """The base file with section ``index`` storing ``stored`` (CRC computed over it)."""
    draft = draft or base()
    sec = draft.sections[index]
    sec.codec, sec.stored = codec, stored
    sec.raw_length = len(sec.raw) if raw_length is None else raw_length
    return draft.build()


def _coefficients() -> bytes:
    return base().sections[COEFFS].raw


@invalid("zlib-corrupt", "Coefficients whose zlib data has an invalid block type (CRC "
         "matches)", "decompression-failed", ["R-24"])
def zlib_corrupt() -> bytes:
    good = zlib.compress(_coefficients(), 9)
    return _stored(COEFFS, good[:2] + bytes([0x07]) + good[3:])


@invalid("zlib-preset-dictionary", "A zlib stream that needs a preset dictionary (FDICT 1)",
         "decompression-failed", ["R-22"])
def zlib_dictionary() -> bytes:
    deflater = zlib.compressobj(9, zdict=b"spcodec")
    return _stored(COEFFS, deflater.compress(_coefficients()) + deflater.flush())


@invalid("zlib-cut-short", "A zlib stream missing its last 4 bytes (the Adler-32)",
         "decompression-failed", ["R-24"])
def zlib_cut() -> bytes:
    return _stored(COEFFS, zlib.compress(_coefficients(), 9)[:-4])


@invalid("zlib-trailing-bytes", "Two bytes after the end of a zlib stream",
         "decompression-failed", ["R-24"])
def zlib_trailing() -> bytes:
    return _stored(COEFFS, zlib.compress(_coefficients(), 9) + b"\0\0")


def _zstd(raw: bytes, **options) -> bytes:
    import zstandard

    return zstandard.ZstdCompressor(level=3, write_content_size=True, **options).compress(raw)


_SKIPPABLE = struct.pack("<II", 0x184D2A50, 4) + b"spc!"


@invalid("zstd-skippable-frame", "A zstd section whose frame is followed by a skippable frame "
         "(a fuzzing finding)", "decompression-failed", ["R-22", "R-24"])
def zstd_skippable() -> bytes:
    return _stored(COEFFS, _zstd(_coefficients()) + _SKIPPABLE, Codec.ZSTD)


@invalid("zstd-two-frames", "A zstd section of two frames (a fuzzing finding)",
         "decompression-failed", ["R-22", "R-24"])
def zstd_two_frames() -> bytes:
    return _stored(COEFFS, _zstd(_coefficients()) + _zstd(b""), Codec.ZSTD)


@invalid("zstd-no-content-size", "A zstd frame that does not declare its content size",
         "decompression-failed", ["R-22"])
def zstd_no_size() -> bytes:
    import zstandard

    frame = zstandard.ZstdCompressor(level=3, write_content_size=False).compress(_coefficients())
    return _stored(COEFFS, frame, Codec.ZSTD)


@invalid("zstd-bad-checksum", "A zstd frame whose checksum does not match", "decompression-failed",
         ["R-22"])
def zstd_checksum() -> bytes:
    frame = bytearray(_zstd(_coefficients(), write_checksum=True))
    frame[-1] ^= 0xFF
    return _stored(COEFFS, bytes(frame), Codec.ZSTD)


@invalid("zstd-frame-shorter-than-declared", "A zstd frame whose header declares one byte more "
         "than its blocks hold (raw_length agrees with the header)", "decompression-failed",
         ["R-24"])
def zstd_short_frame() -> bytes:
    raw = _coefficients()
    frame = bytearray(_zstd(raw))
    descriptor = frame[4]
    if descriptor >> 6 != 1 or not descriptor & 0x20:  # 2-byte content size, single segment
        raise AssertionError(f"unexpected zstd frame descriptor {descriptor:#x}")
    struct.pack_into("<H", frame, 5, len(raw) + 1 - 256)
    return _stored(COEFFS, bytes(frame), Codec.ZSTD, raw_length=len(raw) + 1)


@invalid("zstd-cut-short", "A zstd frame missing its last 3 bytes", "decompression-failed",
         ["R-24"])
def zstd_cut() -> bytes:
    return _stored(COEFFS, _zstd(_coefficients())[:-3], Codec.ZSTD)


# =================================================================== length-mismatch
@invalid("none-codec-length-mismatch", "An uncompressed section whose raw_length is one more "
         "than its stored length", "length-mismatch", ["R-22"])
def none_mismatch() -> bytes:
    return _stored(COEFFS, _coefficients(), Codec.NONE, raw_length=len(_coefficients()) + 1)


@invalid("zlib-longer-than-raw-length", "A zlib stream that inflates to 64 bytes more than its "
         "raw_length", "length-mismatch", ["R-24"])
def zlib_longer() -> bytes:
    raw = _coefficients()
    return _stored(COEFFS, zlib.compress(raw, 9), raw_length=len(raw) - 64)


@invalid("zlib-shorter-than-raw-length", "A zlib stream that ends properly 2 bytes short of its "
         "raw_length", "length-mismatch", ["R-24"])
def zlib_shorter() -> bytes:
    raw = _coefficients()
    return _stored(COEFFS, zlib.compress(raw, 9), raw_length=len(raw) + 2)


@invalid("zstd-content-size-mismatch", "A zstd frame declaring 2 bytes fewer than the section's "
         "raw_length", "length-mismatch", ["R-24"])
def zstd_mismatch() -> bytes:
    raw = _coefficients()
    return _stored(COEFFS, _zstd(raw[:-2]), Codec.ZSTD, raw_length=len(raw))


# ======================================================================= bad-section
@invalid("cluster-table-length-wrong", "A cluster table one byte longer than 4 + 40 C",
         "bad-section", ["R-40"])
def cluster_length() -> bytes:
    return edit_raw(base(), CLUSTERS, lambda b: b + b"\0").build()


@invalid("cluster-table-too-short", "A cluster table of 3 bytes, shorter than its count field",
         "bad-section", ["R-40"])
def cluster_short() -> bytes:
    return edit_raw(base(), CLUSTERS, lambda b: b[:3]).build()


@invalid("cluster-point-counts-dont-add-up", "Layer 0 declares one Gaussian more than its "
         "clusters hold (the header's total agrees)", "bad-section", ["R-46"])
def point_sum() -> bytes:
    draft = base()
    draft.layers[0].gaussian_count += 1
    return draft.build()


@invalid("draco-lengths-dont-add-up", "Four bytes after the last Draco blob of "
         "SKETCH_POSITIONS", "bad-section", ["R-46"])
def draco_sum() -> bytes:
    return edit_raw(base(), SKETCH_POS, lambda b: b + b"\0" * 4).build()


@invalid("coefficients-length-wrong", "SKETCH_COEFFICIENTS two bytes longer than the models",
         "bad-section", ["R-46", "R-44"])
def coefficients_length() -> bytes:
    return edit_raw(base(), COEFFS, lambda b: b + b"\0\0").build()


@invalid("empty-table-with-sketch-data", "A cluster table of zero clusters while "
         "SKETCH_POSITIONS and SKETCH_COEFFICIENTS hold data", "bad-section", ["R-46"])
def empty_table() -> bytes:
    draft = base()
    draft.sections[CLUSTERS].raw = b"\0\0\0\0"
    draft.layers[0].gaussian_count = 0
    return draft.build()


def _codebooks(draft: Draft) -> list[bytes]:
    """The codebook records of a PATCH_CODEBOOKS payload, each as its bytes."""
    raw = draft.sections[BOOKS].raw
    out, pos = [], 1
    for _ in range(raw[0]):
        dim, count = raw[pos + 1], struct.unpack_from("<H", raw, pos + 2)[0]
        out.append(raw[pos:pos + 4 + 2 * dim * count])
        pos += 4 + 2 * dim * count
    return out


def _with_codebooks(books: list[bytes], draft: Draft | None = None) -> bytes:
    draft = draft or base()
    draft.sections[BOOKS].raw = bytes([len(books)]) + b"".join(books)
    return draft.build()


@invalid("codebooks-wrong-attributes", "The SH band 1 codebook missing from an SH-1 file",
         "bad-section", ["R-50"])
def books_missing_band() -> bytes:
    return _with_codebooks(_codebooks(base())[:4])


@invalid("codebooks-out-of-order", "The rotation codebook before the scale codebook",
         "bad-section", ["R-50"])
def books_order() -> bytes:
    books = _codebooks(base())
    books[0], books[1] = books[1], books[0]
    return _with_codebooks(books)


@invalid("codebooks-trailing-byte", "A byte after the last codebook", "bad-section", ["R-50"])
def books_trailing() -> bytes:
    return edit_raw(base(), BOOKS, lambda b: b + b"\0").build()


@invalid("codebooks-cut-inside-entries", "PATCH_CODEBOOKS cut 3 bytes into its last codebook's "
         "entries", "bad-section", ["R-50"])
def books_cut() -> bytes:
    books = _codebooks(base())
    draft = base()
    draft.sections[BOOKS].raw = bytes([len(books)]) + b"".join(books[:-1]) + books[-1][:7]
    return draft.build()


@invalid("codebooks-empty", "An empty PATCH_CODEBOOKS payload", "bad-section", ["R-50"])
def books_empty() -> bytes:
    return edit_raw(base(), BOOKS, lambda b: b[:0]).build()


@invalid("positions-too-short", "A PATCH_POSITIONS payload of 2 bytes", "bad-section", ["R-53"])
def positions_short() -> bytes:
    return edit_raw(base(), POS2, lambda b: b[:2]).build()


@invalid("quant16-parameters-cut", "A QUANT16 payload of 20 bytes: origin and step cut short",
         "bad-section", ["R-53"])
def quant16_cut() -> bytes:
    return edit_raw(base(), POS1, lambda b: b[:20]).build()


@invalid("positions-data-length-wrong", "Float16 positions two bytes longer than 3 N values",
         "bad-section", ["R-53"], max_layers=(1,))
def positions_length() -> bytes:
    return edit_raw(base(), POS2, lambda b: b + b"\0\0").build()


@invalid("draco-data-for-empty-layer", "A Draco-mode layer of zero Gaussians whose data is not "
         "empty", "bad-section", ["R-58"], max_layers=(1,))
def draco_empty_layer() -> bytes:
    draft = base()
    blob, _ = scenes.draco_points(np.ones((3, 3)), kdtree=False)
    draft.sections.append(SectionSpec(T.PATCH_POSITIONS, 3, bytes([3, 0, 0, 0]) + blob))
    draft.sections.append(SectionSpec(T.PATCH_ATTRIBUTES, 3, b""))
    draft.layers.append(LayerSpec(LayerKind.PATCH, 0))
    return draft.build()


@invalid("attributes-length-wrong", "Layer 2's index columns one byte longer than N x groups",
         "bad-section", ["R-52"], max_layers=(1,))
def attributes_length() -> bytes:
    return edit_raw(base(), ATTR2, lambda b: b + b"\0").build()


@invalid("layer-count-claim", "Layer 2 claims 900 000 Gaussians (the header's total agrees, "
         "within the density limit) but holds 6 (a fuzzing finding)", "bad-section",
         ["R-62", "R-53"], max_layers=(1,))
def layer_claim() -> bytes:
    draft = base()
    draft.layers[2].gaussian_count = 900_000
    return draft.build()


# ========================================================================= bad-value
@invalid("sh-degree-4", "The header's sh_degree is 4", "bad-value", ["R-6"])
def sh_degree_4() -> bytes:
    return poke(base_bytes(), 24, "B", 4)


@invalid("polynomial-degree-11", "A scale model of degree 11 (its 364 x 3 coefficients present)",
         "bad-value", ["R-45"])
def degree_11() -> bytes:
    draft = base()
    table = bytearray(draft.sections[CLUSTERS].raw)
    old = table[record(0) + 32]
    table[record(0) + 32] = 11
    draft.sections[CLUSTERS].raw = bytes(table)
    coeffs = draft.sections[COEFFS].raw
    size = 2 * 3 * monomial_count(old)
    extra = np.full(3 * (monomial_count(11) - monomial_count(old)), 0.01, "<f2").tobytes()
    draft.sections[COEFFS].raw = coeffs[:size] + extra + coeffs[size:]
    return draft.build()


def _sh0_with_rest_degree(value: int) -> bytes:
    """An SH-0 file whose first cluster claims an SH-rest model (which has zero outputs, so the
    coefficient section is unchanged: the degree is the only defect)."""
    draft = base(sh_degree=0)
    return edit_raw(draft, CLUSTERS, lambda b: b.__setitem__(record(0) + 36, value)).build()


@invalid("sh-rest-model-in-sh0-scene", "An SH-rest degree of 2 in a scene of SH degree 0",
         "bad-value", ["R-45"])
def rest_in_sh0() -> bytes:
    return _sh0_with_rest_degree(2)


@invalid("sh-rest-degree-200", "An SH-rest degree of 200, neither 0..10 nor 255", "bad-value",
         ["R-45"])
def rest_200() -> bytes:
    draft = base()
    return edit_raw(draft, CLUSTERS, lambda b: b.__setitem__(record(0) + 36, 200)).build()


@invalid("point-count-zero", "A cluster of zero points (the next cluster of its run takes its "
         "points)", "bad-value", ["R-45"])
def point_count_zero() -> bytes:
    def move(b):
        first, second = struct.unpack_from("<I", b, record(1))[0], struct.unpack_from("<I", b, record(2))[0]
        struct.pack_into("<I", b, record(1), 0)
        struct.pack_into("<I", b, record(2), first + second)
    return edit_raw(base(), CLUSTERS, move).build()


@invalid("first-draco-length-zero", "The first cluster record starts no blob (its length moved "
         "to the next blob)", "bad-value", ["R-45"])
def first_draco_zero() -> bytes:
    def move(b):
        first = struct.unpack_from("<I", b, record(0) + 4)[0]
        second = struct.unpack_from("<I", b, record(1) + 4)[0]
        struct.pack_into("<I", b, record(0) + 4, 0)
        struct.pack_into("<I", b, record(1) + 4, first + second)
    return edit_raw(base(), CLUSTERS, move).build()


def _frame_edit(offset: int, value: float):
    return lambda b: struct.pack_into("<f", b, record(0) + offset, value)


@invalid("frame-centre-nan", "A cluster centre coordinate is NaN", "bad-value", ["R-45", "R-34"])
def centre_nan() -> bytes:
    return edit_raw(base(), CLUSTERS, _frame_edit(8, float("nan"))).build()


@invalid("half-extent-zero", "A cluster half extent is 0", "bad-value", ["R-45"])
def half_zero() -> bytes:
    return edit_raw(base(), CLUSTERS, _frame_edit(24, 0.0)).build()


@invalid("half-extent-negative-zero", "A cluster half extent is -0.0, which is not > 0",
         "bad-value", ["R-45"])
def half_negative_zero() -> bytes:
    return edit_raw(base(), CLUSTERS, _frame_edit(24, -0.0)).build()


def _sketch_frame(cluster: int, scale: float | None = None, half: float | None = None) -> bytes:
    """The base file with one cluster's half extents divided by ``scale`` or set to ``half``."""
    def edit(b):
        at = record(cluster) + 20
        values = np.frombuffer(bytes(b[at:at + 12]), "<f4")
        new = values / scale if scale is not None else np.full(3, half, np.float32)
        b[at:at + 12] = np.asarray(new, "<f4").tobytes()
    return edit_raw(base(), CLUSTERS, edit).build()


@invalid("normalized-coordinate-beyond-2", "A cluster frame 2.5 times too small: normalized "
         "coordinates reach about 2.5", "bad-value", ["R-42"])
def beyond_2() -> bytes:
    return _sketch_frame(0, scale=2.5)


@invalid("sketch-model-overflow", "A half extent of 1e-40: the models would overflow to "
         "infinity (a fuzzing finding)", "bad-value", ["R-42", "R-34"])
def model_overflow() -> bytes:
    return _sketch_frame(0, half=1e-40)


@invalid("sketch-rotation-norm-overflow", "A half extent of 1e-16 under a degree-10 rotation "
         "model whose norm overflowed binary64 (a fuzzing finding)", "bad-value", ["R-42", "R-31"])
def rotation_overflow() -> bytes:
    from spcodec.attributes import SketchAttribute
    from spcodec.sections import SketchCluster

    rng = np.random.default_rng(120)
    c = scenes.cluster(rng, 0, 5, scenes.degrees(0, 10, 0, 0))
    rotation = np.zeros((monomial_count(10), 4), np.float16)
    rotation[0, 0] = 1.0
    rotation[monomial_count(9), :2] = 65504.0                     # x^10 drives w and x
    c.models[SketchAttribute.ROTATION] = rotation
    c = SketchCluster(c.draco, c.point_count, c.center, np.full(3, 1e-16, np.float32), c.models)
    return Draft.of(EncodedScene(0, [c])).build()


def _coefficient(value: int) -> bytes:
    return edit_raw(base(), COEFFS, lambda b: struct.pack_into("<H", b, 2, value)).build()


@invalid("coefficient-infinite", "A polynomial coefficient is +infinity", "bad-value",
         ["R-44", "R-34"])
def coefficient_inf() -> bytes:
    return _coefficient(0x7C00)


@invalid("coefficient-nan", "A polynomial coefficient is NaN", "bad-value", ["R-44", "R-34"])
def coefficient_nan() -> bytes:
    return _coefficient(0x7E00)


def _codebook_with(index: int, dim: int, entries: np.ndarray) -> bytes:
    draft = base()
    books = _codebooks(draft)
    attribute = books[index][0]
    books[index] = bytes([attribute, dim]) + struct.pack("<H", len(entries)) + \
        np.asarray(entries, "<f2").tobytes()
    return _with_codebooks(books, draft)


@invalid("codebook-dim-not-dividing", "A scale codebook of entry dimension 2 (the width is 3)",
         "bad-value", ["R-51"])
def dim_2() -> bytes:
    return _codebook_with(0, 2, np.zeros((4, 2)))


@invalid("codebook-dim-zero", "A codebook of entry dimension 0", "bad-value", ["R-51"])
def dim_0() -> bytes:
    return _codebook_with(0, 0, np.zeros((4, 0)))


@invalid("codebook-257-entries", "A colour codebook of 257 entries", "bad-value", ["R-51"])
def entries_257() -> bytes:
    return _codebook_with(3, 3, np.zeros((257, 3)))


@invalid("codebook-no-entries", "An opacity codebook of 0 entries", "bad-value", ["R-51"])
def entries_0() -> bytes:
    return _codebook_with(2, 1, np.zeros((0, 1)))


@invalid("codebook-entry-nan", "A codebook entry is NaN", "bad-value", ["R-51", "R-34"])
def entry_nan() -> bytes:
    entries = np.full((4, 3), 0.5)
    entries[2, 1] = np.nan
    return _codebook_with(3, 3, entries)


@invalid("index-out-of-range", "An index equal to its 4-entry codebook's size", "bad-value",
         ["R-52"], max_layers=(1,))
def index_range() -> bytes:
    return edit_raw(base(), ATTR2, lambda b: b.__setitem__(len(b) - 1, 4)).build()


@invalid("position-mode-unknown", "A patch position mode of 4", "bad-value", ["R-53"])
def mode_4() -> bytes:
    return edit_raw(base(), POS1, lambda b: b.__setitem__(0, 4)).build()


@invalid("float16-position-infinite", "A float16 patch position is -infinity", "bad-value",
         ["R-53", "R-34"], max_layers=(1,))
def f16_inf() -> bytes:
    return edit_raw(base(), POS2, lambda b: struct.pack_into("<H", b, 6, 0xFC00)).build()


@invalid("float32-position-nan", "A float32 patch position is NaN", "bad-value",
         ["R-53", "R-34"])
def f32_nan() -> bytes:
    draft = base(modes=(PositionMode.FLOAT32,))
    return edit_raw(draft, POS1, lambda b: struct.pack_into("<f", b, 8, float("nan"))).build()


def _quant16(origin: tuple[float, float, float], step: tuple[float, float, float]) -> bytes:
    return edit_raw(base(), POS1, lambda b: struct.pack_into("<6f", b, 4, *origin, *step)).build()


@invalid("quant16-origin-infinite", "A QUANT16 origin of +infinity", "bad-value", ["R-55"])
def origin_inf() -> bytes:
    return _quant16((float("inf"), 0, 0), (1e-3, 1e-3, 1e-3))


@invalid("quant16-step-negative", "A QUANT16 step of -0.001", "bad-value", ["R-55"])
def step_negative() -> bytes:
    return _quant16((0, 0, 0), (1e-3, -1e-3, 1e-3))


@invalid("quant16-step-nan", "A QUANT16 step of NaN", "bad-value", ["R-55"])
def step_nan() -> bytes:
    return _quant16((0, 0, 0), (1e-3, 1e-3, float("nan")))


@invalid("quant16-overflows-float32", "origin + 65535 step beyond the float32 range",
         "bad-value", ["R-55"])
def quant16_overflow() -> bytes:
    return _quant16((3.0e38, 0, 0), (1e34, 1e-3, 1e-3))


# ======================================================================= draco-failed
def _blob_edit(edit, draft: Draft | None = None) -> bytes:
    """The base file with its first sketch blob (cluster 0's, kd-tree) edited in place."""
    return edit_raw(draft or base(), SKETCH_POS, edit).build()


def _run_blob(edit) -> bytes:
    """The base file with the blob of clusters 1-2 (sequential) edited in place."""
    draft = base()
    table = draft.sections[CLUSTERS].raw
    start = struct.unpack_from("<I", table, record(0) + 4)[0]

    def at_run(b):
        blob = bytearray(b[start:])
        edit(blob)
        return b[:start] + blob
    return edit_raw(draft, SKETCH_POS, at_run).build()


@invalid("draco-not-a-blob", "A sketch blob whose first bytes are not DRACO", "draco-failed",
         ["R-49"])
def not_draco() -> bytes:
    return _blob_edit(lambda b: b.__setitem__(4, ord("X")))


@invalid("draco-old-version", "A Draco blob of bitstream version 2.2", "draco-failed", ["R-49"])
def draco_version() -> bytes:
    return _blob_edit(lambda b: b.__setitem__(6, 2))


@invalid("draco-mesh", "A Draco blob whose encoder type says mesh", "draco-failed", ["R-49"])
def draco_mesh() -> bytes:
    return _blob_edit(lambda b: b.__setitem__(7, 1))


@invalid("draco-method-unknown", "A Draco blob of encoding method 2", "draco-failed", ["R-49"])
def draco_method() -> bytes:
    return _blob_edit(lambda b: b.__setitem__(8, 2))


@invalid("draco-metadata-flag", "A Draco blob whose flags announce metadata", "draco-failed",
         ["R-49"])
def draco_metadata() -> bytes:
    return _blob_edit(lambda b: b.__setitem__(10, 0x80))


@invalid("draco-point-count-claim", "A Draco header claiming 2^31 - 1 points for a cluster of 6 "
         "(a fuzzing finding: the library allocated gigabytes)", "draco-failed", ["R-49", "R-62"])
def draco_claim() -> bytes:
    return _blob_edit(lambda b: struct.pack_into("<i", b, 11, 0x7FFFFFFF))


@invalid("draco-blob-too-short", "A cluster's blob of 10 bytes, shorter than a Draco header",
         "draco-failed", ["R-49"])
def draco_short() -> bytes:
    draft = base()
    length = struct.unpack_from("<I", draft.sections[CLUSTERS].raw, record(0) + 4)[0]
    edit_raw(draft, CLUSTERS, lambda b: struct.pack_into("<I", b, record(0) + 4, 10))
    return edit_raw(draft, SKETCH_POS, lambda b: b"DRACO\x02\x03\x00\x01\x00" + b[length:]).build()


@invalid("draco-two-attributes", "A sketch blob carrying colours besides the positions",
         "draco-failed", ["R-49"])
def draco_colours() -> bytes:
    import DracoPy

    draft = base()
    table = draft.sections[CLUSTERS].raw
    length = struct.unpack_from("<I", table, record(0) + 4)[0]
    points = np.asarray(DracoPy.decode(draft.sections[SKETCH_POS].raw[:length]).points, np.float32)
    colours = np.tile(np.array([[10, 20, 30]], np.uint8), (len(points), 1))
    blob = DracoPy.encode(points, quantization_bits=14, colors=colours)
    edit_raw(draft, CLUSTERS, lambda b: struct.pack_into("<I", b, record(0) + 4, len(blob)))
    return edit_raw(draft, SKETCH_POS, lambda b: blob + b[length:]).build()


@invalid("draco-generic-attribute", "A sketch blob whose one attribute is GENERIC, not POSITION",
         "draco-failed", ["R-49"])
def draco_generic() -> bytes:
    return _blob_edit(lambda b: b.__setitem__(17, 4))


@invalid("draco-int8-positions", "A kd-tree blob whose position attribute has data type int8 "
         "(Draco decodes it to points)", "draco-failed", ["R-49"])
def draco_int8() -> bytes:
    return _blob_edit(lambda b: b.__setitem__(18, 1))


@invalid("draco-non-finite-points", "A sequential blob whose quantization minimum is +infinity: "
         "its points decode to non-finite values", "draco-failed", ["R-47", "R-34"])
def draco_infinite() -> bytes:
    return _run_blob(_set_quantization_minimum(float("inf")))


def _set_quantization_minimum(value: float):
    """Overwrite the first of the three float32 minima a quantized Draco attribute stores after
    its values (found as the bytes of the decoded points' minimum x)."""
    import DracoPy

    def edit(blob: bytearray) -> None:
        points = np.asarray(DracoPy.decode(bytes(blob)).points, np.float32).reshape(-1, 3)
        needle = np.float32(points[:, 0].min()).tobytes()
        at = bytes(blob).rfind(needle)
        if at < 0:
            raise AssertionError("quantization minimum not found in the blob")
        blob[at:at + 4] = struct.pack("<f", value)
    return edit


@invalid("draco-body-corrupt", "A sketch blob cut to its first 24 bytes (the header intact)",
         "draco-failed", ["R-47"])
def draco_body() -> bytes:
    draft = base()
    length = struct.unpack_from("<I", draft.sections[CLUSTERS].raw, record(0) + 4)[0]
    edit_raw(draft, CLUSTERS, lambda b: struct.pack_into("<I", b, record(0) + 4, 24))
    return edit_raw(draft, SKETCH_POS, lambda b: b[:24] + b[length:]).build()


@invalid("draco-run-count-mismatch", "One point moved from cluster 1's count to cluster 0's: "
         "cluster 0's blob holds one point fewer than its run declares", "draco-failed",
         ["R-47", "R-49"])
def run_mismatch() -> bytes:
    def move(b):
        first, second = struct.unpack_from("<I", b, record(0))[0], struct.unpack_from("<I", b, record(1))[0]
        struct.pack_into("<I", b, record(0), first + 1)
        struct.pack_into("<I", b, record(1), second - 1)
    return edit_raw(base(), CLUSTERS, move).build()


def _draco_patch_base() -> Draft:
    return base(modes=(PositionMode.DRACO,))


@invalid("patch-draco-count-mismatch", "A Draco-mode patch layer whose blob holds 5 points for "
         "a layer of 6", "draco-failed", ["R-58", "R-49"], max_layers=(0,))
def patch_draco_count() -> bytes:
    draft = _draco_patch_base()
    blob, _ = scenes.draco_points(np.arange(15, dtype=np.float32).reshape(5, 3), kdtree=False)
    draft.sections[POS1].raw = bytes([3, 0, 0, 0]) + blob
    return draft.build()


@invalid("patch-draco-empty-data", "A Draco-mode patch layer of 6 Gaussians with no data",
         "draco-failed", ["R-58", "R-49"], max_layers=(0,))
def patch_draco_empty() -> bytes:
    draft = _draco_patch_base()
    draft.sections[POS1].raw = bytes([3, 0, 0, 0])
    return draft.build()


# =========================================================================== bad-gzip
def _with_trailer(wrapped: bytes, crc: int, size: int) -> bytes:
    return wrapped[:-8] + struct.pack("<II", crc & 0xFFFFFFFF, size & 0xFFFFFFFF)


@invalid("gzip-crc-wrong", "A gzip trailer whose CRC-32 is off by one; also with --max-layer 0, "
         "since a decoder checks all of the wrapper", "bad-gzip", ["R-82"], max_layers=(0,))
def gzip_crc() -> bytes:
    inner = base_bytes()
    return _with_trailer(_wrapped(), crc32(inner) + 1, len(inner))


@invalid("gzip-isize-wrong", "A gzip trailer whose ISIZE is one more than the inflated size",
         "bad-gzip", ["R-82"])
def gzip_isize() -> bytes:
    inner = base_bytes()
    return _with_trailer(_wrapped(), crc32(inner), len(inner) + 1)


@invalid("gzip-header-crc-wrong", "A gzip header whose FHCRC does not match (it protects the "
         "layer offsets)", "bad-gzip", ["R-82", "R-83"])
def gzip_fhcrc() -> bytes:
    wrapped = bytearray(_wrapped())
    end = 12 + struct.unpack_from("<H", wrapped, 10)[0]
    wrapped[end] ^= 0xFF
    return bytes(wrapped)


@invalid("gzip-reserved-flag", "A gzip header with reserved flag bit 5 set", "bad-gzip", ["R-82"])
def gzip_flag() -> bytes:
    wrapped = bytearray(gzip.compress(base_bytes(), 9, mtime=0))
    wrapped[3] |= 0x20
    return bytes(wrapped)


@invalid("gzip-method-not-deflate", "A gzip header with compression method 7", "bad-gzip",
         ["R-82"])
def gzip_method() -> bytes:
    wrapped = bytearray(gzip.compress(base_bytes(), 9, mtime=0))
    wrapped[2] = 7
    return bytes(wrapped)


@invalid("gzip-deflate-corrupt", "A gzip member whose first deflate block has the reserved "
         "type 3", "bad-gzip", ["R-82"])
def gzip_deflate() -> bytes:
    inner = base_bytes()
    wrapped = gzip.compress(inner, 9, mtime=0)
    return wrapped[:10] + b"\x07" + wrapped[11:]


@invalid("gzip-later-layer-damaged", "A gzip member whose inflated layer 2 differs from the file "
         "its CRC-32 was computed over; rejected with --max-layer 0 too, where the damaged layer "
         "is not decoded", "bad-gzip", ["R-82", "R-16"], max_layers=(0,),
         also_accepted=("section-crc",))
def gzip_later_damage() -> bytes:
    inner = base_bytes()
    damaged = flip(inner, section_span(inner, ATTR2)[0], 0x01)
    wrapped = gzip_wrap(damaged, layer_end_offsets(damaged))
    return _with_trailer(wrapped, crc32(inner), len(inner))

