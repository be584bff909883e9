"""The encoder's memory of recent section compressions.

Rate and quality control write trial files of the same sections many times (a size search, the
index contexts' "does it shrink" check, then the file itself). Compression is deterministic, so
the writer is handed :data:`RECENT`, which pays for each distinct compression once. It lives in
the encoder, not the format layer: an application that only decodes or writes a file once holds
no such memory.
"""

from __future__ import annotations

import hashlib
import threading
from collections import OrderedDict

from spcodec.codecs import compress
from spcodec.container import Codec


class RecentCompressions:
    """:func:`spcodec.codecs.compress` that remembers its most recent results, up to
    ``max_bytes`` of output, least recently used out first. Keyed by the payload's content (a
    hash), codec, level and column length. Thread-safe: the writer's callers may compress on
    several threads."""

    def __init__(self, max_bytes: int) -> None:
        self.max_bytes = max_bytes
        self.entries: OrderedDict[tuple, bytes] = OrderedDict()
        self.size = 0
        self.lock = threading.Lock()

    def __call__(self, codec: Codec, raw: bytes, level: int | None = None,
                 column_bytes: int | None = None) -> bytes:
        if codec == Codec.NONE:
            return bytes(raw)
        key = (int(codec), level, column_bytes, len(raw),
               hashlib.blake2b(raw, digest_size=20).digest())
        stored = self._get(key)
        if stored is None:
            stored = compress(codec, raw, level, column_bytes)
            self._put(key, stored)
        return stored

    def _get(self, key: tuple) -> bytes | None:
        with self.lock:
            stored = self.entries.get(key)
            if stored is not None:
                self.entries.move_to_end(key)
            return stored

    def _put(self, key: tuple, stored: bytes) -> None:
        if len(stored) > self.max_bytes:
            return
        with self.lock:
            if key in self.entries:
                return
            self.entries[key] = stored
            self.size += len(stored)
            while self.size > self.max_bytes:
                _, dropped = self.entries.popitem(last=False)
                self.size -= len(dropped)


RECENT = RecentCompressions(64 << 20)
"""The memory the encoder's writer uses (64 MB of compressed output)."""
