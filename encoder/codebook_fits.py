"""The encoder's memory of recent codebook fits (one attribute's codebook and indices).

A size target writes trial files of the same patch at several precisions (:mod:`.sizing`), and
each trial changes the options of only some attributes; the file finally written repeats the
trial that fitted. A fit is deterministic for its inputs, so :data:`RECENT` pays for each
distinct one once. Keys hold the fit's inputs by content (a hash of the attribute's values and
the k-means weights) and every setting the fit reads, so a hit returns what a fresh fit would.
"""

from __future__ import annotations

import hashlib
from typing import Callable

import numpy as np

from spcodec.sections import Codebook

from .recent import Recent

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


class RecentFits(Recent[Fit]):
    """Codebook fits by key, up to ``max_bytes`` of entries and indices; the patch encoder fits
    attributes on several threads."""

    def __init__(self, max_bytes: int) -> None:
        super().__init__(max_bytes, lambda fit: fit[0].entries.nbytes + fit[1].nbytes)

    @property
    def max_bytes(self) -> int:
        return self.limit

    def __call__(self, key: tuple, fit: Callable[[], Fit]) -> Fit:
        """What ``fit()`` returns, from memory when ``key`` was fitted before."""
        return _copy(self.get_or_make(key, lambda: _copy(fit())))


RECENT = RecentFits(256 << 20)
"""The memory :meth:`.patch.PatchEncoder.quantize` uses (256 MB of indices and entries)."""
