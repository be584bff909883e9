"""Decode throughput of the JavaScript decoder (web/) in Node, against the Python decoder, reading
the PLY in JavaScript, and SPZ's own JavaScript loader, on the same scenes, in one run (issue 13).

For each scene (fourth_st, guitar, biker from $SPCODEC_DATA) the .spc is made once with

    spcodec encode X.ply -o X.spc --no-retrain

(kept in --workdir), then, in --rounds interleaved rounds, each the best of --repeat runs from
memory:

* ``spcodec.decode`` (Python, the reference decoder);
* in one Node process (bench/web/decode_bench.mjs): the JS ``decode()``, the JS ``StreamDecoder``
  fed 64 KiB chunks, a JS reader of the scene's INRIA PLY into the same typed arrays, and SPZ's
  own loader (``@adobe/spz``, the WebAssembly build of the SPZ reference library; PlayCanvas's
  splat-transform reads SPZ through it) on the scene's own .spz where it has one, and the
  decoder's inflater against fflate's on the scene's zlib sections.

The best over rounds is reported. Needs ``npm ci`` in web/ and (for SPZ) in bench/web/.
``--extra LABEL=SCENE:FILE`` adds a given .spc of one of the scenes as a row of its own (say the
same scene with and without context-coded indices, bench/bench_contexts.py --keep), timed in the
same rounds.

    python bench/bench_web_decode.py [--repeat 10] [--rounds 3] [--workdir DIR] [--json OUT]
        [--extra LABEL=SCENE:FILE ...]
"""

from __future__ import annotations

import argparse
import json
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import spcodec

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "bench"))
from scenes import data_dir  # noqa: E402

SCENES = {  # name: (INRIA PLY, the scene's own SPZ or None)
    "fourth_st": ("pdal_fourth_st_spz/fourth_st_inria.ply", "pdal_fourth_st_spz/fourth_st.spz"),
    "guitar": ("playcanvas_biker_guitar/guitar_inria.ply", None),
    "biker": ("playcanvas_biker_guitar/biker_from_spz_inria.ply", "playcanvas_biker_guitar/biker.spz"),
}


def encode(ply: Path, out: Path) -> None:
    if out.exists():
        return
    cmd = ["spcodec", "encode", str(ply), "-o", str(out), "--no-retrain"]
    print("$", " ".join(cmd), flush=True)
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)


def python_decode_s(data: bytes, repeat: int) -> float:
    spcodec.decode(data)
    best = float("inf")
    for _ in range(repeat):
        start = time.perf_counter()
        spcodec.decode(data)
        best = min(best, time.perf_counter() - start)
    return best


def node_round(config: Path) -> dict:
    out = subprocess.run(["node", str(REPO / "bench" / "web" / "decode_bench.mjs"), str(config)],
                         check=True, capture_output=True, text=True)
    return json.loads(out.stdout)


def _cell(seconds: float, gaussians: int) -> str:
    """Milliseconds (millions of Gaussians per second)."""
    return f"{seconds * 1000:.1f} ({gaussians / seconds / 1e6:.2f})"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=10)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--workdir", type=Path, default=Path(tempfile.gettempdir()) / "spc-web-bench")
    parser.add_argument("--scenes", nargs="*", default=list(SCENES))
    parser.add_argument("--json", type=Path, help="also write the results here")
    parser.add_argument("--extra", action="append", default=[], metavar="LABEL=SCENE:FILE",
                        help="also time FILE, an .spc of SCENE, as the row LABEL")
    args = parser.parse_args()
    args.workdir.mkdir(parents=True, exist_ok=True)
    root = data_dir()
    scenes = []
    for name in args.scenes:
        ply, spz = SCENES[name]
        spc = args.workdir / f"{name}.spc"
        encode(root / ply, spc)
        scenes.append({"name": name, "spc": str(spc), "ply": str(root / ply),
                       "spz": str(root / spz) if spz else None})
    for extra in args.extra:
        label, _, rest = extra.partition("=")
        name, _, spc = rest.partition(":")
        if not (label and spc) or name not in SCENES:
            parser.error(f"--extra wants LABEL=SCENE:FILE with SCENE one of {', '.join(SCENES)}")
        scenes.append({"name": label, "spc": spc, "ply": str(root / SCENES[name][0]), "spz": None})
    config = args.workdir / "config.json"
    config.write_text(json.dumps({"repeat": args.repeat, "scenes": scenes}))

    best: dict[str, dict] = {s["name"]: {} for s in scenes}
    node_info = {}
    for _ in range(args.rounds):
        for s in scenes:
            t = python_decode_s(Path(s["spc"]).read_bytes(), args.repeat)
            row = best[s["name"]]
            row["py_decode_s"] = min(row.get("py_decode_s", float("inf")), t)
        node_info = node_round(config)
        for r in node_info["results"]:
            row = best[r["name"]]
            for key, value in r.items():
                if key.endswith("_s") and value is not None:
                    row[key] = min(row.get(key, float("inf")), value)
                elif not key.endswith("_s"):
                    row[key] = value
            row.setdefault("spz_s", None)

    print(f"\nNode {node_info['node']}, Python {platform.python_version()}, SPZ loader: "
          f"{node_info['spz_loader'] or 'not installed (' + str(node_info['spz_missing']) + ')'}; "
          f"best of {args.repeat} x {args.rounds} rounds, from memory\n")
    print("| scene | Gaussians | .spc MB | PLY MB | Python decode ms (M G/s) | JS decode ms (M G/s) "
          "| JS stream ms | JS PLY read ms | SPZ loader ms (M G/s) | JS / Python | JS / PLY read |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for s in scenes:
        r = best[s["name"]]
        n = r["gaussians"]
        spz_cell = "-" if r.get("spz_s") is None else _cell(r["spz_s"], r["spz_gaussians"])
        print(f"| {s['name']} | {n:,} | {Path(s['spc']).stat().st_size / 1e6:.2f} | "
              f"{Path(s['ply']).stat().st_size / 1e6:.2f} | {_cell(r['py_decode_s'], n)} | "
              f"{_cell(r['js_decode_s'], n)} | {r['js_stream_s'] * 1000:.1f} | "
              f"{r['js_ply_read_s'] * 1000:.1f} | {spz_cell} | "
              f"{r['js_decode_s'] / r['py_decode_s']:.2f} | "
              f"{r['js_decode_s'] / r['js_ply_read_s']:.2f} |")
    print("\n| scene | zlib raw MB | JS inflate ms (MB/s) | fflate unzlibSync ms (MB/s) |")
    print("|---|---:|---:|---:|")
    for s in scenes:
        r = best[s["name"]]
        mb = r["zlib_raw_bytes"] / 1e6
        ff = "-" if r.get("fflate_inflate_s") is None else \
            f"{r['fflate_inflate_s'] * 1000:.1f} ({mb / r['fflate_inflate_s']:.0f})"
        print(f"| {s['name']} | {mb:.2f} | {r['js_inflate_s'] * 1000:.1f} "
              f"({mb / r['js_inflate_s']:.0f}) | {ff} |")
    if args.json:
        args.json.write_text(json.dumps({"node": node_info["node"], "spz_loader": node_info["spz_loader"],
                                         "scenes": scenes, "results": best}, indent=1))


if __name__ == "__main__":
    main()
