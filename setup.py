"""Build hook: the wheel carries the web viewer, so `spcodec serve` works from `pip install .`.

Everything else is declared in pyproject.toml. The viewer is static files beside the JavaScript
decoder (web/): the page, the decoder's modules and the few files of its npm packages a browser
loads (PlayCanvas's module build, Draco's decoder). They go into the wheel as
``spcodec/web/...`` with the same relative layout: the web folder beside ``spcodec/cli``, where
``spcodec.cli.server`` finds it as it finds ``web/`` beside ``cli/`` in a source checkout. npm's
packages are installed first (``npm ci``) when they are missing and npm is here; without npm the
wheel has no viewer and ``spcodec serve`` says so.
"""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py

ROOT = Path(__file__).resolve().parent
WEB = ROOT / "web"

VIEWER_FILES = [
    "viewer/index.html", "viewer/src/*.js", "src/*.js", "loaders/*.js", "package.json",
    "node_modules/draco3d/draco_decoder_nodejs.js", "node_modules/draco3d/draco_decoder.wasm",
    "node_modules/draco3d/package.json",
    "viewer/node_modules/playcanvas/build/playcanvas.mjs",
]
"""What the viewer page loads (its import map and the decoder's imports), relative to web/."""

NPM_FOLDERS = [WEB, WEB / "viewer"]


def _install_npm_packages() -> None:
    """``npm ci`` where the packages the viewer needs are missing (and npm is here)."""
    npm = shutil.which("npm")
    for folder in NPM_FOLDERS:
        if (folder / "node_modules").is_dir() or npm is None:
            continue
        subprocess.run([npm, "ci", "--no-audit", "--no-fund", "--loglevel=error"], cwd=folder,
                       check=False)


class BuildWithViewer(build_py):
    """build_py, then the viewer's files into ``spcodec/web`` of the build."""

    def run(self) -> None:
        super().run()
        if getattr(self, "editable_mode", False) or not (WEB / "viewer" / "index.html").is_file():
            return  # an editable install serves web/ in place; an sdist without web/ has none
        _install_npm_packages()
        target = Path(self.build_lib) / "spcodec" / "web"
        for pattern in VIEWER_FILES:
            for source in sorted(WEB.glob(pattern)):
                destination = target / source.relative_to(WEB)
                destination.parent.mkdir(parents=True, exist_ok=True)
                shutil.copyfile(source, destination)


setup(cmdclass={"build_py": BuildWithViewer})
