"""The streaming viewer (web/viewer) in headless Chromium, against our own decoder's output.

The page streams an .spc with range requests from ``spcodec serve`` and renders each layer with
PlayCanvas's GSplat component. These tests check that it shows layer 0 and then every layer, that
the picture is not blank, that its full-file render matches PlayCanvas rendering the PLY that
``spcodec decode`` writes (and the .glb, through PlayCanvas's glTF loader) at the same camera, that
a throttled connection shows layer 0 long before the file has arrived, and that a corrupt file is
reported with its spec error code. They skip, saying why, where node, the npm packages or Chromium
are missing (``.ci/run`` installs them when it can).
"""

from __future__ import annotations

import dataclasses
import json
import shutil
import subprocess

import numpy as np
import pytest

import spcodec
from spcodec.cli import main

from viewer_harness import LAYER_PICTURES, VIEWER, drive, layer_pictures, missing_tools, page_url, serving

pytestmark = pytest.mark.browser

PSNR_FLOOR_DB = 45.0


def require(needs_decoder: bool = True) -> None:
    reason = missing_tools(needs_decoder)
    if reason:
        pytest.skip(reason)


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    """A small structured scene, encoded by our encoder (a sketch of curves and three patch layers
    of blobs), with its decoded PLY and GLB beside it."""
    require()
    from spcodec.encoder.config import EncoderConfig
    from spcodec.encoder.pipeline import encode
    from spcodec.synthetic import make_scene

    folder = tmp_path_factory.mktemp("viewer")
    spc = folder / "scene.spc"
    spc.write_bytes(encode(make_scene(seed=1, curves=8, per_curve=300, blobs=4000).cloud,
                           EncoderConfig(n_jobs=1, seed=0)).data)
    for suffix in (".ply", ".glb"):
        assert main(["decode", str(spc), "-o", str(spc.with_suffix(suffix))]) == 0
    info = spcodec.inspect(spc).to_json()
    assert len(info["layers"]) >= 3 and info["layers"][0]["gaussians"] > 0
    return spc, info


def image(path) -> np.ndarray:
    from spcodec.imaging.images import read_image
    return read_image(path)


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    from spcodec.imaging.metrics import psnr as metric
    return metric(a, b)


def lit_share(picture: np.ndarray) -> float:
    """Fraction of pixels that are not (nearly) the black background."""
    return float((picture.max(axis=2) > 0.02).mean())


def visit(url: str, *captures: tuple[str, object]) -> dict:
    report = drive([{"url": url, "captures": [{"when": w, "path": str(p) if p else None}
                                              for w, p in captures]}])[0]
    assert report["error"] is None, (report["error"], report["console"][-5:])
    return report


def test_viewer_unit_tests_pass_under_node():
    """The page's range loader and array layout, under node alone (no browser, no packages)."""
    if shutil.which("node") is None:
        pytest.skip("node is not installed")
    done = subprocess.run(["node", "--test", *sorted(str(p) for p in (VIEWER / "test").glob("*.test.mjs"))],
                          capture_output=True, text=True, timeout=300, cwd=VIEWER)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-2000:]


def khronos_validation(path) -> dict:
    done = subprocess.run(["node", str(VIEWER / "test" / "validate-gltf.mjs"), str(path)],
                          capture_output=True, text=True, timeout=120, cwd=VIEWER)
    assert done.returncode == 0, done.stderr[-2000:]
    return json.loads(done.stdout)["issues"]


def test_glb_passes_the_khronos_validator(tmp_path):
    """Everything but the extension itself, which the released validator predates, validates; a
    wrong POSITION bound is caught, so the check can fail."""
    if shutil.which("node") is None or not (VIEWER / "node_modules" / "gltf-validator").is_dir():
        pytest.skip("node or the gltf-validator package (npm ci in web/viewer) is missing")
    from spcodec.gltf import EXTENSION, glb_bytes
    from spcodec.synthetic import make_scene

    cloud = make_scene(seed=2, curves=2, per_curve=50, blobs=200).cloud
    good = tmp_path / "good.glb"
    good.write_bytes(glb_bytes(cloud))
    issues = khronos_validation(good)
    unknown_names = [m for m in issues["messages"] if m["code"] == "MESH_PRIMITIVE_INVALID_ATTRIBUTE"]
    assert len(unknown_names) == issues["numErrors"] == 3 + (cloud.sh_degree + 1) ** 2  # not POSITION
    assert all(f"/attributes/{EXTENSION}:" in m["pointer"] for m in unknown_names)
    assert {m["code"] for m in issues["messages"]} <= {"MESH_PRIMITIVE_INVALID_ATTRIBUTE",
                                                       "UNSUPPORTED_EXTENSION"}
    data = bytearray(good.read_bytes())
    at = data.index(b'"min":[') + len(b'"min":[')
    data[at:at + 1] = b"9" if data[at:at + 1] != b"9" else b"8"  # a wrong lower bound
    bad = tmp_path / "bad.glb"
    bad.write_bytes(bytes(data))
    assert "ACCESSOR_MIN_MISMATCH" in {m["code"] for m in khronos_validation(bad)["messages"]}


def test_page_shows_layer_0_then_every_layer(scene, tmp_path):
    spc, info = scene
    with serving([spc]) as base:
        report = visit(page_url(base, spc), ("layers:1", None), ("complete", tmp_path / "all.png"))
        camera = report["state"]["camera"]
        sketch_only = visit(page_url(base, spc, camera=camera, maxLayer=0),
                            ("complete", tmp_path / "l0.png"))
    first, final = report["captures"][0]["state"], report["state"]
    layers = info["layers"]
    assert first["layersShown"] >= 1 and first["events"][0]["gaussians"] == layers[0]["gaussians"]
    assert final["status"] == "complete" and final["mode"] == "ranges"
    assert final["layerCount"] == final["layersShown"] == len(layers)
    events = final["events"]
    assert [e["index"] for e in events] == list(range(len(layers)))
    assert [e["gaussians"] for e in events] == [layer["gaussians"] for layer in layers]
    shown = [e["tShown"] for e in events]
    assert shown == sorted(shown) and all(e["tDecoded"] <= e["tShown"] for e in events)
    assert final["gaussians"] == info["gaussians"]
    assert final["bytesLoaded"] == final["totalBytes"] == spc.stat().st_size
    # after the header request, one range request per layer, each ending at a layer boundary
    ranges = [(r["first"], r["last"], r["status"]) for r in final["requests"]]
    assert all(status == 206 for _, _, status in ranges)
    ends = [layer["end_offset"] for layer in layers]
    assert [last + 1 for _, last, _ in ranges[-len(layers):]] == ends
    # maxLayer=0 fetches the sketch alone; it is a picture, and the whole scene adds to it
    alone = sketch_only["state"]
    assert alone["layersShown"] == 1 and alone["gaussians"] == layers[0]["gaussians"]
    assert alone["bytesLoaded"] == layers[0]["end_offset"]
    sketch, whole = image(tmp_path / "l0.png"), image(tmp_path / "all.png")
    assert lit_share(sketch) > 0.005 and lit_share(whole) > 0.05
    assert lit_share(whole) > 2 * lit_share(sketch)


def test_full_render_matches_playcanvas_rendering_our_ply_and_glb(scene, tmp_path):
    spc, _ = scene
    ply, glb = spc.with_suffix(".ply"), spc.with_suffix(".glb")
    with serving([spc, ply, glb]) as base:
        reference = visit(page_url(base, ply), ("complete", tmp_path / "ply.png"))
        camera = reference["state"]["camera"]
        ours = visit(page_url(base, spc, camera=camera), ("complete", tmp_path / "spc.png"))
        gltf = visit(page_url(base, glb, camera=camera), ("complete", tmp_path / "glb.png"))
    assert reference["state"]["gaussians"] == ours["state"]["gaussians"] == \
        gltf["state"]["gaussians"] == len(spcodec.decode(spc))
    assert ours["state"]["camera"] == camera == gltf["state"]["camera"]
    ply_image = image(tmp_path / "ply.png")
    assert lit_share(ply_image) > 0.05
    assert psnr(ply_image, image(tmp_path / "spc.png")) >= PSNR_FLOOR_DB
    assert psnr(ply_image, image(tmp_path / "glb.png")) >= PSNR_FLOOR_DB


def test_throttled_stream_shows_layer_0_before_the_file_arrives(scene, tmp_path):
    """At 160 kbit/s (20 kB/s) the file takes seconds; layer 0 must be on screen long before."""
    spc, info = scene
    size = spc.stat().st_size
    with serving([spc], throttle_kbps=160) as base:
        report = visit(page_url(base, spc), ("firstPicture", tmp_path / "first.png"),
                       ("complete", tmp_path / "all.png"))
    at_first, final = report["captures"][0]["state"], report["state"]
    layer0_end = info["layers"][0]["end_offset"]
    assert at_first["layersShown"] >= 1 and at_first["bytesAtFirstPicture"] == layer0_end
    assert at_first["bytesLoaded"] < size  # the rest of the file had not arrived yet
    assert final["tComplete"] >= 0.9 * size / 20_000 * 1000  # the throttle was in force
    assert final["tFirstPicture"] < final["tComplete"] / 2
    assert lit_share(image(tmp_path / "first.png")) > 0.005
    assert final["layersShown"] == len(info["layers"])


def test_the_page_keeps_the_frame_that_showed_each_layer(scene, tmp_path):
    """With ``layerPictures=1`` (the benchmark's quality at every layer) the page keeps one frame
    per non-empty layer shown, in order, each saying which layers it holds; the last is the
    finished picture, and each adds to the one before."""
    spc, info = scene
    with serving([spc], throttle_kbps=160) as base:
        report = drive([{"url": page_url(base, spc, layerPictures=1),
                         "captures": [{"when": "complete", "path": str(tmp_path / "all.png")}],
                         "evaluate": LAYER_PICTURES}])[0]
    assert report["error"] is None, (report["error"], report["console"][-5:])
    pictures = layer_pictures(report)
    nonempty = [layer["index"] for layer in info["layers"] if layer["gaussians"] > 0]
    shown = [p["layer"] for p in pictures]
    assert shown == sorted(set(shown)) and set(shown) <= set(nonempty) and shown[0] == nonempty[0]
    assert all(p["layersInPicture"] >= p["layer"] + 1 for p in pictures)
    assert pictures[-1]["layersInPicture"] == len(info["layers"])
    assert [p["tShown"] for p in pictures] == sorted(p["tShown"] for p in pictures)
    assert pictures[0]["bytesLoaded"] < spc.stat().st_size  # the throttle kept the rest away
    assert psnr(image(tmp_path / "all.png"), pictures[-1]["image"]) >= 60
    lit = [lit_share(p["image"]) for p in pictures]
    assert len(pictures) >= 2 and lit == sorted(lit) and lit[-1] > lit[0]
    assert psnr(pictures[-1]["image"], pictures[0]["image"]) < 40


def test_the_benchmark_page_decodes_and_builds_a_resource(scene):
    """bench/bench_viewer.py's in-page measurements (web/viewer/bench.html) load and run."""
    spc, info = scene
    script = f"""(async () => {{
      const b = window.spcBench;
      return {{ decode: await b.decodeTimes('/scenes/{spc.name}', 1),
                resource: await b.spcToResource('/scenes/{spc.name}') }};
    }})()"""
    with serving([spc]) as base:
        report = drive([{"url": f"{base}/viewer/bench.html", "captures": [], "evaluate": script,
                         "waitFor": "window.spcBenchReady === true", "timeoutMs": 60_000}])[0]
    assert report["error"] is None, (report["error"], report["console"][-5:])
    value = report["value"]
    assert value["decode"]["gaussians"] == value["resource"]["gaussians"] == info["gaussians"]
    assert len(value["decode"]["times"]) == 1 and value["resource"]["ms"] > 0


def test_gzip_wrapped_files_stream_too(scene, tmp_path):
    """With the wrapper's layer offsets ([R-83]) the page still fetches layer by layer; without
    them it reads one stream; either way every layer is shown."""
    import gzip

    from spcodec.codecs import gzip_wrap

    spc, info = scene
    inner = spc.read_bytes()
    marked, plain = tmp_path / "marked.spc", tmp_path / "plain.spc"
    marked.write_bytes(gzip_wrap(inner, [layer["end_offset"] for layer in info["layers"]]))
    plain.write_bytes(gzip.compress(inner))
    with serving([marked, plain]) as base:
        reports = drive([{"url": page_url(base, path), "captures": [{"when": "complete"}]}
                         for path in (marked, plain)])
    for report, mode, path in zip(reports, ("ranges", "stream"), (marked, plain)):
        assert report["error"] is None, report["error"]
        state = report["state"]
        assert state["mode"] == mode and state["layersShown"] == len(info["layers"])
        assert state["gaussians"] == info["gaussians"]
        assert state["bytesLoaded"] == state["totalBytes"] == path.stat().st_size
    # one request per layer ending at the wrapper's recorded offsets, then the gzip trailer
    ends = [layer["end_offset"] for layer in spcodec.inspect(marked).to_json()["layers"]]
    requested = [r["last"] + 1 for r in reports[0]["state"]["requests"]]
    assert requested[-len(ends) - 1:] == [*ends, marked.stat().st_size]


def test_corrupt_file_is_reported_with_its_error_code(scene, tmp_path):
    spc, info = scene
    data = bytearray(spc.read_bytes())
    data[info["layers"][1]["end_offset"] - 10] ^= 0xFF  # inside layer 1's last section
    bad = tmp_path / "bad.spc"
    bad.write_bytes(bytes(data))
    with serving([bad]) as base:
        report = drive([{"url": page_url(base, bad), "captures": [{"when": "complete"}],
                         "timeoutMs": 60000}])[0]
    state = report["state"]
    assert state["status"] == "error" and state["error"]["code"] == "section-crc"
    assert state["error"]["line"].count("section-crc") == 1  # it was shown twice
    assert state["layersDecoded"] == 1  # layer 0 was decoded (and shown) before the bad layer


def test_a_z_up_scene_stands_upright_from_the_axis_its_file_stores(tmp_path):
    """The viewer showed z-up scenes from underneath: the encoder's --up was not stored. Now an
    .spc made with --up=+z renders as its PLY does when told the PLY is z-up, and unlike the PLY
    taken as -y up (the default for files that do not say)."""
    require()
    from spcodec.synthetic import make_scene

    ply, spc, decoded = tmp_path / "z.ply", tmp_path / "z.spc", tmp_path / "z_decoded.ply"
    spcodec.write_ply(ply, make_scene(seed=4, curves=4, per_curve=200, blobs=2500).cloud)
    assert main(["encode", str(ply), "-o", str(spc), "--no-retrain", "--up=+z", "--quiet"]) == 0
    assert main(["decode", str(spc), "-o", str(decoded)]) == 0
    with serving([spc, decoded]) as base:
        ours = visit(page_url(base, spc), ("complete", tmp_path / "spc.png"))
        camera = ours["state"]["camera"]
        told = visit(page_url(base, decoded, camera=camera, up="+z"),
                     ("complete", tmp_path / "told.png"))
        default = visit(page_url(base, decoded, camera=camera), ("complete", tmp_path / "dflt.png"))
    assert ours["state"]["sceneUp"] == told["state"]["sceneUp"] == "+z"
    assert default["state"]["sceneUp"] == "-y"
    spc_image = image(tmp_path / "spc.png")
    assert lit_share(spc_image) > 0.02
    assert psnr(spc_image, image(tmp_path / "told.png")) >= PSNR_FLOOR_DB
    assert psnr(spc_image, image(tmp_path / "dflt.png")) < 25


def test_the_hud_says_what_the_encoder_measured_for_the_prefix_on_screen(scene, tmp_path):
    """A retrained encode stores each prefix's PSNR in the metadata (``stats.prefix_psnr``); the page
    shows the one for the layers on screen, and ignores a malformed table."""
    from spcodec.writer import WriteOptions, build_bitstream

    _, info = scene
    table = [{"layer": 1, "psnr": 24.5}, {"layer": 2, "psnr": 30.25},
             {"layer": len(info["layers"]) - 1, "psnr": 36.0}]
    from spcodec.encoder.config import EncoderConfig
    from spcodec.encoder.pipeline import encode
    from spcodec.synthetic import make_scene

    result = encode(make_scene(seed=1, curves=8, per_curve=300, blobs=4000).cloud,
                    EncoderConfig(n_jobs=1, seed=0))
    files = {}
    for name, stats in (("good", {"prefix_psnr": table}), ("bad", {"prefix_psnr": "36 dB"})):
        files[name] = tmp_path / f"{name}.spc"
        files[name].write_bytes(build_bitstream(dataclasses.replace(
            result.scene, metadata={**result.scene.metadata, "stats": stats}), WriteOptions()))
    with serving(list(files.values())) as base:
        whole = visit(page_url(base, files["good"]), ("complete", None))["state"]
        first = visit(page_url(base, files["good"], maxLayer=1), ("complete", None))["state"]
        bad = visit(page_url(base, files["bad"]), ("complete", None))["state"]
    assert whole["prefixPsnr"] == table
    assert whole["prefixLine"] == "this prefix: 36.0 dB of the file's 36.0 dB (encoder, training views)"
    assert first["prefixLine"] == "this prefix: 24.5 dB of the file's 36.0 dB (encoder, training views)"
    assert bad["status"] == "complete" and bad["prefixLine"] is None


def test_the_pages_ask_for_no_file_that_is_not_there(scene):
    """Every page logged a 404: the decoder's Draco loader probed ``draco3d/package.json`` at a URL
    where it is not served before the one where it is. The viewer (an .spc, whose sketch is Draco),
    its benchmark page and, where their packages are installed, the example pages now load with
    no failed request."""
    spc, _ = scene
    examples = VIEWER.parent / "examples"
    query = f"src=/scenes/{spc.name}&width=320&height=240&capture=1"
    with serving([spc]) as base:
        visits = [{"url": page_url(base, spc), "captures": [{"when": "complete"}]},
                  {"url": f"{base}/viewer/bench.html", "captures": [],
                   "waitFor": "window.spcBenchReady === true",
                   "evaluate": f"window.spcBench.decodeTimes('/scenes/{spc.name}', 1)"}]
        for page, package in (("playcanvas.html", "playcanvas"), ("spark.html", "@sparkjsdev/spark")):
            if (examples / "node_modules" / package).is_dir():
                visits.append({"url": f"{base}/examples/{page}?{query}", "captures": [{"when": "complete"}]})
        reports = drive(visits)
    for report in reports:
        assert report["error"] is None, (report["url"], report["error"], report["console"][-5:])
        # the range loader cancels a body it has read to the end of its layer (net::ERR_ABORTED,
        # nothing logged): not a failed request
        failed = [r for r in report["failedRequests"] if r.get("error") != "net::ERR_ABORTED"]
        assert failed == [], report["url"]
        assert not [line for line in report["console"] if "404" in line], report["url"]


def framed_share(camera: dict, points: np.ndarray, aspect: float) -> float:
    """The share of ``points`` (upright world) in front of ``camera`` and inside its picture
    (vertical field of view ``fov``, +Y up, ``aspect`` width over height)."""
    position, target = np.asarray(camera["position"]), np.asarray(camera["target"])
    forward = (target - position) / np.linalg.norm(target - position)
    right = np.cross(forward, [0.0, 1.0, 0.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    d = points - position
    depth = d @ forward
    half = np.tan(np.radians(camera["fov"]) / 2)
    inside = (depth > 0) & (np.abs(d @ up) <= half * depth) & (np.abs(d @ right) <= half * aspect * depth)
    return float(inside.mean())


def corner_scene(up: str = "+y"):
    """Layer 0 one small cluster in a corner of a 40-unit box that two patch layers fill."""
    from spcodec.synthetic import random_cluster, random_codebooks, random_patch_layer
    from spcodec.writer import EncodedScene

    rng = np.random.default_rng(7)
    books = random_codebooks(rng, 0)
    layers = [random_patch_layer(rng, books, 1500) for _ in range(2)]
    return EncodedScene(0, [random_cluster(rng, 0, points=200)], books, layers, {"up": up})


def test_the_default_camera_frames_the_whole_scene_not_only_layer_0(tmp_path):
    """The camera was framed on the first layer alone: a retrained guitar's 1,025 sketch Gaussians
    left its neck and headstock off-screen. Here layer 0 is one small cluster in a corner of a
    40-unit box that the patch layers fill; this file's metadata has no box of the scene (an older
    file), so the page frames layer 0 first and frames again as the layers reach out of the view:
    the finished page's camera shows nearly all of the scene (layer 0's camera, a sliver of it)."""
    require()
    from spcodec.writer import build_bitstream

    spc = tmp_path / "corner.spc"
    spc.write_bytes(build_bitstream(corner_scene()))  # the world is the file's frame: +y up
    assert "bounds" not in spcodec.inspect(spc).metadata
    points = spcodec.decode(spc).means
    layer0 = len(spcodec.decode(spc, max_layer=0).means)
    assert np.ptp(points[:layer0], axis=0).max() < 0.2 * np.ptp(points, axis=0).min()
    with serving([spc]) as base:
        final = visit(page_url(base, spc), ("complete", None))["state"]
        alone = visit(page_url(base, spc, maxLayer=0), ("complete", None))["state"]
    assert final["status"] == "complete" and final["gaussians"] == len(points)
    aspect = 320 / 240
    assert framed_share(alone["camera"], points, aspect) < 0.5  # layer 0's framing: a part
    assert framed_share(final["camera"], points, aspect) > 0.95
    assert final["cameraFramings"] >= 2 and final["framedOn"] == "centres"


@pytest.mark.parametrize("up", ["+y", "+z"])
def test_a_file_with_its_scene_box_is_framed_whole_from_layer_0_and_never_again(tmp_path, up):
    """The same corner scene written with the box of all its layers in its metadata (``bounds``, as
    ``spcodec encode`` writes it): the page frames the whole scene as soon as layer 0 is in, so
    layer 0 alone (``maxLayer=0``) already shows nearly all of it, and the later layers never move
    the camera: one framing, the same camera. A +z up file is framed in its upright world."""
    require()
    from spcodec.writer import WriteOptions, build_bitstream

    spc = tmp_path / "boxed.spc"
    spc.write_bytes(build_bitstream(corner_scene(up), WriteOptions(bounds=True)))
    assert "bounds" in spcodec.inspect(spc).metadata
    points = spcodec.decode(spc).means
    if up == "+z":  # the page's world: +Z turned to +Y (x, y, z) -> (x, z, -y)
        points = np.stack([points[:, 0], points[:, 2], -points[:, 1]], axis=1)
    with serving([spc]) as base:
        alone = visit(page_url(base, spc, maxLayer=0), ("complete", None))["state"]
        final = visit(page_url(base, spc), ("complete", None))["state"]
    aspect = 320 / 240
    assert alone["framedOn"] == final["framedOn"] == "bounds"
    assert framed_share(alone["camera"], points, aspect) > 0.95
    assert alone["cameraFramings"] == final["cameraFramings"] == 1
    assert final["layersShown"] == 3 and final["gaussians"] == len(points)
    assert np.allclose(final["camera"]["position"], alone["camera"]["position"])
