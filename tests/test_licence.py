"""One licence for both packages, its text shipped in each (issue 40 item 5): the npm package said
MIT while the Python one said Apache-2.0, and the repository had no LICENSE file. The wheel's copy
is checked where the wheel is built (tests/test_packages.py); here the sources that make both
packages, and what ``npm pack`` puts in the tarball."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
WEB = REPO / "web"
SPDX = "Apache-2.0"


def test_the_licence_text_is_apache_2_and_the_same_in_both_packages():
    text = (REPO / "LICENSE").read_text()
    assert "Apache License" in text and "Version 2.0, January 2004" in text
    assert (WEB / "LICENSE").read_bytes() == (REPO / "LICENSE").read_bytes()


def test_every_package_declares_the_same_licence():
    pyproject = (REPO / "pyproject.toml").read_text()  # tomllib is 3.11+, the package 3.10+
    assert re.search(r'^license = "([^"]*)"$', pyproject, re.M).group(1) == SPDX
    assert re.search(r'^license-files = \[(.*)\]$', pyproject, re.M).group(1) == '"LICENSE"'
    web = json.loads((WEB / "package.json").read_text())
    assert web["license"] == SPDX and "LICENSE" in web["files"]
    for private in ("viewer", "examples"):  # not published, but say the same
        assert json.loads((WEB / private / "package.json").read_text())["license"] == SPDX


def test_npm_pack_puts_the_licence_in_the_tarball():
    npm = shutil.which("npm")
    if npm is None:
        pytest.skip("npm is not installed")
    done = subprocess.run([npm, "pack", "--dry-run", "--json", "--ignore-scripts"], cwd=WEB,
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    (packed,) = json.loads(done.stdout)
    files = {entry["path"] for entry in packed["files"]}
    assert "LICENSE" in files and "package.json" in files
