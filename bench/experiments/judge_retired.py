"""Judge every prefix of a retire_layers.py file with retirement applied (PlayCanvas, both
framings; docs/LOG.md 15.7).

python bench/experiments/judge_retired.py OUT.json LABEL FILE.spc MAP.json  (SCENE env: guitar)
Prefix k <= M: sketch + A1 R1 .. Ak Rk (bytes to the end of Rk); prefix k > M: sketch + A1..AM +
L(M+1)..Lk, the retired layers left out (bytes to the end of Lk: they were sent).
"""
import json
import os
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from bench_layers import cloud_framings  # noqa: E402

import spcodec  # noqa: E402

from bench_quality import SCENES  # noqa: E402
from scenes import data_dir  # noqa: E402

CACHE = Path(tempfile.gettempdir()) / "spcodec-yardstick"
out, label, path, mapping = Path(sys.argv[1]), sys.argv[2], Path(sys.argv[3]), sys.argv[4]
kinds = json.loads(Path(mapping).read_text())["kinds"]
rows = json.loads(out.read_text()) if out.exists() else []
scene = os.environ.get("SCENE", "guitar")
rel, up, aa = SCENES[scene]
data = path.read_bytes()
info = spcodec.inspect(data).to_json()
result = spcodec.decode_layers(data)
ends = {layer["index"]: layer["end_offset"] for layer in info["layers"]}
clouds = [layer.cloud for layer in result.layers]
file_index = {kind: i + 1 for i, kind in enumerate(kinds)}
M = sum(1 for k in kinds if k.startswith("A"))
prefixes = []
for k in range(1, len(kinds) - M + 1):
    if k <= M:
        members = [0] + [file_index[f"{t}{j}"] for j in range(1, k + 1) for t in "AR"]
    else:
        members = [0] + [file_index[f"A{j}"] for j in range(1, M + 1)] + \
            [file_index[f"L{j}"] for j in range(M + 1, k + 1)]
    last = max(members)
    cloud = spcodec.GaussianCloud.concat([clouds[i] for i in members if len(clouds[i])])
    psnr = cloud_framings(cloud, data_dir() / rel, up, aa, CACHE)
    row = {"prefix": k, "layers": members, "bytes": ends[last], "share": ends[last] / len(data),
           "gaussians": len(cloud), "orbit": psnr["orbit"], "close": psnr["close"]}
    prefixes.append(row)
    print(f"P{k}: {row['bytes']:,} B ({row['share']:.1%}) {len(cloud)} G, orbit {psnr['orbit']:.2f} "
          f"close {psnr['close']:.2f}", flush=True)
rows.append({"scene": scene, "label": label, "bytes": len(data), "source": str(path),
             "prefixes": prefixes})
out.write_text(json.dumps(rows, indent=1))
