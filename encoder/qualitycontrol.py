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
judgements). The searches judge the close-ups at 400 pixels (:class:`TargetJudge`, a quarter of
the rendering), and the answer once more at the evaluation's 800, where the target is promised:
when it falls short there, the search goes on with the small views' offset corrected. The
original's close-ups come from the evaluation's render cache, and go to it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from spcodec.cloud import GaussianCloud
from spcodec.errors import UsageError
from spcodec.imaging.evaluate import EvalConfig, reference_framing, render_views
from spcodec.imaging.metrics import psnr
from spcodec.imaging.render.settings import BLUR_VARIANCE

CLOSEUP_DISTANCE = 0.5
"""The close-up framing the target is judged at: half the distance of the eval views."""

JUDGE_RESOLUTION = 400
"""Side (pixels) of the close-up views a quality target is searched with (:class:`TargetJudge`):
the evaluation's views dollied to half their distance without enlarging them."""

COUNT_TOLERANCE = 0.02
"""The bisection stops once the bracket spans at most this share of the patch Gaussians."""


class CloseupJudge:
    """Close-up PSNR of a scene against ``original``: ``spcodec eval``'s views at half their
    distance, ``resolution`` pixels across, rendered as the evaluation renders them.

    The original's renders come from the evaluation's render cache (``cache``, a folder, or
    None: made here), under the key ``spcodec eval --closeup-resolution RESOLUTION`` uses, so
    the judge and a later evaluation render the original once between them. Every call renders
    only the scene judged."""

    def __init__(self, original: GaussianCloud, up: str = "-y", antialiased: bool = False,
                 device: str = "auto", views: int = 8, eval_resolution: int = 400,
                 resolution: int = 800, seed: int = 0,
                 cache: Path | None = None) -> None:
        self.config = EvalConfig(views=views, resolution=eval_resolution, device=device, up=up,
                                 antialiased=antialiased, seed=seed,
                                 closeups=(CLOSEUP_DISTANCE,), closeup_resolution=resolution,
                                 blur_variance=BLUR_VARIANCE, cache=cache)
        framing = reference_framing(original, self.config, CLOSEUP_DISTANCE)
        self.cameras = framing.cameras
        self.references = list(framing.images)

    def __call__(self, scene: GaussianCloud) -> float:
        """Mean PSNR (dB) of ``scene`` over the close-up views."""
        drawn = render_views(scene, self.cameras, self.config)
        return float(np.mean([psnr(r, s) for r, s in zip(self.references, drawn)]))


class TargetJudge:
    """The judge a quality target searches with: close-ups at :data:`JUDGE_RESOLUTION`, a
    quarter of the evaluation's pixels (a quarter of its time), reported on the evaluation's scale.

    A file's close-up PSNR at 400 pixels was within 0.02 dB of the evaluation's at 800 on
    kacytran's files (docs/LOG.md), so a search judges the small views, less an offset that is
    0 until a file has been judged both ways. :meth:`verify` judges a file at the evaluation's
    own resolution (what the target is promised in) and takes the offset from it, so a search
    whose answer falls short there can go on with the prediction corrected."""

    def __init__(self, original: GaussianCloud, up: str = "-y", antialiased: bool = False,
                 device: str = "auto", cache: Path | None = None,
                 resolution: int = JUDGE_RESOLUTION, full_resolution: int = 800) -> None:
        self.search = CloseupJudge(original, up, antialiased, device, resolution=resolution,
                                   cache=cache)
        self._full_judge = (lambda: self.search) if resolution == full_resolution else (
            lambda: CloseupJudge(original, up, antialiased, device, resolution=full_resolution,
                                 cache=cache))
        self._full: CloseupJudge | None = None
        self.offset = 0.0
        self.full_judgements = 0

    def __call__(self, scene: GaussianCloud) -> float:
        """The predicted evaluation close-up PSNR (dB) of ``scene``."""
        return self.search(scene) - self.offset

    def verify(self, scene: GaussianCloud, predicted: float | None = None) -> float:
        """The evaluation's close-up PSNR of ``scene``, which also re-sets the offset.
        ``predicted``: what this judge said of ``scene`` (then it is not judged small again)."""
        if self._full is None:  # the original's renders at full size, when first needed
            self._full = self._full_judge()
        self.full_judgements += 1
        full = self._full(scene)
        if self._full is not self.search:
            searched = self.search(scene) if predicted is None else predicted + self.offset
            self.offset = searched - full
        return full


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


def fewest_reaching(target: float, upper: int, psnr_of: Callable[[int], float],
                    known: dict[int, float] | None = None) -> QualityPlan:
    """The fewest of ``1..upper`` patch Gaussians whose file (``psnr_of(count)``, quality rising
    with the count) reaches ``target`` dB, to within :data:`COUNT_TOLERANCE` of ``upper``; all of
    them, not ``reached``, when even ``upper`` falls short. ``known``: counts already judged (a
    caller that judged ``upper`` itself), which are not judged again."""
    judged = dict(known or {})
    if upper not in judged:
        judged[upper] = psnr_of(upper)
    if judged[upper] < target:
        return QualityPlan(upper, judged[upper], False, judged)
    lo, hi = 0, upper  # lo: known (or assumed, at 0) to fall short; hi: known to reach
    slack = max(1, int(COUNT_TOLERANCE * upper))
    while hi - lo > slack:
        mid = (lo + hi) // 2
        if mid not in judged:
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
