"""The deterministic bitstream writer: already-encoded components in, ``.spc`` bytes out.

The encoder and the conformance generator both call :func:`build_bitstream`. It makes no encoding
decisions (no clustering, fitting or quantization): it lays out the sections the spec requires, in
layer order ([R-10]), compresses them, and fills in the header, the layer table, the table of contents
and the CRCs. The same inputs always give the same bytes ([R-90]).

:func:`assemble` is the lower level: it takes explicit :class:`SectionSpec` objects, and lets the
conformance generator override any derived field to build deliberately invalid files through the same
code path.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field, replace

import numpy as np

from .attributes import PatchAttribute
from .bounds import scene_bounds, scene_positions
from .codecs import Compressor, compress, crc32, gzip_wrap, read_gzip_layer_ends
from .container import (
    CONTEXTS_MINOR,
    FIXED_HEADER_SIZE,
    LAYER_DTYPE,
    MAGIC,
    PREVIEW_MINOR,
    SECTION_DTYPE,
    SECTION_FLAG_REQUIRED,
    VERSION_MAJOR,
    VERSION_MINOR,
    Codec,
    FixedHeader,
    LayerKind,
    PreviewPayload,
    SectionType,
    header_size,
)
from .fileio import atomic_write
from .index_contexts import IndexContext, pack_contexts, to_ranks
from .sections import (
    Codebook,
    PatchPositions,
    SketchCluster,
    pack_codebooks,
    pack_indices,
    pack_positions,
    pack_sketch,
)


@dataclass
class PatchLayer:
    """One patch layer: positions and, per attribute, uint8 codebook indices (N, groups)."""

    positions: PatchPositions
    indices: dict[PatchAttribute, np.ndarray]

    def __len__(self) -> int:
        return len(self.positions)


@dataclass(frozen=True)
class Preview:
    """A small stand-alone file shown until layer ``takeover_layer`` has arrived (spec 7.4)."""

    file: bytes
    """A whole spcodec file without gzip wrapper and without a preview of its own."""
    takeover_layer: int

    def payload(self) -> bytes:
        """The ``PREVIEW`` section's raw bytes."""
        return PreviewPayload.build(dict(takeover_layer=self.takeover_layer, reserved=0,
                                         file=self.file))


@dataclass
class EncodedScene:
    """Everything a file holds, already encoded: the writer's input."""

    sh_degree: int
    sketch: list[SketchCluster] = field(default_factory=list)
    codebooks: list[Codebook] = field(default_factory=list)
    patch_layers: list[PatchLayer] = field(default_factory=list)
    metadata: dict | None = None
    preview: Preview | None = None
    index_contexts: list[IndexContext] = field(default_factory=list)
    """Context-coded index columns (spec 7.5): written as ``PATCH_INDEX_CONTEXTS`` in layer 1
    when not empty, every patch layer's target columns then stored as ranks."""

    @property
    def sketch_count(self) -> int:
        return sum(c.point_count for c in self.sketch)


@dataclass
class WriteOptions:
    """How sections are compressed, whether the file is gzip-wrapped, and whether the metadata
    gets the scene's box."""

    codec: Codec = Codec.ZLIB
    level: int | None = None
    gzip: bool = False
    bounds: bool = False
    """Add ``bounds`` (spcodec/bounds.py: every layer's positions, [R-71]) to the metadata, for a
    viewer to frame the whole scene from layer 0: the encoder's files do; hand-made ones, whose
    bytes tests and conformance vectors fix, do not."""


@dataclass
class SectionSpec:
    """One section to assemble. Fields left None are derived; set them to forge invalid files."""

    type: int
    layer: int
    raw: bytes
    codec: int = Codec.ZLIB
    required: bool = True
    flags: int | None = None
    stored: bytes | None = None
    raw_length: int | None = None
    crc: int | None = None
    reserved: int = 0
    column_bytes: int | None = None
    """Length of the equal columns ``raw`` is made of, when it is (PATCH_ATTRIBUTES): lets zlib
    give each column its own deflate block (:func:`spcodec.codecs.compress`)."""


@dataclass
class LayerSpec:
    """One layer of the layer table."""

    kind: LayerKind
    gaussian_count: int
    end_offset: int | None = None


@dataclass(frozen=True)
class SectionExtent:
    """Where one section lies in the unwrapped file, as its table-of-contents entry says."""

    type: str
    """The section type's name (``SectionType``), e.g. ``PATCH_ATTRIBUTES``."""
    layer: int
    offset: int
    length: int
    """Stored bytes (after the section codec)."""


@dataclass(frozen=True)
class FileLayout:
    """The byte layout of a file the writer made: what an encoder sizing trial files needs,
    without reading the file back through the decoder."""

    sections: tuple[SectionExtent, ...]
    layer_gaussians: tuple[int, ...]
    layer_ends: tuple[int, ...]
    """End offset of each layer in the unwrapped file (the layer table's)."""
    file_size: int
    """The unwrapped file's size (the header's)."""
    stored_layer_ends: tuple[int, ...] | None = None
    """End offset of each layer in the bytes as stored: the gzip member's recorded offsets
    when wrapped, else None (then they are ``layer_ends``)."""

    def section_bytes(self) -> dict[str, int]:
        """Stored bytes per section type, summed over layers."""
        out: dict[str, int] = {}
        for sec in self.sections:
            out[sec.type] = out.get(sec.type, 0) + sec.length
        return out

    def stored_ends(self) -> tuple[int, ...]:
        """Each layer's end in the bytes as stored (what a range request asks for)."""
        return self.layer_ends if self.stored_layer_ends is None else self.stored_layer_ends


@dataclass(frozen=True)
class WrittenFile:
    """A file and its layout."""

    data: bytes
    layout: FileLayout

    @property
    def size(self) -> int:
        """Bytes as stored (gzip-wrapped when the file is)."""
        return len(self.data)


def assemble(sections: list[SectionSpec], layers: list[LayerSpec], sh_degree: int,
             level: int | None = None, header_overrides: dict | None = None,
             store_when_larger: bool = True) -> bytes:
    """Lay out header, layer table, TOC and sections; compute offsets and CRCs ([R-4]..[R-12]).

    With ``store_when_larger``, a section that its codec would make larger is stored uncompressed
    (codec none) instead. The version is 1.0, 1.1 when a ``PREVIEW`` section needs it, 1.2 when a
    ``PATCH_INDEX_CONTEXTS`` section does ([R-92]: the oldest minor version that expresses the
    file).
    """
    return assemble_file(sections, layers, sh_degree, level, header_overrides,
                         store_when_larger).data


def assemble_file(sections: list[SectionSpec], layers: list[LayerSpec], sh_degree: int,
                  level: int | None = None, header_overrides: dict | None = None,
                  store_when_larger: bool = True, compressor: Compressor = compress) -> WrittenFile:
    """:func:`assemble` with the layout it laid out; ``compressor`` compresses each section (an
    encoder that writes the same sections many times passes one that remembers)."""
    start = header_size(len(layers), len(sections))
    toc = np.zeros(len(sections), dtype=SECTION_DTYPE)
    bodies, offset, extents = [], start, []
    layer_ends = [start] * len(layers)
    for i, sec in enumerate(sections):
        codec, stored = sec.codec, sec.stored
        if stored is None:
            stored = compressor(Codec(codec), sec.raw, level, sec.column_bytes)
            if store_when_larger and codec != Codec.NONE and len(stored) >= len(sec.raw):
                codec, stored = Codec.NONE, bytes(sec.raw)
        toc[i] = (sec.type, codec,
                  sec.flags if sec.flags is not None else (SECTION_FLAG_REQUIRED if sec.required else 0),
                  sec.layer, sec.reserved, offset, len(stored),
                  sec.raw_length if sec.raw_length is not None else len(sec.raw),
                  sec.crc if sec.crc is not None else crc32(stored), 0)
        bodies.append(stored)
        extents.append(SectionExtent(_type_name(sec.type), sec.layer, offset, len(stored)))
        offset += len(stored)
        if sec.layer < len(layers):
            layer_ends[sec.layer] = offset
    table = np.zeros(len(layers), dtype=LAYER_DTYPE)
    for i, layer in enumerate(layers):
        if layer.end_offset is not None:
            layer_ends[i] = layer.end_offset
        table[i] = (int(layer.kind), b"\0\0\0", layer.gaussian_count, layer_ends[i])
    minor = minor_version(sec.type for sec in sections)
    header = dict(magic=MAGIC, version_major=VERSION_MAJOR, version_minor=minor, flags=0,
                  header_size=start, layer_count=len(layers), section_count=len(sections),
                  sh_degree=sh_degree, reserved=b"\0" * 7,
                  gaussian_count=sum(layer.gaussian_count for layer in layers), file_size=offset)
    header.update(header_overrides or {})
    block = FixedHeader.build(header) + table.tobytes() + toc.tobytes()
    assert len(block) == start - 4 or header_overrides, "header block size mismatch"
    block += crc32(block).to_bytes(4, "little")
    layout = FileLayout(tuple(extents), tuple(layer.gaussian_count for layer in layers),
                        tuple(layer_ends), offset)
    return WrittenFile(block + b"".join(bodies), layout)


def minor_version(section_types) -> int:
    """The oldest minor version whose sections include every one of ``section_types`` ([R-92])."""
    types = set(section_types)
    if SectionType.PATCH_INDEX_CONTEXTS in types:
        return CONTEXTS_MINOR
    return PREVIEW_MINOR if SectionType.PREVIEW in types else VERSION_MINOR


def _type_name(section_type: int) -> str:
    try:
        return SectionType(section_type).name
    except ValueError:  # forged by the conformance generator
        return f"UNKNOWN_{section_type}"


def gzip_file(written: WrittenFile) -> WrittenFile:
    """``written`` wrapped in gzip ([R-82]), its layers' stored ends the member's offsets."""
    data = gzip_wrap(written.data, list(written.layout.layer_ends))
    ends = read_gzip_layer_ends(data)
    return WrittenFile(data, replace(written.layout,
                                     stored_layer_ends=None if ends is None else tuple(ends)))


def scene_sections(scene: EncodedScene, codec: Codec = Codec.ZLIB, bounds: bool = False
                   ) -> tuple[list[SectionSpec], list[LayerSpec]]:
    """The sections and layers of a scene, in the normative order ([R-13], [R-14]); with
    ``bounds``, its metadata (when it has some) records the box of its positions."""
    table, draco, coeffs = pack_sketch(scene.sketch, scene.sh_degree)
    sections: list[SectionSpec] = []
    if scene.metadata is not None:
        meta = json.dumps(with_bounds(scene) if bounds else scene.metadata, sort_keys=True,
                          separators=(",", ":"), ensure_ascii=False).encode("utf-8")
        sections.append(SectionSpec(SectionType.METADATA, 0, meta, codec, required=False))
    if scene.preview is not None:  # before the sketch, so that it arrives first (spec 7.4)
        sections.append(SectionSpec(SectionType.PREVIEW, 0, scene.preview.payload(), codec,
                                    required=False))
    sections += [
        SectionSpec(SectionType.SKETCH_CLUSTERS, 0, table, codec),
        SectionSpec(SectionType.SKETCH_POSITIONS, 0, draco, Codec.NONE),
        SectionSpec(SectionType.SKETCH_COEFFICIENTS, 0, coeffs, codec),
    ]
    layers = [LayerSpec(LayerKind.SKETCH, scene.sketch_count)]
    for k, patch in enumerate(scene.patch_layers, start=1):
        if k == 1:
            sections.append(SectionSpec(SectionType.PATCH_CODEBOOKS, k,
                                        pack_codebooks(scene.codebooks), codec))
            if scene.index_contexts:  # beside the codebooks, before what it applies to
                sections.append(SectionSpec(SectionType.PATCH_INDEX_CONTEXTS, k,
                                            pack_contexts(scene.index_contexts), codec))
        sections.append(SectionSpec(SectionType.PATCH_POSITIONS, k,
                                    pack_positions(patch.positions), codec))
        sections.append(SectionSpec(SectionType.PATCH_ATTRIBUTES, k,
                                    stored_indices(patch, scene), codec, column_bytes=len(patch)))
        layers.append(LayerSpec(LayerKind.PATCH, len(patch)))
    return sections, layers


def with_bounds(scene: EncodedScene) -> dict:
    """The scene's metadata with ``bounds``: the box of every layer's decoded positions (none for
    a scene without Gaussians)."""
    box = scene_bounds(scene_positions(scene.sketch, (p.positions for p in scene.patch_layers)))
    return dict(scene.metadata) if box is None else {**scene.metadata, "bounds": box}


def stored_indices(patch: PatchLayer, scene: EncodedScene) -> bytes:
    """A layer's PATCH_ATTRIBUTES payload: its index columns, target columns as ranks
    ([R-52], [R-107])."""
    raw = pack_indices(patch.indices, scene.codebooks)
    if not scene.index_contexts or not len(patch):
        return raw
    columns = np.frombuffer(raw, np.uint8).reshape(-1, len(patch))
    return to_ranks(columns, scene.index_contexts).tobytes()


def build_bitstream(scene: EncodedScene, options: WriteOptions | None = None) -> bytes:
    """The complete file for ``scene`` (gzip-wrapped when ``options.gzip``)."""
    return write_file(scene, options).data


def write_file(scene: EncodedScene, options: WriteOptions | None = None,
               compressor: Compressor = compress) -> WrittenFile:
    """:func:`build_bitstream` with the file's layout (section and layer extents)."""
    options = options or WriteOptions()
    sections, layers = scene_sections(scene, options.codec, options.bounds)
    written = assemble_file(sections, layers, scene.sh_degree, options.level,
                            compressor=compressor)
    return gzip_file(written) if options.gzip else written


def layer_end_offsets(data: bytes) -> list[int]:
    """End offsets of the layers of an unwrapped file, read back from its layer table."""
    head = FixedHeader.parse(data[:FIXED_HEADER_SIZE])
    table = np.frombuffer(data, dtype=LAYER_DTYPE, count=head.layer_count,
                          offset=FIXED_HEADER_SIZE)
    return [int(e) for e in table["end_offset"]]


def write_bitstream(path, scene: EncodedScene, options: WriteOptions | None = None) -> int:
    """Build the file and write it atomically; returns its size in bytes."""
    data = build_bitstream(scene, options)
    atomic_write(path, data)
    return len(data)
