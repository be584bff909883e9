"""One mutant of the corpus: which mutator, how often each is drawn, gzip re-wrapping on top."""

from __future__ import annotations

from typing import Callable

from .choosers import Chooser, chance, choice
from .claims import mutate_claim
from .payloads import mutate_payload, mutate_stored
from .seeds import SeedFile
from .structure import (
    mutate_append,
    mutate_flip,
    mutate_header,
    mutate_sections,
    mutate_splice,
    mutate_truncate,
)
from .wrapper import mutate_gzip

INNER_MUTATORS: dict[str, Callable[[SeedFile, list[SeedFile], Chooser], bytes]] = {
    "payload": mutate_payload,
    "stored": mutate_stored,
    "header": mutate_header,
    "sections": mutate_sections,
    "truncate": mutate_truncate,
    "append": mutate_append,
    "flip": mutate_flip,
    "splice": mutate_splice,
    "claim": mutate_claim,
}
KIND_WEIGHTS = {"payload": 30, "stored": 14, "header": 17, "sections": 14, "truncate": 6,
                "append": 2, "flip": 3, "splice": 4, "claim": 5, "gzip": 9}
"""How often the by-hand run draws each kind: payload edits reach the most parsers, so they lead."""


def make_mutant(seeds: list[SeedFile], ch: Chooser, kind: str | None = None) -> tuple[str, bytes]:
    """A mutant of a random seed: its kind (the mutator's name) and its bytes.

    Seeds that are gzip-wrapped files are usually re-wrapped after the inner mutation, so the
    inner layers are reached through the wrapper too.
    """
    seed = choice(ch, seeds)
    kind = kind or _weighted_kind(ch)
    if kind == "gzip" or (seed.gzip and chance(ch, 60)):
        inner_kind = kind if kind != "gzip" else choice(ch, list(INNER_MUTATORS))
        inner = INNER_MUTATORS[inner_kind](seed, seeds, ch) if chance(ch, 60) else seed.data
        return "gzip", mutate_gzip(seed, inner, ch)
    return kind, INNER_MUTATORS[kind](seed, seeds, ch)


def _weighted_kind(ch: Chooser) -> str:
    """A mutation kind drawn by :data:`KIND_WEIGHTS`."""
    pick, acc = ch.integer(0, sum(KIND_WEIGHTS.values()) - 1), 0
    for kind, weight in KIND_WEIGHTS.items():
        acc += weight
        if pick < acc:
            return kind
    raise AssertionError("unreachable")  # pragma: no cover
