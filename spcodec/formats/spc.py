"""spcodec's own bitstream (.spc, gzip-wrapped or not): recognized so that a message can name
it, read through the decoder elsewhere (``spcodec decode``, ``eval``, ``render``), never
encoded again."""

from __future__ import annotations

import zlib

from ..container import GZIP_MAGIC, MAGIC

NAME = "spcodec .spc"


def sniff(head: bytes, size: int | None = None) -> bool:
    if head.startswith(MAGIC):
        return True
    return head.startswith(GZIP_MAGIC) and gunzip_head(head, len(MAGIC)).startswith(MAGIC)


def gunzip_head(head: bytes, want: int) -> bytes:
    """The first ``want`` inflated bytes of gzip data that starts with ``head`` (fewer, or
    empty, when ``head`` is too short or not gzip)."""
    try:
        return zlib.decompressobj(16 + zlib.MAX_WBITS).decompress(head, want)
    except zlib.error:
        return b""
