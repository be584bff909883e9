"""Vectors of spec 1.0.1: what valid zlib, zstd and deflate data are, how much of a cut gzip member
is checked, and layers that share an end offset.

Each of these is a place where two decoders written from the 1.0 text could disagree; the spec now
says one thing, and the vector shows which. Deflate bits that no compressor writes (a cut block
header, an incomplete code) are made by :mod:`.deflate_bits`.
"""

from __future__ import annotations

import struct
import zlib

from spcodec.codecs import crc32, read_gzip_layer_ends
from spcodec.container import Codec
from spcodec.writer import layer_end_offsets

from .declare import invalid, valid
from .deflate_bits import DYNAMIC, FIXED, RESERVED, STORED, BitWriter, dynamic_header, fixed_code
from .forge import Draft
from .invalid_cases import (  # the base file and its helpers, shared with the 1.0 vectors
    ATTR2,
    COEFFS,
    META,
    POS2,
    _coefficients,
    _stored,
    _wrapped,
    _zstd,
    base,
    base_bytes,
)

# ------------------------------------------------------------------------------------ zlib
_FAR = bytes(range(256)) + bytes(range(255, -1, -1))
"""512 bytes that zlib codes with matches reaching 512 back, past a 256-byte window."""


def _with_metadata_stream(stored: bytes, raw_length: int) -> bytes:
    """The base file with its metadata section storing ``stored`` as zlib data."""
    return _stored(META, stored, raw_length=raw_length)


def _zlib_header(stream: bytes, cinfo: int) -> bytes:
    """``stream`` with its window field set to ``cinfo`` and FCHECK made right again."""
    cmf = (cinfo << 4) | 8
    flg = stream[1] & 0xE0
    flg |= 31 - ((cmf << 8 | flg) % 31) if (cmf << 8 | flg) % 31 else 0
    return bytes([cmf, flg]) + stream[2:]


@valid("zlib-window-smaller-than-distances",
       "Metadata whose zlib header declares a 256-byte window (CINFO 0) while its matches reach "
       "512 bytes back: the window field is not checked against distances",
       ["R-22", "R-70"], max_layers=(0,))
def zlib_small_window() -> bytes:
    raw = _FAR * 3
    stream = zlib.compress(raw, 9)
    if zlib.decompress(stream) != raw:
        raise AssertionError("zlib round trip failed")
    return _with_metadata_stream(_zlib_header(stream, 0), len(raw))


@invalid("zlib-window-over-32k", "Metadata whose zlib header declares a 64 KiB window (CINFO 8)",
         "decompression-failed", ["R-22", "R-70"])
def zlib_big_window() -> bytes:
    raw = b'{"generator": "spcodec conformance"}'
    return _with_metadata_stream(_zlib_header(zlib.compress(raw, 9), 8), len(raw))


@invalid("zlib-header-check-wrong", "Metadata whose zlib header fails its FCHECK (CMF*256+FLG "
         "not a multiple of 31)", "decompression-failed", ["R-22", "R-70"])
def zlib_fcheck() -> bytes:
    raw = b'{"generator": "spcodec conformance"}'
    stream = zlib.compress(raw, 9)
    return _with_metadata_stream(stream[:1] + bytes([stream[1] ^ 1]) + stream[2:], len(raw))


@invalid("zlib-adler32-wrong", "Metadata whose zlib Adler-32 is off by one (the section CRC "
         "matches)", "decompression-failed", ["R-22", "R-70"])
def zlib_adler() -> bytes:
    raw = b'{"generator": "spcodec conformance"}'
    stream = zlib.compress(raw, 9)
    adler = (struct.unpack(">I", stream[-4:])[0] + 1) & 0xFFFFFFFF
    return _with_metadata_stream(stream[:-4] + struct.pack(">I", adler), len(raw))


@invalid("zlib-incomplete-code", "Metadata whose zlib data has a dynamic block with an incomplete "
         "literal/length code of two codes (lengths 1 and 2)", "decompression-failed",
         ["R-22", "R-70"])
def zlib_incomplete_code() -> bytes:
    bits = BitWriter().block_header(True, DYNAMIC)
    table = dynamic_header(bits, {0: 2, 1: 2, 2: 2, 18: 2}, literal_count=257, distance_count=1)
    # literal/length lengths: symbol 0 -> 1, 1..255 -> 0, 256 -> 2; the one distance length 0
    bits.code(*table[1])
    for run in (138, 117):
        bits.code(*table[18]).put(run - 11, 7)
    bits.code(*table[2]).code(*table[0])
    bits.code(0b0, 1).code(0b10, 2)  # the literal 0, then end of block (as if the code were valid)
    stream = b"\x78\xda" + bits.bytes() + struct.pack(">I", zlib.adler32(b"\0"))
    return _with_metadata_stream(stream, 1)


# ------------------------------------------------------------------------------------ zstd
def _with_coefficients_frame(edit) -> bytes:
    """The base file with its coefficients in a zstd frame changed by ``edit``."""
    return _stored(COEFFS, edit(_zstd(_coefficients())), Codec.ZSTD)


def _with_dictionary_id(frame: bytes) -> bytes:
    """``frame`` with a one-byte Dictionary_ID of 7 in its header (its blocks need none)."""
    descriptor = frame[4]
    if descriptor & 0x03 or not descriptor & 0x20:
        raise AssertionError(f"unexpected zstd frame descriptor {descriptor:#x}")
    return frame[:4] + bytes([descriptor | 0x01, 7]) + frame[5:]


@invalid("zstd-dictionary-id", "Coefficients in a zstd frame that names dictionary 7 (its blocks "
         "do not use it): a frame needing a dictionary is not valid", "decompression-failed",
         ["R-22"])
def zstd_dictionary() -> bytes:
    return _with_coefficients_frame(_with_dictionary_id)


@invalid("zstd-legacy-frame", "Coefficients in a frame with the magic of zstd 0.7 (a legacy "
         "format): only RFC 8878 frames are valid", "decompression-failed", ["R-22"])
def zstd_legacy() -> bytes:
    return _with_coefficients_frame(lambda frame: struct.pack("<I", 0xFD2FB527) + frame[4:])


# ------------------------------------------------------------------------- cut gzip members
def _after_layer_1(tail: bytes) -> bytes:
    """The wrapped base file cut at layer 1's recorded offset, then ``tail`` (the start of a
    deflate block of the writer's choosing: the flush left the stream at a byte boundary)."""
    wrapped = _wrapped()
    return wrapped[:read_gzip_layer_ends(wrapped)[1]] + tail


@invalid("gzip-cut-after-wrong-crc", "A gzip-wrapped file cut after the 4 bytes of a wrong CRC-32, "
         "before ISIZE: a CRC present is checked; also with --max-layer 0", "bad-gzip",
         ["R-81", "R-82"], max_layers=(0,))
def gzip_cut_wrong_crc() -> bytes:
    return _wrapped()[:-8] + struct.pack("<I", (crc32(base_bytes()) + 1) & 0xFFFFFFFF)


@valid("gzip-cut-after-crc", "A gzip-wrapped file cut after its right CRC-32, before ISIZE: the "
       "whole inner file", ["R-81", "R-82"])
def gzip_cut_right_crc() -> bytes:
    return _wrapped()[:-4]


@invalid("gzip-cut-after-reserved-block-type", "A gzip-wrapped file cut after layer 1's flush and "
         "the 3 bits of a block of reserved type 3: bits present are checked; also with "
         "--max-layer 1", "bad-gzip", ["R-81", "R-82"], max_layers=(1,))
def gzip_cut_reserved_block() -> bytes:
    return _after_layer_1(BitWriter().block_header(False, RESERVED).bytes())


@valid("gzip-cut-in-stored-lengths", "A gzip-wrapped file cut after layer 1's flush, a stored "
       "block's LEN and one byte of an NLEN that does not match it: a field cut short is not "
       "checked, layers 0 and 1", ["R-81", "R-11"])
def gzip_cut_stored_lengths() -> bytes:
    head = BitWriter().block_header(False, STORED).align().bytes()
    return _after_layer_1(head + struct.pack("<H", 5) + b"\x00")


@valid("gzip-cut-in-dynamic-header", "A gzip-wrapped file cut after layer 1's flush inside a "
       "dynamic block header (counts and five code-length-code lengths): layers 0 and 1",
       ["R-81", "R-11"])
def gzip_cut_dynamic_header() -> bytes:
    bits = BitWriter().block_header(False, DYNAMIC).put(0, 5).put(0, 5).put(15, 4)
    for length in (3, 3, 3, 3, 3):
        bits.put(length, 3)
    return _after_layer_1(bits.bytes())


@invalid("gzip-cut-after-too-many-codes", "A gzip-wrapped file cut after layer 1's flush and a "
         "dynamic header whose counts claim 287 literal/length codes; also with --max-layer 1",
         "bad-gzip", ["R-81", "R-82"], max_layers=(1,))
def gzip_cut_too_many_codes() -> bytes:
    return _after_layer_1(BitWriter().block_header(False, DYNAMIC).put(30, 5).put(0, 5)
                          .put(0, 4).bytes())


@invalid("gzip-cut-after-bad-repeat", "A gzip-wrapped file cut after layer 1's flush and a dynamic "
         "header whose first code length is a repeat (symbol 16 with its 2 extra bits): a complete "
         "symbol is checked; also with --max-layer 1", "bad-gzip", ["R-81", "R-82"],
         max_layers=(1,))
def gzip_cut_bad_repeat() -> bytes:
    bits = BitWriter().block_header(False, DYNAMIC)
    table = dynamic_header(bits, {16: 1, 0: 1}, literal_count=257, distance_count=1)
    bits.code(*table[16]).put(0, 2)
    if len(bits.bits) != 32:
        raise AssertionError(f"{len(bits.bits)} bits, meant to end at a byte boundary")
    return _after_layer_1(bits.bytes())


@invalid("gzip-cut-inside-code", "A gzip-wrapped file cut after layer 1's flush, six literals of a "
         "fixed block and 7 of the 8 bits of code 286: a code cut short is not checked, so the "
         "inner prefix ends 6 bytes into layer 2; layers 0 and 1 decode with --max-layer 1",
         "truncated", ["R-81", "R-12"], max_layers=(1,))
def gzip_cut_inside_code() -> bytes:
    bits = BitWriter().block_header(False, FIXED)
    for _ in range(6):
        bits.code(*fixed_code(200))
    code, length = fixed_code(286)
    bits.code(code >> 1, length - 1)
    if len(bits.bits) % 8:
        raise AssertionError("the cut code must end the last byte")
    return _after_layer_1(bits.bytes())


# ---------------------------------------------------------------------------- layer table
@invalid("layer-end-offsets-equal", "A file cut where layer 1 ends, whose layer 2 is two empty "
         "sections, so layers 1 and 2 share that end_offset: end offsets must increase",
         "bad-layout", ["R-9"], max_layers=(1,))
def layer_ends_equal() -> bytes:
    draft: Draft = base()
    for index in (POS2, ATTR2):
        section = draft.sections[index]
        section.codec, section.stored, section.raw_length = Codec.NONE, b"", 0
    data = draft.build()
    end = layer_end_offsets(data)[1]
    if layer_end_offsets(data)[2] != end:
        raise AssertionError("layer 2 was meant to be empty")
    return data[:end]

