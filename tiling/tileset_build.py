"""Build a tileset from end to end: partition the input, encode every node as a task on the
engine (:mod:`.jobs`, each node by :func:`.build.build_node`), then write the index
(:mod:`.tileset`). Apart from :mod:`.build` so that the node tasks and the engine that runs them
do not import each other."""

from __future__ import annotations

import os
import shutil
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from spcodec.errors import UsageError

from .build import FORMAT_VERSION, NodeJob
from .config import TilingConfig
from .jobs import engine, run_nodes
from .partition import Partition, input_identity, partition
from .source import open_source
from .tileset import write_tileset

if TYPE_CHECKING:  # the encoder loads scipy, and `spcodec info` imports this package
    from spcodec.encoder.stages import ProgressFactory


@dataclass
class TilingSummary:
    """What :func:`build_tileset` did."""

    tileset: Path
    nodes: int
    leaves: int
    depth: int
    input_gaussians: int
    encoded_gaussians: int
    bytes: int
    encoded_nodes: int
    """Nodes encoded by this run (the others were reused: resume)."""
    partition_seconds: float
    nodes_seconds: float
    mapped: bool
    """Whether the input was read memory-mapped (False: loaded whole, see :mod:`.source`)."""


def build_tileset(input_path: str | os.PathLike, out_dir: str | os.PathLike,
                  config: TilingConfig | None = None,
                  progress: ProgressFactory | None = None) -> TilingSummary:
    """Encode the scene at ``input_path`` as a 3D Tiles 1.1 tileset of ``.spc`` nodes in
    ``out_dir`` (``tileset.json``, ``nodes/``, ``subtrees/`` for a deep tree, and while it runs
    ``work/``: the spilled leaves and merged levels a re-run resumes from, removed at the end
    unless ``config.keep_work``).

    Everything a user can get wrong (settings, input, output, the engine: a ``--cluster``
    address or a missing Dask) is checked before anything is written. ``progress`` gets a stage
    for each partition pass and one for the nodes, counted as they complete (None: silent)."""
    from spcodec.encoder.stages import silent

    progress = progress or silent
    config = config or TilingConfig()
    config.check()
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise UsageError(f"{out} exists and is not a folder")
    source = open_source(input_path)
    if source.count == 0:
        raise UsageError(f"{input_path}: the scene has no Gaussians to encode")
    with engine(config) as client:
        (out / "nodes").mkdir(parents=True, exist_ok=True)
        start = time.perf_counter()
        identity = input_identity(Path(input_path), leaf_size=config.leaf_size,
                                  branching=config.branching, format=FORMAT_VERSION)
        parts = partition(source, out / "work", identity, config.leaf_size, config.branching,
                          config.chunk_rows, progress)
        partitioned = time.perf_counter()
        jobs = jobs_of(parts, out, config)
        stage = progress(f"encode {len(jobs)} nodes", len(jobs))
        records = run_nodes(jobs, client, config.retries, stage)
        stage.done(f"{sum(bool(r['encoded']) for r in records.values())} encoded, "
                   f"{sum(not r['encoded'] for r in records.values())} reused")
        finished = time.perf_counter()
    path = write_tileset(out, parts, records, config.levels_per_index_file())
    remove_stale_nodes(out, parts)
    if not config.keep_work:
        shutil.rmtree(out / "work")
    return TilingSummary(
        tileset=path, nodes=len(parts.nodes), leaves=len(parts.leaves),
        depth=max(len(n) for n in parts.nodes) - 1, input_gaussians=source.count,
        encoded_gaussians=sum(r["count"] for r in records.values()),
        bytes=sum(r["bytes"] for r in records.values()),
        encoded_nodes=sum(bool(r["encoded"]) for r in records.values()),
        partition_seconds=partitioned - start, nodes_seconds=finished - partitioned,
        mapped=source.mapped)


def jobs_of(parts: Partition, out: Path, config: TilingConfig) -> list[NodeJob]:
    """One job per node, every node after its children."""
    folder = str(out.resolve())  # workers may run elsewhere (another working folder)
    nodes = parts.bottom_up()
    height: dict[str, int] = {}  # merges above the leaves
    for n in nodes:
        height[n.id] = 1 + max((height[c] for c in n.children), default=-1)
    return [NodeJob(n.id, tuple(n.children), n.leaf_digest, folder, config.preset, config.seed,
                    config.branching, config.sketch, config.searches(height[n.id]))
            for n in nodes]


def remove_stale_nodes(out: Path, parts: Partition) -> None:
    """Delete node files of an earlier tree (another leaf size or branching) from ``nodes/``:
    the index no longer names them, and a reader of the folder must not take them for tiles."""
    for path in (out / "nodes").iterdir():
        if path.suffix in (".spc", ".json") and path.stem not in parts.nodes:
            path.unlink()
