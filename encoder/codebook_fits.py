"""The encoder's memory of recent codebook fits (one attribute's codebook and indices).

A size target writes trial files of the same patch at several precisions (:mod:`.sizing`), and
each trial changes the options of only some attributes; the file finally written repeats the
trial that fitted. A fit is deterministic for its inputs, so :data:`RECENT` pays for each
distinct one once. Keys hold the fit's inputs by content (a hash of the attribute's values and
the k-means weights) and every setting the fit reads, so a hit returns what a fresh fit would.
"""

from __future__ import annotations

import hashlib
import threading
from collections import OrderedDict
from typing import Callable

import numpy as np

from spcodec.sections import Codebook

Fit = tuple[Codebook, np.ndarray]
"""A codebook and the indices (n, groups) uint8 of the values it was fitted to."""


def digest(array: np.ndarray | None) -> bytes:
    """A content hash of ``array`` (its dtype and shape included); empty for None."""
    if array is None:
        return b""
    array = np.ascontiguousarray(array)
    h = hashlib.blake2b(digest_size=20)
    h.update(f"{array.dtype.str}{array.shape}".encode())
    h.update(memoryview(array).cast("B"))
    return h.digest()


def _copy(fit: Fit) -> Fit:
    """A fit no caller can change in the memory (retraining moves codebook entries in place)."""
    codebook, indices = fit
    return Codebook(codebook.attribute, codebook.entries.copy()), indices.copy()


class RecentFits:
    """Codebook fits by key, up to ``max_bytes`` of entries and indices, least recently used
    out first. Thread-safe: the patch encoder fits attributes on several threads."""

    def __init__(self, max_bytes: int) -> None:
        self.max_bytes = max_bytes
        self.entries: OrderedDict[tuple, Fit] = OrderedDict()
        self.size = 0
        self.hits = 0
        self.lock = threading.Lock()

    def __call__(self, key: tuple, fit: Callable[[], Fit]) -> Fit:
        """What ``fit()`` returns, from memory when ``key`` was fitted before."""
        with self.lock:
            stored = self.entries.get(key)
            if stored is not None:
                self.entries.move_to_end(key)
                self.hits += 1
                return _copy(stored)
        stored = _copy(fit())
        self._put(key, stored)
        return _copy(stored)

    def _put(self, key: tuple, stored: Fit) -> None:
        size = stored[0].entries.nbytes + stored[1].nbytes
        if size > self.max_bytes:
            return
        with self.lock:
            if key in self.entries:
                return
            self.entries[key] = stored
            self.size += size
            while self.size > self.max_bytes:
                _, (codebook, indices) = self.entries.popitem(last=False)
                self.size -= codebook.entries.nbytes + indices.nbytes

    def clear(self) -> None:
        with self.lock:
            self.entries.clear()
            self.size = 0


RECENT = RecentFits(256 << 20)
"""The memory :meth:`.patch.PatchEncoder.quantize` uses (256 MB of indices and entries)."""
