"""File sizes with and without context-coded patch indices (format 1.2, spec 7.5).

Encodes each scene without retraining at each preset twice, ``PatchConfig.index_contexts`` on and
off (everything else equal, so quality is equal: the indices are the same), checks that both files
decode to the same Gaussians, and prints their sizes, the saving and the columns given a context::

    python bench/bench_contexts.py --scenes guitar donut fourth_st --presets balanced transparent

``--keep DIR`` also writes both files (``SCENE-PRESET.spc``, ``SCENE-PRESET-contexts.spc``) for
the decode-time comparison of bench/bench_web_decode.py ``--extra``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from spcodec import read_ply  # noqa: E402
from spcodec.decoder import decode_layers  # noqa: E402
from spcodec.decoder.info import inspect  # noqa: E402
from spcodec.encoder.pipeline import encode  # noqa: E402
from spcodec.encoder.presets import preset_config  # noqa: E402

from scenes import REAL, data_dir  # noqa: E402

FIELDS = ("means", "scales", "quats", "opacities", "sh_dc", "sh_rest")


def encode_both(cloud, preset: str, keep: Path | None = None, name: str = "") -> dict:
    """Sizes of the preset's no-retrain file with and without index contexts."""
    config = preset_config(preset)
    out = {}
    for contexts in (False, True):
        cfg = dataclasses.replace(config, patch=dataclasses.replace(config.patch,
                                                                     index_contexts=contexts))
        t = time.perf_counter()
        out[contexts] = (encode(cloud, cfg).data, time.perf_counter() - t)
    plain, coded = out[False][0], out[True][0]
    if keep is not None:
        keep.mkdir(parents=True, exist_ok=True)
        (keep / f"{name}-{preset}.spc").write_bytes(plain)
        (keep / f"{name}-{preset}-contexts.spc").write_bytes(coded)
    a, b = decode_layers(plain).cloud, decode_layers(coded).cloud
    if not all(np.array_equal(getattr(a, f), getattr(b, f)) for f in FIELDS):
        raise AssertionError("the files with and without contexts decode differently")
    info = inspect(coded).to_json()
    sections = [s for s in info["sections"] if s["type"] == "PATCH_INDEX_CONTEXTS"]
    return dict(preset=preset, without=len(plain), with_contexts=len(coded),
                saving_percent=round(100 * (1 - len(coded) / len(plain)), 2),
                contexts_section=sections[0]["length"] if sections else 0,
                version=info["version"], seconds=[round(out[False][1], 1), round(out[True][1], 1)])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", nargs="+", default=["guitar", "donut", "fourth_st"])
    parser.add_argument("--presets", nargs="+", default=["balanced", "transparent"])
    parser.add_argument("--keep", type=Path, help="write both files of each encode here")
    args = parser.parse_args()
    for scene in args.scenes:
        cloud = read_ply(data_dir() / REAL[scene])
        for preset in args.presets:
            row = encode_both(cloud, preset, args.keep, scene)
            print(json.dumps(dict(scene=scene, gaussians=len(cloud), **row)), flush=True)


if __name__ == "__main__":
    main()
