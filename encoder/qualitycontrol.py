"""Quality control: ``--target-psnr DB`` finds the smallest file whose close-up reaches DB.

Quality is judged where detail shows: by our renderer, at the evaluation's held-out views brought
to half their distance (800x800, the line ``spcodec eval`` prints as "at 0.5 of the distance"),
against the original rendered the same way. The knob is again how many patch Gaussians survive,
and every judgement is of a real file (real codebooks, Draco, zlib), decoded and rendered:

1. **Reach** (:func:`fewest_reaching`): files of the most important patch Gaussians coded
   without retraining, bisected for the fewest that reach the target. Without retraining that is
   the answer. When every patch Gaussian is kept and the file still falls short (by more than
   retraining can add), the target is out of reach and the error says what the best file
   reaches.
2. **Retrain** that many: retraining raises the quality a given count reaches, so the retrained
   patch clears the target with room to spare.
3. **Fit**: after retraining and quantization, bisect again over the trained Gaussians (the least
   important dropped first) for the fewest that still reach the target; the finish follows and
   only raises the quality further. A retrained patch that falls short with every Gaussian kept
   is written anyway (it is the best this encode makes), and the report says so.

Bisection stops once the bracket is within :data:`COUNT_TOLERANCE` of the patch (a handful of
judgements, each a few seconds of rendering).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from spcodec.cloud import GaussianCloud
from spcodec.errors import UsageError
from spcodec.imaging.metrics import psnr
from spcodec.imaging.render import GaussianParams, RenderSettings, render_image, resolve_device
from spcodec.imaging.views import robust_bounds, sample_views

CLOSEUP_DISTANCE = 0.5
"""The close-up framing the target is judged at: half the distance of the eval views."""

COUNT_TOLERANCE = 0.02
"""The bisection stops once the bracket spans at most this share of the patch Gaussians."""


class CloseupJudge:
    """Close-up PSNR of a scene against ``original``: ``spcodec eval``'s views at half their
    distance, ``resolution`` pixels across; the original's renders are made once."""

    def __init__(self, original: GaussianCloud, up: str = "-y", antialiased: bool = False,
                 device: str = "auto", views: int = 8, eval_resolution: int = 400,
                 resolution: int = 800, seed: int = 0) -> None:
        centre = robust_bounds(original).centre
        cameras = sample_views(original, views, resolution=(eval_resolution, eval_resolution),
                               split="eval", seed=seed, up=up)
        zoom = resolution / eval_resolution
        self.cameras = [c.scaled(zoom).dollied(centre, CLOSEUP_DISTANCE) for c in cameras]
        self.settings = RenderSettings(antialiased=antialiased)
        self.device = resolve_device(device)
        self.references = self._render(original)

    def __call__(self, scene: GaussianCloud) -> float:
        """Mean PSNR (dB) of ``scene`` over the close-up views."""
        return float(np.mean([psnr(r, s) for r, s in zip(self.references, self._render(scene))]))

    def _render(self, scene: GaussianCloud) -> list[np.ndarray]:
        params = GaussianParams.from_cloud(scene, self.device)
        return [render_image(params, camera, self.settings) for camera in self.cameras]


RETRAIN_HEADROOM = 1.0
"""How far (dB) above the best file without retraining a retrained encode is still tried: the
quantization-aware retrain of every patch Gaussian gains up to about this much."""


@dataclass
class QualityPlan:
    """The fewest patch Gaussians found to reach the target, and the judgements made."""

    count: int
    psnr: float
    """The close-up PSNR of the file with ``count`` patch Gaussians."""
    reached: bool
    """False: even every candidate kept falls short (``count`` is then all of them)."""
    judged: dict[int, float] = field(default_factory=dict)
    """Every count judged and its PSNR."""


def fewest_reaching(target: float, upper: int, psnr_of: Callable[[int], float]) -> QualityPlan:
    """The fewest of ``1..upper`` patch Gaussians whose file (``psnr_of(count)``, quality rising
    with the count) reaches ``target`` dB, to within :data:`COUNT_TOLERANCE` of ``upper``; all of
    them, not ``reached``, when even ``upper`` falls short."""
    judged = {upper: psnr_of(upper)}
    if judged[upper] < target:
        return QualityPlan(upper, judged[upper], False, judged)
    lo, hi = 0, upper  # lo: known (or assumed, at 0) to fall short; hi: known to reach
    slack = max(1, int(COUNT_TOLERANCE * upper))
    while hi - lo > slack:
        mid = (lo + hi) // 2
        judged[mid] = psnr_of(mid)
        if judged[mid] >= target:
            hi = mid
        else:
            lo = mid
    return QualityPlan(hi, judged[hi], True, judged)


def check_reachable(target: float, plan: QualityPlan, retraining: bool) -> None:
    """A one-line UsageError when ``target`` is beyond what the scene's best file reaches (the
    no-retrain ``plan`` of every patch Gaussian, plus :data:`RETRAIN_HEADROOM` with retraining)."""
    headroom = RETRAIN_HEADROOM if retraining else 0.0
    if plan.reached or plan.psnr + headroom >= target:
        return
    reach = f"{plan.psnr:.2f} dB" + (f" before retraining and about {plan.psnr + headroom:.1f} "
                                     "dB after" if retraining else "")
    raise UsageError(f"--target-psnr {target:g} dB is out of reach: with every patch Gaussian "
                     f"kept this scene reaches {reach} at the close-up framing; ask for at most "
                     "that, or for a finer preset (--preset highrate)")
