"""Hand-made zstd frames (RFC 8878) for the vectors that no compressor writes.

libzstd never writes a Huffman stream with bits left over, a sequence that reaches before the
start of its frame or a block larger than its frame's block maximum, so the vectors of the zstd
rules of [R-22] build those frames here: a frame header, raw and compressed blocks, literals
sections (raw, or Huffman-coded with a tree of directly stored weights, in one or four streams) and
sequences sections whose three codes are RLE-coded (one code each, so the bitstream holds only
the extra bits). Nothing here compresses anything.
"""

from __future__ import annotations

MAGIC = b"\x28\xb5\x2f\xfd"


class ForwardBits:
    """A zstd bitstream (RFC 8878 4.1): bits added from the least significant end, closed by a
    1-bit and zero padding; decoders read it backward, the last bits added first."""

    def __init__(self) -> None:
        self.bits: list[int] = []

    def add(self, value: int, count: int) -> "ForwardBits":
        self.bits += [(value >> i) & 1 for i in range(count)]
        return self

    def close(self) -> bytes:
        bits = self.bits + [1]
        bits += [0] * (-len(bits) % 8)
        return bytes(sum(bit << i for i, bit in enumerate(bits[k:k + 8]))
                     for k in range(0, len(bits), 8))


def frame_header(content_size: int, window_log: int | None = None) -> bytes:
    """A frame header declaring ``content_size``: single-segment (the window is the content) when
    ``window_log`` is None, else with a Window_Descriptor of ``2**window_log`` bytes."""
    if window_log is None:
        if content_size < 256:
            return MAGIC + bytes([0x20, content_size])
        return MAGIC + bytes([0xA0]) + content_size.to_bytes(4, "little")
    if not 10 <= window_log <= 41:
        raise ValueError("window_log must be in 10..41")
    descriptor = bytes([(window_log - 10) << 3])
    if 256 <= content_size < 65536 + 256:
        return MAGIC + bytes([0x40]) + descriptor + (content_size - 256).to_bytes(2, "little")
    return MAGIC + bytes([0x80]) + descriptor + content_size.to_bytes(4, "little")


def block(kind: int, content: bytes, last: bool, regenerated: int | None = None) -> bytes:
    """A block: ``kind`` 0 raw, 1 RLE (``content`` one byte, ``regenerated`` its size), 2
    compressed."""
    size = regenerated if kind == 1 else len(content)
    return ((size << 3) | (kind << 1) | int(last)).to_bytes(3, "little") + content


def raw_literals(data: bytes) -> bytes:
    """A raw literals section."""
    if len(data) < 32:
        return bytes([len(data) << 3]) + data
    if len(data) < 4096:
        return ((len(data) << 4) | 0b0100).to_bytes(2, "little") + data
    return ((len(data) << 4) | 0b1100).to_bytes(3, "little") + data


def huffman_literals(data: bytes, weights: dict[int, int], streams: int = 1,
                     spare_bits: tuple[int, ...] = ()) -> bytes:
    """A compressed literals section (type 2) coding ``data`` with the Huffman code of
    ``weights`` (symbol -> weight, RFC 8878 4.2.1; the largest symbol's weight is left implied,
    as the format wants), stored directly as 4-bit values, in one or four streams.
    ``spare_bits[i]`` zero bits are put at the start of stream i: bits no literal uses."""
    last = max(weights)
    stored = [weights.get(s, 0) for s in range(last)]
    total = sum(1 << (w - 1) for w in weights.values() if w)
    if total & (total - 1):
        raise ValueError("the weights do not make a complete code")
    depth = total.bit_length() - 1
    tree = bytes([127 + len(stored)]) + bytes(
        (stored[i] << 4) | (stored[i + 1] if i + 1 < len(stored) else 0)
        for i in range(0, len(stored), 2))
    codes = _canonical(weights, depth)
    if streams == 1:
        parts = [data]
    else:
        segment = (len(data) + 3) // 4
        parts = [data[i * segment:(i + 1) * segment] for i in range(3)] + [data[3 * segment:]]
    coded = []
    for i, part in enumerate(parts):
        bits = ForwardBits().add(0, spare_bits[i] if i < len(spare_bits) else 0)
        for symbol in reversed(part):
            code, length = codes[symbol]
            bits.add(code, length)
        coded.append(bits.close())
    body = tree + (b"" if streams == 1 else b"".join(len(c).to_bytes(2, "little")
                                                       for c in coded[:3])) + b"".join(coded)
    size_format = 0 if streams == 1 else 1
    if len(data) > 1023 or len(body) > 1023:
        raise ValueError("only the 10-bit size format is written here")
    header = (2 | (size_format << 2) | (len(data) << 4) | (len(body) << 14)).to_bytes(3, "little")
    return header + body


def _canonical(weights: dict[int, int], depth: int) -> dict[int, tuple[int, int]]:
    """Symbol -> (code, length): codes in ascending order from the lowest weight, each weight's
    symbols in natural order (RFC 8878 4.2.1.3)."""
    codes, next_code = {}, 0
    for weight in range(1, depth + 1):
        length = depth + 1 - weight
        for symbol in sorted(s for s, w in weights.items() if w == weight):
            codes[symbol] = (next_code >> (depth - length), length)
            next_code += 1 << (depth - length)
    return codes


LL_CODES = [(c, c, 0) for c in range(16)] + [
    (16, 16, 1), (17, 18, 1), (18, 20, 1), (19, 22, 1), (20, 24, 2), (21, 28, 2), (22, 32, 3),
    (23, 40, 3), (24, 48, 4), (25, 64, 6), (26, 128, 7), (27, 256, 8), (28, 512, 9),
    (29, 1024, 10), (30, 2048, 11), (31, 4096, 12), (32, 8192, 13), (33, 16384, 14),
    (34, 32768, 15), (35, 65536, 16)]
"""Literals-length codes: (code, baseline, extra bits)."""

ML_CODES = [(c, c + 3, 0) for c in range(32)] + [
    (32, 35, 1), (33, 37, 1), (34, 39, 1), (35, 41, 1), (36, 43, 2), (37, 47, 2), (38, 51, 3),
    (39, 59, 3), (40, 67, 4), (41, 83, 4), (42, 99, 5), (43, 131, 7), (44, 259, 8),
    (45, 515, 9), (46, 1027, 10), (47, 2051, 11), (48, 4099, 12), (49, 8195, 13),
    (50, 16387, 14), (51, 32771, 15), (52, 65539, 16)]
"""Match-length codes: (code, baseline, extra bits)."""


def _code(table: list[tuple[int, int, int]], value: int) -> tuple[int, int, int]:
    """(code, extra value, extra bits) of a literals or match length."""
    code, base, bits = max((c for c in table if c[1] <= value), key=lambda c: c[1])
    if value - base >= 1 << bits:
        raise ValueError(f"{value} has no code")
    return code, value - base, bits


def rle_sequences(literal_length: int, match_length: int, offset_value: int,
                  count: int = 1, spare_bits: int = 0) -> bytes:
    """A sequences section of ``count`` identical sequences (literals length, match length,
    Offset_Value of RFC 8878: an offset plus 3, or 1..3 for a repeated offset), its three codes
    RLE-coded; ``spare_bits`` zero bits at the start of the bitstream are bits no sequence
    reads."""
    ll_code, ll_extra, ll_bits = _code(LL_CODES, literal_length)
    ml_code, ml_extra, ml_bits = _code(ML_CODES, match_length)
    of_code = offset_value.bit_length() - 1
    of_extra = offset_value - (1 << of_code)
    bits = ForwardBits().add(0, spare_bits)
    for _ in range(count):  # read backward: offset bits first, then match, then literals length
        bits.add(ll_extra, ll_bits).add(ml_extra, ml_bits).add(of_extra, of_code)
    if count >= 0x7F00 or count > 0x7F:
        raise ValueError("only counts up to 127 are written here")
    return bytes([count, 0b01010100, ll_code, of_code, ml_code]) + bits.close()


NO_SEQUENCES = b"\x00"
"""A sequences section without sequences: the block is its literals."""
