"""The index of a tiled scene: a 3D Tiles 1.1 ``tileset.json`` whose tile contents are ``.spc``.

Boxes are in the scene's own coordinates (no transform: a viewer places the tileset with the
root's ``transform`` it adds); spcodec's own numbers per tile sit in ``extras.spcodec``.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from spcodec.fileio import atomic_write

from .partition import Partition

TILESET_FILE = "tileset.json"


def box_volume(lo: np.ndarray, hi: np.ndarray) -> list[float]:
    """A 3D Tiles ``boundingVolume.box``: centre, then the three half-axis vectors."""
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    centre, half = (lo + hi) / 2, np.maximum((hi - lo) / 2, 1e-9)  # a box may not be flat
    return [*centre.tolist(), half[0], 0.0, 0.0, 0.0, half[1], 0.0, 0.0, 0.0, half[2]]


def tile(parts: Partition, records: dict[str, dict], node_id: str) -> dict:
    """The tile of node ``node_id`` with its subtree."""
    record = records[node_id]
    node = parts.nodes[node_id]
    out = {
        "boundingVolume": {"box": box_volume(*record["box"])},
        "geometricError": record["error"],
        "refine": "REPLACE",
        "content": {"uri": f"nodes/{node_id}.spc"},
        "extras": {"spcodec": {"gaussians": record["count"], "bytes": record["bytes"],
                               "inputGaussians": node.count, "level": len(node_id) - 1}},
    }
    if node.children:
        out["children"] = [tile(parts, records, c) for c in node.children]
    return out


def tileset_document(parts: Partition, records: dict[str, dict]) -> dict:
    """The whole ``tileset.json``. The tileset's own geometric error, the error of drawing
    nothing, is the root box's diagonal."""
    lo, hi = (np.asarray(v) for v in records["n"]["box"])
    return {
        "asset": {"version": "1.1", "generator": "spcodec tiling"},
        "geometricError": float(np.linalg.norm(hi - lo)),
        "root": tile(parts, records, "n"),
    }


def write_tileset(out: Path, parts: Partition, records: dict[str, dict]) -> Path:
    """Write ``out/tileset.json`` atomically and return its path."""
    path = out / TILESET_FILE
    # compact: a viewer fetches the index before any tile, and indenting doubled it
    document = json.dumps(tileset_document(parts, records), separators=(",", ":"))
    atomic_write(path, document.encode())
    return path
