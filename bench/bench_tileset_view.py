"""The streaming viewer on a large tileset (issue 39, "streaming by view"): how many bytes until the
whole scene is on screen, whether the view reaches full detail before anything behind the camera
arrives, and the splat budget kept, in headless Chromium over a paced link.

``tests/test_tileset_viewer.py`` checks the same things on a small synthetic tileset on every run;
this measures them on a tileset as large as one likes (``bench_tiles.py make --layout city``, then
``spcodec tile``). The camera stands at ``--cam`` and looks at ``--target`` (tileset coordinates,
the axes the nodes store), by default at the root box's centre looking along the box's longest
horizontal axis, so about half the scene is behind it. Front and behind are judged from the
index's boxes: a tile is in front when all its corners are past the camera's plane, behind when
all are short of it. The page's world is +Y up; the camera is turned into it by the rotation the
loaders apply for the root's stored up axis (``spcodec.gltf.up_rotation``).

    python bench/bench_tileset_view.py TILESET_DIR [--budget 500000] [--sse 16] [--kbps 20000]
                                       [--cam X,Y,Z --target X,Y,Z] [--work DIR] [--json OUT]
"""

from __future__ import annotations

import argparse
import json
import sys
import urllib.parse
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests"))

import spcodec  # noqa: E402
from spcodec.gltf import up_rotation  # noqa: E402
from spcodec.tiling.tileset import read_tileset  # noqa: E402

from viewer_harness import VIEWER_PAGE, drive, missing_tools, serving, tileset_tiles  # noqa: E402


def rotate(v: np.ndarray, q: tuple[float, float, float, float]) -> np.ndarray:
    """``v`` turned by the unit quaternion ``q`` (x, y, z, w), as the web package's ``rotate``."""
    axis, w = np.asarray(q[:3]), q[3]
    c = np.cross(axis, v)
    return v + 2 * (w * c + np.cross(axis, c))


def default_camera(index: dict, up: str | None) -> tuple[np.ndarray, np.ndarray]:
    """At the root box's centre, looking along its longest axis across the up axis."""
    box = np.asarray(index["root"]["boundingVolume"]["box"], dtype=float)
    centre, half = box[:3], np.abs(box[3:].reshape(3, 3)).sum(axis=0)
    up_axis = "xyz".index((up or "-y")[-1])
    extent = half.copy()
    extent[up_axis] = -1
    forward = np.eye(3)[int(np.argmax(extent))]
    return centre, centre + forward


def corners(tile: dict) -> np.ndarray:
    lo, hi = tile["lo"], tile["hi"]
    return np.array([[(lo, hi)[(k >> i) & 1][i] for i in range(3)] for k in range(8)])


def sides(tiles: dict[str, dict], cam: np.ndarray, target: np.ndarray) -> tuple[set, set]:
    """The tiles wholly in front of the camera's plane, and those wholly behind it."""
    forward = (target - cam) / np.linalg.norm(target - cam)
    front, behind = set(), set()
    for uri, tile in tiles.items():
        depth = (corners(tile) - cam) @ forward
        if depth.min() > 0:
            front.add(uri)
        elif depth.max() < 0:
            behind.add(uri)
    return front, behind


def visit(tileset: Path, cam: np.ndarray, target: np.ndarray, up: str | None, args) -> dict:
    """One page visit over the paced link; its first and finished pictures land in ``args.work``."""
    q = up_rotation(up)
    page_cam, page_target = rotate(cam, q), rotate(target, q)
    query = {"src": f"/scenes/{tileset.name}/tileset.json", "width": args.width,
             "height": args.height, "capture": 1, "fov": args.fov, "budget": args.budget,
             "sse": args.sse, "cam": ",".join(f"{v:.6g}" for v in page_cam),
             "target": ",".join(f"{v:.6g}" for v in page_target)}
    args.work.mkdir(parents=True, exist_ok=True)
    captures = [{"when": "firstPicture", "path": str(args.work / "first.png")},
                {"when": "complete", "path": str(args.work / "done.png")}]
    with serving([tileset], throttle_kbps=args.kbps) as base:
        report = drive([{"url": f"{base}{VIEWER_PAGE}?{urllib.parse.urlencode(query)}",
                         "width": args.width, "height": args.height, "timeoutMs": args.timeout * 1000,
                         "captures": captures}], timeout=args.timeout + 60)[0]
    if report["error"]:
        raise RuntimeError(f"{report['error']}: {report['console'][-5:]}")
    return report["state"]


def summary(state: dict, tiles: dict[str, dict], front: set, behind: set, index_bytes: int) -> dict:
    """What the visit showed, in the issue's terms."""
    progress = state["tileset"]
    node_bytes = sum(t["bytes"] for t in progress["arrivals"])
    total = progress["bytes"]
    arrivals = progress["arrivals"]
    first_behind = next((k for k, a in enumerate(arrivals) if a["id"] in behind), len(arrivals))
    front_leaves = [k for k, a in enumerate(arrivals) if a["id"] in front and tiles[a["id"]]["leaf"]]
    view_done = max((k for k in front_leaves if k < first_behind), default=None)
    return {
        "tiles": len(tiles), "gaussians": progress["gaussians"], "node_bytes": total,
        "index_bytes": index_bytes, "subtree_bytes_read": progress["subtreeBytes"],
        "budget": progress["budget"], "sse": progress["threshold"],
        "whole_scene": {"node_bytes": progress["nodeBytesAtFullPicture"],
                        "share": progress["nodeBytesAtFullPicture"] / total,
                        "bytes_with_index": progress["bytesAtFullPicture"],
                        "index_share": (progress["bytesAtFullPicture"]
                                        - progress["nodeBytesAtFullPicture"]) / total,
                        "s": progress["tFullPicture"] / 1000,
                        "nodes": len(progress["shownAtFullPicture"])},
        "view_full_detail": None if view_done is None else {
            "front_leaves": sum(k < first_behind for k in front_leaves),
            "s": arrivals[view_done]["t"] / 1000,
            "node_bytes": sum(a["bytes"] for a in arrivals[:view_done + 1])},
        "front_leaves_after_a_tile_behind": sum(k > first_behind for k in front_leaves),
        "tiles_behind_fetched": sum(a["id"] in behind for a in arrivals),
        "complete": {"s": state["tComplete"] / 1000, "nodes": len(arrivals), "node_bytes": node_bytes,
                     "share": node_bytes / total, "gaussians_shown": progress["gaussiansShown"]},
        "errors": progress["errors"],
    }


def point(text: str) -> np.ndarray:
    values = [float(v) for v in text.split(",")]
    if len(values) != 3:
        raise argparse.ArgumentTypeError(f"needs three numbers x,y,z, got {text!r}")
    return np.array(values)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("tileset", type=Path, help="a folder holding tileset.json")
    parser.add_argument("--budget", type=int, default=500_000, help="Gaussians drawn at most")
    parser.add_argument("--sse", type=float, default=16, help="screen-space error threshold, px")
    parser.add_argument("--kbps", type=float, default=20_000, help="link speed in kbit/s")
    parser.add_argument("--width", type=int, default=480)
    parser.add_argument("--height", type=int, default=360)
    parser.add_argument("--fov", type=float, default=60)
    parser.add_argument("--cam", type=point, help="camera position, tileset coordinates")
    parser.add_argument("--target", type=point, help="where it looks, tileset coordinates")
    parser.add_argument("--timeout", type=int, default=1800, help="seconds for the visit")
    parser.add_argument("--work", type=Path, default=Path("/tmp/spcodec-bench-tileset-view"))
    parser.add_argument("--json", type=Path, help="also write the results here")
    args = parser.parse_args()
    reason = missing_tools(True)
    if reason:
        print(f"cannot run: {reason}", file=sys.stderr)
        return 2
    index_path = args.tileset / "tileset.json"
    index = read_tileset(index_path)
    tiles = tileset_tiles(index)
    up = spcodec.inspect(args.tileset / index["root"]["content"]["uri"]).to_json()["metadata"].get("up")
    cam, target = default_camera(index, up)
    cam = cam if args.cam is None else args.cam
    target = target if args.target is None else args.target
    front, behind = sides(tiles, cam, target)
    state = visit(args.tileset.resolve(), cam, target, up, args)
    result = {"camera": {"position": cam.tolist(), "target": target.tolist(), "up": up},
              "kbps": args.kbps, **summary(state, tiles, front, behind, index_path.stat().st_size)}
    print(json.dumps(result, indent=1))
    if args.json:
        args.json.write_text(json.dumps(result, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
