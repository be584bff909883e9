"""The viewer streaming a tileset by view (web/viewer/src/tileset.js, web/src/tileset.js), in
headless Chromium, on a tileset ``spcodec.tiling`` encodes with many more Gaussians than the splat
budget.

The scene is long along x (a street, a corridor) and the camera stands inside it looking down +x:
the tiles around and ahead of it are in view, those past its back are behind it. The page must put
the whole scene on screen after a small share of the tileset's bytes (the issue's target: 2 %),
bring the view to full detail (leaves), fetch nothing wholly behind the camera (it cannot be
seen: the selection culls it), and keep within the budget. Front and behind are judged here from
the index's boxes, not from the page's own classes. Skips, saying why, without node, the npm
packages or Chromium.
"""

from __future__ import annotations

import dataclasses
import urllib.parse
from pathlib import Path

import numpy as np
import pytest

import spcodec
from spcodec.imaging.images import read_image
from spcodec.tiling.tileset import read_tileset

from viewer_harness import VIEWER_PAGE, drive, missing_tools, serving, tile_with_one_thread, tileset_tiles

pytestmark = [pytest.mark.browser, pytest.mark.slow]

STRETCH = 8.0
"""The synthetic scene (a cube of side 1.6) is stretched this much along x."""
CAMERA_X = -0.9
"""Where the camera stands on the x axis (tileset coordinates), looking along +x."""
BUDGET = 7500
"""Gaussians drawn at most: the root's children and three of them refined, of 18,000 in all."""
SSE = 16
"""Screen-space error threshold (px) at the page's 240 px, the viewer's default: near tiles refine,
far ones stay coarse."""
TARGET_SHARE = 0.02
"""The issue's target: the whole scene on screen after at most 2 % of the tileset's bytes."""


def require() -> None:
    reason = missing_tools(True)
    if reason:
        pytest.skip(reason)


def street(folder: Path, per_curve: int, blobs: int) -> Path:
    """The synthetic scene stretched along x into a street, as a PLY in ``folder``."""
    from spcodec.synthetic import make_scene

    cloud = make_scene(seed=3, curves=10, per_curve=per_curve, blobs=blobs, sh_degree=1).cloud
    means = cloud.means.copy()
    means[:, 0] *= STRETCH
    spcodec.write_ply(folder / "street.ply", dataclasses.replace(cloud, means=means))
    return folder / "street.ply"


@pytest.fixture(scope="module")
def tileset(tmp_path_factory) -> Path:
    """A 73-node tileset (branching 8, two levels below the root, 250 Gaussians a node) whose
    index is split as a deep one's is: ``tileset.json`` holds the root and links to eight
    external tilesets, each a level-1 node with its leaves."""
    require()
    folder = tmp_path_factory.mktemp("tileset")
    return tile_with_one_thread(street(folder, 300, 13000), folder / "street", leaf_size=256,
                                branching=8, index_levels=1)


@pytest.fixture(scope="module")
def deep_tileset(tmp_path_factory) -> Path:
    """A 341-node tileset (branching 4, four levels below the root, about 47 Gaussians a node)
    with the default index: ``tileset.json`` holds three levels and links to 64 external
    tilesets. Its nodes are too small for a picture; it is about the order and the budget."""
    require()
    folder = tmp_path_factory.mktemp("deep")
    return tile_with_one_thread(street(folder, 600, 6000), folder / "street", leaf_size=64,
                                branching=4)


def visit(tileset: Path, budget: int, captures: list[dict]) -> dict:
    """The viewer's state after streaming ``tileset`` from the street's camera."""
    query = {"src": f"/scenes/{tileset.name}/tileset.json", "width": 320, "height": 240,
             "capture": 1, "cam": f"{CAMERA_X},0,0", "target": f"{CAMERA_X + 1},0,0", "fov": 50,
             "budget": budget, "sse": SSE}
    with serving([tileset]) as base:
        report = drive([{"url": f"{base}{VIEWER_PAGE}?{urllib.parse.urlencode(query)}",
                         "captures": captures}])[0]
    assert report["error"] is None, (report["error"], report["console"][-5:])
    state = report["state"]
    assert state["status"] == "complete" and state["tileset"]["errors"] == []
    return state


def sides(tiles: dict[str, dict], arrivals: list[str]) -> tuple[list[int], list[int]]:
    """Where in ``arrivals`` the leaves wholly in front of the camera's plane came, and the
    tiles wholly behind it."""
    front = {uri for uri, t in tiles.items() if t["lo"][0] > CAMERA_X}
    behind = {uri for uri, t in tiles.items() if t["hi"][0] < CAMERA_X}
    order = {uri: i for i, uri in enumerate(arrivals)}
    return ([order[u] for u in front if u in order and tiles[u]["leaf"]],
            [order[u] for u in behind if u in order])


def assert_axis_drawn_by_leaves(tiles: dict[str, dict], shown: set[str], reach: float) -> None:
    """Every point of the view's axis from 0.1 to ``reach`` units ahead of the camera lies in a
    leaf that is on screen."""
    for t in np.arange(0.1, reach, 0.1):
        point = np.array([CAMERA_X + t, 0.0, 0.0])
        holders = [u for u, tile in tiles.items()
                   if np.all(tile["lo"] <= point) and np.all(point <= tile["hi"])]
        assert any(tiles[u]["leaf"] and u in shown for u in holders), (t, holders)


def test_the_whole_scene_comes_first_then_the_view_to_full_detail_and_nothing_behind(tileset, tmp_path):
    index = read_tileset(tileset)
    tiles = tileset_tiles(index)
    root_uri = index["root"]["content"]["uri"]
    node_bytes = {uri: (tileset / uri).stat().st_size for uri in tiles}
    total = sum(node_bytes.values())
    assert sum(t["gaussians"] for t in tiles.values()) > 2 * BUDGET
    # the nodes store -y up, so the page's +Y-up world is the tileset's turned about x: on the x
    # axis (y = z = 0) the two agree
    assert spcodec.inspect(tileset / root_uri).to_json()["metadata"]["up"] == "-y"
    state = visit(tileset, BUDGET, [{"when": "firstPicture", "path": str(tmp_path / "first.png")},
                                    {"when": "complete", "path": str(tmp_path / "done.png")}])
    progress = state["tileset"]
    assert progress["tiles"] == len(tiles) and progress["bytes"] == total
    arrivals = [a["id"] for a in progress["arrivals"]]
    assert len(arrivals) == len(set(arrivals)) and arrivals[0] == root_uri
    for a in progress["arrivals"]:
        assert a["bytes"] == node_bytes[a["id"]]
    # the index is read as the view needs it: tileset.json first, external tilesets after
    subtrees = {p.name: p.stat().st_size for p in (tileset / "subtrees").iterdir()}
    assert len(subtrees) == 8 and progress["indexBytes"] == (tileset / "tileset.json").stat().st_size
    assert 0 < progress["subtreeBytes"] <= sum(subtrees.values())
    assert state["bytesLoaded"] == (progress["indexBytes"] + progress["subtreeBytes"]
                                    + sum(node_bytes[a] for a in arrivals))

    # the whole scene on screen after the root alone: a small share of the tileset's bytes
    share = progress["nodeBytesAtFullPicture"] / total
    print(f"\nwhole scene on screen after {progress['nodeBytesAtFullPicture']} of {total} node "
          f"bytes ({100 * share:.2f} %); with the index, {progress['bytesAtFullPicture']} of "
          f"{total + (tileset / 'tileset.json').stat().st_size} bytes; {len(arrivals)} of "
          f"{len(tiles)} nodes fetched, {progress['gaussiansShown']} Gaussians shown")
    assert share <= TARGET_SHARE
    assert progress["shownAtFullPicture"] == [root_uri]
    assert state["bytesAtFirstPicture"] == progress["bytesAtFullPicture"]
    picture = read_image(tmp_path / "first.png")  # the frame that first showed it
    assert float((picture.max(axis=2) > 0.02).mean()) > 0.5, "the coarse root fills the view"

    # within the budget, and far from the whole tileset
    assert progress["gaussiansShown"] <= BUDGET
    assert state["bytesLoaded"] < 0.75 * total

    # front and behind, from the boxes: wholly past the camera's plane either way
    front_leaves, behind_tiles = sides(tiles, arrivals)
    assert len(front_leaves) >= 8, front_leaves
    assert not behind_tiles, "a tile wholly behind the camera was fetched: it cannot be seen"

    # what the camera looks at is at full detail: every point of the view's axis up to 1.5 units
    # ahead lies in a leaf that is on screen
    assert_axis_drawn_by_leaves(tiles, set(progress["shown"]), 1.5)


def test_a_tileset_ten_times_its_budget_streams_its_view_first_and_reads_only_the_index_it_needs(
        deep_tileset):
    """Far above the budget, in a tree deep enough for the default index to split: the whole
    scene after the root, the view's leaves and nothing behind the camera, and of the 64 external
    tilesets only those the selection reached."""
    index = read_tileset(deep_tileset)
    tiles = tileset_tiles(index)
    total_gaussians = sum(t["gaussians"] for t in tiles.values())
    budget = total_gaussians // 10
    subtrees = {p.name: p.stat().st_size for p in (deep_tileset / "subtrees").iterdir()}
    assert len(tiles) == 341 and len(subtrees) == 64
    state = visit(deep_tileset, budget, [{"when": "complete"}])
    progress = state["tileset"]
    arrivals = [a["id"] for a in progress["arrivals"]]
    node_bytes = sum((deep_tileset / uri).stat().st_size for uri in tiles)
    print(f"\n{len(arrivals)} of {len(tiles)} nodes, {progress['gaussiansShown']} of "
          f"{total_gaussians} Gaussians shown (budget {budget}); index {progress['indexBytes']} "
          f"bytes, then {progress['subtreeBytes']} of {sum(subtrees.values())} in external files")
    assert progress["tiles"] == len(tiles) and progress["gaussians"] == total_gaussians
    assert progress["shownAtFullPicture"] == [index["root"]["content"]["uri"]]
    assert progress["nodeBytesAtFullPicture"] / node_bytes <= TARGET_SHARE
    assert 0 < progress["gaussiansShown"] <= budget
    assert 0 < progress["subtreeBytes"] < sum(subtrees.values()) / 2, "only what the view reached"
    assert state["bytesLoaded"] < node_bytes / 4
    front_leaves, behind_tiles = sides(tiles, arrivals)
    assert len(front_leaves) >= 8, front_leaves
    assert not behind_tiles, "a tile wholly behind the camera was fetched: it cannot be seen"
    # the budget goes to the larger error first: the view's axis is drawn by leaves from the
    # camera half a unit out (the level-1 tile around the camera has an unbounded error)
    assert_axis_drawn_by_leaves(tiles, set(progress["shown"]), 0.55)
