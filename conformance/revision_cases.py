"""Vectors of spec 1.1.1: places where the Python and JavaScript decoders gave different outcomes
(a differential fuzz of the two), each now decided by the text.

* A gzip member cut after a dynamic block header whose code length code has no symbol: zlib
  accepts that code when it reads it and fails the block only once all its code lengths are read
  (for want of an end-of-block code), so a prefix cut before then is not yet an error ([R-22],
  [R-81]).
* zstd frames that libzstd and fzstd judge differently: a Huffman literal stream with bits no
  literal reads (libzstd's fast four-stream decoder accepts it), a match reaching before the start
  of the frame, a literals length past the block's literals and a sequence bitstream with bits no
  sequence reads (fzstd accepts them), a block that decodes to more than the block maximum
  (libzstd accepts it where its buffers allow), and a match reaching back further than the
  frame's window, which is valid ([R-22]). The frames are made by :mod:`.zstd_bits`.
"""

from __future__ import annotations

from spcodec.container import Codec

from .declare import invalid, valid
from .deflate_bits import DYNAMIC, BitWriter
from .invalid_cases import META, _stored
from .stream_cases import _after_layer_1
from .zstd_bits import (
    NO_SEQUENCES,
    block,
    frame_header,
    huffman_literals,
    raw_literals,
    rle_sequences,
)


# ------------------------------------------------------------------------ cut gzip members
def _empty_code_length_code() -> BitWriter:
    """A dynamic block header (not final) of 257 literal/length and 1 distance code lengths
    whose code length code has no symbol: HCLEN + 4 = 4 lengths, all 0."""
    bits = BitWriter().block_header(False, DYNAMIC).put(0, 5).put(0, 5).put(0, 4)
    for _ in range(4):
        bits.put(0, 3)
    return bits


@valid("gzip-cut-after-empty-code-length-code", "A gzip-wrapped file cut after layer 1's flush, "
       "a dynamic header whose code length code has no symbol, and 3 more bits: zlib accepts such "
       "a code when it reads it, so the cut block is not yet an error; layers 0 and 1",
       ["R-22", "R-81", "R-11"])
def gzip_cut_empty_code_length_code() -> bytes:
    bits = _empty_code_length_code().put(0, 3)
    if bits.bytes() != b"\x04\x00\x00\x00":
        raise AssertionError(f"meant to be the bytes 04 00 00 00, got {bits.bytes().hex()}")
    return _after_layer_1(bits.bytes())


@invalid("gzip-empty-code-length-code-read-out", "A gzip-wrapped file cut after layer 1's flush, "
         "a dynamic header whose code length code has no symbol, and the 258 one-bit code lengths "
         "that code reads (all 0): the block has no end-of-block code; also with --max-layer 1",
         "bad-gzip", ["R-22", "R-81", "R-82"], max_layers=(1,))
def gzip_empty_code_length_code_read_out() -> bytes:
    bits = _empty_code_length_code()
    for i in range(257 + 1):
        bits.put(i & 1, 1)  # either value of each bit means length 0
    return _after_layer_1(bits.bytes())


# ------------------------------------------------------------------------------ zstd frames
def _with_metadata_frame(frame: bytes, raw_length: int) -> bytes:
    """The base file with its metadata section storing ``frame`` as zstd data."""
    return _stored(META, frame, Codec.ZSTD, raw_length=raw_length)


_WINDOW_LOG = 10
"""The smallest window (1 KiB): frames that are not single-segment, so the small blocks here do
not pass their block maximum (a single-segment frame's window is its content size)."""

_TEXT = bytes(97 + (i * 7) % 16 for i in range(200))
"""200 literals over 16 symbols ('a' to 'p'), each coded in 4 bits."""

_SIXTEEN = {97 + i: 1 for i in range(16)}


@invalid("zstd-literal-stream-bits-left", "Metadata in a zstd frame whose literals are Huffman "
         "coded in four streams, the second with 8 bits that no literal reads (libzstd's fast "
         "decoder does not check where a stream ends): every stream is read exactly",
         "decompression-failed", ["R-22", "R-70"])
def zstd_literal_stream_bits_left() -> bytes:
    literals = huffman_literals(_TEXT, _SIXTEEN, streams=4, spare_bits=(0, 8))
    frame = frame_header(len(_TEXT)) + block(2, literals + NO_SEQUENCES, True)
    return _with_metadata_frame(frame, len(_TEXT))


@invalid("zstd-match-before-frame-start", "Metadata in a zstd frame whose one sequence copies 3 "
         "bytes from 20 bytes back after 8 literals (fzstd copies zeros): a match may not reach "
         "before the start of the frame", "decompression-failed", ["R-22", "R-70"])
def zstd_match_before_frame_start() -> bytes:
    section = raw_literals(b"abcdefgh") + rle_sequences(8, 3, 20 + 3)
    return _with_metadata_frame(frame_header(11, _WINDOW_LOG) + block(2, section, True), 11)


@invalid("zstd-literals-length-past-literals", "Metadata in a zstd frame whose one sequence takes "
         "6 literals from a block of 4 (fzstd reads past them): a sequence may not read past the "
         "literals", "decompression-failed", ["R-22", "R-70"])
def zstd_literals_length_past_literals() -> bytes:
    section = raw_literals(b"abcd") + rle_sequences(6, 3, 1 + 3)
    return _with_metadata_frame(frame_header(9, _WINDOW_LOG) + block(2, section, True), 9)


@invalid("zstd-sequence-bits-left", "Metadata in a zstd frame whose sequence bitstream has 3 bits "
         "that no sequence reads (fzstd does not check): the bitstream is read exactly",
         "decompression-failed", ["R-22", "R-70"])
def zstd_sequence_bits_left() -> bytes:
    section = raw_literals(b"abcd") + rle_sequences(4, 4, 1 + 3, spare_bits=3)
    return _with_metadata_frame(frame_header(8, _WINDOW_LOG) + block(2, section, True), 8)


@invalid("zstd-block-over-maximum", "Metadata in a zstd frame of window 1 KiB whose one block "
         "decodes to 1050 bytes (libzstd decodes it where its buffers have room): no block decodes "
         "to more than Block_Maximum_Size", "decompression-failed", ["R-22", "R-70"])
def zstd_block_over_maximum() -> bytes:
    section = raw_literals(b"a") + rle_sequences(1, 1049, 1 + 3)
    return _with_metadata_frame(frame_header(1050, _WINDOW_LOG) + block(2, section, True), 1050)


@valid("zstd-match-beyond-window", "Metadata (a JSON object) in a zstd frame of window 1 KiB "
       "whose last block copies 994 bytes from 1994 bytes back: the window is not compared with "
       "offsets, as in zlib", ["R-22", "R-70"], max_layers=(0,))
def zstd_match_beyond_window() -> bytes:
    head = b'{"k": "' + b"x" * 993
    middle = b"y" * 1000
    section = raw_literals(b'"}') + rle_sequences(0, 993, 1993 + 3)
    text = head + middle + head[7:] + b'"}'
    frame = (frame_header(len(text), _WINDOW_LOG) + block(0, head, False) + block(0, middle, False)
             + block(2, section, True))
    return _with_metadata_frame(frame, len(text))
