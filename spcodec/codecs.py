"""Section codecs and the optional gzip wrapper (spec sections 4.2 and 8).

Decompression is always *bounded*: a section is inflated into at most its declared raw length, and a
stream that would produce one byte more is rejected without producing it ([R-24], [R-25]). The gzip
wrapper is inflated in chunks up to the caller's limit, and a prefix of a wrapped file inflates to a
prefix of the inner file, which keeps progressive decoding working through the wrapper ([R-81]).
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass

from .container import GZIP_MAGIC, Codec
from .errors import FormatError, LimitError

try:  # zstd is an optional dependency ([R-23])
    import zstandard as _zstd
except ImportError:  # pragma: no cover - exercised only where zstandard is absent
    _zstd = None

ZSTD_MAX_WINDOW = 1 << 27
"""Largest zstd window a decoder accepts (128 MiB), so a frame cannot demand a huge buffer."""

_CHUNK = 1 << 20


def zstd_available() -> bool:
    """True when the optional ``zstandard`` package is installed."""
    return _zstd is not None


def crc32(data: bytes | memoryview) -> int:
    """CRC-32 (ISO-HDLC, the zlib/PNG polynomial) of ``data`` ([R-7])."""
    return zlib.crc32(data) & 0xFFFFFFFF


# ------------------------------------------------------------------------------ section codecs
def compress(codec: Codec, raw: bytes, level: int | None = None,
             column_bytes: int | None = None) -> bytes:
    """Compress one section payload. Deterministic for given input, codec, level and columns.

    ``column_bytes`` says the payload is made of columns of that many bytes (the index columns of
    [R-52]). zlib then also tries a deflate block per column, so each column gets a Huffman code
    of its own (a column of opacity indices and one of rotation indices have little in common),
    and keeps whichever stream is smallest. Any of them is one ordinary zlib stream: decoders see
    no difference.
    """
    if codec == Codec.NONE:
        return bytes(raw)
    if codec == Codec.ZLIB:
        level = 9 if level is None else level
        plain = zlib.compress(raw, level)
        if not column_bytes or column_bytes >= len(raw):
            return plain
        by_column = (_deflate_by_column(raw, column_bytes, level, strategy)
                     for strategy in (zlib.Z_DEFAULT_STRATEGY, zlib.Z_HUFFMAN_ONLY))
        return min((plain, *by_column), key=len)
    if codec == Codec.ZSTD:
        if _zstd is None:
            raise FormatError("zstd requested but the 'zstandard' package is not installed "
                              "(pip install 'spcodec[zstd]')", "codec-unavailable")
        params = _zstd.ZstdCompressor(level=19 if level is None else level, write_content_size=True,
                                      write_checksum=False, threads=0)
        return params.compress(raw)
    raise FormatError(f"unknown codec id {int(codec)}", "unknown-codec")


def _deflate_by_column(raw: bytes, column_bytes: int, level: int, strategy: int) -> bytes:
    """One zlib stream that ends a deflate block at every column boundary (``Z_BLOCK`` adds no
    bytes of its own). Large columns still split into several blocks where zlib's buffer fills.
    ``Z_HUFFMAN_ONLY`` wins on columns of near-random indices, where string matches only blur
    the symbol counts; the default strategy where indices repeat."""
    deflater = zlib.compressobj(level, zlib.DEFLATED, 15, 9, strategy)
    parts = []
    for start in range(0, len(raw), column_bytes):
        parts.append(deflater.compress(raw[start:start + column_bytes]))
        parts.append(deflater.flush(zlib.Z_BLOCK))
    parts.append(deflater.flush(zlib.Z_FINISH))
    return b"".join(parts)


def decompress(codec: int, stored: bytes | memoryview, raw_length: int) -> bytes:
    """Inflate ``stored`` into exactly ``raw_length`` bytes, or raise :class:`FormatError`."""
    if codec == Codec.NONE:
        if len(stored) != raw_length:
            raise FormatError(f"uncompressed section stores {len(stored)} bytes but declares "
                              f"{raw_length}", "length-mismatch")
        return bytes(stored)
    if codec == Codec.ZLIB:
        return _inflate_zlib(stored, raw_length)
    if codec == Codec.ZSTD:
        return _inflate_zstd(stored, raw_length)
    raise FormatError(f"unknown codec id {codec}", "unknown-codec")


def _inflate_zlib(stored: bytes | memoryview, raw_length: int) -> bytes:
    inflater = zlib.decompressobj()
    try:
        out = inflater.decompress(stored, raw_length + 1)
    except zlib.error as exc:
        raise FormatError(f"zlib stream is corrupt ({exc})", "decompression-failed") from None
    return _check_inflated(out, raw_length, inflater.eof,
                           bool(inflater.unconsumed_tail), bool(inflater.unused_data))


def _inflate_zstd(stored: bytes | memoryview, raw_length: int) -> bytes:
    """Exactly one zstd frame that declares ``raw_length`` as its content size ([R-22], [R-24]).

    The declared content size bounds the output (libzstd refuses a frame that produces more than
    it declares), so the frame is inflated in one call; anything after the frame, a skippable
    frame, a missing checksum or a cut frame is refused.
    """
    if _zstd is None:
        raise FormatError("section is zstd-compressed but the 'zstandard' package is not "
                          "installed (pip install 'spcodec[zstd]')", "codec-unavailable")
    data = bytes(stored)
    if data[:4] != ZSTD_FRAME_MAGIC:
        raise FormatError("section is not a zstd frame", "decompression-failed")
    try:
        params = _zstd.get_frame_parameters(data)
    except _zstd.ZstdError as exc:
        raise FormatError(f"zstd frame header is corrupt ({exc})", "decompression-failed") from None
    if params.content_size == _zstd.CONTENTSIZE_UNKNOWN:
        raise FormatError("zstd frame does not declare its content size", "decompression-failed")
    if params.content_size != raw_length:
        raise FormatError(f"zstd frame declares {params.content_size} bytes, the section "
                          f"{raw_length}", "length-mismatch")
    if params.window_size > ZSTD_MAX_WINDOW:
        raise FormatError("zstd frame needs a window above 128 MiB", "decompression-failed")
    inflater = _zstd.ZstdDecompressor(max_window_size=ZSTD_MAX_WINDOW).decompressobj()
    try:
        out = inflater.decompress(data)
    except _zstd.ZstdError as exc:
        raise FormatError(f"zstd frame is corrupt ({exc})", "decompression-failed") from None
    return _check_inflated(out, raw_length, inflater.eof, False, bool(inflater.unused_data))


ZSTD_FRAME_MAGIC = b"\x28\xb5\x2f\xfd"
"""First bytes of a (non-skippable) zstd frame."""


def _check_inflated(out: bytes, raw_length: int, at_end: bool, more_output: bool,
                    trailing: bool) -> bytes:
    if len(out) > raw_length or more_output:
        raise FormatError(f"section inflates past its declared raw length of {raw_length} bytes",
                          "length-mismatch")
    if len(out) < raw_length:
        if not at_end:
            raise FormatError("compressed stream ends early", "decompression-failed")
        raise FormatError(f"section inflates to {len(out)} bytes, declared {raw_length}",
                          "length-mismatch")
    if not at_end:
        raise FormatError("compressed stream ends early", "decompression-failed")
    if trailing:
        raise FormatError("bytes follow the end of the compressed stream", "decompression-failed")
    return out


# ------------------------------------------------------------------------------ gzip wrapper
GZIP_EXTRA_ID = b"SP"
"""Subfield id of the gzip FEXTRA record that lists compressed layer end offsets ([R-83])."""

_GZIP_FLAG_FHCRC, _GZIP_FLAG_FEXTRA, _GZIP_FLAG_FNAME, _GZIP_FLAG_FCOMMENT = 2, 4, 8, 16


def is_gzip(data: bytes | memoryview) -> bool:
    """True when ``data`` starts with the gzip magic."""
    return bytes(data[:2]) == GZIP_MAGIC


def gzip_wrap(inner: bytes, layer_ends: list[int], level: int = 9) -> bytes:
    """Wrap a whole file in one gzip member ([R-82]).

    The deflate stream is fully flushed at each layer end, so a prefix of the gzip file that ends at
    a recorded offset inflates to exactly the inner bytes of layers 0..k; the offsets are stored in a
    FEXTRA subfield ``SP``: uint16 count, then count x uint64 little-endian offsets ([R-83]).
    """
    deflater = zlib.compressobj(level, zlib.DEFLATED, -15, 9)
    body, ends, pos = [], [], 0
    for end in layer_ends:
        body.append(deflater.compress(inner[pos:end]))
        body.append(deflater.flush(zlib.Z_FULL_FLUSH))
        ends.append(sum(map(len, body)))
        pos = end
    body.append(deflater.compress(inner[pos:]))
    body.append(deflater.flush(zlib.Z_FINISH))
    head_len = 10 + 2 + 4 + 2 + 8 * len(ends) + 2  # fixed part, XLEN, subfield, payload, FHCRC
    payload = struct.pack("<H", len(ends)) + struct.pack(f"<{len(ends)}Q", *(head_len + e for e in ends))
    extra = GZIP_EXTRA_ID + struct.pack("<H", len(payload)) + payload
    head = GZIP_MAGIC + bytes([8, _GZIP_FLAG_FEXTRA | _GZIP_FLAG_FHCRC]) + b"\0\0\0\0"
    head += bytes([2, 255]) + struct.pack("<H", len(extra)) + extra
    head += struct.pack("<H", crc32(head) & 0xFFFF)  # FHCRC: protects the layer offsets too
    trailer = struct.pack("<II", crc32(inner), len(inner) & 0xFFFFFFFF)
    return head + b"".join(body) + trailer


@dataclass
class Gunzipped:
    """Result of inflating a (possibly partial) gzip wrapper."""

    inner: bytes
    complete: bool
    layer_ends: list[int] | None
    """Compressed layer end offsets from the ``SP`` FEXTRA subfield, when present."""


def read_gzip_layer_ends(data: bytes | memoryview) -> list[int] | None:
    """The ``SP`` subfield's offsets from a gzip header, or None when it has none or is cut short."""
    data = bytes(data[:(1 << 16) + 64])
    if len(data) < 10 or data[:2] != GZIP_MAGIC or not data[3] & _GZIP_FLAG_FEXTRA:
        return None
    if len(data) < 12:
        return None
    xlen = struct.unpack_from("<H", data, 10)[0]
    extra, pos = data[12:12 + xlen], 0
    if len(extra) < xlen:
        return None
    while pos + 4 <= len(extra):
        sid, size = extra[pos:pos + 2], struct.unpack_from("<H", extra, pos + 2)[0]
        body = extra[pos + 4:pos + 4 + size]
        if sid == GZIP_EXTRA_ID and len(body) >= 2:
            count = struct.unpack_from("<H", body)[0]
            if len(body) == 2 + 8 * count:
                return list(struct.unpack_from(f"<{count}Q", body, 2))
            return None
        pos += 4 + size
    return None


def gunzip_head(data: bytes | memoryview, size: int) -> bytes:
    """Up to ``size`` inner bytes from the start of a gzip wrapper; fewer if it is short or
    corrupt (:func:`gunzip` then reports why). Cheap: inflates no more than it returns."""
    inflater = zlib.decompressobj(wbits=31)
    try:
        return inflater.decompress(data, size)
    except zlib.error:
        return b""


def gunzip(data: bytes | memoryview, max_bytes: int) -> Gunzipped:
    """Inflate a gzip-wrapped file into at most ``max_bytes`` inner bytes.

    A truncated member yields the inner prefix with ``complete=False``; a corrupt member, a bad
    gzip CRC, or bytes after the member raise :class:`FormatError` ([R-81], [R-84]).
    """
    inflater = zlib.decompressobj(wbits=31)
    parts, total, trailing = [], 0, False
    view = memoryview(data)
    try:
        for start in range(0, len(view), _CHUNK):
            chunk = view[start:start + _CHUNK]
            while True:
                out = inflater.decompress(chunk, max_bytes + 1 - total)
                parts.append(out)
                total += len(out)
                if total > max_bytes:
                    raise LimitError(f"gzip wrapper inflates past the limit of {max_bytes} bytes")
                chunk = inflater.unconsumed_tail
                if not chunk:
                    break
            if inflater.eof:
                trailing = bool(inflater.unused_data) or start + _CHUNK < len(view)
                break
    except zlib.error as exc:
        raise FormatError(f"gzip wrapper is corrupt ({exc})", "bad-gzip") from None
    if inflater.eof and trailing:
        raise FormatError("bytes follow the gzip member", "trailing-data")
    return Gunzipped(b"".join(parts), inflater.eof, read_gzip_layer_ends(data))
