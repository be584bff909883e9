#!/usr/bin/env bash
# The paper's protocol on a lent GPU in one device call (bench/gpu_protocol.py says what it runs).
#
# The device machine has torch with CUDA but reaches no registry and gets only the checkout, so
# the run carries what it needs in .dev/ (ignored through .git/info/exclude), made here once:
#   .dev/whl/   wheels for Python 3.12: DracoPy, construct, plyfile, gsplat and spcodec itself
#               (docs/DEVICE.md in shared/ has the pip download lines; `pip wheel --no-deps -w
#               .dev/whl .` for spcodec, again after every change)
#   .dev/data/NAME/   the dataset, its PNGs stored as lossless WebP (the carried tree is limited
#               to 64 MiB and lego's PNGs alone are 53 MB); they are turned back into PNG there
# Then, with carry [".dev"] and a timeout of 600 s:
#   bash bench/gpu_protocol.sh .dev/data/lego --ratios 100 30
# Everything after the dataset goes to gpu_protocol.py. Results: $OUT/summary.json and
# $OUT/logs.tgz (the logs and every encode's --stats), written even when a step runs out of time.
set -uo pipefail
data=${1:?usage: gpu_protocol.sh DATASET [gpu_protocol.py options]}
shift
out=${OUT:-/tmp/gpu-protocol-out}
mkdir -p "$out"
start=$(date +%s)
budget=${GPU_PROTOCOL_BUDGET:-570}   # seconds for the whole call, install and build included

python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site \
    .dev/whl/dracopy*.whl .dev/whl/construct*.whl .dev/whl/plyfile*.whl .dev/whl/spcodec*.whl
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/gs .dev/whl/gsplat*.whl
export PYTHONPATH=/tmp/gs:/tmp/site PYTHONUNBUFFERED=1 TORCH_EXTENSIONS_DIR=/tmp/ext
export MAX_JOBS=${MAX_JOBS:-$(nproc)}

dataset=/tmp/data/$(basename "$data")
python3 - "$data" "$dataset" <<'EOF'
"""Copy the dataset, turning lossless WebP images back into the PNGs its transforms name."""
import shutil, sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from PIL import Image

src, dst = Path(sys.argv[1]), Path(sys.argv[2])
shutil.copytree(src, dst, dirs_exist_ok=True)
webps = list(dst.rglob("*.webp"))

def to_png(path: Path) -> None:
    Image.open(path).save(path.with_suffix(".png"))
    path.unlink()

with ProcessPoolExecutor() as pool:
    list(pool.map(to_png, webps))
print(f"dataset ready: {dst} ({len(webps)} images restored)")
EOF

nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader | tee "$out/gpu.txt"
build_start=$(date +%s)
python3 -c "from gsplat.cuda._backend import _C" > "$out/gsplat_build.log" 2>&1 \
    || { echo "gsplat did not build: see gsplat_build.log"; tail -20 "$out/gsplat_build.log"; }
echo "gsplat build: $(( $(date +%s) - build_start )) s" | tee -a "$out/gpu.txt"

left=$(( budget - ($(date +%s) - start) - 20 ))   # 20 s to pack the results
python3 bench/gpu_protocol.py "$dataset" --work /tmp/gp --out /tmp/gp-out --device cuda \
    --deadline "$left" "$@"
cp /tmp/gp-out/summary.json "$out/" 2>/dev/null
cp /tmp/gp/*.json /tmp/gp-out/ 2>/dev/null
cp "$out/gsplat_build.log" /tmp/gp-out/ 2>/dev/null
tar -czf "$out/logs.tgz" -C /tmp gp-out
echo "done in $(( $(date +%s) - start )) s"
