"""Whole-file properties of bitstream v1: exact round trip, prefix property, integrity, truncation.

Each property is stated in the spec; the requirement ids are cited in the test names' docstrings.
"""

from __future__ import annotations

import DracoPy
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import spcodec
from spcodec.attributes import PatchAttribute, SketchAttribute, decode_opacity, decode_rotation
from spcodec.cloud import SH_REST_COUNTS
from spcodec.container import Codec
from spcodec.errors import FormatError, TruncatedError
from spcodec.polynomial import evaluate, normalize_positions
from spcodec.synthetic import random_encoded_scene
from spcodec.writer import EncodedScene, WriteOptions, build_bitstream, write_file

scenes = st.builds(
    random_encoded_scene,
    seed=st.integers(0, 2**31 - 1),
    clusters=st.integers(0, 4),
    patch_layers=st.integers(0, 3),
    patch_size=st.integers(0, 60),
    sh_degree=st.integers(0, 3),
    metadata=st.one_of(st.none(), st.just({"k": "v", "n": 1})),
)
codecs = st.sampled_from([Codec.ZLIB, Codec.NONE, Codec.ZSTD])


def expected_cloud(scene: EncodedScene) -> spcodec.GaussianCloud:
    """What a decoder must output, computed straight from the components (not via the decoder)."""
    parts = []
    sh = scene.sh_degree
    pending = np.zeros((0, 3), np.float32)
    for cl in scene.sketch:
        if cl.draco:  # a blob starts here; clusters without one continue it, in order
            pending = np.asarray(DracoPy.decode(cl.draco).points, np.float32).reshape(-1, 3)
        pts, pending = pending[:cl.point_count], pending[cl.point_count:]
        x = normalize_positions(pts, cl.center, cl.half_extent)
        values = {a: evaluate(x, c) for a, c in cl.models.items()}
        rest = values.get(SketchAttribute.SH_REST)
        parts.append(spcodec.GaussianCloud(
            means=pts, scales=values[SketchAttribute.SCALE],
            quats=decode_rotation(values[SketchAttribute.ROTATION]),
            opacities=decode_opacity(values[SketchAttribute.OPACITY][:, 0]),
            sh_dc=values[SketchAttribute.COLOR_DC],
            sh_rest=np.zeros((len(pts), SH_REST_COUNTS[sh], 3)) if rest is None
            else rest.reshape(len(pts), -1, 3)))
    for layer in scene.patch_layers:
        n = len(layer)
        vals = {}
        for cb in scene.codebooks:
            idx = np.asarray(layer.indices[cb.attribute]).reshape(n, cb.groups)
            vals[cb.attribute] = cb.entries.astype(np.float32)[idx].reshape(n, cb.attribute.width)
        rest = np.zeros((n, SH_REST_COUNTS[sh], 3))
        for band in range(1, sh + 1):
            attr = PatchAttribute(3 + band)
            rest[:, attr.sh_slice] = vals[attr].reshape(n, attr.width // 3, 3)
        parts.append(spcodec.GaussianCloud(
            means=layer.positions.decode(), scales=vals[PatchAttribute.SCALE],
            quats=decode_rotation(vals[PatchAttribute.ROTATION]),
            opacities=decode_opacity(vals[PatchAttribute.OPACITY][:, 0]),
            sh_dc=vals[PatchAttribute.COLOR_DC], sh_rest=rest))
    return spcodec.GaussianCloud.concat(parts, sh)


@given(scenes, codecs, st.booleans())
def test_round_trip_decodes_exactly_what_the_components_define(scene, codec, wrap):
    """[R-30]..[R-56]: lossless parts exact, polynomial parts evaluated as the spec says."""
    data = build_bitstream(scene, WriteOptions(codec=codec, gzip=wrap))
    result = spcodec.decode_layers(data)
    assert result.complete and len(result.layers) == 1 + len(scene.patch_layers)
    got, want = result.cloud, expected_cloud(scene)
    assert len(got) == len(want) == result.header.gaussian_count
    for name, a in got.arrays().items():
        b = want.arrays()[name]
        if name in ("means",) or len(scene.sketch) == 0:
            np.testing.assert_array_equal(a, b, err_msg=name)
        else:  # polynomial parts: same float64 evaluation, same rounding to float32
            np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-6, err_msg=name)
    assert got.is_finite()


@given(scenes)
def test_writer_is_deterministic(scene):
    """[R-90]: the same components give the same bytes."""
    assert build_bitstream(scene) == build_bitstream(scene)


@given(scenes, st.booleans())
def test_every_layer_boundary_prefix_decodes_to_those_layers(scene, wrap):
    """[R-11]: a prefix ending at a layer boundary decodes to layers 0..k."""
    data = build_bitstream(scene, WriteOptions(gzip=wrap))
    full = spcodec.decode_layers(data)
    info = spcodec.inspect(data).to_json()
    for k, layer in enumerate(info["layers"]):
        prefix = data[:layer["end_offset"]]
        part = spcodec.decode_layers(prefix)
        assert [len(x.cloud) for x in part.layers] == [len(x.cloud) for x in full.layers[:k + 1]]
        assert part.cloud.equals(spcodec.decode(data, max_layer=k))
        assert part.complete == (k == len(info["layers"]) - 1)


@settings(max_examples=15)
@given(scenes, st.data())
def test_any_byte_flip_raises_format_error(scene, data):
    """[R-7], [R-8]: every byte is covered by the header CRC or a section CRC."""
    blob = build_bitstream(scene)
    positions = data.draw(st.lists(st.integers(0, len(blob) - 1), min_size=1, max_size=8))
    for pos in positions:
        flipped = bytearray(blob)
        flipped[pos] ^= data.draw(st.integers(1, 255))
        with pytest.raises(FormatError):
            spcodec.decode(bytes(flipped))


def test_every_single_byte_flip_of_a_small_file_is_caught(small_file):
    """[R-7], [R-8], exhaustively over one file: a flip never decodes and never escapes."""
    for pos in range(len(small_file)):
        flipped = bytearray(small_file)
        flipped[pos] ^= 0x5A
        with pytest.raises(FormatError):
            spcodec.decode(bytes(flipped))


def test_every_truncation_of_a_small_file(small_file):
    """[R-12]: a cut inside the header or a layer raises; a cut at a boundary gives fewer layers."""
    header = spcodec.decode_layers(small_file).header
    ends = {layer.end_offset: layer.index for layer in header.layers}
    for cut in range(len(small_file)):
        if cut in ends:
            assert len(spcodec.decode_layers(small_file[:cut]).layers) == ends[cut] + 1
        else:
            with pytest.raises(FormatError) as err:
                spcodec.decode(small_file[:cut])
            assert isinstance(err.value, TruncatedError) or err.value.code in {"truncated",
                                                                                 "bad-magic"}


@settings(max_examples=20)
@given(scenes, st.data())
def test_truncated_gzip_wrapped_files(scene, data):
    """[R-81]: a prefix of a wrapped file behaves like the matching inner prefix."""
    blob = build_bitstream(scene, WriteOptions(gzip=True))
    full = spcodec.decode_layers(blob)
    offsets = spcodec.inspect(blob).gzip_layer_ends
    cut = data.draw(st.integers(0, len(blob) - 1))
    try:
        part = spcodec.decode_layers(blob[:cut])
    except FormatError:
        assert cut not in offsets  # a cut at a recorded flush point always decodes
        return
    k = len(part.layers)
    assert k <= len(full.layers)
    assert part.cloud.equals(spcodec.GaussianCloud.concat(
        [layer.cloud for layer in full.layers[:k]], full.header.sh_degree))


@given(scenes, st.booleans())
def test_layer_end_offsets_increase_strictly(scene, wrap):
    """[R-9] (1.0.1): every layer ends after the one before, so a prefix names one last layer."""
    layers = spcodec.inspect(build_bitstream(scene, WriteOptions(gzip=wrap))).to_json()["layers"]
    ends = [layer.get("inner_end_offset", layer["end_offset"]) for layer in layers]
    assert all(a < b for a, b in zip(ends, ends[1:]))


@given(scenes, codecs, st.booleans())
def test_the_writer_reports_the_layout_the_decoder_reads(scene, codec, wrap):
    """The section and layer extents the writer returns are the file's own table of contents
    and layer table (and, wrapped, the gzip member's recorded offsets): what the encoder sizes
    trial files by, without reading them back."""
    written = write_file(scene, WriteOptions(codec=codec, gzip=wrap))
    assert written.data == build_bitstream(scene, WriteOptions(codec=codec, gzip=wrap))
    info = spcodec.inspect(written.data).to_json()
    layout = written.layout
    assert [(s.type, s.layer, s.offset, s.length) for s in layout.sections] == \
        [(s["type"], s["layer"], s["offset"], s["length"]) for s in info["sections"]]
    assert list(layout.stored_ends()) == [layer["end_offset"] for layer in info["layers"]]
    assert list(layout.layer_ends) == [layer.get("inner_end_offset", layer["end_offset"])
                                       for layer in info["layers"]]
    assert list(layout.layer_gaussians) == [layer["gaussians"] for layer in info["layers"]]
    assert layout.file_size == info["file_size"] and written.size == info["stored_size"]
    totals: dict[str, int] = {}
    for sec in info["sections"]:
        totals[sec["type"]] = totals.get(sec["type"], 0) + sec["length"]
    assert layout.section_bytes() == totals


@settings(max_examples=20)
@given(scenes, st.integers(0, 7))
def test_a_cut_gzip_trailer_checks_the_crc_once_its_four_bytes_are_there(scene, kept):
    """[R-81] (1.0.1): a wrong CRC-32 is refused as soon as the input holds it, not before."""
    blob = bytearray(build_bitstream(scene, WriteOptions(gzip=True)))
    blob[-8] ^= 0x01
    cut = bytes(blob[:len(blob) - 8 + kept])
    if kept < 4:
        assert spcodec.decode(cut).equals(spcodec.decode(build_bitstream(scene)))
    else:
        with pytest.raises(FormatError) as err:
            spcodec.decode(cut)
        assert err.value.code == "bad-gzip"


def test_trailing_bytes_are_refused(small_file):
    with pytest.raises(FormatError) as err:
        spcodec.decode(small_file + b"\0")
    assert err.value.code == "trailing-data"
