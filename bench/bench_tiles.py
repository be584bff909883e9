"""Tiled encodes of a large scene (issue 39): time per Gaussian, peak memory, workers, merges.

``make`` writes the large scene: jittered copies of a shared scene side by side
(:func:`scenes.tiled_scene`), as a binary PLY, made again the same way by the same command.
``run`` encodes one configuration in a fresh process and prints its wall time and the peak
resident memory of the process and of its children (``resource.getrusage``: the Dask workers are
children of their nannies, which are children of this process), so no run inherits another's peak.
``compare`` runs the tiled encode with 1 and 2 local workers and the single-file no-retrain encode
of a 500 k scene, each in its own process. ``merges`` judges the levels of detail of a built
tileset: renders of an inner node's merged Gaussians against renders of the finer Gaussians it
replaces (its children's), at a few views with the CPU renderer, beside a random subset of the same
count as a yardstick. ``decimate`` (issue 39's comparison) builds a tileset of a real scene, decodes
every node of the level nearest 1/16 of the input into one PLY, decimates the input with
PlayCanvas splat-transform (``$SPLAT_TRANSFORM`` or on PATH, ``--decimate``: pairwise merging) to
the same count, and judges both against the input in a third-party renderer
(``../shared/tools/two-framings.sh``: PlayCanvas in Chromium, orbit and close framings), writing
``docs/results/tiles_decimate.json``.

    python bench/bench_tiles.py make --gaussians 2000000 -o big.ply [--base fourth_st | --layout city]
    python bench/bench_tiles.py compare big.ply --work OUT/ [--leaf-size 65536]
    python bench/bench_tiles.py merges OUT/tiled-w1 [--nodes 4] [--views 4]
    python bench/bench_tiles.py decimate --work DIR [--scenes guitar donut]
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import json
import os
import re
import resource
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import BinaryIO, Iterator

import numpy as np

from spcodec import GaussianCloud, read_ply, write_ply
from spcodec.fileio import atomic_write
from spcodec.ply import ply_bytes
from spcodec.tiling.config import PRECISION_SEARCHES, TilingConfig
from spcodec.tiling.tileset import read_tileset

from scenes import CITY_BASES, REAL, city_blocks, data_dir, load_scene, tiled_copies  # bench/ on sys.path


def make(args: argparse.Namespace) -> None:
    """Write the large scene: copies of one scene in a cube, or a city of several (``--layout``)."""
    if args.layout == "city":
        bases = [read_ply(data_dir() / REAL[name]) for name in CITY_BASES]
        write_parts(args.output, city_blocks(bases, args.gaussians, seed=args.seed), args.gaussians)
        print(f"{args.output}: {args.gaussians} Gaussians, a city of {', '.join(CITY_BASES)}")
        return
    base = read_ply(data_dir() / REAL[args.base])
    write_parts(args.output, tiled_copies(base, args.gaussians, seed=args.seed), args.gaussians)
    print(f"{args.output}: {args.gaussians} Gaussians from {args.base}")


def write_parts(path: Path, parts: Iterator[GaussianCloud], n: int) -> None:
    """A binary PLY of ``n`` Gaussians written part after part (all of one SH degree): memory
    holds one part, not the scene (20 M Gaussians are 5 GB)."""
    first = next(parts)
    header, _ = ply_bytes(first.subset(slice(0, 0)))
    header = header.replace(b"element vertex 0\n", f"element vertex {n}\n".encode())

    def produce(out: BinaryIO) -> None:
        out.write(header)
        for part in itertools.chain([first], parts):
            out.write(memoryview(ply_bytes(part)[1]).cast("B"))

    atomic_write(path, produce)


def run_one(args: argparse.Namespace) -> None:
    """One configuration in this process; prints a JSON line (time, memory, sizes)."""
    import torch

    torch.set_num_threads(1)
    start = time.perf_counter()
    if args.mode == "single":
        from spcodec.encoder import encode, preset_config

        cloud = load_scene(args.scene)
        # as a user runs it (the preset's point, D-33), or its own codebooks with or without
        # their sketch (--sketch / --no-sketch), the file the tileset's nodes are made as
        config = preset_config("balanced", point=args.sketch is None)
        if args.sketch is not None:
            config = dataclasses.replace(config, use_sketch=args.sketch)
        result = encode(cloud, config)
        out = {"gaussians": len(cloud), "bytes": len(result.data), "sketch": config.use_sketch}
    else:
        from spcodec.tiling import build_tileset

        sketch = TilingConfig.sketch if args.sketch is None else args.sketch
        summary = build_tileset(args.input, args.output, TilingConfig(
            leaf_size=args.leaf_size, branching=args.branching, workers=args.workers,
            sketch=sketch, precision_search=args.precision_search, keep_work=True))
        per_level: dict[int, list[int]] = {}
        stack = [read_tileset(summary.tileset)["root"]]
        while stack:
            tile = stack.pop()
            extras = tile["extras"]["spcodec"]
            row = per_level.setdefault(extras["level"], [0, 0])
            row[0], row[1] = row[0] + extras["gaussians"], row[1] + extras["bytes"]
            stack.extend(tile.get("children", []))
        out = {"gaussians": summary.input_gaussians, "encoded": summary.encoded_gaussians, "sketch": sketch,
               "bytes": summary.bytes, "nodes": summary.nodes, "depth": summary.depth,
               "levels": {k: {"gaussians": g, "bytes": b} for k, (g, b) in sorted(per_level.items())},
               "partition_s": round(summary.partition_seconds, 2),
               "nodes_s": round(summary.nodes_seconds, 2), **node_cpu(Path(args.output))}
    seconds = time.perf_counter() - start
    own = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    children = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
    out.update(mode=args.mode, workers=args.workers, seconds=round(seconds, 2),
               us_per_gaussian=round(1e6 * seconds / out["gaussians"], 1),
               peak_mb_self=round(own), peak_mb_children=round(children))
    print(json.dumps(out), flush=True)


def node_cpu(tileset: Path) -> dict:
    """CPU seconds summed over the nodes' records: merging (inner nodes; a leaf's is its load)
    and encoding, as the node tasks measured them in their own processes."""
    records = [json.loads(p.read_text()) for p in (tileset / "nodes").glob("*.json")]
    merge = sum(r.get("merge_cpu_seconds", 0.0) for r in records)
    whole = sum(r.get("cpu_seconds", 0.0) for r in records)
    return {"merge_cpu_s": round(merge, 1), "encode_cpu_s": round(whole - merge, 1)}


def compare(args: argparse.Namespace) -> None:
    """The tiled encode with 1 and 2 workers and the single-file baseline, each in a new
    process."""
    here = Path(__file__).resolve()
    runs = [["--mode", "single", "--scene", args.single]] if args.single else []
    for workers in args.workers:
        folder = Path(args.work) / f"tiled-w{workers}"
        if folder.exists():
            shutil.rmtree(folder)  # a fresh build, not a resume
        runs.append(["--mode", "tiled", "--input", str(args.input), "--output", str(folder),
                     "--workers", str(workers), "--leaf-size", str(args.leaf_size)])
    for extra in runs:
        done = subprocess.run([sys.executable, str(here), "run-one", *extra], check=True,
                              capture_output=True, text=True)
        print(done.stdout.strip().splitlines()[-1], flush=True)


def merges(args: argparse.Namespace) -> None:
    """PSNR of merged levels against the finer Gaussians they replace."""
    import torch

    from spcodec.imaging.metrics import psnr
    from spcodec.imaging.render import render_image
    from spcodec.imaging.views import sample_views
    from spcodec.tiling.rows import rows_to_cloud

    torch.set_num_threads(1)
    root = Path(args.tileset)
    records = {p.stem: json.loads(p.read_text()) for p in (root / "nodes").glob("*.json")}
    inner = sorted((i for i in records if f"{i}0" in records), key=len, reverse=True)
    rng = np.random.default_rng(0)
    for node_id in inner[:args.nodes]:
        children = sorted(i for i in records if i[:-1] == node_id and len(i) == len(node_id) + 1)
        finer = rows_to_cloud(np.concatenate([np.load(root / records[c]["cloud"])
                                              for c in children]))
        merged = rows_to_cloud(np.load(root / records[node_id]["cloud"]))
        subset = finer.subset(np.sort(rng.choice(len(finer), len(merged), replace=False)))
        cameras = sample_views(finer, args.views, resolution=(args.size, args.size))
        scores = {"psnr_merged": [], "psnr_random_subset": []}
        for camera in cameras:
            reference = render_image(finer, camera, device="cpu")
            scores["psnr_merged"].append(psnr(reference, render_image(merged, camera, device="cpu")))
            scores["psnr_random_subset"].append(psnr(reference,
                                                     render_image(subset, camera, device="cpu")))
        print(json.dumps({"node": node_id, "finer": len(finer), "coarse": len(merged),
                          "error": records[node_id]["error"],
                          "capped": records[node_id].get("capped"),
                          **{k: round(float(np.mean(v)), 2) for k, v in scores.items()}}),
              flush=True)


REPO = Path(__file__).resolve().parents[1]
FRAMINGS = {"guitar": [], "donut": ["--up", "z", "--aa"]}
"""two-framings.sh options per scene (its up axis; donut was trained antialiased)."""
RESULTS = REPO / "docs" / "results" / "tiles_decimate.json"


def splat_transform() -> str:
    """The splat-transform command: ``$SPLAT_TRANSFORM`` or on PATH."""
    tool = os.environ.get("SPLAT_TRANSFORM") or shutil.which("splat-transform")
    if not tool:
        raise SystemExit("decimate needs splat-transform on PATH or $SPLAT_TRANSFORM")
    return tool


def two_framings(original: Path, other: Path, options: list[str]) -> dict:
    """PSNR of ``other`` against ``original`` in PlayCanvas at the orbit and close framings."""
    script = Path(os.environ.get("SPCODEC_TWO_FRAMINGS", REPO.parent / "shared/tools/two-framings.sh"))
    done = subprocess.run([str(script), str(original), str(other), *options], capture_output=True,
                          text=True, cwd=REPO)
    found = re.search(r"orbit ([\d.]+) dB, close ([\d.]+) dB", done.stdout)
    if not found:
        raise SystemExit(f"two-framings failed on {other}: {done.stdout.strip()} {done.stderr.strip()}")
    return {"orbit_db": float(found.group(1)), "close_db": float(found.group(2))}


def level_near(doc: dict, target: float) -> tuple[int, list[dict]]:
    """(level, its tiles) of the tileset level whose Gaussian count is nearest ``target`` (by
    ratio)."""
    levels: dict[int, list[dict]] = {}
    stack = [doc["root"]]
    while stack:
        tile = stack.pop()
        levels.setdefault(tile["extras"]["spcodec"]["level"], []).append(tile)
        stack.extend(tile.get("children", []))
    count = {k: sum(t["extras"]["spcodec"]["gaussians"] for t in v) for k, v in levels.items()}
    best = min(count, key=lambda k: abs(np.log(count[k] / target)))
    return best, levels[best]


def decimate(args: argparse.Namespace) -> None:
    """Coarse level against splat-transform's decimation to the same count, per scene."""
    import torch

    from spcodec.decoder import decode
    from spcodec.tiling import build_tileset

    torch.set_num_threads(1)  # the nodes run in this process, one core's worth as a worker's

    tool = splat_transform()
    shown = subprocess.run([tool, "-v"], capture_output=True, text=True)
    version = (shown.stdout or shown.stderr).strip().splitlines()[0]
    rows = []
    for name in args.scenes:
        original = data_dir() / REAL[name]
        work = Path(args.work) / name
        n = len(read_ply(original))
        leaf = args.leaf_size or 1 << int(np.ceil(np.log2(n / 16)))
        start = time.perf_counter()
        summary = build_tileset(original, work / "tileset", TilingConfig(
            leaf_size=leaf, branching=4, workers=0, sketch=args.sketch,
            precision_search=args.precision_search))
        built = time.perf_counter() - start
        doc = read_tileset(summary.tileset)
        level, chosen = level_near(doc, n / 16)
        coarse = GaussianCloud.concat([decode(work / "tileset" / t["content"]["uri"]) for t in chosen])
        ours = work / "level.ply"
        write_ply(ours, coarse)
        theirs = work / "decimated.ply"
        start = time.perf_counter()
        subprocess.run([tool, "-w", "-q", "-g", "cpu", str(original), "-F", str(len(coarse)),
                        str(theirs)], check=True, capture_output=True)
        decimated = time.perf_counter() - start
        packed = work / "decimated.compressed.ply"
        subprocess.run([tool, "-w", "-q", str(theirs), str(packed)], check=True, capture_output=True)
        row = {"scene": name, "input": n, "leaf_size": leaf, "level": level,
               "gaussians": len(coarse), "decimated_gaussians": len(read_ply(theirs)),
               "level_bytes": sum(t["extras"]["spcodec"]["bytes"] for t in chosen),
               "decimated_ply_bytes": theirs.stat().st_size,
               "decimated_compressed_ply_bytes": packed.stat().st_size,
               "precision_search": args.precision_search,
               "tileset_seconds": round(built, 1), "decimate_seconds": round(decimated, 1),
               "level_psnr": two_framings(original, ours, FRAMINGS[name]),
               "decimated_psnr": two_framings(original, theirs, FRAMINGS[name])}
        row["met"] = all(row["level_psnr"][k] >= row["decimated_psnr"][k] for k in ("orbit_db", "close_db"))
        print(json.dumps(row), flush=True)
        rows.append(row)
    sketch = [] if args.sketch == TilingConfig.sketch else ["--sketch" if args.sketch else "--no-sketch"]
    if args.precision_search != TilingConfig.precision_search:
        sketch.append(f"--precision-search {args.precision_search}")
    doc = {"command": " ".join(["python bench/bench_tiles.py decimate --work DIR --scenes",
                                *args.scenes, *sketch]),
           "splat_transform": version, "renderer": "../shared/tools/two-framings.sh (PlayCanvas)",
           "rows": rows}
    results = Path(args.results)
    results.write_text(json.dumps(doc, indent=1) + "\n")
    print(f"wrote {results}")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = p.add_subparsers(dest="command", required=True)
    m = sub.add_parser("make")
    m.add_argument("--gaussians", type=int, default=2_000_000)
    m.add_argument("--base", default="fourth_st", choices=sorted(REAL))
    m.add_argument("--layout", choices=["cube", "city"], default="cube",
                   help="cube: copies of --base (tiled_scene); city: blocks of several scenes")
    m.add_argument("--seed", type=int, default=0)
    m.add_argument("-o", "--output", required=True)
    c = sub.add_parser("compare")
    c.add_argument("input")
    c.add_argument("--work", required=True, help="folder for the tilesets")
    c.add_argument("--leaf-size", type=int, default=65536)
    c.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    c.add_argument("--single", default="500k", help="scene of the single-file baseline ('' skips)")
    r = sub.add_parser("run-one")
    r.add_argument("--mode", choices=["single", "tiled"], required=True)
    r.add_argument("--scene", default="500k")
    r.add_argument("--input")
    r.add_argument("--output")
    r.add_argument("--workers", type=int, default=0)
    r.add_argument("--leaf-size", type=int, default=65536)
    r.add_argument("--branching", type=int, default=4)
    r.add_argument("--sketch", action=argparse.BooleanOptionalAction,
                   help="the encodes build a sketch (default: the mode's own: the tiling's for "
                   "tiled, the preset's point without one for single; given, single keeps the "
                   "preset's own codebooks)")
    r.add_argument("--precision-search", choices=PRECISION_SEARCHES,
                   default=TilingConfig.precision_search,
                   help="tiled: nodes that are their preset's point (default: %(default)s)")
    g = sub.add_parser("merges")
    g.add_argument("tileset")
    g.add_argument("--nodes", type=int, default=4)
    g.add_argument("--views", type=int, default=4)
    g.add_argument("--size", type=int, default=256)
    d = sub.add_parser("decimate")
    d.add_argument("--work", required=True, help="scratch folder (tilesets, PLYs)")
    d.add_argument("--scenes", nargs="+", default=list(FRAMINGS), choices=sorted(FRAMINGS))
    d.add_argument("--leaf-size", type=int, default=0,
                   help="default: the power of two at or above 1/16 of the scene, so the root is that level")
    d.add_argument("--sketch", action=argparse.BooleanOptionalAction,
                   default=TilingConfig.sketch, help="nodes' encodes build a sketch (default: %(default)s)")
    d.add_argument("--precision-search", choices=PRECISION_SEARCHES,
                   default=TilingConfig.precision_search,
                   help="nodes that are their preset's point (default: %(default)s)")
    d.add_argument("--results", default=str(RESULTS), help="the JSON written (default: %(default)s)")
    args = p.parse_args()
    {"make": make, "compare": compare, "run-one": run_one, "merges": merges,
     "decimate": decimate}[args.command](args)


if __name__ == "__main__":
    main()
