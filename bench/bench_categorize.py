"""Benchmark of the multi-criteria DBSCAN (encoder stage 1): time, peak memory, clusters.

Scenes: the real captures fourth_st (131k Gaussians) and biker (153k), and larger scenes made by
tiling jittered copies of fourth_st (:func:`tiled_scene`), by default 500k and 1M Gaussians. Each
scene is clustered in a fresh subprocess; the table reports the resident memory before ``fit``
and the resident peak during it (Linux VmHWM, reset just before ``fit``), the peak of numpy
allocations during a second, traced ``fit`` (tracemalloc), wall time of ``fit``
(KD-tree, k-NN eps estimate and both passes; not the PLY reading), clusters and the fraction
clustered.

``--metrics`` instead compares the two direction metrics (sign-free ``axis`` against the paper's
``signed`` formula): on synthetic curves with coherent and with randomized principal-axis signs
(precision and recall of the structured Gaussians, cluster count, adjusted Rand index of the
clusters against the curves), and on the real scenes, where it also reports which fraction of
the near-parallel (|cos| >= 0.9) spatial neighbours have axes pointing in opposite senses.

``--sweep`` reports, on the real scenes, how the cluster count, the clustered fraction and the
largest cluster (fraction of the scene) react to changing each default - the evidence behind the
defaults of :class:`CategorizeConfig`.

Usage::

    python bench/bench_categorize.py                     # fourth_st, biker, 500k, 1M
    python bench/bench_categorize.py --scenes 1M --repeat 2
    python bench/bench_categorize.py --metrics
    python bench/bench_categorize.py --sweep
"""

from __future__ import annotations

import argparse
import ctypes
import multiprocessing as mp
import sys
import time
import tracemalloc
from dataclasses import replace

import numpy as np

from spcodec import GaussianCloud, read_ply
from spcodec.encoder.categorize import MultiCriteriaDBSCAN, direction_distance, principal_axes
from spcodec.encoder.config import CategorizeConfig
from spcodec.encoder.neighbors import iter_radius_pairs
from spcodec.synthetic import make_scene

from scenes import REAL, TILED, data_dir, load_scene  # bench/ is on sys.path


def _status_mib(field: str) -> float:
    """A memory field (``VmRSS``, ``VmHWM``) of /proc/self/status, MiB (Linux)."""
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith(field + ":"):
                return int(line.split()[1]) / 1024
    raise KeyError(field)


def _reset_peak_rss() -> bool:
    """Reset this process's peak RSS (VmHWM) so that it measures only what follows (Linux).

    Heap pages freed earlier (tiling the scene) are first handed back to the system, or ``fit``
    would reuse them without raising the resident size and the peak would read too low.
    """
    try:
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except OSError:
        pass
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        return True
    except OSError:
        return False


def _measure(name: str, config: CategorizeConfig, queue: mp.Queue) -> None:
    """Subprocess body: load, cluster once, report timings and memory through ``queue``.

    The peak is the resident high-water mark reset just before ``fit``, so loading or tiling
    the scene does not count; where the reset is refused it is the whole process's peak. A
    second, untimed ``fit`` under tracemalloc gives the peak of the numpy allocations alone
    (scipy's internal C++ buffers, e.g. the KD-tree, are not traced).
    """
    cloud = load_scene(name)
    if not _reset_peak_rss():
        print("(could not reset the peak RSS: peak includes loading)", file=sys.stderr)
    before = _status_mib("VmRSS")
    start = time.perf_counter()
    model = MultiCriteriaDBSCAN(config).fit(cloud)
    seconds = time.perf_counter() - start
    peak = _status_mib("VmHWM")
    tracemalloc.start()
    MultiCriteriaDBSCAN(config).fit(cloud)
    traced = tracemalloc.get_traced_memory()[1] / 2**20
    tracemalloc.stop()
    queue.put(dict(scene=name, n=len(cloud), seconds=seconds, rss_before=before, rss_peak=peak,
                   traced=traced, eps_s=model.eps_s_, clusters=model.n_clusters_,
                   clustered=float(np.mean(model.labels_ >= 0)),
                   core=float(np.mean(model.core_sample_mask_))))


def run_timings(scenes: list[str], repeat: int, config: CategorizeConfig) -> None:
    """Print one row per scene and repetition."""
    print(f"{'scene':>10} {'N':>9} {'fit s':>7} {'RSS MiB':>8} {'peak MiB':>8} {'traced':>7} "
          f"{'eps_s':>9} {'clusters':>8} {'clustered':>9} {'core':>6}")
    ctx = mp.get_context("spawn")
    for name in scenes:
        for _ in range(repeat):
            queue = ctx.Queue()
            proc = ctx.Process(target=_measure, args=(name, config, queue))
            proc.start()
            r = queue.get()
            proc.join()
            print(f"{r['scene']:>10} {r['n']:>9} {r['seconds']:>7.2f} {r['rss_before']:>8.0f} "
                  f"{r['rss_peak']:>8.0f} {r['traced']:>7.0f} {r['eps_s']:>9.3g} "
                  f"{r['clusters']:>8} {r['clustered']:>9.3f} {r['core']:>6.3f}", flush=True)


# ------------------------------------------------------------------------ direction metrics
def flip_axis_signs(cloud: GaussianCloud, rng: np.random.Generator) -> GaussianCloud:
    """A copy where a random half of the Gaussians are turned 180 degrees about their local y axis.

    That turn maps each ellipsoid onto itself but negates its local x and z axes, so when x is the
    principal axis (as for the synthetic curves) the axis sign becomes random - what a trained
    scene looks like when nothing ties neighbouring Gaussians to one sign.
    """
    out = cloud.subset(slice(None))
    flip = rng.random(len(cloud)) < 0.5
    w, x, y, z = cloud.quats[flip].T
    out.quats[flip] = np.stack([-y, -z, w, x], axis=1)  # q * (0, 0, 1, 0)
    return out


def _synthetic_scores(metric: str, flipped: bool, seeds: range) -> tuple[float, ...]:
    """Mean precision, recall, clusters and clusters per curve over synthetic scenes."""
    from sklearn.metrics import adjusted_rand_score

    p, r, k, ari = [], [], [], []
    for seed in seeds:
        scene = make_scene(seed=seed)
        cloud = flip_axis_signs(scene.cloud, np.random.default_rng(seed)) if flipped \
            else scene.cloud
        labels = MultiCriteriaDBSCAN(CategorizeConfig(direction_metric=metric)).fit(cloud).labels_
        hit = (labels >= 0) & scene.structured
        p.append(hit.sum() / max((labels >= 0).sum(), 1))
        r.append(hit.sum() / scene.structured.sum())
        k.append(labels.max() + 1)
        ari.append(adjusted_rand_score(scene.curve_id[scene.structured],
                                       labels[scene.structured]))
    return float(np.mean(p)), float(np.mean(r)), float(np.mean(k)), float(np.mean(ari))


def _opposite_fraction(cloud: GaussianCloud, eps_s: float, parallel_cos: float = 0.9) -> tuple:
    """Among spatial neighbours with near-parallel axes, the fraction pointing opposite ways."""
    axes = principal_axes(cloud)
    opposite = parallel = 0
    for pairs in iter_radius_pairs(cloud.means.astype(np.float64), eps_s, 65_536):
        a, b = np.take(axes, pairs.rows, axis=0), np.take(axes, pairs.cols, axis=0)
        cos = 1 - 2 * direction_distance(a, b, "signed")
        near = np.abs(cos) >= parallel_cos
        parallel += int(near.sum())
        opposite += int((cos[near] < 0).sum())
    return opposite / max(parallel, 1), parallel


def run_metric_comparison(seeds: range) -> None:
    """Print the synthetic and real-scene comparison of the direction metrics."""
    print("synthetic make_scene (12 curves x 400 + 3000 blobs), mean over seeds", list(seeds))
    print(f"{'axis signs':>11} {'metric':>7} {'precision':>9} {'recall':>7} {'clusters':>8} "
          f"{'ARI':>6}")
    for flipped in (False, True):
        for metric in ("axis", "signed"):
            p, r, k, ari = _synthetic_scores(metric, flipped, seeds)
            print(f"{'random' if flipped else 'coherent':>11} {metric:>7} {p:>9.3f} {r:>7.3f} "
                  f"{k:>8.1f} {ari:>6.3f}")
    print("\nreal scenes (default config otherwise)")
    print(f"{'scene':>10} {'opposite':>8} {'metric':>7} {'clusters':>8} {'clustered':>9}")
    for name in REAL:
        path = data_dir() / REAL[name]
        if not path.exists():
            print(f"{name:>10} missing under {data_dir()}")
            continue
        cloud = read_ply(path)
        opposite = None
        for metric in ("axis", "signed"):
            model = MultiCriteriaDBSCAN(CategorizeConfig(direction_metric=metric)).fit(cloud)
            if opposite is None:
                opposite, _ = _opposite_fraction(cloud, model.eps_s_)
            print(f"{name:>10} {opposite:>8.3f} {metric:>7} {model.n_clusters_:>8} "
                  f"{np.mean(model.labels_ >= 0):>9.3f}", flush=True)


# --------------------------------------------------------------------- default sensitivity
SWEEP = [{}, {"eps_s_factor": 1.0}, {"eps_s_factor": 2.0}, {"eps_c": 0.05}, {"eps_c": 0.15},
         {"eps_d": 0.025}, {"eps_d": 0.1}, {"min_samples": 3}, {"min_samples": 10},
         {"min_cluster_size": 5}, {"min_cluster_size": 50},
         {"eps_s_factor": 2.0, "eps_d": 0.1, "eps_c": 0.15}]
"""One-at-a-time changes from the defaults (plus one all-loose setting) for ``--sweep``."""


def run_sweep(scenes: list[str]) -> None:
    """How clusters, the clustered fraction and the largest cluster react to each parameter."""
    print(f"{'scene':>10} {'change from the defaults':<52} {'clusters':>8} {'clustered':>9} "
          f"{'largest':>8}")
    for name in scenes:
        cloud = load_scene(name)
        for change in SWEEP:
            labels = MultiCriteriaDBSCAN(replace(CategorizeConfig(), **change)).fit(cloud).labels_
            sizes = np.bincount(labels[labels >= 0])
            largest = sizes.max() / len(cloud) if sizes.size else 0.0
            print(f"{name:>10} {str(change or 'defaults'):<52} {sizes.size:>8} "
                  f"{np.mean(labels >= 0):>9.3f} {largest:>8.3f}", flush=True)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--scenes", nargs="+", default=["fourth_st", "biker", *TILED],
                        choices=[*REAL, *TILED])
    parser.add_argument("--repeat", type=int, default=1, help="runs per scene (noisy machine)")
    parser.add_argument("--chunk-size", type=int, default=CategorizeConfig().chunk_size)
    parser.add_argument("--metrics", action="store_true",
                        help="compare the direction metrics instead of timing")
    parser.add_argument("--sweep", action="store_true",
                        help="sensitivity of the result to each default (real scenes)")
    args = parser.parse_args(argv)
    if args.metrics:
        run_metric_comparison(range(5))
        return 0
    if args.sweep:
        run_sweep([s for s in args.scenes if s in REAL] or ["fourth_st", "biker"])
        return 0
    run_timings(args.scenes, args.repeat, replace(CategorizeConfig(), chunk_size=args.chunk_size))
    return 0


if __name__ == "__main__":
    sys.exit(main())
