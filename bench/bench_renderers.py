"""Where our renderer and the viewer's disagree, and why: the same files judged by both.

For an original PLY and decoded versions of it (an SPZ round trip, our files), at the viewer's own
cameras (the orbit framing and half its distance, 512x512: :mod:`viewer_yardstick`):

* **viewer**: PSNR against the original, both rendered by PlayCanvas in Chromium;
* **ours, blur 0.3**: the same, both rendered by our renderer at the same cameras with INRIA's
  screen-space low-pass (0.3 px^2, what our eval and training use);
* **ours, blur 0.075**: with PlayCanvas's low-pass (0.3 in half-pixel units);
* **agreement**: the original rendered by our renderer against the viewer's render of it (how
  close the two renderers are on the same Gaussians);
* **eval**: ``spcodec eval --reference`` (our framing, 400x400, and 1/2 distance at 800x800).

    python bench/bench_renderers.py ORIGINAL.ply NAME=DECODED.ply [...] [--up -y] [--antialiased]
                                    [--cache DIR] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))

import spcodec  # noqa: E402
from spcodec.imaging.evaluate import EvalConfig, evaluate_against_reference  # noqa: E402
from spcodec.imaging.images import read_image  # noqa: E402
from spcodec.imaging.metrics import psnr  # noqa: E402
from spcodec.imaging.render import GaussianParams, RenderSettings, render_image  # noqa: E402

from viewer_yardstick import cameras_of, missing, reference, render_like  # noqa: E402

BLURS = (0.3, 0.075)


def ours(cloud, cameras, blur: float, antialiased: bool) -> list[np.ndarray]:
    """Our renders of ``cloud`` at ``cameras`` (black background, clamped, 8-bit rounded like a
    PNG so both renderers are compared on the same footing)."""
    params = GaussianParams.from_cloud(cloud, "cpu")
    settings = RenderSettings(antialiased=antialiased, blur_variance=blur)
    return [np.round(render_image(params, c, settings) * 255) / 255 for c in cameras]


def finite(cloud):
    """``cloud`` with infinite opacity logits (an opacity of exactly 0 or 1, as SPZ round trips
    write) replaced by +-20, which renders the same; our renderer refuses non-finite input."""
    cloud.opacities = np.nan_to_num(cloud.opacities, posinf=20.0, neginf=-20.0)
    return cloud


def mean_psnr(a: list[np.ndarray], b: list[np.ndarray]) -> float:
    return float(np.mean([psnr(x, y) for x, y in zip(a, b)]))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("original", type=Path)
    ap.add_argument("models", nargs="+", help="NAME=DECODED.ply")
    ap.add_argument("--up", default="-y")
    ap.add_argument("--antialiased", action="store_true")
    ap.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "spcodec-yardstick")
    ap.add_argument("--json", type=Path)
    args = ap.parse_args()
    if (reason := missing()) is not None:
        sys.exit(f"cannot run the viewer: {reason}")
    refs = reference(args.original, args.cache, args.up, args.antialiased)
    original = spcodec.read_ply(args.original)
    cams = {name: cameras_of(folder) for name, folder in refs.items()}
    viewer_orig = {name: [read_image(p) for p in sorted(folder.glob("view_*.png"))]
                   for name, folder in refs.items()}
    ours_orig = {(name, blur): ours(original, cams[name], blur, args.antialiased)
                 for name in refs for blur in BLURS}
    rows = [{"model": "original (agreement: ours vs viewer)", **{
        f"{name} ours {blur}": round(mean_psnr(ours_orig[name, blur], viewer_orig[name]), 2)
        for name in refs for blur in BLURS}}]
    for spec in args.models:
        label, path = spec.split("=", 1)
        cloud = finite(spcodec.read_ply(path))
        row = {"model": label}
        with tempfile.TemporaryDirectory() as tmp:
            for name, folder in refs.items():
                out = render_like(Path(path), folder, Path(tmp) / name, args.antialiased)
                shots = [read_image(p) for p in sorted(out.glob("view_*.png"))]
                row[f"{name} viewer"] = round(mean_psnr(shots, viewer_orig[name]), 2)
                for blur in BLURS:
                    row[f"{name} ours {blur}"] = round(mean_psnr(
                        ours(cloud, cams[name], blur, args.antialiased), ours_orig[name, blur]), 2)
        report = evaluate_against_reference(cloud, original, EvalConfig(
            device="cpu", up=args.up, antialiased=args.antialiased, closeups=(0.5,)))
        row["eval"], row["eval close 0.5"] = round(report.psnr, 2), round(
            report.framing(0.5).psnr, 2)
        rows.append(row)
        print(json.dumps(row), flush=True)
    print(json.dumps(rows[0]))
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
