"""Benchmark of polynomial refinement on real scenes and on a tiled ~1M-Gaussian scene.

Labels come from scikit-learn's DBSCAN on positions (eps = median 8-NN distance, min_samples = 10),
a stand-in for the multi-criteria categorizer; the tiled scene repeats a scene side by side with
jittered positions and reuses the labels (offset per tile), so its cost is the refinement's alone.

    python bench/bench_refine.py                       # fourth_st and biker, then 8 tiles
    python bench/bench_refine.py --scenes fourth_st --tiles 0 --tau 0.02 --jobs 1

Prints, per run: wall time, Gaussians in sketch / patch (by reason), clusters, splits, fits,
coefficient bytes per sketch Gaussian, and degree histograms per attribute.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import time
from collections import Counter

import numpy as np

from spcodec.attributes import SketchAttribute
from spcodec.cloud import GaussianCloud
from spcodec.encoder.config import RefineConfig
from spcodec.encoder.refine import RefineResult, refine
from spcodec.ply import read_ply

from scenes import data_dir  # bench/ is on sys.path

SCENES = {
    "fourth_st": "pdal_fourth_st_spz/fourth_st_inria.ply",
    "biker": "playcanvas_biker_guitar/biker_from_spz_inria.ply",
}


def dbscan_labels(cloud: GaussianCloud, min_samples: int = 10) -> tuple[np.ndarray, float]:
    """Position-only DBSCAN labels and the eps used (median distance to the 8th neighbour)."""
    from scipy.spatial import cKDTree
    from sklearn.cluster import DBSCAN

    p = cloud.means.astype(np.float64)
    sample = p[:: max(1, len(p) // 20000)]
    dist, _ = cKDTree(p).query(sample, k=9)
    eps = float(np.median(dist[:, -1]))
    return DBSCAN(eps=eps, min_samples=min_samples).fit_predict(p).astype(np.int64), eps


def tile(cloud: GaussianCloud, labels: np.ndarray, tiles: int, jitter: float, seed: int = 0
         ) -> tuple[GaussianCloud, np.ndarray]:
    """``tiles`` copies side by side along x, positions jittered by N(0, jitter), labels offset."""
    rng = np.random.default_rng(seed)
    width = float(np.ptp(cloud.means[:, 0])) * 1.1
    top = int(labels.max()) + 1
    parts, labs = [], []
    for t in range(tiles):
        arrays = {k: np.array(v) for k, v in cloud.arrays().items()}
        arrays["means"] = arrays["means"] + rng.normal(0, jitter, arrays["means"].shape)
        arrays["means"][:, 0] += t * width
        parts.append(GaussianCloud(**arrays))
        labs.append(np.where(labels >= 0, labels + t * top, -1))
    return GaussianCloud.concat(parts), np.concatenate(labs)


def sh_rest_loss(cloud: GaussianCloud, result: RefineResult) -> str:
    """What sketch Gaussians lose in higher SH bands: the normalized MSE of their SH rest against
    what they decode to (zeros without an SH-rest model), point-weighted over clusters."""
    from spcodec.encoder.polyfit import AttributeScales, coded_targets, decode_cluster

    if not cloud.sh_rest.shape[1]:
        return "scene has no SH rest"
    if not result.clusters:
        return "no sketch clusters"
    scales = AttributeScales.from_cloud(cloud)
    variance = scales.variance(SketchAttribute.SH_REST, 3 * cloud.sh_rest.shape[1])
    total = energy = 0.0
    for idx, fit in zip(result.clusters, result.fits):
        rest = coded_targets(cloud, idx, sh_rest=True)[SketchAttribute.SH_REST]
        if SketchAttribute.SH_REST in fit.models:
            rest = rest - decode_cluster(fit.frame, fit.models, cloud.means[idx])[
                SketchAttribute.SH_REST]
        total += float((rest ** 2).sum())
        energy += idx.size
    rest_bytes = sum(2 * f.models[SketchAttribute.SH_REST].size for f in result.fits
                     if SketchAttribute.SH_REST in f.models)
    return (f"SH rest of sketch Gaussians: nMSE {total / energy / variance:.4f} "
            f"(scene-scale {np.sqrt(variance / (3 * cloud.sh_rest.shape[1])):.4f}), "
            f"SH-rest coefficient bytes {rest_bytes}")


def summarize(name: str, n: int, result: RefineResult, seconds: float,
              cloud: GaussianCloud | None = None) -> None:
    """Print the numbers the report quotes."""
    s = result.stats
    sketch = max(s.sketch_gaussians, 1)
    print(f"== {name}: {n} Gaussians, {s.input_clusters} input clusters, wall {seconds:.1f} s "
          f"(setup {s.seconds['setup']:.1f} s, node CPU {s.seconds['nodes_cpu']:.1f} s summed over "
          f"workers, load average {os.getloadavg()[0]:.1f})")
    print(f"   sketch {s.sketch_gaussians} ({100 * s.sketch_gaussians / n:.1f}%) in "
          f"{s.accepted_clusters} clusters; patch {s.patch_gaussians} {s.patch_by_reason}")
    print(f"   splits {s.splits}, fits {s.fits}, iqr refits {s.iqr_refits}, max depth "
          f"{s.max_depth}, iqr dropped clusters {s.iqr_dropped_clusters}, coefficient bytes "
          f"{s.coefficient_bytes} "
          f"({s.coefficient_bytes / sketch:.2f} B per sketch Gaussian)")
    if result.fits:
        combined = np.array([f.mse_combined for f in result.fits])
        print(f"   MSE_combined of accepted: median {np.median(combined):.4f}, max "
              f"{combined.max():.4f}")
    for attr in SketchAttribute:
        degrees = Counter(f.degrees[attr] for f in result.fits if attr in f.degrees)
        if degrees:
            weighted = np.average([f.nmse[attr] for f in result.fits if attr in f.nmse],
                                  weights=[f.point_count for f in result.fits if attr in f.nmse])
            print(f"   {attr.name:9s} degrees {dict(sorted(degrees.items()))}, "
                  f"point-weighted nMSE {weighted:.4f}")
    if cloud is not None:
        print(f"   {sh_rest_loss(cloud, result)}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", nargs="*", default=list(SCENES))
    ap.add_argument("--tiles", type=int, default=8, help="tiles of the first scene (0: skip)")
    ap.add_argument("--jobs", type=int, default=None)
    ap.add_argument("--tau", type=float, default=None)
    ap.add_argument("--lam", type=float, default=None)
    ap.add_argument("--beta", type=float, default=None)
    ap.add_argument("--gain", type=float, default=None, help="min_split_gain")
    ap.add_argument("--sh-rest-degree", type=int, default=None)
    ap.add_argument("--no-iqr", action="store_true")
    ap.add_argument("--iqr-k", type=float, default=None)
    args = ap.parse_args()
    cfg = RefineConfig()
    changes = {"tau_max": args.tau, "degree_lambda": args.lam, "beta": args.beta,
               "sh_rest_degree": args.sh_rest_degree, "min_split_gain": args.gain,
               "iqr_k": args.iqr_k}
    cfg = dataclasses.replace(cfg, **{k: v for k, v in changes.items() if v is not None})
    if args.no_iqr:
        cfg = dataclasses.replace(cfg, iqr_k=None)
    print(cfg)
    first = None
    for name in args.scenes:
        cloud = read_ply(data_dir() / SCENES[name])
        t = time.perf_counter()
        labels, eps = dbscan_labels(cloud)
        print(f"-- {name}: DBSCAN eps {eps:.5f} in {time.perf_counter() - t:.1f} s")
        t = time.perf_counter()
        result = refine(cloud, labels, cfg, n_jobs=args.jobs)
        summarize(name, len(cloud), result, time.perf_counter() - t, cloud)
        if first is None:
            first = (name, cloud, labels, eps)
    if args.tiles and first is not None:
        name, cloud, labels, eps = first
        big, big_labels = tile(cloud, labels, args.tiles, jitter=0.05 * eps)
        t = time.perf_counter()
        result = refine(big, big_labels, cfg, n_jobs=args.jobs)
        summarize(f"{name} x{args.tiles} tiles", len(big), result, time.perf_counter() - t)


if __name__ == "__main__":
    main()
