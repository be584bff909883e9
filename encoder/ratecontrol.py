"""Rate control: ``--target-size SIZE`` lands the file within 5 % of SIZE, or says why it cannot.

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
3. **Fit** (:func:`fit_count`): keep the most important Gaussians whose file is as close to the
   target as a bisection over real writes gets (indices and positions only: no k-means). With
   snapping this happens when snapping starts, on the file its codebooks make, so most training
   steps come after the drop; otherwise after retraining and quantization. Then check the final
   file once more and drop again if training or the finish moved it out of tolerance (the one
   correction).

The predicted and actual sizes are both reported.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Callable

from spcodec.errors import UsageError

TOLERANCE = 0.05
"""The file must end within this fraction of the target."""

TRAIN_MARGIN = 0.06
"""Retrain this fraction more Gaussians than predicted (dropped again by :func:`fit_count`)."""

SNAP_MARGIN = 0.25
"""The margin when retraining snaps to codebooks: the count is fitted when snapping starts, with
most steps still to come, and retrained attributes code larger than the untrained ones the
prediction wrote (22 % on fourth_st, docs/RESULTS.md 11.4), so start well above the prediction."""

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


def within(size: int, target: int) -> bool:
    return abs(size - target) <= TOLERANCE * target


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


def plan_count(target: int, patch_count: int, trial: Callable[[int], int]) -> RatePlan:
    """Patch Gaussians to keep so that a file written by ``trial(count)`` is ``target`` bytes.

    ``trial`` must write a real file with the ``count`` most important patch Gaussians and return
    its size. Raises a UsageError when the target is below what the scene can reach.
    """
    fixed = trial(0)
    fewest = min(MIN_PATCH, patch_count)
    smallest = trial(fewest) if patch_count else fixed
    if target < smallest * (1 - TOLERANCE):
        raise UsageError(f"target size {target:,} bytes is too small for this scene: the sketch "
                         f"layer and headers alone take {fixed:,} bytes and the smallest useful "
                         f"file ({fewest} patch Gaussians) {smallest:,}; "
                         f"ask for at least {smallest:,} bytes")
    full = trial(patch_count)
    if target >= full:
        note = "" if within(full, target) else (
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
        if within(size, target):
            break
        streak = streak + 1 if (size > target) == above else 1
        above = size > target
        lo, hi = (lo, (count, size)) if above else ((count, size), hi)
    return RatePlan(best[0], best[1], fixed, full)


def fit_count(target: int, upper: int, size_of: Callable[[int], int]) -> tuple[int, int]:
    """The count in ``1..upper`` whose ``size_of(count)`` (a real write) comes closest to
    ``target`` from below or within tolerance, by bisection (sizes grow with the count)."""
    size = size_of(upper)
    if size <= target * (1 + TOLERANCE):
        return upper, size
    lo, hi = 1, upper  # size_of(hi) is too large
    best = (lo, size_of(lo))
    while hi - lo > 1:
        mid = (lo + hi) // 2
        size = size_of(mid)
        if size > target * (1 + TOLERANCE):
            hi = mid
        else:
            lo, best = mid, (mid, size)
            if within(size, target) and size >= target:
                break
    return best


def _interpolate(target: int, n0: int, s0: int, n1: int, s1: int) -> int:
    """The count where the line through (n0, s0) and (n1, s1) reaches ``target``."""
    if s1 == s0:
        return n1
    count = n0 + (target - s0) * (n1 - n0) / (s1 - s0)
    return int(min(max(round(count), 1), max(n0, n1)))
