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

Judging against a reference renders it at the same cameras for every file of its scene: with
``EvalConfig.cache`` set, those renders (and the cameras) are kept on disk by content and settings
(:mod:`.cache`), so a second judgement renders the model alone and reports the same bits. Progress
goes to ``EvalConfig.progress`` (the encoder's ``StageReporter.stage`` fits): one stage per
framing, a step per view, with the time left for the whole evaluation.

PSNR and SSIM are always reported, LPIPS only when its weights are on disk (``None`` otherwise).
A model that scores below :data:`MISMATCH_PSNR_DB` against a dataset is reported with a
:class:`DatasetMismatchWarning` (:func:`warn_if_mismatched`). Models with NaN or infinite
parameters are refused, as the encoder refuses them.
"""

from __future__ import annotations

import contextlib
import math
import os
import sys
import time
import warnings
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterator

import numpy as np

from spcodec.cloud import GaussianCloud

from .cache import CachedRenders, RenderCache, cache_key, cloud_digest, code_fingerprint
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
    #: Folder of the render cache for the reference's renders (reference mode;
    #: :func:`.cache.default_cache_dir` is the user's), or None: render it every time.
    cache: Path | None = None
    #: Progress of the stages: a function (name, total or None) -> a stage with ``update(count,
    #: **figures)``, ``note(message)`` and ``done(summary)``, such as the encoder's
    #: ``StageReporter.stage``; None: silent.
    progress: Callable[[str, int | None], Any] | None = field(default=None, repr=False,
                                                               compare=False)

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


class _Quiet:
    """A stage that shows nothing (no ``EvalConfig.progress``)."""

    def update(self, count: int = 1, **figures: float) -> None:
        pass

    def note(self, message: str) -> None:
        pass

    def done(self, summary: str = "") -> None:
        pass


def _stages(config: EvalConfig) -> Callable[[str, int | None], Any]:
    return config.progress or (lambda name, total: _Quiet())


@contextlib.contextmanager
def freed_memory_kept() -> Iterator[bool]:
    """While inside, have the C library keep freed memory for reuse instead of handing it back
    to the system at once (glibc's ``mallopt``; elsewhere nothing changes). Yields whether it
    applied.

    The renderer frees and allocates tens of megabytes per step, and glibc by default maps and
    unmaps the largest blocks every time: the page faults cost a fifth of an evaluation's CPU
    time (guitar: 3.9 of 12.7 s rendering the reference, 0.4 s inside). The settings are the
    process's; on leaving, large blocks are mapped again above 32 MB and the heap top is
    trimmed above 64 MB, where glibc's own adaptive thresholds settle in a process that renders.
    """
    import ctypes

    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        yield False
        return
    m_trim_threshold, m_mmap_threshold, m_mmap_max = -1, -3, -4
    applied = bool(mallopt(m_mmap_max, 0)) and bool(mallopt(m_trim_threshold, 1 << 30))
    try:
        yield applied
    finally:
        if applied:
            mallopt(m_mmap_threshold, 32 << 20)
            mallopt(m_trim_threshold, 64 << 20)
            mallopt(m_mmap_max, 65536)


def _renderer(config: EvalConfig, background: tuple[float, float, float]):
    """A function that uploads a cloud once, a function (uploaded, camera) -> (image, seconds),
    the device's name and the identity of the renders (what a cached render depends on)."""
    from . import cameras, render, views
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

    def identity() -> dict:
        import scipy
        import torch

        from .render import resolve_backend

        hardware = str(device.type)
        if device.type == "cuda":
            hardware += ":" + torch.cuda.get_device_name(device)
        return {"settings": asdict(settings), "backend": resolve_backend("auto", device),
                "device": hardware, "torch": torch.__version__, "numpy": np.__version__,
                "scipy": scipy.__version__,
                "code": code_fingerprint(render, cameras, views, sys.modules[__name__])}

    return upload, draw, str(device), identity


@dataclass
class _Framing:
    """One framing of a reference evaluation: its cameras and, once known, the reference's
    renders at them, with where they came from."""

    distance: float
    key: str | None = None
    cameras: list[Camera] = field(default_factory=list)
    renders: CachedRenders | None = None
    source: str = ""
    """"cache" (read from the render cache), "twin" (an identical framing judged before in this
    evaluation) or "" (rendered here)."""

    def title(self) -> str:
        first = self.cameras[0]
        size = f"{len(self.cameras)} views of {first.width}x{first.height}"
        if self.distance == 1.0:
            return f"judge the sampled framing, {size}"
        return f"judge close-ups at {self.distance:g} of the distance, {size}"


def evaluate_against_reference(model: GaussianCloud, reference: GaussianCloud,
                               config: EvalConfig | None = None) -> EvalReport:
    """Render both models at held-out views sampled around ``reference`` and compare, at the
    sampled framing and at each of ``config.closeups``.

    With ``config.cache`` the reference's renders come from (or go to) the render cache: the
    report is the same to the bit either way, ``seconds`` and ``render_seconds`` aside.
    """
    config = config or EvalConfig()
    progress = _stages(config)
    model.check_finite()
    reference.check_finite()
    start = time.perf_counter()
    stage = progress("prepare", None)
    upload, draw, device, identity = _renderer(config, config.background)
    framings = [_Framing(1.0)] + [_Framing(float(f)) for f in config.closeups]
    cache = RenderCache(config.cache) if config.cache is not None else None
    if cache is not None:
        _look_up(framings, cache, config, reference, identity())
    sampled_notes, centre = _place_cameras(framings, config, reference)
    for i, framing in enumerate(framings):  # a framing asked for twice is rendered once
        if framing.renders is None and any(f.distance == framing.distance for f in framings[:i]):
            framing.source, framing.key = "twin", None
    from_cache = sum(f.source == "cache" for f in framings)
    stage.done(f"{config.views} views around the reference" + (
        f"; its renders of {from_cache} of {len(framings)} framings from the cache"
        if from_cache else ""))

    ours, theirs = upload(model), None
    digest = cloud_digest(model) if _REMEMBERED else None
    pace = _Pace([(len(f.cameras), _Pace.work_of(f.cameras[0], 1 if f.source else 2))
                  for f in framings])
    reports = []
    for i, framing in enumerate(framings):
        if framing.source == "twin":
            framing.renders = next(f.renders for f in framings[:i]
                                   if f.distance == framing.distance)
        stage = progress(framing.title(), len(framing.cameras))
        pace.next_framing()
        prefix = "" if framing.distance == 1.0 else f"close_{framing.distance:g}_"
        first = framing.cameras[0]
        report = EvalReport("reference", first.width, first.height, device=device,
                            blur_variance=config.blur_variance, distance=framing.distance)
        drawn = []
        for k, camera in enumerate(framing.cameras):
            t0 = time.perf_counter()
            if framing.renders is not None:
                ref_image = framing.renders.images[k]
            else:
                theirs = theirs if theirs is not None else upload(reference)
                ref_image, _ = draw(theirs, camera)
                drawn.append(ref_image)
            image = _REMEMBERED.get(_drawn_key(digest, config, camera)) if digest else None
            if image is None:
                image, seconds = draw(ours, camera)
            else:
                seconds = 0.0
            report.views.append(_score(f"{prefix}view_{k:03d}", ref_image, image, seconds))
            _save_render(config, f"{prefix}view_{k:03d}.png", ref_image, image)
            pace.step(time.perf_counter() - t0)
            stage.update(1, eta_all=pace.eta())
        summary = f"PSNR {report.psnr:.2f} dB, SSIM {report.ssim:.4f}"
        wanted = (cache is not None and framing.key is not None) or any(
            f.source == "twin" and f.distance == framing.distance for f in framings[i + 1:])
        if framing.source == "cache":
            summary += "; the reference's renders from the cache"
        elif framing.renders is None and wanted:
            framing.renders = CachedRenders(framing.cameras, np.stack(drawn))
            if framing.distance == 1.0:  # what the close-ups need to be placed from this one
                framing.renders.notes = sampled_notes
                framing.renders.extra = {"centre": centre}
            if cache is not None and framing.key is not None:
                problem = cache.put(framing.key, framing.renders)
                if problem:
                    stage.note(problem)
        stage.done(summary)
        reports.append(report)
    report = reports[0]
    report.closeups = reports[1:]
    report.seconds = time.perf_counter() - start
    return report


def reference_framing(reference: GaussianCloud, config: EvalConfig,
                      distance: float) -> CachedRenders:
    """The reference's renders (and cameras) at one framing of :func:`evaluate_against_reference`
    with ``config``: the sampled one (``distance`` 1) or the close-up at ``distance`` (its side
    ``config.closeup_resolution``). From ``config.cache`` when it holds them, else rendered and
    stored there under the key the evaluation uses, so an encode that judges close-ups and a
    later ``spcodec eval`` share them, bit for bit."""
    reference.check_finite()
    upload, draw, _, identity = _renderer(config, config.background)
    framings = [_Framing(1.0)] + ([_Framing(float(distance))] if distance != 1.0 else [])
    cache = RenderCache(config.cache) if config.cache is not None else None
    if cache is not None:
        _look_up(framings, cache, config, reference, identity())
    wanted = framings[-1]
    if wanted.renders is not None:
        return wanted.renders
    notes, centre = _place_cameras(framings, config, reference)
    params = upload(reference)
    renders = CachedRenders(wanted.cameras, np.stack([draw(params, c)[0] for c in wanted.cameras]))
    if distance == 1.0:  # as the evaluation stores its sampled framing
        renders.notes, renders.extra = notes, {"centre": centre}
    if cache is not None and wanted.key is not None:
        cache.put(wanted.key, renders)  # a cache that cannot be written only costs time
    return renders


def render_views(model: GaussianCloud, cameras: list[Camera], config: EvalConfig,
                 remember: bool = False) -> list[np.ndarray]:
    """``model`` rendered at ``cameras`` exactly as the evaluation renders it with ``config``
    (device, low-pass, antialiasing, background), uploaded once. ``remember``: keep these
    renders (of this one scene only) for a later :func:`evaluate_against_reference` of the same
    scene at the same cameras, which then does not draw them again."""
    upload, draw, _, _ = _renderer(config, config.background)
    params = upload(model)
    images = [draw(params, camera)[0] for camera in cameras]
    if remember:
        _REMEMBERED.clear()
        digest = cloud_digest(model)
        _REMEMBERED.update({_drawn_key(digest, config, c): image
                            for c, image in zip(cameras, images)})
    return images


_REMEMBERED: dict[tuple, np.ndarray] = {}
"""The last remembered scene's renders (:func:`render_views`): a quality target verifies its
answer at the close-up the closing evaluation then draws again, seconds per view."""


def _drawn_key(digest: str, config: EvalConfig, camera: Camera) -> tuple:
    """What a render depends on: the scene's content (its ``digest``), how it is drawn, the
    view."""
    return (digest, config.device, tuple(config.background), config.antialiased,
            config.blur_variance, camera.width, camera.height, camera.fx, camera.fy, camera.cx,
            camera.cy, camera.world_to_camera.tobytes())


def _look_up(framings: list[_Framing], cache: RenderCache, config: EvalConfig,
             reference: GaussianCloud, renderer: dict) -> None:
    """Set each framing's cache key, and its renders where the cache holds them."""
    from .views import parse_up

    common = {"reference": cloud_digest(reference), "renderer": renderer,
              "views": config.views, "resolution": config.resolution,
              "up": parse_up(config.up).tolist(), "seed": config.seed, "split": "eval"}
    for framing in framings:
        near = framing.distance != 1.0
        framing.key = cache_key({**common, "distance": framing.distance,
                                 "closeup_resolution": config.closeup_resolution if near
                                 else None})
        framing.renders = cache.get(framing.key)
        framing.source = "cache" if framing.renders is not None else ""


def _place_cameras(framings: list[_Framing], config: EvalConfig, reference: GaussianCloud
                   ) -> tuple[list[str], np.ndarray | None]:
    """Give every framing its cameras: those its cached renders were made at, else sampled
    around ``reference`` (or taken from the cached sampled framing) and brought nearer. Returns
    the view-sampling warnings (repeated when served from the cache) and the centre the
    close-ups dolly towards."""
    from .views import ViewSamplingWarning, robust_bounds, sample_views

    sampled = framings[0].renders
    notes: list[str] = list(sampled.notes) if sampled is not None else []
    centre = None
    if sampled is not None and "centre" in sampled.extra:
        centre = np.asarray(sampled.extra["centre"], dtype=np.float64)
    cameras = sampled.cameras if sampled is not None else []
    if all(f.renders is not None for f in framings) or (sampled is not None and
                                                         centre is not None):
        for note in notes:  # the views were sampled before: say what sampling said then
            warnings.warn(note, ViewSamplingWarning, stacklevel=3)
    else:
        bounds = robust_bounds(reference)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            cameras = sample_views(reference, config.views,
                                   resolution=(config.resolution, config.resolution),
                                   split="eval", seed=config.seed, up=config.up, bounds=bounds)
        for w in caught:  # shown as if not caught, and remembered with the renders
            warnings.warn(w.message, w.category, stacklevel=3)
        notes = [str(w.message) for w in caught if issubclass(w.category, ViewSamplingWarning)]
        centre = bounds.centre  # what the sampled views look at
    zoom = config.closeup_resolution / config.resolution
    for framing in framings:
        if framing.renders is not None:
            framing.cameras = framing.renders.cameras
        elif framing.distance == 1.0:
            framing.cameras = cameras
        else:
            framing.cameras = [c.scaled(zoom).dollied(centre, framing.distance) for c in cameras]
    return notes, centre


class _Pace:
    """Seconds left for an evaluation of several framings, each of views of one cost.

    The framing in progress is extrapolated from its own views; the framings to come from the
    seconds per unit of work so far, a view costing ``renders * (pixels + FIXED_PIXELS)``: a
    render's cost grows with its pixels, plus a part that does not (projecting every Gaussian,
    scoring). Measured on guitar, a close-up view twice as wide as a sampled one costs 2-3x
    as much, not 4x."""

    FIXED_PIXELS = 400 * 400

    def __init__(self, framings: list[tuple[int, float]]) -> None:
        """``framings``: (views, work of one view) of each framing, in the order judged."""
        self.framings = framings
        self.current = -1
        self.seconds = self.work = 0.0
        self.here: list[float] = []

    @classmethod
    def work_of(cls, camera: Camera, renders: int) -> float:
        return renders * (camera.width * camera.height + cls.FIXED_PIXELS)

    def next_framing(self) -> None:
        self.current += 1
        self.here = []

    def step(self, seconds: float) -> None:
        self.here.append(seconds)
        self.seconds += seconds
        self.work += self.framings[self.current][1]

    def eta(self) -> float:
        if not self.here:
            return math.nan
        views, _ = self.framings[self.current]
        left = (views - len(self.here)) * (sum(self.here) / len(self.here))
        later = sum(n * work for n, work in self.framings[self.current + 1:])
        return left + later * self.seconds / self.work


def evaluate_against_dataset(model: GaussianCloud, dataset_path: Path,
                             config: EvalConfig | None = None) -> EvalReport:
    """Render ``model`` at the dataset's test views and compare with its images.

    Warns (:class:`DatasetMismatchWarning`) when the mean PSNR says model and images do not match.
    """
    from .datasets import load_dataset

    config = config or EvalConfig()
    progress = _stages(config)
    model.check_finite()
    start = time.perf_counter()
    stage = progress("prepare", None)
    dataset = load_dataset(dataset_path, downscale=config.downscale)
    views = dataset.test[:config.max_views] if config.max_views else dataset.test
    upload, draw, device, _ = _renderer(config, dataset.background)
    params = upload(model)
    stage.done(f"{len(views)} test views of {dataset_path}")
    first = views[0].camera
    report = EvalReport("dataset", first.width, first.height, device=device,
                        blur_variance=config.blur_variance)
    stage = progress(f"judge {len(views)} test views of {first.width}x{first.height}",
                     len(views))
    pace = _Pace([(len(views), 1.0)])
    pace.next_framing()
    for view in views:
        t0 = time.perf_counter()
        photo = view.load_image()
        image, seconds = draw(params, view.camera)
        report.views.append(_score(view.name, photo, image, seconds, view.valid_mask()))
        _save_render(config, f"{Path(view.name).stem}.png", photo, image)
        pace.step(time.perf_counter() - t0)
        stage.update(1, eta_all=pace.eta())
    stage.done(f"PSNR {report.psnr:.2f} dB, SSIM {report.ssim:.4f}")
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
