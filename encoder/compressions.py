"""The encoder's memory of recent section compressions.

Rate and quality control write trial files of the same sections many times (a size search, the
index contexts' "does it shrink" check, then the file itself). Compression is deterministic, so
the writer is handed :data:`RECENT`, which pays for each distinct compression once. It lives in
the encoder, not the format layer: an application that only decodes or writes a file once holds
no such memory.
"""

from __future__ import annotations

import hashlib

from spcodec.codecs import compress
from spcodec.container import Codec

from .recent import Recent


class RecentCompressions(Recent[bytes]):
    """:func:`spcodec.codecs.compress` that remembers its most recent results, up to
    ``max_bytes`` of output. Keyed by the payload's content (a hash), codec, level and column
    length; the writer's callers may compress on several threads."""

    def __init__(self, max_bytes: int) -> None:
        super().__init__(max_bytes, len)

    @property
    def max_bytes(self) -> int:
        return self.limit

    def __call__(self, codec: Codec, raw: bytes, level: int | None = None,
                 column_bytes: int | None = None) -> bytes:
        if codec == Codec.NONE:
            return bytes(raw)
        key = (int(codec), level, column_bytes, len(raw),
               hashlib.blake2b(raw, digest_size=20).digest())
        return self.get_or_make(key, lambda: compress(codec, raw, level, column_bytes))


RECENT = RecentCompressions(64 << 20)
"""The memory the encoder's writer uses (64 MB of compressed output)."""
