"""The decoder API and the header/layout requirements, on files forged through the writer."""

from __future__ import annotations

import io
import subprocess
import sys

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import spcodec
from spcodec.container import Codec, LayerKind, SectionType
from spcodec.errors import FormatError, LimitError, TruncatedError, UsageError
from spcodec.limits import Limits
from spcodec.writer import SectionSpec, WriteOptions, assemble, build_bitstream, scene_sections


def forge(scene, edit=None, layer_edit=None, **header_overrides) -> bytes:
    """Build ``scene`` after letting ``edit`` change its section list (and layers)."""
    sections, layers = scene_sections(scene)
    if edit:
        sections = edit(sections) or sections
    if layer_edit:
        layers = layer_edit(layers) or layers
    return assemble(sections, layers, scene.sh_degree, header_overrides=header_overrides or None)


def error_code(data: bytes, **kwargs) -> str:
    with pytest.raises(FormatError) as err:
        spcodec.decode(data, **kwargs)
    return err.value.code


# ----------------------------------------------------------------------------- sources & API
def test_decode_accepts_path_bytes_and_file_objects(small_file, tmp_path):
    path = tmp_path / "scene.spc"
    path.write_bytes(small_file)
    a = spcodec.decode(path)
    assert a.equals(spcodec.decode(str(path)))
    assert a.equals(spcodec.decode(small_file))
    assert a.equals(spcodec.decode(memoryview(small_file)))
    assert a.equals(spcodec.decode(io.BytesIO(small_file)))
    with pytest.raises(UsageError):
        spcodec.decode(small_file, max_layer=-1)
    with pytest.raises(UsageError):
        spcodec.decode(12345)


def test_max_layer_needs_only_the_bytes_up_to_that_layer(small_file):
    result = spcodec.decode_layers(small_file)
    first_end = result.header.layers[1].end_offset
    part = spcodec.decode_layers(small_file[:first_end + 10], max_layer=1)  # cut inside layer 2
    assert len(part.layers) == 2 and not part.complete
    with pytest.raises(TruncatedError):
        spcodec.decode(small_file[:first_end + 10])                        # all layers wanted
    assert len(spcodec.decode_layers(small_file, max_layer=99).layers) == 3


def test_inspect_reports_layers_and_byte_ranges(small_file, tmp_path):
    info = spcodec.inspect(small_file).to_json()
    assert info["version"] == "1.0" and info["gaussians"] == len(spcodec.decode(small_file))
    assert [layer["index"] for layer in info["layers"]] == [0, 1, 2]
    assert info["layers"][-1]["end_offset"] == len(small_file)
    for sec in info["sections"]:
        assert {"type", "codec", "offset", "length"} <= sec.keys()
    assert info["metadata"] == {"generator": "tests"}
    # A path is described from its header: corrupt section bytes do not matter to inspect.
    broken = bytearray(small_file)
    broken[-3] ^= 0xFF
    path = tmp_path / "broken.spc"
    path.write_bytes(bytes(broken))
    assert spcodec.inspect(path).to_json()["layers"] == info["layers"]


@given(st.lists(st.integers(1, 700), min_size=1, max_size=60), st.booleans())
def test_stream_decoder_matches_decode_for_any_chunking(small_scene, sizes, wrap):
    data = build_bitstream(small_scene, WriteOptions(gzip=wrap))
    want = spcodec.decode_layers(data).layers
    dec, got, pos, i = spcodec.StreamDecoder(), [], 0, 0
    while pos < len(data):
        step = sizes[i % len(sizes)]
        got += dec.feed(data[pos:pos + step])
        pos, i = pos + step, i + 1
    dec.close()
    assert [layer.index for layer in got] == [layer.index for layer in want]
    assert all(a.cloud.equals(b.cloud) for a, b in zip(got, want))


def test_stream_decoder_reports_layers_as_soon_as_complete(small_file):
    header = spcodec.decode_layers(small_file).header
    dec = spcodec.StreamDecoder()
    assert dec.feed(small_file[:header.layers[0].end_offset - 1]) == []
    assert [layer.index for layer in dec.feed(small_file[header.layers[0].end_offset - 1:
                                                         header.layers[0].end_offset])] == [0]
    with pytest.raises(TruncatedError):
        dec.feed(small_file[header.layers[0].end_offset:header.layers[1].end_offset - 5])
        dec.close()


def test_stream_decoder_refuses_bad_input_early():
    with pytest.raises(FormatError) as err:
        spcodec.StreamDecoder().feed(b"NOTASPCFILE")
    assert err.value.code == "bad-magic"
    with pytest.raises(TruncatedError):
        spcodec.StreamDecoder().close()


# ------------------------------------------------------------------- header & layout checks
def test_version_rules(small_scene):
    assert error_code(forge(small_scene, version_major=2)) == "unsupported-version"
    later_minor = forge(small_scene, version_minor=7)     # minor versions are readable
    assert len(spcodec.decode(later_minor)) == len(spcodec.decode(forge(small_scene)))


def test_reserved_fields_must_be_zero(small_scene):
    assert error_code(forge(small_scene, flags=1)) == "reserved-nonzero"
    assert error_code(forge(small_scene, reserved=b"\0\0\0\x01\0\0\0")) == "reserved-nonzero"

    def set_reserved(sections):
        sections[1].reserved = 1
    assert error_code(forge(small_scene, set_reserved)) == "reserved-nonzero"


def test_header_consistency(small_scene):
    assert error_code(forge(small_scene, gaussian_count=5)) == "bad-layout"
    assert error_code(forge(small_scene, sh_degree=4)) in {"bad-value", "header-crc"}
    assert error_code(forge(small_scene, file_size=10**6)) == "bad-layout"
    assert error_code(b"\x89SPC\r\n\x1a\nxx") == "truncated"
    assert error_code(b"PK\x03\x04" + b"\0" * 60) == "bad-magic"


def test_unknown_sections(small_scene):
    def add(required, layer):
        def edit(sections):
            at = max(i for i, s in enumerate(sections) if s.layer == layer) + 1
            sections.insert(at, SectionSpec(0x7F00, layer, b"future", Codec.NONE,
                                            required=required))
        return edit
    optional = forge(small_scene, add(False, 1))
    assert spcodec.decode(optional).equals(spcodec.decode(forge(small_scene)))
    required = forge(small_scene, add(True, 2))
    assert error_code(required) == "unknown-required-section"
    assert len(spcodec.decode(required, max_layer=1)) > 0     # earlier layers still decode


def test_unknown_codec_and_section_rules(small_scene):
    def codec9(sections):
        sections[1].codec, sections[1].stored = 9, sections[1].raw
    assert error_code(forge(small_scene, codec9)) == "unknown-codec"

    def duplicate(sections):
        sections.insert(2, SectionSpec(SectionType.SKETCH_CLUSTERS, 0, sections[1].raw))
    assert error_code(forge(small_scene, duplicate)) == "duplicate-section"

    def drop_codebooks(sections):
        return [s for s in sections if s.type != SectionType.PATCH_CODEBOOKS]
    assert error_code(forge(small_scene, drop_codebooks)) == "missing-section"

    def misplace(sections):
        for s in sections:
            if s.type == SectionType.PATCH_CODEBOOKS:
                s.layer = 2
        sections.sort(key=lambda s: s.layer)
    assert error_code(forge(small_scene, misplace)) in {"bad-layout", "missing-section"}

    def optional_flag(sections):
        sections[1].required = False
    assert error_code(forge(small_scene, optional_flag)) == "bad-layout"

    def wrong_raw_length(sections):
        sections[1].raw_length = len(sections[1].raw) + 3
    assert error_code(forge(small_scene, wrong_raw_length)) == "length-mismatch"


def test_layer_table_rules(small_scene):
    def patch_first(layers):
        layers[0].kind = LayerKind.PATCH
    assert error_code(forge(small_scene, layer_edit=patch_first)) == "bad-layout"

    def wrong_end(layers):
        layers[1].end_offset = 123
    assert error_code(forge(small_scene, layer_edit=wrong_end)) == "bad-layout"

    def wrong_count(layers):
        layers[1].gaussian_count += 1
        layers[2].gaussian_count -= 1
    assert error_code(forge(small_scene, layer_edit=wrong_count)) == "bad-section"

    def out_of_order(sections):
        sections[-1].layer, sections[-2].layer = 1, 2
    assert error_code(forge(small_scene, out_of_order)) in {"bad-layout", "missing-section"}


def test_limits_are_enforced_before_allocation(small_file, small_scene):
    for limits in [Limits(max_gaussians=10), Limits(max_layers=2), Limits(max_sections=5),
                   Limits(max_file_bytes=100), Limits(max_section_bytes=64)]:
        with pytest.raises(LimitError):
            spcodec.decode(small_file, limits=limits)
    # A tiny file declaring a huge raw section is refused by the expansion rule.
    def inflate_claim(sections):
        sections[-1].raw_length = 10**9
    with pytest.raises(LimitError):
        spcodec.decode(forge(small_scene, inflate_claim))


def test_empty_and_sketch_only_scenes(small_scene):
    from spcodec.writer import EncodedScene
    empty = build_bitstream(EncodedScene(sh_degree=2))
    cloud = spcodec.decode(empty)
    assert len(cloud) == 0 and cloud.sh_degree == 2
    sketch_only = build_bitstream(EncodedScene(3, small_scene.sketch))
    assert len(spcodec.decode(sketch_only)) == small_scene.sketch_count


def test_draco_count_mismatch_is_caught(small_scene):
    import copy
    scene = copy.deepcopy(small_scene)
    scene.sketch[0].point_count += 1
    scene.sketch[1].point_count -= 1
    assert error_code(build_bitstream(scene)) == "draco-failed"
    scene = copy.deepcopy(small_scene)
    scene.sketch[0].draco = b"DRACO" + b"\x07" * 30
    assert error_code(build_bitstream(scene)) == "draco-failed"


def test_importing_the_decoder_keeps_heavy_packages_out():
    """[R-95]: the decoder must embed without torch, scikit-learn or scipy."""
    code = ("import sys, spcodec, spcodec.decoder; from spcodec import read_ply, decode; "
            "heavy = [m for m in ('torch', 'sklearn', 'scipy') if m in sys.modules]; "
            "print(heavy); sys.exit(1 if heavy else 0)")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0, done.stdout + done.stderr


# ----------------------------------------------------------- findings of the spec review
def test_positions_far_outside_the_cluster_frame_are_refused(small_scene):
    """[R-42]: a tiny frame with a high-degree model would evaluate to inf; it is bad-value."""
    import copy
    scene = copy.deepcopy(small_scene)
    scene.sketch[0].half_extent = np.full(3, 1e-20, np.float32)
    assert error_code(build_bitstream(scene)) == "bad-value"


def test_a_draco_blob_declaring_another_count_is_refused_before_decoding(small_scene):
    """[R-49]: the point count in the blob's header must be the declared one."""
    import copy
    scene = copy.deepcopy(small_scene)
    blob = bytearray(scene.sketch[0].draco)
    blob[11:15] = (50_000_000).to_bytes(4, "little")
    scene.sketch[0].draco = bytes(blob)
    with pytest.raises(FormatError, match="declares 50000000 points") as err:
        spcodec.decode(build_bitstream(scene))
    assert err.value.code == "draco-failed"


def test_declared_counts_are_confirmed_before_output_is_allocated(small_scene):
    """[R-60]: a small file claiming 64 M Gaussians in a patch layer costs no gigabytes."""
    import tracemalloc

    def claim(layers):
        layers[1].gaussian_count = 64_000_000 - sum(layer.gaussian_count for layer in layers[2:]) \
            - layers[0].gaussian_count
    data = forge(small_scene, layer_edit=claim)
    tracemalloc.start()
    with pytest.raises(FormatError):
        spcodec.decode(data)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert peak < 50 * 2**20, f"peak {peak / 2**20:.0f} MiB"


def test_a_short_gzip_layer_table_is_ignored_by_inspect(small_scene):
    """[R-83]: SP offsets that do not describe every layer are treated as absent."""
    import struct
    data = bytearray(build_bitstream(small_scene, WriteOptions(gzip=True)))
    xlen_at = 10
    sub_at = xlen_at + 2
    count_at = sub_at + 4
    assert bytes(data[sub_at:sub_at + 2]) == b"SP"
    struct.pack_into("<H", data, count_at, 1)  # claim one layer (the header CRC is not set here:
    flags = data[3] & ~2                        # drop FHCRC so the edit is not a gzip error)
    data[3] = flags
    del data[count_at + 2 + 8 * 3:count_at + 2 + 8 * 3 + 2]  # remove the 2-byte FHCRC field
    info = spcodec.inspect(bytes(data)).to_json()
    assert [layer["end_offset"] for layer in info["layers"]] == [None] * len(info["layers"])


def test_inspect_applies_the_metadata_limit(small_file):
    info = spcodec.inspect(small_file, limits=Limits(max_metadata_bytes=4))
    assert info.metadata is None and "limit" in info.metadata_error


def test_stream_decoder_agrees_with_decode(small_file):
    header = spcodec.decode_layers(small_file).header
    first_end = header.layers[0].end_offset
    dec = spcodec.StreamDecoder(max_layer=1)
    dec.feed(small_file[:first_end])
    with pytest.raises(TruncatedError):  # layer 1 was asked for and never arrived
        dec.close()
    with pytest.raises(TruncatedError):
        spcodec.decode(small_file[:first_end], max_layer=1)
    for junk in (b"abc", b"x"):
        with pytest.raises(FormatError) as err:
            spcodec.StreamDecoder().feed(junk)
        assert err.value.code == "bad-magic"
        with pytest.raises(FormatError) as err:
            spcodec.decode(junk)
        assert err.value.code == "bad-magic"
    with pytest.raises(UsageError):
        spcodec.StreamDecoder(max_layer=-1)
