"""Section codecs and the gzip wrapper: exact, bounded, and strict about corruption."""

from __future__ import annotations

import gzip
import zlib

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from spcodec.codecs import (
    compress,
    crc32,
    decompress,
    gunzip,
    gzip_wrap,
    read_gzip_layer_ends,
    zstd_available,
)
from spcodec.container import Codec
from spcodec.errors import FormatError, LimitError

CODECS = [Codec.NONE, Codec.ZLIB] + ([Codec.ZSTD] if zstd_available() else [])


@pytest.mark.parametrize("codec", CODECS)
@given(data=st.binary(max_size=3000))
def test_round_trip(codec, data):
    assert decompress(codec, compress(codec, data), len(data)) == data


@given(column=st.integers(1, 400), alphabets=st.lists(st.integers(1, 256), min_size=1, max_size=8),
       seed=st.integers(0, 2**32 - 1))
def test_index_columns_round_trip_and_never_grow(column, alphabets, seed):
    """Per-column deflate blocks are an ordinary zlib stream, never larger than the plain one."""
    rng = np.random.default_rng(seed)
    raw = b"".join(rng.integers(0, k, column, dtype=np.uint8).tobytes() for k in alphabets)
    stored = compress(Codec.ZLIB, raw, column_bytes=column)
    assert zlib.decompress(stored) == raw
    assert decompress(Codec.ZLIB, stored, len(raw)) == raw
    assert len(stored) <= len(compress(Codec.ZLIB, raw))


def test_columns_of_unlike_indices_get_codes_of_their_own():
    """Index columns whose symbol counts differ (a few opacity levels beside a spread of
    rotations) cost less with a Huffman code each than with one code shared by all."""
    rng = np.random.default_rng(7)
    columns = [rng.integers(0, 4, 4000), rng.integers(0, 256, 4000),
               rng.geometric(0.05, 4000).clip(0, 255), rng.integers(100, 132, 4000)]
    raw = b"".join(c.astype(np.uint8).tobytes() for c in columns)
    plain, by_column = compress(Codec.ZLIB, raw), compress(Codec.ZLIB, raw, column_bytes=4000)
    assert len(by_column) < 0.97 * len(plain)
    assert zlib.decompress(by_column) == raw


def test_crc_is_the_zlib_polynomial():
    assert crc32(b"123456789") == 0xCBF43926


@pytest.mark.parametrize("codec", [Codec.ZLIB] + ([Codec.ZSTD] if zstd_available() else []))
def test_inflating_past_the_declared_length_is_refused(codec):
    bomb = compress(codec, b"\0" * 1_000_000)
    with pytest.raises(FormatError) as err:
        decompress(codec, bomb, 1000)
    assert err.value.code == "length-mismatch"


@pytest.mark.parametrize("codec", [Codec.ZLIB] + ([Codec.ZSTD] if zstd_available() else []))
def test_short_and_corrupt_streams_are_refused(codec):
    raw = bytes(range(256)) * 40
    stored = compress(codec, raw)
    for bad, length in [(stored[:-5], len(raw)), (stored, len(raw) + 1),
                        (stored + b"junk", len(raw)), (b"\x00" * 20, len(raw))]:
        with pytest.raises(FormatError) as err:
            decompress(codec, bad, length)
        assert err.value.code in {"decompression-failed", "length-mismatch"}


def test_stored_sections_must_match_their_length():
    with pytest.raises(FormatError) as err:
        decompress(Codec.NONE, b"abc", 4)
    assert err.value.code == "length-mismatch"


def test_unknown_codec():
    with pytest.raises(FormatError) as err:
        decompress(9, b"", 0)
    assert err.value.code == "unknown-codec"


def test_gzip_wrapper_is_standard_gzip_with_layer_offsets():
    inner = b"A" * 1000 + bytes(range(256)) * 8 + b"Z" * 500
    ends = [1000, 3048, len(inner)]
    wrapped = gzip_wrap(inner, ends)
    assert gzip.decompress(wrapped) == inner            # any gzip tool reads it
    offsets = read_gzip_layer_ends(wrapped)
    assert offsets is not None and len(offsets) == 3
    for end, offset in zip(ends, offsets):               # each prefix inflates to the layer end
        out = zlib.decompressobj(wbits=31).decompress(wrapped[:offset])
        assert out == inner[:end]
    full = gunzip(wrapped, 1 << 20)
    assert full.complete and full.inner == inner and full.layer_ends == offsets


def test_gunzip_of_a_prefix_is_a_prefix_and_limits_hold():
    inner = bytes(range(256)) * 400
    wrapped = gzip_wrap(inner, [len(inner)])
    part = gunzip(wrapped[: len(wrapped) // 2], 1 << 20)
    assert not part.complete and inner.startswith(part.inner)
    with pytest.raises(LimitError):
        gunzip(wrapped, 1000)


def test_gunzip_rejects_trailing_members_and_corruption():
    wrapped = gzip_wrap(b"hello" * 100, [500])
    with pytest.raises(FormatError) as err:
        gunzip(wrapped + gzip.compress(b"x"), 1 << 20)
    assert err.value.code == "trailing-data"
    broken = bytearray(wrapped)
    broken[-6] ^= 0xFF  # inside the CRC-32 of the trailer
    with pytest.raises(FormatError) as err:
        gunzip(bytes(broken), 1 << 20)
    assert err.value.code == "bad-gzip"


@pytest.mark.skipif(not zstd_available(), reason="zstandard not installed")
def test_zstd_section_is_exactly_one_frame():
    """[R-22], [R-24]: anything after the frame, or a skippable frame instead of one, is refused.

    Found by fuzzing: the stream reader read past the frame, so a trailing skippable frame was
    accepted and a trailing second frame was reported as length-mismatch.
    """
    import struct

    raw = b"spcodec " * 40
    frame = compress(Codec.ZSTD, raw)
    skippable = struct.pack("<II", 0x184D2A50, 4) + b"abcd"
    for stored, length in [(frame + skippable, len(raw)), (frame + compress(Codec.ZSTD, b""),
                           len(raw)), (frame + b"\0", len(raw)), (skippable, 0),
                           (frame[:-1], len(raw))]:
        with pytest.raises(FormatError) as err:
            decompress(Codec.ZSTD, stored, length)
        assert err.value.code == "decompression-failed"
    assert decompress(Codec.ZSTD, frame, len(raw)) == raw


@pytest.mark.skipif(not zstd_available(), reason="zstandard is not installed")
def test_zstd_sections_are_exactly_one_frame_with_its_size():
    import zstandard
    raw = bytes(range(256)) * 20
    frame = compress(Codec.ZSTD, raw)
    skippable = b"\x50\x2a\x4d\x18" + (4).to_bytes(4, "little") + b"abcd"
    no_size = zstandard.ZstdCompressor(write_content_size=False).compress(raw)
    with_checksum = zstandard.ZstdCompressor(write_checksum=True).compress(raw)
    assert decompress(Codec.ZSTD, with_checksum, len(raw)) == raw
    cases = {
        "second frame": (frame + compress(Codec.ZSTD, b""), "decompression-failed"),
        "skippable frame first": (skippable + frame, "decompression-failed"),
        "skippable frame after": (frame + skippable, "decompression-failed"),
        "truncated": (frame[:-10], "decompression-failed"),
        "checksum missing": (with_checksum[:-4], "decompression-failed"),
        "no content size": (no_size, "decompression-failed"),
        "empty": (b"", "decompression-failed"),
    }
    for name, (stored, code) in cases.items():
        with pytest.raises(FormatError) as err:
            decompress(Codec.ZSTD, stored, len(raw))
        assert err.value.code == code, name
    with pytest.raises(FormatError) as err:
        decompress(Codec.ZSTD, frame, len(raw) - 1)
    assert err.value.code == "length-mismatch"


# ---------------------------------------------------------------- spec 1.1.1: zstd, rule by rule
def _zstd_outcome(frame: bytes, length: int) -> str:
    try:
        decompress(Codec.ZSTD, frame, length)
    except FormatError as exc:
        return exc.code
    return "ok"


@pytest.mark.skipif(not zstd_available(), reason="zstandard is not installed")
def test_zstd_frames_follow_the_rules_of_r22_where_libzstd_and_fzstd_differed():
    """[R-22], spec 1.1.1: each rule on a hand-made frame, next to the same frame made right.
    libzstd accepted a Huffman stream with bits left over (its fast four-stream decoder) and a
    block larger than the block maximum; fzstd accepted the sequence defects."""
    from spcodec.conformance.zstd_bits import (
        NO_SEQUENCES,
        block,
        frame_header,
        huffman_literals,
        raw_literals,
        rle_sequences,
    )

    text = bytes(97 + (i * 7) % 16 for i in range(200))
    sixteen = {97 + i: 1 for i in range(16)}

    def huffman(spare):
        section = huffman_literals(text, sixteen, streams=4, spare_bits=spare)
        return frame_header(200) + block(2, section + NO_SEQUENCES, True), 200

    def one_block(literals, sequences, size):
        return frame_header(size, 10) + block(2, raw_literals(literals) + sequences, True), size

    def after_abcd(sequences):  # no literals: Offset_Value 3 is Repeated_Offset1 - 1, 1 is 4
        return (frame_header(7, 10) + block(0, b"abcd", False)
                + block(2, raw_literals(b"") + sequences, True)), 7

    cases = {  # name: ((frame, length) that must fail, (frame, length) that decodes)
        "Huffman stream with 8 bits left over": (huffman((0, 8)), huffman(())),
        "Huffman stream with 1 bit left over": (huffman((0, 0, 0, 1)), huffman(())),
        "match before the start of the frame": (one_block(b"abcdefgh", rle_sequences(8, 3, 23), 11),
                                                one_block(b"abcdefgh", rle_sequences(8, 3, 11), 11)),
        "literals length past the literals": (one_block(b"abcd", rle_sequences(6, 3, 4), 9),
                                              one_block(b"abcdef", rle_sequences(6, 3, 4), 9)),
        "sequence bits left over": (one_block(b"abcd", rle_sequences(4, 4, 4, spare_bits=3), 8),
                                    one_block(b"abcd", rle_sequences(4, 4, 4), 8)),
        "block over the block maximum": (one_block(b"a", rle_sequences(1, 1049, 4), 1050),
                                          one_block(b"a", rle_sequences(1, 1023, 4), 1024)),
        "repeated offset 1 - 1 = 0": (after_abcd(rle_sequences(0, 3, 3)),
                                      after_abcd(rle_sequences(0, 3, 1))),
    }
    for name, ((bad, bad_length), (good, good_length)) in cases.items():
        assert _zstd_outcome(bad, bad_length) == "decompression-failed", name
        assert _zstd_outcome(good, good_length) == "ok", name


@pytest.mark.skipif(not zstd_available(), reason="zstandard is not installed")
def test_zstd_block_maxima_and_windows():
    """[R-22]: Block_Size of every block type within the block maximum; offsets are not compared
    with the window (a match 2000 bytes back in a frame of window 1 KiB decodes); a frame of
    content size 0 may hold an RLE block of 0 bytes (libzstd's streaming decoder refuses it)."""
    from spcodec.conformance.zstd_bits import block, frame_header, raw_literals, rle_sequences

    first, second = bytes(range(250)) * 4, b"y" * 1000
    far = (frame_header(3000, 10) + block(0, first, False) + block(0, second, False)
           + block(2, raw_literals(b"") + rle_sequences(0, 1000, 2003), True))
    assert decompress(Codec.ZSTD, far, 3000) == first + second + first
    raw_block = frame_header(1025, 10) + block(0, b"r" * 1025, True)
    rle_block = frame_header(1025, 10) + block(1, b"r", True, 1025)
    assert _zstd_outcome(raw_block, 1025) == _zstd_outcome(rle_block, 1025) == \
        "decompression-failed"
    assert decompress(Codec.ZSTD, frame_header(1024, 10) + block(1, b"r", True, 1024), 1024) == \
        b"r" * 1024
    empty = frame_header(0) + block(0, b"", False) + block(1, b"k", True, 0)
    assert decompress(Codec.ZSTD, empty, 0) == b""
    empty_compressed = frame_header(10, 10) + block(0, b"r" * 10, False) + block(2, b"", True)
    assert _zstd_outcome(empty_compressed, 10) == "decompression-failed"


@pytest.mark.skipif(not zstd_available(), reason="zstandard is not installed")
def test_zstd_fse_table_description_may_not_run_past_its_block():
    """[R-22]: libzstd's reader of FSE table descriptions, near the end of its data, goes on
    from the data's last four bytes again, so it can accept a description whose bits run past
    the block. This frame (16 raw literals, one sequence whose literals-length table is such a
    description; found by a search) is one libzstd decodes; the spec refuses it."""
    import zstandard

    frame = bytes.fromhex("28b52ffd800039000000dd0000806162636465666768696a6b6c6d6e6f7001800128"
                          "868b2602953c")
    assert len(zstandard.ZstdDecompressor().decompress(frame)) == 57
    assert _zstd_outcome(frame, 57) == "decompression-failed"


def test_a_code_length_code_without_symbols_fails_only_once_its_lengths_are_read():
    """[R-22], [R-81], spec 1.1.1: a dynamic header whose code length code has no symbol is
    accepted when read, as zlib does; its 258 one-bit code lengths (257 literal/length, 1
    distance) are then read, and the block fails for want of an end-of-block code. A prefix cut
    before the last of them is not an error."""
    inner = bytes(range(200)) * 5
    layer_end = 300
    wrapped = gzip_wrap(inner, [layer_end])
    cut = read_gzip_layer_ends(wrapped)[0]
    header = bytes([0x04, 0x00, 0x00, 0x00])  # BTYPE 2, HLIT/HDIST/HCLEN 0, four 0-lengths, 3 bits
    got = gunzip(wrapped[:cut] + header, 1 << 20)
    assert got.inner == inner[:layer_end] and not got.complete
    # 3 lengths in the header's last byte, 8 per further byte: 31 bytes make 251, 32 make 259
    assert gunzip(wrapped[:cut] + header + b"\xff" * 31, 1 << 20).inner == inner[:layer_end]
    with pytest.raises(FormatError) as err:
        gunzip(wrapped[:cut] + header + b"\xff" * 32, 1 << 20)
    assert err.value.code == "bad-gzip"
