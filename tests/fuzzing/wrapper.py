"""Mutators of the gzip wrapper ([R-80]..[R-84]): a (mutated) inner file re-wrapped, or the
wrapper's header fields, layer offsets, deflate bytes and trailer damaged."""

from __future__ import annotations

import struct
import zlib

from spcodec.codecs import crc32, gzip_wrap
from spcodec.writer import layer_end_offsets

from .choosers import Chooser, chance, choice
from .edits import Field, array_fields, havoc, poke
from .seeds import SeedFile


def gzip_header_fields(data: bytes) -> list[Field]:
    """Fields of the wrapper of :func:`spcodec.codecs.gzip_wrap`: flags, XLEN, SP subfield."""
    fields = [Field(2, "B"), Field(3, "B"), Field(8, "B"), Field(9, "B"), Field(10, "H"),
              Field(14, "H"), Field(16, "H")]
    if len(data) > 18:
        count = struct.unpack_from("<H", data, 16)[0]
        fields += array_fields(18, "Q", count, 8)
    return fields


def repair_fhcrc(buf: bytearray) -> None:
    """Recompute the gzip FHCRC of a wrapper whose header ends after the FEXTRA field."""
    if len(buf) < 12 or not buf[3] & 2 or not buf[3] & 4:
        return
    end = 12 + struct.unpack_from("<H", buf, 10)[0]
    if end + 2 <= len(buf):
        struct.pack_into("<H", buf, end, crc32(bytes(buf[:end])) & 0xFFFF)


def mutate_gzip(seed: SeedFile, inner: bytes, ch: Chooser) -> bytes:
    """Wrap ``inner`` in gzip, then maybe damage the wrapper itself ([R-80]..[R-84])."""
    try:
        ends = [e for e in layer_end_offsets(inner) if e <= len(inner)]
    except Exception:  # a mutant's layer table may be unreadable: wrap without flush points
        ends = []
    wrapped = bytearray(gzip_wrap(inner, ends, level=6))
    op = ch.integer(0, 9)
    if op <= 3:
        return bytes(wrapped)
    if op == 4:
        for _ in range(ch.integer(1, 2)):
            poke(wrapped, choice(ch, gzip_header_fields(bytes(wrapped))), ch)
        if chance(ch, 80):
            repair_fhcrc(wrapped)
        return bytes(wrapped)
    if op == 5:
        return bytes(wrapped[:ch.integer(0, len(wrapped))])
    if op == 6:
        return bytes(wrapped) + choice(ch, [b"\0", b"\x1f\x8b", bytes(wrapped), ch.blob(8)])
    if op == 7:
        at = ch.integer(len(wrapped) - 8, len(wrapped) - 1)
        wrapped[at] ^= 1 << ch.integer(0, 7)
        return bytes(wrapped)
    if op == 8:
        return _gzip_with_fixed_trailer(inner, ch)
    head = 12 + struct.unpack_from("<H", wrapped, 10)[0] + 2
    body = havoc(bytes(wrapped[head:-8]), ch, 1)
    return bytes(wrapped[:head]) + body + bytes(wrapped[-8:])


def _gzip_with_fixed_trailer(inner: bytes, ch: Chooser) -> bytes:
    """A plain gzip stream (optionally FNAME/FCOMMENT) of damaged inner bytes with a correct CRC."""
    damaged = havoc(inner, ch, 1)
    flags = choice(ch, [0, 8, 16, 24])
    head = b"\x1f\x8b\x08" + bytes([flags]) + b"\0\0\0\0\0\xff"
    head += b"name\0" if flags & 8 else b""
    head += b"comment\0" if flags & 16 else b""
    deflater = zlib.compressobj(6, zlib.DEFLATED, -15)
    body = deflater.compress(damaged) + deflater.flush()
    return head + body + struct.pack("<II", crc32(damaged), len(damaged) & 0xFFFFFFFF)
