"""Mutators that claim far more than the file holds (counts, lengths, codebook sizes), the rest
kept consistent, so the memory bounds of [R-60]..[R-62] are tested where the claim is read."""

from __future__ import annotations

import struct

from spcodec.container import SectionType
from spcodec.writer import LayerSpec, SectionSpec

from .choosers import Chooser, chance, choice
from .payloads import recompress
from .seeds import SeedFile, copy_layers, copy_sections, pick_section, rebuild

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
        sec = sections[pick_section(seed, ch)]
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
