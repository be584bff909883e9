"""Rate-distortion curves: S&P++ retrained, Prune&Retrain, the no-retrain presets, SPZ and SOG, in one run.

For each scene every method is encoded from the same input PLY and judged the same ways:

* **the viewer** (the yardstick): the decoded file against the input, both rendered by the
  PlayCanvas engine in Chromium at its orbit framing and at half that distance (``orbit`` and
  ``close`` columns; :mod:`viewer_yardstick`, skipped with a note where it cannot run);
* **our eval**: renders against renders of the input at the 8 held-out sampled views of 400x400
  and at half their distance, 800x800 (``spcodec eval --reference``); for **lego** (dataset mode:
  the model trained by ``bench/train_vanilla.py`` retrained against the dataset's training images)
  against its test images (``spcodec eval --dataset``) as well.

Methods (the paper's section "Comparison Methods"):

* ``sp``: S&P++, ``spcodec encode`` (sketch + pruned and retrained patch, quantization-aware
  finish) at each ``--factors`` patch downsample;
* ``pr``: Prune&Retrain, every Gaussian treated as patch (``--no-sketch``) and pruned uniformly
  (``--prune uniform``) by the same factors, same retraining budget;
* ``noretrain``: the four no-retrain presets (``transparent`` keeps every Gaussian);
* ``spz``: a real SPZ writer (PlayCanvas splat-transform on PATH or ``$SPLAT_TRANSFORM``, else
  gsply), decoded back and judged like the rest;
* ``sog``: PlayCanvas's SOG, written by splat-transform on the CPU (``-g cpu``);
* ``spz4``: S&P++ aimed at a quarter of SPZ's bytes (``--target-size``), the issue's bar;
* ``sp-target``: S&P++ aimed at each ``--spz-fractions`` of SPZ's bytes (``--target-size``): the
  curve a user walks by asking for a size, where ``sp`` walks the patch downsample; its figure
  line runs through the ``spz4`` point, so the default shares leave the quarter out;
* ``pr-target``: Prune&Retrain aimed at each ``--pr-fractions`` of SPZ's bytes (the quarter
  included), the same size control as ``sp-target``: the two curves compare at equal bytes.
* ``nr-target``: no retraining, aimed at each ``--nr-fractions`` of SPZ's bytes: below the
  preset's file the least important are dropped, above it every Gaussian stays and the
  precision search (encoder/allocation.py) buys precision: the no-retrain curve a user walks;
* ``spu-target``, ``sps-target``: S&P++ with the patch pruned uniformly (``--prune uniform``)
  or sampled in proportion to blend weight (``--prune sampled``) at the ``--pr-fractions``: the
  sketch of ``sp-target`` with the pruning rule of ``pr-target`` or one between the two, which
  tells sketch and pruning rule apart where Prune&Retrain wins (docs/LOG.md 13.18).

Every encode runs as its own ``spcodec encode`` process under ``/usr/bin/time`` (peak memory
per run) with ``--stats`` (time per stage). With ``--encoded DIR`` a point whose file
``DIR/SCENE-METHOD-POINT.spc`` (and ``.stats.json``) exists is judged, not encoded: encodes made
elsewhere with the same options (on a lent GPU, say) join the same rows. Rows are appended to a
JSON file as they finish (each with the commit, the time and the machine's load), so an
interrupted sweep continues where it stopped; ``--plot DIR`` draws one PSNR-vs-size figure per
scene (log size axis) into DIR, SVG by bench/svg_chart.py (``--png``: matplotlib, installed by
hand), for a look at a sweep under way: the committed figures of ``docs/results/rd_sweep.json``
are bench/results_page.py's. ``--no-eval`` leaves out our eval where a loaded machine has no time
for it (the viewer's framings are what the targets name).

    python bench/bench_rd.py --json rd.json [--scenes fourth_st donut guitar kacytran lego]
        [--methods sp pr noretrain spz sog spz4 sp-target pr-target spu-target sps-target]
        [--factors 2 4 8 16]
        [--spz-fractions 0.0625 0.125 0.5] [--pr-fractions 0.0625 0.125 0.25 0.5]
        [--nr-fractions 0.125 0.25 0.5 0.6 0.75 0.9]
        [--presets transparent] [--iterations 3000] [--encoded DIR] [--no-eval]
        [--lego-model /path/lego.ply --lego-downscale 4] [--no-viewer]
    python bench/bench_rd.py --json rd.json --plot DIR [--png]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import spcodec
from spcodec.imaging.evaluate import EvalConfig, evaluate_against_dataset, evaluate_against_reference

import viewer_yardstick
from bench_quality import SCENES, spz_round_trip  # bench/ is on sys.path
from scenes import data_dir

LEGO_DATASET = "nerf_synthetic_lego"
METHODS = ("sp", "pr", "noretrain", "spz", "sog", "spz4", "sp-target", "pr-target", "spu-target",
           "sps-target", "nr-target")
SIZED = ("spz4", "sp-target", "pr-target", "spu-target", "sps-target", "nr-target")
"""Methods aimed at a share of SPZ's bytes: they need the scene's ``spz`` row first."""
PRUNE_RULE = {"pr": "uniform", "pr-target": "uniform", "spu-target": "uniform",
              "sps-target": "sampled"}
"""Methods with another pruning rule than the encoder's default (``--prune``)."""
NO_SKETCH = ("pr", "pr-target")
"""Prune&Retrain: every Gaussian patch (``--no-sketch``)."""
LABELS = {"sp": "S&P++ (retrained)", "pr": "Prune&Retrain", "noretrain": "no-retrain presets",
          "spz": "SPZ", "sog": "SOG", "spz4": "S&P++ at SPZ/4", "original": "original",
          # rows added by hand from single encodes (docs/LOG.md says which)
          "sp-highrate": "S&P++, highrate codebooks", "sp-target": "S&P++ --target-size",
          "nr-target": "no-retrain --target-size",
          "pr-target": "Prune&Retrain --target-size",
          "spu-target": "S&P++ --target-size --prune uniform",
          "sps-target": "S&P++ --target-size --prune sampled",
          "nosketch-target": "no sketch, importance pruning, --target-size (13.18)",
          "sp-target-uncapped": "S&P++ --target-size, sketch not capped (before 13.6)",
          "spz4-uncapped": "S&P++ at SPZ/4, sketch not capped (before 13.6)",
          "spz4-p12": "S&P++ at SPZ/4, 12-bit positions, 1000 steps (13.10)"}
PRESETS = ("lowrate", "balanced", "highrate", "transparent")
SINGLE_POINTS = ("spz", "sog", "spz4", "spz4-uncapped", "spz4-p12")
"""Methods with one point per scene, drawn larger than the curves."""


def scene_setup(name: str, args) -> dict:
    """Input PLY, view options and how to judge a scene."""
    if name == "lego":
        if not args.lego_model:
            raise SystemExit("lego needs --lego-model (a model made by bench/train_vanilla.py)")
        # Blender's world is z-up (the training cameras sit above z = 0.5): viewers orbit it so.
        # Retrained at INRIA's low-pass (0.3 px^2), which the vanilla model trained with and the
        # test-image PSNR renders with: at 200x200 the model itself scores 31.6 dB at 0.3 and
        # 26.5 at the viewer's 0.075, so a file trained at 0.075 is judged 4-5 dB low there.
        return {"ply": Path(args.lego_model), "up": "+z", "antialiased": False,
                "dataset": data_dir() / LEGO_DATASET, "downscale": args.lego_downscale,
                "blur_variance": 0.3}
    rel, up, antialiased = SCENES[name]
    return {"ply": data_dir() / rel, "up": up, "antialiased": antialiased, "dataset": None,
            "downscale": 1}


def judge(decoded: spcodec.GaussianCloud, original: spcodec.GaussianCloud, setup: dict,
          decoded_ply: Path | None = None, viewer: Path | None = None, ours: bool = True) -> dict:
    """PSNR/SSIM as ``spcodec eval`` measures them for this scene (and at half the distance),
    and, with ``viewer`` (a cache folder) and the decoded PLY, the viewer's two framings.
    ``ours=False`` skips our eval against renders of the input (a dataset's test images are
    always judged): on a loaded machine it halves a point's time, and the targets are the viewer's."""
    decoded = _finite(decoded)
    out = {}
    if setup["dataset"] is not None:
        report = evaluate_against_dataset(decoded, setup["dataset"], EvalConfig(
            downscale=setup["downscale"], device="cpu"))
        out.update(psnr=report.psnr, ssim=report.ssim)
    elif ours:
        report = evaluate_against_reference(decoded, original, EvalConfig(
            device="cpu", up=setup["up"], antialiased=setup["antialiased"], closeups=(0.5,)))
        close = report.framing(0.5)
        out.update(psnr=report.psnr, ssim=report.ssim, psnr_close=close.psnr,
                   ssim_close=close.ssim)
    if viewer is not None and decoded_ply is not None:
        out.update(viewer_yardstick.two_framings(setup["ply"], decoded_ply, viewer,
                                                 setup["up"], setup["antialiased"]))
    return out


def _finite(cloud: spcodec.GaussianCloud) -> spcodec.GaussianCloud:
    """Peers write an opacity of exactly 0 or 1 as an infinite logit; it renders as +-20."""
    import numpy as np
    cloud.opacities = np.nan_to_num(cloud.opacities, posinf=20.0, neginf=-20.0)
    return cloud


def sog_round_trip(ply: Path, work: Path) -> tuple[str, int, Path]:
    """(tool, SOG bytes, decoded PLY) through PlayCanvas splat-transform on the CPU."""
    import shutil
    tool = os.environ.get("SPLAT_TRANSFORM") or shutil.which("splat-transform")
    if not tool:
        raise SystemExit("sog needs splat-transform on PATH or $SPLAT_TRANSFORM")
    sog, back = work / "peer.sog", work / "peer.ply"
    subprocess.run([tool, "-w", "-g", "cpu", str(ply), str(sog)], check=True, capture_output=True)
    subprocess.run([tool, "-w", str(sog), str(back)], check=True, capture_output=True)
    return "splat-transform", sog.stat().st_size, back


def encode_args(method: str, param, setup: dict, args) -> list[str]:
    """The ``spcodec encode`` options of one point of a curve."""
    view = [f"--up={setup['up']}"] + (["--antialiased"] if setup["antialiased"] else [])
    if method == "noretrain":
        return ["--no-retrain", "--preset", param, *view]
    if method == "nr-target":
        return ["--no-retrain", "--target-size", str(param), "--threads", str(args.threads),
                *view]
    size = ["--target-size", str(param)] if method in SIZED else \
        ["--patch-downsample", str(param)]
    common = [*size, "--iterations", str(args.iterations), "--threads", str(args.threads),
              "--device", "cpu", *view]
    if setup["dataset"] is not None:
        common += ["--dataset", str(setup["dataset"]), "--downscale", str(setup["downscale"])]
    if "blur_variance" in setup:
        common += ["--blur-variance", str(setup["blur_variance"])]
    if method in NO_SKETCH:
        common += ["--no-sketch"]
    if method in PRUNE_RULE:
        common += ["--prune", PRUNE_RULE[method]]
    return common


def run_encode(ply: Path, extra: list[str], work: Path) -> tuple[Path, dict, float]:
    """One ``spcodec encode`` process: the file, its statistics and its peak RSS (MiB)."""
    out, stats, mem = work / "out.spc", work / "stats.json", work / "time.txt"
    for stale in (out, stats, Path(str(out) + ".ckpt")):
        stale.unlink(missing_ok=True)
    cmd = ["/usr/bin/time", "-f", "%M", "-o", str(mem), sys.executable, "-m", "spcodec.cli",
           "encode", str(ply), "-o", str(out), "--stats", str(stats), "--quiet", *extra]
    subprocess.run(cmd, check=True)
    return out, json.loads(stats.read_text()), int(mem.read_text().split()[-1]) / 1024


def encoded_file(folder: Path | None, scene: str, method: str, point
                 ) -> tuple[Path, dict, None] | None:
    """(file, statistics, no peak memory) of a point encoded elsewhere, or None."""
    if folder is None:
        return None
    out = folder / f"{scene}-{method}-{point}.spc"
    if not out.exists():
        return None
    return out, json.loads(out.with_suffix(".stats.json").read_text()), None


def _commit() -> str | None:
    """The checkout's commit, so a row says which encoder it measured (None outside git)."""
    found = subprocess.run(["git", "-C", str(Path(__file__).resolve().parent), "rev-parse", "HEAD"],
                           capture_output=True, text=True)
    return (found.stdout.strip() or None) if found.returncode == 0 else None


def sweep(args) -> None:
    rows = json.loads(args.json.read_text()) if args.json.exists() else []
    done = {(r["scene"], r["method"], str(r.get("point", r["param"]))) for r in rows}
    commit = _commit()
    viewer = None
    if not args.no_viewer:
        reason = viewer_yardstick.missing()
        if reason:
            print(f"viewer columns skipped: {reason}", file=sys.stderr)
        else:
            viewer = args.viewer_cache

    def record(row: dict) -> None:
        row.update(commit=commit, finished=time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
                   load=round(os.getloadavg()[0], 2))
        rows.append(row)
        args.json.write_text(json.dumps(rows, indent=2))
        seen = "".join(f"  {k} {row[k]:6.2f}" for k in ("orbit", "close") if k in row)
        ours = f"  eval {row['psnr']:6.2f} dB" if "psnr" in row else ""
        print(f"{row['scene']:>10} {row['method']:>9} {str(row['param']):>8}: "
              f"{row['bytes']:>10,} B{ours}{seen}  "
              f"{row.get('seconds') or 0:7.1f} s", flush=True)

    for name in args.scenes:
        setup = scene_setup(name, args)
        original = spcodec.read_ply(setup["ply"])
        ply_bytes = setup["ply"].stat().st_size
        if setup["dataset"] is not None and (name, "original", "-") not in done:
            record(dict(scene=name, method="original", param="-", point="-", bytes=ply_bytes,
                        **judge(original, original, setup), gaussians=len(original)))
        points = {"sp": args.factors, "pr": args.factors,
                  "noretrain": args.presets,
                  "spz": ["-"], "sog": ["-"], "spz4": ["-"], "sp-target": args.spz_fractions,
                  "pr-target": args.pr_fractions, "spu-target": args.pr_fractions,
                  "sps-target": args.pr_fractions, "nr-target": args.nr_fractions}
        for method in args.methods:
            for param in points[method]:
                if (name, method, str(param)) in done:
                    continue
                with tempfile.TemporaryDirectory() as tmp:
                    work = Path(tmp)
                    if method in ("spz", "sog"):
                        if method == "spz":
                            tool, size, _ = spz_round_trip(setup["ply"], work)
                            back = work / "peer.ply"
                        else:
                            tool, size, back = sog_round_trip(setup["ply"], work)
                        record(dict(scene=name, method=method, param=tool, point=param,
                                    bytes=size, ply=ply_bytes, **judge(
                                        spcodec.read_ply(back), original, setup, back, viewer,
                                        not args.no_eval)))
                        done.add((name, method, str(param)))
                        continue
                    target = param
                    if method in SIZED:
                        spz = next((r for r in rows if r["scene"] == name and r["method"] == "spz"),
                                   None)
                        if spz is None:
                            raise SystemExit(f"{name}: {method} needs the spz row: run --methods "
                                             f"spz {method}")
                        share = 0.25 if method == "spz4" else param
                        target = int(spz["bytes"] * share)
                    start = time.perf_counter()
                    made = encoded_file(args.encoded, name, method, param)
                    if made is not None:
                        out, stats, peak = made
                    else:
                        out, stats, peak = run_encode(
                            setup["ply"], encode_args(method, target, setup, args), work)
                    seconds = sum(stats["seconds"].values()) if made else \
                        time.perf_counter() - start
                    decoded = spcodec.decode(out)
                    decoded_ply = work / "decoded.ply"
                    spcodec.write_ply(decoded_ply, decoded)
                    record(dict(scene=name, method=method, param=target, point=param,
                                bytes=out.stat().st_size,
                                **judge(decoded, original, setup, decoded_ply, viewer,
                                        not args.no_eval),
                                seconds=seconds, stages=stats["seconds"], peak_mib=peak,
                                ply=ply_bytes, gaussians=len(decoded),
                                encoded=out.name if made else "here",
                                sketch=stats["sketch_gaussians"], reported=stats.get("quality"),
                                retrain=stats.get("retrain")))
                    done.add((name, method, str(param)))


def _minor_label(value: float, _position) -> str:
    """Plain labels at 2, 3 and 5 times a power of ten on the log size axis, none between."""
    lead = round(value / 10 ** math.floor(math.log10(value)))
    return f"{value:g}" if lead in (2, 3, 5) else ""


PANELS = (("orbit", "PlayCanvas, orbit framing"), ("close", "PlayCanvas, half the distance"),
          ("psnr", "our eval (400x400, whole scene)"))


SVG_STYLES = {  # method: (colour, marker, drawn as a line); spz4 joins the sp-target line
    "sp-target": ("#d62728", "circle", True), "sp": ("#e377c2", "circle", True),
    "pr-target": ("#1f77b4", "circle", True), "pr": ("#17becf", "circle", True),
    "spu-target": ("#bcbd22", "circle", True), "sps-target": ("#8c564b", "circle", True),
    "nr-target": ("#ff7f0e", "diamond", True), "noretrain": ("#2ca02c", "circle", True),
    "spz": ("#000000", "square", False), "sog": ("#9467bd", "diamond", False),
    "original": ("#7f7f7f", "square", False)}


def svg_figure(rows: list[dict], name: str) -> str | None:
    """One scene's figure as SVG text (bench/svg_chart.py: no plotting dependency, the same text
    on every machine): a panel per framing, one size axis, None where no row has a framing."""
    from svg_chart import Panel, Series, chart
    panels = []
    for key, title in PANELS:
        series = []
        for method, (colour, marker, line) in SVG_STYLES.items():
            drawn = (method, "spz4") if method == "sp-target" else (method,)
            pts = tuple((float(r["bytes"]), float(r[key])) for r in rows
                        if r["scene"] == name and r["method"] in drawn and r.get(key) is not None)
            if pts:
                series.append(Series(LABELS[method], colour, pts, line, marker))
        if series:
            test_images = name == "lego" and key == "psnr"
            panels.append(Panel("test images" if test_images else title, tuple(series)))
    return chart(f"{name}: PSNR against file size", panels) if panels else None


def plot(args) -> None:
    """One figure per scene: PSNR against size (log) at the viewer's two framings and in our
    eval, a panel each; lego's third panel is against its test images. SVG unless ``--png``
    (matplotlib, installed by hand)."""
    if not args.png:
        rows = json.loads(args.json.read_text())
        args.plot.mkdir(parents=True, exist_ok=True)
        for name in dict.fromkeys(r["scene"] for r in rows):
            text = svg_figure(rows, name)
            if text is not None:
                path = args.plot / f"rd_{name}.svg"
                path.write_text(text, encoding="utf-8")
                print(f"wrote {path}")
        return
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import FuncFormatter

    rows = json.loads(args.json.read_text())
    args.plot.mkdir(parents=True, exist_ok=True)
    styles = {"sp": ("o-", "C0"), "pr": ("s--", "C1"), "noretrain": ("^:", "C2"),
              "spz": ("*", "C3"), "sog": ("X", "C5"), "spz4": ("P", "C4"), "original": ("D", "k"),
              "sp-target": ("o-", "C6"), "sp-target-uncapped": ("x:", "C7"),
              "pr-target": ("s--", "C1"), "spu-target": ("v-.", "m"),
              "sps-target": ("<-.", "y"), "nr-target": ("^-", "C2"),
              "nosketch-target": ("D", "C9"),
              "spz4-uncapped": ("x", "C4"), "spz4-p12": ("P", "C8")}
    for name in dict.fromkeys(r["scene"] for r in rows):
        panels = [(key, title) for key, title in PANELS
                  if any(key in r for r in rows if r["scene"] == name)]
        fig, axes = plt.subplots(1, len(panels), figsize=(5.2 * len(panels), 4.2), dpi=110,
                                 squeeze=False)
        for ax, (key, title) in zip(axes[0], panels):
            for method, (style, colour) in styles.items():
                drawn = (method, "spz4") if method == "sp-target" else (method,)
                pts = sorted((r["bytes"], r[key]) for r in rows
                             if r["scene"] == name and r["method"] in drawn and key in r)
                if pts:
                    ax.plot([p[0] / 1e6 for p in pts], [p[1] for p in pts], style,
                            color=colour, label=LABELS[method],
                            markersize=9 if method in SINGLE_POINTS else 5)
            ax.set_xscale("log")
            ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
            ax.xaxis.set_minor_formatter(FuncFormatter(_minor_label))
            ax.set_xlabel("file size (MB, log scale)")
            test_images = name == "lego" and key == "psnr"
            against = "test images" if test_images else "the original"
            ax.set_ylabel(f"PSNR (dB) against {against}")
            ax.set_title(f"{name}: {'against its test images' if test_images else title}",
                         fontsize=10)
            ax.grid(True, which="both", alpha=0.3)
        axes[0][0].legend(fontsize=8)
        fig.tight_layout()
        fig.savefig(args.plot / f"rd_{name}.png")
        plt.close(fig)
        print(f"wrote {args.plot / f'rd_{name}.png'}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", type=Path, required=True, help="rows, appended as runs finish")
    ap.add_argument("--scenes", nargs="+", default=["fourth_st", "donut", "guitar", "kacytran"])
    ap.add_argument("--methods", nargs="+", default=list(METHODS), choices=METHODS)
    ap.add_argument("--factors", nargs="+", type=float, default=[2, 4, 8, 16])
    ap.add_argument("--spz-fractions", nargs="+", type=float, default=[1 / 16, 1 / 8, 1 / 2],
                    help="sp-target: the shares of SPZ's bytes to aim at (a quarter is spz4's)")
    ap.add_argument("--pr-fractions", nargs="+", type=float, default=[1 / 16, 1 / 8, 1 / 4, 1 / 2],
                    help="pr-target, spu-target and sps-target: the shares of SPZ's bytes to aim at")
    ap.add_argument("--nr-fractions", nargs="+", type=float,
                    default=[1 / 8, 1 / 4, 0.5, 0.6, 0.75, 0.9],
                    help="shares of SPZ's bytes the nr-target points aim at")
    ap.add_argument("--encoded", type=Path, help="judge DIR/SCENE-METHOD-POINT.spc (with its "
                    ".stats.json) where it exists rather than encoding that point")
    ap.add_argument("--iterations", type=int, default=3000)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--no-viewer", action="store_true", help="skip the PlayCanvas columns")
    ap.add_argument("--no-eval", action="store_true", help="skip our eval against renders of the "
                    "input (psnr, psnr_close columns); a dataset's test images are still judged")
    ap.add_argument("--presets", nargs="+", default=list(PRESETS), choices=PRESETS,
                    help="the noretrain points (default: all four)")
    ap.add_argument("--viewer-cache", type=Path,
                    default=Path(tempfile.gettempdir()) / "spcodec-yardstick",
                    help="where the inputs' viewer renders are kept between runs")
    ap.add_argument("--lego-model", help="the model bench/train_vanilla.py wrote")
    ap.add_argument("--lego-downscale", type=int, default=4)
    ap.add_argument("--plot", type=Path, help="draw the figures into this folder and exit")
    ap.add_argument("--png", action="store_true", help="with --plot: PNG by matplotlib, not SVG")
    args = ap.parse_args()
    if args.plot:
        plot(args)
    else:
        sweep(args)


if __name__ == "__main__":
    main()
