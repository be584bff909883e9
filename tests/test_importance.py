"""Blend weights (imaging/importance.py) against a brute-force per-pixel accumulation."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from spcodec.imaging.importance import blend_weights
from spcodec.imaging.render import RenderSettings, render
from spcodec.imaging.render.projection import project

from test_render import axis_camera, make_params, random_scene

pytestmark = pytest.mark.usefixtures("single_torch_thread")


def brute_force_weights(params, cam, cfg: RenderSettings) -> np.ndarray:
    """Sum of T * alpha per Gaussian, one Gaussian at a time over every pixel (the blend rules of
    ``test_render.reference_render``, bookkeeping the weights instead of the colour)."""
    proj = project(params, cam, cfg)
    mean = proj.means2d.detach().numpy()
    conic = proj.conics.detach().numpy()
    opac = proj.opacities.detach().numpy()
    cols, rows = np.meshgrid(np.arange(cam.width) + 0.5, np.arange(cam.height) + 0.5)
    trans = np.ones(cols.shape)
    done = np.zeros(cols.shape, bool)
    out = np.zeros(len(params))
    for k in np.argsort(proj.depths.numpy(), kind="stable"):
        dx, dy = cols - mean[k, 0], rows - mean[k, 1]
        q = conic[k, 0] * dx * dx + 2 * conic[k, 1] * dx * dy + conic[k, 2] * dy * dy
        alpha = np.minimum(cfg.max_alpha, opac[k] * np.exp(-0.5 * q))
        used = (alpha >= 1 / 255) & ~done
        test_t = trans * (1 - alpha)
        stop = used & (test_t < 1e-4)
        done |= stop
        add = used & ~stop
        out[int(proj.ids[k])] += float((trans[add] * alpha[add]).sum())
        trans = np.where(add, test_t, trans)
    return out


@pytest.mark.parametrize("seed", [0, 1])
def test_weights_match_brute_force_and_sum_to_the_alpha_map(seed: int) -> None:
    params = random_scene(60, degree=1, seed=seed, opacity_range=(0.3, 0.99))
    cam = axis_camera(40, 32, focal=30.0)
    cfg = RenderSettings()
    got = blend_weights(params, [cam], cfg)
    want = brute_force_weights(params, cam, cfg)
    np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-9)
    alpha = render(params, cam, cfg).alpha.sum().item()
    assert got.sum() == pytest.approx(alpha, rel=1e-6)
    assert (want > 0).sum() > 10  # the scene is not trivially empty


def test_occluded_and_unseen_gaussians_score_less_or_nothing() -> None:
    # the same Gaussian twice on the optical axis, the rear one hidden behind the front one, and
    # a third one behind the camera
    params = make_params([[0, 0, 2.0], [0, 0, 3.0], [0, 0, -1.0]], [0.3, 0.3, 0.3],
                         [0.95, 0.95, 0.95], colors=[[1, 0, 0]] * 3)
    weights = blend_weights(params, [axis_camera()])
    assert weights[0] > 4 * weights[1] > 0
    assert weights[2] == 0


def test_weights_add_over_views_and_follow_the_cloud() -> None:
    params = random_scene(30, degree=0, seed=3, dtype=torch.float32)
    cams = [axis_camera(32, 24), axis_camera(32, 24, cx=10.0)]
    both = blend_weights(params, cams)
    parts = blend_weights(params, cams[:1]) + blend_weights(params, cams[1:])
    np.testing.assert_allclose(both, parts, rtol=1e-6)
    np.testing.assert_allclose(blend_weights(params.to_cloud(), cams), both, rtol=1e-6)


def test_training_view_weights_use_training_views_on_any_number_of_threads() -> None:
    from spcodec.imaging.importance import training_view_weights
    from spcodec.imaging.views import sample_views

    cloud = random_scene(200, degree=2, seed=5, dtype=torch.float32).to_cloud()
    one = training_view_weights(cloud, 3, (48, 36), seed=2)
    cams = sample_views(cloud, 3, (48, 36), split="train", seed=2)
    np.testing.assert_allclose(one, blend_weights(cloud, cams), rtol=1e-5, atol=1e-9)
    np.testing.assert_array_equal(training_view_weights(cloud, 3, (48, 36), seed=2, jobs=2), one)
    eval_cams = sample_views(cloud, 3, (48, 36), split="eval", seed=2)
    assert not np.allclose(blend_weights(cloud, eval_cams), one)
    assert (one > 0).sum() > 50
