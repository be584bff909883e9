"""The packages as users install them: a wheel of this checkout in a fresh virtual environment,
and ``npm pack`` of web/ in an empty project.

A plain ``pip install .`` used to fail zstd vectors of its own conformance suite and to serve no
viewer page (404); the npm package had no types an editor could read. These tests build and
install both for real (PyPI and the npm registry are reached), so they are slow; they skip, saying
why, where pip's build, npm or the local torch wheel are missing.
"""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
import urllib.parse
import urllib.request
import zipfile
from pathlib import Path

import pytest

import spcodec

REPO = Path(__file__).resolve().parents[1]
WEB = REPO / "web"

pytestmark = pytest.mark.slow


def run(*args, cwd=None, env=None, timeout=900) -> subprocess.CompletedProcess:
    done = subprocess.run([str(a) for a in args], cwd=cwd, env=env, capture_output=True,
                          text=True, timeout=timeout)
    assert done.returncode == 0, (args, done.stdout[-2000:], done.stderr[-3000:])
    return done


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    """The wheel of this checkout, as ``pip wheel .`` builds it."""
    work = tmp_path_factory.mktemp("wheel")
    run(sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", work, REPO, timeout=1200)
    return next(work.glob("spcodec-*.whl"))


@pytest.fixture(scope="module")
def venv(wheel, tmp_path_factory) -> Path:
    """A fresh virtual environment with the wheel of this checkout and its encoder extra."""
    env_dir = tmp_path_factory.mktemp("venv") / "venv"
    run(sys.executable, "-m", "venv", env_dir)
    pip = env_dir / "bin" / "pip"
    run(pip, "install", "-q", "torch==2.13.0", timeout=1200)  # the local CPU build, first
    run(pip, "install", "-q", f"{wheel}[encoder]", timeout=1200)
    return env_dir


def test_the_wheel_carries_the_licence_text_and_names_it(wheel):
    """The licence travels with the wheel (PEP 639: a copy under the dist-info, named in the
    metadata), the same text as the repository's and the npm package's (tests/test_licence.py)."""
    with zipfile.ZipFile(wheel) as archive:
        info = next(n for n in archive.namelist() if n.endswith(".dist-info/METADATA"))
        folder = info.rsplit("/", 1)[0]
        metadata = archive.read(info).decode()
        shipped = archive.read(f"{folder}/licenses/LICENSE")
    assert "License-Expression: Apache-2.0" in metadata.splitlines()
    assert "License-File: LICENSE" in metadata.splitlines()
    assert shipped == (REPO / "LICENSE").read_bytes()


def test_the_wheel_runs_the_demo_and_its_own_conformance_suite(venv, tmp_path):
    spc = venv / "bin" / "spcodec"
    run(spc, "demo", "-o", tmp_path / "demo", cwd=tmp_path)
    assert spcodec.decode(tmp_path / "demo" / "demo.spc").sh_degree >= 0
    done = run(spc, "conformance", cwd=tmp_path)  # exit 0: every decode ran and passed
    assert "0 failed, 0 not run" in done.stdout
    assert "zstandard package is not installed" in done.stdout  # no zstd extra: expected so


def test_the_wheel_serves_the_viewer_page_and_what_it_loads(venv, tmp_path):
    source = REPO / "conformance" / "vectors" / "valid"
    scene = next(source.rglob("*.spc"))
    proc = subprocess.Popen([venv / "bin" / "spcodec", "serve", scene, "--port", "0"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            cwd=tmp_path)
    try:
        line = proc.stdout.readline()
        base = re.search(r"open (http://\S+/)", line).group(1)
        page = urllib.request.urlopen(base, timeout=30)  # redirected to the viewer
        html = page.read().decode()
        assert page.status == 200 and "spcodec viewer" in html
        imports = json.loads(re.search(r'<script type="importmap">(.*?)</script>', html,
                                       re.S).group(1))["imports"]
        page_url = page.geturl()
        for target in [*imports.values(), "./src/app.js",
                       "../node_modules/draco3d/draco_decoder.wasm", "../src/index.js",
                       "../loaders/playcanvas.js"]:
            reply = urllib.request.urlopen(urllib.parse.urljoin(page_url, target), timeout=30)
            assert reply.status == 200 and reply.read(1), target
    finally:
        proc.terminate()
        proc.wait(timeout=30)
    assert "warning" not in proc.stderr.read()


@pytest.fixture(scope="module")
def npm_project(tmp_path_factory) -> Path:
    """An empty npm project with the package `npm pack` makes of web/ installed in it."""
    npm = shutil.which("npm")
    if npm is None or not (WEB / "node_modules" / "typescript").is_dir():
        pytest.skip("npm, or web/'s npm packages (npm ci in web/), are missing")
    work = tmp_path_factory.mktemp("npm")
    run(npm, "pack", "--pack-destination", work, cwd=WEB)
    tarball = next(work.glob("spcodec-*.tgz"))
    project = work / "app"
    project.mkdir()
    run(npm, "init", "-y", cwd=project)
    run(npm, "install", "--no-audit", "--no-fund", tarball, cwd=project)
    return project


def test_the_npm_package_decodes_a_file_in_an_empty_project(npm_project):
    fixture = WEB / "test" / "fixtures" / "sh3-zlib-quant16.spc"
    script = npm_project / "decode.mjs"
    script.write_text("import { readFileSync } from 'node:fs';\n"
                      "import { decode, streamLayers } from 'spcodec';\n"
                      "import { loadSpc } from 'spcodec/playcanvas';\n"
                      f"const scene = await decode(readFileSync({json.dumps(str(fixture))}));\n"
                      "console.log(JSON.stringify({ count: scene.count, sh: scene.shDegree,\n"
                      "  stream: typeof streamLayers, loader: typeof loadSpc }));\n")
    done = run("node", script, cwd=npm_project)
    got = json.loads(done.stdout)
    cloud = spcodec.decode(fixture)
    assert got == {"count": len(cloud), "sh": cloud.sh_degree, "stream": "function",
                   "loader": "function"}


def test_the_npm_package_has_types_an_editor_reads(npm_project):
    """TypeScript, as an editor's language service does, finds the declarations: a correct use
    checks clean and a wrong one is caught."""
    tsc = WEB / "node_modules" / ".bin" / "tsc"
    options = ["--noEmit", "--strict", "--module", "nodenext", "--moduleResolution", "nodenext",
               "--target", "es2022", "--lib", "es2022,dom"]
    good = npm_project / "good.ts"
    good.write_text("import { decode, streamLayers, SpcError } from 'spcodec';\n"
                    "import { loadSpc } from 'spcodec/spark';\n"
                    "export async function count(bytes: Uint8Array): Promise<number> {\n"
                    "  const scene = await decode(bytes);\n"
                    "  const kind: string = scene.layers[0].kind;\n"
                    "  await streamLayers('x.spc', { onLayer: (l) => { l.cloud.count.toFixed(); } });\n"
                    "  void loadSpc; void kind; void SpcError;\n"
                    "  return scene.count;\n}\n")
    bad = npm_project / "bad.ts"
    bad.write_text("import { decode } from 'spcodec';\n"
                   "export async function wrong(bytes: Uint8Array): Promise<string> {\n"
                   "  return (await decode(bytes)).count;\n}\n")
    typed = subprocess.run([str(tsc), *options, str(good)], cwd=npm_project,
                           capture_output=True, text=True)
    assert typed.returncode == 0, typed.stdout + typed.stderr
    caught = subprocess.run([str(tsc), *options, str(bad)], cwd=npm_project,
                            capture_output=True, text=True)
    assert caught.returncode != 0 and "not assignable to type 'string'" in caught.stdout
