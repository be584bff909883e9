"""Image-quality metrics as the 3DGS literature reports them: PSNR, SSIM and (when possible) LPIPS.

Images are float arrays (H, W, 3) in [0, 1] (see :mod:`spcodec.imaging.images`); values are used as
given (clamp renders to [0, 1] first, as 3DGS does). numpy only, except:

* :func:`lpips`, which needs the ``lpips`` package *and* its weights already on disk (it never
  downloads: see :func:`lpips_status`), and
* :func:`ssim_torch`, a differentiable twin of :func:`ssim` for training, importing torch lazily.

**PSNR cap.** ``10 log10(1 / MSE)`` is infinite for identical images, which strict JSON cannot
store; PSNR is therefore capped at :data:`PSNR_CAP_DB` = 100 dB (an MSE of 1e-10, far below the
8-bit quantization floor of ~59 dB where two renders that differ at all already lie).

**SSIM** follows the 3DGS evaluation code (``utils/loss_utils.py``): an 11x11 Gaussian window with
sigma 1.5, local statistics by 'same' convolution with *zero* padding (5 pixels), C1 = 0.01^2,
C2 = 0.03^2, and the SSIM map averaged over all pixels and channels. Zero padding makes the local
means near the border biased towards 0, so the border pixels' values differ from
scikit-image's ``structural_similarity`` (reflect padding, then a 5-pixel border cropped before
averaging); on the interior (pixels at least 5 from the border) the two maps are identical.
"""

from __future__ import annotations

import importlib.util
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

PSNR_CAP_DB = 100.0
SSIM_WINDOW = 11
SSIM_SIGMA = 1.5
SSIM_C1 = 0.01 ** 2
SSIM_C2 = 0.03 ** 2


class MetricUnavailable(RuntimeError):
    """A metric cannot be computed here (e.g. LPIPS without its weights); never a fake value."""


def _pair(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    if a.shape != b.shape:
        raise ValueError(f"images differ in shape: {a.shape} vs {b.shape}")
    if a.ndim == 2:
        a, b = a[:, :, None], b[:, :, None]
    if a.ndim != 3 or a.size == 0:
        raise ValueError(f"expected (H, W) or (H, W, C) images, got shape {a.shape}")
    if not (np.isfinite(a).all() and np.isfinite(b).all()):
        raise ValueError("images contain NaN or infinite values")
    return a, b


def _mask(mask: np.ndarray | None, shape: tuple[int, ...]) -> np.ndarray | None:
    if mask is None:
        return None
    m = np.asarray(mask, dtype=bool)
    if m.shape != shape[:2]:
        raise ValueError(f"mask is {m.shape}, images are {shape[:2]}")
    if not m.any():
        raise ValueError("mask selects no pixel")
    return m


def mse(reference: np.ndarray, ours: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Mean squared error over pixels (those in ``mask`` when given) and channels."""
    return _mse(*_pair(reference, ours), mask)


def _mse(a: np.ndarray, b: np.ndarray, mask: np.ndarray | None) -> float:
    sq = (a - b) ** 2
    m = _mask(mask, a.shape)
    return float(sq.mean() if m is None else sq[m].mean())


def psnr(reference: np.ndarray, ours: np.ndarray, mask: np.ndarray | None = None,
         cap: float = PSNR_CAP_DB) -> float:
    """Peak signal-to-noise ratio in dB for a peak of 1, capped at ``cap`` (finite for JSON)."""
    return _psnr_of(mse(reference, ours, mask), cap)


def _psnr_of(error: float, cap: float = PSNR_CAP_DB) -> float:
    if error <= 10.0 ** (-cap / 10.0):
        return float(cap)
    return float(min(cap, -10.0 * math.log10(error)))


def gaussian_window(size: int = SSIM_WINDOW, sigma: float = SSIM_SIGMA) -> np.ndarray:
    """Normalized 1D Gaussian taps centred on the middle one (2D window: their outer product)."""
    x = np.arange(size, dtype=np.float64) - size // 2
    taps = np.exp(-(x * x) / (2.0 * sigma * sigma))
    return taps / taps.sum()


def _blur_zero_padded(channel: np.ndarray, taps: np.ndarray) -> np.ndarray:
    """'same' 2D correlation with the separable window, zeros outside the image."""
    from scipy.ndimage import correlate1d

    rows = correlate1d(channel, taps, axis=0, mode="constant", cval=0.0)
    return correlate1d(rows, taps, axis=1, mode="constant", cval=0.0)


def ssim_map(reference: np.ndarray, ours: np.ndarray) -> np.ndarray:
    """Per-pixel, per-channel SSIM (H, W, C) exactly as the 3DGS evaluation computes it."""
    return _ssim_map(*_pair(reference, ours))


_SSIM_BAND = 48
"""Rows of the SSIM map computed together when only parts of two images differ."""


def _ssim_map(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """:func:`ssim_map` of two float64 (H, W, C) images, computed only where it can differ from 1.

    A pixel whose 11x11 window sees the same values in both images has SSIM exactly 1: equal
    inputs give bit-equal local statistics, so numerator and denominator are the same number.
    Renders of a model and of its compressed copy agree on every pixel that neither covers
    (50-90 % of an evaluation view), so the map is computed on bands of rows, each over the
    columns where the window reaches a differing pixel, plus the window's half-width of real
    neighbours around it: a correlation is the same sum of the same products at every position,
    so each computed value is bit-identical to the whole-image computation.
    """
    height, width = a.shape[:2]
    out = np.ones(a.shape, dtype=np.float64)
    differs = (a != b).any(axis=2)
    r = SSIM_WINDOW // 2
    bands = []  # (row0, row1, col0, col1) of the map to compute
    for y0 in range(0, height, _SSIM_BAND):
        y1 = min(height, y0 + _SSIM_BAND)
        cols = np.flatnonzero(differs[max(0, y0 - r):y1 + r].any(axis=0))
        if len(cols):
            bands.append((y0, y1, max(0, int(cols[0]) - r), min(width, int(cols[-1]) + r + 1)))
    if not bands:
        return out
    if sum((y1 - y0 + 2 * r) * (x1 - x0 + 2 * r) for y0, y1, x0, x1 in bands) >= height * width:
        bands = [(0, height, 0, width)]  # differing nearly everywhere: one piece is cheaper
    for y0, y1, x0, x1 in bands:
        # the piece and r real neighbours around it (zeros beyond the image, as the padding)
        cy0, cy1, cx0, cx1 = max(0, y0 - r), min(height, y1 + r), max(0, x0 - r), min(width,
                                                                                     x1 + r)
        piece = _ssim_piece(a[cy0:cy1, cx0:cx1], b[cy0:cy1, cx0:cx1])
        out[y0:y1, x0:x1] = piece[y0 - cy0:y1 - cy0, x0 - cx0:x1 - cx0]
    return out


def _ssim_piece(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The 3DGS SSIM map of two (h, w, C) images (zero padding at their borders), one channel
    at a time (a channel's five statistics stay in the CPU's caches), with the arithmetic of
    the formula operation for operation, in place."""
    taps = gaussian_window()
    out = np.empty(a.shape, dtype=np.float64)
    for c in range(a.shape[2]):
        x, y = np.ascontiguousarray(a[:, :, c]), np.ascontiguousarray(b[:, :, c])
        mu_x, mu_y = _blur_zero_padded(x, taps), _blur_zero_padded(y, taps)
        mu_xx, mu_yy, mu_xy = mu_x * mu_x, mu_y * mu_y, mu_x * mu_y
        var_x = _blur_zero_padded(x * x, taps)
        var_x -= mu_xx
        var_y = _blur_zero_padded(y * y, taps)
        var_y -= mu_yy
        cov = _blur_zero_padded(x * y, taps)
        cov -= mu_xy
        # ((2 mu_x mu_y + C1) (2 cov + C2)) / ((mu_x^2 + mu_y^2 + C1) (var_x + var_y + C2))
        num = np.multiply(mu_x, 2.0, out=mu_x)
        num *= mu_y
        num += SSIM_C1
        cov *= 2.0
        cov += SSIM_C2
        num *= cov
        den = np.add(mu_xx, mu_yy, out=mu_xx)
        den += SSIM_C1
        var_x += var_y
        var_x += SSIM_C2
        den *= var_x
        np.divide(num, den, out=out[:, :, c])
    return out


def ssim(reference: np.ndarray, ours: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Mean SSIM over pixels (those in ``mask`` when given) and channels; 1 for identical images."""
    return _ssim_of(ssim_map(reference, ours), mask)


def _ssim_of(smap: np.ndarray, mask: np.ndarray | None) -> float:
    m = _mask(mask, smap.shape)
    return float(smap.mean() if m is None else smap[m].mean())


def ssim_torch(reference: Any, ours: Any) -> Any:
    """Differentiable SSIM of torch tensors (C, H, W) or (B, C, H, W), same definition as ssim().

    Returns a 0-d tensor (the mean over batch, channels and pixels), e.g. for a
    ``(1 - lambda) L1 + lambda (1 - SSIM)`` training loss. The five local statistics are blurred
    in one depthwise call per axis (the Gaussian window is separable): on the CPU that is 5x
    faster, forward and backward, than one 11x11 convolution per statistic, and a training step
    spends as much time here as in the renderer.
    """
    import torch
    import torch.nn.functional as F

    x, y = reference, ours
    if x.shape != y.shape or x.dim() not in (3, 4):
        raise ValueError(f"expected two (C, H, W) or (B, C, H, W) tensors of one shape, got "
                         f"{tuple(x.shape)} and {tuple(y.shape)}")
    if x.dim() == 3:
        x, y = x.unsqueeze(0), y.unsqueeze(0)
    channels = x.shape[1]
    stats = torch.cat([x, y, x * x, y * y, x * y], dim=1)
    k = stats.shape[1]
    taps = torch.as_tensor(gaussian_window(), dtype=x.dtype, device=x.device)
    pad = SSIM_WINDOW // 2
    rows = F.conv2d(stats, taps.view(1, 1, 1, -1).expand(k, 1, 1, SSIM_WINDOW), padding=(0, pad),
                    groups=k)
    blurred = F.conv2d(rows, taps.view(1, 1, -1, 1).expand(k, 1, SSIM_WINDOW, 1),
                       padding=(pad, 0), groups=k)
    mu_x, mu_y, xx, yy, xy = blurred.split(channels, dim=1)
    var_x = xx - mu_x * mu_x
    var_y = yy - mu_y * mu_y
    cov = xy - mu_x * mu_y
    smap = ((2 * mu_x * mu_y + SSIM_C1) * (2 * cov + SSIM_C2)) / \
        ((mu_x * mu_x + mu_y * mu_y + SSIM_C1) * (var_x + var_y + SSIM_C2))
    return smap.mean()


# ------------------------------------------------------------------------------------------ LPIPS
LPIPS_BACKBONE_FILES = {
    "vgg": "vgg16-397923af.pth",
    "alex": "alexnet-owt-7be5be79.pth",
    "squeeze": "squeezenet1_1-b8a52dc0.pth",
}
"""torchvision checkpoint file names of the LPIPS backbones, as cached by torch.hub."""


@dataclass(frozen=True)
class LpipsStatus:
    """Whether LPIPS can run here without fetching anything, and why not when it cannot."""

    available: bool
    reason: str
    net: str
    linear_weights: Path | None = None
    backbone_weights: Path | None = None


def _torch_hub_dir() -> Path:
    """torch.hub's cache folder, resolved as torch.hub.get_dir() does, without importing torch."""
    if os.environ.get("TORCH_HOME"):
        return Path(os.environ["TORCH_HOME"]).expanduser() / "hub"
    cache = os.environ.get("XDG_CACHE_HOME") or os.path.join("~", ".cache")
    return Path(cache).expanduser() / "torch" / "hub"


def lpips_status(net: str = "vgg") -> LpipsStatus:
    """Check, by looking at files only, that LPIPS(``net``) can be built with no download.

    Needs the ``lpips`` and ``torchvision`` packages, the linear-layer weights that ``lpips``
    ships (``lpips/weights/v0.1/<net>.pth``) and the backbone checkpoint in torch.hub's cache
    (``<hub>/checkpoints/<file>``). The 3DGS papers report LPIPS with ``net="vgg"``.
    """
    if net not in LPIPS_BACKBONE_FILES:
        return LpipsStatus(False, f"unknown LPIPS network {net!r} (use vgg, alex or squeeze)", net)
    for package in ("lpips", "torchvision"):
        if importlib.util.find_spec(package) is None:
            return LpipsStatus(False, f"the '{package}' package is not installed", net)
    spec = importlib.util.find_spec("lpips")
    locations = list(spec.submodule_search_locations or [])
    linear = Path(locations[0]) / "weights" / "v0.1" / f"{net}.pth" if locations else None
    if linear is None or not linear.is_file():
        return LpipsStatus(False, f"LPIPS linear weights {linear} are missing", net)
    backbone = _torch_hub_dir() / "checkpoints" / LPIPS_BACKBONE_FILES[net]
    if not backbone.is_file():
        return LpipsStatus(False, f"LPIPS backbone weights {backbone} are not on disk (not "
                                  "downloaded on purpose)", net, linear)
    return LpipsStatus(True, "ok", net, linear, backbone)


_LPIPS_MODELS: dict[str, Any] = {}


def lpips(reference: np.ndarray, ours: np.ndarray, net: str = "vgg") -> float:
    """LPIPS distance (lower is better); MetricUnavailable when :func:`lpips_status` says no."""
    status = lpips_status(net)
    if not status.available:
        raise MetricUnavailable(f"LPIPS unavailable: {status.reason}")
    a, b = _pair(reference, ours)
    if a.shape[2] != 3:
        raise ValueError("LPIPS needs RGB images")
    import torch

    model = _LPIPS_MODELS.get(net)
    if model is None:
        import lpips as lpips_package

        # Both weight files were found above, so torchvision loads the backbone from its cache.
        model = lpips_package.LPIPS(net=net, model_path=str(status.linear_weights),
                                    verbose=False).eval()
        _LPIPS_MODELS[net] = model

    def tensor(img: np.ndarray) -> Any:
        return torch.from_numpy(np.ascontiguousarray(img.transpose(2, 0, 1), np.float32))[None]

    with torch.no_grad():
        value = model(tensor(a), tensor(b), normalize=True)  # normalize: [0, 1] -> [-1, 1]
    return float(value.reshape(-1)[0])


def image_metrics(reference: np.ndarray, ours: np.ndarray, mask: np.ndarray | None = None,
                  lpips_net: str | None = "vgg") -> dict[str, float | None]:
    """PSNR, SSIM and LPIPS of one image pair as a strict-JSON-ready dict.

    ``lpips`` is None when LPIPS is unavailable (or ``lpips_net`` is None); it ignores ``mask``.
    """
    a, b = _pair(reference, ours)  # once for both metrics
    result: dict[str, float | None] = {
        "psnr": _psnr_of(_mse(a, b, mask)),
        "ssim": _ssim_of(_ssim_map(a, b), mask),
        "lpips": None,
    }
    if lpips_net is not None and lpips_status(lpips_net).available:
        result["lpips"] = lpips(reference, ours, lpips_net)
    return result
