"""Quality that rises early: every layer prefix of a plain and a nested encode, as a viewer shows it.

Each scene is encoded twice from the same input with the same retraining budget: plain retraining
(all patch survivors trained for the full file, then split into layers by importance) and nested
retraining (``--nested``: the layers are fixed first and every training step renders a prefix of
them, so each prefix is a trained scene; encoder/retraining/nested.py). Every prefix that ends at
a non-empty layer is decoded (``spcodec decode --max-layer K``) and rendered by the PlayCanvas
engine at the orbit framing and at half its distance against the original
(bench/viewer_yardstick.py). It prints one table per scene and the issue's targets: the longest
prefix within 30 % of the bytes within 3 dB of the full file, the first non-empty layer complete
within 10 % of the bytes and within 10 dB. A file with a preview (spec 1.1) leads with the
preview's row and is judged as a viewer shows it: the preview from its arrival until its takeover
layer. ``--rd`` adds the RD points of ``bench/bench_rd.py`` (files encoded for their size) to the
figure, so a prefix can be read against a file made for its size.

    python bench/bench_layers.py --json layers.json [--scenes guitar fourth_st biker donut kacytran]
        [--iterations 3000] [--threads 1] [--patch-layers N]
        [--file guitar:plain=/path/a.spc --file guitar:nested=/path/b.spc]   # judge, don't encode
    python bench/bench_layers.py --json layers.json --plot docs/results/prefix_nested.png
        [--rd docs/results/rd_viewer.json]

An interrupted run keeps what it measured (rows are written as each file is judged) and
continues where it stopped. matplotlib is needed for the figure only.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import spcodec
from spcodec.cli import build_parser
from spcodec.cli.encode import encode_config
from spcodec.encoder.config import EncoderConfig
from spcodec.encoder.pipeline import encode

import viewer_yardstick  # bench/ is on sys.path
from bench_quality import SCENES
from scenes import data_dir

SHARE_TARGET, DB_TARGET, FIRST_SHARE, FIRST_DB = 0.30, 3.0, 0.10, 10.0
LABELS = ("plain", "nested")


def cloud_framings(cloud: spcodec.GaussianCloud, original: Path, up: str, antialiased: bool,
                   cache: Path) -> dict[str, float]:
    """Viewer PSNR of ``cloud`` against ``original`` at both framings (through a temporary PLY,
    which is what the viewer loads)."""
    with tempfile.TemporaryDirectory() as tmp:
        ply = Path(tmp) / "prefix.ply"
        spcodec.write_ply(ply, cloud)
        return viewer_yardstick.two_framings(original, ply, cache, up, antialiased)


def prefixes(data: bytes, original: Path, up: str, antialiased: bool, cache: Path) -> list[dict]:
    """Bytes, share, Gaussians and viewer PSNR at both framings of every prefix that ends at a
    non-empty layer, led by the preview's row (``"layer": "preview"``) when the file has one."""
    info = spcodec.inspect(data).to_json()
    rows, gaussians = [], 0
    preview = spcodec.decode_preview(data)
    if preview is not None:
        psnr = cloud_framings(preview.cloud, original, up, antialiased, cache)
        end = preview.section.end
        rows.append({"layer": "preview", "takeover_layer": preview.takeover_layer, "bytes": end,
                     "share": end / len(data), "gaussians": len(preview.cloud),
                     "orbit": round(psnr["orbit"], 3), "close": round(psnr["close"], 3)})
        print(f"    preview: {end:,} B ({end / len(data):.1%}) orbit {psnr['orbit']:.2f} "
              f"close {psnr['close']:.2f} dB, shown until layer {preview.takeover_layer}",
              flush=True)
    for layer in info["layers"]:
        gaussians += layer["gaussians"]
        if not gaussians or layer["gaussians"] == 0:
            continue
        psnr = cloud_framings(spcodec.decode(data, max_layer=layer["index"]), original, up,
                              antialiased, cache)
        rows.append({"layer": layer["index"], "bytes": layer["end_offset"],
                     "share": layer["end_offset"] / len(data), "gaussians": gaussians,
                     "orbit": round(psnr["orbit"], 3), "close": round(psnr["close"], 3)})
        print(f"    L0-{layer['index']}: {layer['end_offset']:,} B "
              f"({layer['end_offset'] / len(data):.1%}) orbit {psnr['orbit']:.2f} "
              f"close {psnr['close']:.2f} dB", flush=True)
    return rows


def on_screen(rows: list[dict]) -> list[dict]:
    """What a viewer shows as the bytes arrive: the preview, from its arrival until the prefix
    that ends with its takeover layer ([R-104]), then the prefixes."""
    preview = rows[0] if rows and rows[0]["layer"] == "preview" else None
    if preview is None:
        return rows
    return [preview] + [dict(preview, bytes=r["bytes"], share=r["share"], layer=r["layer"])
                        if r["layer"] < preview["takeover_layer"] else r for r in rows[1:]]


def verdict(rows: list[dict], framing: str) -> dict:
    """The issue's targets for one file at one framing, judged on what a viewer shows."""
    rows = on_screen(rows)
    full = rows[-1][framing]
    early = [r for r in rows if r["share"] <= SHARE_TARGET]
    best = max(early, key=lambda r: r[framing]) if early else None
    first = rows[0]
    return {"full": full, "best_within_share": None if best is None else best[framing],
            "gap_db": None if best is None else round(full - best[framing], 3),
            "first_share": first["share"], "first_gap_db": round(full - first[framing], 3),
            "met": best is not None and full - best[framing] <= DB_TARGET
            and first["share"] <= FIRST_SHARE and full - first[framing] <= FIRST_DB}


def config_for(label: str, iterations: int, layers: int | None, up: str,
               antialiased: bool) -> EncoderConfig:
    """The encode ``spcodec encode X.ply -o F --iterations N [--nested] [--patch-layers L]
    [--up U] [--antialiased]`` runs: the CLI's own configuration, defaults included (six patch
    layers when retraining)."""
    argv = ["encode", "in.ply", "-o", "out.spc", "--iterations", str(iterations), f"--up={up}"]
    argv += ["--nested"] if label == "nested" else []
    argv += ["--patch-layers", str(layers)] if layers is not None else []
    argv += ["--antialiased"] if antialiased else []
    return encode_config(build_parser().parse_args(argv))


def run(args: argparse.Namespace) -> list[dict]:
    rows = json.loads(args.json.read_text()) if args.json.exists() else []
    done = {(r["scene"], r["label"]) for r in rows}
    given = dict(item.split("=", 1) for item in args.file)
    cache = args.viewer_cache
    for scene in args.scenes:
        rel, up, antialiased = SCENES[scene]
        original = data_dir() / rel
        # files given for a scene are judged instead of encoding any
        labels = tuple(key.split(":", 1)[1] for key in given if key.startswith(f"{scene}:")) \
            or LABELS
        for label in labels:
            if (scene, label) in done:
                continue
            source = given.get(f"{scene}:{label}")
            start = time.perf_counter()
            if source is not None:
                data, how = Path(source).read_bytes(), f"file {source}"
            else:
                config = config_for(label, args.iterations, args.patch_layers, up, antialiased)
                data = encode(spcodec.read_ply(original), config).data
                how = f"encoded, {args.iterations} steps"
            seconds = time.perf_counter() - start
            print(f"{scene} {label}: {len(data):,} bytes ({how}, {seconds:.0f} s)", flush=True)
            prefix_rows = prefixes(data, original, up, antialiased, cache)
            rows.append({"scene": scene, "label": label, "bytes": len(data), "source": how,
                         "encode_seconds": round(seconds, 1), "prefixes": prefix_rows,
                         "orbit": verdict(prefix_rows, "orbit"),
                         "close": verdict(prefix_rows, "close")})
            args.json.write_text(json.dumps(rows, indent=1))
    return rows


def report(rows: list[dict]) -> None:
    for row in rows:
        print(f"\n{row['scene']} {row['label']} ({row['bytes']:,} bytes)\n"
              "| prefix | bytes | share | Gaussians | orbit dB | close dB |\n"
              "|---|---:|---:|---:|---:|---:|")
        for p in row["prefixes"]:
            name = "preview" if p["layer"] == "preview" else f"L0-{p['layer']}"
            print(f"| {name} | {p['bytes']:,} | {p['share']:.1%} | {p['gaussians']:,} | "
                  f"{p['orbit']:.2f} | {p['close']:.2f} |")
    print("\n| scene | encode | framing | full dB | best <= 30 % | gap dB | first layer at | "
          "its gap dB | targets |\n|---|---|---|---:|---:|---:|---:|---:|---|")
    for row in rows:
        for framing in ("orbit", "close"):
            v = row[framing]
            best = "-" if v["best_within_share"] is None else f"{v['best_within_share']:.2f}"
            gap = "-" if v["gap_db"] is None else f"{v['gap_db']:.2f}"
            print(f"| {row['scene']} | {row['label']} | {framing} | {v['full']:.2f} | {best} | "
                  f"{gap} | {v['first_share']:.1%} | {v['first_gap_db']:.2f} | "
                  f"{'met' if v['met'] else 'missed'} |")


def plot(rows: list[dict], path: Path, rd: Path | None) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import NullFormatter, ScalarFormatter

    scenes = list(dict.fromkeys(r["scene"] for r in rows))
    rd_rows = json.loads(rd.read_text()) if rd is not None and rd.exists() else []
    fig, axes = plt.subplots(2, len(scenes), figsize=(4.4 * len(scenes), 7), squeeze=False)
    for col, scene in enumerate(scenes):
        for line, framing in enumerate(("orbit", "close")):
            ax = axes[line][col]
            for row in (r for r in rows if r["scene"] == scene):
                shown = on_screen(row["prefixes"])
                ax.plot([p["bytes"] / 1e3 for p in shown], [p[framing] for p in shown],
                        "s-" if row["label"].startswith("nested") else "o--",
                        label=f"{row['label']} prefixes")
            points = [r for r in rd_rows if r["scene"] == scene and r.get(framing) is not None
                      and r["method"] in ("sp", "spz4", "sp-target")]
            if points:
                ax.plot([r["bytes"] / 1e3 for r in points], [r[framing] for r in points], "P",
                        color="C4", markersize=9, label="retrained for its size")
            ax.set_xscale("log")
            ax.xaxis.set_major_formatter(ScalarFormatter())
            low, high = ax.get_xlim()  # within one decade no major tick shows: label the minor
            ax.xaxis.set_minor_formatter(ScalarFormatter() if high / low < 10 else NullFormatter())
            ax.set_title(f"{scene}, {framing} (PlayCanvas)")
            ax.set_xlabel("bytes received (kB)")
            ax.grid(alpha=0.3, which="both")
        axes[0][col].set_ylabel("PSNR vs original, orbit (dB)")
        axes[1][col].set_ylabel("PSNR vs original, close-up (dB)")
    for ax in axes[0]:  # each scene's own: not every scene has a nested encode
        ax.legend(loc="lower right", fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    print(f"wrote {path}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", type=Path, required=True, help="rows, written as files are judged")
    ap.add_argument("--scenes", nargs="+",
                    default=["guitar", "fourth_st", "biker", "donut", "kacytran"])
    ap.add_argument("--iterations", type=int, default=3000)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--patch-layers", type=int, help="patch layers of both encodes")
    ap.add_argument("--file", action="append", default=[], metavar="SCENE:LABEL=PATH",
                    help="judge this .spc (LABEL: any name); a scene with files given is not "
                    "encoded")
    ap.add_argument("--viewer-cache", type=Path,
                    default=Path(tempfile.gettempdir()) / "spcodec-yardstick")
    ap.add_argument("--plot", type=Path, help="draw the figure from --json into this PNG and exit")
    ap.add_argument("--rd", type=Path, help="bench_rd.py rows to draw beside the prefixes")
    args = ap.parse_args()
    if args.plot:
        plot(json.loads(args.json.read_text()), args.plot, args.rd)
        return
    reason = viewer_yardstick.missing()
    if reason:
        raise SystemExit(f"the viewer yardstick cannot run: {reason}")
    import torch

    torch.set_num_threads(args.threads)
    report(run(args))


if __name__ == "__main__":
    main()
