"""The index of a tiled scene: a 3D Tiles 1.1 ``tileset.json`` whose tile contents are ``.spc``.

Boxes are in the scene's own coordinates (no transform: a viewer places the tileset with the
root's ``transform`` it adds); spcodec's own numbers per tile sit in ``extras.spcodec``. A deep
tree is split into external tilesets (``subtrees/<id>.json``, 3D Tiles' own way to page an
index), so what a viewer reads before its first node stays small however large the scene.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath

import numpy as np

from spcodec.errors import UsageError
from spcodec.fileio import atomic_write

from .partition import Partition

TILESET_FILE = "tileset.json"
SUBTREES = "subtrees"
"""The folder of the external tilesets, beside ``nodes/``."""


def box_volume(lo: np.ndarray, hi: np.ndarray) -> list[float]:
    """A 3D Tiles ``boundingVolume.box``: centre, then the three half-axis vectors."""
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    centre, half = (lo + hi) / 2, np.maximum((hi - lo) / 2, 1e-9)  # a box may not be flat
    return [*centre.tolist(), half[0], 0.0, 0.0, 0.0, half[1], 0.0, 0.0, 0.0, half[2]]


@dataclass
class _IndexFiles:
    """The documents of one index being written: ``tileset.json`` and the external tilesets,
    by their path relative to the tileset's folder."""

    parts: Partition
    records: dict[str, dict]
    levels: int
    """Levels of tiles per file (0: the whole tree in ``tileset.json``)."""
    documents: dict[str, dict] = field(default_factory=dict)

    def tile(self, node_id: str, top: int, prefix: str) -> dict:
        """The tile of ``node_id`` with its subtree, in a file whose root is at level ``top``
        and whose URIs are relative to ``prefix`` (the file's folder from the tileset's)."""
        record, node = self.records[node_id], self.parts.nodes[node_id]
        level = len(node_id) - 1
        out = self.link_or_tile(record, node_id, f"{prefix}nodes/{node_id}.spc", level)
        if not node.children:
            return out
        if self.levels and level + 1 - top == self.levels:  # children start files of their own
            out["children"] = [self.subtree(c, prefix) if self.parts.nodes[c].children
                               else self.tile(c, top, prefix) for c in node.children]
        else:
            out["children"] = [self.tile(c, top, prefix) for c in node.children]
        return out

    def subtree(self, node_id: str, prefix: str) -> dict:
        """A link to ``node_id``'s external tileset, which this writes: a tile of the node's
        box, error and numbers whose content is that file and which has no children, as 3D
        Tiles requires of a tile that points to an external tileset."""
        record = self.records[node_id]
        parent = self.records[node_id[:-1]]
        name = f"{SUBTREES}/{node_id}.json"
        self.documents[name] = {
            "asset": {"version": "1.1", "generator": "spcodec tiling"},
            # the error of drawing none of it: its parent drawn instead
            "geometricError": parent["error"],
            "root": self.tile(node_id, len(node_id) - 1, "../"),
        }
        link_prefix = "" if prefix == "../" else f"{SUBTREES}/"
        return self.link_or_tile(record, node_id, f"{link_prefix}{node_id}.json", len(node_id) - 1)

    def link_or_tile(self, record: dict, node_id: str, uri: str, level: int) -> dict:
        return {
            "boundingVolume": {"box": box_volume(*record["box"])},
            "geometricError": record["error"],
            "refine": "REPLACE",
            "content": {"uri": uri},
            "extras": {"spcodec": {"gaussians": record["count"], "bytes": record["bytes"],
                                   "inputGaussians": self.parts.nodes[node_id].count,
                                   "level": level}},
        }


def index_documents(parts: Partition, records: dict[str, dict], levels: int = 0) -> dict[str, dict]:
    """Every file of the index by its path in the tileset's folder: ``tileset.json`` and, when
    ``levels`` is positive, one external tileset per inner node every ``levels`` levels
    (a leaf stays in its parent's file: a file of one tile would only cost a request).

    The tileset's own geometric error, the error of drawing nothing, is the root box's diagonal;
    ``extras.spcodec`` of ``tileset.json`` states the whole tileset's tiles, Gaussians and bytes,
    which a viewer would otherwise learn only once it had read every file."""
    files = _IndexFiles(parts, records, levels)
    root = files.tile("n", 0, "")
    lo, hi = (np.asarray(v) for v in records["n"]["box"])
    totals = {"tiles": len(records), "gaussians": sum(r["count"] for r in records.values()),
              "bytes": sum(r["bytes"] for r in records.values())}
    main = {"asset": {"version": "1.1", "generator": "spcodec tiling"},
            "geometricError": float(np.linalg.norm(hi - lo)), "root": root,
            "extras": {"spcodec": totals}}
    return {TILESET_FILE: main, **files.documents}


def write_tileset(out: Path, parts: Partition, records: dict[str, dict], levels: int = 0) -> Path:
    """Write the index (:func:`index_documents`), each file atomically, ``tileset.json`` last so
    that it never names a file not yet written, and remove external tilesets of an earlier tree.
    Returns the path of ``tileset.json``."""
    documents = index_documents(parts, records, levels)
    folder = out / SUBTREES
    if len(documents) > 1:
        folder.mkdir(exist_ok=True)
    for name, document in sorted(documents.items(), key=lambda item: item[0] == TILESET_FILE):
        # compact: a viewer fetches the index before any tile, and indenting doubled it
        atomic_write(out / name, json.dumps(document, separators=(",", ":")).encode())
    if folder.is_dir():
        for path in folder.glob("*.json"):
            if f"{SUBTREES}/{path.name}" not in documents:
                path.unlink()
        if not any(folder.iterdir()):
            folder.rmdir()
    return out / TILESET_FILE


def is_subtree(uri: str) -> bool:
    """Whether a tile's content URI names an external tileset (a JSON file), not a node."""
    return uri.split("?")[0].split("#")[0].lower().endswith(".json")


def read_tileset(path: str | Path) -> dict:
    """A tileset's index as one document: ``path`` (a ``tileset.json`` or the folder holding
    it) with every external tileset read and put in place of the tile that points to it, and
    every content URI made relative to the folder of ``tileset.json``. For tools and tests
    that walk the whole tree; a viewer reads the external files only as it needs them."""
    index = Path(path)
    if index.is_dir():
        index = index / TILESET_FILE
    document = _load(index)
    folder = index.parent
    stack = [(document["root"], PurePosixPath("."), None, None)]
    while stack:
        tile, base, parent, slot = stack.pop()
        uri = tile.get("content", {}).get("uri")
        if isinstance(uri, str) and is_subtree(uri):
            if tile.get("children"):
                raise UsageError(f"{index}: the tile pointing to {uri} also has children")
            where = _relative(base, uri)
            root = _load(folder / where)["root"]
            if parent is None:
                raise UsageError(f"{index}: the root tile may not be an external tileset")
            parent["children"][slot] = root
            stack.append((root, PurePosixPath(where).parent, parent, slot))
            continue
        if isinstance(uri, str):
            tile["content"]["uri"] = _relative(base, uri)
        for i, child in enumerate(tile.get("children", [])):
            stack.append((child, base, tile, i))
    return document


def _relative(base: PurePosixPath, uri: str) -> str:
    """``uri``, written in a file in folder ``base``, relative to the tileset's folder."""
    parts: list[str] = []
    for part in (base / uri).parts:
        if part == "..":
            if not parts:
                raise UsageError(f"{uri} points outside the tileset's folder")
            parts.pop()
        elif part != ".":
            parts.append(part)
    return "/".join(parts)


def _load(path: Path) -> dict:
    try:
        document = json.loads(path.read_text())
    except (OSError, ValueError) as error:
        raise UsageError(f"{path}: cannot read the tileset index ({error})") from None
    if not isinstance(document, dict) or not isinstance(document.get("root"), dict):
        raise UsageError(f"{path}: not a 3D Tiles tileset (no root tile)")
    return document
