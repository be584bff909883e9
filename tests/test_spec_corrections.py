"""The spec 1.0 corrections of issue 12, one test per decision (spec/CHANGELOG.md lists them).

Each decision is also held by conformance vectors; these tests state it directly on the decoder,
so a change of behaviour names the decision it breaks.
"""

from __future__ import annotations

import struct
import zlib

import numpy as np
import pytest

import spcodec
from spcodec.codecs import crc32, gzip_wrap, read_gzip_layer_ends
from spcodec.container import Codec, PositionMode, SectionType
from spcodec.errors import FormatError
from spcodec.sections import parse_codebooks, parse_positions, parse_sketch
from spcodec.writer import (
    SectionSpec,
    WriteOptions,
    assemble,
    build_bitstream,
    layer_end_offsets,
    scene_sections,
)


def code_of(run) -> str:
    with pytest.raises(FormatError) as err:
        run()
    return err.value.code


def wrapped(small_file: bytes) -> bytes:
    return gzip_wrap(small_file, layer_end_offsets(small_file))


# ----------------------------------------------------------------------------- gzip and K
def test_the_whole_wrapper_is_checked_whatever_max_layer(small_file):
    """[R-82]: K selects layers, it does not make the decoder stop inflating. A wrapper whose
    CRC-32 fails is bad-gzip with max_layer 0, in decode and in the stream decoder fed all of it;
    the lazy decode is the prefix that ends at layer 0's recorded offset."""
    good = wrapped(small_file)
    bad = good[:-8] + struct.pack("<I", crc32(small_file) ^ 1) + good[-4:]
    assert code_of(lambda: spcodec.decode(bad, max_layer=0)) == "bad-gzip"
    stream = spcodec.StreamDecoder(max_layer=0)
    assert code_of(lambda: stream.feed(bad)) == "bad-gzip"
    lazy = bad[:read_gzip_layer_ends(bad)[0]]
    assert spcodec.decode(lazy).equals(spcodec.decode(good, max_layer=0))


def test_trailing_data_is_refused_whatever_max_layer(small_file):
    """Step 6: len(B) > file_size is trailing-data with K given too."""
    assert code_of(lambda: spcodec.decode(small_file + b"\0", max_layer=0)) == "trailing-data"


def test_short_gzip_prefixes_are_truncated(small_file):
    """[R-3], [R-81]: 1F, 1F 8B and every cut inside the gzip header hold no inner byte:
    truncated, in decode and in the stream decoder. A header no continuation can make valid is
    bad-gzip even when cut short."""
    data = wrapped(small_file)
    header_end = 12 + struct.unpack_from("<H", data, 10)[0] + 2   # FEXTRA, then FHCRC
    for cut in range(header_end + 1):
        assert code_of(lambda c=cut: spcodec.decode(data[:c])) == "truncated", cut
        stream = spcodec.StreamDecoder()
        stream.feed(data[:cut])
        assert code_of(stream.close) == "truncated", cut
    assert code_of(lambda: spcodec.decode(b"\x1f\x8b\x07\x00")) == "bad-gzip"   # CM 7
    assert code_of(lambda: spcodec.decode(b"\x1f\x8b\x08\x20")) == "bad-gzip"   # reserved flag


def test_cut_wrappers_decode_as_the_inner_prefix_they_hold(small_file):
    """[R-81]: a cut wrapper decodes exactly as the bytes a streaming inflater produces from it."""
    data = wrapped(small_file)
    for cut in range(0, len(data), 7):
        inner = zlib.decompressobj(wbits=31).decompress(data[:cut])
        try:
            want = ("ok", len(spcodec.decode(inner)))
        except FormatError as exc:
            want = ("error", exc.code)
        try:
            got = ("ok", len(spcodec.decode(data[:cut])))
        except FormatError as exc:
            got = ("error", exc.code)
        assert got == want, cut


def test_recorded_layer_offsets_end_the_flush_marker(small_file):
    """[R-83]: the recorded offset is the end of the empty stored block's 00 00 FF FF; the
    prefixes cut inside the marker inflate to the same inner bytes."""
    data = wrapped(small_file)
    ends = layer_end_offsets(small_file)
    for offset, inner_end in zip(read_gzip_layer_ends(data), ends):
        assert data[offset - 4:offset] == b"\x00\x00\xff\xff"
        for cut in range(offset - 4, offset + 1):
            assert zlib.decompressobj(wbits=31).decompress(data[:cut]) == small_file[:inner_end]


def test_wrapper_bits_that_change_nothing_are_not_errors(small_file):
    """[R-16]: the padding bits before a flush's stored block do not reach the inflated bytes;
    setting them is no error and the file decodes as before."""
    data = bytearray(wrapped(small_file))
    marker = read_gzip_layer_ends(bytes(data))[0] - 4
    data[marker - 1] |= 0xF8   # the stored block's header takes the low 3 bits at most
    assert spcodec.decode(bytes(data)).equals(spcodec.decode(small_file))


# ------------------------------------------------------------------------- one code each
def test_non_finite_draco_points_are_draco_failed():
    """[R-34] vs [R-47]: a blob decoding to non-finite points is draco-failed, not bad-value."""
    import DracoPy

    from spcodec.draco_io import decode_points

    points = np.random.default_rng(2).normal(size=(12, 3)).astype(np.float32)
    blob = bytearray(DracoPy.encode(points, quantization_bits=14, preserve_order=True))
    at = bytes(blob).rfind(np.float32(points[:, 0].min()).tobytes())  # quantization minimum
    blob[at:at + 4] = struct.pack("<f", float("inf"))
    assert not np.isfinite(np.asarray(DracoPy.decode(bytes(blob)).points)).all()
    assert code_of(lambda: decode_points(bytes(blob), 12, "blob")) == "draco-failed"


@pytest.mark.skipif(not __import__("spcodec.codecs").codecs.zstd_available(),
                    reason="zstandard is not installed")
def test_zstd_size_mismatches_by_where_they_are_found():
    """[R-24]: a frame whose declared content size is not raw_length is length-mismatch; one whose
    blocks do not fill its own declared size is corrupt: decompression-failed."""
    import zstandard

    from spcodec.codecs import decompress

    raw = bytes(range(256)) * 8
    frame = bytearray(zstandard.ZstdCompressor(write_content_size=True).compress(raw))
    assert frame[4] >> 6 == 1  # a 2-byte content size field at bytes 5-6 (value - 256)
    assert code_of(lambda: decompress(Codec.ZSTD, bytes(frame), len(raw) + 1)) == "length-mismatch"
    struct.pack_into("<H", frame, 5, len(raw) + 1 - 256)
    assert code_of(lambda: decompress(Codec.ZSTD, bytes(frame), len(raw) + 1)) == \
        "decompression-failed"


# ------------------------------------------------------------- payloads too short for fields
def test_payloads_shorter_than_their_fixed_fields_are_bad_section(small_scene):
    """[R-40], [R-50], [R-53]: every cut of a cluster table below 4 bytes, of a positions payload
    below 4 (28 in mode 1), and of a codebook section anywhere inside it, is bad-section."""
    from spcodec.limits import DEFAULT_LIMITS

    for size in range(4):
        assert code_of(lambda s=size: parse_sketch(b"\1\0\0\0"[:s], 0, 0, 0, 0, DEFAULT_LIMITS)) \
            == "bad-section"
    for mode, fixed in [(0, 4), (1, 28), (2, 4), (3, 4)]:
        payload = bytes([mode]) + bytes(27)
        for size in range(fixed):
            assert code_of(lambda s=size, p=payload: parse_positions(p[:s], 0)) == "bad-section"
    sections, _ = scene_sections(small_scene)
    books = next(s.raw for s in sections if s.type == SectionType.PATCH_CODEBOOKS)
    for size in range(len(books)):
        assert code_of(lambda s=size: parse_codebooks(books[:s], small_scene.sh_degree)) == \
            "bad-section"


def test_draco_data_in_a_layer_of_no_gaussians_is_bad_section():
    """[R-58]: a Draco-mode layer of N = 0 has empty data; anything else is bad-section."""
    assert len(parse_positions(bytes([PositionMode.DRACO, 0, 0, 0]), 0)) == 0
    assert code_of(lambda: parse_positions(bytes([3, 0, 0, 0]) + b"DRACO", 0)) == "bad-section"


# ------------------------------------------------------------------------ limits and values
def test_limits_apply_to_every_table_entry_whatever_its_layer_and_type(small_scene):
    """[R-60]: an optional section of unknown type in the last layer that declares a raw length
    over the limit is refused, with max_layer 0 too."""
    sections, layers = scene_sections(small_scene)
    sections.append(SectionSpec(0x7F00, len(layers) - 1, b"12345678", Codec.NONE, required=False,
                                raw_length=(1 << 31) + 1))
    data = assemble(sections, layers, small_scene.sh_degree)
    for k in (None, 0):
        assert code_of(lambda m=k: spcodec.decode(data, max_layer=m)) == "limit-exceeded"


def test_a_negative_zero_step_is_not_negative():
    """[R-55]: -0.0 compares equal to zero, so it is a legal step; every Gaussian sits at the
    origin on that axis. The smallest negative step is bad-value."""
    def payload(step_y: float) -> bytes:
        q = np.array([[0, 0, 0], [4, 9, 2], [65535, 65535, 65535]], "<u2")  # zigzag codes
        return bytes([1, 0, 0, 0]) + struct.pack("<6f", 1.0, -2.5, 0.0, 0.5, step_y, 0.25) + \
            np.ascontiguousarray(q.T).tobytes()
    positions = parse_positions(payload(-0.0), 3).decode()
    assert (positions[:, 1] == np.float32(-2.5)).all()
    assert code_of(lambda: parse_positions(payload(-1e-45), 3)) == "bad-value"


def test_bytes_after_a_draco_stream_are_ignored_by_the_reference_decoder(small_scene):
    """ID-3 of section 1.1: a decoder MAY ignore bytes after a blob's Draco stream (writers must
    not leave them). The reference decoder does, and decodes the same Gaussians."""
    import copy

    scene = copy.deepcopy(small_scene)
    scene.sketch[0].draco += b"trailing bytes"
    assert spcodec.decode(build_bitstream(scene)).equals(spcodec.decode(build_bitstream(small_scene)))


def test_a_gzip_wrapped_file_cut_inside_its_trailer_decodes(small_scene):
    """[R-81] (not implementation-defined): the cut holds the whole inner file."""
    data = build_bitstream(small_scene, WriteOptions(gzip=True))
    for cut in range(1, 8):
        assert spcodec.decode(data[:-cut]).equals(spcodec.decode(data))
