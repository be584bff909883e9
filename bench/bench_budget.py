"""Error budget: what each stored quantity costs on its own, as the viewer shows it.

An encode without retraining keeps every input Gaussian (``EncodeResult.source_index`` says which
decoded Gaussian is which input one). A *hybrid* is the original scene with one quantity replaced by
what the file stores for it: the sketch's Draco positions, the sketch's polynomial attributes, the
patch positions, one patch attribute's codebook values, and so on. Rendered by the PlayCanvas
engine at the orbit framing and at half its distance against the original, each hybrid's PSNR is
that quantity's cost; the whole decoded file is the last row. Position precision is also
simulated directly (every position snapped to a uniform grid of 2^b steps over the scene's box, as
QUANT16 and Draco store it over a layer's or cluster's box), and float16 rounding alone (what the
codebooks' binary16 entries cost before any clustering).

    python bench/bench_budget.py --scenes guitar donut fourth_st biker --preset highrate \\
        --json budget.json
    python bench/bench_budget.py --scenes fourth_st --target-size 2355982 --json budget.json

With ``--target-size``, each row of a quantity the precision search chose also carries the search's
predicted image MSE for it (``predicted_mse``: the linearized renderer's, or for positions our own
renderer's, summed over its two training framings), the viewer's MSE summed the same way
(``viewer_mse``) and their ratio: the check that keeps the search's distortion model honest. A ratio
that differs between quantities of one scene means the search misjudges one against another; a
ratio common to all only rescales the curve. The viewer's 8-bit output makes small errors look
larger than their squared error predicts, so compare quantities of similar error.

Needs the viewer yardstick (``bench/viewer_yardstick.py``: node, Chromium and the shared tool).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import spcodec  # noqa: E402
from spcodec.cloud import GaussianCloud  # noqa: E402

import viewer_yardstick  # noqa: E402
from bench_quality import SCENES  # noqa: E402
from scenes import data_dir  # noqa: E402

ATTRIBUTES = ("scales", "quats", "opacities", "sh_dc", "sh_rest")
"""The non-position arrays of a cloud, each one row of the budget."""


def encode(original: GaussianCloud, preset: str, up: str, antialiased: bool, seed: int,
           target_size: int | None = None):
    """The no-retrain encode of ``preset`` (the operating point whose budget is wanted); with
    ``target_size``, the file ``spcodec encode --no-retrain --target-size`` writes."""
    from spcodec.encoder.config import EncoderConfig
    from spcodec.encoder.pipeline import encode as run
    from spcodec.encoder.presets import preset_config, sized
    from spcodec.encoder.retraining.control import RunControl
    from spcodec.encoder.stages import silent

    config = preset_config(preset, EncoderConfig(seed=seed))
    if target_size is not None:
        config = sized(config, target_size)
    config = dataclasses.replace(config, up=up, antialiased=antialiased)
    return run(original, config, progress=silent, control=RunControl(device="cpu"))


def hybrid(original: GaussianCloud, decoded: GaussianCloud, source: np.ndarray, rows: np.ndarray,
           names: tuple[str, ...]) -> GaussianCloud:
    """``original`` with arrays ``names`` of the Gaussians ``rows`` (decoded order) as decoded."""
    out = original.subset(np.arange(len(original)))
    for name in names:
        target = getattr(out, name)
        target[source[rows]] = getattr(decoded, name)[rows]
    return out


def sh_band(original: GaussianCloud, decoded: GaussianCloud, source: np.ndarray,
            rows: np.ndarray, band: int) -> GaussianCloud:
    """``original`` with SH band ``band`` (its ``2 band + 1`` coefficients) of the Gaussians
    ``rows`` (decoded order) as decoded: which band the ``sh_rest`` row's loss is in."""
    out = original.subset(np.arange(len(original)))
    coefficients = slice(band * band - 1, (band + 1) ** 2 - 1)
    out.sh_rest[source[rows], coefficients] = decoded.sh_rest[rows, coefficients]
    return out


def grid_positions(original: GaussianCloud, bits: int) -> GaussianCloud:
    """Every position on a uniform grid of ``2^bits - 1`` steps per axis over the scene's box."""
    out = original.subset(np.arange(len(original)))
    low, high = original.means.min(0), original.means.max(0)
    step = np.where(high > low, (high - low) / (2 ** bits - 1), 1.0)
    out.means = (np.round((original.means - low) / step) * step + low).astype(np.float32)
    return out


def float16_attributes(original: GaussianCloud) -> GaussianCloud:
    """Every non-position value rounded to binary16 (opacity and rotation as coded: after the
    sigmoid, and normalized), the floor of binary16 codebook entries."""
    from spcodec.attributes import decode_opacity

    out = original.subset(np.arange(len(original)))
    for name in ("scales", "sh_dc", "sh_rest"):
        setattr(out, name, getattr(original, name).astype(np.float16).astype(np.float32))
    quats = original.quats / np.linalg.norm(original.quats, axis=1, keepdims=True)
    out.quats = quats.astype(np.float16).astype(np.float32)
    alpha = 1.0 / (1.0 + np.exp(-original.opacities.astype(np.float64)))
    out.opacities = decode_opacity(alpha.astype(np.float16).astype(np.float32))
    return out


def variants(original: GaussianCloud, result, decoded: GaussianCloud,
             grid_bits: tuple[int, ...] = ()):
    """(row name, cloud) for every budget row of one encode."""
    source = result.source_index
    sketch = np.arange(result.stats.sketch_gaussians)
    patch = np.arange(result.stats.sketch_gaussians, len(decoded))
    yield "sketch positions (Draco)", hybrid(original, decoded, source, sketch, ("means",))
    yield "sketch attributes (polynomial models)", hybrid(original, decoded, source, sketch,
                                                          ATTRIBUTES)
    yield "patch positions", hybrid(original, decoded, source, patch, ("means",))
    for name in ATTRIBUTES:
        yield f"patch {name} (codebooks)", hybrid(original, decoded, source, patch, (name,))
    for band in range(1, original.sh_degree + 1):
        yield f"patch SH band {band} (codebooks)", sh_band(original, decoded, source, patch, band)
    yield "float16 rounding of every attribute", float16_attributes(original)
    for bits in grid_bits:
        yield f"positions on a {bits}-bit grid", grid_positions(original, bits)
    yield "the whole file", decoded


SEARCHED = {"patch positions": "POSITION", "patch scales (codebooks)": "SCALE",
            "patch quats (codebooks)": "ROTATION", "patch opacities (codebooks)": "OPACITY",
            "patch sh_dc (codebooks)": "COLOR_DC"}
"""Budget rows of a quantity the precision search chooses, by the search's name for it."""


def searched_quantity(label: str) -> str | None:
    """The precision search's name of the quantity a budget row replaces (None: not searched)."""
    if label.startswith("patch SH band "):
        return f"SH_BAND_{label.split()[3]}"
    return SEARCHED.get(label)


def viewer_mse(seen: dict[str, float]) -> float:
    """The viewer's PSNRs of one row as MSE summed over its framings, as the search sums its
    distortion over its two (an identical render, infinite dB, adds nothing)."""
    return sum(10.0 ** (-db / 10.0) for db in seen.values() if math.isfinite(db))


def with_prediction(row: dict, predicted: dict[str, float], seen: dict[str, float]) -> dict:
    """``row`` with the search's predicted MSE of its quantity, the viewer's, and their ratio,
    when the search chose that quantity's precision (``predicted``: the encode statistics'
    ``predicted_distortions``); the whole file's row gets the sum of every prediction."""
    quantity = searched_quantity(row["quantity"])
    if row["quantity"] == "the whole file" and predicted:
        guess = sum(predicted.values())
    elif quantity in predicted:
        guess = predicted[quantity]
    else:
        return row
    seen_mse = viewer_mse(seen)
    return {**row, "predicted_mse": guess, "viewer_mse": seen_mse,
            "viewer_over_predicted": seen_mse / guess if guess > 0 else None}


def budget(name: str, preset: str, cache: Path, seed: int, grid_bits: tuple[int, ...],
           target_size: int | None = None) -> list[dict]:
    rel, up, antialiased = SCENES[name]
    ply = data_dir() / rel
    original = spcodec.read_ply(ply)
    start = time.perf_counter()
    result = encode(original, preset, up, antialiased, seed, target_size)
    decoded = spcodec.decode(result.data)
    predicted = ((result.stats.rate or {}).get("precision") or {}).get("predicted_distortions", {})
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "variant.ply"
        for label, cloud in variants(original, result, decoded, grid_bits):
            spcodec.write_ply(path, cloud)
            seen = viewer_yardstick.two_framings(ply, path, cache, up, antialiased)
            row = with_prediction(dict(scene=name, preset=preset, target_size=target_size,
                                       bytes=len(result.data), quantity=label), predicted, seen)
            # identical renders have no PSNR: null in the JSON, "=" in the printout
            seen = {k: None if math.isinf(v) else v for k, v in seen.items()}
            row.update(seen)
            shown = {k: "=" if v is None else f"{v:.2f}" for k, v in seen.items()}
            ratio = row.get("viewer_over_predicted")
            model = "" if ratio is None else f"  viewer / predicted MSE {ratio:6.2f}"
            print(f"{name:>10} {label:<42} orbit {shown['orbit']:>6}  close {shown['close']:>6}"
                  f"{model}", flush=True)
            rows.append(row)
    rows[-1]["seconds"] = time.perf_counter() - start
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenes", nargs="+", default=["guitar", "donut", "fourth_st", "biker"])
    parser.add_argument("--preset", default="highrate")
    parser.add_argument("--json", type=Path, required=True, help="rows, appended as scenes finish")
    parser.add_argument("--viewer-cache", type=Path,
                        default=Path(tempfile.gettempdir()) / "spcodec-yardstick")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--grid-bits", type=int, nargs="*", default=[],
                        help="also judge every position on a uniform grid of these many bits")
    parser.add_argument("--target-size", type=int, default=None,
                        help="budget the file of this many bytes that --no-retrain --target-size "
                             "writes (one scene at a time: a size is a scene's own)")
    args = parser.parse_args()
    if args.target_size is not None and len(args.scenes) != 1:
        parser.error("--target-size is one scene's size: give one of --scenes")
    reason = viewer_yardstick.missing()
    if reason:
        raise SystemExit(f"bench_budget needs the viewer yardstick: {reason}")
    rows = json.loads(args.json.read_text()) if args.json.exists() else []
    for name in args.scenes:
        rows += budget(name, args.preset, args.viewer_cache, args.seed, tuple(args.grid_bits),
                       args.target_size)
        args.json.write_text(json.dumps(rows, indent=2))


if __name__ == "__main__":
    main()
