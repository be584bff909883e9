"""Entropy-constrained assignment (encoder/ecvq.py) and its use by the patch encoder: lambda 0 is
nearest assignment, a positive lambda never raises the Lagrangian, the SH zero entry, and files
that the existing decoder reads."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import spcodec
from spcodec.attributes import PatchAttribute
from spcodec.encoder.config import PatchConfig
from spcodec.encoder.ecvq import (
    code_lengths,
    ecvq_assign,
    ecvq_refine,
    lagrangian,
    with_zero_entry,
)
from spcodec.encoder.kmeans import nearest, sampled_codebook
from spcodec.encoder.patch import PatchEncoder, coded_attributes, quantized_cloud
from spcodec.synthetic import make_scene
from spcodec.writer import EncodedScene, build_bitstream


def problem(seed: int, n: int, dim: int, size: int):
    """Groups, heavy-tailed weights, distinct float16 entries and code lengths of a histogram."""
    rng = np.random.default_rng(seed)
    groups = rng.normal(0, 1, (n, dim)) * rng.choice([0.01, 1.0, 30.0])
    weights = rng.pareto(1.5, n) + 0.01
    entries = np.unique(rng.normal(0, 1, (size, dim)).astype(np.float16) * groups.std(), axis=0)
    lengths = code_lengths(rng.integers(0, len(entries), 3 * n) ** 2 % len(entries), len(entries))
    return groups, weights, entries, lengths


@given(st.integers(0, 2**31), st.integers(1, 400), st.integers(1, 6), st.integers(1, 256))
def test_lambda_zero_is_nearest_assignment(seed, n, dim, size):
    groups, weights, entries, lengths = problem(seed, n, dim, size)
    np.testing.assert_array_equal(ecvq_assign(groups, entries, weights, 0.0, lengths),
                                  nearest(groups, entries))


@given(st.integers(0, 2**31), st.integers(1, 400), st.integers(1, 6), st.integers(1, 256),
       st.floats(1e-6, 1e3))
def test_a_positive_lambda_never_raises_the_lagrangian(seed, n, dim, size, fraction):
    """Under the same code lengths, ECVQ's weighted error + lambda * bits is at most nearest
    assignment's (to rounding), for any lambda."""
    groups, weights, entries, lengths = problem(seed, n, dim, size)
    spread = float((weights * (groups ** 2).sum(axis=1)).mean())
    bit_cost = fraction * max(spread, 1e-12)
    ecvq = ecvq_assign(groups, entries, weights, bit_cost, lengths)
    near = nearest(groups, entries)
    a = lagrangian(groups, entries, weights, ecvq, bit_cost, lengths)
    b = lagrangian(groups, entries, weights, near, bit_cost, lengths)
    assert a <= b * (1 + 1e-9) + 1e-12, (a, b)


def test_refinement_trades_error_for_bits_monotonically_in_lambda():
    """Rounds of lengths, assignment and centroids: more lambda, fewer index bits (an entropy
    the Huffman code follows) for more error; small lambda costs almost no error."""
    rng = np.random.default_rng(4)
    groups = rng.standard_t(3, (30_000, 3)) * 0.1
    weights = rng.gamma(0.5, 2.0, len(groups))
    entries = sampled_codebook(groups, weights, 128, seed=0)
    near = nearest(groups, entries)
    base_bits = code_lengths(near, len(entries))[near].mean()
    base_error = lagrangian(groups, entries, weights, near, 0.0, np.zeros(len(entries)))
    bits, errors = [], []
    for bit_cost in (1e-5, 1e-4, 1e-3):
        book, idx = ecvq_refine(groups, entries, weights, bit_cost, 3)
        assert book.dtype == np.float16 and book.shape == entries.shape
        bits.append(code_lengths(idx, len(book))[idx].mean())
        errors.append(lagrangian(groups, book, weights, idx, 0.0, np.zeros(len(book))))
        again = ecvq_refine(groups, entries, weights, bit_cost, 3)  # deterministic
        np.testing.assert_array_equal(again[1], idx)
    assert base_bits > bits[0] > bits[1] > bits[2]
    assert errors[0] < errors[1] < errors[2]
    assert errors[0] < base_error * 1.05


@given(st.integers(0, 2**31), st.integers(1, 256), st.sampled_from([1, 9, 15, 21]))
def test_the_zero_entry_is_exact_and_fits_uint8(seed, size, dim):
    rng = np.random.default_rng(seed)
    entries = np.unique((rng.normal(0, 1, (size, dim)) + 0.5).astype(np.float16), axis=0)
    out, mask = with_zero_entry(entries)
    assert len(out) <= 256 and mask.sum() >= 1
    assert not out[mask].astype(np.float64).any()
    assert len(out) == min(len(entries) + 1, 256)
    again, same = with_zero_entry(out)  # already there: unchanged
    np.testing.assert_array_equal(again, out)
    np.testing.assert_array_equal(same, mask)


@pytest.fixture(scope="module")
def cloud():
    return make_scene(11, curves=0, blobs=2500, sh_degree=2).cloud


def ecvq_config(cost: float) -> PatchConfig:
    base = PatchConfig(kmeans_iterations=10, kmeans_samples=20_000, ecvq=True, sh_zero_entry=True)
    names = [a.name for a in PatchAttribute.for_sh_degree(2)]
    return dataclasses.replace(base, ecvq_bit_costs={name: cost for name in names})


def entropy_bits(indices: dict) -> float:
    total = 0.0
    for idx in indices.values():
        for column in np.asarray(idx).T:
            p = np.bincount(column) / len(column)
            p = p[p > 0]
            total -= float((p * np.log2(p)).sum()) * len(column)
    return total


def test_ecvq_files_decode_with_the_existing_decoder(cloud):
    """The codebooks and indices ECVQ makes are an ordinary file: decoding it gives the cloud
    the quantized attributes describe, and its index columns carry fewer bits than nearest
    assignment's; each SH band's codebook holds one exact zero entry."""
    enc = PatchEncoder(ecvq_config(0.02), seed=1)
    out = enc.encode(cloud, np.ones(len(cloud)))
    data = build_bitstream(EncodedScene(cloud.sh_degree, [], out.codebooks, out.layers))
    decoded = spcodec.decode(data)
    order = np.concatenate(out.order)
    q = enc.quantize(cloud, enc.kmeans_weights(np.ones(len(cloud))))
    for a, b in zip(q.codebooks, out.codebooks):
        np.testing.assert_array_equal(a.entries, b.entries)
    assert quantized_cloud(q.subset(order), decoded.means, cloud.sh_degree).equals(decoded)
    plain = PatchEncoder(dataclasses.replace(enc.config, ecvq=False), seed=1).quantize(
        cloud, enc.kmeans_weights(np.ones(len(cloud))))
    assert entropy_bits(q.indices) < entropy_bits(plain.indices)
    band = PatchAttribute.SH_BAND_2
    book = next(cb for cb in q.codebooks if cb.attribute is band).entries
    zero = np.flatnonzero(~book.astype(np.float64).any(axis=1))
    assert len(zero) == 1
    on_zero = q.subset(order).indices[band][:, 0] == zero[0]
    assert not decoded.sh_rest[on_zero, 3:8].any()  # a Gaussian on it has no second band
    assert decoded.sh_rest[~on_zero, 3:8].any(axis=1).all()


def test_ecvq_off_or_lambda_zero_is_the_nearest_encoder(cloud):
    weights = np.ones(len(cloud))
    plain = PatchEncoder(PatchConfig(kmeans_iterations=10, kmeans_samples=20_000), seed=2)
    zero = PatchEncoder(dataclasses.replace(ecvq_config(0.0), sh_zero_entry=False), seed=2)
    a, b = plain.quantize(cloud, weights), zero.quantize(cloud, weights)
    for x, y in zip(a.codebooks, b.codebooks):
        np.testing.assert_array_equal(x.entries, y.entries)
    for attr in a.indices:
        np.testing.assert_array_equal(a.indices[attr], b.indices[attr])
    assert coded_attributes(cloud).keys() == a.indices.keys()
