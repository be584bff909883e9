"""The tileset's index split into external tilesets (spec/tileset.md, "The index"): whatever
the tree and the levels per file, reading the files back gives the one-file index; every file
but the last level's holds at most the levels asked; a link tile has no children; a re-write
leaves no file of an earlier tree."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from spcodec.errors import UsageError
from spcodec.tiling.config import INDEX_LINKS, TilingConfig
from spcodec.tiling.partition import Partition, TreeNode
from spcodec.tiling.tileset import (
    SUBTREES,
    TILESET_FILE,
    index_documents,
    is_subtree,
    read_tileset,
    write_tileset,
)


@st.composite
def trees(draw) -> tuple[Partition, dict[str, dict]]:
    """A tree of uneven depth (up to five levels below the root) and a record per node."""
    branching = draw(st.sampled_from([2, 4, 8]))
    nodes: dict[str, TreeNode] = {}
    pending = ["n"]
    while pending:
        node_id = pending.pop()
        deep = len(node_id) - 1
        split = deep < 5 and draw(st.booleans() if deep else st.just(True))
        children = [f"{node_id}{i}" for i in range(branching)] if split else []
        nodes[node_id] = TreeNode(node_id, count=0, children=children)
        pending.extend(children)
    for node in sorted(nodes.values(), key=lambda n: -len(n.id)):
        node.count = sum(nodes[c].count for c in node.children) or draw(st.integers(1, 10**6))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    records: dict[str, dict] = {}
    for node in sorted(nodes.values(), key=lambda n: -len(n.id)):  # errors grow level by level
        lo = rng.normal(size=3)
        error = 0.0 if node.is_leaf else float(rng.uniform(0.01, 1)) + max(
            records[c]["error"] for c in node.children)
        records[node.id] = {"box": [lo, lo + rng.uniform(0.1, 2, 3)], "error": error,
                            "count": int(rng.integers(1, 5000)), "bytes": int(rng.integers(50, 10**5))}
    return Partition(nodes, sh_degree=0, identity={}), records


def tiles(tile: dict, level: int = 0):
    yield tile, level
    for child in tile.get("children", []):
        yield from tiles(child, level + 1)


@settings(max_examples=40, deadline=None)
@given(trees(), st.integers(0, 4))
def test_the_external_tilesets_read_back_as_the_one_file_index(tmp_path_factory, tree, levels):
    parts, records = tree
    out = tmp_path_factory.mktemp("index")
    write_tileset(out, parts, records, levels)
    one_file = index_documents(parts, records, 0)[TILESET_FILE]
    assert read_tileset(out) == json.loads(json.dumps(one_file))
    files = {p.relative_to(out).as_posix() for p in out.rglob("*.json")}
    assert files == set(index_documents(parts, records, levels))
    linked = set()
    for name in files:
        doc = json.loads((out / name).read_text())
        assert doc["asset"]["version"] == "1.1"
        if name != TILESET_FILE:  # the error of drawing none of it: its parent's
            assert doc["geometricError"] >= doc["root"]["geometricError"]
        for tile, depth in tiles(doc["root"]):
            uri = tile["content"]["uri"]
            if is_subtree(uri):
                assert "children" not in tile, "a link tile has no children (3D Tiles)"
                assert levels and depth == levels and depth > 0
                linked.add((out / name).parent.joinpath(uri).resolve().relative_to(out.resolve()).as_posix())
            else:
                assert (Path(name).parent / uri).as_posix().endswith(f"nodes/{tile_id(uri)}.spc")
                assert depth < levels or not levels or not tile.get("children")
    assert linked == files - {TILESET_FILE}, "every external tileset is named once, and only those"
    inner = [n for n in parts.nodes.values() if n.children]
    expected = sum(len(n.id) - 1 > 0 and (len(n.id) - 1) % levels == 0 for n in inner) if levels else 0
    assert len(files) - 1 == expected
    totals = json.loads((out / TILESET_FILE).read_text())["extras"]["spcodec"]
    assert totals == {"tiles": len(records), "gaussians": sum(r["count"] for r in records.values()),
                      "bytes": sum(r["bytes"] for r in records.values())}


def tile_id(uri: str) -> str:
    return Path(uri).stem


@settings(max_examples=10, deadline=None)
@given(trees())
def test_a_rewrite_with_fewer_files_leaves_none_of_the_earlier_ones(tmp_path_factory, tree):
    parts, records = tree
    out = tmp_path_factory.mktemp("index")
    write_tileset(out, parts, records, 1)
    write_tileset(out, parts, records, 0)
    assert sorted(p.name for p in out.iterdir()) == [TILESET_FILE]


def test_the_default_levels_keep_a_file_s_links_within_the_bound():
    for branching, levels in ((2, 6), (4, 3), (8, 2)):
        config = TilingConfig(branching=branching)
        assert config.levels_per_index_file() == levels
        assert branching ** levels <= INDEX_LINKS < branching ** (levels + 1)
    assert TilingConfig(index_levels=0).levels_per_index_file() == 0
    with pytest.raises(UsageError, match="index levels must be 0"):
        TilingConfig(index_levels=-1).check()


def test_a_broken_external_tileset_is_one_line_naming_it(tmp_path):
    root = {"boundingVolume": {"box": [0] * 12}, "geometricError": 1, "content": {"uri": "nodes/n.spc"},
            "children": [{"boundingVolume": {"box": [0] * 12}, "geometricError": 0,
                          "content": {"uri": f"{SUBTREES}/n0.json"}}]}
    (tmp_path / TILESET_FILE).write_text(json.dumps({"asset": {"version": "1.1"}, "root": root}))
    with pytest.raises(UsageError, match=r"n0\.json: cannot read the tileset index"):
        read_tileset(tmp_path)
    (tmp_path / SUBTREES).mkdir()
    (tmp_path / SUBTREES / "n0.json").write_text(json.dumps({"asset": {"version": "1.1"}, "root": {
        "content": {"uri": "../../outside.spc"}}}))
    with pytest.raises(UsageError, match="outside the tileset's folder"):
        read_tileset(tmp_path)
