"""The seed corpus: small valid files kept as their parts, so a mutant can be rebuilt with its
offsets, lengths and checksums derived again."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from spcodec.codecs import compress
from spcodec.container import Codec, PositionMode
from spcodec.synthetic import random_codebooks, random_patch_layer, random_sketch
from spcodec.writer import EncodedScene, LayerSpec, SectionSpec, assemble, scene_sections

from .choosers import Chooser


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
    """A synthetic scene of the given shape (the codec's own random generators, seeded)."""
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
    """Shallow copies a mutator may edit: the seed's own specs stay valid for the next mutant."""
    return [dataclasses.replace(s) for s in sections]


def copy_layers(layers: list[LayerSpec]) -> list[LayerSpec]:
    """Shallow copies of the layer specs, for the same reason as :func:`copy_sections`."""
    return [dataclasses.replace(layer) for layer in layers]


def rebuild(seed: SeedFile, sections: list[SectionSpec], layers: list[LayerSpec] | None = None,
            header: dict | None = None) -> bytes:
    """Assemble a mutant: offsets, lengths and CRCs are derived unless a spec overrides them."""
    return assemble(sections, layers if layers is not None else seed.layers, seed.sh_degree,
                    header_overrides=header, store_when_larger=False)


def pick_section(seed: SeedFile, ch: Chooser) -> int:
    """Index of one of the seed's sections, the target of a section-level mutation."""
    return ch.integer(0, len(seed.sections) - 1)
