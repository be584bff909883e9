"""Which distortion model predicts the rendered error of quantizing one attribute (issue 37).

A rate-distortion search over every stored quantity's precision needs each option's distortion
without rendering it. This bench measures two candidate models against renders. Each option is
one attribute's codebook (entry dimension and entry count) or a position grid. The *hybrid* is
the input scene with that one attribute replaced by what the option stores, rendered at eval's
held-out views (the sampled framing and half its distance, 256 pixels, our renderer), against
the input rendered the same way. The models are:

* **weighted**: the attribute's squared error in its coded domain, weighted by each Gaussian's
  blend-weight importance (what weighted k-means minimizes);
* **gradient**: the expected image MSE of the linearized renderer, sum over Gaussians and
  parameters of ``F * delta^2`` (:mod:`spcodec.imaging.sensitivity`, the encoder's own model),
  ``--samples`` random projections per view, at the same views.

One row per option: both predictions, the measured MSE at both framings, and the index columns'
order-0 entropy plus the codebook (bytes). ::

    python bench/bench_distortion_model.py SCENE.ply --json out.json [--up=-y] [--samples 2]
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np
import torch

from spcodec.attributes import PatchAttribute
from spcodec.cloud import GaussianCloud
from spcodec.decoder.layers import fill_patch_attributes
from spcodec.encoder.config import PatchConfig
from spcodec.encoder.patch import PatchEncoder, assign_attribute, coded_attributes, train_codebook
from spcodec.imaging.render import GaussianParams, RenderSettings, render_image
from spcodec.imaging.sensitivity import Sensitivity, render_sensitivity
from spcodec.imaging.views import robust_bounds, sample_views
from spcodec.ply import read_ply
from spcodec.sections import Codebook

LADDERS = {"SCALE": [3, 1], "ROTATION": [4, 2, 1], "OPACITY": [1], "COLOR_DC": [3, 1],
           "SH_BAND_1": [9, 3, 1], "SH_BAND_2": [15, 3, 1], "SH_BAND_3": [21, 3, 1]}
"""Entry dimensions tried per attribute, coarsest first (each divides the attribute's width)."""
ENTRIES = (256, 64)
POSITION_BITS = (10, 12, 14)


class Views:
    """The held-out views at both framings and the input's renders there."""

    def __init__(self, cloud: GaussianCloud, up: str, resolution: int, count: int) -> None:
        orbit = sample_views(cloud, count, resolution=(resolution, resolution), split="eval",
                             up=up, seed=0)
        centre = robust_bounds(cloud).centre
        self.framings = {"orbit": orbit, "close": [c.dollied(centre, 0.5) for c in orbit]}
        self.settings = RenderSettings(background=(0.0, 0.0, 0.0))
        self.reference = {name: [render_image(cloud, c, self.settings) for c in cams]
                          for name, cams in self.framings.items()}

    def measured(self, hybrid: GaussianCloud) -> dict[str, float]:
        """Mean image MSE of ``hybrid`` per framing."""
        params = GaussianParams.from_cloud(hybrid)
        return {name: float(np.mean([np.mean((render_image(params, c, self.settings) - r) ** 2)
                                     for c, r in zip(cams, self.reference[name])]))
                for name, cams in self.framings.items()}

    def sensitivity(self, cloud: GaussianCloud, samples: int) -> dict[str, Sensitivity]:
        """Per framing, the renderer linearized (:mod:`spcodec.imaging.sensitivity`)."""
        return {name: render_sensitivity(cloud, cams, self.settings, samples)
                for name, cams in self.framings.items()}


def gradient_prediction(sensitivity: dict[str, Sensitivity], hybrid: GaussianCloud,
                        cloud: GaussianCloud) -> dict[str, float]:
    return {name: float(s.mse(cloud, hybrid).sum()) for name, s in sensitivity.items()}


def entropy_bytes(indices: np.ndarray) -> float:
    """Order-0 entropy of each index column, in bytes (per-column Huffman is within 1 %)."""
    total = 0.0
    for column in indices.T:
        p = np.bincount(column, minlength=256) / len(column)
        p = p[p > 0]
        total -= (p * np.log2(p)).sum() * len(column) / 8
    return total


def options(cloud: GaussianCloud, weights: np.ndarray | None, config: PatchConfig):
    """(attribute, entry dim, entries, hybrid, coded error, rate bytes) for every option."""
    values = coded_attributes(cloud)
    for attr, coded in values.items():
        for dim in LADDERS[attr.name]:
            for size in ENTRIES:
                entries = train_codebook(coded, dim, size, weights, config, 1)
                idx = assign_attribute(attr, coded, entries)
                hybrid = cloud.subset(np.arange(len(cloud)))
                fill_patch_attributes({attr: idx.T}, [Codebook(attr, entries)], hybrid)
                back = coded_attributes(hybrid)[attr]
                if attr is PatchAttribute.ROTATION:
                    back = np.sign((back * coded).sum(axis=1, keepdims=True) + 1e-30) * back
                error = ((back - coded) ** 2).sum(axis=1)
                yield attr.name, dim, size, hybrid, error, entropy_bytes(idx) + entries.size * 2
    lo = cloud.means.min(axis=0)
    span = float((cloud.means.max(axis=0) - lo).max())
    for bits in POSITION_BITS:
        step = span / ((1 << bits) - 1)
        hybrid = cloud.subset(np.arange(len(cloud)))
        hybrid.means[:] = (np.round((cloud.means - lo) / step) * step + lo).astype(np.float32)
        yield "POSITION", bits, 0, hybrid, ((hybrid.means - cloud.means) ** 2).sum(axis=1), None


def main(argv: list[str] | None = None) -> list[dict]:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("scene")
    p.add_argument("--json", required=True)
    p.add_argument("--up", default="-y")
    p.add_argument("--views", type=int, default=4)
    p.add_argument("--resolution", type=int, default=256)
    p.add_argument("--samples", type=int, default=2)
    args = p.parse_args(argv)
    torch.set_num_threads(1)
    cloud = read_ply(args.scene)
    config = PatchConfig()
    encoder = PatchEncoder(config, seed=0, jobs=1)
    importance = encoder.measure_importance(cloud)
    share = importance / importance.sum()
    views = Views(cloud, args.up, args.resolution, args.views)
    start = time.perf_counter()
    sensitivity = views.sensitivity(cloud, args.samples)
    seconds = time.perf_counter() - start
    rows = []
    for name, dim, size, hybrid, error, rate in options(cloud, encoder.kmeans_weights(importance),
                                                         config):
        measured = views.measured(hybrid)
        gradient = gradient_prediction(sensitivity, hybrid, cloud)
        rows.append({"attribute": name, "entry_dim_or_bits": dim, "entries": size,
                     "weighted": float((share * error).sum()), "gradient": gradient,
                     "measured": measured, "rate_bytes": rate})
        print(f"{name:10s} {dim:3d} {size:4d}  " + "  ".join(
            f"{f}: measured {measured[f]:.2e} gradient/measured "
            f"{gradient[f] / max(measured[f], 1e-30):.2f}" for f in measured), flush=True)
    doc = {"scene": args.scene.split("/")[-1], "gaussians": len(cloud),
           "sensitivity_seconds": round(seconds, 1),
           "settings": {k: v for k, v in vars(args).items() if k not in ("scene", "json")},
           "rows": rows}
    with open(args.json, "w") as fh:
        json.dump(doc, fh, indent=1)
    return rows


if __name__ == "__main__":
    main(sys.argv[1:])
