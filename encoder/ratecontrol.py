"""Rate control: ``--target-size SIZE`` writes a file of at most SIZE bytes, within 1 % of it
where the scene allows, or says why it cannot.

The target is a budget (a download, a quota, a quarter of another codec's file): a file over it
is a broken promise however small the excess, and one far under it wastes bytes that would have
bought Gaussians. So every size the encoder fits against is a real write, and the last word is
a trim that only ever removes the least important Gaussians.

The size of a file is the sketch and headers (fixed once categorization is done) plus the patch,
which grows almost linearly with the number of patch Gaussians for given codebook settings. So
the one free knob is how many patch Gaussians survive pruning:

1. **Predict** (:func:`plan_count`): write trial files of the pruned patch without retraining
   (real codebooks, real Draco and zlib) and solve for the count whose file hits the target by
   interpolation within a shrinking bracket (sizes are not quite linear in the count: codebooks
   grow until they hold their 256 entries), usually in two or three trials.
2. **Retrain** more Gaussians than predicted (:data:`TRAIN_MARGIN`, or :data:`SNAP_MARGIN` when
   retraining snaps to codebooks): retraining changes the statistics, and surplus is cheap to
   drop later while a shortfall cannot be made up.
3. **Fit** (:func:`fit_count`): keep the most important Gaussians whose file is the largest at
   or under the target, searched over real writes (indices and positions only: no k-means).
   With snapping this happens when snapping starts, on the file its codebooks make, so most
   training steps come after the drop; otherwise after retraining and quantization.
4. **Trim**: the finish moves codebook entries and indices, so the final file can grow past the
   target; then the least important Gaussians go until it fits again, with the per-prefix
   PSNR table the metadata then records counted in (``SceneWriter.with_prefix_psnr``; without
   it a small file could end a few bytes over). A file that comes out under stays so, since
   dropped Gaussians cannot come back (on the shared scenes at a quarter of SPZ the finish shrank
   every file, which ended 0.1-2.3 % under: docs/LOG.md 13.15).

The predicted and actual sizes are both reported.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Callable

from spcodec.errors import UsageError

TOLERANCE = 0.05
"""How near the target the *prediction* (:func:`plan_count`) must land before retraining; the
trained file is then fitted to the target exactly (:func:`fit_count`)."""

FIT_SLACK = 0.01
"""A fitted file is at most the target and, when the patch has Gaussians enough, no more than
this fraction under it (the search stops there rather than bisecting to the last Gaussian)."""

TRAIN_MARGIN = 0.06
"""Retrain this fraction more Gaussians than predicted (dropped again by :func:`fit_count`)."""

SNAP_MARGIN = 0.25
"""The margin when retraining snaps to codebooks: the count is fitted when snapping starts, with
most steps still to come, and retrained attributes code larger than the untrained ones the
prediction wrote (22 % on fourth_st, docs/LOG.md 11.4), so start well above the prediction."""

MAX_TRIALS = 8
"""Trial writes :func:`plan_count` makes at most (interpolation steps within a bracket)."""

MIN_PATCH = 16
"""Fewer patch Gaussians than this is not a scene any more: the target is too small."""

_SIZE = re.compile(r"^\s*([0-9]*\.?[0-9]+)\s*([kmg]i?)?b?\s*$", re.IGNORECASE)
_UNITS = {"": 1, "k": 1000, "m": 1000 ** 2, "g": 1000 ** 3,
          "ki": 1024, "mi": 1024 ** 2, "gi": 1024 ** 3}


def parse_size(text: str) -> int:
    """Bytes from ``"150k"``, ``"2MB"``, ``"1.5M"``, ``"300000"`` or ``"512KiB"`` (k and M are
    decimal; KiB and MiB binary)."""
    match = _SIZE.match(str(text))
    if not match:
        raise UsageError(f"cannot read a size from {text!r}: use e.g. 150k, 2MB or 300000")
    value = float(match.group(1)) * _UNITS[(match.group(2) or "").lower()]
    if value < 1:
        raise UsageError(f"target size must be at least 1 byte, got {text!r}")
    return int(round(value))


def within(size: int, target: int, tolerance: float = TOLERANCE) -> bool:
    """Whether ``size`` is within ``tolerance`` (a fraction) of ``target`` either way."""
    return abs(size - target) <= tolerance * target


@dataclass
class RatePlan:
    """The count of patch Gaussians predicted to hit the target, and what was learnt doing it."""

    count: int
    predicted_bytes: int
    fixed_bytes: int
    """The file with no patch Gaussian at all (sketch, headers, metadata)."""
    full_bytes: int
    """The file with every patch Gaussian (no pruning)."""
    note: str = ""


def plan_count(target: int, patch_count: int, trial: Callable[[int], int],
               tolerance: float = TOLERANCE) -> RatePlan:
    """Patch Gaussians to keep so that a file written by ``trial(count)`` is ``target`` bytes,
    give or take ``tolerance`` (a fraction: loose before retraining, which changes the sizes
    anyway; tight when the trial's file is the one written).

    ``trial`` must write a real file with the ``count`` most important patch Gaussians and return
    its size. Raises a UsageError when the target is below what the scene can reach.
    """
    fixed = trial(0)
    fewest = min(MIN_PATCH, patch_count)
    smallest = trial(fewest) if patch_count else fixed
    if target < smallest:
        raise UsageError(f"target size {target:,} bytes is too small for this scene: the sketch "
                         f"layer and headers alone take {fixed:,} bytes and the smallest useful "
                         f"file ({fewest} patch Gaussians) {smallest:,}; "
                         f"ask for at least {smallest:,} bytes")
    full = trial(patch_count)
    if target >= full:
        note = "" if within(full, target, tolerance) else (
            f"target {target:,} bytes is above the unpruned encode ({full:,} bytes): every patch "
            "Gaussian is kept and the file stays smaller than the target")
        return RatePlan(patch_count, full, fixed, full, note)
    # the first patch Gaussian brings the codebooks, a step in size: interpolate from past it
    lo, hi = ((fewest, smallest) if smallest < target else (0, fixed)), (patch_count, full)
    best = min([hi, lo] if lo[0] else [hi], key=lambda known: abs(known[1] - target))
    above, streak = None, 0  # which side of the target the last trials landed, how many in a row
    for _ in range(MAX_TRIALS):
        count = _interpolate(target, *lo, *hi)
        # the line points at a known end, or it keeps landing on one side (sizes bend: codebooks
        # fill up with the first few hundred Gaussians, so it creeps up on the target): bisect
        if not lo[0] < count < hi[0] or streak >= 2:
            count = (lo[0] + hi[0]) // 2
        if count in (lo[0], hi[0]):
            break
        size = trial(count)
        if abs(size - target) < abs(best[1] - target):
            best = (count, size)
        if within(size, target, tolerance):
            break
        streak = streak + 1 if (size > target) == above else 1
        above = size > target
        lo, hi = (lo, (count, size)) if above else ((count, size), hi)
    return RatePlan(best[0], best[1], fixed, full)


def fit_count(target: int, upper: int, size_of: Callable[[int], int]) -> tuple[int, int]:
    """``(count, size_of(count))`` for the largest count in ``1..upper`` whose file is at most
    ``target`` bytes; the search stops early at a count within :data:`FIT_SLACK` under it.

    ``size_of`` must write a real file (sizes grow with the count, up to compression noise: the
    result is always a measured size at or under the target, never an extrapolation). Sizes are
    nearly linear in the count, so interpolation aimed at the middle of the window usually lands
    in two or three writes; it falls back to bisection when it keeps landing on one side. When
    even one Gaussian does not fit, ``(1, size)`` comes back over the target (the caller's plan
    has refused such targets before).
    """
    size = size_of(upper)
    if size <= target:
        return upper, size
    lo, lo_size = 1, size_of(1)
    if lo_size > target:
        return lo, lo_size
    hi, hi_size = upper, size
    aim = target * (1 - FIT_SLACK / 2)
    above, streak = None, 0
    while hi - lo > 1:
        count = _interpolate(aim, lo, lo_size, hi, hi_size)
        if not lo < count < hi or streak >= 2:
            count = (lo + hi) // 2
        size = size_of(count)
        streak = streak + 1 if (size > target) == above else 1
        above = size > target
        if above:
            hi, hi_size = count, size
        else:
            lo, lo_size = count, size
            if size >= target * (1 - FIT_SLACK):
                break
    return lo, lo_size


def _interpolate(target: float, n0: int, s0: int, n1: int, s1: int) -> int:
    """The count where the line through (n0, s0) and (n1, s1) reaches ``target``."""
    if s1 == s0:
        return n1
    count = n0 + (target - s0) * (n1 - n0) / (s1 - s0)
    return int(min(max(round(count), 1), max(n0, n1)))
