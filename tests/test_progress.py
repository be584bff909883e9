"""Progress display: on standard error only, a bar or lines with an ETA, quiet for quick stages."""

from __future__ import annotations

import io
import json
import sys
import time
from types import SimpleNamespace

import pytest

import spcodec
from spcodec.cli import main
from spcodec.encoder import progress
from spcodec.encoder.progress import StageReporter
from spcodec.synthetic import make_scene


@pytest.fixture(scope="module")
def ply(tmp_path_factory):
    path = tmp_path_factory.mktemp("progress") / "s.ply"
    spcodec.write_ply(path, make_scene(11, curves=6, per_curve=150, blobs=800).cloud)
    return path


class Clock:
    """A stand-in for time.perf_counter that the test moves."""

    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


@pytest.fixture
def clock(monkeypatch):
    fake = Clock()
    monkeypatch.setattr(progress, "time", SimpleNamespace(perf_counter=fake))
    return fake


def test_without_delay_a_stage_shows_at_once_with_an_eta(capsys, clock):
    stage = StageReporter().stage("judge", 4)
    for _ in range(4):
        clock.now += 2.0
        stage.update(1, eta_all=30.0)
    stage.done("PSNR 40 dB")
    out, err = capsys.readouterr()
    lines = err.splitlines()
    assert out == ""
    assert lines[0] == "[1] judge ..."
    assert lines[1] == "[1] judge 1/4, 0.50 it/s, ETA 0:06, all stages 0:30"
    assert lines[-1] == "[1] judge: PSNR 40 dB (8.0 s)"


def test_a_delayed_stage_shows_nothing_when_quick(capsys, clock):
    reporter = StageReporter(delay=2.0)
    stage = reporter.stage("prepare", None)
    clock.now += 0.5
    stage.done("8 views")
    stage = reporter.stage("judge", 8)
    for _ in range(8):
        clock.now += 0.1
        stage.update(1, eta_all=1.0)
    stage.done("PSNR 40 dB")
    assert capsys.readouterr() == ("", "")


def test_a_delayed_stage_shows_once_it_runs_long(capsys, clock):
    stage = StageReporter(delay=2.0).stage("judge", 8)
    clock.now += 1.0
    stage.update(1, eta_all=20.0)  # too early: nothing yet
    assert capsys.readouterr().err == ""
    clock.now += 1.5
    stage.update(1, eta_all=15.0)
    clock.now += 1.0
    stage.note("a note")
    stage.done("PSNR 40 dB")
    out, err = capsys.readouterr()
    assert out == ""
    assert err.splitlines() == ["[1] judge ...", "[1] judge 2/8, 0.80 it/s, ETA 0:08, all stages 0:15",
                                "[1] a note", "[1] judge: PSNR 40 dB (3.5 s)"]


def test_a_long_stage_without_steps_still_reports_its_end(capsys, clock):
    stage = StageReporter(delay=2.0).stage("prepare", None)
    clock.now += 3.0
    stage.done("8 views")
    assert capsys.readouterr() == ("", "[1] prepare: 8 views (3.0 s)\n")


def test_on_a_terminal_the_bar_is_on_stderr_with_the_eta_of_everything(monkeypatch):
    err = io.StringIO()
    err.isatty = lambda: True
    out = io.StringIO()
    monkeypatch.setattr(sys, "stderr", err)
    monkeypatch.setattr(sys, "stdout", out)
    stage = StageReporter().stage("judge", 3)
    for _ in range(3):
        time.sleep(0.15)  # past tqdm's 0.1 s between refreshes
        stage.update(1, eta_all=75.0)
    stage.done("PSNR 40 dB")
    assert out.getvalue() == ""
    text = err.getvalue()
    assert "[1] judge" in text and "ETA all=1:15" in text and "2/3" in text
    assert text.splitlines()[-1].startswith("[1] judge: PSNR 40 dB (")


def _eval(ply, *extra):
    return main(["eval", str(ply), "--reference", str(ply), "--json", "--views", "2",
                 "--resolution", "32", "--closeups", "0.5", "--closeup-resolution", "40",
                 "--device", "cpu", "--no-cache", *extra])


def test_eval_progress_goes_to_stderr_and_json_alone_to_stdout(capsys, monkeypatch, ply):
    monkeypatch.setattr(progress._PrintedStage, "_due", lambda self: True)  # as if slow
    assert _eval(ply) == 0
    out, err = capsys.readouterr()
    doc = json.loads(out)  # nothing but the document
    assert doc["views"] == 2 and len(doc["closeups"]) == 1
    lines = err.splitlines()
    assert lines[0].startswith("[1] prepare: 2 views around the reference (")
    assert any(line.startswith("[2] judge the sampled framing, 2 views of 32x32 1/2, ") and
               "ETA" in line and "all stages" in line for line in lines)
    assert any(line.startswith("[3] judge close-ups at 0.5 of the distance, 2 views of 40x40: "
                               "PSNR ") for line in lines)


def test_eval_quiet_and_quick_print_no_progress(capsys, monkeypatch, ply):
    import spcodec.imaging.render  # noqa: F401  (torch's import is no stage of this test)

    # every stage quicker than the delay (decided without the wall clock: a loaded machine
    # once made this 40x40 eval take longer than the 2 s delay)
    monkeypatch.setattr(progress._PrintedStage, "_due", lambda self: self.shown)
    assert _eval(ply) == 0
    out, err = capsys.readouterr()
    assert json.loads(out)["views"] == 2 and err == ""
    monkeypatch.setattr(progress._PrintedStage, "_due", lambda self: True)
    assert _eval(ply, "--quiet") == 0
    out, err = capsys.readouterr()
    assert json.loads(out)["views"] == 2 and err == ""


def test_the_summary_of_an_encode_without_evaluation_says_how_to_measure_it():
    stats = {"gaussians": 10, "bytes": 100, "sketch_gaussians": 0, "patch_gaussians": 10,
             "sketch": {}, "patch_layers": 1, "sections": {"PATCH_ATTRIBUTES": 60},
             "seconds": {"retrain": 2.0}, "output": "o.spc",
             "evaluation": {"skipped": True, "eval_options": [],
                            "command": "spcodec eval o.spc --reference i.ply"}}
    stream = io.StringIO()
    progress.print_summary(stats, stream)
    text = stream.getvalue()
    assert "  quality: not evaluated (--no-eval); `spcodec eval o.spc --reference i.ply` " \
        "measures it\n" in text
    assert "quality: PSNR" not in text
    stream = io.StringIO()
    progress.print_summary({k: v for k, v in stats.items() if k != "evaluation"}, stream)
    assert "quality" not in stream.getvalue()  # a --no-retrain encode is never judged


@pytest.mark.parametrize("kept, line", [(10, "every Gaussian kept"), (6, "6 of 10 Gaussians kept")])
def test_the_summary_of_a_size_target_says_how_many_gaussians_its_precision_kept(kept, line):
    """Below the preset's file a size target may prune at the precision it chose: the summary
    names the count, not "every Gaussian kept"."""
    stats = {"gaussians": 10, "bytes": 100, "sketch_gaussians": 0, "patch_gaussians": kept,
             "sketch": {}, "patch_layers": 1, "sections": {"PATCH_ATTRIBUTES": 60},
             "seconds": {}, "output": "o.spc",
             "rate": {"target_bytes": 100, "predicted_bytes": 100, "precision": {
                 "options": {"SCALE": {"entry_dim": 1, "entries": 64}}}}}
    stream = io.StringIO()
    progress.print_summary(stats, stream)
    assert f"  {line}; codebooks" in stream.getvalue()


@pytest.mark.parametrize("precision, line", [
    ({"preset_bytes": 90, "options": {"SCALE": {"entry_dim": 1, "entries": 64}}},
     "its codebooks' 90 bytes (as the search predicts them) spent by the search"),
    ({"preset_bytes": 90}, "nothing predicted to beat its own codebooks")])
def test_the_summary_of_a_preset_point_says_what_its_bytes_are(precision, line):
    """A no-retrain preset's point has no target (D-34): the summary says whose bytes it spent,
    or that the preset's own precision was kept."""
    stats = {"gaussians": 10, "bytes": 100, "sketch_gaussians": 0, "patch_gaussians": 10,
             "sketch": {}, "patch_layers": 1, "sections": {"PATCH_ATTRIBUTES": 60},
             "seconds": {}, "output": "o.spc",
             "rate": {"preset_point": True, "predicted_count": 10, "precision": precision}}
    stream = io.StringIO()
    progress.print_summary(stats, stream)
    assert f"  the preset's point: {line}" in stream.getvalue()
