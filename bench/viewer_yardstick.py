"""The third-party yardstick: a PLY against its original, rendered by the PlayCanvas engine in
headless Chromium at the viewer's orbit framing and at half that distance (a close-up).

It drives the shared tool ``viewer-render`` (``$SPCODEC_VIEWER_RENDER``, by default
``../shared/tools/viewer-render`` beside the checkout): 8 views around the median of the
positions, 20 degrees above the horizon, a 50-degree vertical field of view, at the distance
where a sphere of half the 5-95 % box diagonal just fits the frame (``orbit``) and at half that
distance (``close``), 512x512; PSNR over whole images, black background included. The
original's renders are made once per file and options and kept in ``cache``.

    from viewer_yardstick import two_framings
    two_framings(original_ply, decoded_ply, cache_dir, up="-y")   # {"orbit": dB, "close": dB}
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
TOOL = Path(os.environ.get("SPCODEC_VIEWER_RENDER", REPO.parent / "shared/tools/viewer-render"))
FRAMINGS = {"orbit": 1.0, "close": 0.5}
"""Name -> distance factor of the orbit framing."""


def missing() -> str | None:
    """Why the yardstick cannot run here (None: it can)."""
    if not (TOOL / "render.sh").exists():
        return f"viewer-render not found at {TOOL} (set SPCODEC_VIEWER_RENDER)"
    if shutil.which("node") is None:
        return "node is not installed"
    return None


def tool_up(up: str) -> str:
    """Our up-axis names (``-y``, ``+z``) in the tool's (``-y``, ``z``)."""
    return up.lstrip("+")


def _options(up: str, antialiased: bool) -> list[str]:
    return ["--up", tool_up(up)] + (["--aa"] if antialiased else [])


def reference(original: Path, cache: Path, up: str = "-y", antialiased: bool = False
              ) -> dict[str, Path]:
    """Folders of the original's renders (PNG views and ``cameras.json``) per framing."""
    original = Path(original).resolve()
    key = hashlib.sha256(f"{original} {original.stat().st_size} {original.stat().st_mtime_ns} "
                         f"{up} {antialiased}".encode()).hexdigest()[:16]
    out = {}
    for name, scale in FRAMINGS.items():
        folder = Path(cache) / f"{original.stem}-{key}" / name
        if not (folder / "cameras.json").exists():
            _run([str(TOOL / "render.sh"), str(original), str(folder), "--dist-scale", str(scale),
                  *_options(up, antialiased)])
        out[name] = folder
    return out


def render_like(ply: Path, reference_folder: Path, out: Path, antialiased: bool = False) -> Path:
    """Renders of ``ply`` at the cameras of ``reference_folder``."""
    args = [str(TOOL / "render.sh"), str(ply), str(out), "--cameras",
            str(reference_folder / "cameras.json")]
    _run(args + (["--aa"] if antialiased else []))
    return out


def psnr_folders(a: Path, b: Path) -> float:
    """Mean PSNR over the views two render folders share (8-bit images, peak 255), as the tool's
    compare.py takes it: identical views are left out of the mean (inf if all are)."""
    from spcodec.imaging.images import read_image

    values = []
    for view in sorted(Path(a).glob("view_*.png")):
        x, y = read_image(view), read_image(Path(b) / view.name)
        mse = float(np.mean((x.astype(np.float64) - y.astype(np.float64)) ** 2))
        if mse > 0:
            values.append(10 * np.log10(1.0 / mse))
    if not list(Path(a).glob("view_*.png")):
        raise RuntimeError(f"no views rendered in {a}")
    return float(np.mean(values)) if values else float("inf")


def two_framings(original: Path, decoded: Path, cache: Path, up: str = "-y",
                 antialiased: bool = False) -> dict[str, float]:
    """PSNR of ``decoded`` against ``original`` at both framings, as the viewer shows them."""
    refs = reference(original, cache, up, antialiased)
    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name, folder in refs.items():
            render_like(decoded, folder, Path(tmp) / name, antialiased)
            out[name] = round(psnr_folders(folder, Path(tmp) / name), 3)
    return out


def cameras_of(folder: Path):
    """The tool's cameras as :class:`~spcodec.imaging.cameras.Camera` (same pixel convention)."""
    from spcodec.imaging.cameras import Camera

    doc = json.loads((Path(folder) / "cameras.json").read_text())
    return [Camera(doc["width"], doc["height"], v["fx"], v["fy"], v["cx"], v["cy"],
                   np.array(v["world_to_camera"], np.float64), v["name"]) for v in doc["views"]]


def _run(args: list[str]) -> None:
    done = subprocess.run(args, capture_output=True, text=True)
    if done.returncode not in (0, 3):  # 3: a view is nearly blank, still written
        raise RuntimeError(f"viewer-render failed ({done.returncode}): "
                           f"{(done.stderr or done.stdout).strip().splitlines()[-1:]}")
