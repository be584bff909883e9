"""Retraining on one scene, two questions the encoder's defaults rest on (docs/LOG.md, section 11).

``convergence``: PSNR of the pruned and retrained patch (unquantized, no sketch: every Gaussian is
patch) against renders of the original at ``spcodec eval``'s 8 held-out views, after 0, 250, 500,
1000, ... steps, for one prune method. Run it for ``importance`` and ``uniform`` to compare them.

``quantize``: how much each attribute's codebook costs after retraining. The patch is pruned by
importance, retrained for ``--steps``, then quantized with each preset's codebooks of a no-retrain
encode; PSNR on 12 training views with everything quantized and with
one attribute at a time.

    python bench/bench_retrain.py convergence SCENE.ply --method importance [--factor 4]
        [--steps 3000] [--resolution 400] [--up -y]
    python bench/bench_retrain.py quantize SCENE.ply [--factor 4] [--steps 300]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch

import spcodec
from spcodec.cloud import GaussianCloud
from spcodec.decoder.layers import fill_patch_attributes
from spcodec.encoder.config import RetrainConfig
from spcodec.encoder.patch import PatchEncoder, quantized_cloud
from spcodec.encoder.presets import preset_config
from spcodec.encoder.prune import kept_count, select
from spcodec.encoder.retraining.control import RunControl
from spcodec.encoder.retraining.stage import RetrainStage, spread
from spcodec.encoder.statistics import RetrainStats
from spcodec.imaging.evaluate import EvalConfig, evaluate_against_reference
from spcodec.imaging.importance import blend_weights
from spcodec.imaging.render import GaussianParams, RenderSettings, render
from spcodec.imaging.training.loop import FitLoop
from spcodec.imaging.training.loss import psnr_of
from spcodec.imaging.training.optim import FreeGaussians
from spcodec.imaging.training.targets import distillation_targets
from spcodec.imaging.views import sample_views

CHECKPOINTS = (250, 500, 1000, 1500, 2000, 3000, 4000)


def convergence(args) -> None:
    cloud = spcodec.read_ply(args.scene)
    settings = RenderSettings()
    cameras = sample_views(cloud, 48, resolution=(args.resolution, args.resolution),
                           split="train", up=args.up)
    targets = distillation_targets(cloud, cameras, settings, torch.device("cpu"))
    weights = blend_weights(cloud, spread(cameras, 16), settings)
    keep = select(args.method, len(cloud), kept_count(len(cloud), args.factor), 0, weights)
    model = FreeGaussians(cloud.subset(keep), "cpu", extent=targets.extent)
    loop = FitLoop(model, targets, settings, args.steps)
    judge = EvalConfig(device="cpu", up=args.up)
    print(f"{args.method}: {len(keep)} of {len(cloud)} kept")
    print("| steps | PSNR dB | seconds |\n|---:|---:|---:|")
    print(f"| 0 | {evaluate_against_reference(model.to_cloud(), cloud, judge).psnr:.2f} | 0 |",
          flush=True)
    start = time.perf_counter()
    for stop in (c for c in CHECKPOINTS if c <= args.steps):
        while loop.step < stop:
            loop.one_step()
        psnr = evaluate_against_reference(model.to_cloud(), cloud, judge).psnr
        print(f"| {stop} | {psnr:.2f} | {time.perf_counter() - start:.0f} |", flush=True)


def quantize(args) -> None:
    cloud = spcodec.read_ply(args.scene)
    config = RetrainConfig(iterations=args.steps, views=24, resolution=200, finish_iterations=0)
    settings = RenderSettings()
    cameras = sample_views(cloud, config.views, resolution=(200, 200), split="train")
    targets = distillation_targets(cloud, cameras, settings, torch.device("cpu"))
    nothing = GaussianCloud.zeros(0, cloud.sh_degree)
    stage = RetrainStage(config, targets, nothing, PatchEncoder(), 0, RunControl(device="cpu"))
    weights = stage.patch_weights(cloud, np.arange(len(cloud)))
    keep = select("importance", len(cloud), kept_count(len(cloud), args.factor), 0, weights)
    trained = stage.retrain(cloud.subset(keep), RetrainStats(config.prune))

    def psnr(model: GaussianCloud) -> float:
        params = GaussianParams.from_cloud(model)
        return float(np.mean([psnr_of(render(params, v.camera, settings).image.clamp(0, 1),
                                      v.image) for v in targets.views[:12]]))

    print(f"retrained ({len(keep)} Gaussians, {args.steps} steps): {psnr(trained):.2f} dB")
    books = {name: preset_config(name).patch for name in ("lowrate", "balanced", "highrate")}
    for name, patch_config in books.items():
        stage.patch_encoder = PatchEncoder(patch_config)
        quantized, _ = stage.quantize(trained)
        whole = psnr(quantized_cloud(quantized, trained.means, trained.sh_degree))
        alone = []
        for book in quantized.codebooks:
            model = trained.subset(np.arange(len(trained)))
            fill_patch_attributes({book.attribute: quantized.indices[book.attribute].T}, [book],
                                  model)
            alone.append(f"{book.attribute.name} {psnr(model):.2f}")
        print(f"{name} codebooks: all quantized {whole:.2f} dB; one at a time: "
              + ", ".join(alone), flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="command", required=True)
    conv = sub.add_parser("convergence")
    conv.add_argument("scene")
    conv.add_argument("--method", choices=["importance", "uniform"], default="importance")
    conv.add_argument("--factor", type=float, default=4.0)
    conv.add_argument("--steps", type=int, default=3000)
    conv.add_argument("--resolution", type=int, default=400)
    conv.add_argument("--up", default="-y")
    quant = sub.add_parser("quantize")
    quant.add_argument("scene")
    quant.add_argument("--factor", type=float, default=4.0)
    quant.add_argument("--steps", type=int, default=300)
    args = ap.parse_args()
    torch.set_num_threads(1)
    {"convergence": convergence, "quantize": quantize}[args.command](args)


if __name__ == "__main__":
    main()
