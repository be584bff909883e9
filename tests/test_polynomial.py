"""The polynomial basis the spec fixes ([R-40]..[R-43])."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from spcodec.polynomial import (
    MAX_DEGREE,
    degree_for_count,
    evaluate,
    features,
    monomial_count,
    monomial_exponents,
    normalize_positions,
)


def test_degree_two_order_is_the_spec_example():
    # 1, x, y, z, x^2, xy, xz, y^2, yz, z^2
    expected = [(0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1), (2, 0, 0), (1, 1, 0), (1, 0, 1),
                (0, 2, 0), (0, 1, 1), (0, 0, 2)]
    assert [tuple(r) for r in monomial_exponents(2)] == expected


@pytest.mark.parametrize("degree", range(MAX_DEGREE + 1))
def test_counts_and_graded_prefix(degree):
    exps = monomial_exponents(degree)
    assert len(exps) == monomial_count(degree) == (degree + 1) * (degree + 2) * (degree + 3) // 6
    assert len({tuple(r) for r in exps}) == len(exps)          # no monomial twice
    assert exps.sum(axis=1).max(initial=0) == degree
    assert np.all(np.diff(exps.sum(axis=1)) >= 0)               # graded by total degree
    if degree:
        np.testing.assert_array_equal(exps[:monomial_count(degree - 1)],
                                      monomial_exponents(degree - 1))
    assert degree_for_count(len(exps)) == degree


def test_highest_degree_has_286_terms_and_others_are_rejected():
    assert monomial_count(10) == 286
    with pytest.raises(ValueError):
        monomial_exponents(11)
    assert degree_for_count(5) is None


@given(st.integers(0, MAX_DEGREE), st.integers(1, 40), st.integers(0, 2**31 - 1))
def test_evaluate_equals_explicit_sum(degree, n, seed):
    rng = np.random.default_rng(seed)
    x = rng.uniform(-1, 1, (n, 3))
    coeffs = rng.normal(size=(monomial_count(degree), 2)).astype(np.float16)
    exps = monomial_exponents(degree)
    explicit = np.zeros((n, 2))
    for (i, j, k), c in zip(exps, coeffs.astype(np.float64)):
        explicit += np.outer(x[:, 0] ** i * x[:, 1] ** j * x[:, 2] ** k, c)
    np.testing.assert_allclose(evaluate(x, coeffs), explicit, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(features(x, degree)[:, 0], 1.0)


def test_evaluate_chunks_large_inputs_consistently():
    rng = np.random.default_rng(0)
    x = rng.uniform(-1, 1, (70_000, 3))
    coeffs = rng.normal(size=(monomial_count(3), 1))
    np.testing.assert_allclose(evaluate(x, coeffs)[-5:], features(x[-5:], 3) @ coeffs)


def test_normalization_uses_float32_frame_and_float64_arithmetic():
    centre = np.array([0.1, 0.2, 0.3])
    half = np.array([0.5, 0.25, 2.0])
    p = np.array([[0.6, 0.45, 2.3]], dtype=np.float32)
    x = normalize_positions(p, centre, half)
    assert x.dtype == np.float64
    expected = (p.astype(np.float64) - centre.astype(np.float32)) / half.astype(np.float32)
    np.testing.assert_array_equal(x, expected)
