"""Polynomial models of position, as the bitstream defines them (spec section 6.3, [R-40]..[R-44]).

A sketch cluster stores, for each modelled attribute, a matrix of float16 coefficients ``C`` of shape
``(M(d), O)``: ``M(d) = (d+1)(d+2)(d+3)/6`` monomials of total degree <= ``d`` in the three normalized
coordinates, times ``O`` outputs. The value at normalized position ``X`` is ``phi(X) @ C``.

The monomial order is *graded lexicographic* ([R-41]): by total degree ``t = 0..d``; within a degree,
by decreasing exponent of x, then decreasing exponent of y; the exponent of z is what remains. For
d = 2 that is ``1, x, y, z, x^2, xy, xz, y^2, yz, z^2`` (the order of scikit-learn's
``PolynomialFeatures``). Because the order is graded, the features of degree ``d`` are a prefix of
those of any higher degree, so one feature matrix serves every attribute of a cluster.

Evaluation is in float64 ([R-43]); encoder and decoder both call :func:`evaluate`, so the encoder
measures exactly what a decoder produces.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

MAX_DEGREE = 10
"""Highest polynomial degree the format allows."""

_ROWS_PER_CHUNK = 1 << 15


def monomial_count(degree: int) -> int:
    """Number of monomials of total degree <= ``degree`` in three variables."""
    return (degree + 1) * (degree + 2) * (degree + 3) // 6


@lru_cache(maxsize=None)
def monomial_exponents(degree: int) -> np.ndarray:
    """(M, 3) int array of exponents (i, j, k) of x^i y^j z^k in the normative order."""
    if not 0 <= degree <= MAX_DEGREE:
        raise ValueError(f"polynomial degree {degree} outside 0..{MAX_DEGREE}")
    rows = [
        (i, j, t - i - j)
        for t in range(degree + 1)
        for i in range(t, -1, -1)
        for j in range(t - i, -1, -1)
    ]
    out = np.array(rows, dtype=np.int64).reshape(-1, 3)
    out.setflags(write=False)
    return out


def degree_for_count(count: int) -> int | None:
    """The degree whose monomial count is ``count``, or None."""
    for d in range(MAX_DEGREE + 1):
        if monomial_count(d) == count:
            return d
    return None


def normalize_positions(positions: np.ndarray, center: np.ndarray,
                        half_extent: np.ndarray) -> np.ndarray:
    """Map positions into the cluster's normalized frame, ``(p - center) / half_extent``, float64."""
    p = np.asarray(positions, dtype=np.float64)
    c = np.asarray(center, dtype=np.float32).astype(np.float64)
    h = np.asarray(half_extent, dtype=np.float32).astype(np.float64)
    return (p - c) / h


def features(x: np.ndarray, degree: int) -> np.ndarray:
    """Monomial feature matrix (n, M(degree)) in float64 for normalized positions ``x`` (n, 3).

    Built a degree at a time: in the graded lexicographic order the degree-t block is ``x *`` the
    whole degree t-1 block, then ``y *`` its x-free tail (the last t entries), then ``z *`` its
    last entry. Three broadcast products per degree instead of one product per column.
    """
    x = np.asarray(x, dtype=np.float64)
    out = np.empty((x.shape[0], monomial_count(degree)), order="F")
    out[:, 0] = 1.0
    prev, stop = 0, 1
    for t in range(1, degree + 1):
        width = stop - prev
        out[:, stop:stop + width] = out[:, prev:stop] * x[:, :1]
        out[:, stop + width:stop + width + t] = out[:, stop - t:stop] * x[:, 1:2]
        out[:, stop + width + t] = out[:, stop - 1] * x[:, 2]
        prev, stop = stop, stop + width + t + 1
    return out


def evaluate(x: np.ndarray, coefficients: np.ndarray) -> np.ndarray:
    """Evaluate a model: ``features(x) @ coefficients`` in float64, in bounded-memory chunks.

    ``coefficients`` has shape (M(d), O) and any float dtype (float16 in files); the result is
    (n, O) float64.
    """
    coeffs = np.asarray(coefficients).astype(np.float64)
    degree = degree_for_count(coeffs.shape[0])
    if degree is None:
        raise ValueError(f"{coeffs.shape[0]} coefficients match no polynomial degree")
    x = np.asarray(x, dtype=np.float64)
    out = np.empty((x.shape[0], coeffs.shape[1]), dtype=np.float64)
    for start in range(0, x.shape[0], _ROWS_PER_CHUNK):
        stop = start + _ROWS_PER_CHUNK
        out[start:stop] = features(x[start:stop], degree) @ coeffs
    return out
