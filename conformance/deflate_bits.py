"""Hand-made deflate bits (RFC 1951) for the vectors that no compressor writes.

zlib never emits an incomplete Huffman code or a block header cut in a chosen place, so the vectors
of spec 1.0.1's deflate rules build those bits here: a little-endian bit writer that knows the fixed
literal/length code and the layout of a dynamic block header. Nothing here compresses anything.
"""

from __future__ import annotations

CODE_LENGTH_ORDER = (16, 17, 18, 0, 8, 7, 9, 6, 10, 5, 11, 4, 12, 3, 13, 2, 14, 1, 15)
"""The order in which a dynamic header stores the code length code's lengths."""

STORED, FIXED, DYNAMIC, RESERVED = range(4)
"""The block types (BTYPE)."""


class BitWriter:
    """Bits packed from the least significant end of each byte, as deflate stores them."""

    def __init__(self) -> None:
        self.bits: list[int] = []

    def put(self, value: int, count: int) -> "BitWriter":
        """``count`` bits of ``value``, least significant first (header fields, extra bits)."""
        self.bits += [(value >> i) & 1 for i in range(count)]
        return self

    def code(self, code: int, length: int) -> "BitWriter":
        """A Huffman code, most significant bit first (RFC 1951 section 3.1.1)."""
        self.bits += [(code >> (length - 1 - i)) & 1 for i in range(length)]
        return self

    def block_header(self, final: bool, block_type: int) -> "BitWriter":
        return self.put(int(final), 1).put(block_type, 2)

    def align(self) -> "BitWriter":
        """Zero bits up to the next byte boundary (before a stored block's lengths)."""
        self.bits += [0] * (-len(self.bits) % 8)
        return self

    def bytes(self) -> bytes:
        """The bits so far, the last byte padded with zeros."""
        padded = self.bits + [0] * (-len(self.bits) % 8)
        return bytes(sum(bit << i for i, bit in enumerate(padded[k:k + 8]))
                     for k in range(0, len(padded), 8))


def fixed_code(symbol: int) -> tuple[int, int]:
    """(code, length) of a literal/length symbol in the fixed code (RFC 1951 section 3.2.6)."""
    if symbol < 144:
        return 0x30 + symbol, 8
    if symbol < 256:
        return 0x190 + symbol - 144, 9
    if symbol < 280:
        return symbol - 256, 7
    return 0xC0 + symbol - 280, 8


def canonical_codes(lengths: dict[int, int]) -> dict[int, tuple[int, int]]:
    """Symbol -> (code, length) of the canonical code with these lengths (RFC 1951 3.2.2)."""
    codes, code, previous = {}, 0, 0
    for symbol, length in sorted(lengths.items(), key=lambda item: (item[1], item[0])):
        if length == 0:
            continue
        code <<= length - previous
        codes[symbol], code, previous = (code, length), code + 1, length
    return codes


def dynamic_header(writer: BitWriter, code_lengths: dict[int, int], literal_count: int,
                   distance_count: int) -> dict[int, tuple[int, int]]:
    """Write HLIT, HDIST, HCLEN and the code length code's lengths; return that code.

    ``code_lengths`` maps code-length symbols (0..18) to their lengths in the code length code.
    """
    stored = max(CODE_LENGTH_ORDER.index(s) for s, n in code_lengths.items() if n) + 1
    stored = max(stored, 4)
    writer.put(literal_count - 257, 5).put(distance_count - 1, 5).put(stored - 4, 4)
    for symbol in CODE_LENGTH_ORDER[:stored]:
        writer.put(code_lengths.get(symbol, 0), 3)
    return canonical_codes(code_lengths)
