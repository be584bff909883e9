"""Structure-aware fuzzing of the spcodec decoder, with checksum repair.

Every byte of a valid file is covered by the header CRC or a section CRC, so random byte flips die
at the CRC checks and never reach the parsers behind them. The mutators here change *structure*
and then repair the checksums, so the mutant reaches the layer they aim at:

* ``payload``: a section's raw (decompressed) payload, edited field by field where the layout is
  known (cluster records, codebooks, positions, Draco headers, metadata JSON), recompressed with
  the section's codec and reassembled with derived CRCs;
* ``stored``: a section's stored (compressed) bytes, CRC recomputed: decompressors and Draco on
  garbage;
* ``header``: any field of the fixed header, the layer table or the TOC (lengths, counts, offsets,
  CRCs, codecs...), header CRC recomputed;
* ``sections``: dropped, duplicated, swapped, retyped, moved or spliced-in sections, codec swaps;
* ``truncate`` / ``append`` / ``flip``: cuts at every layer, trailing bytes, unrepaired flips;
* ``splice``: one file's header block on another file's sections;
* ``claim``: a count or length claiming far more than the file holds, the rest kept consistent;
* ``gzip``: the (mutated) inner file re-wrapped, or the gzip stream itself edited (header fields
  with FHCRC repaired, the ``SP`` layer-offset list, deflate bytes, trailer, extra members).

Each mutant is given to ``decode_layers``, ``decode(max_layer=k)``, ``inspect`` (and its JSON) and
the :class:`~spcodec.StreamDecoder` fed in random chunk sizes. The oracle: each either succeeds
with finite arrays of consistent length, or raises :class:`~spcodec.FormatError` with a code of
the spec's list; nothing else, no warning, within a time bound (an interval timer interrupts a
hang); the stream decoder accepts what ``decode_layers`` accepts, with the same layers. Every
n-th input is also run under tracemalloc against a memory bound, and the process runs under an
address-space limit with DracoPy's MemoryErrors counted (the decoder turns them into
``draco-failed``, which would hide a blob that asked Draco for gigabytes). Anything else is a
*finding*, saved as a reproducer; ``current.bin`` in the output folder is the input being
tried, should the process die.

The same mutators drive ``tests/test_fuzz.py`` through hypothesis (a :class:`Chooser` backed by
``data.draw``) and, with ``--atheris``, a coverage-guided run (a chooser backed by atheris'
``FuzzedDataProvider``).

    python bench/fuzz_decoder.py --iterations 200000 [--seconds 1200] [--seed 1] [--out DIR]
    python bench/fuzz_decoder.py --replay DIR/finding-0001.bin
    python bench/fuzz_decoder.py --atheris -- -max_total_time=600
"""

from __future__ import annotations

import argparse
import collections
import dataclasses
import json
import random
import resource
import signal
import struct
import sys
import tempfile
import time
import traceback
import tracemalloc
import warnings
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Protocol, Sequence, TypeVar

import numpy as np

import spcodec
from spcodec.codecs import compress, crc32, gzip_wrap
from spcodec.container import (
    FIXED_HEADER_SIZE,
    Codec,
    LayerKind,
    PositionMode,
    SectionType,
    header_size,
)
from spcodec.errors import ERROR_CODES, FormatError
from spcodec.synthetic import random_codebooks, random_patch_layer, random_sketch
from spcodec.writer import (
    EncodedScene,
    LayerSpec,
    SectionSpec,
    assemble,
    layer_end_offsets,
    scene_sections,
)

T = TypeVar("T")


# =============================================================================== choosers
class Chooser(Protocol):
    """Where a mutator gets its random decisions: random.Random, hypothesis or atheris."""

    def integer(self, lo: int, hi: int) -> int:
        """An integer in ``lo..hi`` inclusive."""

    def blob(self, size: int) -> bytes:
        """``size`` arbitrary bytes."""


class RandomChooser:
    """Decisions from a seeded :class:`random.Random` (the by-hand fuzz run)."""

    def __init__(self, rng: random.Random) -> None:
        self.rng = rng

    def integer(self, lo: int, hi: int) -> int:
        return self.rng.randint(lo, hi)

    def blob(self, size: int) -> bytes:
        return self.rng.randbytes(size)


def choice(ch: Chooser, items: Sequence[T]) -> T:
    """One of ``items``."""
    return items[ch.integer(0, len(items) - 1)]


def chance(ch: Chooser, percent: int) -> bool:
    """True with probability ``percent`` / 100."""
    return ch.integer(0, 99) < percent


# ================================================================================== seeds
@dataclass
class SeedFile:
    """A valid file kept as its parts, so mutants can be rebuilt with repaired checksums."""

    name: str
    sections: list[SectionSpec]
    """With ``stored`` and the actual ``codec`` filled in, so unmutated sections are reused."""
    layers: list[LayerSpec]
    sh_degree: int
    gzip: bool
    data: bytes
    """The assembled inner file."""


def _freeze_stored(sections: list[SectionSpec]) -> list[SectionSpec]:
    """Compress each section once (as the writer would) so mutants only recompress what changed."""
    for sec in sections:
        stored = compress(Codec(sec.codec), sec.raw)
        if sec.codec != Codec.NONE and len(stored) >= len(sec.raw):
            sec.codec, stored = Codec.NONE, bytes(sec.raw)
        sec.stored = stored
    return sections


def _scene(seed: int, sh: int, clusters: int, modes: list[PositionMode], size: int,
           metadata: dict | None) -> EncodedScene:
    rng = np.random.default_rng(seed)
    sketch = random_sketch(rng, sh, clusters)
    books = random_codebooks(rng, sh) if modes else []
    layers = [random_patch_layer(rng, books, size, mode) for mode in modes]
    return EncodedScene(sh, sketch, books, layers, metadata)


SEED_SPECS = [
    # name, scene seed, sh degree, clusters, patch position modes, patch size, codec, metadata, gzip
    ("sh3-zlib-meta", 1, 3, 4, [PositionMode.QUANT16, PositionMode.FLOAT16], 40, Codec.ZLIB,
     {"encoder": "fuzz", "n": [1, 2.5, None]}, False),
    ("sh0-none-draco", 2, 0, 3, [PositionMode.DRACO, PositionMode.FLOAT32], 30, Codec.NONE, None,
     False),
    ("sh1-zstd-3layers", 3, 1, 5, [PositionMode.FLOAT32, PositionMode.QUANT16, PositionMode.DRACO],
     25, Codec.ZSTD, {"k": "v"}, False),
    ("sh2-nosketch", 4, 2, 0, [PositionMode.FLOAT16], 20, Codec.ZLIB, None, False),
    ("sh3-sketch-only-gzip", 5, 3, 3, [], 0, Codec.ZLIB, {"gz": True}, True),
    ("sh2-gzip-2layers", 6, 2, 2, [PositionMode.DRACO, PositionMode.QUANT16], 30, Codec.ZLIB,
     None, True),
]


def build_seeds() -> list[SeedFile]:
    """A small, varied corpus: every SH degree, codec, position mode, gzip and metadata."""
    seeds = []
    for name, seed, sh, clusters, modes, size, codec, meta, gz in SEED_SPECS:
        scene = _scene(seed, sh, clusters, modes, size, meta)
        sections, layers = scene_sections(scene, codec)
        sections = _freeze_stored(sections)
        data = assemble(sections, layers, sh)
        seeds.append(SeedFile(name, sections, layers, sh, gz, data))
    return seeds


def copy_sections(sections: list[SectionSpec]) -> list[SectionSpec]:
    return [dataclasses.replace(s) for s in sections]


def copy_layers(layers: list[LayerSpec]) -> list[LayerSpec]:
    return [dataclasses.replace(layer) for layer in layers]


def rebuild(seed: SeedFile, sections: list[SectionSpec], layers: list[LayerSpec] | None = None,
            header: dict | None = None) -> bytes:
    """Assemble a mutant: offsets, lengths and CRCs are derived unless a spec overrides them."""
    return assemble(sections, layers if layers is not None else seed.layers, seed.sh_degree,
                    header_overrides=header, store_when_larger=False)


# ============================================================================ value pools
INTERESTING = {
    "B": [0, 1, 2, 3, 4, 7, 9, 10, 11, 127, 128, 254, 255],
    "H": [0, 1, 2, 3, 255, 256, 257, 0x7FFF, 0x8000, 0xFFFE, 0xFFFF],
    "I": [0, 1, 2, 3, 0x7F, 0x80, 0xFF, 0x100, 0xFFFF, 0x10000, 0x7FFFFFFF, 0x80000000,
          0xFFFFFFFE, 0xFFFFFFFF],
    "i": [0, 1, -1, 2, 0x7FFFFFFF, -0x80000000, 1 << 24, 1 << 30],
    "Q": [0, 1, 2, 0xFFFFFFFF, 1 << 32, 1 << 40, (1 << 63) - 1, 1 << 63, (1 << 64) - 1],
    "f": [0.0, -0.0, 1.0, -1.0, 1e-45, 1e-38, 1e-30, 1e30, 3.4e38, -3.4e38, float("inf"),
          float("-inf"), float("nan")],
    "e": [0.0, -0.0, 1.0, -1.0, 6e-8, 1e-4, 65504.0, -65504.0, float("inf"), float("-inf"),
          float("nan")],
}
_SIZES = {"B": 1, "H": 2, "I": 4, "i": 4, "Q": 8, "f": 4, "e": 2}
_MAX = {"B": 0xFF, "H": 0xFFFF, "I": 0xFFFFFFFF, "Q": (1 << 64) - 1}


def interesting(ch: Chooser, fmt: str, original: int | float) -> int | float:
    """An edge value for a field of struct format ``fmt``, or a small step from ``original``."""
    if fmt in _MAX and chance(ch, 30):
        step = choice(ch, [-2, -1, 1, 2, original, -(original // 2) if original else 1])
        return int(min(max(original + step, 0), _MAX[fmt]))
    return choice(ch, INTERESTING[fmt])


@dataclass(frozen=True)
class Field:
    """A fixed-format field at a byte offset of some buffer."""

    offset: int
    fmt: str


def poke(buf: bytearray, field: Field, ch: Chooser) -> None:
    """Overwrite one field with an interesting value (little-endian, [R-2])."""
    size = _SIZES[field.fmt]
    if field.offset + size > len(buf):
        return
    code = "<" + field.fmt
    (old,) = struct.unpack_from(code, buf, field.offset)
    new = interesting(ch, field.fmt, old if field.fmt in _MAX else 0)
    try:
        struct.pack_into(code, buf, field.offset, new)
    except (struct.error, OverflowError):
        struct.pack_into(code, buf, field.offset, choice(ch, INTERESTING[field.fmt]))


def array_fields(offset: int, fmt: str, count: int, limit: int = 64) -> list[Field]:
    """Fields of a packed array, capped: the first ``limit`` elements are enough to hit a check."""
    return [Field(offset + i * _SIZES[fmt], fmt) for i in range(min(count, limit))]


# ====================================================================== payload layouts
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


# ==================================================================== byte-level havoc
def havoc(data: bytes, ch: Chooser, rounds: int | None = None) -> bytes:
    """A few random byte edits: flips, overwrites, inserts, deletes, duplications, cuts."""
    buf = bytearray(data)
    for _ in range(rounds if rounds is not None else ch.integer(1, 4)):
        op = ch.integer(0, 7)
        at = ch.integer(0, len(buf)) if buf else 0
        if op == 0 and at < len(buf):
            buf[at] ^= 1 << ch.integer(0, 7)
        elif op == 1 and at < len(buf):
            buf[at] = ch.integer(0, 255)
        elif op == 2:
            buf[at:at] = ch.blob(ch.integer(1, 16))
        elif op == 3:
            del buf[at:at + ch.integer(1, 16)]
        elif op == 4:
            size = ch.integer(1, 32)
            buf[at:at] = buf[at:at + size]
        elif op == 5:
            del buf[at:]
        elif op == 6:
            buf += ch.blob(ch.integer(1, 16)) if chance(ch, 50) else b"\0" * ch.integer(1, 64)
        elif op == 7 and at + 4 <= len(buf):
            struct.pack_into("<I", buf, at, choice(ch, INTERESTING["I"]))
    return bytes(buf)


# ================================================================ metadata generators
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


# ===================================================================== mutators
def _pick_section(seed: SeedFile, ch: Chooser) -> int:
    return ch.integer(0, len(seed.sections) - 1)


def recompress(sec: SectionSpec, raw: bytes) -> None:
    """Give a section a new raw payload, stored with the section's codec, lengths derived."""
    sec.raw = raw
    sec.stored = compress(Codec(sec.codec), raw, 1) if sec.codec in (1, 2) else raw
    sec.raw_length = None
    sec.crc = None


def mutate_payload(seed: SeedFile, seeds: list[SeedFile], ch: Chooser) -> bytes:
    """Edit a raw payload (structure-aware where the layout is known), recompress, repair CRCs."""
    sections = copy_sections(seed.sections)
    sec = sections[_pick_section(seed, ch)]
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
    sec = sections[_pick_section(seed, ch)]
    sec.stored = havoc(sec.stored, ch)
    if chance(ch, 30):
        sec.raw_length = max(0, len(sec.raw) + ch.integer(-3, 3))
    else:
        sec.raw_length = len(sec.raw)
    return rebuild(seed, sections)


def header_fields(data: bytes) -> list[Field]:
    """Every field of the header block of an assembled file: fixed header, layers, TOC."""
    fields = [Field(8, "H"), Field(10, "H"), Field(12, "I"), Field(16, "I"), Field(20, "H"),
              Field(22, "H"), Field(24, "B"), Field(25, "B"), Field(31, "B"), Field(32, "Q"),
              Field(40, "Q")]
    layers, count = struct.unpack_from("<HH", data, 20)
    for i in range(layers):
        base = FIXED_HEADER_SIZE + 16 * i
        fields += [Field(base, "B"), Field(base + 1, "B"), Field(base + 4, "I"),
                   Field(base + 8, "Q")]
    toc = FIXED_HEADER_SIZE + 16 * layers
    for j in range(count):
        base = toc + 40 * j
        fields += [Field(base, "H"), Field(base + 2, "B"), Field(base + 3, "B"),
                   Field(base + 4, "H"), Field(base + 6, "H"), Field(base + 8, "Q"),
                   Field(base + 16, "Q"), Field(base + 24, "Q"), Field(base + 32, "I"),
                   Field(base + 36, "I")]
    return fields


def repair_header_crc(buf: bytearray) -> None:
    """Recompute the header CRC where the (possibly edited) tables say the header ends ([R-8])."""
    layers, count = struct.unpack_from("<HH", buf, 20)
    size = header_size(layers, count)
    if size <= len(buf):
        struct.pack_into("<I", buf, size - 4, crc32(bytes(buf[:size - 4])))


def mutate_header(seed: SeedFile, seeds: list[SeedFile], ch: Chooser) -> bytes:
    """Edit header, layer-table or TOC fields of a valid file, then repair the header CRC."""
    buf = bytearray(seed.data)
    original = bytes(buf[20:24])
    fields = header_fields(seed.data)
    for _ in range(ch.integer(1, 3)):
        poke(buf, choice(ch, fields), ch)
    if bytes(buf[20:24]) != original and chance(ch, 50):
        buf[20:24] = original  # keep the tables where they are, most of the time
    if chance(ch, 90):
        repair_header_crc(buf)
    return bytes(buf)


def mutate_sections(seed: SeedFile, seeds: list[SeedFile], ch: Chooser) -> bytes:
    """Drop, duplicate, swap, retype, move or splice sections; change codecs or flags."""
    sections = copy_sections(seed.sections)
    layers = copy_layers(seed.layers)
    i = _pick_section(seed, ch)
    op = ch.integer(0, 9)
    if op == 0 and len(sections) > 1:
        del sections[i]
    elif op == 1:
        sections.insert(ch.integer(0, len(sections)), dataclasses.replace(sections[i]))
    elif op == 2:
        j = _pick_section(seed, ch)
        sections[i], sections[j] = sections[j], sections[i]
    elif op == 3:
        sections[i].type = choice(ch, [int(t) for t in SectionType] + [0, 0x7F00, 0xFFFF])
    elif op == 4:
        sections[i].layer = ch.integer(0, len(layers))
    elif op == 5:
        other = choice(ch, seeds)
        donor = dataclasses.replace(choice(ch, other.sections))
        donor.layer = sections[i].layer
        sections[i] = donor if chance(ch, 70) else sections[i]
        if sections[i] is not donor:
            sections.insert(i, donor)
    elif op == 6:
        sections[i].codec = choice(ch, [0, 1, 2, 3, 255])
        if sections[i].codec < 3 and chance(ch, 50):
            recompress(sections[i], sections[i].raw)  # a consistent codec change
    elif op == 7:
        sections[i].flags = choice(ch, [0, 1, 2, 3, 0x80, 0xFF])
    elif op == 8:
        sections[i].reserved = choice(ch, [1, 0x8000])
    else:
        return _mutate_layer_table(seed, sections, layers, ch)
    return rebuild(seed, sections, layers)


def _mutate_layer_table(seed: SeedFile, sections: list[SectionSpec], layers: list[LayerSpec],
                        ch: Chooser) -> bytes:
    """Add or drop layers, or change their counts and kinds, keeping the header consistent."""
    op = ch.integer(0, 3)
    k = ch.integer(0, len(layers) - 1)
    if op == 0:
        layers.append(LayerSpec(LayerKind.PATCH, ch.integer(0, 5)))
    elif op == 1 and len(layers) > 1:
        layers.pop()
    elif op == 2:
        layers[k].gaussian_count = interesting(ch, "I", layers[k].gaussian_count)
    else:
        layers[k].kind = choice(ch, [0, 1, 2])
    return rebuild(seed, sections, layers)


def mutate_truncate(seed: SeedFile, seeds: list[SeedFile], ch: Chooser) -> bytes:
    """Cut the file inside the header, at a layer boundary (+-1), or anywhere."""
    ends = layer_end_offsets(seed.data)
    marks = [0, 1, 7, 8, FIXED_HEADER_SIZE - 1, FIXED_HEADER_SIZE,
             header_size(len(seed.layers), len(seed.sections)) - 1]
    marks += [e + d for e in ends for d in (-1, 0, 1)]
    cut = choice(ch, marks) if chance(ch, 60) else ch.integer(0, len(seed.data))
    return seed.data[:max(0, cut)]


def mutate_append(seed: SeedFile, seeds: list[SeedFile], ch: Chooser) -> bytes:
    """Bytes after file_size: zeros, random, or a second copy of the file."""
    extra = choice(ch, [b"\0", ch.blob(ch.integer(1, 64)), seed.data])
    return seed.data + extra


def mutate_flip(seed: SeedFile, seeds: list[SeedFile], ch: Chooser) -> bytes:
    """Unrepaired byte edits: the CRC checks must catch every one of them."""
    return havoc(seed.data, ch)


def mutate_splice(seed: SeedFile, seeds: list[SeedFile], ch: Chooser) -> bytes:
    """Another seed's header on this seed's sections (and vice versa), header CRC intact."""
    other = choice(ch, seeds)
    cut = header_size(len(other.layers), len(other.sections))
    return other.data[:cut] + seed.data[header_size(len(seed.layers), len(seed.sections)):]


HUGE_COUNTS = [1 << 20, 30_000_000, 60_000_000, 0xFFFFFFFF]
HUGE_LENGTHS = [(1 << 26) - 1, 1 << 26, 1 << 31, 1 << 40, (1 << 64) - 1]


def mutate_claim(seed: SeedFile, seeds: list[SeedFile], ch: Chooser) -> bytes:
    """A count or length that claims far more data than the file holds, everything else kept
    consistent (header total, CRCs) so the claim reaches the code that would size memory by it.

    Draco point-count fields are left as they are: a consistent claim there is the one case
    where the Draco library itself allocates, outside what this harness can measure.
    """
    sections, layers = copy_sections(seed.sections), copy_layers(seed.layers)
    op = ch.integer(0, 4)
    if op == 0:  # a layer claims many Gaussians (assemble keeps the header total consistent)
        layers[ch.integer(0, len(layers) - 1)].gaussian_count = choice(ch, HUGE_COUNTS)
    elif op == 1:
        sec = sections[_pick_section(seed, ch)]
        sec.raw_length = choice(ch, HUGE_LENGTHS)
    elif op in (2, 3):
        _claim_in_cluster_table(sections, layers, ch, op == 2)
    else:
        _claim_in_codebooks(sections, ch)
    return rebuild(seed, sections, layers)


def _claim_in_cluster_table(sections: list[SectionSpec], layers: list[LayerSpec], ch: Chooser,
                            points: bool) -> None:
    """A cluster's point count (with layer 0's count raised to match), or the cluster count."""
    sec = next(s for s in sections if s.type == SectionType.SKETCH_CLUSTERS)
    buf = bytearray(sec.raw)
    count = struct.unpack_from("<I", buf, 0)[0]
    if points and count:
        at = 4 + 40 * ch.integer(0, count - 1)
        old, new = struct.unpack_from("<I", buf, at)[0], choice(ch, HUGE_COUNTS[:3])
        struct.pack_into("<I", buf, at, new)
        layers[0].gaussian_count += new - old
    else:
        struct.pack_into("<I", buf, 0, choice(ch, [4_000_000, 0xFFFFFFFF, count + 1]))
    recompress(sec, bytes(buf))


def _claim_in_codebooks(sections: list[SectionSpec], ch: Chooser) -> None:
    """A codebook that claims 65535 entries of up to 255 components."""
    sec = next((s for s in sections if s.type == SectionType.PATCH_CODEBOOKS), None)
    if sec is None:
        return
    buf = bytearray(sec.raw)
    struct.pack_into("<H", buf, 3, 0xFFFF)
    if chance(ch, 50):
        buf[2] = 255
    recompress(sec, bytes(buf))


INNER_MUTATORS: dict[str, Callable[[SeedFile, list[SeedFile], Chooser], bytes]] = {
    "payload": mutate_payload,
    "stored": mutate_stored,
    "header": mutate_header,
    "sections": mutate_sections,
    "truncate": mutate_truncate,
    "append": mutate_append,
    "flip": mutate_flip,
    "splice": mutate_splice,
    "claim": mutate_claim,
}
KIND_WEIGHTS = {"payload": 30, "stored": 14, "header": 17, "sections": 14, "truncate": 6,
                "append": 2, "flip": 3, "splice": 4, "claim": 5, "gzip": 9}


# =================================================================================== gzip
def gzip_header_fields(data: bytes) -> list[Field]:
    """Fields of the wrapper of :func:`spcodec.codecs.gzip_wrap`: flags, XLEN, SP subfield."""
    fields = [Field(2, "B"), Field(3, "B"), Field(8, "B"), Field(9, "B"), Field(10, "H"),
              Field(14, "H"), Field(16, "H")]
    if len(data) > 18:
        count = struct.unpack_from("<H", data, 16)[0]
        fields += array_fields(18, "Q", count, 8)
    return fields


def repair_fhcrc(buf: bytearray) -> None:
    """Recompute the gzip FHCRC of a wrapper whose header ends after the FEXTRA field."""
    if len(buf) < 12 or not buf[3] & 2 or not buf[3] & 4:
        return
    end = 12 + struct.unpack_from("<H", buf, 10)[0]
    if end + 2 <= len(buf):
        struct.pack_into("<H", buf, end, crc32(bytes(buf[:end])) & 0xFFFF)


def mutate_gzip(seed: SeedFile, inner: bytes, ch: Chooser) -> bytes:
    """Wrap ``inner`` in gzip, then maybe damage the wrapper itself ([R-80]..[R-84])."""
    try:
        ends = [e for e in layer_end_offsets(inner) if e <= len(inner)]
    except Exception:  # a mutant's layer table may be unreadable: wrap without flush points
        ends = []
    wrapped = bytearray(gzip_wrap(inner, ends, level=6))
    op = ch.integer(0, 9)
    if op <= 3:
        return bytes(wrapped)
    if op == 4:
        for _ in range(ch.integer(1, 2)):
            poke(wrapped, choice(ch, gzip_header_fields(bytes(wrapped))), ch)
        if chance(ch, 80):
            repair_fhcrc(wrapped)
        return bytes(wrapped)
    if op == 5:
        return bytes(wrapped[:ch.integer(0, len(wrapped))])
    if op == 6:
        return bytes(wrapped) + choice(ch, [b"\0", b"\x1f\x8b", bytes(wrapped), ch.blob(8)])
    if op == 7:
        at = ch.integer(len(wrapped) - 8, len(wrapped) - 1)
        wrapped[at] ^= 1 << ch.integer(0, 7)
        return bytes(wrapped)
    if op == 8:
        return _gzip_with_fixed_trailer(inner, ch)
    head = 12 + struct.unpack_from("<H", wrapped, 10)[0] + 2
    body = havoc(bytes(wrapped[head:-8]), ch, 1)
    return bytes(wrapped[:head]) + body + bytes(wrapped[-8:])


def _gzip_with_fixed_trailer(inner: bytes, ch: Chooser) -> bytes:
    """A plain gzip stream (optionally FNAME/FCOMMENT) of damaged inner bytes with a correct CRC."""
    damaged = havoc(inner, ch, 1)
    flags = choice(ch, [0, 8, 16, 24])
    head = b"\x1f\x8b\x08" + bytes([flags]) + b"\0\0\0\0\0\xff"
    head += b"name\0" if flags & 8 else b""
    head += b"comment\0" if flags & 16 else b""
    deflater = zlib.compressobj(6, zlib.DEFLATED, -15)
    body = deflater.compress(damaged) + deflater.flush()
    return head + body + struct.pack("<II", crc32(damaged), len(damaged) & 0xFFFFFFFF)


# =============================================================================== mutants
def make_mutant(seeds: list[SeedFile], ch: Chooser, kind: str | None = None) -> tuple[str, bytes]:
    """A mutant of a random seed: its kind (the mutator's name) and its bytes.

    Seeds that are gzip-wrapped files are usually re-wrapped after the inner mutation, so the
    inner layers are reached through the wrapper too.
    """
    seed = choice(ch, seeds)
    kind = kind or _weighted_kind(ch)
    if kind == "gzip" or (seed.gzip and chance(ch, 60)):
        inner_kind = kind if kind != "gzip" else choice(ch, list(INNER_MUTATORS))
        inner = INNER_MUTATORS[inner_kind](seed, seeds, ch) if chance(ch, 60) else seed.data
        return "gzip", mutate_gzip(seed, inner, ch)
    return kind, INNER_MUTATORS[kind](seed, seeds, ch)


def _weighted_kind(ch: Chooser) -> str:
    pick, acc = ch.integer(0, sum(KIND_WEIGHTS.values()) - 1), 0
    for kind, weight in KIND_WEIGHTS.items():
        acc += weight
        if pick < acc:
            return kind
    raise AssertionError("unreachable")  # pragma: no cover


# ================================================================================ oracle
class Finding(AssertionError):
    """The decoder broke its contract on an input: wrong exception type, bad output, too slow."""

    def __init__(self, target: str, problem: str, cause: BaseException | None = None) -> None:
        super().__init__(f"{target}: {problem}")
        self.target, self.problem, self.cause = target, problem, cause


@dataclass
class Outcome:
    """What the decoding entry points made of one input: 'ok' or an error code, per target."""

    results: dict[str, str]


def _code(exc: FormatError, target: str) -> str:
    if exc.code not in ERROR_CODES:
        raise Finding(target, f"FormatError with unknown code {exc.code!r}", exc)
    return exc.code


def _check_cloud(cloud: spcodec.GaussianCloud, expected: int, target: str) -> None:
    """Output contract: every array has the cloud's length and only finite values ([R-34])."""
    n = len(cloud)
    if n != expected:
        raise Finding(target, f"decoded {n} Gaussians, the decoded layers declare {expected}")
    for name, array in cloud.arrays().items():
        if array.shape[0] != n:
            raise Finding(target, f"{name} has {array.shape[0]} rows for {n} Gaussians")
        if not np.isfinite(array).all():
            raise Finding(target, f"{name} holds a non-finite value")


def _run(target: str, fn: Callable[[], T]) -> T | FormatError:
    """Call ``fn``; a FormatError is an answer, anything else (warnings included) a finding."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            return fn()
    except FormatError as exc:
        _code(exc, target)
        return exc
    except Finding:
        raise
    except BaseException as exc:  # noqa: B036 - the point is to catch everything
        if isinstance(exc, (KeyboardInterrupt, TimeoutError)):
            raise
        raise Finding(target, f"{type(exc).__name__}: {exc}", exc) from exc


def _stream(data: bytes, chunks: list[int]) -> list:
    dec = spcodec.StreamDecoder()
    got, pos, i = [], 0, 0
    while pos < len(data):
        step = chunks[i % len(chunks)]
        got += dec.feed(data[pos:pos + step])
        pos, i = pos + step, i + 1
    dec.close()
    return got


def check_input(data: bytes, ch: Chooser) -> Outcome:
    """Run every decoding entry point on ``data`` and enforce the contract; raise Finding."""
    results: dict[str, str] = {}
    full = _run("decode_layers", lambda: spcodec.decode_layers(data))
    if isinstance(full, FormatError):
        results["decode_layers"] = full.code
    else:
        _check_cloud(full.cloud, sum(layer.cloud.means.shape[0] for layer in full.layers),
                     "decode_layers")
        declared = sum(full.header.layers[k].gaussian_count for k in range(len(full.layers)))
        if len(full.cloud) != declared:
            raise Finding("decode_layers", f"{len(full.cloud)} Gaussians, header says {declared}")
        results["decode_layers"] = "ok"
        k = ch.integer(0, len(full.layers) - 1)
        part = _run("decode(max_layer)", lambda: spcodec.decode(data, max_layer=k))
        if isinstance(part, FormatError) or not part.equals(
                spcodec.GaussianCloud.concat([x.cloud for x in full.layers[:k + 1]],
                                             full.header.sh_degree)):
            raise Finding("decode(max_layer)", f"max_layer={k} disagrees with decode_layers")
    info = _run("inspect", lambda: json.dumps(spcodec.inspect(data).to_json()))
    results["inspect"] = info.code if isinstance(info, FormatError) else "ok"
    chunks = [ch.integer(1, 4096) for _ in range(ch.integer(1, 4))]
    layers = _run("StreamDecoder", lambda: _stream(data, chunks))
    results["stream"] = layers.code if isinstance(layers, FormatError) else "ok"
    _compare_stream(full, layers)
    return Outcome(results)


def _compare_stream(full, layers) -> None:
    """The stream decoder must accept exactly what decode_layers accepts, with the same layers.

    When both reject, the codes may differ: the stream decodes each layer as soon as its bytes
    are in, so it can report a fault of an early layer before it sees a later truncation,
    trailing bytes or a broken gzip trailer that decode_layers checks first.
    """
    if isinstance(full, FormatError) != isinstance(layers, FormatError):
        got = layers.code if isinstance(layers, FormatError) else "ok"
        want = full.code if isinstance(full, FormatError) else "ok"
        raise Finding("StreamDecoder", f"stream says {got}, decode_layers says {want}")
    if isinstance(full, FormatError):
        return
    if [x.index for x in layers] != [x.index for x in full.layers] or not all(
            a.cloud.equals(b.cloud) for a, b in zip(layers, full.layers)):
        raise Finding("StreamDecoder", "stream layers differ from decode_layers")


# ======================================================================= memory watchdog
class DracoWatch:
    """Counts DracoPy MemoryErrors: decode_points turns them into draco-failed, which hides a
    blob that made Draco ask for gigabytes (the bench runs under an address-space limit)."""

    def __init__(self) -> None:
        import DracoPy

        self.module, self.original, self.hits = DracoPy, DracoPy.decode, 0

        def watched(blob, *args, **kwargs):
            try:
                return self.original(blob, *args, **kwargs)
            except MemoryError:
                self.hits += 1
                raise

        DracoPy.decode = watched

    def close(self) -> None:
        self.module.decode = self.original


# ============================================================================ the runner
@dataclass
class Stats:
    """Counters of a fuzz run."""

    executions: int = 0
    by_kind: collections.Counter = dataclasses.field(default_factory=collections.Counter)
    by_code: collections.Counter = dataclasses.field(default_factory=collections.Counter)
    findings: collections.Counter = dataclasses.field(default_factory=collections.Counter)
    slowest: float = 0.0
    peak_ratio: float = 0.0


class _Timeout(TimeoutError):
    pass


def _alarm(signum, frame):  # pragma: no cover - only fires on a hang
    raise _Timeout("execution exceeded the time bound")


def save_reproducer(out: Path, index: int, kind: str, data: bytes, problem: str) -> Path:
    """Write the input and a note on what went wrong; return the input's path."""
    path = out / f"finding-{index:04d}-{kind}.bin"
    path.write_bytes(data)
    path.with_suffix(".txt").write_text(problem + "\n")
    return path


def fuzz(iterations: int, seconds: float, rng_seed: int, out: Path, time_bound: float,
         memory_every: int, report_every: float = 30.0) -> Stats:
    """Run mutants until ``iterations`` or ``seconds`` run out; save findings under ``out``."""
    seeds = build_seeds()
    for seed in seeds:  # the corpus itself must decode
        check_input(seed.data, RandomChooser(random.Random(0)))
    rng = random.Random(rng_seed)
    ch = RandomChooser(rng)
    stats, watch = Stats(), DracoWatch()
    signal.signal(signal.SIGALRM, _alarm)
    current = out / "current.bin"  # survives a crash of the process: the last input tried
    start = last_report = time.perf_counter()
    seen_problems: dict[str, int] = {}
    try:
        while stats.executions < iterations and time.perf_counter() - start < seconds:
            kind, data = make_mutant(seeds, ch)
            current.write_bytes(data)
            problem = _execute(data, ch, stats, watch, time_bound,
                               stats.executions % memory_every == 0)
            stats.executions += 1
            stats.by_kind[kind] += 1
            if problem:
                key = problem.split(":")[0] + ":" + problem.split(":")[1][:60] \
                    if ":" in problem else problem
                stats.findings[key] += 1
                if seen_problems.setdefault(key, 0) < 3:
                    seen_problems[key] += 1
                    path = save_reproducer(out, sum(seen_problems.values()), kind, data, problem)
                    print(f"FINDING [{kind}] {problem}\n  reproducer: {path}", flush=True)
            if time.perf_counter() - last_report > report_every:
                last_report = time.perf_counter()
                _report(stats, last_report - start)
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        watch.close()
    _report(stats, time.perf_counter() - start, final=True)
    return stats


def _execute(data: bytes, ch: Chooser, stats: Stats, watch: DracoWatch, time_bound: float,
             measure: bool) -> str | None:
    """Check one input; return a description of a finding, or None."""
    before = watch.hits
    if measure:
        tracemalloc.start()
    signal.setitimer(signal.ITIMER_REAL, time_bound * 4)
    t0 = time.perf_counter()
    try:
        outcome = check_input(data, ch)
    except Finding as exc:
        return f"{exc.target}: {exc.problem}"
    except _Timeout:
        return "hang: no answer within the time bound"
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        elapsed = time.perf_counter() - t0
        peak = tracemalloc.get_traced_memory()[1] if measure else 0
        if measure:
            tracemalloc.stop()
    stats.slowest = max(stats.slowest, elapsed)
    for code in outcome.results.values():
        stats.by_code[code] += 1
    if watch.hits != before:
        return "draco-memory: DracoPy raised MemoryError (asked for more than the address space)"
    if elapsed > time_bound:
        return f"slow: {elapsed:.2f} s for a {len(data)}-byte input"
    if measure:
        ratio = peak / (len(data) + 1)
        stats.peak_ratio = max(stats.peak_ratio, ratio)
        if peak > memory_bound(len(data)):
            return f"memory: traced peak {peak / 2**20:.1f} MiB for a {len(data)}-byte input"
    return None


def memory_bound(size: int) -> int:
    """Peak traced memory allowed for decoding every target on an input of ``size`` bytes.

    Generous on purpose: an honest decode expands a small file by its compression ratio and the
    output's 236 bytes per Gaussian; what this catches is allocation sized by a claimed count.
    """
    return 512 * size + 32 * 2**20


def _report(stats: Stats, elapsed: float, final: bool = False) -> None:
    rate = stats.executions / max(elapsed, 1e-9)
    print(f"{'FINAL ' if final else ''}{stats.executions} executions in {elapsed:.0f} s "
          f"({rate:.0f}/s); slowest {stats.slowest * 1000:.0f} ms; peak/input "
          f"{stats.peak_ratio:.0f}x; findings {sum(stats.findings.values())}", flush=True)
    if final:
        print("by mutation kind:", dict(stats.by_kind.most_common()))
        print("by result (per target call):", dict(stats.by_code.most_common()))
        print("findings:", dict(stats.findings.most_common()) or "none")


def replay(path: Path) -> int:
    """Run one saved input through every target and print what happens."""
    data = path.read_bytes()
    try:
        outcome = check_input(data, RandomChooser(random.Random(0)))
    except Finding as exc:
        traceback.print_exception(exc.cause or exc)
        print(f"FINDING {exc}")
        return 1
    print(outcome.results)
    return 0


# ================================================================================ atheris
class AtherisChooser:
    """Decisions from atheris' FuzzedDataProvider: the coverage-guided engine steers them."""

    def __init__(self, provider) -> None:
        self.fdp = provider

    def integer(self, lo: int, hi: int) -> int:
        return self.fdp.ConsumeIntInRange(lo, hi)

    def blob(self, size: int) -> bytes:
        return self.fdp.ConsumeBytes(size)


def run_atheris(argv: list[str]) -> None:  # pragma: no cover - by hand only
    """Coverage-guided fuzzing: atheris chooses the mutations, the oracle is the same.

    The choices come from libFuzzer's input, so its corpus and crash files replay through this
    mode (``--atheris -- crash-<hash>``), not through ``--replay``. Slow (about 20 inputs/s on
    the 2-core machine: every loaded module is instrumented, numpy's Python parts included);
    it complements the random mode, it does not replace it.
    """
    import atheris

    atheris.instrument_all()  # spcodec is already imported: instrument what is loaded
    seeds = build_seeds()

    def one_input(raw: bytes) -> None:
        ch = AtherisChooser(atheris.FuzzedDataProvider(raw))
        _, data = make_mutant(seeds, ch, choice(ch, list(KIND_WEIGHTS)))
        check_input(data, ch)

    atheris.Setup([sys.argv[0]] + argv, one_input)
    atheris.Fuzz()


# =================================================================================== main
def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--iterations", type=int, default=200_000)
    parser.add_argument("--seconds", type=float, default=float("inf"))
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--out", type=Path, default=None,
                        help="folder for reproducers (default: a new temporary folder)")
    parser.add_argument("--time-bound", type=float, default=2.0,
                        help="seconds one input may take through all targets")
    parser.add_argument("--memory-every", type=int, default=25,
                        help="measure traced peak memory on every n-th input")
    parser.add_argument("--address-space-gib", type=float, default=8.0,
                        help="RLIMIT_AS for this process, so a runaway allocation fails")
    parser.add_argument("--replay", type=Path, default=None)
    parser.add_argument("--atheris", action="store_true")
    args, rest = parser.parse_known_args(argv)
    if args.replay:
        return replay(args.replay)
    limit = int(args.address_space_gib * 2**30)
    resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
    if args.atheris:
        run_atheris(rest)
        return 0
    out = args.out or Path(tempfile.mkdtemp(prefix="spcodec-fuzz-"))
    out.mkdir(parents=True, exist_ok=True)
    print(f"reproducers go to {out}", flush=True)
    stats = fuzz(args.iterations, args.seconds, args.seed, out, args.time_bound,
                 args.memory_every)
    return 1 if stats.findings else 0


if __name__ == "__main__":
    sys.exit(main())
