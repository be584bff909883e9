"""``spcodec tile``: a scene too big for one file, as a 3D Tiles 1.1 tileset of .spc nodes."""

from __future__ import annotations

import argparse

from .options import EXIT_OK, Bounded

NAME = "tile"
HELP = ("encode a scene as a tileset (OUT/tileset.json, 3D Tiles 1.1, and one .spc per node): "
        "read in chunks, cut into a k-d tree, coarser levels merged from finer ones, each node "
        "encoded on its own as a task on Dask; `spcodec serve OUT/` streams it by view")

PROGRESS_DELAY = 2.0
"""Seconds a stage runs before its progress is shown (as ``eval`` and ``render``): a small build
prints only its result."""


def configure(p: argparse.ArgumentParser) -> None:
    from spcodec.tiling.config import INDEX_LINKS, PRECISION_SEARCHES, TilingConfig

    defaults = TilingConfig()
    p.add_argument("input", help="the scene (a binary PLY or a .splat is read memory-mapped, a "
                   "chunk at a time; other formats are loaded whole)")
    p.add_argument("-o", "--output", required=True, help="the tileset's folder")
    p.add_argument("--leaf-size", type=Bounded(int, 16), default=defaults.leaf_size, metavar="N",
                   help="Gaussians per node at most, %(type)s; a worker's memory follows it "
                   "(default: %(default)s)")
    p.add_argument("--branching", type=int, default=defaults.branching, choices=(2, 4, 8),
                   help="children per node, and how many Gaussians a coarser level merges into "
                   "one (default: %(default)s)")
    p.add_argument("--preset", default=defaults.preset,
                   help="the no-retrain preset every node is encoded with (default: %(default)s)")
    p.add_argument("--sketch", action=argparse.BooleanOptionalAction, default=defaults.sketch,
                   help="let the encodes of nodes that are not points of the curve (see "
                   "--precision-search) build a sketch, as the preset would in one file; in nodes "
                   "it cost CPU and bought no quality at equal bytes (default: no sketch)")
    p.add_argument("--precision-search", nargs="?", const="all", default=defaults.precision_search,
                   choices=PRECISION_SEARCHES, metavar="NODES",
                   help="make nodes their preset's point of the rate-distortion curve, as one file "
                   "is: better pictures at equal bytes, for the search's fixed cost in each node "
                   "searched; NODES is none, coarse (the levels two merges or more above the "
                   "leaves), inner (every merged level) or all (the flag alone) "
                   "(default: %(default)s)")
    p.add_argument("--workers", type=Bounded(int, 0), default=defaults.workers, metavar="N",
                   help="local worker processes, one thread each, %(type)s; 0 encodes in this "
                   "process (default: %(default)s)")
    p.add_argument("--cluster", metavar="ADDRESS",
                   help="a running Dask scheduler (tcp://host:8786) instead of local workers; "
                   "its workers must see the output folder at the same path (default: local "
                   "workers)")
    p.add_argument("--seed", type=int, default=defaults.seed,
                   help="the encoder's seed: the same seed, the same bytes (default: %(default)s)")
    p.add_argument("--index-levels", type=Bounded(int, 0), default=None, metavar="N",
                   help="levels of tiles in each file of the index: tileset.json holds the top N "
                   "and points to an external tileset (subtrees/ID.json) for each inner node "
                   "below them; 0 writes one file (default: as many as keep a file's links to "
                   f"{INDEX_LINKS}, 3 at branching 4)")
    p.add_argument("--keep-work", action="store_true",
                   help="keep OUT/work/ after a successful build; by default it is removed, since "
                   "its spilled leaves are as large as the input and only resume a failed build")
    p.add_argument("--quiet", action="store_true",
                   help="no progress display on stderr (default: off)")


def run(args: argparse.Namespace) -> int:
    from spcodec.encoder.progress import StageReporter
    from spcodec.tiling import TilingConfig, build_tileset

    config = TilingConfig(leaf_size=args.leaf_size, branching=args.branching, preset=args.preset,
                          sketch=args.sketch, precision_search=args.precision_search,
                          workers=args.workers, cluster=args.cluster,
                          seed=args.seed, keep_work=args.keep_work,
                          index_levels=args.index_levels)
    reporter = StageReporter(enabled=not args.quiet, delay=PROGRESS_DELAY)
    try:
        summary = build_tileset(args.input, args.output, config, reporter.stage)
    except BaseException:  # end the stage's line, so the one-line error stands on its own
        reporter.interrupt()
        raise
    print(f"{summary.tileset}: {summary.nodes} nodes ({summary.leaves} leaves, depth "
          f"{summary.depth}), {summary.input_gaussians:,} Gaussians in, "
          f"{summary.encoded_gaussians:,} encoded over every level, {summary.bytes:,} bytes; "
          f"{summary.encoded_nodes} nodes encoded this run, the others reused")
    return EXIT_OK
