"""The error budget's check of the search's distortion model (bench/bench_budget.py): which row
is which searched quantity, the viewer's error on the search's scale, and their ratio."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))
import bench_budget  # noqa: E402  (bench/ is not a package)

PREDICTED = {"POSITION": 2e-6, "SCALE": 3e-6, "ROTATION": 1e-6, "OPACITY": 0.0,
             "COLOR_DC": 2e-6, "SH_BAND_2": 5e-7}


def row(label: str) -> dict:
    return {"scene": "s", "quantity": label}


def test_every_searched_row_names_the_quantity_the_search_chose():
    assert bench_budget.searched_quantity("patch positions") == "POSITION"
    assert bench_budget.searched_quantity("patch quats (codebooks)") == "ROTATION"
    assert bench_budget.searched_quantity("patch SH band 2 (codebooks)") == "SH_BAND_2"
    assert bench_budget.searched_quantity("patch sh_rest (codebooks)") is None
    assert bench_budget.searched_quantity("sketch positions (Draco)") is None


@given(st.floats(20, 120), st.floats(20, 120))
def test_the_viewers_error_is_summed_over_its_framings_as_the_search_sums_its_own(orbit, close):
    mse = bench_budget.viewer_mse({"orbit": orbit, "close": close})
    assert mse == pytest.approx(10 ** (-orbit / 10) + 10 ** (-close / 10))
    assert bench_budget.viewer_mse({"orbit": orbit, "close": math.inf}) == \
        pytest.approx(10 ** (-orbit / 10))


def test_a_row_carries_its_prediction_and_the_ratio_the_viewer_sees():
    seen = {"orbit": 50.0, "close": 47.0}
    out = bench_budget.with_prediction(row("patch scales (codebooks)"), PREDICTED, seen)
    assert out["predicted_mse"] == 3e-6
    assert out["viewer_mse"] == pytest.approx(1e-5 + 10 ** -4.7)
    assert out["viewer_over_predicted"] == pytest.approx(out["viewer_mse"] / 3e-6)
    whole = bench_budget.with_prediction(row("the whole file"), PREDICTED, seen)
    assert whole["predicted_mse"] == pytest.approx(sum(PREDICTED.values()))


def test_rows_the_search_did_not_choose_and_exact_options_carry_no_ratio():
    seen = {"orbit": 60.0, "close": 55.0}
    assert "predicted_mse" not in bench_budget.with_prediction(row("patch sh_rest (codebooks)"),
                                                               PREDICTED, seen)
    assert "predicted_mse" not in bench_budget.with_prediction(row("the whole file"), {}, seen)
    exact = bench_budget.with_prediction(row("patch opacities (codebooks)"), PREDICTED, seen)
    assert exact["predicted_mse"] == 0.0 and exact["viewer_over_predicted"] is None
