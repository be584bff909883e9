"""Tests of the differentiable 3DGS renderer (imaging/render): closed forms, gradients, blending
rules, tiling invariance, SH, the public API and (when CUDA + gsplat exist) agreement with gsplat.
"""

from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest
import torch
from hypothesis import given
from hypothesis import strategies as st

from spcodec import read_ply
from spcodec.cloud import GaussianCloud
from spcodec.imaging.cameras import Camera
from spcodec.imaging.render import (
    GaussianParams,
    RenderSettings,
    render,
    render_image,
    resolve_backend,
    resolve_device,
)
from spcodec.imaging.render.binning import (
    DRAWING_TILES,
    PAIR_RATIO,
    TRAINING_TILE,
    choose_tile,
    tile_pairs,
)
from spcodec.imaging.render.gsplat_backend import GSPLAT_MAX_ALPHA, gsplat_problem
from spcodec.imaging.render.projection import project
from spcodec.imaging.render.sh import SH_C0, sh_basis
from spcodec.imaging.render.torch_backend import render_torch

from conftest import real_file


@pytest.fixture(autouse=True, scope="module")
def _single_thread():
    """These renders are tiny; on a shared machine extra OpenMP threads only add barrier stalls
    (seen: 10x slower runs). Restored afterwards so other test modules keep their setting."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


# ----------------------------------------------------------------------------------- helpers
def axis_camera(width: int = 64, height: int = 48, focal: float = 50.0, cx: float | None = None,
                cy: float | None = None) -> Camera:
    """Camera at the origin looking down +z (world = camera coordinates)."""
    return Camera(width, height, focal, focal, width / 2 if cx is None else cx,
                  height / 2 if cy is None else cy, np.eye(4))


def make_params(means, scales, opacities, colors=None, quats=None, sh=None,
                dtype=torch.float64, requires_grad=False) -> GaussianParams:
    """Params from plain values: scales are *linear* std devs, opacities linear, colours rgb."""
    means = torch.as_tensor(np.asarray(means, float), dtype=dtype)
    n = len(means)
    scales = torch.log(torch.as_tensor(np.asarray(scales, float), dtype=dtype).expand(n, 3))
    quats = (torch.tensor([[1.0, 0, 0, 0]], dtype=dtype).expand(n, 4) if quats is None
             else torch.as_tensor(np.asarray(quats, float), dtype=dtype))
    opac = torch.as_tensor(np.asarray(opacities, float), dtype=dtype)
    logits = torch.log(opac / (1 - opac))
    if sh is None:
        rgb = torch.as_tensor(np.asarray(colors, float), dtype=dtype).reshape(n, 3)
        sh = ((rgb - 0.5) / SH_C0)[:, None, :]
    else:
        sh = torch.as_tensor(np.asarray(sh, float), dtype=dtype)
    tensors = [t.clone().contiguous().requires_grad_(requires_grad)
               for t in (means, scales, quats, logits, sh)]
    return GaussianParams(*tensors)


def random_scene(n: int, degree: int, seed: int, dtype=torch.float64, spread: float = 0.6,
                 opacity_range=(0.05, 0.8), scale_range=(0.02, 0.12)) -> GaussianParams:
    """Random Gaussians in front of ``axis_camera`` (z around 3), anisotropic and rotated."""
    g = np.random.default_rng(seed)
    means = np.c_[g.uniform(-spread, spread, (n, 2)), g.uniform(2.5, 3.5, n)]
    scales = np.log(g.uniform(*scale_range, (n, 3)))
    quats = g.normal(size=(n, 4))
    opac = g.uniform(*opacity_range, n)
    sh = g.normal(scale=0.3, size=(n, (degree + 1) ** 2, 3))
    sh[:, 0] = g.uniform(-0.5, 1.2, (n, 3))
    arrays = (means, scales, quats, np.log(opac / (1 - opac)), sh)
    return GaussianParams(*(torch.tensor(a, dtype=dtype) for a in arrays))


def settings(**kw) -> RenderSettings:
    return RenderSettings(**kw)


def reference_render(params: GaussianParams, cam: Camera, cfg: RenderSettings):
    """Brute-force blend of the spec, one Gaussian at a time over every pixel (no tiles, no
    footprint boxes). Returns image, alpha and the mask of pixels that terminated early."""
    proj = project(params, cam, cfg)
    mean = proj.means2d.detach().numpy()
    conic = proj.conics.detach().numpy()
    opac = proj.opacities.detach().numpy()
    rgb = proj.colors.detach().numpy()
    cols, rows = np.meshgrid(np.arange(cam.width) + 0.5, np.arange(cam.height) + 0.5)
    trans = np.ones(cols.shape)
    done = np.zeros(cols.shape, bool)
    image = np.zeros(cols.shape + (3,))
    for i in np.argsort(proj.depths.numpy(), kind="stable"):
        dx, dy = cols - mean[i, 0], rows - mean[i, 1]
        q = conic[i, 0] * dx * dx + 2 * conic[i, 1] * dx * dy + conic[i, 2] * dy * dy
        alpha = np.minimum(cfg.max_alpha, opac[i] * np.exp(-0.5 * q))
        used = (alpha >= 1 / 255) & ~done
        test_t = trans * (1 - alpha)
        stop = used & (test_t < 1e-4)
        done |= stop
        add = used & ~stop
        image[add] += (trans[add] * alpha[add])[:, None] * rgb[i]
        trans = np.where(add, test_t, trans)
    image += trans[..., None] * np.asarray(cfg.background)
    return image, 1 - trans, done


# --------------------------------------------------------------------------- closed forms
@pytest.mark.parametrize("antialiased", [False, True])
def test_single_isotropic_gaussian_matches_closed_form(antialiased: bool) -> None:
    # mean on the optical axis, principal point on a pixel centre: the 2D covariance is
    # (f s / z)^2 I + 0.3 I exactly, and the peak lands on pixel (24, 32)
    focal, z, s, opacity = 50.0, 2.0, 0.04, 0.7
    cam = axis_camera(64, 48, focal, cx=32.5, cy=24.5)
    rgb = np.array([0.9, 0.4, 0.2])
    params = make_params([[0.0, 0.0, z]], [s], [opacity], rgb)
    out = render(params, cam, settings(antialiased=antialiased), backend="torch")

    var_raw = (focal * s / z) ** 2  # 1 px^2: the 0.3 low-pass is a large effect here
    var = var_raw + 0.3
    peak_opacity = opacity * (var_raw / var if antialiased else 1.0)  # sqrt(det ratio) in 2D
    cols, rows = np.meshgrid(np.arange(64) + 0.5, np.arange(48) + 0.5)
    d2 = (cols - 32.5) ** 2 + (rows - 24.5) ** 2
    alpha = np.minimum(0.99, peak_opacity * np.exp(-0.5 * d2 / var))
    alpha[alpha < 1 / 255] = 0.0
    expected = alpha[..., None] * rgb

    image = out.image.numpy()
    np.testing.assert_allclose(image, expected, atol=1e-10)
    np.testing.assert_allclose(out.alpha.numpy(), alpha, atol=1e-10)
    np.testing.assert_allclose(image[24, 32], peak_opacity * rgb, rtol=1e-12)
    # the width is that of variance var (not var_raw): one pixel off the peak
    assert image[24, 33, 0] / image[24, 32, 0] == pytest.approx(math.exp(-0.5 / var), rel=1e-12)
    assert image[24, 33, 0] / image[24, 32, 0] != pytest.approx(math.exp(-0.5 / var_raw),
                                                                rel=1e-3)


def test_background_shows_through_by_transmittance() -> None:
    cam = axis_camera(32, 32, 40.0, cx=16.5, cy=16.5)
    bg = (0.2, 0.5, 0.9)
    rgb = np.array([1.0, 0.0, 0.3])
    params = make_params([[0.0, 0.0, 2.0]], [0.05], [0.6], rgb)
    with_bg = render(params, cam, settings(background=bg), backend="torch")
    without = render(params, cam, settings(), backend="torch")
    alpha = without.alpha[..., None]
    expected = without.image + (1 - alpha) * torch.tensor(bg, dtype=torch.float64)
    torch.testing.assert_close(with_bg.image, expected, atol=1e-12, rtol=0)
    assert float(alpha.max()) == pytest.approx(0.6, rel=1e-12)
    torch.testing.assert_close(with_bg.image[0, 0], torch.tensor(bg, dtype=torch.float64))
    assert float(with_bg.alpha[0, 0]) == 0.0


# ----------------------------------------------------------------------- blending rules
def test_nearer_gaussian_wins_regardless_of_input_order() -> None:
    cam = axis_camera(32, 32, 40.0, cx=16.5, cy=16.5)
    red, blue = [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]
    near, far = [0.0, 0.0, 2.0], [0.0, 0.0, 3.0]
    # same screen footprint: the far one is 1.5x larger in the world
    a = make_params([near, far], [[0.1], [0.15]], [0.95, 0.9], [red, blue])
    b = make_params([far, near], [[0.15], [0.1]], [0.9, 0.95], [blue, red])
    img_a = render(a, cam, settings(), backend="torch").image
    img_b = render(b, cam, settings(), backend="torch").image
    torch.testing.assert_close(img_a, img_b, atol=1e-12, rtol=0)
    centre = img_a[16, 16].numpy()
    np.testing.assert_allclose(centre, [0.95, 0.0, 0.05 * 0.9], atol=1e-12)


def _stack(opacities, colors, dtype=torch.float64) -> GaussianParams:
    """Large Gaussians on the optical axis at increasing depth, same footprint on screen."""
    depths = 2.0 + np.arange(len(opacities))
    means = np.c_[np.zeros((len(depths), 2)), depths]
    scales = 0.2 * depths[:, None] / 2.0
    return make_params(means, scales, opacities, colors, dtype=dtype)


@pytest.mark.parametrize("chunk", [1, 2, 3, 32])
def test_early_termination_stops_before_the_fragment_that_crosses(chunk: int) -> None:
    # alpha 0.8 each at the centre pixel: T = 0.2^k; the 6th would give 6.4e-5 < 1e-4 so it and
    # everything after stay out; the 8th (alpha 0.01) would fit under T but the pixel stopped
    colors = np.eye(8, 3, k=0)[[0, 1, 2, 0, 1, 2, 0, 1]] * np.arange(1, 9)[:, None] / 8
    opac = [0.8] * 7 + [0.01]
    params = _stack(opac, colors)
    cam = axis_camera(16, 16, 40.0, cx=8.5, cy=8.5)
    bg = (0.3, 0.3, 0.3)
    out = render(params, cam, settings(background=bg, chunk_size=chunk, tile_size=8),
                 backend="torch")
    t = 1.0
    expected = np.zeros(3)
    for k in range(5):
        expected += t * 0.8 * colors[k]
        t *= 0.2
    expected += t * np.array(bg)
    np.testing.assert_allclose(out.image[8, 8].numpy(), expected, atol=1e-12)
    assert float(out.alpha[8, 8]) == pytest.approx(1 - 0.2 ** 5, abs=1e-12)


def test_skipped_fragments_and_alpha_clamp() -> None:
    # opacity 0.999 clamps to 0.99 at the peak; a near Gaussian below 1/255 is skipped entirely
    cam = axis_camera(16, 16, 40.0, cx=8.5, cy=8.5)
    params = make_params([[0, 0, 1.5], [0, 0, 3.0]], [[0.2], [0.2]], [0.003, 0.999],
                         [[0, 1, 0], [1, 1, 1]])
    out = render(params, cam, settings(), backend="torch")
    np.testing.assert_allclose(out.image[8, 8].numpy(), [0.99, 0.99, 0.99], atol=1e-12)
    out = render(params, cam, settings(max_alpha=0.999), backend="torch")
    np.testing.assert_allclose(out.image[8, 8].numpy(), [0.999] * 3, atol=1e-9)


@pytest.mark.parametrize("antialiased", [False, True])
def test_dense_scene_matches_brute_force_reference(antialiased: bool) -> None:
    params = random_scene(300, 1, seed=6, opacity_range=(0.02, 0.9999), scale_range=(0.01, 0.25))
    cam = axis_camera(48, 36, 35.0)
    cfg = settings(background=(0.7, 0.2, 0.4), antialiased=antialiased)
    image, alpha, done = reference_render(params, cam, cfg)
    assert done.mean() > 0.05 and (alpha < 0.5).mean() > 0.05  # terminated and open pixels
    out = render(params, cam, cfg, backend="torch")
    np.testing.assert_allclose(out.image.numpy(), image, atol=1e-10)
    np.testing.assert_allclose(out.alpha.numpy(), alpha, atol=1e-10)


@pytest.mark.slow
def test_real_scene_matches_brute_force_reference() -> None:
    # 45k trained Gaussians (tiny, clamped, overlapping) through the whole pipeline in float64
    cloud = read_ply(real_file("v3dg_donut_mipsplatting/fused.ply"))
    params = GaussianParams.from_cloud(cloud, dtype=torch.float64)
    lo, hi = np.percentile(cloud.means, [1, 99], axis=0)
    centre, radius = (lo + hi) / 2, np.linalg.norm(hi - lo) / 2
    eye = centre + np.array([0.4, -0.8, 0.6]) / np.linalg.norm([0.4, -0.8, 0.6]) * 2.2 * radius
    cam = Camera.look_at(eye, centre, np.array([0.0, 0.0, 1.0]), 48, 40, math.radians(50))
    cfg = settings(background=(1.0, 1.0, 1.0))
    image, alpha, done = reference_render(params, cam, cfg)
    assert (alpha > 0.9).mean() > 0.2 and done.any()
    out = render(params, cam, cfg, backend="torch")
    np.testing.assert_allclose(out.image.numpy(), image, atol=1e-9)
    np.testing.assert_allclose(out.alpha.numpy(), alpha, atol=1e-9)


# ------------------------------------------------------------------------------- tiling
def test_tile_chunk_and_batch_sizes_do_not_change_the_image() -> None:
    params = random_scene(300, 1, seed=3, dtype=torch.float32, opacity_range=(0.2, 0.99))
    cam = axis_camera(70, 45, 45.0)
    base = render(params, cam, settings(background=(0.1, 0.2, 0.3)), backend="torch")
    assert float(base.alpha.min()) < 0.5 < float(base.alpha.max())
    for tile, chunk, batch in [(4, 1, 1 << 22), (8, 7, 1 << 22), (13, 256, 1 << 22),
                               (16, 5, 3000), (64, 64, 1 << 22)]:
        other = render(params, cam, settings(background=(0.1, 0.2, 0.3), tile_size=tile,
                                             chunk_size=chunk, batch_elements=batch),
                       backend="torch")
        # float32 rounding of the exponent, expanded about each tile's centre, grows with the
        # tile's side (1e-5 holds to 64; the image is in [0, 1])
        torch.testing.assert_close(other.image, base.image, atol=1e-5, rtol=0)
        torch.testing.assert_close(other.alpha, base.alpha, atol=1e-5, rtol=0)


@pytest.mark.parametrize("tile", [None, 2, 4, 8, 16])
def test_a_pass_that_only_draws_draws_what_a_pass_with_gradients_draws(tile) -> None:
    # without gradients the exponents come from a quadratic about each tile's centre, with
    # them from each pixel's offset to the mean; and the tile side differs (None: 8 and 4)
    params = random_scene(300, 1, seed=8, dtype=torch.float32, opacity_range=(0.0, 0.99),
                          scale_range=(0.01, 0.3))
    cam = axis_camera(70, 45, 45.0)
    cfg = settings(background=(0.2, 0.1, 0.3), tile_size=tile)
    with torch.no_grad():
        drawn = render(params, cam, cfg, backend="torch")
    leaves = GaussianParams(*(t.clone().requires_grad_(True) for t in params.tensors()))
    trained = render(leaves, cam, cfg, backend="torch")
    assert float(drawn.alpha.min()) < 0.5 < float(drawn.alpha.max())
    torch.testing.assert_close(drawn.image, trained.image.detach(), atol=1e-5, rtol=0)
    torch.testing.assert_close(drawn.alpha, trained.alpha.detach(), atol=1e-5, rtol=0)


@given(st.lists(st.tuples(st.integers(0, 300), st.integers(0, 60), st.integers(0, 300),
                          st.integers(0, 60)), max_size=40))
def test_tile_pairs_count_the_tiles_each_box_meets(boxes) -> None:
    rows = torch.tensor([(c, c + w, r, r + h) for c, w, r, h in boxes],
                        dtype=torch.int32).reshape(-1, 4)
    for tile in (1, 4, 8):
        met = sum(len({(x // tile, y // tile) for x in range(c, c + w + 1)
                       for y in range(r, r + h + 1)}) for c, w, r, h in boxes)
        assert tile_pairs(rows, tile) == met


def test_a_drawing_pass_takes_large_tiles_for_large_footprints_only() -> None:
    small, large = DRAWING_TILES
    dots = torch.tensor([[8 * k, 8 * k + 1, 0, 1] for k in range(50)])  # 2 px: 1 tile each
    wide = torch.tensor([[0, 255, 0, 255]] * 50)  # 256 px: 4x the small tiles of the large
    assert tile_pairs(wide, small) > PAIR_RATIO * tile_pairs(wide, large)
    assert choose_tile(dots, gradients=False) == small
    assert choose_tile(wide, gradients=False) == large
    assert choose_tile(wide, gradients=True) == TRAINING_TILE
    assert choose_tile(wide[:0], gradients=False) == TRAINING_TILE


# ------------------------------------------------------------------------------ gradients
def _loss_fn(params_template: GaussianParams, cam: Camera, cfg: RenderSettings, backward: str,
             seed: int):
    g = torch.Generator().manual_seed(seed)
    w_img = torch.rand(cam.height, cam.width, 3, generator=g, dtype=torch.float64) - 0.3
    w_alpha = torch.rand(cam.height, cam.width, generator=g, dtype=torch.float64) - 0.5

    def loss(means, scales, quats, opacities, sh):
        out = render_torch(GaussianParams(means, scales, quats, opacities, sh), cam, cfg,
                           backward=backward)
        return (out.image * w_img).sum() + (out.alpha * w_alpha).sum()

    return loss


@pytest.mark.parametrize("degree,antialiased,backward", [
    (1, False, "replay"), (3, True, "replay"), (2, False, "autograd")])
def test_gradcheck_all_parameters(degree: int, antialiased: bool, backward: str) -> None:
    # few, moderately opaque Gaussians: no alpha clamp, T stays far above 1e-4, and the
    # 1/255 contour crosses no pixel centre within finite-difference reach
    params = random_scene(4, degree, seed=10 + degree, spread=0.25, opacity_range=(0.3, 0.75),
                          scale_range=(0.05, 0.15))
    cam = axis_camera(14, 11, 12.0)
    cfg = settings(background=(0.3, 0.6, 0.1), antialiased=antialiased, tile_size=4,
                   chunk_size=2)
    loss = _loss_fn(params, cam, cfg, backward, seed=degree)
    inputs = tuple(t.clone().requires_grad_(True) for t in params.tensors())
    assert torch.autograd.gradcheck(loss, inputs, eps=1e-6, atol=1e-6, rtol=1e-4)


def test_replay_backward_equals_autograd_with_clamp_and_termination() -> None:
    # dense opaque scene: many pixels terminate and many fragments clamp at max_alpha
    params = random_scene(120, 2, seed=5, opacity_range=(0.5, 0.9999), scale_range=(0.05, 0.2))
    cam = axis_camera(40, 30, 30.0)
    cfg = settings(background=(0.5, 0.5, 0.5), tile_size=8, chunk_size=6)
    grads = {}
    for backward in ("replay", "autograd"):
        inputs = [t.clone().requires_grad_(True) for t in params.tensors()]
        loss = _loss_fn(params, cam, cfg, backward, seed=1)(*inputs)
        grads[backward] = torch.autograd.grad(loss, inputs)
    assert reference_render(params, cam, cfg)[2].mean() > 0.03  # termination did happen
    for a, b in zip(grads["replay"], grads["autograd"]):
        torch.testing.assert_close(a, b, atol=1e-9, rtol=1e-7)


# ------------------------------------------------- screen positions (adaptive density control)
def _with_culled(params: GaussianParams) -> GaussianParams:
    """``params`` plus one Gaussian behind the camera and one far off screen, placed first and
    in the middle so the scatter to one row per Gaussian is exercised."""
    extra = make_params([[0, 0, -2.0], [50.0, 0, 3.0]], [[0.05]] * 2, [0.5] * 2,
                        sh=np.zeros((2, params.sh.shape[1], 3)))
    parts = [torch.cat([e[:1], p[:60], e[1:], p[60:]]) for e, p in
             zip(extra.tensors(), params.tensors())]
    return GaussianParams(*parts)


def test_means2d_gradient_equals_autograd_through_the_blend() -> None:
    from spcodec.imaging.render.binning import bin_gaussians
    from spcodec.imaging.render.composite import BlendConfig, blend_autograd

    params = _with_culled(random_scene(120, 1, seed=21, opacity_range=(0.2, 0.95)))
    cam = axis_camera(40, 30, 30.0)
    cfg = settings(background=(0.5, 0.2, 0.9), tile_size=8, chunk_size=6)
    w = torch.rand(cam.height, cam.width, 3, generator=torch.Generator().manual_seed(3),
                   dtype=torch.float64)
    leaves = GaussianParams(*(t.clone().requires_grad_(True) for t in params.tensors()))
    out = render(leaves, cam, cfg, backend="torch")
    (out.image * w).sum().backward()
    ours = out.means2d_grad()

    # oracle: the same blend with the screen positions as a leaf, differentiated by autograd
    proj = project(params, cam, cfg)
    leaf = proj.means2d.detach().clone().requires_grad_(True)
    bins = bin_gaussians(proj.pixel_boxes, proj.depths, leaf.detach(), proj.conics,
                         proj.extents, cam.width, cam.height, cfg.tile_size)
    image, _ = blend_autograd(leaf, proj.conics, proj.opacities, proj.colors,
                              torch.tensor(cfg.background, dtype=torch.float64), bins,
                              BlendConfig(cfg.max_alpha, cfg.chunk_size, cfg.batch_elements),
                              cam.width, cam.height)
    (image * w).sum().backward()
    assert ours.shape == (len(params), 2)
    torch.testing.assert_close(ours[proj.ids], leaf.grad, atol=1e-10, rtol=1e-8)
    culled = torch.ones(len(params), dtype=torch.bool)
    culled[proj.ids] = False
    assert out.visible.tolist() == (~culled).tolist() and int(culled.sum()) == 2
    assert float(ours[culled].abs().max()) == 0.0 and float(ours.abs().max()) > 0.0
    torch.testing.assert_close(out.means2d.detach()[proj.ids], proj.means2d)


def test_means2d_gradients_sum_to_the_principal_point_derivative() -> None:
    # moving the principal point by d moves every screen position by d along that axis and
    # changes nothing else (no Gaussian near the frustum clamp), so the loss's derivative w.r.t.
    # cx / cy is the sum of the per-Gaussian gradients: an oracle outside the renderer's code
    params = random_scene(40, 0, seed=4, spread=0.3, opacity_range=(0.3, 0.8))
    w = torch.rand(30, 40, 3, generator=torch.Generator().manual_seed(1), dtype=torch.float64)

    def loss(cx: float, cy: float, grad: bool = False):
        p = GaussianParams(*(t.clone().requires_grad_(grad) for t in params.tensors()))
        out = render(p, axis_camera(40, 30, 30.0, cx=cx, cy=cy), settings(), backend="torch")
        value = (out.image * w).sum()
        if grad:
            value.backward()
            return out.means2d_grad()
        return float(value)

    grads = loss(20.0, 15.0, grad=True)
    h = 1e-5
    d_cx = (loss(20.0 + h, 15.0) - loss(20.0 - h, 15.0)) / (2 * h)
    d_cy = (loss(20.0, 15.0 + h) - loss(20.0, 15.0 - h)) / (2 * h)
    assert float(grads[:, 0].sum()) == pytest.approx(d_cx, rel=1e-5)
    assert float(grads[:, 1].sum()) == pytest.approx(d_cy, rel=1e-5)


def test_radii_are_the_footprint_half_size_and_zero_when_culled() -> None:
    # isotropic Gaussians on the optical axis: screen std sqrt((f s / z)^2 + blur), 1/255
    # contour at k = sqrt(2 ln(255 o)) standard deviations
    cam = axis_camera(32, 32, 40.0)
    params = make_params([[0, 0, 2.0], [0, 0, 3.0], [0, 0, -2.0]], [[0.05], [0.02], [0.05]],
                         [0.5, 0.9, 0.5], [[1, 1, 1]] * 3)
    out = render(params, cam, settings(), backend="torch")
    for i, (s, o, z) in enumerate([(0.05, 0.5, 2.0), (0.02, 0.9, 3.0)]):
        sigma = math.sqrt((40.0 * s / z) ** 2 + 0.3)
        assert float(out.radii[i]) == pytest.approx(math.sqrt(2 * math.log(255 * o)) * sigma)
    assert float(out.radii[2]) == 0.0 and out.means2d_grad() is None


# ------------------------------------------------------------------------------- colour
def _real_sh_scipy(degree: int, dirs: np.ndarray) -> np.ndarray:
    """3DGS basis from scipy's complex SH: textbook real SH times (-1)^m, index l*l + l + m."""
    from scipy.special import sph_harm_y

    theta = np.arccos(np.clip(dirs[:, 2], -1, 1))  # polar angle from +z
    phi = np.arctan2(dirs[:, 1], dirs[:, 0])
    out = np.zeros((len(dirs), (degree + 1) ** 2))
    for l_ in range(degree + 1):
        for m in range(-l_, l_ + 1):
            y = sph_harm_y(l_, abs(m), theta, phi)  # includes the Condon-Shortley phase
            if m < 0:
                real = math.sqrt(2) * (-1) ** m * y.imag
            elif m == 0:
                real = y.real
            else:
                real = math.sqrt(2) * (-1) ** m * y.real
            out[:, l_ * l_ + l_ + m] = (-1) ** m * real
    return out


def test_sh_basis_matches_scipy_spherical_harmonics() -> None:
    dirs = np.random.default_rng(0).normal(size=(200, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    ours = sh_basis(torch.tensor(dirs), 3).numpy()
    np.testing.assert_allclose(ours, _real_sh_scipy(3, dirs), atol=1e-12)


def test_rendered_colour_uses_sh_at_the_view_direction() -> None:
    # one big Gaussian seen from an oblique camera: its centre pixel shows
    # clamp(SH(dir) + 0.5, 0) * alpha for dir = normalize(mean - camera centre)
    g = np.random.default_rng(7)
    sh = g.normal(scale=0.4, size=(1, 16, 3))
    sh[0, 0] = [0.6, 0.1, -0.3]
    mean = np.array([[0.2, -0.1, 0.4]])
    eye = np.array([1.5, 2.0, -3.0])
    cam = Camera.look_at(eye, mean[0], np.array([0.0, -1.0, 0.0]), 33, 33, math.radians(40))
    params = make_params(mean, [0.3], [0.5], sh=sh)
    out = render(params, cam, settings(), backend="torch")
    uv, _ = cam.project(mean)
    col, row = (np.floor(uv[0])).astype(int)
    d = mean[0] - eye
    d /= np.linalg.norm(d)
    basis = _real_sh_scipy(3, d[None])[0]
    rgb = np.maximum(basis @ sh[0] + 0.5, 0.0)
    # alpha at that pixel, from the projected conic (the pixel centre is off the mean)
    proj = project(params, cam, settings())
    a, b, c = proj.conics[0].tolist()
    dx, dy = col + 0.5 - uv[0, 0], row + 0.5 - uv[0, 1]
    alpha = 0.5 * math.exp(-0.5 * (a * dx * dx + 2 * b * dx * dy + c * dy * dy))
    np.testing.assert_allclose(out.image[row, col].numpy(), alpha * rgb, atol=1e-10)


# --------------------------------------------------------------------------- projection
def _numpy_ewa(params: GaussianParams, cam: Camera) -> tuple[np.ndarray, np.ndarray]:
    """Independent float64 EWA: means2d and blurred 2D covariances via explicit 3x3 matrices."""
    p = {k: t.detach().numpy().astype(float) for k, t in zip(
        ("means", "scales", "quats", "opacities", "sh"), params.tensors())}
    w, t = cam.rotation, cam.translation
    out_mean, out_cov = [], []
    for mean, scale, q in zip(p["means"], p["scales"], p["quats"]):
        qw, qx, qy, qz = q / np.linalg.norm(q)
        rot = np.array([
            [1 - 2 * (qy ** 2 + qz ** 2), 2 * (qx * qy - qw * qz), 2 * (qx * qz + qw * qy)],
            [2 * (qx * qy + qw * qz), 1 - 2 * (qx ** 2 + qz ** 2), 2 * (qy * qz - qw * qx)],
            [2 * (qx * qz - qw * qy), 2 * (qy * qz + qw * qx), 1 - 2 * (qx ** 2 + qy ** 2)]])
        cov3 = rot @ np.diag(np.exp(2 * scale)) @ rot.T
        x, y, z = w @ mean + t
        lim_x = 1.3 * cam.width / (2 * cam.fx)  # centred principal point: INRIA's 1.3 tan
        lim_y = 1.3 * cam.height / (2 * cam.fy)
        tx, ty = np.clip(x / z, -lim_x, lim_x) * z, np.clip(y / z, -lim_y, lim_y) * z
        jac = np.array([[cam.fx / z, 0, -cam.fx * tx / z ** 2],
                        [0, cam.fy / z, -cam.fy * ty / z ** 2]])
        out_cov.append(jac @ w @ cov3 @ w.T @ jac.T + 0.3 * np.eye(2))
        out_mean.append([cam.fx * x / z + cam.cx, cam.fy * y / z + cam.cy])
    return np.array(out_mean), np.array(out_cov)


def test_projection_matches_explicit_ewa() -> None:
    params = random_scene(50, 0, seed=2, spread=1.8)  # some beyond the 1.3 tan clamp
    cam = Camera.look_at(np.array([0.3, -0.2, -0.5]), np.array([0.0, 0.1, 3.0]),
                         np.array([0.0, -1.0, 0.0]), 64, 48, math.radians(55))
    proj = project(params, cam, settings())
    means2d, cov = _numpy_ewa(params, cam)
    ids = proj.ids.numpy()
    assert 10 < len(ids) < 50  # some culled off-screen, most kept
    np.testing.assert_allclose(proj.means2d.numpy(), means2d[ids], rtol=1e-10, atol=1e-9)
    conic = np.linalg.inv(cov[ids])
    np.testing.assert_allclose(proj.conics.numpy(), np.c_[conic[:, 0, 0], conic[:, 0, 1],
                                                          conic[:, 1, 1]], rtol=1e-9, atol=1e-12)


def test_culling_near_plane_and_off_screen() -> None:
    cam = axis_camera(32, 32, 40.0)
    params = make_params([[0, 0, 2.0], [0, 0, 0.005], [0, 0, -2.0], [5.0, 0, 2.0]],
                         [[0.05]] * 4, [0.5] * 4, [[1, 1, 1]] * 4)
    out = render(params, cam, settings(), backend="torch")
    assert out.visible.tolist() == [True, False, False, False]
    only_first = render(make_params([[0, 0, 2.0]], [0.05], [0.5], [[1, 1, 1]]), cam,
                        settings(), backend="torch")
    torch.testing.assert_close(out.image, only_first.image)
    near = render(params, cam, settings(near_plane=0.001), backend="torch")
    assert near.visible.tolist()[:2] == [True, True]


def test_empty_and_fully_culled_scenes_render_the_background() -> None:
    cam = axis_camera(20, 12, 20.0)
    bg = (0.25, 0.5, 0.75)
    empty = GaussianParams.from_cloud(GaussianCloud.zeros(0, 1), dtype=torch.float64)
    behind = make_params([[0, 0, -1.0], [0.1, 0, -2.0]], [[0.1]] * 2, [0.9] * 2, [[1, 0, 0]] * 2,
                         requires_grad=True)
    for params in (empty, behind):
        out = render(params, cam, settings(background=bg), backend="torch")
        torch.testing.assert_close(out.image, torch.tensor(bg, dtype=torch.float64).expand(
            12, 20, 3))
        assert float(out.alpha.detach().abs().max()) == 0.0 and not out.visible.any()
    out = render(behind, cam, settings(background=bg), backend="torch")
    out.image.sum().backward()
    assert all(t.grad is None or float(t.grad.abs().max()) == 0.0 for t in behind.tensors())


def test_non_finite_gaussians_are_culled_not_propagated() -> None:
    cam = axis_camera(24, 24, 30.0)
    good = [[0.0, 0.0, 2.0]]
    params = make_params(good * 4, [[0.05]] * 4, [0.8] * 4, [[0.2, 0.9, 0.4]] * 4,
                         requires_grad=False)
    with torch.no_grad():
        params.means[1, 0] = float("nan")
        params.scales[2, 1] = float("inf")
        params.quats[3] = 0.0  # zero quaternion: no rotation defined
    out = render(params, cam, settings(), backend="torch")
    assert out.visible.tolist() == [True, False, False, False]
    single = render(make_params(good, [0.05], [0.8], [[0.2, 0.9, 0.4]]), cam, settings(),
                    backend="torch")
    torch.testing.assert_close(out.image, single.image)


def test_sh_degree_setting_truncates_the_colour_model() -> None:
    params = random_scene(40, 3, seed=12)
    truncated = GaussianParams(params.means, params.scales, params.quats, params.opacities,
                               params.sh[:, :4].contiguous())
    cam = axis_camera(32, 24, 30.0)
    capped = render(params, cam, settings(sh_degree=1), backend="torch").image
    torch.testing.assert_close(capped, render(truncated, cam, settings(), backend="torch").image)
    full = render(params, cam, settings(), backend="torch").image
    assert float((full - capped).abs().max()) > 1e-3


# ---------------------------------------------------------------------------------- API
def test_params_validate_shapes() -> None:
    params = random_scene(3, 1, seed=0)
    with pytest.raises(ValueError, match="quats"):
        GaussianParams(params.means, params.scales, params.quats[:, :3], params.opacities,
                       params.sh)
    with pytest.raises(ValueError, match="SH"):
        GaussianParams(params.means, params.scales, params.quats, params.opacities,
                       params.sh[:, :3])


def test_params_round_trip_through_cloud() -> None:
    g = np.random.default_rng(1)
    cloud = GaussianCloud(g.normal(size=(5, 3)), g.normal(size=(5, 3)), g.normal(size=(5, 4)),
                          g.normal(size=5), g.normal(size=(5, 3)), g.normal(size=(5, 8, 3)))
    params = GaussianParams.from_cloud(cloud, "cpu", requires_grad=True)
    assert params.sh_degree == 2 and params.sh.shape == (5, 9, 3)
    assert all(t.requires_grad and t.is_leaf for t in params.tensors())
    assert params.to_cloud().equals(cloud)


def test_render_image_and_device_resolution() -> None:
    cloud = random_scene(30, 1, seed=4, dtype=torch.float32).to_cloud()
    cam = axis_camera(24, 20, 20.0)
    img = render_image(cloud, cam, RenderSettings(background=(1.0, 1.0, 1.0)), device="cpu")
    assert img.shape == (20, 24, 3) and img.dtype == np.float32
    assert 0.0 <= img.min() and img.max() <= 1.0 and img.min() < 0.9
    assert resolve_device("cpu") == torch.device("cpu")
    with pytest.raises(ValueError):
        resolve_device("tpu")
    assert resolve_backend("auto", torch.device("cpu")) == "torch"
    if not torch.cuda.is_available():
        assert resolve_device("auto") == torch.device("cpu")
        with pytest.raises(RuntimeError, match="requested but") as err:
            resolve_device("cuda")
        assert "\n" not in str(err.value)
    else:  # CUDA needs no gsplat: the torch renderer runs there when gsplat is missing
        assert resolve_device("auto").type == "cuda"
        if gsplat_problem() is not None:
            assert resolve_backend("auto", torch.device("cuda")) == "torch"
    if gsplat_problem() is not None:
        with pytest.raises(RuntimeError, match="gsplat"):
            render(GaussianParams.from_cloud(cloud), cam, backend="gsplat")


def test_format_layer_and_decoder_do_not_import_torch() -> None:
    code = ("import sys, spcodec, spcodec.decoder, spcodec.cli; "
            "assert 'torch' not in sys.modules, 'torch imported'")
    subprocess.run([sys.executable, "-c", code], check=True)


# ------------------------------------------------------------------------------ gsplat
def test_gsplat_arguments_follow_its_documented_contract() -> None:
    # runs without CUDA: a stand-in for gsplat.rasterization checks the 1.5.x argument contract,
    # undoes the activations and renders with our renderer; the wrapped result must then equal
    # the torch renderer's exactly (catches activation, shape and output-layout slips)
    from spcodec.imaging.render.gsplat_backend import gsplat_arguments, result_from_gsplat

    params = random_scene(50, 3, seed=9, dtype=torch.float32, spread=3.0)
    cam = Camera.look_at(np.array([0.1, -0.2, -0.4]), np.array([0.0, 0.0, 3.0]),
                         np.array([0.0, -1.0, 0.0]), 40, 30, math.radians(50))
    cfg = settings(background=(0.1, 0.5, 0.9), antialiased=True, sh_degree=2)

    def fake_rasterization(means, quats, scales, opacities, colors, viewmats, Ks, width, height,
                           near_plane, eps2d, sh_degree, packed, backgrounds, render_mode,
                           rasterize_mode):
        n = len(means)
        assert viewmats.shape == (1, 4, 4) and Ks.shape == (1, 3, 3)
        assert backgrounds.shape == (1, 3) and eps2d == 0.3 and not packed
        assert colors.shape == (n, (sh_degree + 1) ** 2, 3) and sh_degree == 2
        assert bool((scales > 0).all()) and bool(((opacities > 0) & (opacities < 1)).all())
        assert render_mode == "RGB" and rasterize_mode == "antialiased"
        w2c = viewmats[0].double().numpy()
        k = Ks[0].double().numpy()
        camera = Camera(width, height, k[0, 0], k[1, 1], k[0, 2], k[1, 2], w2c)
        raw = GaussianParams(means, torch.log(scales), quats, torch.logit(opacities), colors)
        out = render_torch(raw, camera, RenderSettings(
            background=tuple(backgrounds[0].tolist()), near_plane=near_plane,
            antialiased=rasterize_mode == "antialiased"))
        radii = torch.zeros(1, n, 2, dtype=torch.int32)
        radii[0, out.visible] = 3
        return (out.image[None], out.alpha[None, :, :, None],
                {"radii": radii, "means2d": out.means2d[None]})

    result = result_from_gsplat(*fake_rasterization(**gsplat_arguments(params, cam, cfg)),
                                dtype=torch.float32)
    ours = render_torch(params, cam, cfg)
    torch.testing.assert_close(result.image, ours.image, atol=1e-6, rtol=0)
    torch.testing.assert_close(result.alpha, ours.alpha, atol=1e-6, rtol=0)
    assert torch.equal(result.visible, ours.visible) and 0 < int(ours.visible.sum()) < 50
    assert torch.equal(result.radii, torch.where(ours.visible, 3.0, 0.0))
    assert result.means2d.shape == (1, 50, 2) and result.means2d_grad() is None


@pytest.mark.skipif(gsplat_problem() is not None,
                    reason=f"gsplat backend unavailable: {gsplat_problem()}")
@pytest.mark.parametrize("antialiased", [False, True])
def test_torch_renderer_matches_gsplat(antialiased: bool) -> None:
    params = random_scene(2000, 3, seed=8, dtype=torch.float32, spread=1.0,
                          opacity_range=(0.05, 0.99), scale_range=(0.005, 0.05))
    cam = Camera.look_at(np.array([0.2, -0.3, -0.5]), np.array([0.0, 0.0, 3.0]),
                         np.array([0.0, -1.0, 0.0]), 160, 120, math.radians(50))
    cfg = RenderSettings(background=(0.2, 0.4, 0.6), antialiased=antialiased,
                         max_alpha=GSPLAT_MAX_ALPHA)
    cuda = GaussianParams(*(t.cuda().requires_grad_(True) for t in params.tensors()))
    cpu = GaussianParams(*(t.clone().requires_grad_(True) for t in params.tensors()))
    ref = render(cuda, cam, cfg, backend="gsplat")
    ours = render(cpu, cam, cfg, backend="torch")
    diff = (ref.image.cpu() - ours.image.detach()).abs()
    assert float(diff.mean()) < 1e-4 and float(diff.max()) < 1e-2
    torch.testing.assert_close(ref.alpha.cpu(), ours.alpha.detach(), atol=1e-2, rtol=0)
    # gsplat keeps Gaussians whose integer-rounded box touches the image even when it covers no
    # pixel centre; we cull those, so a few border Gaussians may differ
    assert float((ref.visible.cpu() != ours.visible).float().mean()) < 0.01
    w = torch.rand(cam.height, cam.width, 3, generator=torch.Generator().manual_seed(0))
    (ref.image * w.cuda()).sum().backward()
    (ours.image * w).sum().backward()
    for a, b in zip(cuda.tensors(), cpu.tensors()):
        ga, gb = a.grad.cpu(), b.grad
        assert float((ga - gb).norm()) <= 0.05 * float(gb.norm()) + 1e-6
    # what adaptive density control reads: screen-position gradients and radii (gsplat rounds
    # radii up to whole pixels and caps the contour at 3.33 sigma)
    both = ref.visible.cpu() & ours.visible
    ga, gb = ref.means2d_grad().cpu()[both], ours.means2d_grad()[both]
    assert float((ga - gb).norm()) <= 0.05 * float(gb.norm()) + 1e-6
    assert float((ref.radii.cpu()[both] - ours.radii[both]).abs().max()) <= 1.01
