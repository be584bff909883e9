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
from functools import lru_cache
from typing import Callable

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
Compressor = Callable[[Codec, bytes, int | None, int | None], bytes]
"""What the writer compresses sections with: :func:`compress`, or an encoder's wrapper of it."""


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

    The spec's rules for a zstd frame are RFC 8878's as libzstd 1.5.7 applies them in one pass,
    with some that libzstd does not apply everywhere: every block within Block_Maximum_Size
    (compressed size and decoded size), every Huffman literal stream consumed exactly (libzstd's
    fast four-stream loop, used on CPUs with BMI2, does not check where a stream ends), every FSE
    table description within its block, and offsets bounded by the start of the frame, not by its
    window. So the frame's structure is read here (header, block headers, literal and sequence
    section headers, Huffman trees), libzstd decodes it block by block (which gives each block's
    decoded size), and the Huffman streams are checked against the literals they decode to.
    """
    if _zstd is None:
        raise FormatError("section is zstd-compressed but the 'zstandard' package is not "
                          "installed (pip install 'spcodec[zstd]')", "codec-unavailable")
    data = bytes(stored)
    frame = _zstd_frame(data, raw_length)
    out = _zstd_decode_blocks(data, frame, raw_length)
    _zstd_check_entropy(data, frame)
    return out


ZSTD_FRAME_MAGIC = b"\x28\xb5\x2f\xfd"
"""First bytes of a (non-skippable) zstd frame."""

_ZSTD_BLOCK_MAX = 128 * 1024


def _zstd_corrupt(message: str) -> FormatError:
    return FormatError(message, "decompression-failed")


@dataclass
class _ZstdFrame:
    """The structure of a zstd frame: its header and where each block lies."""

    header_size: int
    window_size: int
    single_segment: bool
    checksum: bool
    block_max: int
    blocks: list[tuple[int, int, int, bool]]
    """Per block: offset of its 3-byte header, type (0 raw, 1 RLE, 2 compressed), Block_Size,
    last-block flag."""


def _zstd_frame(data: bytes, raw_length: int) -> _ZstdFrame:
    """Read a frame's header and block headers, in the order the JavaScript decoder does."""
    if len(data) < 5:
        raise _zstd_corrupt("the zstd frame header is cut short")
    if data[:4] != ZSTD_FRAME_MAGIC:
        raise _zstd_corrupt("section is not a zstd frame")
    descriptor = data[4]
    single = bool(descriptor & 0x20)
    if descriptor & 0x08:
        raise _zstd_corrupt("zstd frame header has its reserved bit set")
    checksum = bool(descriptor & 0x04)
    dict_bytes = (0, 1, 2, 4)[descriptor & 3]
    fcs_bytes = (1 if single else 0, 2, 4, 8)[descriptor >> 6]
    header_size = 5 + (0 if single else 1) + dict_bytes + fcs_bytes
    if len(data) < header_size:
        raise _zstd_corrupt("the zstd frame header is cut short")
    pos = 5
    window = 0
    if not single:
        exponent, mantissa = data[5] >> 3, data[5] & 7
        window = (1 << (10 + exponent)) + (1 << (7 + exponent)) * mantissa
        pos += 1
    dict_id = int.from_bytes(data[pos:pos + dict_bytes], "little")
    pos += dict_bytes
    if not fcs_bytes:
        raise _zstd_corrupt("zstd frame does not declare its content size")
    content = int.from_bytes(data[pos:pos + fcs_bytes], "little") + (256 if fcs_bytes == 2 else 0)
    if single:
        window = content
    if content != raw_length:
        raise FormatError(f"zstd frame declares {content} bytes, the section {raw_length}",
                          "length-mismatch")
    if window > ZSTD_MAX_WINDOW:
        raise _zstd_corrupt("zstd frame needs a window above 128 MiB")
    if dict_id:
        raise _zstd_corrupt("zstd frame needs a dictionary")
    block_max = min(window, _ZSTD_BLOCK_MAX)
    blocks, pos = [], header_size
    while True:
        if pos + 3 > len(data):
            raise _zstd_corrupt("the zstd frame ends early")
        head = int.from_bytes(data[pos:pos + 3], "little")
        kind, size, last = (head >> 1) & 3, head >> 3, bool(head & 1)
        if kind == 3:
            raise _zstd_corrupt("zstd block of the reserved type")
        if size > block_max:
            raise _zstd_corrupt("zstd block larger than the block maximum")
        if kind == 2 and size < 2:  # libzstd's streaming decoder skips an empty one
            raise _zstd_corrupt("zstd compressed block too short")
        blocks.append((pos, kind, size, last))
        pos += 3 + (1 if kind == 1 else size)
        if last:
            break
    pos += 4 if checksum else 0
    if pos > len(data):
        raise _zstd_corrupt("the zstd frame ends early")
    if pos != len(data):
        raise _zstd_corrupt("bytes follow the zstd frame")
    return _ZstdFrame(header_size, window, single, checksum, block_max, blocks)


def _zstd_decode_blocks(data: bytes, frame: _ZstdFrame, raw_length: int) -> bytes:
    """libzstd's decode, fed one block at a time, so each block's decoded size is known.

    A frame whose content is larger than its window is given to libzstd with a window that holds
    the whole content (same content size, blocks and checksum): every offset back to the start of
    the frame then decodes as the spec says, whatever the declared window (libzstd's ring buffer
    would otherwise keep somewhat more than the window, and fail or read stale bytes beyond). The
    rules that depend on the declared window (block sizes) are checked here, against it. (So is
    a frame of content size 0: libzstd's streaming decoder takes the one byte of an RLE block for
    a block larger than its window of 0 bytes.)
    """
    if 0 < raw_length <= frame.window_size:
        head = data[:frame.header_size]
    else:
        window_log = max(10, (raw_length - 1).bit_length())
        head = (ZSTD_FRAME_MAGIC + bytes([0xC0 | (data[4] & 0x04), (window_log - 10) << 3])
                + raw_length.to_bytes(8, "little"))
    inflater = _zstd.ZstdDecompressor(max_window_size=1 << 31).decompressobj()
    parts, total = [], 0
    try:
        for i, (start, kind, size, last) in enumerate(frame.blocks):
            stop = start + 3 + (1 if kind == 1 else size) + (4 if last and frame.checksum else 0)
            chunk = data[start:stop]
            out = inflater.decompress(head + chunk if i == 0 else chunk)
            if len(out) > frame.block_max:
                raise _zstd_corrupt("zstd block decodes to more than the block maximum")
            total += len(out)
            if total > raw_length:
                raise _zstd_corrupt("zstd frame inflates past its content size")
            parts.append(out)
    except _zstd.ZstdError as exc:
        raise _zstd_corrupt(f"zstd frame is corrupt ({exc})") from None
    if not inflater.eof or total != raw_length:
        raise _zstd_corrupt(f"zstd frame inflates to {total} bytes, declared {raw_length}")
    return b"".join(parts)


# --------------------------------------------------------------- zstd entropy sections
def _read_fse_distribution(data: bytes, start: int, end: int, max_symbol: int
                           ) -> tuple[list[int], int, int, int]:
    """An FSE table description (RFC 8878 4.1.1) in ``data[start:end]``: (counts, largest
    symbol, accuracy log, bytes used). Bits past ``end`` are an error."""
    if end <= start:
        raise _zstd_corrupt("zstd FSE table description missing")
    value = int.from_bytes(data[start:end], "little")
    avail = (end - start) * 8
    bit = 4
    table_log = (value & 15) + 5
    if table_log > 15:
        raise _zstd_corrupt("zstd FSE accuracy log too large")
    counts = [0] * (max_symbol + 1)
    remaining, threshold, nbits = (1 << table_log) + 1, 1 << table_log, table_log + 1
    symbol, previous0, too_many = 0, False, False
    while True:
        if previous0:
            repeat = (value >> bit) & 3
            bit += 2
            while repeat == 3:
                symbol += 3
                repeat = (value >> bit) & 3
                bit += 2
            symbol += repeat
            if symbol > max_symbol:
                too_many = True
                break
        top = 2 * threshold - 1 - remaining
        low = (value >> bit) & (threshold - 1)
        if low < top:
            count = low
            bit += nbits - 1
        else:
            count = (value >> bit) & (2 * threshold - 1)
            if count >= threshold:
                count -= top
            bit += nbits
        count -= 1
        remaining -= count if count >= 0 else -count
        counts[symbol] = count
        symbol += 1
        previous0 = count == 0
        if remaining < threshold:
            if remaining <= 1:
                break
            nbits = remaining.bit_length()
            threshold = 1 << (nbits - 1)
        if symbol > max_symbol:
            break
    if remaining != 1 or too_many or bit > avail:
        raise _zstd_corrupt("zstd FSE table description is invalid")
    return counts, symbol - 1, table_log, (bit + 7) >> 3


def _huffman_code_lengths(data: bytes, start: int, end: int) -> tuple[list[int], int]:
    """A Huffman tree description (RFC 8878 4.2.1): each symbol's code length (0: absent) and
    the description's size. Called on trees libzstd has accepted."""
    size = data[start]
    stored = (size - 127 + 1) // 2 if size >= 128 else size
    return _huffman_tree(bytes(data[start:min(end, start + 1 + stored)]))


@lru_cache(maxsize=256)
def _huffman_tree(tree: bytes) -> tuple[list[int], int]:
    """:func:`_huffman_code_lengths` of a tree description alone (frames repeat their trees)."""
    data, start = tree, 0
    size = data[start]
    if size >= 128:
        count = size - 127
        size = (count + 1) // 2
        weights = []
        for b in data[start + 1:start + 1 + size]:
            weights += (b >> 4, b & 15)
        weights = weights[:count]
    else:
        weights = _fse_weights(data, start + 1, start + 1 + size)
    total = sum((1 << w) >> 1 for w in weights)
    log = total.bit_length()
    rest = (1 << log) - total
    weights.append(rest.bit_length())
    lengths = [log + 1 - w if w else 0 for w in weights]
    return lengths + [0] * (256 - len(lengths)), size + 1


def _fse_weights(data: bytes, start: int, end: int) -> list[int]:
    """Huffman weights coded with FSE: two interleaved states read until the stream overflows."""
    counts, max_symbol, log, used = _read_fse_distribution(data, start, end, 255)
    size = 1 << log
    symbols, high = [0] * size, size - 1
    following = [0] * (max_symbol + 1)
    for s in range(max_symbol + 1):
        if counts[s] == -1:
            symbols[high] = s
            high -= 1
            following[s] = 1
        else:
            following[s] = max(counts[s], 0)
    step, position = (size >> 1) + (size >> 3) + 3, 0
    for s in range(max_symbol + 1):
        for _ in range(max(counts[s], 0)):
            symbols[position] = s
            position = (position + step) & (size - 1)
            while position > high:
                position = (position + step) & (size - 1)
    nbits, base = [0] * size, [0] * size
    for u in range(size):
        state = following[symbols[u]]
        following[symbols[u]] += 1
        nbits[u] = log - (state.bit_length() - 1)
        base[u] = (state << nbits[u]) - size
    stream = data[start + used:end]
    value = int.from_bytes(stream, "little")
    pos = len(stream) * 8 - 8 + stream[-1].bit_length() - 1

    def read(n: int) -> int:
        nonlocal pos
        pos -= n
        return (value >> pos) & ((1 << n) - 1) if pos >= 0 else (value << -pos) & ((1 << n) - 1)

    states = [read(log), read(log)]
    weights, turn = [], 0
    while True:
        weights.append(symbols[states[turn]])
        states[turn] = base[states[turn]] + read(nbits[states[turn]])
        if pos < 0:
            weights.append(symbols[states[1 - turn]])
            return weights
        turn = 1 - turn


def _zstd_check_entropy(data: bytes, frame: _ZstdFrame) -> None:
    """What libzstd does not check (everywhere) in a frame it decoded: literal sizes within the
    frame's block maximum, FSE table descriptions that stay within their block, and Huffman
    literal streams that end exactly where their literals end ([R-22])."""
    import numpy as np

    huffman, synthetic, lengths = [], [], None
    for start, kind, size, _ in frame.blocks:
        if kind != 2:
            continue
        pos, end = start + 3, start + 3 + size
        b0 = data[pos]
        lit_type, size_format = b0 & 3, (b0 >> 2) & 3
        if lit_type < 2:
            head = {0: 1, 2: 1, 1: 2, 3: 3}[size_format]
            lit_size = int.from_bytes(data[pos:pos + head], "little") >> (3 if head == 1 else 4)
            lit_end = pos + head + (lit_size if lit_type == 0 else 1)
        else:
            head = {0: 3, 1: 3, 2: 4, 3: 5}[size_format]
            word = int.from_bytes(data[pos:pos + head], "little")
            bits = {3: 10, 4: 14, 5: 18}[head]
            lit_size = (word >> 4) & ((1 << bits) - 1)
            lit_end = pos + head + (word >> (4 + bits))
            streams = pos + head
            if lit_type == 2:
                lengths, tree = _huffman_code_lengths(data, streams, lit_end)
                streams += tree
            if size_format == 0:
                ranges, counts = [(streams, lit_end)], [lit_size]
            else:
                jump = [int.from_bytes(data[streams + 2 * i:streams + 2 * i + 2], "little")
                        for i in range(3)]
                bounds = [streams + 6]
                for length in jump:
                    bounds.append(bounds[-1] + length)
                ranges = list(zip(bounds, bounds[1:] + [lit_end]))
                segment = (lit_size + 3) // 4
                counts = [segment] * 3 + [lit_size - 3 * segment]
            huffman.append((lit_size, lengths, ranges, counts))
            synthetic.append(data[pos:lit_end] + b"\0")
        if lit_size > frame.block_max:
            raise _zstd_corrupt("zstd literals larger than the block maximum")
        _check_sequence_tables(data, lit_end, end)
    if not huffman:
        return
    # libzstd decodes the Huffman literals again, alone: each block's literals section followed
    # by an empty sequences section, in a frame of their own
    total = sum(h[0] for h in huffman)
    frame_bytes = [ZSTD_FRAME_MAGIC, bytes([0x80, 0x38]), total.to_bytes(4, "little")]
    for i, content in enumerate(synthetic):
        frame_bytes.append(((len(content) << 3) | 4 | (i == len(synthetic) - 1))
                           .to_bytes(3, "little"))
        frame_bytes.append(content)
    try:
        literals = _zstd.ZstdDecompressor().decompress(b"".join(frame_bytes))
    except _zstd.ZstdError as exc:
        raise _zstd_corrupt(f"zstd literals are corrupt ({exc})") from None
    if len(literals) != total:
        raise _zstd_corrupt("zstd literals decode to another size")
    decoded, at = np.frombuffer(literals, dtype=np.uint8), 0
    for lit_size, lengths, ranges, counts in huffman:
        table = np.array([n if n else 1 << 20 for n in lengths], dtype=np.int64)
        cumulative = np.concatenate(([0], np.cumsum(table[decoded[at:at + lit_size]])))
        first = 0
        for (begin, stop), count in zip(ranges, counts):
            if stop <= begin or data[stop - 1] == 0:
                raise _zstd_corrupt("zstd Huffman stream without its final bit")
            avail = (stop - begin - 1) * 8 + data[stop - 1].bit_length() - 1
            if int(cumulative[first + count] - cumulative[first]) != avail:
                raise _zstd_corrupt("zstd Huffman stream does not end where its literals end")
            first += count
        at += lit_size


def _check_sequence_tables(data: bytes, pos: int, end: int) -> None:
    """The FSE table descriptions of a sequences section stay within the block (libzstd reads
    one that runs past the block's end as if its last bytes repeated)."""
    count = data[pos]
    pos += 1
    if count == 0:
        return
    pos += 2 if count == 0xFF else (1 if count > 0x7F else 0)
    modes = data[pos]
    pos += 1
    for shift, max_symbol in ((6, 35), (4, 31), (2, 52)):
        mode = (modes >> shift) & 3
        if mode == 1:
            pos += 1
        elif mode == 2:
            pos += _read_fse_distribution(data, pos, end, max_symbol)[3]


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
