"""Quality that rises early: PSNR of every layer prefix against the bytes it needs (issue 13.6).

Each scene is encoded twice in one run, with the default encoder and with the previous default
(opacity-footprint layers of 20/30/50 %, no cap on the sketch layer; ``bench_encode.py``'s
:func:`previous_config`), and every prefix that ends at a non-empty layer is judged as
``spcodec eval PREFIX --reference PLY --max-layer K`` judges it: 8 held-out sampled views of
400x400, PSNR against the original's renders. It prints one table per scene and the two targets:
the prefix at <= 30 % of the bytes within 6 dB of the full file, and the first non-empty layer
complete after <= 10 % of the bytes. ``--plot`` draws PSNR against bytes for each scene, ours
beside the previous ordering (matplotlib: a bench-only dependency, ``pip install matplotlib``).

    python bench/bench_layers.py [--scenes guitar fourth_st biker donut kacytran]
                                 [--plot docs/results/prefix_psnr.png] [--json out.json]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import spcodec
from spcodec.encoder.config import EncoderConfig
from spcodec.encoder.pipeline import encode
from spcodec.imaging.evaluate import EvalConfig, evaluate_against_reference

from bench_encode import previous_config  # bench/ is on sys.path
from scenes import load_scene

SHARE_TARGET, DB_TARGET, FIRST_TARGET = 0.30, 6.0, 0.10


def prefixes(data: bytes, reference: spcodec.GaussianCloud, views: int) -> list[dict]:
    """Bytes, share, Gaussians and PSNR of every prefix that ends at a non-empty layer."""
    info = spcodec.inspect(data).to_json()
    rows, gaussians = [], 0
    for layer in info["layers"]:
        gaussians += layer["gaussians"]
        if not gaussians:
            continue
        model = spcodec.decode(data, max_layer=layer["index"])
        psnr = evaluate_against_reference(model, reference, EvalConfig(views=views)).psnr
        rows.append({"layer": layer["index"], "bytes": layer["end_offset"],
                     "share": layer["end_offset"] / len(data), "gaussians": gaussians,
                     "psnr": psnr})
    return rows


def verdict(rows: list[dict]) -> dict:
    """The two targets for one file."""
    full = rows[-1]["psnr"]
    early = [r for r in rows if r["share"] <= SHARE_TARGET]
    best = max(early, key=lambda r: r["psnr"]) if early else None
    return {"full_psnr": full, "first_share": rows[0]["share"],
            "best_within_share": None if best is None else best["psnr"],
            "gap_db": None if best is None else full - best["psnr"]}


def run(names: list[str], views: int, current: EncoderConfig) -> dict:
    results = {}
    for name in names:
        cloud = load_scene(name)
        results[name] = {}
        for label, config in (("previous", previous_config()), ("current", current)):
            start = time.perf_counter()
            data = encode(cloud, config).data
            seconds = time.perf_counter() - start
            rows = prefixes(data, cloud, views)
            results[name][label] = {"bytes": len(data), "encode_seconds": seconds,
                                    "prefixes": rows, **verdict(rows)}
            print(f"{name} {label}: {len(data):,} bytes, encoded in {seconds:.1f} s", flush=True)
    return results


def report(results: dict) -> None:
    for name, runs in results.items():
        print(f"\n{name}\n| encoder | layers | bytes | share | Gaussians | PSNR dB |")
        print("|---|---|---:|---:|---:|---:|")
        for label, res in runs.items():
            for r in res["prefixes"]:
                print(f"| {label} | L0-{r['layer']} | {r['bytes']:,} | {r['share']:.1%} | "
                      f"{r['gaussians']:,} | {r['psnr']:.2f} |")
    print("\n| scene | encoder | bytes | first picture at | best prefix <= 30 % | full | gap dB |")
    print("|---|---|---:|---:|---:|---:|---:|")
    for name, runs in results.items():
        for label, res in runs.items():
            best, gap = res["best_within_share"], res["gap_db"]
            print(f"| {name} | {label} | {res['bytes']:,} | {res['first_share']:.1%} | "
                  f"{'-' if best is None else f'{best:.2f}'} | {res['full_psnr']:.2f} | "
                  f"{'-' if gap is None else f'{gap:.2f}'} |")
        old, new = runs["previous"]["bytes"], runs["current"]["bytes"]
        print(f"| {name} | size change | {100 * (new / old - 1):+.2f} % | | | | |")


def plot(results: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(results), figsize=(4.2 * len(results), 3.6), squeeze=False)
    for ax, (name, runs) in zip(axes[0], results.items()):
        for label, style in (("previous", "o--"), ("current", "s-")):
            rows = runs[label]["prefixes"]
            ax.plot([r["bytes"] / 1e3 for r in rows], [r["psnr"] for r in rows], style,
                    label="footprint order (previous)" if label == "previous"
                    else "blend-weight order (now)")
        full = runs["current"]
        ax.axvline(SHARE_TARGET * full["bytes"] / 1e3, color="grey", lw=0.8, ls=":")
        ax.axhline(full["full_psnr"] - DB_TARGET, color="grey", lw=0.8, ls=":")
        ax.set_title(name)
        ax.set_xlabel("prefix bytes (kB)")
        ax.grid(alpha=0.3)
    axes[0][0].set_ylabel("PSNR vs original (dB)")
    axes[0][0].legend(loc="lower right", fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    print(f"wrote {path}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", nargs="+",
                    default=["guitar", "fourth_st", "biker", "donut", "kacytran"])
    ap.add_argument("--views", type=int, default=8)
    ap.add_argument("--plot", type=Path, help="write the PSNR-vs-bytes figure here (PNG)")
    ap.add_argument("--json", type=Path, help="also write the measurements as JSON")
    ap.add_argument("--layer-fractions", help="try another split of the patch, e.g. 0.1,0.2,0.7")
    ap.add_argument("--importance-views", type=int, help="try another number of views")
    args = ap.parse_args()
    current = EncoderConfig()
    if args.layer_fractions:
        fractions = tuple(float(v) for v in args.layer_fractions.split(","))
        current.patch = dataclasses.replace(current.patch, layers=len(fractions),
                                            layer_fractions=fractions)
    if args.importance_views:
        current.patch = dataclasses.replace(current.patch, importance_views=args.importance_views)
    results = run(args.scenes, args.views, current)
    report(results)
    if args.json:
        args.json.write_text(json.dumps(results, indent=1))
    if args.plot:
        plot(results, args.plot)


if __name__ == "__main__":
    main()
