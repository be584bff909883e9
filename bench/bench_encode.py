"""The no-retrain encode on real and enlarged scenes (issue "Encoder I").

For each scene: time per stage, sketch fraction, clusters, bytes per sketch Gaussian, Draco ratio of
sketch positions against float32 with their mean error (% of the robust diameter), and the file size
against the input PLY and against the scene's own SPZ file (which the PLY was decoded from, so it is
a reference size, not a fair peer). The 500k and 1M scenes tile jittered copies of fourth_st.

``--against-previous`` instead times the default encode against the previous default (scikit-learn
k-means++ on 200,000 uniform samples, the opacity-footprint importance, three layers 20/30/50 %,
no cap on the sketch layer: :func:`previous_config`) in the same process, alternating the two
``--repeat`` times and keeping each stage's best time, and judges both files as ``spcodec eval
--reference`` does (8 held-out views of 400x400).

    python bench/bench_encode.py [--scenes fourth_st biker 500k 1M] [--codec zlib]
    python bench/bench_encode.py --against-previous [--scenes fourth_st] [--repeat 3]
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import time

from spcodec.encoder.config import EncoderConfig
from spcodec.encoder.pipeline import encode
from spcodec.ply import ply_dtype

from scenes import REAL, data_dir, load_scene  # bench/ is on sys.path

OWN_SPZ = {"fourth_st": "pdal_fourth_st_spz/fourth_st.spz",
           "biker": "playcanvas_biker_guitar/biker.spz"}


def ply_size(name: str, cloud) -> int:
    """The input PLY's size: the real file, or what write_ply would write for a tiled scene."""
    if name in REAL:
        return os.path.getsize(data_dir() / REAL[name])
    return len(cloud) * ply_dtype(cloud.sh_degree).itemsize + 600


def previous_config(base: EncoderConfig | None = None) -> EncoderConfig:
    """``base`` (default: the default config) with the patch coding and layering of the encoder
    before blend-weight layers and sampled k-means (see the module docstring)."""
    base = base or EncoderConfig()
    patch = dataclasses.replace(base.patch, kmeans="exhaustive", kmeans_samples=200_000,
                                kmeans_iterations=60, importance="footprint",
                                kmeans_weight_floor=0.0, layers=3, layer_fractions=(0.2, 0.3, 0.5))
    return dataclasses.replace(base, patch=patch, max_sketch_share=None)


def against_previous(names: list[str], repeat: int, codec: str) -> None:
    """Stage times (best of ``repeat``), size and PSNR of the default against the previous one."""
    from spcodec.decoder import decode
    from spcodec.imaging.evaluate import EvalConfig, evaluate_against_reference

    rows = []
    for name in names:
        cloud = load_scene(name)
        configs = {"previous": previous_config(EncoderConfig(codec=codec)),
                   "current": EncoderConfig(codec=codec)}
        best: dict[str, dict[str, float]] = {k: {} for k in configs}
        data: dict[str, bytes] = {}
        for _ in range(repeat):
            for label, config in configs.items():
                start = time.perf_counter()
                result = encode(cloud, config)
                seconds = dict(result.stats.seconds, total=time.perf_counter() - start)
                for stage, value in seconds.items():
                    best[label][stage] = min(best[label].get(stage, value), value)
                data[label] = result.data
                print(f"{name} {label}: {seconds['total']:.1f} s", flush=True)
        for label in configs:
            psnr = evaluate_against_reference(decode(data[label]), cloud, EvalConfig(views=8)).psnr
            rows.append((name, label, best[label], len(data[label]), psnr))
    stages = ["importance", "categorize", "refine", "sketch", "patch", "write", "total"]
    print("| scene | encoder | " + " | ".join(f"{s} s" for s in stages) + " | bytes | PSNR dB |")
    print("|---|---|" + "---:|" * (len(stages) + 2))
    for name, label, seconds, size, psnr in rows:
        cells = [f"{seconds[s]:.2f}" if s in seconds else "-" for s in stages]
        print(f"| {name} | {label} | " + " | ".join(cells) + f" | {size:,} | {psnr:.2f} |")
    for name in names:
        old, new = [r for r in rows if r[0] == name]
        print(f"{name}: {old[2]['total'] / new[2]['total']:.2f}x faster, size "
              f"{100 * (new[3] / old[3] - 1):+.2f} %, PSNR {new[4] - old[4]:+.2f} dB")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", nargs="+", default=None)
    ap.add_argument("--codec", default="zlib", choices=["zlib", "zstd"])
    ap.add_argument("--against-previous", action="store_true",
                    help="time the default encode against the previous default")
    ap.add_argument("--repeat", type=int, default=3, help="runs per encoder (--against-previous)")
    args = ap.parse_args()
    if args.against_previous:
        against_previous(args.scenes or ["fourth_st"], args.repeat, args.codec)
        return
    args.scenes = args.scenes or ["fourth_st", "biker", "500k", "1M"]
    rows = []
    for name in args.scenes:
        cloud = load_scene(name)
        start = time.perf_counter()
        result = encode(cloud, EncoderConfig(codec=args.codec))
        wall = time.perf_counter() - start
        st = result.stats.to_json()
        k, size = st["sketch_gaussians"], st["bytes"]
        sketch_bytes = sum(v for key, v in st["sections"].items() if key.startswith("SKETCH"))
        draco = st["sections"].get("SKETCH_POSITIONS", 0)
        spz = OWN_SPZ.get(name)
        spz_size = os.path.getsize(data_dir() / spz) if spz and (data_dir() / spz).exists() else None
        err = st["sketch_error"].get("position_rel_diameter", {}).get("mean")
        sec = st["seconds"]
        rows.append([name, f"{len(cloud):,}", f"{sec.get('importance', 0):.1f}",
                     f"{sec.get('categorize', 0):.1f}",
                     f"{sec.get('refine', 0):.1f}", f"{sec.get('sketch', 0):.1f}",
                     f"{sec['patch']:.1f}", f"{sec['write']:.1f}", f"{wall:.1f}",
                     f"{k / len(cloud):.1%}", str(st["sketch"].get("clusters_encoded", 0)),
                     f"{sketch_bytes / k:.2f}" if k else "-",
                     f"{12 * k / draco:.1f}x" if draco else "-",
                     f"{100 * err:.4f}" if err is not None else "-",
                     f"{size / 1e6:.3f}", f"{ply_size(name, cloud) / size:.1f}x",
                     f"{spz_size / size:.2f}x" if spz_size else "-"])
        print(f"{name}: done in {wall:.1f} s", flush=True)
    head = ["scene", "N", "importance s", "categorize s", "refine s", "sketch s", "patch s",
            "write s", "total s", "sketch", "clusters", "B/sketch G", "Draco vs f32", "pos err % diam", "MB",
            "vs PLY", "vs own SPZ"]
    print("| " + " | ".join(head) + " |")
    print("|" + "---|" * len(head))
    for row in rows:
        print("| " + " | ".join(row) + " |")


if __name__ == "__main__":
    main()
