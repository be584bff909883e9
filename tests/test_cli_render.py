"""``spcodec render``'s progress: a turntable of many views of a large scene runs for tens of
seconds on a CPU, so its views are one stage with a count and an ETA on stderr (issue 40 item 2),
shown only once the stage has run longer than eval's 2 s delay; the PNG's line alone goes to
stdout."""

from __future__ import annotations

import pytest

import spcodec
from spcodec.cli import main
from spcodec.encoder import progress
from spcodec.synthetic import make_scene


@pytest.fixture(scope="module")
def ply(tmp_path_factory):
    path = tmp_path_factory.mktemp("render") / "s.ply"
    spcodec.write_ply(path, make_scene(12, curves=4, per_curve=100, blobs=400).cloud)
    return path


def _render(ply, png, *extra) -> int:
    return main(["render", str(ply), "-o", str(png), "--resolution", "24", "--device", "cpu",
                 *extra])


def test_a_slow_turntable_shows_its_views_counted_with_an_eta(capsys, monkeypatch, tmp_path, ply):
    monkeypatch.setattr(progress._PrintedStage, "_due", lambda self: True)  # as if slow
    png = tmp_path / "t.png"
    assert _render(ply, png, "--turntable", "4") == 0
    out, err = capsys.readouterr()
    assert out == f"wrote {png} (52x52)\n"  # 4 views of 24 px: a 2x2 sheet, 4 px apart
    lines = err.splitlines()
    assert lines[0] == "[1] render 4 views of 24x24 ...", err
    counted = [line.split()[6] for line in lines if "it/s, ETA " in line]
    assert counted == ["1/4,", "2/4,", "3/4,", "4/4,"], err
    assert lines[-1].startswith("[1] render 4 views of 24x24: 4 rendered ("), err
    assert png.stat().st_size > 0


def test_a_quick_render_or_quiet_prints_only_the_png(capsys, monkeypatch, tmp_path, ply):
    # quicker than the delay, decided without the wall clock (a loaded machine is slow)
    monkeypatch.setattr(progress._PrintedStage, "_due", lambda self: self.shown)
    assert _render(ply, tmp_path / "a.png", "--view", "1") == 0
    out, err = capsys.readouterr()
    assert out.startswith("wrote ") and err == ""
    monkeypatch.setattr(progress._PrintedStage, "_due", lambda self: True)
    assert _render(ply, tmp_path / "b.png", "--turntable", "2", "--quiet") == 0
    out, err = capsys.readouterr()
    assert out.startswith("wrote ") and err == ""


def test_an_error_while_rendering_ends_the_progress_line_first(capsys, monkeypatch, tmp_path, ply):
    """The one-line error starts a line of its own, after the stage's last count."""
    import spcodec.imaging.render as render

    calls = []

    def failing(*args, **kwargs):
        calls.append(1)
        if len(calls) == 2:
            raise MemoryError
        return real(*args, **kwargs)

    real = render.render_image
    monkeypatch.setattr(render, "render_image", failing)
    monkeypatch.setattr(progress._PrintedStage, "_due", lambda self: True)
    assert _render(ply, tmp_path / "x.png", "--turntable", "3") != 0
    _, err = capsys.readouterr()
    lines = err.splitlines()
    assert lines[-1] == "spcodec: error: out of memory", err
    assert lines[0] == "[1] render 3 views of 24x24 ...", err
    assert lines[1].startswith("[1] render 3 views of 24x24 1/3, "), err
    assert not (tmp_path / "x.png").exists()
