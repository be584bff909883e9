"""Every conformance case, valid ones first, in declaration order.

The case modules declare their cases (with :mod:`.declare`) when they are imported; this module
imports them, so declaring stays below collecting and nothing imports back.
"""

from __future__ import annotations

from . import invalid_cases, valid_cases  # noqa: F401  (importing them declares their cases)
from .declare import CASES, Case

__all__ = ["Case", "all_cases"]


def all_cases() -> list[Case]:
    """Every declared case, valid ones first, in declaration order."""
    return [c for c in CASES if c.kind == "valid"] + [c for c in CASES if c.kind == "invalid"]
