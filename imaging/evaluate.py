"""Quality evaluation: render a model and compare it with a reference model or a dataset's images.

Two modes:

* **against a reference model** (``--reference ORIG.ply``): both models are rendered at held-out
  views sampled around the *reference* (so both are judged from the same cameras, which see the
  scene), and the renders are compared. This measures what a codec changed, with no dataset needed.
  The sampled views frame the whole scene, where fine texture falls below a pixel; the same
  directions are judged again from closer (``closeups``: by default at 1/2 and 1/4 of the
  distance, 800x800), where a viewer's user looks when they move in.
* **against a dataset** (``--dataset DIR``): the model is rendered at the dataset's test views and
  compared with the photographs.

PSNR and SSIM are always reported, LPIPS only when its weights are on disk (``None`` otherwise).
A model that scores below :data:`MISMATCH_PSNR_DB` against a dataset is reported with a
:class:`DatasetMismatchWarning` (:func:`warn_if_mismatched`). Models with NaN or infinite
parameters are refused, as the encoder refuses them.
"""

from __future__ import annotations

import math
import os
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from spcodec.cloud import GaussianCloud

from .cameras import Camera
from .metrics import image_metrics

MISMATCH_PSNR_DB = 15.0
"""Mean PSNR (dB) of a model against a dataset's images below which they likely do not match.

Trained 3DGS models score about 23-33 dB against their own test images on the benchmark scenes of
the literature; a model of another scene, or one in another coordinate frame than the dataset's
cameras, scores about what unrelated images do (guitar against the lego dataset: 8.9 dB). A very
coarse model (a sketch-only prefix) may fall below it too, hence a warning and not an error."""


class DatasetMismatchWarning(UserWarning):
    """A model scores so low against a dataset's images that they likely show different scenes."""


def warn_if_mismatched(psnr_db: float, dataset: str | os.PathLike | None = None) -> bool:
    """Warn with a :class:`DatasetMismatchWarning` when ``psnr_db`` is below ``MISMATCH_PSNR_DB``.

    ``psnr_db`` is the PSNR of a model's renders against target images at their cameras (the mean
    over views); ``dataset`` names the images in the message. Returns True when it warned. The one
    check for "wrong model or wrong images": :func:`evaluate_against_dataset` runs it on every
    result, and a training loop can run it at iteration 0, before optimizing a model that cannot
    match. NaN (no views) never warns.
    """
    if not psnr_db < MISMATCH_PSNR_DB:
        return False
    images = f"the images of {dataset}" if dataset is not None else "the target images"
    warnings.warn(f"PSNR {psnr_db:.1f} dB against {images} is below {MISMATCH_PSNR_DB:g} dB: the "
                  "model and the images likely show different scenes (or the model is in another "
                  "coordinate frame than their cameras)", DatasetMismatchWarning, stacklevel=2)
    return True


@dataclass
class EvalConfig:
    """Options of an evaluation."""

    #: Views sampled around the reference (reference mode only).
    views: int = 8
    #: Side of the square sampled views, in pixels (reference mode only).
    resolution: int = 400
    #: Dataset images are divided by this integer factor (dataset mode only).
    downscale: int = 1
    #: At most this many dataset test views (None: all).
    max_views: int | None = None
    #: "auto", "cpu" or "cuda".
    device: str = "auto"
    #: Up axis of the scene for view sampling ("-y" suits COLMAP-derived scenes).
    up: str = "-y"
    #: Render with Mip-Splatting's antialiased opacity (for models trained that way).
    antialiased: bool = False
    #: Background colour (reference mode; dataset mode uses the dataset's).
    background: tuple[float, float, float] = (0.0, 0.0, 0.0)
    #: Seed of the view sampling.
    seed: int = 0
    #: Where to write "reference | ours | error" PNGs, one per view (None: nowhere).
    save_renders: Path | None = None
    #: Closer framings judged besides the sampled one (reference mode only): each factor brings
    #: every camera that much nearer the scene's robust centre along its own view direction
    #: (0.5: half the distance); empty: the sampled framing alone.
    closeups: tuple[float, ...] = (0.5, 0.25)
    #: Side of the square close-up views, in pixels: finer than the sampled framing, so that
    #: Gaussians a whole-scene view shows below a pixel cover several.
    closeup_resolution: int = 800
    #: The screen-space low-pass both models render with (px^2): INRIA's and gsplat's 0.3 (the
    #: renderer's default), with which published test PSNR is measured; an encode judging its
    #: file against a dataset passes the low-pass it trained with.
    blur_variance: float = 0.3

    def __post_init__(self) -> None:
        if any(not 0 < f < 1 for f in self.closeups):
            raise ValueError(f"closeups are distance factors in (0, 1), got {self.closeups}")
        if self.closeup_resolution < 8:
            raise ValueError("closeup_resolution must be at least 8")
        if not self.blur_variance >= 0:
            raise ValueError(f"blur_variance must be >= 0, got {self.blur_variance}")


@dataclass
class ViewResult:
    name: str
    psnr: float
    ssim: float
    lpips: float | None
    render_seconds: float


@dataclass
class EvalReport:
    """Aggregate and per-view metrics of one evaluation."""

    mode: str
    width: int
    height: int
    views: list[ViewResult] = field(default_factory=list)
    device: str = "cpu"
    seconds: float = 0.0
    distance: float = 1.0
    """Camera distance relative to the sampled framing (1: the framing itself)."""
    closeups: list["EvalReport"] = field(default_factory=list)
    """The same views judged from closer (reference mode), nearest last."""
    blur_variance: float = 0.3
    """The low-pass (px^2) the renders were made with (:attr:`EvalConfig.blur_variance`)."""

    @property
    def psnr(self) -> float:
        return float(np.mean([v.psnr for v in self.views])) if self.views else math.nan

    @property
    def ssim(self) -> float:
        return float(np.mean([v.ssim for v in self.views])) if self.views else math.nan

    @property
    def lpips(self) -> float | None:
        values = [v.lpips for v in self.views]
        return float(np.mean(values)) if values and None not in values else None

    def framing(self, distance: float) -> "EvalReport":
        """This report (distance 1) or its close-up at ``distance``; KeyError if not judged."""
        for report in [self, *self.closeups]:
            if math.isclose(report.distance, distance):
                return report
        raise KeyError(f"no framing at {distance} of the distance was judged")

    def to_json(self) -> dict:
        """The ``spcodec eval --json`` document (strict JSON: no NaN or infinity). The top level
        is the sampled framing; ``closeups`` holds the closer ones in the same form."""
        doc = {
            "psnr": round(self.psnr, 4), "ssim": round(self.ssim, 6),
            "lpips": None if self.lpips is None else round(self.lpips, 6),
            "views": len(self.views), "mode": self.mode,
            "width": self.width, "height": self.height, "device": self.device,
            "seconds": round(self.seconds, 3), "distance": self.distance,
            "blur_variance": self.blur_variance,
            "per_view": [{"name": v.name, "psnr": round(v.psnr, 4), "ssim": round(v.ssim, 6),
                          "lpips": None if v.lpips is None else round(v.lpips, 6),
                          "render_seconds": round(v.render_seconds, 4)} for v in self.views],
        }
        if self.mode == "reference":
            doc["closeups"] = [c.to_json() for c in self.closeups]
        return doc

    def summary_lines(self, name: str) -> list[str]:
        """One line per framing, as ``spcodec eval`` prints them."""
        lpips = "n/a (weights not found)" if self.lpips is None else f"{self.lpips:.4f}"
        lines = [f"{name}: PSNR {self.psnr:.2f} dB, SSIM {self.ssim:.4f}, LPIPS {lpips} over "
                 f"{len(self.views)} views of {self.width}x{self.height} ({self.mode}, "
                 f"low-pass {self.blur_variance:g} px^2, {self.device}, {self.seconds:.1f} s)"]
        for close in self.closeups:
            lpips = "" if close.lpips is None else f", LPIPS {close.lpips:.4f}"
            lines.append(f"  closer, at {close.distance:g} of the distance: PSNR {close.psnr:.2f} "
                         f"dB, SSIM {close.ssim:.4f}{lpips} over {len(close.views)} views of "
                         f"{close.width}x{close.height}")
        return lines


def _renderer(config: EvalConfig, background: tuple[float, float, float]):
    """A function cloud-or-params, camera -> image, plus a function that uploads a cloud once."""
    from .render import GaussianParams, RenderSettings, render_image, resolve_device

    device = resolve_device(config.device)
    settings = RenderSettings(background=tuple(float(c) for c in background),
                              antialiased=config.antialiased, blur_variance=config.blur_variance)

    def upload(cloud: GaussianCloud):
        return GaussianParams.from_cloud(cloud, device)

    def draw(params, camera: Camera) -> tuple[np.ndarray, float]:
        start = time.perf_counter()
        image = render_image(params, camera, settings)
        return image, time.perf_counter() - start

    return upload, draw, str(device)


def evaluate_against_reference(model: GaussianCloud, reference: GaussianCloud,
                               config: EvalConfig | None = None) -> EvalReport:
    """Render both models at held-out views sampled around ``reference`` and compare, at the
    sampled framing and at each of ``config.closeups``."""
    from .views import robust_bounds, sample_views

    config = config or EvalConfig()
    model.check_finite()
    reference.check_finite()
    start = time.perf_counter()
    cameras = sample_views(reference, config.views, resolution=(config.resolution,
                                                                config.resolution),
                           split="eval", seed=config.seed, up=config.up)
    upload, draw, device = _renderer(config, config.background)
    ours, theirs = upload(model), upload(reference)
    report = _compare(ours, theirs, cameras, draw, config, device, "")
    centre = robust_bounds(reference).centre  # what the sampled views look at
    zoom = config.closeup_resolution / config.resolution
    for factor in config.closeups:
        near = [c.scaled(zoom).dollied(centre, factor) for c in cameras]
        close = _compare(ours, theirs, near, draw, config, device, f"close_{factor:g}_")
        close.distance = factor
        report.closeups.append(close)
    report.seconds = time.perf_counter() - start
    return report


def _compare(ours, theirs, cameras: list[Camera], draw, config: EvalConfig, device: str,
             prefix: str) -> EvalReport:
    """Scores of ``ours`` against ``theirs`` (uploaded models) at ``cameras``."""
    first = cameras[0]
    report = EvalReport("reference", first.width, first.height, device=device,
                        blur_variance=config.blur_variance)
    for i, camera in enumerate(cameras):
        ref_image, _ = draw(theirs, camera)
        image, seconds = draw(ours, camera)
        report.views.append(_score(f"{prefix}view_{i:03d}", ref_image, image, seconds))
        _save_render(config, f"{prefix}view_{i:03d}.png", ref_image, image)
    return report


def evaluate_against_dataset(model: GaussianCloud, dataset_path: Path,
                             config: EvalConfig | None = None) -> EvalReport:
    """Render ``model`` at the dataset's test views and compare with its images.

    Warns (:class:`DatasetMismatchWarning`) when the mean PSNR says model and images do not match.
    """
    from .datasets import load_dataset

    config = config or EvalConfig()
    model.check_finite()
    start = time.perf_counter()
    dataset = load_dataset(dataset_path, downscale=config.downscale)
    views = dataset.test[:config.max_views] if config.max_views else dataset.test
    upload, draw, device = _renderer(config, dataset.background)
    params = upload(model)
    first = views[0].camera
    report = EvalReport("dataset", first.width, first.height, device=device,
                        blur_variance=config.blur_variance)
    for view in views:
        photo = view.load_image()
        image, seconds = draw(params, view.camera)
        report.views.append(_score(view.name, photo, image, seconds, view.valid_mask()))
        _save_render(config, f"{Path(view.name).stem}.png", photo, image)
    report.seconds = time.perf_counter() - start
    warn_if_mismatched(report.psnr, dataset_path)
    return report


def _save_render(config: EvalConfig, name: str, reference: np.ndarray, image: np.ndarray) -> None:
    """Write 'reference | ours | error' as ``name`` into ``config.save_renders`` (if set), creating
    the folder with the first image."""
    if config.save_renders is None:
        return
    from .images import side_by_side, write_png

    folder = Path(config.save_renders)
    folder.mkdir(parents=True, exist_ok=True)
    write_png(folder / name, side_by_side(reference, image))


def _score(name: str, reference: np.ndarray, image: np.ndarray, seconds: float,
           mask: np.ndarray | None = None) -> ViewResult:
    values = image_metrics(reference, image, mask=mask)
    return ViewResult(name, float(values["psnr"]), float(values["ssim"]), values.get("lpips"),
                      seconds)
