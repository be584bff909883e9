"""Below the preset's file a size target weighs every Gaussian at a coarse precision, fewer
Gaussians at precisions between, and the preset's precision pruned, on renders
(encoder/sizing.py ``SizeTarget._best_below``)."""

from __future__ import annotations

import dataclasses
import types

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from spcodec.encoder import sizing as sizing_module
from spcodec.encoder.config import EncoderConfig, PatchConfig
from spcodec.encoder.patch import PatchEncoder
from spcodec.encoder.presets import preset_config, sized

PATCH, PRUNED = 100, 30


@dataclasses.dataclass(frozen=True)
class Point:
    """A stand-in for a point of the precision curve, told apart by the budget that chose it."""

    budget: float

    def patch_config(self, base: PatchConfig) -> PatchConfig:
        return base

    def describe(self) -> dict:
        return {"budget": self.budget}


class Curve:
    """A stand-in precision search: the point for a budget is that budget."""

    def for_bytes(self, budget: float) -> Point:
        return Point(budget)


@settings(max_examples=60, deadline=None)
@given(st.booleans(), st.lists(st.integers(0, 2 * PATCH), min_size=sizing_module.PRUNED_STEPS - 1,
                               max_size=sizing_module.PRUNED_STEPS - 1),
       st.lists(st.floats(10.0, 60.0), min_size=sizing_module.PRUNED_STEPS + 1,
                max_size=sizing_module.PRUNED_STEPS + 1, unique=True))
def test_the_file_that_renders_closest_is_kept(every, counts, scores):
    """Counts between the preset's pruned file and every Gaussian, spaced geometrically, each at
    the precision that would fit it, are pruned to the target; a count that keeps no more than the
    preset's pruned file, or every Gaussian, is no candidate. Of the rest, every Gaussian at
    the fitting precision and the preset's pruned file, the best rendered score wins."""
    assert sizing_module.PRUNED_STEPS - 1 == len(counts)
    planned = iter(counts)
    rendered: list[list[bytes]] = []
    config = sized(preset_config("balanced", EncoderConfig()), 10**6)
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(sizing_module, "plan_count",
                      lambda *args, **kw: types.SimpleNamespace(count=next(planned)))
        patch.setattr(sizing_module, "pruned_file", lambda writer, encoder, cloud, weights, n:
                      types.SimpleNamespace(data=f"{n}".encode()))
        patch.setattr(sizing_module.SizeTarget, "_render_psnr",
                      lambda self, files: rendered.append(list(files)) or scores[:len(files)])
        target = sizing_module.SizeTarget(config, None, "cpu")
        record: dict = {}
        chosen, count, data = target._best_below(
            Curve(), Point(-1.0), Point(0.0) if every else None, b"every" if every else None,
            50.0, None, PatchEncoder(config.patch), list(range(PATCH)), None, PRUNED, record)
    steps = sizing_module.PRUNED_STEPS
    shares = [(PRUNED / PATCH) ** (1 - step / steps) for step in range(1, steps)]
    between = [(Point(50.0 / share), n) for share, n in zip(shares, counts) if PRUNED < n < PATCH]
    expected = ([(Point(0.0), PATCH, b"every")] if every else []) + \
        [(point, n, f"{n}".encode()) for point, n in between]
    if not expected:
        assert (chosen, count, data) == (None, PRUNED, None) and rendered == []
        return
    expected.append((None, PRUNED, f"{PRUNED}".encode()))
    assert rendered == [[file for _, _, file in expected]]
    best = max(range(len(expected)), key=lambda i: scores[i])
    assert (chosen, count, data) == expected[best]
    assert [c["gaussians"] for c in record["candidates"]] == [n for _, n, _ in expected]


@settings(max_examples=30, deadline=None)
@given(st.integers(1, 2 * PATCH), st.floats(10.0, 60.0), st.floats(10.0, 60.0))
def test_a_gap_in_the_curve_is_filled_by_the_next_point_pruned_when_it_renders_closer(
        count, every_score, pruned_score):
    """Above the preset's file, where the allocation that fits lands more than 3 % under the
    target and the next one is over it, that next allocation pruned to the target competes on
    renders with every Gaussian at the one that fits (``SizeTarget._fill_gap``). The next
    allocation's file of every Gaussian, already written, is not written again."""
    config = sized(preset_config("balanced", EncoderConfig()), 10**6)
    rendered: list[list[bytes]] = []
    full_sizes: list[int] = []

    def plan_count(target, patch_count, size, tolerance):
        full_sizes.append(size(patch_count))
        return types.SimpleNamespace(count=count)

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(sizing_module, "plan_count", plan_count)
        patch.setattr(sizing_module, "pruned_file", lambda writer, encoder, cloud, weights, n:
                      types.SimpleNamespace(data=f"{n}".encode()))
        patch.setattr(sizing_module.SizeTarget, "_render_psnr",
                      lambda self, files: rendered.append(list(files)) or
                      [every_score, pruned_score][:len(files)])
        target = sizing_module.SizeTarget(config, None, "cpu")
        record: dict = {}
        chosen, kept, data = target._fill_gap(Point(1.0), b"every", Point(2.0), 12_345, None,
                                              PatchEncoder(config.patch), list(range(PATCH)),
                                              None, record)
    assert full_sizes == [12_345]
    if count >= PATCH:  # the next point fits whole: nothing to prune, nothing rendered
        assert (chosen, kept, data) == (Point(1.0), PATCH, b"every") and rendered == []
        return
    assert rendered == [[b"every", f"{count}".encode()]]
    assert [c["gaussians"] for c in record["gap"]] == [PATCH, count]
    expected = (Point(2.0), count, f"{count}".encode()) if pruned_score > every_score else \
        (Point(1.0), PATCH, b"every")
    assert (chosen, kept, data) == expected
