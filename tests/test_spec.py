"""The spec, the code and the tests use one vocabulary: requirement ids and error codes."""

from __future__ import annotations

import re

from spcodec.errors import ERROR_CODES

from conftest import REPO

SPEC = (REPO / "spec" / "bitstream-v1.md").read_text(encoding="utf-8")
DEFINED = set(re.findall(r"\*\*\[R-(\d+)\]\*\*", SPEC))
_INDEX_ROW = re.compile(r"^\| \[R-(\d+)\] \| [^|]+ \| (decoder|file|writer|reference) \| "
                        r"(yes|no: [^|]+) \|$", re.MULTILINE)


def requirement_index() -> dict[str, tuple[str, bool]]:
    """Annex D: requirement id ("R-n") -> (what it binds, whether a decoder can check it)."""
    annex = SPEC[SPEC.index("## Annex D."):SPEC.index("## Annex E.")]
    return {f"R-{n}": (binds, checkable == "yes") for n, binds, checkable in _INDEX_ROW.findall(annex)}


def checkable_requirements() -> set[str]:
    """The requirements the conformance suite must exercise (Annex D, checkable by a decoder)."""
    return {r for r, (_, checkable) in requirement_index().items() if checkable}


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


def test_the_requirement_index_lists_every_requirement_once():
    """Annex D: one row per defined requirement, none for an undefined one."""
    annex = SPEC[SPEC.index("## Annex D."):SPEC.index("## Annex E.")]
    rows = re.findall(r"^\| \[R-(\d+)\] \|", annex, flags=re.MULTILINE)
    assert len(rows) == len(set(rows)), "a requirement has two rows"
    assert set(rows) == DEFINED
    assert len(requirement_index()) == len(rows), "a row does not follow the table's format"
    binds = {r: b for r, (b, _) in requirement_index().items()}
    assert binds["R-1"] == "decoder" and binds["R-94"] == "writer" and binds["R-95"] == "reference"
    assert not requirement_index()["R-25"][1] and requirement_index()["R-7"][1]


def test_implementation_defined_outcomes_are_listed():
    """Section 1.1 names each case where two conforming decoders may differ."""
    section = SPEC[SPEC.index("### 1.1 Conformance"):SPEC.index("**[R-2]**")]
    assert re.findall(r"^\| (ID-\d+):", section, flags=re.MULTILINE) == \
        [f"ID-{i}" for i in range(1, 7)]


def _requirement_paragraphs() -> dict[int, str]:
    """Each normative requirement's text: from its ``**[R-n]**`` to the next one or heading
    (section 12's table, Annex D and the suite's interface of Annex F left out: they cite the
    codes rather than say when a decoder reports them)."""
    body = SPEC[:SPEC.index("## 12. Error conditions")] + \
        SPEC[SPEC.index("## 13. Versioning"):SPEC.index("## Annex D.")] + \
        SPEC[SPEC.index("## Annex E."):SPEC.index("## Annex F.")]
    paragraphs = {}
    for chunk in re.split(r"\n(?=\*\*\[R-\d+\]\*\*)", body):
        head = re.match(r"\*\*\[R-(\d+)\]\*\*", chunk)
        if head:
            paragraphs[int(head.group(1))] = re.split(r"\n#+ ", chunk)[0]
    return paragraphs


def test_error_table_cites_every_requirement_that_names_a_code():
    """Section 12: a code's row lists every requirement whose text says a decoder reports it, and
    no requirement that never mentions it (spec 1.0.1 found six rows short)."""
    named: dict[str, set[int]] = {}
    for number, text in _requirement_paragraphs().items():
        for code in set(re.findall(r"`([a-z]+(?:-[a-z]+)*)`", text)) & set(ERROR_CODES):
            named.setdefault(code, set()).add(number)
    table = SPEC[SPEC.index("## 12. Error conditions"):SPEC.index("## 13. Versioning")]
    rows = re.findall(r"^\| `([a-z-]+)` \| [^|]+ \| ([^|]+) \|$", table, flags=re.MULTILINE)
    assert rows, "section 12's table was not found"
    for code, cited in rows:
        listed = {int(n) for n in re.findall(r"R-(\d+)", cited)}
        assert listed == named.get(code, set()), f"section 12, row {code}"
