"""A retrained encode's first line estimates the whole run, stage by stage; its targets render in
one pass (crops as their own small cameras); --no-eval skips the closing evaluation."""

from __future__ import annotations

import dataclasses
import json
import shlex

import numpy as np
import pytest
import torch

import spcodec
from spcodec.cli import build_parser, main
from spcodec.encoder import progress
from spcodec.encoder.estimate import RunEstimate, duration
from spcodec.encoder.retraining.clock import TrainingClock
from spcodec.errors import UsageError
from spcodec.imaging.cameras import Camera
from spcodec.imaging.render import GaussianParams, RenderSettings, render
from spcodec.imaging.training.targets import check_targets, distillation_targets
from spcodec.imaging.views import close_crops, sample_views
from spcodec.synthetic import make_scene

pytestmark = pytest.mark.usefixtures("single_torch_thread")

TINY = ["--iterations", "60", "--finish-iterations", "8", "--views", "6", "--resolution", "48",
        "--close-views", "4", "--threads", "1", "--device", "cpu"]
"""A retrained encode of seconds: more retraining steps than the estimate's correction waits."""


@pytest.fixture(scope="module")
def scene():
    return make_scene(11, curves=6, per_curve=150, blobs=800).cloud


@pytest.fixture(scope="module")
def ply(tmp_path_factory, scene):
    path = tmp_path_factory.mktemp("estimate") / "s.ply"
    spcodec.write_ply(path, scene)
    return path


# --------------------------------------------------------------------------- the estimate
@pytest.mark.training
def test_the_first_line_estimates_every_stage_and_training_corrects_it(capsys, monkeypatch,
                                                                       ply, tmp_path):
    monkeypatch.setattr(progress._PrintedStage, "_due", lambda self: True)  # as if slow
    out = tmp_path / "s.spc"
    assert main(["encode", str(ply), "-o", str(out), "--no-eval", "--stats",
                 str(tmp_path / "s.json"), *TINY]) == 0
    lines = capsys.readouterr().err.splitlines()
    assert lines[0] == "[1] estimate ..."
    first = lines[1]
    assert first.startswith("[1] estimate: this encode takes about ")
    for stage in ("targets ", "retraining + finish ", "(68 steps at ~", "evaluation skipped",
                  "--no-retrain"):
        assert stage in first
    assert lines[2].startswith("[2] targets")  # the first long stage comes after it
    assert any(line.startswith("[2] targets 10/10, ") and "ETA" in line for line in lines)
    corrected = [line for line in lines if "estimate corrected: 50 steps measured at " in line]
    assert len(corrected) == 1 and "the rest of the encode takes about " in corrected[0]
    stats = json.loads((tmp_path / "s.json").read_text())
    assert stats["seconds"]["estimate"] < stats["seconds"]["retrain"] + stats["seconds"]["targets"]
    estimate = stats["retrain"]["estimate"]  # what bench_rd records beside the measured seconds
    assert estimate["total"] == pytest.approx(estimate["targets"] + estimate["training"])
    assert estimate["evaluation"] is None and estimate["training"] > 0


def test_the_line_names_the_evaluation_and_the_faster_ways():
    from spcodec.encoder.config import RetrainConfig

    estimate = RunEstimate(targets=80.0, training=560.0, evaluation=80.0, step=0.15, steps=3600,
                           fixed=20.0)
    line = estimate.line(RetrainConfig())
    assert "about 12 min here: targets 80 s, retraining + finish 9 min (3,600 steps at ~0.15 s)" \
        in line and "evaluation 80 s" in line and "--no-eval" in line
    # 1,600 steps at 0.15 s and the fixed 20 s: 260 s of training, 440 s in all
    assert "--iterations 1000: about 7 min" in line
    skipped = dataclasses.replace(estimate, evaluation=None)
    assert skipped.total == pytest.approx(640.0) and "evaluation skipped" in skipped.line(
        RetrainConfig())


def test_a_correction_rescales_the_training_steps_only():
    estimate = RunEstimate(targets=10.0, training=3600 * 0.1 + 20.0, evaluation=30.0, step=0.1,
                           steps=3600, fixed=20.0)
    assert estimate.corrected(0.2).training == pytest.approx(3600 * 0.2 + 20.0)
    assert (estimate.corrected(0.2).evaluation, estimate.corrected(0.2).targets) == (30.0, 10.0)


def test_durations_read_at_the_precision_of_an_estimate():
    assert [duration(s) for s in (4.2, 89.0, 95.0, 3599.0, 3900.0)] == \
        ["4 s", "89 s", "2 min", "1 h 00 min", "1 h 05 min"]


def test_the_training_clock_counts_from_the_end_of_the_first_step(monkeypatch):
    from spcodec.encoder.retraining import clock as clock_module

    now = [100.0]
    monkeypatch.setattr(clock_module.time, "perf_counter", lambda: now[0])
    probed, unprobed = TrainingClock(after=30.0, probe_step=0.25), TrainingClock(after=30.0)
    for clock in (probed, unprobed):
        clock.tick()  # the first step: buffers allocated, not counted
    assert np.isnan(probed.per_step) and np.isnan(probed.eta_all(100))
    for _ in range(4):
        now[0] += 0.5
        for clock in (probed, unprobed):
            clock.tick()
    assert probed.per_step == pytest.approx(0.5)
    # twice as slow as the probe: the evaluation after the steps too
    assert probed.eta_all(100) == pytest.approx(100 * 0.5 + 2 * 30.0)
    assert unprobed.eta_all(100) == pytest.approx(100 * 0.5 + 30.0)


# ----------------------------------------------------------------------------- the targets
def _crops_and_frames(scene, resolution: int, side: int):
    """Close crops with the full frame each is cut from, and the crop's corner in it."""
    for crop in close_crops(scene, 3, resolution=resolution, crop=side, seed=2):
        x0, y0 = round(resolution / 2 - crop.cx), round(resolution / 2 - crop.cy)
        assert 0 <= x0 <= resolution - side and 0 <= y0 <= resolution - side
        yield crop, Camera(resolution, resolution, crop.fx, crop.fy, resolution / 2,
                           resolution / 2, crop.world_to_camera), x0, y0


def _both(params, crop, frame, x0, y0, settings):
    with torch.no_grad():
        whole = render(params, frame, settings).image[y0:y0 + crop.height, x0:x0 + crop.width]
        return render(params, crop, settings).image, whole


def test_a_crop_renders_the_pixels_of_its_full_frame(scene):
    """A close crop is its own camera (the full view's intrinsics, shifted): it renders the full
    frame's pixels there at a fraction of the cost. Exactly so for every Gaussian whose centre
    falls within 15 % of the crop's side outside it; beyond, the projection's Jacobian is clamped
    at the rendered image's edge (as INRIA's and gsplat's renderers do), the crop's nearer than
    the frame's, which moves a few border pixels by a trace (guitar: at most 3/255, 70-90 dB)."""
    settings = RenderSettings(antialiased=True)
    resolution, side = 160, 96
    for crop, frame, x0, y0 in _crops_and_frames(scene, resolution, side):
        uv, depth = crop.project(scene.means)
        near = (depth > 0) & ((uv >= -0.15 * side) & (uv <= 1.15 * side)).all(axis=1)
        cut, whole = _both(GaussianParams.from_cloud(scene.subset(np.flatnonzero(near)), "cpu"),
                           crop, frame, x0, y0, settings)
        assert cut.shape == (side, side, 3) and float(whole.max()) > 0.05  # it shows the scene
        torch.testing.assert_close(cut, whole, atol=1e-5, rtol=1e-4)
        cut, whole = _both(GaussianParams.from_cloud(scene, "cpu"), crop, frame, x0, y0, settings)
        mse = float(((cut.clamp(0, 1) - whole.clamp(0, 1)) ** 2).mean())
        assert mse < 1e-5  # above 50 dB with the Gaussians the clamp moves


def test_distillation_targets_check_themselves_in_the_one_pass(scene):
    """The renders that make the targets give the check's figures: no second pass."""
    settings = RenderSettings()
    whole = sample_views(scene, 3, resolution=(40, 40), split="train")
    crops = close_crops(scene, 2, resolution=80, crop=24)
    counted = []
    targets = distillation_targets(scene, whole, settings, torch.device("cpu"), crops,
                                   on_view=lambda: counted.append(1))
    assert len(counted) == 5
    assert targets.psnr_model == pytest.approx(
        check_targets(scene, targets, settings, torch.device("cpu")))


def test_distillation_targets_refuse_cameras_that_miss_the_model(scene):
    away = sample_views(scene, 1, resolution=(24, 24), split="train")[0]
    turned = away.world_to_camera.copy()
    turned[[0, 2], :] *= -1  # half a turn about the camera's y axis: the scene is behind it
    behind = dataclasses.replace(away, world_to_camera=turned)
    with pytest.raises(UsageError, match="do not see the model"):
        distillation_targets(scene, [behind], RenderSettings(), torch.device("cpu"))


# ------------------------------------------------------------------------------- --no-eval
@pytest.mark.training
def test_no_eval_writes_no_quality_and_says_how_to_measure_it(capsys, ply, tmp_path):
    out, stats = tmp_path / "n.spc", tmp_path / "n.json"
    assert main(["encode", str(ply), "-o", str(out), "--no-eval", "--antialiased", "--quiet",
                 "--stats", str(stats), *TINY]) == 0
    summary = capsys.readouterr().out
    doc = json.loads(stats.read_text())
    assert "quality" not in doc and "evaluate" not in doc["seconds"]
    command = doc["evaluation"]["command"]
    assert command == shlex.join(["spcodec", "eval", str(out), "--reference", str(ply),
                                  "--antialiased"])
    assert f"quality: not evaluated (--no-eval); `{command}` measures it" in summary
    args = build_parser().parse_args(shlex.split(command)[1:])  # a command eval takes
    assert args.antialiased and args.reference == str(ply)
