"""A bounded, thread-safe memory of recent results: the one mechanism behind the encoder's
memories of section compressions (:mod:`.compressions`), codebook fits (:mod:`.codebook_fits`)
and index-context choices (:mod:`.contexts`).

A size target writes trial files of the same patch many times; each of those steps is
deterministic for its inputs, so a memory keyed by the inputs' content pays for each distinct
result once. Least recently used out first, within a limit on the summed ``size_of`` of what it
holds (bytes, or a count).
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from typing import Callable, Generic, TypeVar

V = TypeVar("V")


class Recent(Generic[V]):
    """Values by key, their ``size_of`` summing to at most ``limit``; a value larger than the
    limit is not kept. A kept value may be None (a choice of nothing is a choice)."""

    def __init__(self, limit: int, size_of: Callable[[V], int] = lambda value: 1) -> None:
        self.limit = limit
        self.size_of = size_of
        self.entries: OrderedDict[tuple, V] = OrderedDict()
        self.size = 0
        self.hits = 0
        self.lock = threading.Lock()

    def get_or_make(self, key: tuple, make: Callable[[], V]) -> V:
        """The value kept under ``key``, or ``make()``'s (kept when it fits). ``make`` runs
        outside the lock, so threads with different keys work at once."""
        with self.lock:
            if key in self.entries:
                self.entries.move_to_end(key)
                self.hits += 1
                return self.entries[key]
        value = make()
        self.put(key, value)
        return value

    def get(self, key: tuple, default: V | None = None) -> V | None:
        """The value kept under ``key`` (``default`` when none is)."""
        with self.lock:
            if key not in self.entries:
                return default
            self.entries.move_to_end(key)
            self.hits += 1
            return self.entries[key]

    def put(self, key: tuple, value: V) -> None:
        """Keep ``value`` under ``key`` (a key already kept keeps its first value, which a
        deterministic step makes the same)."""
        size = self.size_of(value)
        if size > self.limit:
            return
        with self.lock:
            if key in self.entries:
                self.entries.move_to_end(key)
                return
            self.entries[key] = value
            self.size += size
            while self.size > self.limit:
                _, dropped = self.entries.popitem(last=False)
                self.size -= self.size_of(dropped)

    def clear(self) -> None:
        with self.lock:
            self.entries.clear()
            self.size = 0
