"""Partition a scene into spatial leaves in two passes over the input.

Pass 1 reads centres only (12 bytes per Gaussian, 48 while the tree is built) and builds a k-d
tree that splits at medians; pass 2 streams the scene in chunks and spills every Gaussian's row to
its leaf's ``.npy`` file. A scene larger than a block is cut through blocks instead
(:mod:`.blocks`), so that memory follows the block and not the scene.

The tree itself, and why a median k-d tree, are in :mod:`.kdtree`.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Callable

import numpy as np

from spcodec.fileio import atomic_write

from .kdtree import TreeNode, build_tree, fresh_leaves, leaf_path
from .rows import cloud_to_rows, row_width
from .source import SceneSource

if TYPE_CHECKING:
    from spcodec.encoder.stages import ProgressFactory

PARTITION_FILE = "partition.json"


@dataclass
class Partition:
    """The tree, and where each leaf's rows were spilled."""

    nodes: dict[str, TreeNode]
    sh_degree: int
    identity: dict
    """The input and settings it was made from; a re-run with the same reuses it."""

    @property
    def leaves(self) -> list[TreeNode]:
        return [n for n in self.nodes.values() if n.is_leaf]

    def bottom_up(self) -> list[TreeNode]:
        """Every node after all of its children (deepest first)."""
        return sorted(self.nodes.values(), key=lambda n: -len(n.id))


def partition(source: SceneSource, work: Path, identity: dict, leaf_size: int, branching: int,
              chunk_rows: int, progress: ProgressFactory | None = None,
              block: int | None = None) -> Partition:
    """Both passes, or the partition already in ``work`` when it was made from the same input
    with the same settings (``identity``). ``progress`` gets a stage per pass, counted in chunks
    read (and one for the leaves' digests), as each takes minutes at 20 M Gaussians.

    A scene of more than ``block`` rows (None: :func:`.blocks.block_rows`, 5 M at SH degree 0)
    is cut through blocks (:mod:`.blocks`), so the peak memory follows the block and not the
    scene; a smaller one exactly, all its centres in memory."""
    from spcodec.encoder.stages import silent

    from .blocks import block_rows, partition_in_blocks

    progress = progress or silent
    previous = load_partition(work, identity)
    if previous is not None:
        return previous
    (work / PARTITION_FILE).unlink(missing_ok=True)  # written again once the spill is complete
    limit = block_rows(source.sh_degree, leaf_size) if block is None else block
    if source.count > limit:
        nodes, leaves = partition_in_blocks(source, work, leaf_size, branching, chunk_rows, limit,
                                            progress)
    else:
        nodes, leaves = _partition_exactly(source, work, leaf_size, branching, chunk_rows,
                                           progress)
    stage = progress(f"digest {len(leaves)} leaves", len(leaves))
    for node_id in leaves:
        nodes[node_id].leaf_digest = file_digest(leaf_path(work, node_id))
        stage.update()
    stage.done("done")
    result = Partition(nodes, source.sh_degree, identity)
    doc = {"identity": identity, "sh_degree": source.sh_degree,
           "nodes": [asdict(n) for n in nodes.values()]}
    atomic_write(work / PARTITION_FILE, json.dumps(doc).encode())  # last: marks the spill done
    return result


def _partition_exactly(source: SceneSource, work: Path, leaf_size: int, branching: int,
                       chunk_rows: int, progress: ProgressFactory) -> tuple[dict[str, TreeNode],
                                                                            list[str]]:
    """Pass 1 reads every centre and builds the tree; pass 2 spills the rows to the leaves."""
    chunks = -(-source.count // chunk_rows)
    stage = progress(f"partition pass 1 of 2: read {source.count:,} centres", chunks)
    points = source.all_positions(chunk_rows, stage.update)        # pass 1: centres only
    nodes, leaf_rows = build_tree(points, leaf_size, branching)
    del points
    stage.done(f"{len(leaf_rows)} leaves of at most {leaf_size:,} Gaussians")
    stage = progress(f"partition pass 2 of 2: spill rows to {len(leaf_rows)} leaves", chunks)
    spill(source, work, leaf_rows, chunk_rows, stage.update)       # pass 2: whole rows
    stage.done(f"{source.count:,} rows spilled")
    return nodes, list(leaf_rows)


def spill(source: SceneSource, work: Path, leaf_rows: dict[str, np.ndarray],
          chunk_rows: int, chunk_done: Callable[[], object] = lambda: None) -> None:
    """Pass 2: each chunk's rows appended to their leaves' files (each file sized in advance);
    ``chunk_done`` is called after each chunk."""
    fresh_leaves(work)
    owner = np.empty(source.count, np.int32)      # leaf number of every row
    names = sorted(leaf_rows)
    width = row_width(source.sh_degree)
    for k, name in enumerate(names):
        owner[leaf_rows[name]] = k
        np.lib.format.open_memmap(leaf_path(work, name), mode="w+", dtype=np.float32,
                                  shape=(len(leaf_rows[name]), width)).flush()
    cursor = np.zeros(len(names), np.int64)
    for start, cloud in source.chunks(chunk_rows):
        rows = cloud_to_rows(cloud)
        ids = owner[start:start + len(cloud)]
        order = np.argsort(ids, kind="stable")
        present, first, counts = np.unique(ids[order], return_index=True, return_counts=True)
        for k, lo, n in zip(present, first, counts):
            out = np.load(leaf_path(work, names[k]), mmap_mode="r+")
            out[cursor[k]:cursor[k] + n] = rows[order[lo:lo + n]]
            out.flush()
            del out
            cursor[k] += n
        chunk_done()


def load_partition(work: Path, identity: dict) -> Partition | None:
    """The partition recorded in ``work`` when its identity matches and its leaves exist."""
    try:
        doc = json.loads((work / PARTITION_FILE).read_text())
    except (OSError, ValueError):
        return None
    if doc.get("identity") != identity:
        return None
    nodes = {n["id"]: TreeNode(**n) for n in doc["nodes"]}
    if not all(leaf_path(work, n.id).is_file() for n in nodes.values() if n.is_leaf):
        return None
    return Partition(nodes, doc["sh_degree"], identity)


def input_identity(path: Path, **settings) -> dict:
    """What decides a partition: the input file (resolved name, size, modification time) and the
    settings; a changed file or setting makes a fresh one."""
    stat = os.stat(path)
    return {"input": str(Path(path).resolve()), "size": stat.st_size,
            "mtime_ns": stat.st_mtime_ns, **settings}


def file_digest(path: Path) -> str:
    """SHA-256 of a file, read in 8 MiB pieces."""
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        for piece in iter(lambda: fh.read(8 << 20), b""):
            digest.update(piece)
    return digest.hexdigest()
