"""The README's Python snippets run as written, on a real (small) file: the documentation stays true."""

from __future__ import annotations

import re

import pytest

import spcodec

from conftest import REPO


def readme_snippets() -> list[str]:
    return re.findall(r"```python\n(.*?)```", (REPO / "README.md").read_text(), re.S)


def test_the_readme_has_snippets():
    assert len(readme_snippets()) >= 2


@pytest.mark.parametrize("index", range(len(readme_snippets())))
def test_readme_snippet_runs(index, tmp_path, monkeypatch, small_file):
    from spcodec.synthetic import make_scene

    scene = make_scene(3, curves=2, per_curve=100, blobs=300).cloud
    spcodec.write_ply(tmp_path / "scene.ply", scene)
    (tmp_path / "scene.spc").write_bytes(small_file)
    monkeypatch.chdir(tmp_path)
    namespace: dict = {}
    exec(compile(readme_snippets()[index], f"README.md python block {index}", "exec"), namespace)
    if "everything" in namespace:  # the streaming snippet: per-layer clouds add up to the file
        assert namespace["everything"].equals(spcodec.decode(small_file))
        assert [len(c) for c in namespace["shown"]] == \
            [layer["gaussians"] for layer in namespace["info"]["layers"]]
    if "result" in namespace:  # the encoding snippet wrote a file that decodes
        assert len(spcodec.decode(tmp_path / "scene.spc")) == len(scene)
