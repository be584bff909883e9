"""The settings of a tiled encode."""

from __future__ import annotations

from dataclasses import dataclass

from spcodec.errors import UsageError

BRANCHINGS = (2, 4, 8)

INDEX_LINKS = 64
"""At most this many external tilesets named by one file of the index by default
(:attr:`TilingConfig.index_levels`)."""

PRECISION_SEARCHES = {"none": None, "coarse": 2, "inner": 1, "all": 0}
"""The nodes :attr:`TilingConfig.precision_search` may name, and how many merges above the
leaves a node must be to be searched under each (None: never)."""


@dataclass(frozen=True)
class TilingConfig:
    """How a scene is cut, merged, encoded and scheduled.

    ``leaf_size`` bounds every node: a leaf holds at most that many input Gaussians and an inner
    node about as many merged ones, so it sets the peak memory of one encode. ``branching`` is
    both the tree's fan-out and the merge's reduction per level (the depth follows as
    ``log_branching(N / leaf_size)``). ``workers=0`` runs every node in this process, with no
    engine; otherwise a local Dask cluster of that many single-threaded worker processes, unless
    ``cluster`` gives a scheduler's address (``tcp://host:8786``), whose workers then do the work
    and must see the output folder at the same path (a shared file system): tasks pass file
    names, not Gaussians.
    """

    leaf_size: int = 65536
    branching: int = 4
    preset: str = "balanced"
    sketch: bool = False
    """Whether the nodes' encodes build a sketch (``--sketch``). Off by default: in a tileset's
    nodes, leaves and merged inner nodes alike, the sketch's cluster search cost a third of a
    node's CPU where it found no cluster and, where it did, its files were worse at equal bytes
    (docs/LOG.md, issue 39). It can only take the preset's sketch away, never add one, and only
    from nodes that are not points of the curve (:attr:`precision_search`): a point builds none."""
    precision_search: str = "coarse"
    """Which nodes are their preset's point of the rate-distortion curve, as a single file is
    (``--precision-search``, DECISIONS D-33): the preset's bytes spent by the precision search,
    without a sketch. One of :data:`PRECISION_SEARCHES`: ``"none"`` (the preset's own codebook
    shapes), ``"coarse"`` (the levels at least two merges above the leaves, DECISIONS D-35),
    ``"inner"`` (every merged level) or ``"all"``. The search's fixed cost is paid per node
    searched, about 9 CPU s in a node of 19,532 (five times its encode): every inner node of
    the 20 M tileset would take the build from 0.76x to about 1.6x a single file's time per
    Gaussian, the coarse ones to about 1.0x. They are what a viewer draws first and from afar,
    where it gained 1.8-3.5 dB at fewer bytes (docs/LOG.md 26.3, 28.2, 28.3)."""
    workers: int = 2
    cluster: str | None = None
    seed: int = 0
    chunk_rows: int = 262144
    """Rows read from the input at a time (the partition's peak memory besides the centres)."""
    retries: int = 2
    """Times the engine re-runs a failed node task before the build fails."""
    index_levels: int | None = None
    """Levels of tiles in each file of the index (``--index-levels``): ``tileset.json`` holds the
    top ones and points to an external tileset (``subtrees/<id>.json``) for every inner node
    below them, which holds the next ones, and so on; 0 writes the whole tree in one file. None
    (the default) takes as many levels as keep a file's links to at most
    :data:`INDEX_LINKS` (3 at branching 4), so a viewer reads a few tens of kilobytes before its
    first node at any scene size, where one file grew with the scene (463 kB at 1,365 nodes,
    2.7 times the root node it fetches next)."""
    keep_work: bool = False
    """Keep ``work/`` after a successful build. It holds the spilled leaves (a copy of the whole
    input) and the merged levels, needed only to resume a build that failed, so by default a
    finished tileset is left without it; a re-run then reads the input again but re-encodes
    nothing."""

    def check(self) -> None:
        """One-line UsageError for a setting that cannot work."""
        from spcodec.encoder.presets import PRESETS

        if self.branching not in BRANCHINGS:
            raise UsageError(f"branching must be one of {', '.join(map(str, BRANCHINGS))}, "
                             f"got {self.branching}")
        if self.leaf_size < 16 * self.branching:
            raise UsageError(f"leaf size must be at least {16 * self.branching} with branching "
                             f"{self.branching}, got {self.leaf_size}")
        if self.preset not in PRESETS:
            raise UsageError(f"unknown preset {self.preset!r}: use one of {', '.join(PRESETS)}")
        if self.workers < 0:
            raise UsageError(f"workers must be 0 (this process) or more, got {self.workers}")
        if self.chunk_rows < 1:
            raise UsageError(f"chunk rows must be positive, got {self.chunk_rows}")
        if self.retries < 0:
            raise UsageError(f"retries must be 0 or more, got {self.retries}")
        if self.index_levels is not None and self.index_levels < 0:
            raise UsageError(f"index levels must be 0 (one file) or more, got {self.index_levels}")
        if self.precision_search not in PRECISION_SEARCHES:
            raise UsageError(f"precision search must be one of {', '.join(PRECISION_SEARCHES)}, "
                             f"got {self.precision_search!r}")
        if self.sketch and self.precision_search == "all":
            raise UsageError("--precision-search all makes every node its preset's point, which "
                             "builds no sketch (DECISIONS D-33): drop --sketch or choose "
                             "another")

    def levels_per_index_file(self) -> int:
        """:attr:`index_levels`, or by default the most levels whose last one, ``branching **
        levels`` tiles, stays within :data:`INDEX_LINKS`."""
        if self.index_levels is not None:
            return self.index_levels
        levels = 1
        while self.branching ** (levels + 1) <= INDEX_LINKS:
            levels += 1
        return levels

    def searches(self, height: int) -> bool:
        """Whether a node ``height`` merges above the leaves (0: a leaf) is its preset's point."""
        least = PRECISION_SEARCHES[self.precision_search]
        return least is not None and height >= least
