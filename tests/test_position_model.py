"""The position grids' noise model (encoder/allocation.py, displacement_model): a size target
renders two grids and predicts the others' rendered error from how far each moves the
Gaussians. Checked against real renders of every grid."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from spcodec.encoder import allocation
from spcodec.encoder.allocation import displacement_model, position_options
from spcodec.encoder.config import AllocationConfig, EncoderConfig, PatchConfig
from spcodec.synthetic import make_scene

from conftest import real_file

positive = st.floats(1e-6, 1e3, allow_nan=False, allow_infinity=False)


@settings(max_examples=200, deadline=None)
@given(a=st.floats(0, 1e3), b=st.floats(0, 1e3), s1=positive, ratio=st.floats(1.5, 1e3))
def test_the_model_goes_through_two_points_of_its_own_form(a, b, s1, ratio):
    """Two measurements of a curve a*s + b*s^2 (a, b >= 0) give back that curve."""
    s2 = s1 * ratio
    curve = lambda s: a * s + b * s * s  # noqa: E731
    model = displacement_model([(s1, curve(s1)), (s2, curve(s2))])
    for s in (s1 / 3, s1, (s1 + s2) / 2, s2, s2 * 2):
        assert model(s) == pytest.approx(curve(s), rel=1e-6, abs=1e-9 * (1 + curve(s2)))


@settings(max_examples=200, deadline=None)
@given(points=st.lists(st.tuples(positive, st.floats(0, 1e3)), min_size=1, max_size=4))
def test_the_model_never_predicts_negative_error_and_grows_with_the_shift(points):
    """Whatever the renders measured, a larger move never predicts less error, and none
    predicts a negative one; no move predicts none."""
    model = displacement_model(points)
    shifts = sorted({s for s, _ in points} | {1e-7, 1e4})
    predicted = [model(s) for s in shifts]
    assert all(p >= 0 for p in predicted)
    assert all(b >= a - 1e-12 * abs(a) for a, b in zip(predicted, predicted[1:]))
    assert model(0.0) == 0.0


def test_no_measurement_predicts_no_error():
    assert displacement_model([])(1.0) == 0.0


def _every_grid_rendered(monkeypatch, scene, rows, config, small):
    """position_options with the model and with every grid rendered."""
    modelled = position_options(scene, rows, config, small, device="cpu")
    monkeypatch.setattr(allocation, "POSITION_RENDERS", tuple(range(len(small.position_bits))))
    rendered = position_options(scene, rows, config, small, device="cpu")
    return modelled, rendered


def test_predicted_grids_are_near_their_renders(single_torch_thread, monkeypatch):
    """On a synthetic scene, every grid the model predicts is within 2x of its render, the
    rendered grids are their renders, and the bytes are the real writes either way."""
    scene = make_scene(5, blobs=1500).cloud
    small = AllocationConfig(sample=2_000, views=2, resolution=64,
                             position_bits=(8, 9, 10, 11, 12, 13))
    config = EncoderConfig(patch=PatchConfig(kmeans_iterations=5, kmeans_samples=4_000))
    calibration = set(allocation.POSITION_RENDERS)  # off-grid grids, coarsest first: these
    modelled, rendered = _every_grid_rendered(monkeypatch, scene, np.arange(len(scene)), config,
                                              small)
    for m, r in zip(modelled, rendered):
        assert m.bits_per_gaussian == r.bits_per_gaussian
        assert 0.5 < m.distortion / r.distortion < 2.0, (m, r)
    for i in calibration:
        assert modelled[i] == rendered[i]


@pytest.mark.slow  # renders kacytran at seven grids: about 15 CPU s
def test_held_out_real_scene_predictions_are_near_their_renders(single_torch_thread,
                                                                monkeypatch):
    """kacytran (not tuned on): a size target's default grids, predicted against rendered.
    Grids up to 13 bits within 1.5x; the finer ones, whose error is a hundredth of the
    coarsest's or less and barely moves a size target's choice, within 2.5x (measured: 1.7x
    at 14 bits, 2.3x at 16)."""
    from spcodec import read_ply

    scene = read_ply(real_file("kacytran_try_sh3/point_cloud_iteration_7000.ply"))
    small = AllocationConfig()
    config = EncoderConfig()
    modelled, rendered = _every_grid_rendered(monkeypatch, scene, np.arange(len(scene)), config,
                                              small)
    for m, r in zip(modelled, rendered):
        ratio = m.distortion / r.distortion
        assert (1 / 1.5 < ratio < 1.5) if m.bits <= 13 else (1 / 2.5 < ratio < 2.5), (m, r)
    assert dataclasses.replace(modelled[0]) == rendered[0]
