"""Decode speed against reading the same scene's PLY, in one run (issue "Bitstream v1").

Builds a patch-only bitstream from a real scene (k-means codebooks from the reference patch
encoder), then times, alternating to share the machine's noise:

* ``plyfile``: ``PlyData.read`` (memory-mapped) plus materializing the vertex array, the cheapest
  way plyfile gives a user the data in memory (``mmap=False`` is ~100x slower in plyfile 1.1);
* ``spcodec.read_ply``: the same plus splitting into the scene model's arrays;
* ``spcodec.decode``: the whole .spc (zlib sections, then zstd sections).

Each timing is the best of ``--repeat`` runs, single-threaded (numpy does not thread these
operations). Peak memory is the tracemalloc peak of one decode (numpy reports its buffers there).

    python bench/bench_decode.py [--scene PATH] [--repeat 15]
"""

from __future__ import annotations

import argparse
import os
import time
import tracemalloc
from pathlib import Path

import numpy as np
from plyfile import PlyData

import spcodec
from spcodec.container import Codec
from spcodec.encoder.config import PatchConfig
from spcodec.encoder.patch import PatchEncoder
from spcodec.writer import EncodedScene, WriteOptions, build_bitstream

DEFAULT_SCENE = Path(os.environ.get("SPCODEC_DATA", Path(__file__).resolve().parents[2] /
                                    "shared" / "data")) / "pdal_fourth_st_spz" / "fourth_st_inria.ply"


def best_of(fn, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return min(times)


def plyfile_read(path: Path) -> np.ndarray:
    return np.array(PlyData.read(str(path))["vertex"].data)


def peak_bytes(fn) -> int:
    tracemalloc.start()
    fn()
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    return peak


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", type=Path, default=DEFAULT_SCENE)
    parser.add_argument("--repeat", type=int, default=15)
    args = parser.parse_args()

    cloud = spcodec.read_ply(args.scene)
    encoding = PatchEncoder(PatchConfig(kmeans_iterations=20)).encode(cloud)
    scene = EncodedScene(cloud.sh_degree, [], encoding.codebooks, encoding.layers)
    files = {"zlib": build_bitstream(scene, WriteOptions(codec=Codec.ZLIB)),
             "zstd": build_bitstream(scene, WriteOptions(codec=Codec.ZSTD))}
    n = len(cloud)
    ply_size = args.scene.stat().st_size

    timings = {"plyfile read": [], "spcodec.read_ply": []}
    timings.update({f"spcodec.decode ({c})": [] for c in files})
    for _ in range(3):  # interleave the rounds so background load hits every contender alike
        timings["plyfile read"].append(best_of(lambda: plyfile_read(args.scene), args.repeat))
        timings["spcodec.read_ply"].append(best_of(lambda: spcodec.read_ply(args.scene),
                                                   args.repeat))
        for codec, data in files.items():
            timings[f"spcodec.decode ({codec})"].append(
                best_of(lambda d=data: spcodec.decode(d), args.repeat))
    ply_time = min(timings["plyfile read"])

    print(f"scene: {args.scene.name}, {n} Gaussians, SH degree {cloud.sh_degree}, "
          f"PLY {ply_size / 1e6:.2f} MB")
    print("| operation | size (MB) | time (ms) | vs plyfile read | M Gaussians/s | peak memory (MB) |")
    print("|---|---:|---:|---:|---:|---:|")
    for name, values in timings.items():
        t = min(values)
        if name.startswith("spcodec.decode"):
            data = files[name.split("(")[1].rstrip(")")]
            size, peak = len(data), peak_bytes(lambda d=data: spcodec.decode(d))
        elif name == "plyfile read":
            size, peak = ply_size, peak_bytes(lambda: plyfile_read(args.scene))
        else:
            size, peak = ply_size, peak_bytes(lambda: spcodec.read_ply(args.scene))
        print(f"| {name} | {size / 1e6:.2f} | {t * 1e3:.1f} | {t / ply_time:.2f} | "
              f"{n / t / 1e6:.2f} | {peak / 1e6:.0f} |")


if __name__ == "__main__":
    main()
