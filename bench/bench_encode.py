"""The no-retrain encode on real and enlarged scenes (issue "Encoder I").

For each scene: time per stage, sketch fraction, clusters, bytes per sketch Gaussian, Draco ratio of
sketch positions against float32 with their mean error (% of the robust diameter), and the file size
against the input PLY and against the scene's own SPZ file (which the PLY was decoded from, so it is
a reference size, not a fair peer). The 500k and 1M scenes tile jittered copies of fourth_st.

    python bench/bench_encode.py [--scenes fourth_st biker 500k 1M] [--codec zlib]
"""

from __future__ import annotations

import argparse
import os
import time

from spcodec.encoder.pipeline import EncoderConfig, encode
from spcodec.ply import ply_dtype

from scenes import REAL, data_dir, load_scene  # bench/ is on sys.path

OWN_SPZ = {"fourth_st": "pdal_fourth_st_spz/fourth_st.spz",
           "biker": "playcanvas_biker_guitar/biker.spz"}


def ply_size(name: str, cloud) -> int:
    """The input PLY's size: the real file, or what write_ply would write for a tiled scene."""
    if name in REAL:
        return os.path.getsize(data_dir() / REAL[name])
    return len(cloud) * ply_dtype(cloud.sh_degree).itemsize + 600


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", nargs="+", default=["fourth_st", "biker", "500k", "1M"])
    ap.add_argument("--codec", default="zlib", choices=["zlib", "zstd"])
    args = ap.parse_args()
    rows = []
    for name in args.scenes:
        cloud = load_scene(name)
        start = time.perf_counter()
        result = encode(cloud, EncoderConfig(codec=args.codec))
        wall = time.perf_counter() - start
        st = result.stats
        k, size = st["sketch_gaussians"], st["bytes"]
        sketch_bytes = sum(v for key, v in st["sections"].items() if key.startswith("SKETCH"))
        draco = st["sections"].get("SKETCH_POSITIONS", 0)
        spz = OWN_SPZ.get(name)
        spz_size = os.path.getsize(data_dir() / spz) if spz and (data_dir() / spz).exists() else None
        err = st["sketch_error"].get("position_rel_diameter", {}).get("mean")
        sec = st["seconds"]
        rows.append([name, f"{len(cloud):,}", f"{sec.get('categorize', 0):.1f}",
                     f"{sec.get('refine', 0):.1f}", f"{sec.get('sketch', 0):.1f}",
                     f"{sec['patch']:.1f}", f"{sec['write']:.1f}", f"{wall:.1f}",
                     f"{k / len(cloud):.1%}", str(st["sketch"].get("clusters_encoded", 0)),
                     f"{sketch_bytes / k:.2f}" if k else "-",
                     f"{12 * k / draco:.1f}x" if draco else "-",
                     f"{100 * err:.4f}" if err is not None else "-",
                     f"{size / 1e6:.3f}", f"{ply_size(name, cloud) / size:.1f}x",
                     f"{spz_size / size:.2f}x" if spz_size else "-"])
        print(f"{name}: done in {wall:.1f} s", flush=True)
    head = ["scene", "N", "categorize s", "refine s", "sketch s", "patch s", "write s", "total s",
            "sketch", "clusters", "B/sketch G", "Draco vs f32", "pos err % diam", "MB",
            "vs PLY", "vs own SPZ"]
    print("| " + " | ".join(head) + " |")
    print("|" + "---|" * len(head))
    for row in rows:
        print("| " + " | ".join(row) + " |")


if __name__ == "__main__":
    main()
