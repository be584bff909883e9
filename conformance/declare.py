"""How a conformance case is declared: what each vector is, and the function that builds its bytes.

A case is declared where it is built (``valid_cases.py``, ``invalid_cases.py``) with :func:`valid` or
:func:`invalid`; :mod:`.cases` collects them. The generator builds every case, runs the reference
decoder on it to record the outcomes, and refuses a case whose outcome is not the one it was
declared with: an invalid case must be rejected with its code, a valid one must decode.
"""

from __future__ import annotations

import dataclasses
import re
from dataclasses import dataclass
from typing import Callable

from spcodec.errors import ERROR_CODES

Builder = Callable[[], bytes]
_ID = re.compile(r"^[a-z0-9]+(-[a-z0-9]+)*$")
_REQUIREMENT = re.compile(r"^R-\d+$")


@dataclass(frozen=True)
class Case:
    """One vector's definition."""

    id: str
    kind: str
    title: str
    requirements: tuple[str, ...]
    build: Builder
    error: str | None = None
    """Invalid cases: the code the decode without ``max_layer`` must report."""
    defect: str | None = None
    max_layers: tuple[int, ...] | None = None
    """The ``max_layer`` values to record outcomes for; None: every layer and one past the last
    (valid cases), none (invalid cases)."""
    also_accepted: tuple[str, ...] = ()
    """Further codes allowed where the case's error is expected (several failing checks)."""
    prefixes: bool = False
    """Also emit the prefixes of the file that end at each layer boundary but the last."""
    npz: bool = False
    """Store the expected output as ``.npz`` (large and repetitive) rather than PLY."""


CASES: list[Case] = []


def _register(case: Case) -> None:
    if not _ID.match(case.id):
        raise ValueError(f"case id {case.id!r} is not lower-case words joined by '-'")
    if any(c.id == case.id for c in CASES):
        raise ValueError(f"case id {case.id!r} is declared twice")
    bad = [r for r in case.requirements if not _REQUIREMENT.match(r)]
    if bad or not case.requirements:
        raise ValueError(f"case {case.id}: requirements must be 'R-n' ids, got {case.requirements}")
    for code in (case.error, *case.also_accepted):
        if code is not None and code not in ERROR_CODES:
            raise ValueError(f"case {case.id}: unknown error code {code!r}")
    CASES.append(dataclasses.replace(case, requirements=tuple(sorted(
        set(case.requirements), key=lambda r: int(r[2:])))))


def valid(id: str, title: str, requirements: list[str], *, max_layers: tuple[int, ...] | None = None,
          prefixes: bool = False, npz: bool = False) -> Callable[[Builder], Builder]:
    """Declare the decorated function as the builder of a valid vector."""
    def wrap(build: Builder) -> Builder:
        _register(Case(id, "valid", title, tuple(requirements), build, max_layers=max_layers,
                       prefixes=prefixes, npz=npz))
        return build
    return wrap


def invalid(id: str, title: str, error: str, requirements: list[str], *, defect: str | None = None,
            max_layers: tuple[int, ...] = (), also_accepted: tuple[str, ...] = ()
            ) -> Callable[[Builder], Builder]:
    """Declare the decorated function as the builder of an invalid vector that must be rejected
    with ``error``; ``defect`` (default: the title) is its line in ``invalid/README.md``."""
    def wrap(build: Builder) -> Builder:
        _register(Case(id, "invalid", title, tuple(requirements), build, error, defect or title,
                       max_layers, also_accepted))
        return build
    return wrap
