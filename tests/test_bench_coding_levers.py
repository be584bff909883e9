"""The measurements behind two codings not adopted (bench/bench_coding_levers.py): index columns
given a spatial neighbour, and rotations as their three smallest components."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from spcodec import write_ply
from spcodec.encoder import encode, preset_config
from spcodec.synthetic import make_scene

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))
import bench_coding_levers as levers  # noqa: E402  (bench/ is not a package)


@given(st.lists(st.integers(0, 15), min_size=1, max_size=200))
def test_order0_entropy_is_at_most_the_stored_bits_and_zero_for_one_value(values):
    values = np.asarray(values)
    bits = levers.entropy_bytes(values) * 8
    assert 0 <= bits <= len(values) * np.log2(16) + 1e-9
    assert levers.entropy_bytes(np.full(len(values), values[0])) == 0


@settings(max_examples=20, deadline=None)
@given(st.integers(0, 2**31 - 1))
def test_a_column_that_copies_its_neighbour_costs_little_given_it(seed):
    """Held out, a context that decides the value is cheap and an unrelated one is not."""
    rng = np.random.default_rng(seed)
    context = rng.integers(0, 8, 4000)
    copied = levers.held_out_bytes(context, context, 8)
    unrelated = levers.held_out_bytes(rng.integers(0, 8, 4000), context, 8)
    assert copied < 0.1 * unrelated
    assert unrelated > 0.9 * levers.entropy_bytes(rng.integers(0, 8, 4000))


@pytest.fixture(scope="module")
def scene_files(tmp_path_factory) -> tuple[Path, Path]:
    folder = tmp_path_factory.mktemp("levers")
    cloud = make_scene(seed=3, curves=2, per_curve=200, blobs=1500, sh_degree=0).cloud
    ply, spc = folder / "scene.ply", folder / "scene.spc"
    write_ply(ply, cloud)
    spc.write_bytes(encode(cloud, preset_config("balanced", point=False)).data)
    return ply, spc


def test_neighbours_reads_every_index_column_of_a_real_file(scene_files):
    _, spc = scene_files
    names, entries, layers = levers.index_columns(spc.read_bytes())
    assert len(names) == len(entries) == layers[0].shape[0]
    result = levers.neighbours(spc)
    assert [row["column"] for row in result["columns"]] == names
    assert result["order0_bytes"] == sum(r["order0_bytes"] for r in result["columns"]) > 0
    assert result["bytes"] == spc.stat().st_size


def test_rotations_at_multiples_are_never_farther_and_three_components_cost_fewer_bits(scene_files):
    ply, _ = scene_files
    result = levers.rotations(ply)
    assert [row["entries"] for row in result["rows"]] == list(levers.ENTRY_COUNTS)
    for row in result["rows"]:
        # the encoder's assignment tries the unit quaternion itself among its multiples
        assert row["four_at_multiples"]["mean_degrees"] <= row["four_rounded"]["mean_degrees"]
        assert row["smallest_three"]["bits"] < row["four_rounded"]["bits"]
