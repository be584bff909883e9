"""Mutators of the file's structure: header, layer-table and TOC fields (header CRC repaired),
section lists and layer tables reshuffled, cuts, trailing bytes, unrepaired flips, splices."""

from __future__ import annotations

import dataclasses
import struct

from spcodec.codecs import crc32
from spcodec.container import FIXED_HEADER_SIZE, LayerKind, SectionType, header_size
from spcodec.writer import LayerSpec, SectionSpec, layer_end_offsets

from .choosers import Chooser, chance, choice
from .edits import Field, havoc, interesting, poke
from .payloads import recompress
from .seeds import SeedFile, copy_layers, copy_sections, pick_section, rebuild


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
    i = pick_section(seed, ch)
    op = ch.integer(0, 9)
    if op == 0 and len(sections) > 1:
        del sections[i]
    elif op == 1:
        sections.insert(ch.integer(0, len(sections)), dataclasses.replace(sections[i]))
    elif op == 2:
        j = pick_section(seed, ch)
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
