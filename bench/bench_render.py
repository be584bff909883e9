"""Benchmark of the differentiable renderer on real scenes (run by hand, not a test).

    python bench/bench_render.py                      # default scenes, 256 and 400 px
    python bench/bench_render.py --threads 1 --reps 7
    python bench/bench_render.py --backward autograd  # the blend without the replaying backward
    python bench/bench_render.py --drawing-tiles --scenes kacytran guitar donut fourth_st biker \
        --threads 1

``--drawing-tiles`` times a pass that only draws (no gradients) at both of
``binning.DRAWING_TILES`` over the views such passes render (the precision search's training
views, a quality target's close-ups), with each view's ratio of small-tile to large-tile pairs,
and fits the ratio above which the large tile is faster, holding each scene out in turn: the
measurement behind ``binning.PAIR_RATIO``.

Every case runs in its own subprocess so that its peak resident memory (``ru_maxrss``) is its
own; the table shows the peak and the part of it added by rendering (peak minus the resident
size after loading the scene). Times are wall-clock seconds, best and median of ``--reps`` runs
after one warm-up: on a shared machine the best is the least disturbed run.

The camera looks at the centre of the scene's robust bounding box (1st-99th percentile of the
means) from outside it, far enough for the box's circumscribed sphere to fit the view.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from scenes import REAL, UP, data_dir  # noqa: E402

DATA = data_dir()
SCENES = {name: DATA / path for name, path in REAL.items()}


def overview_camera(means, size: int, fov_deg: float = 50.0):
    """A camera outside the robust bounding box that sees all of it."""
    import numpy as np

    from spcodec.imaging.cameras import Camera

    lo, hi = np.percentile(means, [1, 99], axis=0)
    centre = (lo + hi) / 2
    radius = float(np.linalg.norm(hi - lo)) / 2
    fov = math.radians(fov_deg)
    direction = np.array([1.0, -2.0, 1.5])
    direction /= np.linalg.norm(direction)
    eye = centre + direction * radius / math.sin(fov / 2) * 1.05
    return Camera.look_at(eye, centre, np.array([0.0, 0.0, 1.0]), size, size, fov, "overview")


def rss_mib() -> float:
    """Peak resident set size of this process so far, MiB (Linux reports KiB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def run_case(scene: str, size: int, reps: int, backend: str, backward: str,
             tile_size: int | None) -> dict:
    """Time one (scene, size) in this process; returns the measurements as a dict."""
    import torch

    import spcodec
    from spcodec.imaging.render import GaussianParams, RenderSettings, render
    from spcodec.imaging.render.torch_backend import render_torch

    cloud = spcodec.read_ply(SCENES[scene])
    camera = overview_camera(cloud.means, size)
    device = torch.device("cuda" if backend == "gsplat" else "cpu")
    params = GaussianParams.from_cloud(cloud, device, requires_grad=True)
    settings = RenderSettings() if tile_size is None else RenderSettings(tile_size=tile_size)
    weights = torch.rand(size, size, 3, generator=torch.Generator().manual_seed(0)).to(device)
    base_rss = rss_mib()

    def draw():
        if backend == "torch":
            return render_torch(params, camera, settings, backward=backward)
        return render(params, camera, settings, backend=backend)

    def sync():
        if device.type == "cuda":
            torch.cuda.synchronize()

    def forward():
        with torch.no_grad():
            draw()
        sync()

    def forward_backward():
        for t in params.tensors():
            t.grad = None
        out = draw()
        ((out.image * weights).sum() + out.alpha.sum()).backward()
        sync()

    timings = {}
    for name, fn in (("forward", forward), ("forward_backward", forward_backward)):
        fn()  # warm-up (allocator, lazy init)
        samples = []
        for _ in range(reps):
            start = time.perf_counter()
            fn()
            samples.append(time.perf_counter() - start)
        timings[name] = (min(samples), statistics.median(samples))
    with torch.no_grad():
        coverage = float((draw().alpha > 0.5).float().mean())
    return {
        "scene": scene, "gaussians": len(cloud), "sh_degree": cloud.sh_degree, "size": size,
        "forward": timings["forward"], "forward_backward": timings["forward_backward"],
        "base_mib": base_rss, "peak_mib": rss_mib(), "threads": torch.get_num_threads(),
        "coverage": coverage,
    }


def drawing_views(scene: str, per_group: int = 3) -> list[dict]:
    """Per view of ``scene`` a pass that only draws might render (the precision search's
    training views at its two framings, the quality target's close-ups at 400 and 800 px):
    its pixel boxes' tile pairs and the seconds of a drawing pass at each of the two tiles
    (best of two after a warm-up), in this process."""
    import torch

    import spcodec
    from spcodec.encoder.allocation import training_framings
    from spcodec.encoder.config import AllocationConfig, EncoderConfig
    from spcodec.encoder.qualitycontrol import CloseupJudge
    from spcodec.imaging.render import GaussianParams, RenderSettings, render_image
    from spcodec.imaging.render.binning import DRAWING_TILES, tile_pairs
    from spcodec.imaging.render.projection import project

    cloud = spcodec.read_ply(SCENES[scene])
    config = EncoderConfig(up=UP.get(scene, "-y"))
    params = GaussianParams.from_cloud(cloud, torch.device("cpu"))
    groups = {f"training {name}": cameras for name, cameras
              in training_framings(cloud, config, AllocationConfig()).items()}
    for size in (400, 800):
        groups[f"close-up {size}"] = CloseupJudge(cloud, up=config.up, resolution=size,
                                                  device="cpu").cameras
    rows = []
    for group, cameras in groups.items():
        for camera in cameras[:per_group]:
            with torch.no_grad():
                boxes = project(params, camera, RenderSettings()).pixel_boxes
            row = {"scene": scene, "group": group,
                   "ratio": tile_pairs(boxes, DRAWING_TILES[0]) / tile_pairs(boxes, DRAWING_TILES[1])}
            for tile in DRAWING_TILES:
                settings = RenderSettings(tile_size=tile)
                render_image(params, camera, settings)  # warm-up
                row[tile] = min(_seconds(render_image, params, camera, settings)
                                for _ in range(2))
            rows.append(row)
    return rows


def _seconds(fn, *args) -> float:
    """Wall seconds of ``fn(*args)``."""
    start = time.perf_counter()
    fn(*args)
    return time.perf_counter() - start


def print_drawing_views(rows: list[dict]) -> None:
    """The views by pair ratio; each threshold fitted on all scenes but one, and what it costs
    that one over the faster tile of each view, beside each tile alone."""
    from spcodec.imaging.render.binning import DRAWING_TILES

    small, large = DRAWING_TILES
    print(f"| scene | views | pair ratio | tile {small} s | tile {large} s |\n|---|---|---|---|---|")
    for r in sorted(rows, key=lambda r: r["ratio"]):
        print(f"| {r['scene']} | {r['group']} | {r['ratio']:.2f} | {r[small]:.3f} | "
              f"{r[large]:.3f} |")

    def cost(part: list[dict], threshold: float) -> float:
        return statistics.mean((r[large] if r["ratio"] > threshold else r[small])
                               / min(r[small], r[large]) for r in part)

    scenes = sorted({r["scene"] for r in rows})
    if len(scenes) < 2:
        print("\n(one scene: no threshold is fitted; hold one out of two or more)")
        return
    thresholds = [1.5 + 0.05 * k for k in range(51)]
    print("\n| held out | threshold fitted on the others | its cost | "
          f"tile {small} alone | tile {large} alone |\n|---|---|---|---|---|")
    for scene in scenes:
        fit = [r for r in rows if r["scene"] != scene]
        test = [r for r in rows if r["scene"] == scene]
        best = min(thresholds, key=lambda t: cost(fit, t))
        print(f"| {scene} | {best:.2f} | {cost(test, best):.3f} | {cost(test, 99.0):.3f} | "
              f"{cost(test, 0.0):.3f} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", nargs="+", default=["donut", "fourth_st"],
                        choices=sorted(SCENES))
    parser.add_argument("--sizes", nargs="+", type=int, default=[256, 400])
    parser.add_argument("--reps", type=int, default=5)
    parser.add_argument("--threads", type=int, default=None,
                        help="torch.set_num_threads in each case (default: torch's choice)")
    parser.add_argument("--backend", choices=["torch", "gsplat"], default="torch")
    parser.add_argument("--backward", choices=["replay", "autograd"], default="replay",
                        help="torch backend: hand-written replaying blend backward or autograd")
    parser.add_argument("--tile-size", type=int, default=None)
    parser.add_argument("--drawing-tiles", action="store_true",
                        help="time drawing passes at both drawing tiles, per view (see above)")
    parser.add_argument("--case", nargs=2, metavar=("SCENE", "SIZE"), help=argparse.SUPPRESS)
    args = parser.parse_args()

    if args.drawing_tiles:
        import torch

        if args.threads:
            torch.set_num_threads(args.threads)
        print_drawing_views([row for scene in args.scenes for row in drawing_views(scene)])
        return

    if args.case:  # child process: one measurement, JSON on stdout
        if args.threads:
            import torch

            torch.set_num_threads(args.threads)
        result = run_case(args.case[0], int(args.case[1]), args.reps, args.backend,
                          args.backward, args.tile_size)
        print(json.dumps(result))
        return

    rows = []
    for scene in args.scenes:
        for size in args.sizes:
            cmd = [sys.executable, __file__, "--case", scene, str(size), "--reps", str(args.reps),
                   "--backend", args.backend, "--backward", args.backward]
            if args.threads:
                cmd += ["--threads", str(args.threads)]
            if args.tile_size:
                cmd += ["--tile-size", str(args.tile_size)]
            out = subprocess.run(cmd, check=True, capture_output=True, text=True,
                                 env=dict(os.environ))
            rows.append(json.loads(out.stdout.strip().splitlines()[-1]))
            print(f"done {scene} {size}", file=sys.stderr)

    print(f"backend={args.backend} backward={args.backward} threads={rows[0]['threads']} "
          f"reps={args.reps} (best / median seconds)\n")
    print("| scene | Gaussians | SH | size | covered | forward s | forward+backward s "
          "| peak RSS MiB | added by rendering MiB |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        f, fb = r["forward"], r["forward_backward"]
        cells = [r["scene"], f"{r['gaussians']:,}", str(r["sh_degree"]),
                 f"{r['size']}x{r['size']}", f"{r['coverage']:.0%}",
                 f"{f[0]:.3f} / {f[1]:.3f}", f"{fb[0]:.3f} / {fb[1]:.3f}",
                 f"{r['peak_mib']:.0f}", f"{r['peak_mib'] - r['base_mib']:.0f}"]
        print("| " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
