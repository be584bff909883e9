"""Byte-level edits: edge values poked into fixed-format fields, and havoc (random flips, inserts,
deletes, cuts) for bytes whose layout the mutators do not model."""

from __future__ import annotations

import struct
from dataclasses import dataclass

from .choosers import Chooser, chance, choice

INTERESTING = {
    "B": [0, 1, 2, 3, 4, 7, 9, 10, 11, 127, 128, 254, 255],
    "H": [0, 1, 2, 3, 255, 256, 257, 0x7FFF, 0x8000, 0xFFFE, 0xFFFF],
    "I": [0, 1, 2, 3, 0x7F, 0x80, 0xFF, 0x100, 0xFFFF, 0x10000, 0x7FFFFFFF, 0x80000000,
          0xFFFFFFFE, 0xFFFFFFFF],
    "i": [0, 1, -1, 2, 0x7FFFFFFF, -0x80000000, 1 << 24, 1 << 30],
    "Q": [0, 1, 2, 0xFFFFFFFF, 1 << 32, 1 << 40, (1 << 63) - 1, 1 << 63, (1 << 64) - 1],
    "f": [0.0, -0.0, 1.0, -1.0, 1e-45, 1e-38, 1e-30, 1e30, 3.4e38, -3.4e38, float("inf"),
          float("-inf"), float("nan")],
    "e": [0.0, -0.0, 1.0, -1.0, 6e-8, 1e-4, 65504.0, -65504.0, float("inf"), float("-inf"),
          float("nan")],
}
_SIZES = {"B": 1, "H": 2, "I": 4, "i": 4, "Q": 8, "f": 4, "e": 2}
_MAX = {"B": 0xFF, "H": 0xFFFF, "I": 0xFFFFFFFF, "Q": (1 << 64) - 1}


def interesting(ch: Chooser, fmt: str, original: int | float) -> int | float:
    """An edge value for a field of struct format ``fmt``, or a small step from ``original``."""
    if fmt in _MAX and chance(ch, 30):
        step = choice(ch, [-2, -1, 1, 2, original, -(original // 2) if original else 1])
        return int(min(max(original + step, 0), _MAX[fmt]))
    return choice(ch, INTERESTING[fmt])


@dataclass(frozen=True)
class Field:
    """A fixed-format field at a byte offset of some buffer."""

    offset: int
    fmt: str


def poke(buf: bytearray, field: Field, ch: Chooser) -> None:
    """Overwrite one field with an interesting value (little-endian, [R-2])."""
    size = _SIZES[field.fmt]
    if field.offset + size > len(buf):
        return
    code = "<" + field.fmt
    (old,) = struct.unpack_from(code, buf, field.offset)
    new = interesting(ch, field.fmt, old if field.fmt in _MAX else 0)
    try:
        struct.pack_into(code, buf, field.offset, new)
    except (struct.error, OverflowError):
        struct.pack_into(code, buf, field.offset, choice(ch, INTERESTING[field.fmt]))


def array_fields(offset: int, fmt: str, count: int, limit: int = 64) -> list[Field]:
    """Fields of a packed array, capped: the first ``limit`` elements are enough to hit a check."""
    return [Field(offset + i * _SIZES[fmt], fmt) for i in range(min(count, limit))]


def havoc(data: bytes, ch: Chooser, rounds: int | None = None) -> bytes:
    """A few random byte edits: flips, overwrites, inserts, deletes, duplications, cuts."""
    buf = bytearray(data)
    for _ in range(rounds if rounds is not None else ch.integer(1, 4)):
        op = ch.integer(0, 7)
        at = ch.integer(0, len(buf)) if buf else 0
        if op == 0 and at < len(buf):
            buf[at] ^= 1 << ch.integer(0, 7)
        elif op == 1 and at < len(buf):
            buf[at] = ch.integer(0, 255)
        elif op == 2:
            buf[at:at] = ch.blob(ch.integer(1, 16))
        elif op == 3:
            del buf[at:at + ch.integer(1, 16)]
        elif op == 4:
            size = ch.integer(1, 32)
            buf[at:at] = buf[at:at + size]
        elif op == 5:
            del buf[at:]
        elif op == 6:
            buf += ch.blob(ch.integer(1, 16)) if chance(ch, 50) else b"\0" * ch.integer(1, 64)
        elif op == 7 and at + 4 <= len(buf):
            struct.pack_into("<I", buf, at, choice(ch, INTERESTING["I"]))
    return bytes(buf)
