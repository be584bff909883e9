"""The loaders web developers add .spc with (web/loaders/), in their example pages, in Chromium.

Each page must show the scene upright, draw what PlayCanvas draws for the decoded PLY from the same
camera, and report a corrupt file in one message instead of hanging. They skip, saying why, where
node, the npm packages (``npm ci`` in web/, web/viewer/ and web/examples/) or Chromium are missing.
"""

from __future__ import annotations

import urllib.parse
from pathlib import Path

import numpy as np
import pytest

import spcodec
from spcodec.cli import main
from spcodec.tiling.tileset import read_tileset

from viewer_harness import WEB, drive, missing_tools, page_url, serving, tile_with_one_thread

pytestmark = pytest.mark.browser

EXAMPLES = WEB / "examples"
SAME_RENDERER_DB = 45.0
"""Two renders of the same Gaussians by the same renderer from the same camera agree beyond this."""
CROSS_RENDERER_DB = 30.0
"""Spark against PlayCanvas on the same Gaussians and camera: the renderers differ (low-pass,
sorting, precision; 38.8 dB measured), so only the same scene in the same pose scores this high."""


def require(*packages: str) -> None:
    reason = missing_tools(True)
    for package in packages:
        if reason is None and not (EXAMPLES / "node_modules" / package).is_dir():
            reason = f"npm package {package} is not installed: run 'npm ci' in web/examples"
    if reason:
        pytest.skip(reason)


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """A z-up scene (so that upright is not the default) as .spc, decoded PLY and embedded .glb."""
    require("playcanvas")
    from spcodec.synthetic import make_scene

    folder = tmp_path_factory.mktemp("loaders")
    ply = folder / "source.ply"
    spcodec.write_ply(ply, make_scene(seed=6, curves=6, per_curve=250, blobs=3000).cloud)
    spc, decoded, glb = folder / "scene.spc", folder / "decoded.ply", folder / "embedded.glb"
    assert main(["encode", str(ply), "-o", str(spc), "--no-retrain", "--up=+z", "--quiet"]) == 0
    assert main(["decode", str(spc), "-o", str(decoded)]) == 0
    assert main(["embed", str(spc), "-o", str(glb)]) == 0
    bad = folder / "corrupt.spc"
    data = bytearray(spc.read_bytes())
    data[spcodec.inspect(spc).to_json()["layers"][1]["end_offset"] - 10] ^= 0xFF
    bad.write_bytes(bytes(data))
    return {"spc": spc, "ply": decoded, "glb": glb, "bad": bad}


def example_url(base: str, page: str, scene: Path, camera: dict | None = None, **extra) -> str:
    query = {"src": f"/scenes/{scene.name}", "width": 320, "height": 240, "capture": 1, **extra}
    if camera:
        query.update(cam=",".join(map(repr, camera["position"])),
                     target=",".join(map(repr, camera["target"])), fov=camera["fov"])
    return f"{base}/examples/{page}?{urllib.parse.urlencode(query)}"


def shoot(url: str, path: Path) -> dict:
    report = drive([{"url": url, "captures": [{"when": "complete", "path": str(path)}],
                     "timeoutMs": 120000}])[0]
    assert report["error"] is None, (report["error"], report["console"][-5:])
    return report["state"]


def image(path: Path) -> np.ndarray:
    from spcodec.imaging.images import read_image
    return read_image(path)


def psnr(a: Path, b: Path) -> float:
    from spcodec.imaging.metrics import psnr as metric
    return metric(image(a), image(b))


def lit(path: Path) -> float:
    return float((image(path).max(axis=2) > 0.02).mean())


def test_playcanvas_loader_draws_the_decoded_scene_upright_streamed_as_asset_and_embedded(
        files, tmp_path):
    with serving([files["spc"], files["ply"], files["glb"]]) as base:
        streamed = shoot(example_url(base, "playcanvas.html", files["spc"]), tmp_path / "s.png")
        camera = streamed["camera"]
        as_asset = shoot(example_url(base, "playcanvas.html", files["spc"], camera, mode="asset"),
                         tmp_path / "a.png")
        embedded = shoot(example_url(base, "playcanvas.html", files["glb"], camera),
                         tmp_path / "g.png")
        # PlayCanvas's own PLY loader, told the PLY is z-up, and taken as -y up (the default)
        told = shoot(page_url(base, files["ply"], camera=camera, up="+z"), tmp_path / "p.png")
        upside = shoot(page_url(base, files["ply"], camera=camera), tmp_path / "d.png")
    count = len(spcodec.decode(files["spc"]))
    assert streamed["gaussians"] == as_asset["gaussians"] == embedded["gaussians"] == count
    assert streamed["layersShown"] == len(spcodec.inspect(files["spc"]).to_json()["layers"])
    assert told["sceneUp"] == "+z" and upside["sceneUp"] == "-y"
    assert lit(tmp_path / "p.png") > 0.02
    for shot in ("s.png", "a.png", "g.png"):
        assert psnr(tmp_path / "p.png", tmp_path / shot) >= SAME_RENDERER_DB, shot
    assert psnr(tmp_path / "d.png", tmp_path / "s.png") < 25  # so "upright" is not an accident


def test_playcanvas_loader_reports_a_corrupt_file_once(files, tmp_path):
    with serving([files["bad"]]) as base:
        report = drive([{"url": example_url(base, "playcanvas.html", files["bad"]),
                         "captures": [{"when": "complete"}], "timeoutMs": 60000}])[0]
    state = report["state"]
    assert state["status"] == "error" and "section-crc" in state["error"]["message"]
    assert state["error"]["message"].count("section-crc") == 1


def test_spark_loader_draws_the_decoded_scene_upright_streamed_and_embedded(files, tmp_path):
    """Spark draws from the arrays the loader packs for it what it draws from the decoded PLY
    through its own PLY reader, and the same scene, upright, as PlayCanvas draws it (two
    renderers: a looser bound, far above an upside-down picture)."""
    require("playcanvas", "three", "@sparkjsdev/spark")
    with serving([files["spc"], files["ply"], files["glb"]]) as base:
        streamed = shoot(example_url(base, "spark.html", files["spc"]), tmp_path / "s.png")
        camera = streamed["camera"]
        embedded = shoot(example_url(base, "spark.html", files["glb"], camera), tmp_path / "g.png")
        spark_ply = shoot(example_url(base, "spark.html", files["ply"], camera, ply=1, up="+z"),
                          tmp_path / "p.png")
        playcanvas = shoot(page_url(base, files["ply"], camera=camera, up="+z"),
                           tmp_path / "pc.png")
        upside = shoot(page_url(base, files["ply"], camera=camera), tmp_path / "pcd.png")
    count = len(spcodec.decode(files["spc"]))
    assert streamed["gaussians"] == embedded["gaussians"] == spark_ply["gaussians"] == count
    assert playcanvas["sceneUp"] == "+z" and upside["sceneUp"] == "-y"
    assert lit(tmp_path / "s.png") > 0.02
    assert psnr(tmp_path / "p.png", tmp_path / "s.png") >= SAME_RENDERER_DB
    assert psnr(tmp_path / "p.png", tmp_path / "g.png") >= SAME_RENDERER_DB
    across = psnr(tmp_path / "pc.png", tmp_path / "s.png")
    assert across >= CROSS_RENDERER_DB, across
    assert psnr(tmp_path / "pcd.png", tmp_path / "s.png") < across - 5


def test_spark_loader_reports_a_corrupt_file_once(files, tmp_path):
    require("playcanvas", "three", "@sparkjsdev/spark")
    with serving([files["bad"]]) as base:
        report = drive([{"url": example_url(base, "spark.html", files["bad"]),
                         "captures": [{"when": "complete"}], "timeoutMs": 60000}])[0]
    state = report["state"]
    assert state["status"] == "error" and state["error"]["message"].count("section-crc") == 1


@pytest.fixture(scope="module")
def tileset(tmp_path_factory) -> Path:
    """A tileset (branching 4, two levels below the root) of a synthetic scene, 256 Gaussians
    a leaf: more Gaussians in all than the budget the pages are given."""
    require("playcanvas", "three", "@sparkjsdev/spark")
    from spcodec.synthetic import make_scene

    folder = tmp_path_factory.mktemp("loader-tiles")
    spcodec.write_ply(folder / "scene.ply", make_scene(seed=4, curves=4, per_curve=200, blobs=3300).cloud)
    return tile_with_one_thread(folder / "scene.ply", folder / "tiles", leaf_size=256, branching=4)


def test_both_loaders_stream_a_tileset_by_view_and_draw_the_same_tiles(tileset, tmp_path):
    """The example pages stream a tileset.json through loadTileset into real Spark and PlayCanvas:
    within the budget, the whole scene covered, refined past the root, and, from the same
    camera, the same tiles in both, which the two renderers draw alike."""
    index = read_tileset(tileset)
    total = sum(t["gaussians"] for t in tile_counts(index["root"]))
    budget = total // 6  # room for the root's children and a little more, not for the tileset
    query = {"src": f"/scenes/{tileset.name}/tileset.json", "width": 320, "height": 240, "capture": 1,
             "budget": budget, "sse": 4}
    with serving([tileset]) as base:
        spark = shoot_tileset(f"{base}/examples/spark.html?{urllib.parse.urlencode(query)}",
                              tmp_path / "spark.png")
        camera = spark["camera"]
        query.update(cam=",".join(map(repr, camera["position"])),
                     target=",".join(map(repr, camera["target"])), fov=camera["fov"])
        playcanvas = shoot_tileset(f"{base}/examples/playcanvas.html?{urllib.parse.urlencode(query)}",
                                   tmp_path / "playcanvas.png")
    root = index["root"]["content"]["uri"]
    for state in (spark, playcanvas):
        assert state["covers"] is True
        assert 0 < state["gaussians"] <= budget < total
        assert root not in state["tilesShown"], "refined past the root"
    assert spark["tilesShown"] == playcanvas["tilesShown"]
    assert spark["gaussians"] == playcanvas["gaussians"]
    across = psnr(tmp_path / "playcanvas.png", tmp_path / "spark.png")
    print(f"\n{len(spark['tilesShown'])} tiles, {spark['gaussians']} of {total} Gaussians (budget "
          f"{budget}); Spark against PlayCanvas {across:.1f} dB, {lit(tmp_path / 'spark.png'):.0%} lit")
    assert lit(tmp_path / "spark.png") > 0.02
    assert across >= CROSS_RENDERER_DB


def tile_counts(tile: dict) -> list[dict]:
    """Every tile's ``extras.spcodec`` below and including ``tile``."""
    return [tile["extras"]["spcodec"], *(t for child in tile.get("children", []) for t in tile_counts(child))]


def shoot_tileset(url: str, path: Path) -> dict:
    report = drive([{"url": url, "captures": [{"when": "complete", "path": str(path)}],
                     "timeoutMs": 120000}])[0]
    assert report["error"] is None, (report["error"], report["console"][-5:])
    assert report["state"]["status"] == "complete", report["state"]
    return report["state"]
