"""Patch positions coded as a set (Draco's kd-tree coding, spec 1.2.1 [R-58]) against sequential
coding of the same grid, on the shared scenes, in one run (issue 37).

For each scene the same no-retrain preset is encoded twice, with ``PatchConfig.set_coding_saving``
as configured and off (None). Where the two decode to the same Gaussians in another order (the
sorted rows agree exactly: "same Gaussians"), they render alike and only their bytes differ;
where not, the smaller patch let the sketch keep other clusters within its share of the file
(DECISIONS D-10), or a layer on the input's grid took Draco's binary32 grid instead of exact
QUANT16 (patch.on_input_grid), and the viewer judges the two files
(``../shared/tools/two-framings.sh``). Prints each file's bytes, its
PATCH_POSITIONS bytes and the change, and keeps the files in --workdir (for
``bench/bench_web_decode.py --extra LABEL=SCENE:FILE``, which times both decoders on them).

    python bench/bench_positions_as_set.py [--scenes guitar biker ...] [--preset balanced]
        [--workdir DIR] [--json OUT]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import spcodec
from spcodec.encoder.pipeline import encode
from spcodec.encoder.presets import preset_config

sys.path.insert(0, str(Path(__file__).resolve().parent))
from scenes import REAL, UP, data_dir  # noqa: E402


def positions_bytes(data: bytes) -> int:
    """Stored bytes of every PATCH_POSITIONS section of the file."""
    info = spcodec.inspect(data).to_json()
    return sum(s["length"] for s in info["sections"] if s["type"] == "PATCH_POSITIONS")


def sorted_rows(data: bytes) -> np.ndarray:
    """The decoded Gaussians as rows (position, then every attribute), sorted: order-free."""
    cloud = spcodec.decode(data)
    rows = np.concatenate([cloud.means, cloud.scales, cloud.quats, cloud.opacities[:, None],
                           cloud.sh_dc.reshape(len(cloud), -1),
                           cloud.sh_rest.reshape(len(cloud), -1)], axis=1)
    return rows[np.lexsort(rows.T[::-1])]


def measure(name: str, preset: str, workdir: Path) -> dict:
    cloud = spcodec.read_ply(data_dir() / REAL[name])
    base = preset_config(preset)
    if name in UP:
        base = dataclasses.replace(base, up=UP[name])
    out = {"scene": name, "gaussians": len(cloud), "preset": preset}
    files = {}
    for as_set, saving in ((False, None), (True, base.patch.set_coding_saving)):
        config = dataclasses.replace(base, patch=dataclasses.replace(base.patch,
                                                                     set_coding_saving=saving))
        start = time.process_time()
        data = encode(cloud, config).data
        label = "set" if as_set else "sequential"
        files[label] = data
        path = workdir / f"{name}-{preset}-{label}.spc"
        path.write_bytes(data)
        out[label] = {"bytes": len(data), "positions_bytes": positions_bytes(data),
                      "encode_cpu_s": round(time.process_time() - start, 2), "file": str(path)}
    a, b = sorted_rows(files["set"]), sorted_rows(files["sequential"])
    out["same_gaussians"] = bool(a.shape == b.shape and np.array_equal(a, b))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", nargs="*", default=list(REAL), choices=list(REAL))
    parser.add_argument("--preset", default="balanced")
    parser.add_argument("--workdir", type=Path,
                        default=Path(tempfile.gettempdir()) / "spc-positions-as-set")
    parser.add_argument("--json", type=Path, help="also write the results here")
    args = parser.parse_args()
    args.workdir.mkdir(parents=True, exist_ok=True)
    rows = []
    print("| scene | preset | sequential file | set file | change | positions, sequential -> set |"
          " same Gaussians |")
    print("|---|---|---:|---:|---:|---|---|")
    for name in args.scenes:
        r = measure(name, args.preset, args.workdir)
        rows.append(r)
        seq, st = r["sequential"], r["set"]
        change = 100.0 * (st["bytes"] / seq["bytes"] - 1)
        pos = 100.0 * (st["positions_bytes"] / seq["positions_bytes"] - 1)
        print(f"| {name} | {r['preset']} | {seq['bytes']:,} | {st['bytes']:,} | {change:+.1f} % | "
              f"{seq['positions_bytes']:,} -> {st['positions_bytes']:,} ({pos:+.1f} %) | "
              f"{'yes' if r['same_gaussians'] else 'no'} |", flush=True)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1) + "\n")


if __name__ == "__main__":
    main()
