"""Judge preview + every prefix of the main file (PlayCanvas, both framings).

python bench/experiments/judge_preview.py OUT.json LABEL PREVIEW.spc MAIN.spc  (SCENE env: guitar)
Bytes of a prefix: the preview's file plus the main file's prefix (two headers: within ~1 kB of
one file holding both).
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
out, label, pv, main = Path(sys.argv[1]), sys.argv[2], Path(sys.argv[3]), Path(sys.argv[4])
rows = json.loads(out.read_text()) if out.exists() else []
scene = os.environ.get("SCENE", "guitar")
rel, up, aa = SCENES[scene]
preview, pbytes = spcodec.decode(pv.read_bytes()), pv.stat().st_size
data = main.read_bytes()
info = spcodec.inspect(data).to_json()
prefixes = []
for layer in info["layers"]:
    if layer["gaussians"] == 0:
        continue
    cloud = spcodec.GaussianCloud.concat([preview, spcodec.decode(data, max_layer=layer["index"])])
    psnr = cloud_framings(cloud, data_dir() / rel, up, aa, CACHE)
    b = pbytes + layer["end_offset"]
    row = {"layer": layer["index"], "bytes": b, "share": b / (pbytes + len(data)),
           "gaussians": len(cloud), "orbit": psnr["orbit"], "close": psnr["close"]}
    prefixes.append(row)
    print(f"preview + L0-{layer['index']}: {b:,} B ({row['share']:.1%}) orbit {psnr['orbit']:.2f} "
          f"close {psnr['close']:.2f}", flush=True)
rows.append({"scene": scene, "label": label, "bytes": pbytes + len(data), "source": str(main),
             "prefixes": prefixes})
out.write_text(json.dumps(rows, indent=1))
