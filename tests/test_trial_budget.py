"""The size target's trial budgets (encoder/sizing.py, _size_line): how the bytes of the
precision search's trial files steer the next trial's budget."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from spcodec.encoder.sizing import SLOPE_RANGE, _size_line

bytes_ = st.floats(1e3, 1e7)


@settings(max_examples=300, deadline=None)
@given(intercept=st.floats(0, 1e5), slope=st.floats(SLOPE_RANGE[0] * 1.01, SLOPE_RANGE[1] * 0.99),
       b0=bytes_, step=st.floats(0.01, 0.5), other=st.floats(0, 1e5))
def test_two_trials_on_a_line_give_that_line(intercept, slope, b0, step, other):
    """Files whose bytes are a line of the predicted bytes: two trials find it, so the next
    budget lands a third trial exactly on its aim."""
    b1 = b0 * (1 + step)
    measured = [(b0, intercept + slope * b0), (b1, intercept + slope * b1)]
    got_intercept, got_slope = _size_line(measured, other)
    aim = intercept + slope * b0 * 1.3
    budget = (aim - got_intercept) / got_slope
    assert intercept + slope * budget == pytest.approx(aim, rel=1e-6)


@settings(max_examples=200, deadline=None)
@given(b=bytes_, size=st.integers(1, 10**7), other=st.floats(0, 1e5))
def test_one_trial_rescales_by_its_miss_through_the_presets_other_bytes(b, size, other):
    """After one trial the budget is rescaled by its miss, ``other`` kept: the same budget
    comes back on the trial's own bytes."""
    got_other, ratio = _size_line([(b, size)], other)
    assert got_other == other
    assert ratio > 0
    if size - other >= 1:
        assert other + ratio * b == pytest.approx(size)


def test_trials_too_close_to_measure_a_slope_keep_the_last_miss():
    """Two trials whose sizes rose against their predictions (a slope outside SLOPE_RANGE, or
    none) say nothing of the line: the last trial's miss rescales, as after one."""
    other = 10_000.0
    for measured in ([(100_000.0, 90_000), (100_000.0, 95_000)],
                     [(100_000.0, 90_000), (100_100.0, 95_000)],
                     [(100_000.0, 95_000), (110_000.0, 90_000)]):
        assert _size_line(measured, other) == _size_line(measured[-1:], other)
