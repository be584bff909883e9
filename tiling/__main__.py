"""``python -m spcodec.tiling IN -o OUT/``: encode a scene as a tileset (see the package)."""

from __future__ import annotations

import argparse
import sys

from spcodec.encoder.progress import StageReporter
from spcodec.errors import SpcodecError

from .config import PRECISION_SEARCHES, TilingConfig
from .tileset_build import build_tileset


def parser() -> argparse.ArgumentParser:
    defaults = TilingConfig()
    p = argparse.ArgumentParser(prog="python -m spcodec.tiling",
                                description="Encode a scene as a 3D Tiles 1.1 tileset of .spc nodes.")
    p.add_argument("input", help="the scene (a binary PLY or a .splat is read memory-mapped)")
    p.add_argument("-o", "--output", required=True, help="output folder")
    p.add_argument("--leaf-size", type=int, default=defaults.leaf_size,
                   help=f"Gaussians per node at most (default {defaults.leaf_size})")
    p.add_argument("--branching", type=int, default=defaults.branching,
                   help=f"children per node and merge reduction, 2, 4 or 8 (default "
                        f"{defaults.branching})")
    p.add_argument("--preset", default=defaults.preset, help="encoder preset of every node")
    p.add_argument("--sketch", action=argparse.BooleanOptionalAction, default=defaults.sketch,
                   help="build a sketch in the encodes of nodes that are not points of the curve "
                        "(default: no sketch; it did not pay in nodes)")
    p.add_argument("--precision-search", nargs="?", const="all", default=defaults.precision_search,
                   choices=PRECISION_SEARCHES, metavar="NODES",
                   help="make nodes their preset's point of the rate-distortion curve, as one file "
                   "is: better pictures at equal bytes, for the search's fixed cost in each node "
                   "searched; NODES is none, coarse (the levels two merges or more above the "
                   "leaves), inner (every merged level) or all (the flag alone) "
                   "(default: %(default)s)")
    p.add_argument("--workers", type=int, default=defaults.workers,
                   help="local worker processes; 0 runs in this process")
    p.add_argument("--cluster", help="address of a running Dask scheduler (tcp://host:8786)")
    p.add_argument("--seed", type=int, default=defaults.seed)
    p.add_argument("--keep-work", action="store_true",
                   help="keep OUT/work/ (spilled leaves, as large as the input; they only resume a "
                        "failed build)")
    p.add_argument("--quiet", action="store_true", help="no progress display on stderr")
    return p


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    config = TilingConfig(leaf_size=args.leaf_size, branching=args.branching, preset=args.preset,
                          sketch=args.sketch, precision_search=args.precision_search,
                          workers=args.workers, cluster=args.cluster,
                          seed=args.seed, keep_work=args.keep_work)
    reporter = StageReporter(enabled=not args.quiet, delay=2.0)
    try:
        summary = build_tileset(args.input, args.output, config, reporter.stage)
    except (SpcodecError, OSError) as exc:
        reporter.interrupt()
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"{summary.tileset}: {summary.nodes} nodes ({summary.leaves} leaves, depth "
          f"{summary.depth}), {summary.input_gaussians} Gaussians in, {summary.bytes} bytes; "
          f"{summary.encoded_nodes} nodes encoded, the others reused")
    return 0


if __name__ == "__main__":
    sys.exit(main())
