"""The streaming viewer in headless Chromium: time to first picture against time to the full scene
on a throttled link, the JavaScript decoder's throughput there, and an .spc against a PLY from
request to a drawable PlayCanvas resource (issue "spcodec in the browser", benchmark).

For each scene (default fourth_st and guitar), encoded with ``spcodec encode X.ply -o X.spc
--no-retrain`` (cached in ``--work``) and decoded to ``X.decoded.ply`` (the same Gaussians as a
PLY):

1. **Streaming** (``spcodec serve``'s pacing at ``--kbps``, default 20,000 kbit/s = 20 Mbit/s):
   the viewer page opens the .spc; the page records when the first non-empty layer is on screen
   and when every layer is, with the bytes received by then. Times run from the viewer's first
   request for the scene (the engine is already up). ``--repeat`` visits, median reported. For
   reference, the page also opens the decoded PLY over the same link (PlayCanvas's PLY loader
   shows nothing before the whole file is in), at the camera the .spc visit chose; the PSNR of
   the first and of the full picture against the PLY's is reported (PNGs left in ``--work``).
   When bytes arrive faster than the renderer draws, the first frame can already hold later
   layers: the report says how many, and how many bytes had arrived by then.
2. **Decode throughput** in the page: ``decode(bytes)`` of the whole file, after one warm-up,
   ``--decode-repeat`` times; Gaussians per second from the median.
3. **Quality at every layer** at each of ``--layer-kbps`` (default 2, 20 and 100 Mbit/s): the
   page keeps the frame that showed each non-empty layer (``layerPictures=1``); each frame's PSNR
   against the finished picture of the same visit, with when it was shown, the bytes in by then
   and the layers it holds (at a fast link one frame can hold several).
4. **.spc vs PLY** (no throttle, loopback): request + decode + PlayCanvas resource for the .spc,
   against PlayCanvas's PLY loader for the decoded PLY (request + parse + the same resource),
   alternating ``--repeat`` times; medians and their ratio.

Rendering is WebGL 2 on SwiftShader (no GPU here), so "on screen" includes a software rasterizer's
sort and draw; the share of bytes at the first picture does not depend on it.

``--file SCENE=PATH`` judges a given .spc instead (a nested encode, say: ``spcodec encode X.ply
-o X.spc --nested``).

    python bench/bench_viewer.py [--scenes fourth_st guitar] [--kbps 20000] [--repeat 3]
                                 [--layer-kbps 2000 20000 100000] [--file guitar=/path/g.spc]
                                 [--work DIR] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests"))

from spcodec.imaging.images import read_image  # noqa: E402
from spcodec.imaging.metrics import psnr  # noqa: E402

from scenes import data_dir  # noqa: E402  bench/ is on sys.path
from viewer_harness import LAYER_PICTURES, drive, layer_pictures, missing_tools, page_url, serving  # noqa: E402

SCENES = {
    "fourth_st": "pdal_fourth_st_spz/fourth_st_inria.ply",
    "guitar": "playcanvas_biker_guitar/guitar_inria.ply",
}


def prepare(name: str, work: Path, given: Path | None = None) -> tuple[Path, Path]:
    """The scene's .spc (``given``, else the default encode without retraining, made once) and
    its decoded PLY."""
    source = data_dir() / SCENES[name]
    spc = given or work / f"{name}.spc"
    ply = work / f"{spc.stem}.decoded.ply"
    if given is None and not spc.exists():
        subprocess.run([sys.executable, "-m", "spcodec.cli", "encode", str(source), "-o", str(spc),
                        "--no-retrain", "--quiet"], check=True)
    if not ply.exists():
        subprocess.run([sys.executable, "-m", "spcodec.cli", "decode", str(spc), "-o", str(ply)],
                       check=True, stdout=subprocess.DEVNULL)
    return spc, ply


def layer_facts(spc: Path) -> dict:
    import spcodec

    info = spcodec.inspect(spc).to_json()
    first = next(layer for layer in info["layers"] if layer["gaussians"] > 0)
    return {"file_bytes": info["stored_size"], "gaussians": info["gaussians"],
            "layers": [(layer["gaussians"], layer["end_offset"]) for layer in info["layers"]],
            "first_nonempty_layer": first["index"], "first_picture_bytes": first["end_offset"],
            "first_picture_share": first["end_offset"] / info["stored_size"]}


def streaming(spc: Path, ply: Path, kbps: float, repeat: int, shots: Path) -> dict:
    """Viewer visits over the paced link; the first one saves its first and its full picture,
    and the PLY visit (same camera) its picture, as PNGs in ``shots``."""
    first, full, reference_png = (shots / f"{spc.stem}.{what}.png" for what in ("first", "full", "ply"))
    captures = [{"when": "firstPicture", "path": str(first)}, {"when": "complete", "path": str(full)}]
    with serving([spc, ply], throttle_kbps=kbps) as base:
        visits = drive([{"url": page_url(base, spc, 480, 360), "timeoutMs": 600_000,
                         "captures": captures if i == 0 else [{"when": "complete"}]}
                        for i in range(repeat)], timeout=3600)
        camera = visits[0]["state"]["camera"]
        reference = drive([{"url": page_url(base, ply, 480, 360, camera=camera), "timeoutMs": 600_000,
                            "captures": [{"when": "complete", "path": str(reference_png)}]}],
                          timeout=3600)[0]
    for report in [*visits, reference]:
        if report["error"]:
            raise RuntimeError(report["error"])
    states = [v["state"] for v in visits]
    first_decoded = [next(e["tDecoded"] for e in s["events"] if e["gaussians"] > 0) for s in states]
    return {
        "first_layer_decoded_s": statistics.median(first_decoded) / 1000,
        "first_picture_s": statistics.median(s["tFirstPicture"] for s in states) / 1000,
        "full_scene_s": statistics.median(s["tComplete"] for s in states) / 1000,
        "bytes_at_first_picture": states[0]["bytesAtFirstPicture"],
        "layers_in_first_picture": [s["layersInFirstPicture"] for s in states],
        "bytes_when_first_picture_shown": [s["bytesWhenFirstPictureShown"] for s in states],
        "bytes_total": states[0]["totalBytes"],
        "runs": [(s["tFirstPicture"] / 1000, s["tComplete"] / 1000) for s in states],
        "camera": camera,
        "ply_picture_s": reference["state"]["tComplete"] / 1000,
        "ply_bytes": reference["state"]["bytesLoaded"],
        "full_vs_ply_psnr_db": psnr(read_image(reference_png), read_image(full)),
        "first_frame_vs_ply_psnr_db": psnr(read_image(reference_png), read_image(first)),
    }


def distinct(pictures: list[dict]) -> list[dict]:
    """The first frame for each set of layers: when bytes come faster than frames, the frame
    that showed layer k may already hold k+1, and the one for k+1 then shows nothing new."""
    kept = []
    for picture in pictures:
        if not kept or picture["layersInPicture"] > kept[-1]["layersInPicture"]:
            kept.append(picture)
    return kept


def layer_by_layer(spc: Path, rates_kbps: list[float], camera: dict) -> list[dict]:
    """At each link speed, every frame that showed a new layer, judged against the visit's
    finished picture (same camera, so the difference is the layers still to come)."""
    runs = []
    for kbps in rates_kbps:
        with serving([spc], throttle_kbps=kbps) as base:
            report = drive([{"url": page_url(base, spc, 480, 360, camera=camera, layerPictures=1),
                             "timeoutMs": 600_000, "captures": [{"when": "complete"}],
                             "evaluate": LAYER_PICTURES}], timeout=3600)[0]
        if report["error"]:
            raise RuntimeError(report["error"])
        pictures = distinct(layer_pictures(report))
        final, total = pictures[-1], report["state"]["totalBytes"]
        rows = [{"layer": p["layer"], "layers_in_picture": p["layersInPicture"],
                 "bytes": p["bytesLoaded"], "share": p["bytesLoaded"] / total,
                 "shown_s": p["tShown"] / 1000,
                 "psnr_vs_full_db": None if p is final else psnr(final["image"], p["image"])}
                for p in pictures]
        runs.append({"kbps": kbps, "frames": rows})
    return runs


def in_page(spc: Path, ply: Path, repeat: int, decode_repeat: int) -> dict:
    with serving([spc, ply]) as base:
        bench = f"{base}/viewer/bench.html"
        script = f"""(async () => {{
          const b = window.spcBench;
          const decode = await b.decodeTimes('/scenes/{spc.name}', {decode_repeat});
          const spc = [], ply = [];
          for (let i = 0; i < {repeat}; i++) {{
            spc.push(await b.spcToResource('/scenes/{spc.name}'));
            ply.push((await b.plyToResource('/scenes/{ply.name}')).ms);
          }}
          return {{ decode, spc, ply, renderer: b.renderer }};
        }})()"""
        report = drive([{"url": bench, "captures": [], "evaluate": script,
                         "waitFor": "window.spcBenchReady === true", "timeoutMs": 600_000}],
                       timeout=3600)[0]
    if report["error"]:
        raise RuntimeError(report["error"] + "\n" + "\n".join(report["console"][-5:]))
    value = report["value"]
    decode_ms = statistics.median(value["decode"]["times"])
    spc_ms = statistics.median(run["ms"] for run in value["spc"])
    ply_ms = statistics.median(value["ply"])
    phases = {phase: statistics.median(run[phase] for run in value["spc"])
              for phase in ("fetchMs", "decodeMs", "convertMs", "resourceMs")}
    return {"decode_ms": decode_ms,
            "gaussians_per_s": value["decode"]["gaussians"] / (decode_ms / 1000),
            "spc_to_resource_ms": spc_ms, "ply_to_resource_ms": ply_ms,
            "ply_over_spc": ply_ms / spc_ms, "spc_phases_ms": phases, "renderer": value["renderer"],
            "spc_runs_ms": [run["ms"] for run in value["spc"]], "ply_runs_ms": value["ply"]}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenes", nargs="+", default=list(SCENES), choices=list(SCENES))
    parser.add_argument("--kbps", type=float, default=20_000, help="link speed in kbit/s")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--decode-repeat", type=int, default=5)
    parser.add_argument("--layer-kbps", type=float, nargs="+", default=[2_000, 20_000, 100_000],
                        help="link speeds for the picture at every layer, kbit/s")
    parser.add_argument("--file", action="append", default=[], metavar="SCENE=PATH",
                        help="judge this .spc for SCENE instead of the default encode")
    parser.add_argument("--work", type=Path, default=Path("/tmp/spcodec-bench-viewer"))
    parser.add_argument("--json", type=Path, help="also write the results here")
    args = parser.parse_args()
    problem = missing_tools()
    if problem:
        print(f"cannot run: {problem}", file=sys.stderr)
        return 1
    given = dict(entry.split("=", 1) for entry in args.file)
    if not set(given) <= set(SCENES):
        parser.error(f"--file names a scene that is not one of {', '.join(SCENES)}")
    args.work.mkdir(parents=True, exist_ok=True)
    results = {"kbps": args.kbps, "date": time.strftime("%Y-%m-%d"), "scenes": {}}
    for name in args.scenes:
        spc, ply = prepare(name, args.work, Path(given[name]) if name in given else None)
        stream = streaming(spc, ply, args.kbps, args.repeat, args.work)
        row = {"file": str(spc), **layer_facts(spc), **stream,
               "layer_by_layer": layer_by_layer(spc, args.layer_kbps, stream["camera"]),
               **in_page(spc, ply, args.repeat, args.decode_repeat)}
        results["scenes"][name] = row
        print(f"{name}: {row['gaussians']:,} Gaussians, {row['file_bytes']:,} bytes; first picture "
              f"(layer {row['first_nonempty_layer']}) after {row['bytes_at_first_picture']:,} bytes "
              f"({100 * row['first_picture_share']:.1f} %): decoded at {row['first_layer_decoded_s']:.2f} s, "
              f"on screen at {row['first_picture_s']:.2f} s; "
              f"full scene {row['full_scene_s']:.2f} s; PLY {row['ply_bytes']:,} bytes shown at "
              f"{row['ply_picture_s']:.2f} s; PSNR against the PLY's render: full "
              f"{row['full_vs_ply_psnr_db']:.1f} dB, first frame {row['first_frame_vs_ply_psnr_db']:.1f} dB "
              f"(layers in it: {row['layers_in_first_picture']}, bytes in by then: "
              f"{row['bytes_when_first_picture_shown']})", flush=True)
        for run in row["layer_by_layer"]:
            print(f"  at {run['kbps'] / 1000:g} Mbit/s: " + "; ".join(
                f"L0-{f['layers_in_picture'] - 1} {f['shown_s']:.2f} s "
                f"{f['share']:.0%} " + ("full" if f["psnr_vs_full_db"] is None
                                         else f"{f['psnr_vs_full_db']:.1f} dB")
                for f in run["frames"]), flush=True)
        print(f"  decode {row['decode_ms']:.0f} ms = {row['gaussians_per_s'] / 1e6:.2f} M Gaussians/s; "
              f"to a PlayCanvas resource: .spc {row['spc_to_resource_ms']:.0f} ms, PLY "
              f"{row['ply_to_resource_ms']:.0f} ms (PLY / spc {row['ply_over_spc']:.2f}x); .spc phases "
              + ", ".join(f"{k[:-2]} {v:.0f}" for k, v in row["spc_phases_ms"].items()) + " ms", flush=True)
    if args.json:
        args.json.write_text(json.dumps(results, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
