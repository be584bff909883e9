"""Where the mutators get their decisions: a seeded ``random.Random`` (the by-hand run), hypothesis
(``tests/test_fuzz.py``) or atheris' data provider (coverage-guided). One protocol, so the same
mutators serve all three and a hypothesis failure shrinks to a small mutation."""

from __future__ import annotations

import random
from typing import Protocol, Sequence, TypeVar

T = TypeVar("T")


class Chooser(Protocol):
    """Where a mutator gets its random decisions: random.Random, hypothesis or atheris."""

    def integer(self, lo: int, hi: int) -> int:
        """An integer in ``lo..hi`` inclusive."""

    def blob(self, size: int) -> bytes:
        """``size`` arbitrary bytes."""


class RandomChooser:
    """Decisions from a seeded :class:`random.Random` (the by-hand fuzz run)."""

    def __init__(self, rng: random.Random) -> None:
        self.rng = rng

    def integer(self, lo: int, hi: int) -> int:
        return self.rng.randint(lo, hi)

    def blob(self, size: int) -> bytes:
        return self.rng.randbytes(size)


def choice(ch: Chooser, items: Sequence[T]) -> T:
    """One of ``items``."""
    return items[ch.integer(0, len(items) - 1)]


def chance(ch: Chooser, percent: int) -> bool:
    """True with probability ``percent`` / 100."""
    return ch.integer(0, 99) < percent


class AtherisChooser:
    """Decisions from atheris' FuzzedDataProvider: the coverage-guided engine steers them."""

    def __init__(self, provider) -> None:
        self.fdp = provider

    def integer(self, lo: int, hi: int) -> int:
        return self.fdp.ConsumeIntInRange(lo, hi)

    def blob(self, size: int) -> bytes:
        return self.fdp.ConsumeBytes(size)
