"""A scene too large to partition in memory: its top levels cut at the medians of a sample, its
rows routed to blocks on disk, and each block then partitioned exactly (docs/LOG.md 32.4).

The exact partition (:func:`.kdtree.build_tree`) holds every centre, its row number and, while
the root is split, copies of both: about 48 bytes a Gaussian, 4 GB at 85 M. Here the tiles above
blocks of at most ``limit`` rows are split at the medians of a strided sample of the centres and
kept as planes; pass 1 streams whole rows through the planes into one file per block, and pass 2
loads one block at a time and cuts it as a small scene is cut. So the peak follows the block, not
the scene. Sibling counts above the blocks differ by the sample's error (a fraction of a per cent
with two million samples); every tile below them is cut exactly, at most ``leaf_size`` a leaf.
"""

from __future__ import annotations

import os
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Callable, Iterator

import numpy as np

from .kdtree import TreeNode, build_tree, fresh_leaves, leaf_path, longest_axis
from .rows import cloud_to_rows, row_width

if TYPE_CHECKING:
    from .source import SceneSource

SAMPLE_ROWS = 1 << 21
"""Centres sampled (every k-th row) to place the planes above the blocks."""

BLOCK_BYTES = 512 << 20
"""Memory one block may take in pass 2: its rows and the exact partition's 48 bytes a row."""

EXACT_BYTES_PER_ROW = 48
"""What the exact partition holds per Gaussian (centre, row number, the root split's copies)."""


def block_rows(sh_degree: int, leaf_size: int) -> int:
    """Rows one block holds at most for this SH degree: a scene of no more is cut exactly."""
    return max(leaf_size, BLOCK_BYTES // (4 * row_width(sh_degree) + EXACT_BYTES_PER_ROW))


@dataclass
class Cut:
    """A tile above the blocks: halving planes into its children, or (no children) a block."""

    id: str
    planes: dict[str, tuple[int, float]] = field(default_factory=dict)
    """By the bits of the halvings taken so far ("" first): the axis and the largest coordinate
    on it that goes to the lower half."""
    children: list["Cut"] = field(default_factory=list)

    def blocks(self) -> Iterator["Cut"]:
        if not self.children:
            yield self
        for child in self.children:
            yield from child.blocks()


def plan_cuts(points: np.ndarray, node_id: str, limit: float, branching: int,
              per_sample: float) -> Cut:
    """The tiles above blocks of at most ``limit`` rows, split as :func:`.kdtree.split_into`
    splits (halves of halves, each across the longest side of its part's box) at the medians of
    ``points``, a sample of which each row stands for ``per_sample`` rows of the scene."""
    cut = Cut(node_id)
    if len(points) * per_sample <= limit or len(points) < 2 * branching:
        return cut
    pieces = [("", points)]
    while len(pieces) < branching:
        halves = []
        for bits, part in pieces:
            if len(part) < 2:  # a half of equal centres: all of it goes low
                cut.planes[bits] = (0, float("inf"))
                halves += [(bits + "0", part), (bits + "1", part[:0])]
                continue
            axis = longest_axis(part)
            coords = part[:, axis]
            threshold = float(np.partition(coords, len(coords) // 2 - 1)[len(coords) // 2 - 1])
            cut.planes[bits] = (axis, threshold)
            low = coords <= threshold
            halves += [(bits + "0", part[low]), (bits + "1", part[~low])]
        pieces = halves
    # a part as large as the whole (equal centres that no plane divides) is a block as it is
    cut.children = [plan_cuts(part, f"{node_id}{k}", limit, branching, per_sample)
                    if len(part) < len(points) else Cut(f"{node_id}{k}")
                    for k, (_, part) in enumerate(pieces)]
    return cut


def route(cut: Cut, centres: np.ndarray, rows: np.ndarray, branching: int
          ) -> Iterator[tuple[str, np.ndarray]]:
    """``(block id, rows of it)`` for ``rows`` (indices into ``centres``) sent through the planes."""
    if not cut.children:
        yield cut.id, rows
        return
    code = np.zeros(len(rows), np.int64)
    for level in range(branching.bit_length() - 1):
        upper = np.zeros(len(rows), bool)
        for value in range(1 << level):
            axis, threshold = cut.planes[format(value, f"0{level}b") if level else ""]
            here = code == value
            upper[here] = centres[rows[here], axis] > threshold
        code = code * 2 + upper
    for k, child in enumerate(cut.children):
        yield from route(child, centres, rows[code == k], branching)


def sample_centres(source: SceneSource, count: int, chunk_rows: int,
                   chunk_done: Callable[[], object]) -> tuple[np.ndarray, float]:
    """Every k-th centre (about ``count`` of them) and how many rows each stands for."""
    stride = max(1, -(-source.count // count))
    parts = []
    for start in range(0, source.count, chunk_rows):
        stop = min(source.count, start + chunk_rows)
        parts.append(source.positions(start, stop)[(-start) % stride::stride].astype(np.float32))
        chunk_done()
    points = np.concatenate(parts)
    return points, source.count / len(points)


def partition_in_blocks(source: SceneSource, work: Path, leaf_size: int, branching: int,
                        chunk_rows: int, limit: int, progress, sample_rows: int | None = None,
                        ) -> tuple[dict[str, TreeNode], list[str]]:
    """The tree of ``source`` (nodes by id) and its leaves' ids, each leaf's rows spilled to
    :func:`.kdtree.leaf_path` in input order, cut through blocks of at most about ``limit``
    rows. A block no row reached is left out of its parent (only a scene of many equal centres
    can leave one empty)."""
    chunks = -(-source.count // chunk_rows)
    sample_rows = SAMPLE_ROWS if sample_rows is None else sample_rows
    stage = progress(f"partition: sample {min(source.count, sample_rows):,} centres", chunks)
    points, per_sample = sample_centres(source, sample_rows, chunk_rows, stage.update)
    top = plan_cuts(points, "n", limit, branching, per_sample)
    del points
    blocks = list(top.blocks())
    stage.done(f"{len(blocks)} blocks of about {limit:,} Gaussians at most")
    folder = work / "blocks"
    shutil.rmtree(folder, ignore_errors=True)  # an interrupted run's files: never appended to
    folder.mkdir(parents=True)
    stage = progress(f"partition pass 1 of 2: route {source.count:,} rows to {len(blocks)} blocks",
                     chunks)
    for _, cloud in source.chunks(chunk_rows):
        rows = cloud_to_rows(cloud)
        for block_id, mine in route(top, rows, np.arange(len(rows)), branching):
            if len(mine):
                with open(folder / f"{block_id}.f32", "ab") as fh:
                    fh.write(rows[mine].tobytes())
        stage.update()
    stage.done(f"{source.count:,} rows routed")
    width = row_width(source.sh_degree)
    nodes: dict[str, TreeNode] = {}
    leaves: list[str] = []
    stage = progress(f"partition pass 2 of 2: cut {len(blocks)} blocks into leaves", len(blocks))
    fresh_leaves(work)
    for block in blocks:
        path = folder / f"{block.id}.f32"
        if path.is_file():
            rows = np.fromfile(path, np.float32).reshape(-1, width)
            sub, leaf_rows = build_tree(rows[:, :3], leaf_size, branching)
            for node in sub.values():
                node.id = block.id + node.id[1:]
                node.children = [block.id + c[1:] for c in node.children]
                nodes[node.id] = node
            for local_id, members in leaf_rows.items():
                leaf_id = block.id + local_id[1:]
                np.save(leaf_path(work, leaf_id), rows[members])
                leaves.append(leaf_id)
            os.remove(path)
        stage.update()
    stage.done(f"{len(leaves)} leaves of at most {leaf_size:,} Gaussians")
    folder.rmdir()
    _add_cuts(top, nodes)
    return nodes, leaves


def _add_cuts(cut: Cut, nodes: dict[str, TreeNode]) -> int:
    """The tiles above the blocks added to ``nodes``, counted from their blocks; returns the
    rows under ``cut`` (0 for a block no row reached, which its parent leaves out)."""
    if not cut.children:
        return nodes[cut.id].count if cut.id in nodes else 0
    counts = [_add_cuts(child, nodes) for child in cut.children]
    total = sum(counts)
    if total:
        nodes[cut.id] = TreeNode(cut.id, total, [c.id for c, n in zip(cut.children, counts) if n])
    return total
