"""``spcodec conformance``: the options; :mod:`spcodec.conformance.command` does the work."""

from __future__ import annotations

import argparse

from .options import Bounded

NAME = "conformance"
HELP = "check a decoder against the conformance vectors (or regenerate them)"


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("--decoder", metavar="'CMD {input} {output}'",
                   help="judge this command line instead of the in-process decoder: it must write "
                        "an INRIA PLY to {output} and exit 0, or exit non-zero, write nothing and "
                        "print [error-code] on stderr (conformance/README.md) (default: the "
                        "in-process decoder)")
    p.add_argument("--max-layer-arg", metavar="'--max-layer {k}'",
                   help="what to append to --decoder for a decode of layers 0..k (without it, "
                        "those decodes are not run) (default: none)")
    p.add_argument("--json", action="store_true", help="print the results as one JSON document "
                   "(default: a table)")
    p.add_argument("--only", nargs="+", metavar="PATTERN",
                   help="run only the vectors whose id matches a shell-style pattern (default: "
                   "every vector)")
    p.add_argument("--without-zstd", action="store_true",
                   help="the decoder has no zstd support: decodes that need it expect "
                        "codec-unavailable (default: off)")
    p.add_argument("--timeout", type=Bounded(float, 0, exclusive=True), default=None, metavar="S",
                   help="seconds an external decode may take: %(type)s (default: 60)")
    p.add_argument("--suite", metavar="DIR", help="the suite to run (default: the one installed "
                   "with spcodec)")
    p.add_argument("--generate", metavar="DIR",
                   help="instead of running, regenerate every vector and the manifest into DIR "
                        "(e.g. conformance/ in the repository) (default: off)")


def run(args: argparse.Namespace) -> int:
    from spcodec.conformance.command import run as run_conformance

    return run_conformance(args)
