"""The entry points the evaluation command and the retraining loop call."""

from __future__ import annotations

from typing import Literal

import numpy as np
import torch

from spcodec.cloud import GaussianCloud

from ..cameras import Camera
from .gsplat_backend import gsplat_problem, render_gsplat
from .params import GaussianParams
from .settings import RenderResult, RenderSettings
from .torch_backend import render_torch

Backend = Literal["auto", "torch", "gsplat"]


def resolve_device(spec: str = "auto") -> torch.device:
    """``"auto"``: CUDA when torch sees a GPU, else the CPU; ``"cpu"``; ``"cuda"`` /
    ``"cuda:N"``: that GPU, or a one-line RuntimeError naming what is missing.

    gsplat is not required on CUDA: without it the torch renderer runs there (resolve_backend),
    and still far faster than on the CPU (docs/LOG.md 13.7: five 3000-step encodes at once
    on one H100, 4-10 minutes each)."""
    if spec == "cpu":
        return torch.device("cpu")
    if spec == "auto" or spec.startswith("cuda"):
        if torch.cuda.is_available():
            return torch.device("cuda" if spec == "auto" else spec)
        if spec == "auto":
            return torch.device("cpu")
        raise RuntimeError(f"device {spec!r} requested but torch.cuda.is_available() is False "
                           f"(torch {torch.__version__})")
    raise ValueError(f"unknown device {spec!r}: use 'auto', 'cpu' or 'cuda[:N]'")


def resolve_backend(backend: Backend, device: torch.device) -> Literal["torch", "gsplat"]:
    """The backend ``render`` uses for tensors on ``device``: gsplat on CUDA when it imports,
    else the torch renderer (on any device)."""
    if backend == "torch":
        return "torch"
    if backend == "gsplat":
        problem = gsplat_problem()
        if problem is not None:
            raise RuntimeError(f"backend 'gsplat' requested but {problem}")
        if device.type != "cuda":
            raise RuntimeError(f"backend 'gsplat' needs CUDA tensors, got {device}")
        return "gsplat"
    if backend == "auto":
        return "gsplat" if device.type == "cuda" and gsplat_problem() is None else "torch"
    raise ValueError(f"unknown backend {backend!r}: use 'auto', 'torch' or 'gsplat'")


def render(params: GaussianParams, camera: Camera, settings: RenderSettings | None = None,
           backend: Backend = "auto") -> RenderResult:
    """Render one view; differentiable w.r.t. every tensor of ``params`` on both backends."""
    settings = settings or RenderSettings()
    if resolve_backend(backend, params.device) == "gsplat":
        return render_gsplat(params, camera, settings)
    return render_torch(params, camera, settings)


def render_image(scene: GaussianCloud | GaussianParams, camera: Camera,
                 settings: RenderSettings | None = None, device: str = "auto",
                 backend: Backend = "auto") -> np.ndarray:
    """Evaluation helper: an (H, W, 3) float32 image clamped to [0, 1], without gradients.

    Pass GaussianParams (already on a device) to render many views without re-uploading.
    """
    with torch.no_grad():
        if isinstance(scene, GaussianCloud):
            scene = GaussianParams.from_cloud(scene, resolve_device(device))
        return picture(render(scene, camera, settings, backend).image)


def picture(image: torch.Tensor) -> np.ndarray:
    """A rendered image as :func:`render_image` returns it: clamped to [0, 1], float32, on the
    CPU (a renderer's forward pass taken for other ends, such as a sensitivity, gives the same
    picture through it)."""
    return image.detach().clamp(0.0, 1.0).to("cpu", torch.float32).numpy()
