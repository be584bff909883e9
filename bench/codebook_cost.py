"""What each codebook costs a retrained patch, at the count rate control chose (docs/LOG.md 13.12).

Runs ``spcodec encode`` with the given arguments; at the start of the quantization-aware finish,
where the retrained patch and its codebooks are both at hand, it renders the training views
(PSNR against the distillation targets, sketch in front) for:

* the patch as the file codes it, and as trained (no codebook at all);
* each attribute in turn put back to its trained value, the others coded;
* a residual codebook per SH band (256 entries k-means on the first codebook's error, the coded
  value the sum of two entries: a coding the format does not have), all bands at once;
* the SH bands above degree ``d - 1`` and ``d - 2`` set to zero (what a per-Gaussian SH rate
  term could give up).

It prints one JSON line (``RESULT {...}``) and stops: no file is written, and the checkpoint the
encode leaves beside ``-o`` is removed.

    python bench/codebook_cost.py encode fourth_st_inria.ply -o /tmp/x.spc \
        --target-size 785328 --iterations 1000 --threads 1
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np
from sklearn.cluster import KMeans

import spcodec.cli as cli
from spcodec.attributes import PatchAttribute
from spcodec.cloud import GaussianCloud
from spcodec.encoder.patch import Quantized, quantized_cloud
from spcodec.encoder.retraining import stage as retrain

RESIDUAL_ENTRIES = 256


def with_trained(coded: GaussianCloud, trained: GaussianCloud,
                 attribute: PatchAttribute) -> GaussianCloud:
    """``coded`` with one attribute taken from ``trained`` (in place; returns it)."""
    if attribute == PatchAttribute.SCALE:
        coded.scales[:] = trained.scales
    elif attribute == PatchAttribute.ROTATION:
        coded.quats[:] = trained.quats
    elif attribute == PatchAttribute.OPACITY:
        coded.opacities[:] = trained.opacities
    elif attribute == PatchAttribute.COLOR_DC:
        coded.sh_dc[:] = trained.sh_dc
    else:
        coded.sh_rest[:, attribute.sh_slice, :] = trained.sh_rest[:, attribute.sh_slice, :]
    return coded


def with_residual_sh(coded: GaussianCloud, trained: GaussianCloud, seed: int) -> dict:
    """Add a second, residual codebook's entry to every SH band of ``coded`` (in place); the
    RMS error of each band before and after."""
    errors = {}
    for attribute in PatchAttribute.for_sh_degree(trained.sh_degree)[4:]:
        rows = attribute.sh_slice
        error = (trained.sh_rest[:, rows, :] - coded.sh_rest[:, rows, :]).reshape(len(coded), -1)
        means = KMeans(n_clusters=min(RESIDUAL_ENTRIES, len(coded)), n_init=1,
                       random_state=seed).fit(error)
        entries = means.cluster_centers_.astype(np.float16).astype(np.float32)[means.labels_]
        coded.sh_rest[:, rows, :] += entries.reshape(len(coded), -1, 3)
        errors[attribute.name] = [float(np.sqrt((error ** 2).mean())),
                                  float(np.sqrt(((error - entries) ** 2).mean()))]
    return errors


def measure(stage: "retrain.RetrainStage", trained: GaussianCloud, quantized: Quantized) -> dict:
    """Training-view PSNR of the codings above."""
    degree = trained.sh_degree
    coded = lambda: quantized_cloud(quantized, trained.means, degree)  # noqa: E731 - fresh copy
    out = {"gaussians": len(trained), "psnr_coded": stage.psnr(coded()),
           "psnr_trained": stage.psnr(trained)}
    for attribute in PatchAttribute.for_sh_degree(degree):
        out[f"psnr_exact_{attribute.name}"] = stage.psnr(with_trained(coded(), trained, attribute))
    if degree:
        cloud = coded()
        out["sh_rms_error_first_then_residual"] = with_residual_sh(cloud, trained, seed=0)
        out["psnr_residual_sh"] = stage.psnr(cloud)
    for keep in range(max(degree - 2, 0), degree):
        cloud = coded()
        cloud.sh_rest[:, (keep + 1) ** 2 - 1:, :] = 0
        out[f"psnr_sh_above_degree_{keep}_zeroed"] = stage.psnr(cloud)
    return {k: round(v, 3) if isinstance(v, float) else v for k, v in out.items()}


def main(argv: list[str]) -> int:
    output = Path(argv[argv.index("-o") + 1])

    def finish(stage, trained, quantized, stats, on_step=None, priority=None):
        start = time.perf_counter()
        result = measure(stage, trained, quantized)
        result["seconds"] = round(time.perf_counter() - start, 1)
        print("RESULT " + json.dumps(result), flush=True)
        raise SystemExit(0)

    retrain.RetrainStage.finish = finish
    try:
        return cli.main(argv)
    finally:
        Path(f"{output}.ckpt").unlink(missing_ok=True)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
