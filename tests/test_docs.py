"""The documentation stays true: the results page is what its generator writes from the committed
rows, every decision the encoder cites exists, the configuration cites decisions rather than
carrying measurements, and every relative link and LOG citation lands on something that exists."""

from __future__ import annotations

import re
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from conftest import REPO

sys.path.insert(0, str(REPO / "bench"))
import results_page  # noqa: E402  (bench/ is not a package)
import svg_chart  # noqa: E402

DOCS = REPO / "docs"
LINK = re.compile(r"\[[^\]]*\]\(([^)\s]+)\)")
DECISION = re.compile(r"\bD-(\d+)\b")
DB_FIGURE = re.compile(r"\d\s*dB\b")
LOG_CITATION = re.compile(r"docs/LOG\.md,?(?: section)? (\d+(?:\.\d+)?)")


def markdown_files() -> list[Path]:
    return sorted(DOCS.glob("*.md")) + [REPO / "README.md"]


def heading_anchors(path: Path) -> set[str]:
    """The anchors GitHub gives a Markdown file's headings (the rule the page generator uses)."""
    anchors = set()
    for line in path.read_text(encoding="utf-8").splitlines():
        if line.startswith("#"):
            anchors.add(re.sub(r"[^\w\- ]", "", line.lstrip("#").strip().lower()).replace(" ", "-"))
    return anchors


def test_results_page_is_what_the_generator_writes():
    done = subprocess.run([sys.executable, "bench/results_page.py", "--check"], cwd=REPO,
                          capture_output=True, text=True)
    assert done.returncode == 0, done.stdout + done.stderr


def test_check_names_a_file_that_differs(tmp_path):
    built = results_page.build()
    copies = {tmp_path / p.name: text for p, text in built.items()}
    for path, text in copies.items():
        path.write_text(text, encoding="utf-8")
    assert results_page.stale(copies) == []
    edited = next(iter(copies))
    edited.write_text(copies[edited] + " ", encoding="utf-8")
    (tmp_path / "rd_lego.svg").unlink()
    assert set(results_page.stale(copies)) == {edited, tmp_path / "rd_lego.svg"}


def test_build_is_deterministic():
    assert results_page.build() == results_page.build()


def test_every_decision_cited_in_the_encoder_exists():
    decisions = DECISION.findall((DOCS / "DECISIONS.md").read_text(encoding="utf-8"))
    headings = re.findall(r"^### D-(\d+):", (DOCS / "DECISIONS.md").read_text(encoding="utf-8"), re.M)
    assert headings == [str(i) for i in range(1, len(headings) + 1)], "D-n numbered 1, 2, ... once each"
    cited = {(path.name, n) for path in (REPO / "encoder").rglob("*.py")
             for n in DECISION.findall(path.read_text(encoding="utf-8"))}
    assert cited, "the encoder cites its decisions"
    missing = sorted((name, n) for name, n in cited if n not in headings)
    assert not missing, f"cited but not in docs/DECISIONS.md: {missing}"
    assert set(decisions) >= set(headings)


def test_config_cites_decisions_instead_of_db_figures():
    config = (REPO / "encoder" / "config.py").read_text(encoding="utf-8")
    figures = [line.strip() for line in config.splitlines() if DB_FIGURE.search(line)]
    assert not figures, f"dB figures in encoder/config.py (cite DECISIONS D-n instead): {figures}"
    assert "(DECISIONS D-" in config


@pytest.mark.parametrize("path", markdown_files(), ids=lambda p: p.name)
def test_relative_links_point_to_existing_files(path):
    broken = []
    for target in LINK.findall(path.read_text(encoding="utf-8")):
        if re.match(r"[a-z]+:", target) or target.startswith("#"):
            continue
        file, _, anchor = target.partition("#")
        resolved = (path.parent / file).resolve()
        if not resolved.exists():
            broken.append(target)
        elif anchor and resolved.suffix == ".md" and anchor not in heading_anchors(resolved):
            broken.append(target)
    assert not broken, f"{path.name}: links to nothing: {broken}"


def cited_sources() -> list[Path]:
    sources = [REPO / "README.md", REPO / "web" / "README.md"]
    for folder in ("encoder", "imaging", "bench", "tests", "decoder", "cli", "tiling"):
        sources += sorted((REPO / folder).rglob("*.py"))
    return sources


def test_log_citations_name_existing_sections():
    sections = set(results_page.log_anchors((DOCS / "LOG.md").read_text(encoding="utf-8")))
    unknown = [(path.name, n) for path in cited_sources()
               for n in LOG_CITATION.findall(path.read_text(encoding="utf-8")) if n not in sections]
    assert not unknown, f"citations of docs/LOG.md sections that do not exist: {unknown}"


def test_no_section_is_cited_from_the_results_page():
    """RESULTS.md has questions, not numbered sections: a number after it is a LOG section."""
    stale = [path.name for path in cited_sources()
             if re.search(r"RESULTS(?:\.md)?,?(?: section)? \d", path.read_text(encoding="utf-8"))]
    assert not stale, f"cite docs/LOG.md n.m, not RESULTS n.m: {stale}"


def test_smallest_as_good_takes_the_smallest_default_file_at_both_framings():
    spz = {"scene": "s", "method": "spz", "bytes": 1000, "orbit": 40.0, "close": 35.0}
    rows = [spz,
            {"scene": "s", "method": "sp-target", "bytes": 300, "orbit": 41.0, "close": 34.9},
            {"scene": "s", "method": "sp-target", "bytes": 500, "orbit": 40.0, "close": 35.0},
            {"scene": "s", "method": "noretrain", "bytes": 800, "orbit": 50.0, "close": 45.0},
            {"scene": "s", "method": "pr-target", "bytes": 400, "orbit": 45.0, "close": 40.0},
            {"scene": "t", "method": "sp-target", "bytes": 100, "orbit": 60.0, "close": 60.0}]
    assert results_page.smallest_as_good(rows, "s", spz)["bytes"] == 500
    assert results_page.smallest_as_good(rows, "s", spz, ("noretrain",))["bytes"] == 800
    assert results_page.smallest_as_good(rows[:2], "s", spz) is None


@given(st.floats(1e2, 1e8), st.floats(1.5, 1e3))
def test_log_ticks_lie_in_range_and_rise(lo, span):
    ticks = svg_chart.log_ticks(lo, lo * span)
    assert all(lo <= t <= lo * span for t in ticks)
    assert ticks == sorted(set(ticks))


@given(st.floats(-50, 150), st.floats(1, 200))
def test_linear_ticks_lie_in_range_and_are_few(lo, span):
    ticks = svg_chart.linear_ticks(lo, lo + span)
    assert 2 <= len(ticks) <= 8
    assert all(lo - 1e-9 <= t <= lo + span + 1e-9 for t in ticks)


points = st.lists(st.tuples(st.floats(1e3, 1e8), st.floats(5, 130)), min_size=1, max_size=12)


@given(points, points)
def test_chart_is_svg_with_every_mark_inside_its_panel(first, second):
    panels = [svg_chart.Panel("a", (svg_chart.Series("one", "#000", tuple(first)),)),
              svg_chart.Panel("b", (svg_chart.Series("two", "#111", tuple(second), False, "square"),))]
    text = svg_chart.chart("t", panels)
    root = ET.fromstring(text)
    ns = "{http://www.w3.org/2000/svg}"
    plot_w = svg_chart.PANEL_WIDTH - svg_chart.MARGIN_LEFT - svg_chart.MARGIN_RIGHT
    plot_h = svg_chart.PANEL_HEIGHT - svg_chart.MARGIN_TOP - svg_chart.MARGIN_BOTTOM
    groups = root.findall(f"{ns}g")
    assert len(groups) == 2
    for group in groups:
        for dot in group.findall(f"{ns}circle"):
            assert -0.1 <= float(dot.get("cx")) <= plot_w + 0.1
            assert -0.1 <= float(dot.get("cy")) <= plot_h + 0.1
        for square in group.findall(f"{ns}rect")[1:]:
            assert -3.6 <= float(square.get("y")) <= plot_h + 0.1
    assert svg_chart.chart("t", panels) == text


def test_no_retrain_curve_lists_each_file_by_size_and_draws_each_scene():
    def row(method, nbytes, point="-", **extra):
        return {"scene": "guitar", "method": method, "point": point, "bytes": nbytes, "orbit": 40.0,
                "close": 35.0, "commit": "0123456789", **extra}
    rows = [row("spz", 1000), row("nr-target", 750, 0.75, seconds=12.0, load=3.5),
            row("nr-target", 250, 0.25, seconds=9.0, load=2.0), row("noretrain", 900, "transparent"),
            row("pr-target", 500, 0.5), {**row("spz", 10), "scene": "kacytran"}]
    page = results_page.Page({})
    files = results_page.no_retrain_curve(page, rows)
    table = [line for line in page.lines if line.startswith("| guitar")]
    assert [line.split(" | ")[2] for line in table] == ["250", "750", "900", "1,000"]
    assert "| 0.75 |" in table[1] and "| 12 (3.5) |" in table[1]
    assert "0123456" in page.text()
    assert set(files) == {results_page.DOCS / "results" / "rd_guitar.svg"}
    ET.fromstring(files[results_page.DOCS / "results" / "rd_guitar.svg"])
