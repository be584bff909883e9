"""Quality against a peer, in one run: SPZ (a real implementation) and our no-retrain presets.

For each shared scene, the input PLY is (a) written as SPZ by a real SPZ implementation and decoded
back to PLY, and (b) encoded by spcodec with each preset and decoded. Both are rendered against the
input PLY at the same held-out sampled views (``spcodec eval --reference`` semantics) and compared.

SPZ implementation: PlayCanvas ``splat-transform`` (npm ``@playcanvas/splat-transform``) when its
CLI is on PATH or named by ``$SPLAT_TRANSFORM``; else ``gsply`` (PyPI). Neither is a dependency of
spcodec; install one by hand to run this benchmark.

    python bench/bench_quality.py [--scenes fourth_st biker donut guitar kacytran] [--views 8]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

import spcodec
from spcodec.encoder.pipeline import encode
from spcodec.encoder.presets import PRESETS, preset_config
from spcodec.imaging.evaluate import EvalConfig, evaluate_against_reference

from scenes import data_dir  # bench/ is on sys.path

SCENES = {  # name: (path under $SPCODEC_DATA, up axis, rendered antialiased)
    "fourth_st": ("pdal_fourth_st_spz/fourth_st_inria.ply", "-y", False),
    "biker": ("playcanvas_biker_guitar/biker_from_spz_inria.ply", "-y", False),
    "donut": ("v3dg_donut_mipsplatting/fused.ply", "+z", True),
    "guitar": ("playcanvas_biker_guitar/guitar_inria.ply", "-y", False),
    "kacytran": ("kacytran_try_sh3/point_cloud_iteration_7000.ply", "-y", False),
}


def spz_round_trip(ply: Path, work: Path) -> tuple[str, int, spcodec.GaussianCloud]:
    """(tool, SPZ bytes, decoded cloud) for the input PLY through a real SPZ implementation."""
    tool = os.environ.get("SPLAT_TRANSFORM") or shutil.which("splat-transform")
    spz, back = work / "peer.spz", work / "peer.ply"
    if tool:
        subprocess.run([tool, "-w", str(ply), str(spz)], check=True, capture_output=True)
        subprocess.run([tool, "-w", str(spz), str(back)], check=True, capture_output=True)
        return "splat-transform", spz.stat().st_size, spcodec.read_ply(back)
    import gsply  # noqa: PLC0415 - optional peer

    data = gsply.plyread(str(ply))
    gsply.write_spz(str(spz), data)
    gsply.plywrite(str(back), gsply.read_spz(str(spz)))
    return "gsply", spz.stat().st_size, spcodec.read_ply(back)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", nargs="+", default=list(SCENES))
    ap.add_argument("--views", type=int, default=8)
    ap.add_argument("--resolution", type=int, default=400)
    ap.add_argument("--json", type=Path, help="also write the rows as JSON")
    args = ap.parse_args()
    rows = []
    for name in args.scenes:
        rel, up, antialiased = SCENES[name]
        ply = data_dir() / rel
        cloud = spcodec.read_ply(ply)
        config = EvalConfig(views=args.views, resolution=args.resolution, device="cpu", up=up,
                            antialiased=antialiased)
        with tempfile.TemporaryDirectory() as tmp:
            tool, spz_size, spz_cloud = spz_round_trip(ply, Path(tmp))
        report = evaluate_against_reference(spz_cloud, cloud, config)
        rows.append(dict(scene=name, codec=f"SPZ ({tool})", bytes=spz_size, psnr=report.psnr,
                         ssim=report.ssim, seconds=None, spz=spz_size, ply=ply.stat().st_size))
        for preset in PRESETS:
            start = time.perf_counter()
            result = encode(cloud, preset_config(preset))
            seconds = time.perf_counter() - start
            report = evaluate_against_reference(spcodec.decode(result.data), cloud, config)
            rows.append(dict(scene=name, codec=f"spcodec {preset}", bytes=len(result.data),
                             psnr=report.psnr, ssim=report.ssim, seconds=seconds, spz=spz_size,
                             ply=ply.stat().st_size, sketch=result.stats.sketch_gaussians))
        print(f"{name}: done", flush=True)
    print(f"renders: {args.views} held-out views of {args.resolution}x{args.resolution} "
          f"against the input PLY")
    print("| scene | codec | bytes | vs PLY | vs SPZ | PSNR dB | SSIM | encode s |")
    print("|---|---|---:|---:|---:|---:|---:|---:|")
    for r in rows:
        enc = f"{r['seconds']:.1f}" if r["seconds"] is not None else "-"
        print(f"| {r['scene']} | {r['codec']} | {r['bytes']:,} | {r['ply'] / r['bytes']:.1f}x | "
              f"{r['bytes'] / r['spz']:.2f} | {r['psnr']:.2f} | {r['ssim']:.4f} | {enc} |")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2))


if __name__ == "__main__":
    main()
