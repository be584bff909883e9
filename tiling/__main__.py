"""``python -m spcodec.tiling IN -o OUT/``: ``spcodec tile IN -o OUT/`` under another name, with
the same options, defaults and one-line errors (one parser for both, so they cannot drift)."""

from __future__ import annotations

import sys


def main(argv: list[str] | None = None) -> int:
    """``spcodec tile`` with ``argv`` (default: this process's arguments)."""
    from spcodec.cli import main as spcodec

    return spcodec(["tile", *(sys.argv[1:] if argv is None else argv)])


if __name__ == "__main__":
    sys.exit(main())
