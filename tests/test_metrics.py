"""PSNR / SSIM / LPIPS: definitions, edge cases and an independent SSIM implementation."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from spcodec.imaging import metrics
from spcodec.imaging.metrics import (
    PSNR_CAP_DB,
    MetricUnavailable,
    image_metrics,
    lpips,
    lpips_status,
    psnr,
    ssim,
    ssim_map,
)


def _image(seed: int = 0, shape=(48, 64, 3)) -> np.ndarray:
    """A smooth pattern plus texture, so SSIM has real structure to compare."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:shape[0], 0:shape[1]] / max(shape)
    base = 0.5 + 0.3 * np.sin(9 * xx)[..., None] * np.cos(7 * yy)[..., None] * [1.0, 0.6, -0.8]
    return np.clip(base + 0.1 * rng.random(shape), 0.0, 1.0)


def _noisy(image: np.ndarray, sigma: float, seed: int = 1) -> np.ndarray:
    return np.clip(image + np.random.default_rng(seed).normal(0.0, sigma, image.shape), 0.0, 1.0)


# ------------------------------------------------------------------------------------------- PSNR
def test_psnr_of_identical_images_is_the_finite_cap() -> None:
    img = _image()
    value = psnr(img, img.copy())
    assert value == PSNR_CAP_DB >= 60.0
    json.dumps({"psnr": value}, allow_nan=False)  # strict JSON accepts it


def test_psnr_matches_its_definition_and_decreases_with_noise() -> None:
    img = _image()
    values = [psnr(img, _noisy(img, s)) for s in (0.01, 0.03, 0.1, 0.3)]
    assert all(a > b for a, b in zip(values, values[1:]))
    noisy = _noisy(img, 0.05)
    expected = -10 * math.log10(np.mean((img - noisy) ** 2))
    assert psnr(img, noisy) == pytest.approx(expected, abs=1e-9)
    assert psnr(np.zeros((4, 4, 3)), np.full((4, 4, 3), 0.1)) == pytest.approx(20.0)


def test_psnr_mask_restricts_the_pixels() -> None:
    a = np.zeros((10, 10, 3))
    b = a.copy()
    b[:, 5:] = 0.5  # only the right half differs
    mask = np.zeros((10, 10), bool)
    mask[:, :5] = True
    assert psnr(a, b, mask) == PSNR_CAP_DB
    assert psnr(a, b, ~mask) == pytest.approx(-10 * math.log10(0.25))
    with pytest.raises(ValueError):
        psnr(a, b, np.zeros((10, 10), bool))


def test_metrics_reject_mismatched_or_invalid_images() -> None:
    with pytest.raises(ValueError):
        psnr(np.zeros((4, 4, 3)), np.zeros((4, 5, 3)))
    with pytest.raises(ValueError):
        ssim(np.full((16, 16, 3), np.nan), np.zeros((16, 16, 3)))


# ------------------------------------------------------------------------------------------- SSIM
def test_ssim_of_identical_images_is_one_and_drops_with_noise() -> None:
    img = _image()
    assert ssim(img, img) == pytest.approx(1.0, abs=1e-12)
    values = [ssim(img, _noisy(img, s)) for s in (0.01, 0.05, 0.2)]
    assert 1.0 > values[0] > values[1] > values[2] > 0.0


def test_ssim_interior_equals_scikit_image() -> None:
    """scikit-image (reflect padding, border cropped) must agree exactly away from the border."""
    structural_similarity = pytest.importorskip("skimage.metrics").structural_similarity
    ref = _image(3, (120, 150, 3))
    for sigma in (0.02, 0.1):
        ours = _noisy(ref, sigma, seed=7)
        theirs, theirs_map = structural_similarity(
            ref, ours, gaussian_weights=True, sigma=1.5, use_sample_covariance=False,
            data_range=1.0, channel_axis=2, full=True)
        mine = ssim_map(ref, ours)
        np.testing.assert_allclose(mine[5:-5, 5:-5], theirs_map[5:-5, 5:-5], atol=1e-10)
        assert mine[5:-5, 5:-5].mean() == pytest.approx(theirs, abs=1e-10)
        # The full-image means differ only through the 5-pixel border (zero vs reflect padding),
        # 15% of the pixels here: the full mean is scikit-image's interior plus our border.
        interior = mine[5:-5, 5:-5]
        border_sum = mine.sum() - interior.sum()
        assert ssim(ref, ours) == pytest.approx((theirs * interior.size + border_sum) / mine.size,
                                                abs=1e-10)
        assert ssim(ref, ours) != pytest.approx(theirs, abs=1e-6)
    low_noise = _noisy(ref, 0.01, seed=3)
    theirs = structural_similarity(ref, low_noise, gaussian_weights=True, sigma=1.5,
                                   use_sample_covariance=False, data_range=1.0, channel_axis=2)
    assert ssim(ref, low_noise) == pytest.approx(theirs, abs=0.01)


def test_ssim_border_uses_zero_padding_like_3dgs() -> None:
    """Brute-force 2D zero-padded windows at the corner pixel (the 3DGS conv2d with padding=5)."""
    ref = _image(5, (20, 20, 3))
    ours = _noisy(ref, 0.1)
    taps = metrics.gaussian_window()
    window = np.outer(taps, taps)
    pad = lambda img: np.pad(img, ((5, 5), (5, 5)), mode="constant")  # noqa: E731
    for channel in range(3):
        x, y = pad(ref[:, :, channel]), pad(ours[:, :, channel])
        px, py = x[0:11, 0:11], y[0:11, 0:11]  # window centred on pixel (0, 0)
        mu_x, mu_y = (window * px).sum(), (window * py).sum()
        var_x = (window * px * px).sum() - mu_x ** 2
        var_y = (window * py * py).sum() - mu_y ** 2
        cov = (window * px * py).sum() - mu_x * mu_y
        c1, c2 = 0.01 ** 2, 0.03 ** 2
        expected = ((2 * mu_x * mu_y + c1) * (2 * cov + c2)) / \
            ((mu_x ** 2 + mu_y ** 2 + c1) * (var_x + var_y + c2))
        assert ssim_map(ref, ours)[0, 0, channel] == pytest.approx(expected, abs=1e-12)


def test_gaussian_window_is_the_3dgs_one() -> None:
    taps = metrics.gaussian_window()
    assert taps.shape == (11,) and taps.sum() == pytest.approx(1.0)
    assert np.argmax(taps) == 5 and taps[0] == pytest.approx(taps[10])
    assert taps[6] / taps[5] == pytest.approx(math.exp(-1 / (2 * 1.5 ** 2)))


def test_torch_ssim_matches_numpy_and_has_gradients() -> None:
    torch = pytest.importorskip("torch")
    ref = _image(2, (32, 40, 3))
    ours = _noisy(ref, 0.05)
    a = torch.tensor(ref.transpose(2, 0, 1), dtype=torch.float64)
    b = torch.tensor(ours.transpose(2, 0, 1), dtype=torch.float64, requires_grad=True)
    value = metrics.ssim_torch(a, b)
    assert float(value.detach()) == pytest.approx(ssim(ref, ours), abs=1e-10)
    value.backward()
    assert b.grad is not None and float(b.grad.abs().sum()) > 0


# ------------------------------------------------------------------------------------------ LPIPS
def test_lpips_is_reported_unavailable_without_local_weights(monkeypatch, tmp_path: Path) -> None:
    """With an empty torch hub cache, LPIPS must say why it cannot run, never return a number."""
    monkeypatch.setenv("TORCH_HOME", str(tmp_path / "torch-home"))
    status = lpips_status("vgg")
    assert not status.available
    assert status.reason  # names the missing package or weight file
    img = _image()
    with pytest.raises(MetricUnavailable, match="LPIPS unavailable"):
        lpips(img, img)
    result = image_metrics(img, _noisy(img, 0.05))
    assert result["lpips"] is None
    json.dumps(result, allow_nan=False)


def test_lpips_status_names_the_missing_backbone_file(monkeypatch, tmp_path: Path) -> None:
    """Simulate an installed lpips package whose backbone checkpoint is not cached."""
    package = tmp_path / "site" / "lpips"
    (package / "weights" / "v0.1").mkdir(parents=True)
    (package / "__init__.py").write_text("")
    (package / "weights" / "v0.1" / "vgg.pth").write_bytes(b"x")
    (tmp_path / "site" / "torchvision").mkdir()
    (tmp_path / "site" / "torchvision" / "__init__.py").write_text("")
    monkeypatch.syspath_prepend(str(tmp_path / "site"))
    monkeypatch.setenv("TORCH_HOME", str(tmp_path / "hub-home"))
    status = lpips_status("vgg")
    assert not status.available
    assert "vgg16-397923af.pth" in status.reason
    checkpoints = tmp_path / "hub-home" / "hub" / "checkpoints"
    checkpoints.mkdir(parents=True)
    (checkpoints / "vgg16-397923af.pth").write_bytes(b"x")
    status = lpips_status("vgg")
    assert status.available and status.backbone_weights == checkpoints / "vgg16-397923af.pth"
    assert not lpips_status("resnet").available


def test_lpips_value_when_really_available() -> None:
    status = lpips_status("vgg")
    if not status.available:
        pytest.skip(f"LPIPS not available on this machine: {status.reason}")
    img = _image(shape=(64, 64, 3))
    assert lpips(img, img) == pytest.approx(0.0, abs=1e-6)
    assert lpips(img, _noisy(img, 0.2)) > lpips(img, _noisy(img, 0.02)) > 0.0
