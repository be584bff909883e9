"""The C allocator's settings for a process that renders: freed memory kept for reuse.

glibc returns a large freed block to the kernel at once (``mmap`` above a threshold that starts at
128 KiB, and the heap's top above 128 KiB), and the next render asks for it again: the kernel then
zeroes every page once more. Our renderer frees and allocates tens of MB per view, so a quality
target's renders spent a quarter of their CPU time in the kernel (docs/LOG.md). Keeping blocks up
to :data:`MMAP_THRESHOLD` in the heap and up to :data:`TRIM_THRESHOLD` of free heap unreturned
removes most of it, for a peak about 8 % higher.

Only the command line calls :func:`keep_freed_memory`: a library embedded in someone else's
process leaves their allocator alone. Elsewhere than glibc it does nothing, and a user who set
glibc's own tunables (``GLIBC_TUNABLES``, ``MALLOC_*_``) keeps them.
"""

from __future__ import annotations

import ctypes
import os

M_TRIM_THRESHOLD = -1
M_MMAP_THRESHOLD = -3
"""glibc's ``mallopt`` parameter numbers (malloc.h)."""

TRIM_THRESHOLD = 256 << 20
"""Free memory at the heap's top kept rather than returned (bytes)."""

MMAP_THRESHOLD = 32 << 20
"""Blocks below this come from the heap, not their own mapping: glibc's largest allowed value."""

_USER_SETTINGS = ("GLIBC_TUNABLES", "MALLOC_TRIM_THRESHOLD_", "MALLOC_MMAP_THRESHOLD_")


def keep_freed_memory() -> bool:
    """Set the thresholds above when the C library is glibc and the user set none of its own;
    True when they were set."""
    if any(name in os.environ for name in _USER_SETTINGS):
        return False
    try:  # the symbols the interpreter was linked with, the C library's among them
        libc = ctypes.CDLL(None)
    except (OSError, TypeError):  # Windows has no such handle
        return False
    mallopt = getattr(libc, "mallopt", None)
    gnu = getattr(libc, "gnu_get_libc_version", None)
    if mallopt is None or gnu is None:  # not glibc: musl, macOS, Windows
        return False
    return bool(mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD)) and bool(
        mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD))
