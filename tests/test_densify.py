"""Adaptive density control (imaging/training/densify.py) and vanilla training
(bench/train_vanilla.py): the statistics it reads from the renderer, the clone / split / prune
rules, optimizer state kept aligned through every change, and short runs that grow and improve."""

from __future__ import annotations

import copy
import json
import math

import numpy as np
import pytest
import torch
from hypothesis import given
from hypothesis import strategies as st

import spcodec
from spcodec.cloud import GaussianCloud
from spcodec.imaging.cameras import Camera
from spcodec.imaging.evaluate import EvalConfig, evaluate_against_dataset
from spcodec.imaging.render import RenderSettings, render
from spcodec.imaging.training.densify import (
    Densifier,
    DensifyConfig,
    append_gaussians,
    keep_gaussians,
    reset_opacities,
)
from spcodec.imaging.training.loop import FitLoop
from spcodec.imaging.training.optim import FreeGaussians, LearningRates
from spcodec.imaging.training.targets import distillation_targets

from conftest import load_bench_script, write_transforms_dataset

pytestmark = pytest.mark.usefixtures("single_torch_thread")


def cloud_of(n: int, seed: int = 0, degree: int = 1, spread: float = 0.5,
             scale: float = 0.05, opacity: float = 0.5) -> GaussianCloud:
    g = np.random.default_rng(seed)
    quats = g.normal(size=(n, 4))
    return GaussianCloud(
        means=g.uniform(-spread, spread, (n, 3)).astype(np.float32),
        scales=np.log(g.uniform(0.5, 1.5, (n, 3)) * scale).astype(np.float32),
        quats=(quats / np.linalg.norm(quats, axis=1, keepdims=True)).astype(np.float32),
        opacities=np.full(n, math.log(opacity / (1 - opacity)), np.float32),
        sh_dc=g.normal(size=(n, 3)).astype(np.float32),
        sh_rest=g.normal(scale=0.1, size=(n, (degree + 1) ** 2 - 1, 3)).astype(np.float32))


def ring_cameras(count: int, size: int = 32, radius: float = 3.0) -> list[Camera]:
    """Cameras on a tilted ring around the origin, looking at it."""
    cams = []
    for i in range(count):
        a = 2 * math.pi * i / count
        eye = np.array([radius * math.cos(a), 0.8 * math.sin(3 * a), radius * math.sin(a)])
        cams.append(Camera.look_at(eye, np.zeros(3), np.array([0.0, -1.0, 0.0]), size, size,
                                   math.radians(40)))
    return cams


def stepped(model: FreeGaussians, seed: int, steps: int = 2) -> None:
    """A few Adam steps with random gradients, so every moment is non-zero."""
    g = torch.Generator().manual_seed(seed)
    for _ in range(steps):
        for t in model.tensors.values():
            t.grad = torch.randn(t.shape, generator=g)
        model.optimizer.step()


def adam_state(model: FreeGaussians, name: str) -> dict:
    return model.optimizer.state[model.tensors[name]]


# ------------------------------------------------------------------------ optimizer surgery
@given(st.lists(st.booleans(), min_size=6, max_size=6), st.integers(0, 3), st.integers(0, 99))
def test_pruned_gaussians_step_exactly_as_they_would_have(keep, extra, seed):
    """Adam is element-wise, so after ``keep_gaussians`` (and after ``append_gaussians``) the
    surviving Gaussians must take exactly the step they would have taken untouched."""
    model = FreeGaussians(cloud_of(6, seed), "cpu", extent=2.0)
    stepped(model, seed)
    reference = copy.deepcopy(model)
    mask = torch.tensor(keep)
    keep_gaussians(model, mask)
    append_gaussians(model, {k: torch.randn((extra,) + v.shape[1:]) for k, v in
                             model.tensors.items()})
    assert all(model.optimizer.param_groups[i]["params"] == [t]
               for i, t in enumerate(model.tensors.values()))
    for name, t in model.tensors.items():
        state = adam_state(model, name)
        assert state["exp_avg"].shape == t.shape == state["exp_avg_sq"].shape
        kept = int(mask.sum())
        assert float(state["exp_avg"][kept:].abs().sum()) == 0.0  # appended: zero moments
        torch.testing.assert_close(state["exp_avg_sq"][:kept],
                                   adam_state(reference, name)["exp_avg_sq"][mask])
    g = torch.Generator().manual_seed(seed + 1)
    for ref_t, t in zip(reference.tensors.values(), model.tensors.values()):
        ref_t.grad = torch.randn(ref_t.shape, generator=g)
        t.grad = torch.cat([ref_t.grad[mask], torch.zeros((extra,) + t.shape[1:])])
    reference.optimizer.step()
    model.optimizer.step()
    for ref_t, t in zip(reference.tensors.values(), model.tensors.values()):
        torch.testing.assert_close(t.detach()[:int(mask.sum())], ref_t.detach()[mask],
                                   rtol=0, atol=0)


def test_opacity_reset_caps_opacities_and_zeroes_only_their_moments():
    cloud = cloud_of(5)
    cloud.opacities[:] = np.array([-8.0, -4.0, 0.0, 3.0, -4.6], np.float32)
    model = FreeGaussians(cloud, "cpu")
    stepped(model, 1)
    before = {k: v.detach().clone() for k, v in model.tensors.items()}
    scales_moment = adam_state(model, "scales")["exp_avg"].clone()
    reset_opacities(model, 0.01)
    opac = torch.sigmoid(model.tensors["opacities"].detach())
    expected = torch.sigmoid(before["opacities"]).clamp_max(0.01)
    torch.testing.assert_close(opac, expected)
    assert float(adam_state(model, "opacities")["exp_avg"].abs().sum()) == 0.0
    assert torch.equal(adam_state(model, "scales")["exp_avg"], scales_moment)
    assert model.tensors["opacities"].requires_grad and model.tensors["opacities"].is_leaf


# --------------------------------------------------------------------------------- the rules
def test_clone_split_and_prune_follow_the_3dgs_rules():
    # extent 10: percent_dense 0.01 -> clone up to scale 0.1
    cloud = cloud_of(5, seed=3, degree=2)
    cloud.scales[:] = np.log([[0.05] * 3, [0.3, 0.2, 0.2], [0.05] * 3, [0.05] * 3, [0.3] * 3])
    cloud.opacities[:] = np.log(np.array([0.5, 0.5, 0.5, 0.003, 0.5]) /
                                (1 - np.array([0.5, 0.5, 0.5, 0.003, 0.5])))
    model = FreeGaussians(cloud, "cpu", extent=10.0)
    stepped(model, 2)
    densifier = Densifier(DensifyConfig(), extent=10.0, seed=4)
    densifier.reset_statistics(5, torch.device("cpu"))
    # mean NDC gradients: 0 and 1 above the threshold, 2 and 3 below, 4 never seen; 3 is
    # transparent
    densifier.grad_sum += torch.tensor([0.003, 0.0009, 0.0001, 0.0001, 0.0])
    densifier.count += torch.tensor([10.0, 3.0, 2.0, 5.0, 0.0])
    before = {k: v.detach().clone() for k, v in model.tensors.items()}
    event = densifier.densify(model, step=600)
    assert (event.cloned, event.split, event.pruned, event.total) == (1, 1, 1, 6)
    t = {k: v.detach() for k, v in model.tensors.items()}
    # survivors first, in order (0, 2, 4), then the clone of 0, then 1's two children
    for name in t:
        torch.testing.assert_close(t[name][:3], before[name][[0, 2, 4]])
        torch.testing.assert_close(t[name][3], before[name][0])
        if name not in ("means", "scales"):
            torch.testing.assert_close(t[name][4:], before[name][[1, 1]])
    torch.testing.assert_close(t["scales"][4:], before["scales"][[1, 1]] - math.log(1.6))
    offsets = t["means"][4:] - before["means"][1]
    assert float(offsets.norm(dim=1).min()) > 0 and float(offsets.norm(dim=1).max()) < 3.0
    assert len(densifier.grad_sum) == 6 and float(densifier.count.sum()) == 0.0
    for name in t:
        assert adam_state(model, name)["exp_avg"].shape[0] == 6
        assert float(adam_state(model, name)["exp_avg"][3:].abs().sum()) == 0.0


def test_split_children_are_drawn_from_the_parent():
    cloud = cloud_of(1, seed=5)
    cloud.scales[:] = np.log([[0.4, 0.1, 0.02]])
    model = FreeGaussians(cloud, "cpu", extent=1.0)
    densifier = Densifier(DensifyConfig(split_into=2), extent=1.0, seed=0)
    many = {k: v.detach().repeat_interleave(4000, dim=0) for k, v in model.tensors.items()}
    model.tensors = many
    children = densifier.split_children(model, torch.ones(4000, dtype=torch.bool))
    offsets = (children["means"] - many["means"].repeat_interleave(2, dim=0)).double()
    q = torch.tensor(cloud.quats[0], dtype=torch.float64)
    from spcodec.imaging.render.projection import rotation_entries
    rot = torch.tensor([[float(e) for e in row] for row in rotation_entries(q[None])],
                       dtype=torch.float64)
    local_std = (offsets @ rot).std(dim=0)  # back in the Gaussian's frame
    np.testing.assert_allclose(local_std.numpy(), [0.4, 0.1, 0.02], rtol=0.05)


def test_oversized_gaussians_are_pruned_only_after_the_first_periodic_reset():
    cloud = cloud_of(3)
    cloud.scales[:] = np.log([[0.05] * 3, [0.5] * 3, [0.05] * 3])
    config = DensifyConfig(reset_every=300, max_screen_radius=20.0, max_world_scale=0.1)
    for step, expected in ((300, 3), (310, 1)):
        model = FreeGaussians(cloud, "cpu")
        densifier = Densifier(config, extent=2.0)
        densifier.reset_statistics(3, torch.device("cpu"))
        densifier.max_radius += torch.tensor([5.0, 5.0, 25.0])  # 1: too large in the world
        assert densifier.densify(model, step).total == expected  # 2: too large on screen


def test_statistics_are_view_space_gradients_in_ndc_of_the_drawn_gaussians():
    cloud = cloud_of(30, seed=6, degree=0)
    cloud.means[0] = [0.0, 0.0, 10.0]  # behind the camera: never drawn
    model = FreeGaussians(cloud, "cpu", extent=3.0)
    camera = Camera.look_at(np.array([0.0, 0.0, 3.0]), np.zeros(3), np.array([0.0, -1.0, 0.0]),
                            40, 24, math.radians(40))
    densifier = Densifier(DensifyConfig(), extent=3.0)
    for _ in range(2):
        result = render(model.params(), camera, RenderSettings())
        result.image.square().sum().backward()
        densifier.observe(result)
    grad = result.means2d_grad()
    ndc = (grad * torch.tensor([20.0, 12.0])).norm(dim=1)
    seen = result.visible
    assert not bool(seen[0]) and int(seen.sum()) > 20
    torch.testing.assert_close(densifier.grad_sum, 2 * torch.where(seen, ndc, 0.0))
    torch.testing.assert_close(densifier.count, 2.0 * seen)
    torch.testing.assert_close(densifier.max_radius, torch.where(seen, result.radii, 0.0))


def test_schedule_scales_with_the_run_length():
    scaled = DensifyConfig(reset_at_start=True).scaled(3000)
    assert (scaled.start, scaled.stop, scaled.every, scaled.reset_every) == (50, 1500, 10, 300)
    assert scaled.grad_threshold == 0.0002 and scaled.reset_at_start
    assert DensifyConfig().scaled(30).every == 1
    with pytest.raises(ValueError):
        DensifyConfig(every=0)


# ------------------------------------------------------------------------------- short runs
@pytest.fixture(scope="module")
def tiny_targets():
    truth = cloud_of(60, seed=7, degree=0, spread=0.6, scale=0.08, opacity=0.9)
    settings = RenderSettings(background=(1.0, 1.0, 1.0))
    return distillation_targets(truth, ring_cameras(6, size=24), settings, torch.device("cpu"))


def _fit(targets, densify: bool, steps: int = 200, every: int = 20, n0: int = 20):
    """``n0`` Gaussians trained for ``steps``, densifying every ``every`` steps (or never).

    Tiny images make every pixel a large share of the loss, so per-Gaussian gradients run ~10x
    larger than at 800x800: the threshold is raised to match, else every Gaussian splits."""
    start = cloud_of(n0, seed=8, degree=0, spread=0.4, scale=0.2, opacity=0.3)
    # positions move 20x faster than in a 30k-step run, so that a short run can place Gaussians
    rates = LearningRates(position_init=3.2e-3, position_final=3.2e-4)
    model = FreeGaussians(start, "cpu", rates, extent=targets.extent)
    config = DensifyConfig(grad_threshold=0.002, start=every, stop=steps - every, every=every,
                           reset_every=10 * steps)
    densifier = Densifier(config, targets.extent, seed=1)
    loop = FitLoop(model, targets, RenderSettings(background=targets.background), steps,
                   seed=2, after_step=(lambda s, r: densifier.after_step(model, s, r))
                   if densify else None)
    before = loop.mean_psnr()
    loop.run()
    return len(model), before, loop.mean_psnr(), densifier


def test_a_short_densifying_run_grows_and_fits_better_than_without(tiny_targets):
    count, before, after, densifier = _fit(tiny_targets, densify=True)
    plain_count, _, plain, _ = _fit(tiny_targets, densify=False)
    assert plain_count == 20 and count > 100, count
    assert any(e.cloned for e in densifier.events) and any(e.split for e in densifier.events)
    assert after > plain + 2.0 and plain > before, (before, after, plain)


def _load_bench():
    return load_bench_script("train_vanilla")


@pytest.mark.filterwarnings("ignore::spcodec.imaging.evaluate.DatasetMismatchWarning")
def test_train_vanilla_writes_a_model_and_its_record(tmp_path):
    truth = cloud_of(120, seed=9, degree=1, spread=1.0, scale=0.15, opacity=0.9)
    cams = ring_cameras(10)
    write_transforms_dataset(tmp_path / "data", truth, cams[:8], cams[8:])
    out = tmp_path / "model.ply"
    # the schedule scaled to 90 steps: densify at every step from 3 to 44, reset opacities every
    # 9 (black background: none at the start); a threshold for tiny images (see _fit)
    doc = _load_bench().main([str(tmp_path / "data"), "-o", str(out), "--downscale", "1",
                              "--iterations", "90", "--init-points", "300", "--sh-degree", "1",
                              "--grad-threshold", "0.005", "--quiet"])
    model = spcodec.read_ply(out)
    assert len(model) == doc["gaussians"] != 300 and model.sh_degree == 1
    assert json.loads(out.with_suffix(".json").read_text()) == doc
    assert doc["resolution"] == [32, 32] and doc["test"]["views"] == 2
    assert doc["sh_every"] == 3 and doc["config"]["densify"]["every"] == 1
    assert doc["opacity_resets"] == [9, 18, 27, 36] and "--iterations 90" in doc["command"]
    assert [e["step"] for e in doc["densification"]] == list(range(3, 45))
    again = evaluate_against_dataset(model, tmp_path / "data", EvalConfig(device="cpu"))
    assert doc["test"]["psnr"] == pytest.approx(again.psnr, abs=1e-3)
