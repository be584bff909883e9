"""Running the web viewer in headless Chromium from Python (browser tests and bench_viewer.py).

The page is served by :mod:`spcodec.cli.server` in a thread; ``web/viewer/test/drive.mjs`` (node +
playwright-core) visits it and reports the page's progress state and the canvas as PNGs; the
callers judge them. :func:`missing_tools` says why this cannot run here (no node, no npm packages,
no chromium, no JavaScript decoder), so tests can skip with that reason.
"""

from __future__ import annotations

import base64
import contextlib
import io
import json
import os
import shutil
import subprocess
import threading
import urllib.parse
from pathlib import Path
from typing import Iterator, Sequence

import numpy as np

from spcodec.cli.server import SCENE_PREFIX, VIEWER_PAGE, make_server

REPO = Path(__file__).resolve().parents[1]
WEB = REPO / "web"
VIEWER = WEB / "viewer"
DRIVER = VIEWER / "test" / "drive.mjs"


def chromium_path() -> str:
    return os.environ.get("SPCODEC_CHROMIUM", "/usr/bin/chromium")


def missing_tools(needs_decoder: bool = True) -> str | None:
    """Why the browser tests cannot run here, or None when they can."""
    if shutil.which("node") is None:
        return "node is not installed"
    for package in ("playcanvas", "playwright-core"):
        if not (VIEWER / "node_modules" / package).is_dir():
            return f"npm package {package} is not installed: run 'npm ci' in web/viewer"
    if not Path(chromium_path()).exists():
        return f"no Chromium at {chromium_path()}: apt-get install chromium (or set SPCODEC_CHROMIUM)"
    if needs_decoder:
        if not (WEB / "src" / "index.js").is_file():
            return "the JavaScript decoder (web/src/index.js) is not in this tree"
        if not (WEB / "node_modules" / "fflate").is_dir():
            return "the JavaScript decoder's npm packages are not installed: run 'npm ci' in web"
    return None


@contextlib.contextmanager
def serving(scenes: Sequence[Path], throttle_kbps: float | None = None) -> Iterator[str]:
    """Serve ``scenes`` and the web folder on a free loopback port; yields the base URL."""
    server = make_server(list(scenes), port=0, throttle_kbps=throttle_kbps, web_root=WEB)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        host, port = server.server_address[:2]
        yield f"http://{host}:{port}"
    finally:
        server.shutdown()
        server.server_close()


def page_url(base: str, scene: Path, width: int = 320, height: int = 240,
             camera: dict | None = None, **extra) -> str:
    """The viewer's URL for ``scene`` (served under its file name), canvas only (no overlay)."""
    query = {"src": SCENE_PREFIX + scene.name, "width": width, "height": height, "capture": 1}
    if camera:  # the page's world is +Y up: a camera is its position, target and field of view
        query.update(cam=_joined(camera["position"]), target=_joined(camera["target"]),
                     fov=camera["fov"])
    query.update(extra)
    return f"{base}{VIEWER_PAGE}?{urllib.parse.urlencode(query)}"


def _joined(values: Sequence[float]) -> str:
    return ",".join(repr(float(v)) for v in values)


def drive(visits: list[dict], timeout: float = 300.0) -> list[dict]:
    """Run the driver on ``visits`` (see drive.mjs) and return its per-visit reports."""
    done = subprocess.run(["node", str(DRIVER)], input=json.dumps({"visits": visits}),
                          capture_output=True, text=True, timeout=timeout, cwd=VIEWER)
    if done.returncode != 0:
        raise RuntimeError(f"drive.mjs failed ({done.returncode}): {done.stderr.strip()[-2000:]}")
    return json.loads(done.stdout)["visits"]


LAYER_PICTURES = "window.spcViewerLayerPictures ?? []"
"""A visit's ``evaluate`` that returns the frames a page opened with ``layerPictures=1`` kept."""


def layer_pictures(report: dict) -> list[dict]:
    """The frames of a visit that evaluated :data:`LAYER_PICTURES`, one per non-empty layer shown:
    its fields, with ``image`` (float RGB in [0, 1]) in place of the PNG data URL."""
    from spcodec.imaging.images import read_image

    pictures = []
    for entry in report["value"] or []:
        png = base64.b64decode(entry.pop("png").split(",", 1)[1])
        pictures.append({**entry, "image": read_image(io.BytesIO(png))})  # PIL reads a buffer too
    return pictures


def tile_with_one_thread(ply: Path, out: Path, leaf_size: int, branching: int,
                         index_levels: int | None = None) -> Path:
    """``ply`` tiled into ``out`` on this process (no workers) at one torch thread, restored
    after: the browser tests' tilesets, built the way the CPU encodes fastest here. Their nodes
    of a few hundred Gaussians keep the preset's shapes: the precision search's fixed cost per
    inner node would be most of the build, and these tests are about streaming, not pictures."""
    import torch

    from spcodec.tiling import TilingConfig, build_tileset

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        build_tileset(ply, out, TilingConfig(leaf_size=leaf_size, branching=branching, workers=0,
                                             precision_search="none", index_levels=index_levels))
    finally:
        torch.set_num_threads(threads)
    return out


def tileset_tiles(index: dict) -> dict[str, dict]:
    """Every tile of a tileset.json by content URI: its box's corners (``lo``, ``hi``; the box's
    axes are the scene's, as the tiler writes them), whether it is a ``leaf``, its ``gaussians``.
    Callers judge a page's order of arrivals by these boxes, not by the page's own classes."""
    out: dict[str, dict] = {}
    stack = [index["root"]]
    while stack:
        tile = stack.pop()
        box = tile["boundingVolume"]["box"]
        centre, half = np.array(box[:3]), np.abs(np.reshape(box[3:], (3, 3))).sum(axis=0)
        out[tile["content"]["uri"]] = {"lo": centre - half, "hi": centre + half,
                                       "leaf": not tile.get("children"),
                                       "gaussians": tile["extras"]["spcodec"]["gaussians"]}
        stack.extend(tile.get("children", []))
    return out
