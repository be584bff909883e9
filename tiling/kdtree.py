"""The median k-d tree a scene's tiles follow: each node split into ``branching`` children by
halvings at medians, each across the longest side of the part's box, down to leaves of at most
``leaf_size`` Gaussians (:mod:`.partition` builds it over a whole scene, :mod:`.blocks` over one
block at a time).

Why a median k-d tree and not an octree: a median split halves the count whatever the density,
so every leaf holds between ``leaf_size / branching`` and ``leaf_size`` Gaussians and the depth is
``log_b(N / leaf_size)``. Captured scenes are very unevenly dense (a detailed centre, a sparse
far field), and an octree's leaves, cut at fixed places, range from a handful to its cap, so its
node count, per-node encode time and peak memory would follow the density instead of a setting.
"""

from __future__ import annotations

import shutil
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np


@dataclass
class TreeNode:
    """One tile of the hierarchy: a leaf holds input Gaussians, an inner node merged ones."""

    id: str
    """"n" for the root, then one digit per level: the child's position under its parent."""
    count: int
    """Input Gaussians below this node."""
    children: list[str] = field(default_factory=list)
    leaf_digest: str | None = None
    """For leaves, the SHA-256 of the spilled rows (what the leaf's encode takes)."""

    @property
    def is_leaf(self) -> bool:
        return not self.children


def longest_axis(coords: np.ndarray) -> int:
    """The axis along which the box of ``coords`` (n, 3) is longest: every split cuts across it."""
    return int(np.argmax(coords.max(axis=0) - coords.min(axis=0)))


def median_split(points: np.ndarray, index: np.ndarray, left: int) -> tuple[np.ndarray, np.ndarray]:
    """``index`` cut in two across the longest side of its points' box: the ``left`` rows with the
    smallest coordinates on that axis, then the rest."""
    coords = points[index]
    axis = longest_axis(coords)
    order = np.argpartition(coords[:, axis], left - 1) if 0 < left < len(index) else \
        np.arange(len(index))
    return index[order[:left]], index[order[left:]]


def split_into(points: np.ndarray, index: np.ndarray, parts: int) -> list[np.ndarray]:
    """``index`` cut into ``parts`` (a power of two) halves of halves at medians."""
    pieces = [index]
    while len(pieces) < parts:
        pieces = [half for piece in pieces for half in median_split(points, piece, len(piece) // 2)]
    return pieces


def build_tree(points: np.ndarray, leaf_size: int, branching: int) -> tuple[dict[str, TreeNode],
                                                                           dict[str, np.ndarray]]:
    """The tile tree over ``points`` and, per leaf id, the row numbers it holds (ascending)."""
    nodes: dict[str, TreeNode] = {}
    leaf_rows: dict[str, np.ndarray] = {}
    stack = [("n", np.arange(len(points), dtype=np.int64))]
    while stack:
        node_id, index = stack.pop()
        node = TreeNode(node_id, int(len(index)))
        nodes[node_id] = node
        if len(index) <= leaf_size:
            leaf_rows[node_id] = np.sort(index)
            continue
        for k, part in enumerate(split_into(points, index, branching)):
            node.children.append(f"{node_id}{k}")
            stack.append((f"{node_id}{k}", part))
    return nodes, leaf_rows


def leaf_path(work: Path, node_id: str) -> Path:
    """Where leaf ``node_id``'s rows are spilled."""
    return work / "leaves" / f"{node_id}.npy"


def fresh_leaves(work: Path) -> None:
    """An empty folder for the leaves: another partition's leaves may not be mistaken for ours."""
    shutil.rmtree(work / "leaves", ignore_errors=True)
    (work / "leaves").mkdir(parents=True)
