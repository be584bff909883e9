"""Vanilla 3DGS training on the project's own CPU renderer: a trained model matched to its images.

No shared scene has both a trained model and the images it was trained from; this script makes
one (the model dataset-mode retraining is measured on). The recipe is the 3DGS paper's, as the
INRIA code runs it on NeRF-synthetic scenes, with every step count scaled to a shorter run:

* **Init**: ``--init-points`` Gaussians uniformly in the cube ``[-1.3, 1.3]^3`` (INRIA's random
  init for scenes without points), random colours, isotropic scales from the mean distance to the
  3 nearest neighbours, identity rotations, opacity 0.1, SH coefficients above DC zero.
* **Optimization**: one training view per step (seeded permutation per epoch), loss 0.8 L1 +
  0.2 D-SSIM over the dataset's background (white for NeRF-synthetic), Adam at the 3DGS rates with
  the position rate decaying over the run and scaled by the camera extent (``FreeGaussians``).
* **SH degree** raised by one every ``sh_every`` steps up to ``--sh-degree`` (INRIA: 1000 of
  30,000, scaled like the rest).
* **Adaptive density control** (``imaging/training/densify.py``): the INRIA schedule of a
  30,000-step run (densify from 500 to 15,000 every 100, opacity reset every 3,000 and at the
  start for a white background) times ``iterations / 30000``, as gsplat's ``steps_scaler`` does.

Writes MODEL.ply (INRIA layout) and MODEL.json (how it was made: command, settings, densification
log, time, peak memory, machine load, test PSNR/SSIM on the dataset's test split)::

    nice -n 5 python bench/train_vanilla.py ../shared/data/nerf_synthetic_lego \\
        -o lego_vanilla.ply --downscale 4 --iterations 3000 --threads 1

(25 min on the project's shared 2-core machine, 31.6 dB on the test split: docs/LOG.md,
section "Vanilla training"; one torch thread is ~4x faster than two on a loaded machine). Judge
the result again with ``spcodec eval MODEL.ply --dataset DIR --downscale N`` (the same N).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import resource
import shlex
import subprocess
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch

from spcodec.cloud import SH_REST_COUNTS, GaussianCloud
from spcodec.encoder.progress import StageReporter
from spcodec.fileio import atomic_write
from spcodec.imaging.datasets import load_dataset
from spcodec.imaging.evaluate import EvalConfig, evaluate_against_dataset
from spcodec.imaging.render import GaussianParams, RenderSettings, resolve_backend, resolve_device
from spcodec.imaging.render.sh import SH_C0
from spcodec.imaging.training.densify import REFERENCE_ITERATIONS, Densifier, DensifyConfig
from spcodec.imaging.training.loop import FitLoop, StepReport
from spcodec.imaging.training.optim import FreeGaussians, LearningRates
from spcodec.imaging.training.targets import Targets, dataset_targets
from spcodec.ply import write_ply

SH_EVERY = 1000
"""INRIA raises the SH degree every 1000 of its 30,000 steps."""


@dataclass
class VanillaConfig:
    """Everything that decides the trained model (stored in MODEL.json)."""

    iterations: int = 3000
    init_points: int = 100_000
    init_half_size: float = 1.3
    init_opacity: float = 0.1
    sh_degree: int = 3
    seed: int = 0
    densify: DensifyConfig = field(default_factory=DensifyConfig)
    rates: LearningRates = field(default_factory=LearningRates)

    @property
    def sh_every(self) -> int:
        return max(1, round(SH_EVERY * self.iterations / REFERENCE_ITERATIONS))


def random_box_cloud(count: int, half_size: float, opacity: float, sh_degree: int,
                     seed: int) -> GaussianCloud:
    """``count`` Gaussians uniform in ``[-half_size, half_size]^3`` (see the module docstring)."""
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(seed)
    means = rng.uniform(-half_size, half_size, (count, 3))
    colours = rng.uniform(0.0, 1.0, (count, 3))
    k = min(3, count - 1)
    if k > 0:
        dist, _ = cKDTree(means).query(means, k=k + 1)
        spacing = np.sqrt(np.mean(dist[:, 1:] ** 2, axis=1)).clip(1e-7)
    else:
        spacing = np.full(count, half_size)
    quats = np.zeros((count, 4))
    quats[:, 0] = 1.0
    return GaussianCloud(
        means=means.astype(np.float32),
        scales=np.repeat(np.log(spacing)[:, None], 3, axis=1).astype(np.float32),
        quats=quats.astype(np.float32),
        opacities=np.full(count, math.log(opacity / (1 - opacity)), np.float32),
        sh_dc=((colours - 0.5) / SH_C0).astype(np.float32),
        sh_rest=np.zeros((count, SH_REST_COUNTS[sh_degree], 3), np.float32))


class VanillaGaussians(FreeGaussians):
    """Free Gaussians rendered at an SH degree that rises by one every ``sh_every`` steps (the
    higher bands get no gradient, hence no Adam update, until their turn)."""

    def __init__(self, cloud: GaussianCloud, device: torch.device | str, rates: LearningRates,
                 extent: float, sh_every: int) -> None:
        super().__init__(cloud, device, rates, extent)
        self.max_degree = int(round(math.sqrt(cloud.sh_rest.shape[1] + 1))) - 1
        self.sh_every, self.degree = sh_every, 0

    def before_step(self, step: int, total: int) -> None:
        super().before_step(step, total)
        self.degree = min(self.max_degree, step // self.sh_every)

    def params(self) -> GaussianParams:
        full = super().params()
        return GaussianParams(full.means, full.scales, full.quats, full.opacities,
                              full.sh[:, :(self.degree + 1) ** 2])


@dataclass
class Trained:
    """A training run's model and its record."""

    cloud: GaussianCloud
    seconds: float
    densifier: Densifier
    final_loss: float
    final_psnr: float
    psnr_start: float
    psnr_end: float
    load: list[float]


def train(targets: Targets, config: VanillaConfig, device: torch.device | str = "cpu",
          progress: bool = True) -> Trained:
    """Train from a random box init against ``targets``; see the module docstring."""
    init = random_box_cloud(config.init_points, config.init_half_size, config.init_opacity,
                            config.sh_degree, config.seed)
    model = VanillaGaussians(init, device, config.rates, targets.extent, config.sh_every)
    densifier = Densifier(config.densify, targets.extent, seed=config.seed)
    settings = RenderSettings(background=targets.background)
    loop = FitLoop(model, targets, settings, config.iterations, seed=config.seed,
                   after_step=lambda step, result: densifier.after_step(model, step, result))
    stage = StageReporter(progress).stage("vanilla training", config.iterations)
    load, recent = [], []

    def on_step(report: StepReport) -> None:
        recent.append((report.loss, report.psnr))
        del recent[:-50]
        stage.update(1, loss=report.loss, psnr=report.psnr, gaussians=len(model))
        if report.step % 100 == 0:
            load.append(os.getloadavg()[0])

    psnr_start = loop.mean_psnr()
    start = time.perf_counter()
    loop.run(on_step)
    seconds = time.perf_counter() - start
    psnr_end = loop.mean_psnr()
    final_loss, final_psnr = (float(v) for v in np.mean(recent, axis=0))
    stage.done(f"{len(model)} Gaussians, last 50 steps: loss {final_loss:.4f}, "
               f"PSNR {final_psnr:.2f} dB")
    return Trained(model.to_cloud(), seconds, densifier, final_loss, final_psnr, psnr_start,
                   psnr_end, load)


def peak_gpu_mib() -> float | None:
    """The most GPU memory torch held at once in this process (None without CUDA)."""
    if not torch.cuda.is_available() or not torch.cuda.is_initialized():
        return None
    return round(torch.cuda.max_memory_allocated() / 2**20, 1)


def git_commit() -> str | None:
    try:
        return subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True,
                              check=True, cwd=Path(__file__).parent).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return None


def record(args: argparse.Namespace, config: VanillaConfig, targets: Targets, run: Trained,
           test: dict) -> dict:
    """MODEL.json: how the model was made and what it scores."""
    camera = targets.views[0].camera
    events = run.densifier.events
    return {
        "command": "python bench/train_vanilla.py " + shlex.join(args.argv),
        "dataset": str(Path(args.dataset).resolve()), "downscale": args.downscale,
        "resolution": [camera.width, camera.height], "training_views": len(targets.views),
        "config": asdict(config), "sh_every": config.sh_every, "extent": targets.extent,
        "gaussians": len(run.cloud), "training_seconds": round(run.seconds, 1),
        "seconds_per_step": round(run.seconds / config.iterations, 4),
        "final_train_loss": round(run.final_loss, 5),
        "final_train_psnr": round(run.final_psnr, 3),
        "train_psnr_8_views": {"start": round(run.psnr_start, 3), "end": round(run.psnr_end, 3)},
        "peak_rss_mib": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
        "peak_gpu_mib": peak_gpu_mib(),
        "load_average": {"start": args.load_start, "during_mean":
                         round(float(np.mean(run.load)), 2) if run.load else None,
                         "end": round(os.getloadavg()[0], 2)},
        "densification": [asdict(e) for e in events],
        "opacity_resets": run.densifier.resets,
        "test": test,
        "machine": {"cpus": os.cpu_count(), "torch_threads": torch.get_num_threads(),
                    "device": torch.cuda.get_device_name() if args.device == "cuda" else "cpu",
                    "renderer": resolve_backend("auto", torch.device(args.device)),
                    "nice": os.nice(0), "platform": platform.platform(),
                    "torch": torch.__version__, "python": platform.python_version()},
        "git_commit": git_commit(),
        "date": time.strftime("%Y-%m-%d %H:%M:%S %z"),
    }


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("dataset", help="dataset folder (COLMAP, transforms.json or LLFF)")
    p.add_argument("-o", "--output", required=True, type=Path, help="MODEL.ply to write "
                   "(MODEL.json is written beside it)")
    p.add_argument("--downscale", type=int, default=4, help="image downscale factor (default 4)")
    p.add_argument("--iterations", type=int, default=3000, help="training steps (default 3000)")
    p.add_argument("--init-points", type=int, default=100_000,
                   help="random initial Gaussians (default 100000, INRIA's)")
    p.add_argument("--sh-degree", type=int, default=3, choices=range(4), help="default 3")
    p.add_argument("--grad-threshold", type=float, default=0.0002,
                   help="densify from this mean view-space gradient (NDC; default 0.0002). Tiny "
                        "images give larger gradients per Gaussian and want a larger value")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--threads", type=int, default=None, help="torch CPU threads")
    p.add_argument("--device", default="cpu", choices=["cpu", "cuda"],
                   help="where the Gaussians train (gsplat on CUDA where it imports, else the "
                        "torch renderer) (default: cpu)")
    p.add_argument("--eval-device", default=None, choices=["cpu", "cuda"],
                   help="where the test split renders (default: --device)")
    p.add_argument("--max-views", type=int, default=None,
                   help="use at most this many training views (default: all)")
    p.add_argument("--no-eval", action="store_true", help="skip the test-split evaluation")
    p.add_argument("--quiet", action="store_true")
    args = p.parse_args(argv)
    args.argv = list(sys.argv[1:] if argv is None else argv)
    if args.iterations < 1 or args.init_points < 1 or args.downscale < 1 \
            or not args.grad_threshold > 0:
        p.error("--iterations, --init-points, --downscale and --grad-threshold must be positive")
    return args


def main(argv: list[str] | None = None) -> dict:
    args = parse_args(argv)
    args.load_start = round(os.getloadavg()[0], 2)
    if args.threads:
        torch.set_num_threads(args.threads)
    dataset = load_dataset(args.dataset, downscale=args.downscale)
    try:
        device = resolve_device(args.device)
    except RuntimeError as exc:
        raise SystemExit(f"--device {args.device}: {exc}; use --device cpu") from None
    targets = dataset_targets(dataset, device, args.max_views)
    white = all(c >= 1.0 for c in targets.background)
    config = VanillaConfig(iterations=args.iterations, init_points=args.init_points,
                           sh_degree=args.sh_degree, seed=args.seed,
                           densify=DensifyConfig(grad_threshold=args.grad_threshold,
                                                 reset_at_start=white).scaled(args.iterations))
    run = train(targets, config, device, progress=not args.quiet)
    write_ply(args.output, run.cloud)
    test = {}
    if not args.no_eval and dataset.test:
        report = evaluate_against_dataset(run.cloud, Path(args.dataset), EvalConfig(
            downscale=args.downscale, device=args.eval_device or args.device))
        test = {"psnr": round(report.psnr, 3), "ssim": round(report.ssim, 4),
                "views": len(report.views)}
    doc = record(args, config, targets, run, test)
    atomic_write(args.output.with_suffix(".json"), (json.dumps(doc, indent=1) + "\n").encode())
    if not args.quiet:
        print(f"wrote {args.output} ({len(run.cloud)} Gaussians, {run.seconds:.0f} s); "
              f"test PSNR {test.get('psnr', 'n/a')} dB, SSIM {test.get('ssim', 'n/a')}",
              file=sys.stderr)
    return doc


if __name__ == "__main__":
    main()
