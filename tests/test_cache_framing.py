"""One framing of a reference evaluation on its own (what a quality target's judge renders):
the same cameras and bits as the evaluation's, shared with it through the render cache."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from spcodec.encoder.qualitycontrol import CloseupJudge, TargetJudge
from spcodec.imaging.evaluate import (
    EvalConfig,
    evaluate_against_reference,
    reference_framing,
    render_views,
)
from spcodec.synthetic import make_scene

pytestmark = pytest.mark.usefixtures("single_torch_thread")


@pytest.fixture(scope="module")
def scene():
    return make_scene(2, curves=3, per_curve=80, blobs=400, sh_degree=1).cloud


def _config(cache, **extra) -> EvalConfig:
    return EvalConfig(views=3, resolution=48, closeups=(0.5,), closeup_resolution=96,
                      device="cpu", cache=cache, **extra)


def _noisy(scene):
    noise = np.random.default_rng(1).normal(0, 0.05, scene.sh_dc.shape)
    return dataclasses.replace(scene, sh_dc=(scene.sh_dc + noise).astype(scene.sh_dc.dtype))


class _Summaries:
    """A progress sink that keeps what each stage said when it was done."""

    def __init__(self) -> None:
        self.done: list[str] = []

    def __call__(self, name: str, total):
        sink = self

        class Stage:
            def update(self, count: int = 1, **figures) -> None:
                pass

            def note(self, message: str) -> None:
                pass

            def done(self, summary: str = "") -> None:
                sink.done.append(summary)

        return Stage()


def test_a_framing_rendered_alone_is_the_one_the_evaluation_reads_back(tmp_path, scene):
    framing = reference_framing(scene, _config(tmp_path), 0.5)
    assert len(framing.cameras) == 3 and framing.images.shape == (3, 96, 96, 3)
    assert len(list(tmp_path.glob("*.npz"))) == 1
    model = _noisy(scene)
    said = _Summaries()
    cached = evaluate_against_reference(model, scene, _config(tmp_path, progress=said)
                                        ).framing(0.5)
    assert "from the cache" not in said.done[1] and "from the cache" in said.done[2]
    fresh = evaluate_against_reference(model, scene, _config(None)).framing(0.5)
    assert [v.psnr for v in cached.views] == [v.psnr for v in fresh.views]
    # served from the cache: the same bits and cameras as rendering it again
    again = reference_framing(scene, _config(None), 0.5)
    assert np.array_equal(again.images, framing.images)
    assert [c.world_to_camera.tolist() for c in again.cameras] == [
        c.world_to_camera.tolist() for c in framing.cameras]
    drawn = render_views(scene, framing.cameras, _config(None))
    assert np.array_equal(np.stack(drawn), framing.images)


@pytest.mark.slow  # renders the scene at full and reduced size: 9-11 s
def test_the_judge_reports_the_evaluations_closeup_psnr(tmp_path, scene):
    model = _noisy(scene)
    report = evaluate_against_reference(model, scene, EvalConfig(closeups=(0.5,), device="cpu"))
    judge = CloseupJudge(scene, device="cpu", cache=tmp_path)
    assert judge(model) == pytest.approx(report.framing(0.5).psnr, abs=1e-9)
    assert len(list(tmp_path.glob("*.npz"))) == 1  # the original's close-ups, for eval to reuse


@pytest.mark.slow  # renders the scene at full and reduced size: 9-11 s
def test_the_target_judge_predicts_at_fewer_pixels_and_verifies_at_full(tmp_path, scene):
    model = _noisy(scene)
    full = CloseupJudge(scene, device="cpu")(model)
    small = CloseupJudge(scene, device="cpu", resolution=200)(model)
    judge = TargetJudge(scene, device="cpu", cache=tmp_path, resolution=200)
    assert judge.offset == 0.0 and judge(model) == pytest.approx(small, abs=1e-9)
    assert judge.verify(model) == pytest.approx(full, abs=1e-9) and judge.full_judgements == 1
    assert judge.offset == pytest.approx(small - full, abs=1e-9)
    assert judge(model) == pytest.approx(full, abs=1e-9)  # the offset corrects the prediction
    told = TargetJudge(scene, device="cpu", cache=tmp_path, resolution=200)
    told.search = None  # given its own prediction, verify must not judge small again
    assert told.verify(model, predicted=small) == pytest.approx(full, abs=1e-9)
    assert told.offset == pytest.approx(small - full, abs=1e-9)


def test_renders_remembered_by_the_judge_make_the_same_report_without_drawing(scene, monkeypatch):
    """A quality target verifies its answer at the close-up framing and keeps those renders;
    the closing evaluation of the same scene then scores them, to the bit, instead of drawing
    them again, and a different scene is drawn as before."""
    from spcodec.imaging import evaluate as evaluate_module

    config = _config(None)
    model = _noisy(scene)
    monkeypatch.setattr(evaluate_module, "_REMEMBERED", {})
    plain = evaluate_against_reference(model, scene, config)
    cameras = reference_framing(scene, config, 0.5).cameras
    render_views(model, cameras, config, remember=True)
    reused = evaluate_against_reference(model, scene, config)
    for ours, theirs in zip(plain.closeups[0].views + plain.views,
                            reused.closeups[0].views + reused.views):
        assert (ours.psnr, ours.ssim) == (theirs.psnr, theirs.ssim)
    assert all(v.render_seconds == 0.0 for v in reused.closeups[0].views)  # scored, not drawn
    assert all(v.render_seconds > 0.0 for v in reused.views)  # the sampled framing was not remembered
    other = evaluate_against_reference(scene, scene, config)
    assert all(v.render_seconds > 0.0 for v in other.closeups[0].views)
