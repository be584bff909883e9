"""Every conformance case, valid ones first, in declaration order.

The case modules declare their cases (with :mod:`.declare`) when they are imported; this module
imports them, so declaring stays below collecting and nothing imports back.
"""

from __future__ import annotations

from . import (  # importing them declares their cases
    contexts_cases,
    invalid_cases,
    preview_cases,
    revision_cases,
    stream_cases,
    valid_cases,
)
from .declare import CASES, Case

__all__ = ["Case", "all_cases"]


MODULES = (valid_cases, invalid_cases, stream_cases, preview_cases, revision_cases,
           contexts_cases)
"""The case modules in the suite's order: spec 1.0.1's cases after those of 1.0, then 1.1's,
then 1.1.1's, then 1.2's."""


def all_cases() -> list[Case]:
    """Every declared case, valid ones first, each kind by module then declaration order."""
    rank = {module.__name__: i for i, module in enumerate(MODULES)}
    ordered = sorted(CASES, key=lambda c: rank[c.build.__module__])
    return [c for c in ordered if c.kind == "valid"] + [c for c in ordered if c.kind == "invalid"]
