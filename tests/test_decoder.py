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


# ------------------------------------------------------------------ findings of the fuzzer
def test_claimed_gaussian_counts_are_not_allocated_before_validation(small_scene):
    """[R-60], [R-62]: output memory is sized by validated payloads, not by the layer table.

    Found by fuzzing: a few-KB file whose layer table claimed 60 million Gaussians made the
    decoder allocate ~14 GB of output before the cluster table refused the count.
    """
    import tracemalloc

    def claim_sketch(layers):
        layers[0].gaussian_count = 60_000_000

    def claim_patch(layers):
        layers[2].gaussian_count = 60_000_000

    lenient = Limits(max_gaussians_per_byte=1e12)  # let the claim through to the payload checks
    for edit in (claim_sketch, claim_patch):
        data = forge(small_scene, layer_edit=edit)
        assert error_code(data) == "limit-exceeded"  # the default density limit ([R-61])
        tracemalloc.start()
        try:
            with pytest.raises(FormatError) as err:
                spcodec.decode(data, limits=lenient)
            assert err.value.code == "bad-section"
            peak = tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()
        assert peak < 16 * 2**20, f"{peak / 2**20:.0f} MiB traced for a {len(data)}-byte file"


def test_sketch_models_that_overflow_are_refused(small_scene):
    """[R-34]: finite coefficients at huge normalized positions must not give inf or NaN.

    Found by fuzzing: a half extent of 1e-40 made the degree-d monomials overflow, and the
    decoder returned infinite scales (with numpy overflow warnings).
    """
    import copy
    import warnings

    scene = copy.deepcopy(small_scene)
    scene.sketch[0].half_extent = np.array([1e-40, 1e-40, 1e-40], np.float32)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert error_code(build_bitstream(scene)) == "bad-value"


def test_huge_finite_rotation_models_decode_to_unit_quaternions(small_scene):
    """[R-31]: q / |q| is a unit quaternion even when |q|^2 overflows binary64.

    The naive norm overflowed to inf and gave the zero quaternion for a rotation model evaluating
    to ~1e158. Since [R-42] bounds normalized coordinates, a file can no longer reach such values
    (it is refused first); the mapping itself stays robust.
    """
    import copy

    from spcodec.attributes import SketchAttribute, decode_rotation
    from spcodec.polynomial import monomial_count

    assert np.allclose(decode_rotation(np.array([[1e200, 1e200, 0.0, 0.0]])),
                       [[2**-0.5, 2**-0.5, 0.0, 0.0]])
    scene = copy.deepcopy(small_scene)
    cluster = scene.sketch[0]
    cluster.half_extent = np.full(3, 1e-16, np.float32)
    rotation = np.zeros((monomial_count(10), 4), np.float16)
    rotation[0, 0] = 1.0
    rotation[monomial_count(9), :2] = 65504.0   # x^10 drives w and x
    cluster.models = {SketchAttribute.SCALE: np.zeros((1, 3), np.float16),
                      SketchAttribute.ROTATION: rotation,
                      SketchAttribute.OPACITY: np.full((1, 1), 0.5, np.float16),
                      SketchAttribute.COLOR_DC: np.zeros((1, 3), np.float16)}
    assert error_code(build_bitstream(scene)) == "bad-value"


@pytest.mark.parametrize("payload", [b"[" * 100_000, b'{"a":' * 50_000 + b"1" + b"}" * 50_000,
                                     b'{"n": NaN}', b'{"i": -Infinity}'])
def test_hostile_metadata_is_reported_as_bad_metadata(small_scene, payload):
    """[R-70]: inspect reports unparsable metadata, it does not crash on it.

    Found by fuzzing: deeply nested JSON raised RecursionError out of inspect(). NaN and
    Infinity are Python extensions that are not JSON, and would make `info --json` invalid.
    """
    def hostile(sections):
        sections[0].raw = payload
    data = forge(small_scene, hostile)
    info = spcodec.inspect(data)
    assert info.metadata is None and "bad-metadata" in info.metadata_error
    assert len(spcodec.decode(data)) == len(spcodec.decode(forge(small_scene)))


def test_inspect_applies_the_metadata_limit(small_file):
    """[R-60]: the metadata limit holds for inspect as it does for decode."""
    info = spcodec.inspect(small_file, limits=Limits(max_metadata_bytes=4))
    assert info.metadata is None and "limit-exceeded" in info.metadata_error


def test_gzip_layer_offsets_that_do_not_fit_the_file_are_ignored(small_file):
    """[R-83]: the SP subfield is advisory; one with the wrong count no longer breaks to_json.

    Found by fuzzing: a wrapper whose SP list was shorter than the layer table made
    ``inspect(...).to_json()`` raise IndexError.
    """
    import struct

    from spcodec.codecs import crc32, gzip_wrap
    from spcodec.writer import layer_end_offsets

    ends = layer_end_offsets(small_file)
    wrapped = bytearray(gzip_wrap(small_file, ends))
    recorded = list(struct.unpack_from(f"<{len(ends)}Q", wrapped, 18))  # after XLEN, id, size, count
    struct.pack_into(f"<{len(ends)}Q", wrapped, 18, *recorded[::-1])   # not increasing
    header_end = 12 + struct.unpack_from("<H", wrapped, 10)[0]
    struct.pack_into("<H", wrapped, header_end, crc32(bytes(wrapped[:header_end])) & 0xFFFF)
    for data in (gzip_wrap(small_file, ends[:1]), bytes(wrapped)):    # too short; decreasing
        info = spcodec.inspect(data)
        assert info.gzip_layer_ends is None
        assert [layer["end_offset"] for layer in info.to_json()["layers"]] == [None] * len(ends)
        assert len(spcodec.decode(data)) == len(spcodec.decode(small_file))
    good = spcodec.inspect(gzip_wrap(small_file, ends))
    assert good.gzip_layer_ends == recorded


def test_gzip_wrapper_inflates_no_further_than_the_inner_file_size(small_file):
    """[R-84], [R-61]: a few KB of gzip must not inflate to hundreds of MB before a check.

    The wrapper was inflated up to max_file_bytes (4 GiB) before the inner header was read, so
    a gzip bomb (garbage, or a valid file followed by zeros) cost its whole inflated size,
    twice. Now the inner header block is read first and its file_size caps the inflation.
    """
    import gzip
    import tracemalloc

    zeros = b"\0" * (32 << 20)
    bombs = {"trailing-data": gzip.compress(small_file + zeros, 9),
             "bad-magic": gzip.compress(zeros, 9)}
    for code, bomb in bombs.items():
        assert len(bomb) < 64 * 1024
        for run in (lambda b=bomb: spcodec.decode(b),
                    lambda b=bomb: spcodec.StreamDecoder().feed(b),
                    lambda b=bomb: spcodec.inspect(b)):
            tracemalloc.start()
            try:
                with pytest.raises(FormatError) as err:
                    run()
                peak = tracemalloc.get_traced_memory()[1]
            finally:
                tracemalloc.stop()
            assert err.value.code == code
            assert peak < 8 * 2**20, f"{peak / 2**20:.0f} MiB traced for a {len(bomb)}-byte bomb"


def test_file_objects_are_read_in_bounded_chunks(small_file):
    """A buffered file's read(n) allocates n bytes up front: one read(max_file_bytes + 1) cost
    4 GiB of address space (MemoryError under a limit) for any file, however small."""
    class Greedy(io.BytesIO):
        def read(self, size=-1):
            assert 0 <= size <= 1 << 24, f"read({size})"
            return super().read(size)

    assert spcodec.decode(Greedy(small_file)).equals(spcodec.decode(small_file))
    with pytest.raises(LimitError):
        spcodec.decode(Greedy(small_file), limits=Limits(max_file_bytes=len(small_file) - 1))


def test_errors_are_reported_in_the_order_of_the_decoding_process(small_scene):
    """Section 12: "the first failing check in the order of section 11". Step 7 verifies the
    CRC of every section of every decoded layer (and inflates them) before steps 8-9 parse any.

    Each file below has two faults; the decoder used to report the later one: it inflated and
    parsed each section (even ran Draco on a layer's positions) before checking the CRC of the
    next section.
    """
    def bad_crc(index):
        def edit(sections):
            sections[index].crc = 0xDEADBEEF
        return edit

    def corrupt_zlib(index):
        def edit(sections):
            sections[index].codec, sections[index].stored = Codec.ZLIB, b"\x78\x9c\xff\xff\xff"
        return edit

    def garbage_positions(sections):
        sec = next(s for s in sections if s.type == SectionType.PATCH_POSITIONS)
        sec.raw = bytes([3, 0, 0, 0]) + b"DRACO" + bytes(30)

    def long_cluster_table(sections):
        sections[1].raw += b"\0"

    def both(*edits):
        def edit(sections):
            for e in edits:
                e(sections)
        return edit

    # metadata, clusters, positions, coefficients | codebooks, positions, attributes | ...
    assert error_code(forge(small_scene, both(corrupt_zlib(1), bad_crc(3)))) == "section-crc"
    assert error_code(forge(small_scene, both(garbage_positions, bad_crc(6)))) == "section-crc"
    assert error_code(forge(small_scene, both(long_cluster_table, bad_crc(8)))) == "section-crc"
    # Step 7 runs layer by layer: a layer-0 inflation failure precedes a layer-2 CRC mismatch.
    assert error_code(forge(small_scene, both(corrupt_zlib(1), bad_crc(8)))) == \
        "decompression-failed"
    # With only the first fault, its own code is reported.
    assert error_code(forge(small_scene, long_cluster_table)) == "bad-section"
    assert error_code(forge(small_scene, corrupt_zlib(1))) == "decompression-failed"
    assert error_code(forge(small_scene, garbage_positions)) == "draco-failed"


def _one_point_clusters(count: int) -> bytes:
    """A file of ``count`` one-point sketch clusters sharing one Draco blob: identical records
    and identical points compress to almost nothing, so the file is tiny."""
    import DracoPy

    from spcodec.container import CLUSTER_DTYPE
    from spcodec.writer import LayerSpec

    blob = DracoPy.encode(np.zeros((count, 3), np.float32), quantization_bits=1,
                          compression_level=10, preserve_order=True)
    records = np.zeros(count, CLUSTER_DTYPE)
    records["point_count"] = 1
    records["draco_length"][0] = len(blob)
    records["half_extent"] = 1.0
    records["degrees"] = [1, 1, 1, 1, 255]                   # linear models, no SH rest
    coefficients = np.full(4 * (3 + 4 + 1 + 3) * count, 0.25, "<f2").tobytes()
    table = count.to_bytes(4, "little") + records.tobytes()
    sections = [SectionSpec(SectionType.SKETCH_CLUSTERS, 0, table, Codec.ZSTD),
                SectionSpec(SectionType.SKETCH_POSITIONS, 0, blob, Codec.NONE),
                SectionSpec(SectionType.SKETCH_COEFFICIENTS, 0, coefficients, Codec.ZSTD)]
    return assemble(sections, [LayerSpec(LayerKind.SKETCH, count)], sh_degree=0)


def test_many_tiny_clusters_decode_in_time_proportional_to_their_points():
    """[R-1] (no hang): the sketch decoder looped over clusters at ~50 us each, so a file of a
    few KB holding 200 000 one-point clusters took over 10 s; the limits admit 4 million."""
    import time

    data = _one_point_clusters(200_000)
    assert len(data) < 8192
    start = time.perf_counter()
    cloud = spcodec.decode(data)
    elapsed = time.perf_counter() - start
    assert len(cloud) == 200_000 and cloud.is_finite()
    assert elapsed < 3.0, f"{elapsed:.1f} s for {len(data)} bytes"


def test_sketch_decoding_is_bit_exact_with_the_per_cluster_evaluation(small_scene):
    """Small clusters are evaluated together, yet every Gaussian is bit-for-bit what
    evaluate_models + fill_cluster give for its cluster alone (what the encoder predicts)."""
    from spcodec.attributes import SketchAttribute
    from spcodec.cloud import GaussianCloud
    from spcodec.decoder.layers import SMALL_CLUSTER, evaluate_models, fill_cluster
    from spcodec.polynomial import normalize_positions
    from spcodec.synthetic import random_encoded_scene

    scene = random_encoded_scene(seed=3, clusters=40, patch_layers=0, sh_degree=3)
    sizes = [c.point_count for c in scene.sketch]
    assert min(sizes) < SMALL_CLUSTER <= max(sizes)
    cloud = spcodec.decode(build_bitstream(scene))
    start = 0
    for cluster in scene.sketch:
        rows = slice(start, start + cluster.point_count)
        start += cluster.point_count
        x = normalize_positions(cloud.means[rows], cluster.center, cluster.half_extent)
        values = evaluate_models(x, {a: cluster.models.get(a) for a in SketchAttribute})
        alone = GaussianCloud.zeros(cluster.point_count, scene.sh_degree)
        fill_cluster(alone, slice(None), values, scene.sh_degree)
        for name, array in alone.arrays().items():
            if name != "means":
                assert getattr(cloud, name)[rows].tobytes() == array.tobytes(), name


# ----------------------------------------------------------- findings of the spec review
def test_positions_far_outside_the_cluster_frame_are_refused(small_scene):
    """[R-42]: a tiny frame with a high-degree model would evaluate to inf; it is bad-value."""
    import copy
    scene = copy.deepcopy(small_scene)
    scene.sketch[0].half_extent = np.full(3, 1e-20, np.float32)
    assert error_code(build_bitstream(scene)) == "bad-value"


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


def test_normalized_coordinates_beyond_two_are_refused_even_without_overflow(small_scene):
    """[R-42]: |x| <= 2 is a rule of its own, not only a guard against overflow."""
    import copy
    scene = copy.deepcopy(small_scene)
    cluster = scene.sketch[0]
    cluster.half_extent = (cluster.half_extent / 2.5).astype(np.float32)  # points now reach ~2.5
    assert error_code(build_bitstream(scene)) == "bad-value"
    cluster.half_extent = (cluster.half_extent * 2.5 / 1.9).astype(np.float32)  # within 2: valid
    assert len(spcodec.decode(build_bitstream(scene))) == len(spcodec.decode(build_bitstream(
        small_scene)))


def test_a_small_file_cannot_declare_millions_of_gaussians():
    """[R-61]: more than 1 M Gaussians need at least one byte per 64 Gaussians of file."""
    from spcodec.limits import Limits
    limits = Limits()
    limits.check_gaussian_density(1_000_000, 10)          # the floor admits small files
    limits.check_gaussian_density(64 * 200_000, 200_000)  # 64 per byte
    with pytest.raises(LimitError):
        limits.check_gaussian_density(64 * 200_000 + 1, 200_000)
