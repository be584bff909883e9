"""The scene's box in the metadata (``bounds``, spec [R-71]): what the viewer frames from layer 0.

The box must hold every position any decoder computes, of every layer, and its robust part must
be the viewer's own framing rule (the 2nd..98th percentile of each axis), so that a file with
``bounds`` is framed as the page would frame all of its decoded centres.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

import spcodec
from spcodec.bounds import decimal_places, round_down, round_up, scene_bounds
from spcodec.cli import main
from spcodec.container import PositionMode
from spcodec.synthetic import (
    make_scene,
    random_codebooks,
    random_encoded_scene,
    random_patch_layer,
    random_sketch,
)
from spcodec.writer import EncodedScene, WriteOptions, build_bitstream


def holds(box: dict, points: np.ndarray) -> bool:
    """Whether the corners ``box["min"]``, ``box["max"]`` hold every row of ``points``."""
    return bool((points >= np.array(box["min"])).all() and (points <= np.array(box["max"])).all())


finite = st.floats(-1e6, 1e6, allow_nan=False, width=32)
clouds = st.integers(1, 60).flatmap(lambda n: arrays(np.float32, (n, 3), elements=finite))


@given(clouds, st.floats(-1e4, 1e4, width=32), st.floats(1e-3, 1e3))
def test_the_box_holds_every_point_and_is_tight_to_its_rounding(points, shift, scale):
    points = (points * np.float32(scale / 1e6) + np.float32(shift)).astype(np.float32)
    box = scene_bounds(points)
    robust = box["robust"]
    assert holds(box, points)
    assert holds(box, np.array([robust["min"], robust["max"]]))  # the robust box lies inside
    xyz = points.astype(np.float64)
    extent = float(np.ptp(xyz, axis=0).max())
    step = 10.0 ** -decimal_places(extent, float(np.abs(xyz).max()))
    assert (np.array(box["max"]) - xyz.max(axis=0) <= step * 1.001).all()
    assert (xyz.min(axis=0) - np.array(box["min"]) <= step * 1.001).all()
    # the viewer's percentile rule: sorted values at floor(0.02 (n - 1)) and ceil(0.98 (n - 1))
    ordered = np.sort(xyz, axis=0)
    n = len(xyz)
    low, high = ordered[math.floor(0.02 * (n - 1))], ordered[math.ceil(0.98 * (n - 1))]
    assert (np.array(robust["min"]) <= low).all() and (low - np.array(robust["min"]) <= step * 1.001).all()
    assert (np.array(robust["max"]) >= high).all() and (np.array(robust["max"]) - high <= step * 1.001).all()
    assert robust["percentiles"] == [2, 98]


@given(st.floats(-1e30, 1e30, allow_nan=False), st.integers(-20, 20))
def test_rounding_goes_outward_by_less_than_a_step(value, places):
    down, up = round_down([value], places)[0], round_up([value], places)[0]
    step = 10.0 ** -places
    assert down <= value <= up
    assert value - down < step * 1.000001 + abs(value) * 1e-15
    assert up - value < step * 1.000001 + abs(value) * 1e-15


def test_a_box_prints_short_and_nothing_finite_gives_none():
    points = np.array([[0.1, -2.0, 3.3], [0.30000001, 7.77777, -1.0], [np.nan, 0, 0]], np.float32)
    box = scene_bounds(points)
    assert box["min"] == [0.1, -2.0, -1.0] and box["max"] == [0.301, 7.778, 3.3]  # 3 places
    assert len(json.dumps(box)) < 200
    assert scene_bounds(np.full((4, 3), np.inf, np.float32)) is None
    assert scene_bounds(np.zeros((0, 3), np.float32)) is None
    one = scene_bounds(np.array([[1e6, -5e-7, 0.0]], np.float32))  # a point: rounding by its size
    assert holds(one, np.array([[1e6, -5e-7, 0.0]], np.float32))


def test_a_hand_made_scene_with_every_position_mode_gets_the_box_of_what_decodes():
    """Sketch blobs shared by several clusters, and patch layers stored in each of the four modes:
    the box is of the decoded positions (quantized, half-float, Draco), every layer's."""
    rng = np.random.default_rng(3)
    books = random_codebooks(rng, 1)
    layers = [random_patch_layer(rng, books, 120, mode) for mode in PositionMode]
    scene = EncodedScene(1, random_sketch(rng, 1, 5), books, layers, {"note": "kept"})
    data = build_bitstream(scene, WriteOptions(bounds=True))
    metadata = spcodec.inspect(data).metadata
    points = spcodec.decode(data).means
    assert metadata["note"] == "kept" and holds(metadata["bounds"], points)
    sketch_only = spcodec.decode(data, max_layer=0).means
    assert not holds(metadata["bounds"]["robust"], points)  # the patch layers reach further
    assert np.ptp(points, axis=0).min() > 2 * np.ptp(sketch_only, axis=0).max()
    assert "bounds" not in spcodec.inspect(build_bitstream(scene)).metadata  # not asked for


@settings(max_examples=15)
@given(st.integers(0, 2**31))
def test_any_written_scene_has_a_box_holding_what_decodes(seed):
    """Random scenes (any SH degree, shared sketch blobs, any position mode, empty layers): the box
    holds every decoded position; a scene without Gaussians gets none."""
    data = build_bitstream(random_encoded_scene(seed, metadata={}), WriteOptions(bounds=True))
    points = spcodec.decode(data).means
    metadata = spcodec.inspect(data).metadata
    assert ("bounds" in metadata) == (len(points) > 0)
    if len(points):
        assert holds(metadata["bounds"], points)


def test_an_encoded_file_records_a_box_holding_every_decoded_position(tmp_path):
    """A real encode (``spcodec encode --no-retrain``): the metadata's box holds every decoded
    position of every layer, and its robust box the viewer's percentiles of them."""
    ply, spc = tmp_path / "scene.ply", tmp_path / "scene.spc"
    spcodec.write_ply(ply, make_scene(seed=2, curves=6, per_curve=250, blobs=3000).cloud)
    assert main(["encode", str(ply), "-o", str(spc), "--no-retrain", "--quiet"]) == 0
    info = spcodec.inspect(spc).to_json()
    assert len(info["layers"]) >= 2
    box = info["metadata"]["bounds"]
    points = spcodec.decode(spc).means
    assert len(points) == info["gaussians"]
    for layer in range(len(info["layers"])):
        assert holds(box, spcodec.decode(spc, max_layer=layer).means)
    side = np.ptp(points, axis=0)
    for corner, percentile in (("min", 2), ("max", 98)):
        truth = np.percentile(points, percentile, axis=0)
        assert np.abs(np.array(box["robust"][corner]) - truth).max() < 0.01 * side.max()


@pytest.mark.parametrize("up", ["+z"])
def test_the_box_is_in_the_files_own_coordinates_whatever_the_up_axis(tmp_path, up):
    """Positions are stored as they came; so is the box: an up axis turns neither."""
    ply, spc = tmp_path / "z.ply", tmp_path / "z.spc"
    cloud = make_scene(seed=5, curves=3, per_curve=150, blobs=1500).cloud
    cloud.means[:, 2] *= 4  # tall along z
    spcodec.write_ply(ply, cloud)
    assert main(["encode", str(ply), "-o", str(spc), "--no-retrain", "--quiet", f"--up={up}"]) == 0
    box = spcodec.inspect(spc).metadata["bounds"]
    sides = np.array(box["max"]) - np.array(box["min"])
    assert int(np.argmax(sides)) == 2
    assert holds(box, spcodec.decode(spc).means)
