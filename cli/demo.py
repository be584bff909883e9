"""``spcodec demo``: the whole pipeline on a built-in scene, with no input files and no GPU.

It generates the synthetic scene of :mod:`spcodec.synthetic` (Gaussians along curves plus scattered
blobs), encodes it with the reference encoder (no retraining), writes ``demo.spc``, decodes it,
writes ``demo.ply`` and, when the renderer's dependencies are installed, renders both models at a few
views and reports PSNR/SSIM of the decoded scene against the original.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from spcodec.errors import UsageError

from .options import EXIT_OK, SEED

NAME = "demo"
HELP = "run the pipeline on a built-in synthetic scene and write demo.spc/demo.ply"


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("-o", "--output-dir", default="spcodec-demo",
                   help="folder for demo.spc and demo.ply, created if missing (default: "
                   "%(default)s)")
    p.add_argument("--seed", type=SEED, default=0,
                   help="seed of the built-in scene: %(type)s (default: %(default)s)")


def run(args: argparse.Namespace) -> int:
    return run_demo(Path(args.output_dir), seed=args.seed)


def run_demo(out_dir: Path, seed: int = 0) -> int:
    """Encode, decode and (when possible) evaluate the built-in scene; files go to ``out_dir``."""
    from spcodec.decoder import decode_layers
    from spcodec.encoder.config import EncoderConfig
    from spcodec.encoder.pipeline import encode
    from spcodec.encoder.progress import StageReporter, print_summary
    from spcodec.fileio import atomic_write
    from spcodec.ply import write_ply
    from spcodec.synthetic import make_scene

    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UsageError(f"cannot create {out_dir}: {exc.strerror}") from None
    scene = make_scene(seed)
    original = scene.cloud
    print(f"built-in scene: {len(original):,} Gaussians ({int(scene.structured.sum()):,} along "
          f"{int(scene.curve_id.max()) + 1} curves, the rest scattered), SH degree "
          f"{original.sh_degree}")
    write_ply(out_dir / "original.ply", original)
    result = encode(original, EncoderConfig(seed=seed), progress=StageReporter().stage,
                    source_name="built-in synthetic scene")
    atomic_write(out_dir / "demo.spc", result.data)
    start = time.perf_counter()
    decoded = decode_layers(result.data)
    elapsed = time.perf_counter() - start
    write_ply(out_dir / "demo.ply", decoded.cloud)
    print_summary(dict(result.stats.to_json(),
                       input_bytes=(out_dir / "original.ply").stat().st_size,
                       output=str(out_dir / "demo.spc")))
    print(f"decoded in {elapsed * 1000:.1f} ms -> {out_dir / 'demo.ply'}")
    for layer in decoded.layers:
        print(f"  layer {layer.index} ({layer.kind}): {len(layer.cloud):,} Gaussians, complete at "
              f"byte {layer.end_offset:,}")
    _report_quality(decoded.cloud, original)
    return EXIT_OK


def _report_quality(decoded, original) -> None:
    """PSNR/SSIM of the decoded scene against the original at sampled views, if torch is here."""
    from spcodec.imaging.evaluate import EvalConfig, evaluate_against_reference

    try:
        report = evaluate_against_reference(decoded, original, EvalConfig(
            views=4, resolution=256, device="cpu", up="-y", closeups=(0.5,),
            closeup_resolution=512))
    except ModuleNotFoundError as exc:  # the renderer needs torch (extra "encoder")
        print(f"quality: skipped ({exc.name} is not installed: pip install 'spcodec[encoder]')")
        return
    close = report.framing(0.5)
    print(f"quality vs original: PSNR {report.psnr:.2f} dB, SSIM {report.ssim:.4f} over "
          f"{len(report.views)} views of {report.width}x{report.height}; at half the distance "
          f"PSNR {close.psnr:.2f} dB, SSIM {close.ssim:.4f} ({close.width}x{close.height}) "
          f"({report.seconds:.1f} s)")
