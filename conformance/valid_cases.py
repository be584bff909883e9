"""Valid vectors: files every conforming decoder must decode, and the Gaussians they decode to.

Together they cover every section type and codec, gzip on and off, SH degrees 0..3, polynomial
degrees 0..10 for every modelled attribute (the SH-rest model included), the four patch position
modes, kd-tree and sequential Draco, runs of clusters sharing a blob, an empty sketch and empty
patch layers, 1 to 8 layers, prefixes cut at each layer boundary, skipped optional sections of
unknown types, and extreme legal values.
"""

from __future__ import annotations

import gzip
import struct
import zlib

import numpy as np

from spcodec.attributes import PatchAttribute, SketchAttribute
from spcodec.codecs import gzip_wrap, read_gzip_layer_ends
from spcodec.container import CLUSTER_DTYPE, SH_REST_ABSENT, Codec, LayerKind, PositionMode, SectionType
from spcodec.sections import Codebook, PatchPositions, SketchCluster
from spcodec.writer import EncodedScene, LayerSpec, PatchLayer, SectionSpec, layer_end_offsets

from . import scenes
from .declare import valid
from .forge import Draft, metadata

F16_MAX = 65504.0
F16_TINY = 2.0 ** -24
"""The smallest positive binary16 (subnormal)."""
F32_MAX = float(np.finfo(np.float32).max)

MODES = [PositionMode.FLOAT16, PositionMode.QUANT16, PositionMode.FLOAT32, PositionMode.DRACO]


def _file(scene: EncodedScene, codec: Codec = Codec.ZLIB) -> bytes:
    return Draft.of(scene, codec).build()


def _gzip(inner: bytes) -> bytes:
    return gzip_wrap(inner, layer_end_offsets(inner))


# ------------------------------------------------------------------- scenes, codecs, gzip
@valid("sh0-zlib-two-layers",
       "SH 0, zlib sections, three kd-tree sketch clusters, QUANT16 and float16 patch layers",
       ["R-2", "R-30", "R-31", "R-32", "R-40", "R-41", "R-43", "R-44", "R-47", "R-48", "R-50",
        "R-52", "R-54", "R-55", "R-56", "R-57", "R-11", "R-96", "R-98"], prefixes=True)
def sh0_zlib() -> bytes:
    return _file(scenes.scene(1, 0, [7, 5, 9], [PositionMode.QUANT16, PositionMode.FLOAT16], 12,
                              metadata={"generator": "spcodec conformance"}))


@valid("sh1-none-float32", "SH 1, every section stored with codec none, float32 patch positions",
       ["R-22", "R-33", "R-53", "R-56"])
def sh1_none() -> bytes:
    scene = scenes.scene(2, 1, [6, 4, 5], [PositionMode.FLOAT32], 10, runs=[1, 2])
    draft = Draft.of(scene, Codec.NONE)
    return draft.build()


@valid("sh2-zstd-draco-patch",
       "SH 2, every section zstd-compressed (Draco blobs too), Draco patch positions",
       ["R-22", "R-23", "R-24", "R-58", "R-33"])
def sh2_zstd() -> bytes:
    scene = scenes.scene(3, 2, [5, 6, 4], [PositionMode.DRACO, PositionMode.DRACO], 9, runs=[2, 1])
    draft = Draft.of(scene)
    draft.set_codec(Codec.ZSTD)
    return draft.build()


@valid("codecs-zlib-everywhere",
       "SH 1, every section zlib-compressed, even the Draco positions and metadata it enlarges",
       ["R-22", "R-24", "R-70"])
def zlib_everywhere() -> bytes:
    scene = scenes.scene(4, 1, [4, 4], [PositionMode.QUANT16], 6,
                         metadata={"note": "zlib everywhere"})
    draft = Draft.of(scene)
    draft.set_codec(Codec.ZLIB)
    return draft.build()


@valid("sh3-gzip-all-modes",
       "SH 3 with SH-rest models, gzip wrapper with layer offsets, patch layers in all four modes",
       ["R-80", "R-81", "R-82", "R-83", "R-33", "R-53", "R-58"], prefixes=True)
def sh3_gzip() -> bytes:
    rng = np.random.default_rng(5)
    clusters = [scenes.cluster(rng, 3, n, scenes.degrees(1, 1, 0, 2, rest))
                for n, rest in [(5, 1), (4, SH_REST_ABSENT), (6, 0)]]
    books = scenes.codebooks(rng, 3, entries=4)
    layers = [scenes.patch_layer(rng, books, 5, mode) for mode in MODES]
    return _gzip(_file(EncodedScene(3, clusters, books, layers)))


@valid("zstd-frames-with-checksums", "SH 1, zstd frames that carry their optional checksum",
       ["R-22", "R-23"])
def zstd_checksums() -> bytes:
    import zstandard

    scene = scenes.scene(6, 1, [5], [PositionMode.FLOAT16], 6)
    draft = Draft.of(scene)
    draft.set_codec(Codec.ZSTD)
    compressor = zstandard.ZstdCompressor(level=3, write_content_size=True, write_checksum=True)
    for sec in draft.sections:
        sec.stored = compressor.compress(sec.raw)
    return draft.build()


# ----------------------------------------------------------------------- the sketch layer
@valid("sketch-degrees-0-to-10",
       "SH 0, eleven clusters whose four models take every polynomial degree from 0 to 10",
       ["R-41", "R-43", "R-44", "R-45", "R-46", "R-96"])
def sketch_degrees() -> bytes:
    rng = np.random.default_rng(7)
    clusters = [scenes.cluster(rng, 0, 6, scenes.degrees(d, (d + 3) % 11, (d + 6) % 11,
                                                         (d + 9) % 11), density=0.35)
                for d in range(11)]
    return _file(EncodedScene(0, clusters))


@valid("sketch-sh-rest-degrees",
       "SH 1, SH-rest models of degrees 0, 1, 2, 3, 5 and 10, and a cluster without one",
       ["R-33", "R-44", "R-45"])
def sketch_sh_rest() -> bytes:
    rng = np.random.default_rng(8)
    clusters = [scenes.cluster(rng, 1, 5, scenes.degrees(1, 0, 1, 1, rest), density=0.4)
                for rest in [0, 1, 2, 3, 5, 10, SH_REST_ABSENT]]
    return _file(EncodedScene(1, clusters))


@valid("sketch-shared-blobs",
       "SH 1, runs of 1, 2, 3 and 5 clusters sharing sequential Draco blobs; kd-tree singles",
       ["R-47", "R-48", "R-40", "R-42"])
def sketch_runs() -> bytes:
    rng = np.random.default_rng(9)
    runs = [1, 2, 3, 1, 5]
    clusters = scenes.sketch(rng, 1, [4, 3, 5, 2, 3, 6, 1, 4, 2, 3, 5, 2], runs)
    return _file(EncodedScene(1, clusters))


@valid("many-tiny-clusters",
       "100 000 one-point clusters sharing one blob: decoding must cost time per point, not per "
       "cluster", ["R-1", "R-47", "R-48"], npz=True)
def many_tiny_clusters() -> bytes:
    count = 100_000
    blob, _ = scenes.draco_points(np.zeros((count, 3), np.float32), kdtree=False, bits=1,
                                  level=10)
    records = np.zeros(count, CLUSTER_DTYPE)          # built as arrays: 100 000 objects are slow
    records["point_count"] = 1
    records["draco_length"][0] = len(blob)
    records["half_extent"] = 1.0
    records["degrees"] = [1, 1, 1, 1, SH_REST_ABSENT]
    rotation = np.array([[1, 0, 0, 0]] + [[0.25] * 4] * 3, "<f2")
    one = np.concatenate([np.full(12, 0.25), rotation.ravel(), np.full(4, 0.25),
                          np.full(12, 0.25)]).astype("<f2").tobytes()
    sections = [SectionSpec(SectionType.SKETCH_CLUSTERS, 0,
                            struct.pack("<I", count) + records.tobytes()),
                SectionSpec(SectionType.SKETCH_POSITIONS, 0, blob, Codec.NONE),
                SectionSpec(SectionType.SKETCH_COEFFICIENTS, 0, one * count)]
    return Draft(sections, [LayerSpec(LayerKind.SKETCH, count)], 0).build()


# ------------------------------------------------------------------------ layers, sections
@valid("empty-sketch", "SH 2, a cluster table of zero clusters and two patch layers",
       ["R-46", "R-13"])
def empty_sketch() -> bytes:
    return _file(scenes.scene(10, 2, [], [PositionMode.QUANT16, PositionMode.DRACO], 7))


@valid("sketch-only", "SH 2, one layer: the sketch alone", ["R-13", "R-9"])
def sketch_only() -> bytes:
    return _file(scenes.scene(11, 2, [6, 3], [], 0, runs=[2]))


@valid("empty-scene", "SH 2, no Gaussians at all: one layer, an empty cluster table",
       ["R-46", "R-98"])
def empty_scene() -> bytes:
    return _file(EncodedScene(2))


@valid("empty-patch-layers",
       "SH 1, patch layers of zero Gaussians in QUANT16, Draco and float16, then one of five",
       ["R-53", "R-55", "R-58", "R-52", "R-99"])
def empty_patch() -> bytes:
    rng = np.random.default_rng(12)
    clusters = scenes.sketch(rng, 1, [4], None)
    books = scenes.codebooks(rng, 1, entries=3)
    layers = [scenes.patch_layer(rng, books, 0, mode) for mode in
              (PositionMode.QUANT16, PositionMode.DRACO, PositionMode.FLOAT16)]
    layers.append(scenes.patch_layer(rng, books, 5, PositionMode.FLOAT32))
    return _file(EncodedScene(1, clusters, books, layers))


@valid("eight-layers", "SH 0, a sketch and seven patch layers",
       ["R-11", "R-12", "R-57", "R-10", "R-100"],
       prefixes=True)
def eight_layers() -> bytes:
    rng = np.random.default_rng(13)
    clusters = scenes.sketch(rng, 0, [4, 3], None)
    books = scenes.codebooks(rng, 0, entries=4)
    layers = [scenes.patch_layer(rng, books, 3 + k % 3, MODES[k % 4]) for k in range(7)]
    return _file(EncodedScene(0, clusters, books, layers))


def _small_draft(seed: int = 14) -> Draft:
    scene = scenes.scene(seed, 1, [4, 3], [PositionMode.QUANT16, PositionMode.FLOAT16], 4,
                         metadata={"k": "v"})
    return Draft.of(scene)


@valid("unknown-optional-sections",
       "Optional sections of unknown types in layers 0, 1 and 2, with codecs none, zlib, zstd and "
       "the unknown id 7, all skipped", ["R-20", "R-22", "R-92"])
def unknown_optional() -> bytes:
    draft = _small_draft()
    draft.sections.insert(0, SectionSpec(0x7F00, 0, b"first in layer 0", Codec.NONE,
                                         required=False))
    draft.insert_after_layer(0, SectionSpec(0x0100, 0, b"zstd, never inflated" * 3, Codec.ZSTD,
                                            required=False))
    draft.insert_after_layer(1, SectionSpec(0xFFFF, 1, b"zlib payload" * 4, Codec.ZLIB,
                                            required=False))
    draft.insert_after_layer(2, SectionSpec(0x0123, 2, b"", 7, required=False, stored=b"\x07" * 9))
    return draft.build()


@valid("sections-in-any-order",
       "Sections in each layer in an order other than the recommended one",
       ["R-13", "R-57"])
def sections_any_order() -> bytes:
    draft = _small_draft(15)
    by_layer: dict[int, list[SectionSpec]] = {}
    for sec in draft.sections:
        by_layer.setdefault(sec.layer, []).append(sec)
    draft.sections = [sec for layer in sorted(by_layer) for sec in reversed(by_layer[layer])]
    return draft.build()


@valid("minor-version-7", "A file that says version 1.7: later minor versions decode",
       ["R-92", "R-5"])
def minor_version() -> bytes:
    draft = _small_draft(16)
    draft.header["version_minor"] = 7
    return draft.build()


@valid("metadata-not-json",
       "Metadata that is not JSON (deep nesting, NaN): decoders decode the file all the same "
       "(a tool that reports metadata says bad-metadata)", ["R-70"])
def metadata_not_json() -> bytes:
    draft = _small_draft(17)
    draft.sections[0] = metadata(b'{"n": NaN, "deep": ' + b"[" * 5000)
    return draft.build()


@valid("patch-draco-kdtree-order",
       "A patch layer in a kd-tree Draco blob (a set of positions, as writers may code it from "
       "1.2.1, [R-58]): its Gaussians come in Draco's decode order", ["R-58", "R-100", "R-1"])
def patch_kdtree() -> bytes:
    rng = np.random.default_rng(18)
    books = scenes.codebooks(rng, 0, entries=3)
    blob, decoded = scenes.draco_points(rng.uniform(-3, 3, (9, 3)), kdtree=True)
    indices = {cb.attribute: rng.integers(0, cb.entries.shape[0], (9, cb.groups)).astype(np.uint8)
               for cb in books}
    layer = PatchLayer(PatchPositions.draco(blob, decoded), indices)
    return _file(EncodedScene(0, scenes.sketch(rng, 0, [3], None), books, [layer]))


# --------------------------------------------------------------------------- extreme values
def _extreme_codebooks() -> list[Codebook]:
    """Entries at the binary16 extremes, signed zeros and subnormals; scalar and vector books."""
    special = [F16_MAX, -F16_MAX, F16_TINY, -F16_TINY, 0.0, -0.0, 1.0, -1.0]
    scale = np.array(special + [0.5] * 248, np.float16).reshape(256, 1)          # 256 entries
    rotation = np.array([[0, 0, 0, 0], [F16_MAX, F16_MAX, F16_MAX, F16_MAX],
                         [F16_TINY, 0, 0, 0], [-1, 0, 0, 0]], np.float16)          # zero: identity
    opacity = np.array([[0.0], [1.0], [1e-4], [1 - 1e-4], [-F16_MAX], [F16_MAX], [0.5]], np.float16)
    colour = np.array(special, np.float16).reshape(8, 1)
    band1 = np.array([[F16_MAX, -F16_TINY, -0.0]], np.float16)                      # one entry
    return [Codebook(PatchAttribute.SCALE, scale), Codebook(PatchAttribute.ROTATION, rotation),
            Codebook(PatchAttribute.OPACITY, opacity), Codebook(PatchAttribute.COLOR_DC, colour),
            Codebook(PatchAttribute.SH_BAND_1, band1)]


def _cycle_indices(books: list[Codebook], n: int) -> dict[PatchAttribute, np.ndarray]:
    """Every entry of every codebook used, the last (index 255 of a full book) included."""
    out = {}
    for cb in books:
        count = cb.entries.shape[0]
        idx = (np.arange(n * cb.groups) * 7 + 255) % count
        out[cb.attribute] = idx.reshape(n, cb.groups).astype(np.uint8)
    return out


@valid("extreme-patch-values",
       "Codebook entries at the binary16 extremes, a zero quaternion, clamped opacities, 256 and "
       "1-entry books; positions at the float16 and float32 extremes; QUANT16 with a -0.0 step, "
       "wrapping deltas and origin + 65535 step just below the float32 maximum",
       ["R-31", "R-32", "R-34", "R-51", "R-52", "R-53", "R-54", "R-55", "R-56", "R-96"])
def extreme_patch() -> bytes:
    books = _extreme_codebooks()
    n = 8
    f16 = np.array([[F16_MAX, -F16_MAX, 0.0], [-0.0, F16_TINY, -F16_TINY]] * 4, np.float16)
    f32 = np.array([[F32_MAX, -F32_MAX, 1e-45], [-0.0, 1e38, -1e-38]] * 4, np.float32)
    q = np.array([[0, 0, 7], [65535, 65535, 8], [0, 1, 9], [32768, 0, 10], [32767, 65535, 11],
                  [1, 32768, 12], [65535, 0, 13], [0, 32767, 14]], np.uint16)
    origin = np.array([3.0e38, -1.5, 1e-45], np.float32)
    step = np.array([np.float32((F32_MAX - 3.0e38) / 65535 * 0.999), -0.0, 0.0], np.float32)
    layers = [PatchLayer(PatchPositions.float16(f16), _cycle_indices(books, n)),
              PatchLayer(PatchPositions.float32(f32), _cycle_indices(books, n)),
              PatchLayer(PatchPositions(PositionMode.QUANT16, q, origin, step),
                         _cycle_indices(books, n))]
    return _file(EncodedScene(1, [], books, layers))


@valid("extreme-sketch-values",
       "Sketch models with binary16-extreme and subnormal coefficients, opacities coded outside "
       "[0, 1], normalized coordinates of exactly 2, a one-point cluster",
       ["R-31", "R-32", "R-34", "R-42", "R-43", "R-45", "R-96"])
def extreme_sketch() -> bytes:
    rng = np.random.default_rng(19)
    wide = scenes.cluster(rng, 0, 6, scenes.degrees(1, 1, 1, 1))
    decoded = _decoded_points(wide)
    low, high = decoded.min(axis=0), decoded.max(axis=0)
    wide.center = low.copy()                                     # the lowest point: x = 0
    wide.half_extent = ((high - low) / 2).astype(np.float32)      # the highest point: x = 2
    reach = (high.astype(np.float64) - low) / wide.half_extent
    if reach.max() > 2 or not (reach == 2).any():
        raise AssertionError(f"normalized extremes {reach}, wanted 2 exactly on some axis")
    wide.models[SketchAttribute.SCALE][:] = [[F16_TINY, -F16_TINY, -1], [1, 0, 0], [0, 1, 0],
                                             [0, 0, 1]]
    wide.models[SketchAttribute.OPACITY][:] = [[-2.0], [3.0], [0], [0]]   # coded -2 .. 10
    wide.models[SketchAttribute.COLOR_DC][0] = [F16_MAX, -F16_MAX, 0.0]
    wide.models[SketchAttribute.ROTATION][0] = [F16_MAX, -F16_MAX, 1, 0]
    single = scenes.cluster(rng, 0, 1, scenes.degrees(0, 0, 0, 0))
    single.models[SketchAttribute.OPACITY][:] = 1.5                # clamped to 1 - 1e-4
    return _file(EncodedScene(0, [wide, single]))


def _decoded_points(c: SketchCluster) -> np.ndarray:
    import DracoPy

    return np.asarray(DracoPy.decode(c.draco).points, np.float32).reshape(-1, 3)


# ------------------------------------------------------------------------------- gzip forms
def _gzip_base() -> bytes:
    return _file(scenes.scene(20, 1, [5, 4], [PositionMode.QUANT16, PositionMode.FLOAT16], 6,
                              runs=[2]))


@valid("gzip-plain-member",
       "A gzip wrapper as any gzip tool writes it: no layer offsets, no header CRC, a file name",
       ["R-80", "R-82", "R-83"])
def gzip_plain() -> bytes:
    inner = _gzip_base()
    head = b"\x1f\x8b\x08\x08" + struct.pack("<I", 1_700_000_000) + b"\x02\x03" + b"scene.spc\0"
    deflater = zlib.compressobj(6, zlib.DEFLATED, -15)
    body = deflater.compress(inner) + deflater.flush()
    return head + body + struct.pack("<II", zlib.crc32(inner), len(inner))


@valid("gzip-layer-offsets-malformed",
       "A gzip wrapper whose SP subfield lists fewer offsets than there are layers (to be ignored)",
       ["R-83", "R-80"])
def gzip_offsets_short() -> bytes:
    inner = _gzip_base()
    return gzip_wrap(inner, layer_end_offsets(inner)[:1])


@valid("gzip-padding-bits-set",
       "A gzip wrapper with padding bits set before a flush's stored block: the same inflated bytes",
       ["R-16", "R-81", "R-80"])
def gzip_padding() -> bytes:
    wrapped = bytearray(_gzip(_gzip_base()))
    marker = read_gzip_layer_ends(bytes(wrapped))[0] - 4       # where 00 00 FF FF starts
    wrapped[marker - 1] ^= 0x80                                # the top bit pads to the byte
    if gzip.decompress(bytes(wrapped)) != gzip.decompress(_gzip(_gzip_base())):
        raise AssertionError("the changed bit was not padding")
    return bytes(wrapped)


@valid("gzip-cut-in-trailer",
       "A gzip-wrapped file cut inside its 8-byte trailer: the whole inner file, CRC unchecked",
       ["R-81", "R-16"])
def gzip_cut_trailer() -> bytes:
    return _gzip(_gzip_base())[:-3]


@valid("gzip-cut-inside-flush",
       "A gzip-wrapped file cut two bytes before layer 1's recorded offset, inside the flush: "
       "layers 0 and 1", ["R-81", "R-83", "R-11"])
def gzip_cut_flush() -> bytes:
    wrapped = _gzip(_gzip_base())
    return wrapped[:read_gzip_layer_ends(wrapped)[1] - 2]

