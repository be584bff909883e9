"""The spec, the code and the tests use one vocabulary: requirement ids and error codes."""

from __future__ import annotations

import re

from spcodec.errors import ERROR_CODES

from conftest import REPO

SPEC = (REPO / "spec" / "bitstream-v1.md").read_text(encoding="utf-8")
DEFINED = set(re.findall(r"\*\*\[R-(\d+)\]\*\*", SPEC))


def _cited_in(folders: list[str]) -> set[str]:
    cited = set()
    for folder in folders:
        for path in (REPO / folder).rglob("*.py"):
            text = path.read_text(encoding="utf-8")
            for lo, hi in re.findall(r"\[R-(\d+)\]\.\.\[R-(\d+)\]", text):
                cited |= {lo, hi}
            cited |= set(re.findall(r"\[R-(\d+)\]", text))
    return cited


def test_every_requirement_is_defined_once():
    ids = re.findall(r"\*\*\[R-(\d+)\]\*\*", SPEC)
    assert len(ids) == len(set(ids)), "a requirement id is defined twice"


def test_every_cited_requirement_exists_in_the_spec():
    cited = _cited_in(["spcodec", "decoder", "encoder", "tests", "conformance"])
    assert cited - DEFINED == set()


def test_requirements_cited_inside_the_spec_exist():
    assert set(re.findall(r"\[R-(\d+)\]", SPEC)) - DEFINED == set()


def test_error_codes_match_the_spec_table():
    table = set(re.findall(r"^\| `([a-z-]+)` \|", SPEC, flags=re.MULTILINE))
    format_codes = set(ERROR_CODES) - {"ply-invalid", "dataset-invalid"}
    assert table == format_codes
