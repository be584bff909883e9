"""Tiled encodes (spcodec.tiling): chunked input, the two-pass partition, the moment-preserving
merge, node files, the 3D Tiles index, Dask scheduling with retries, and resume."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from spcodec.cloud import GaussianCloud
from spcodec.decoder import decode
from spcodec.encoder.stages import Stage
from spcodec.ply import read_ply, write_ply
from spcodec.synthetic import make_scene
from spcodec.tiling import TilingConfig, build_tileset
from spcodec.tiling.build import FAIL_ONCE_ENV
from spcodec.tiling.config import PRECISION_SEARCHES
from spcodec.tiling.grouping import merge_level, pair_groups
from spcodec.tiling.merge import MAX_OPACITY, covariances, merge_groups, weights
from spcodec.tiling.partition import build_tree, input_identity, leaf_path, partition
from spcodec.tiling.rows import cloud_to_rows, rows_to_cloud
from spcodec.tiling.source import open_source
from spcodec.tiling.tileset import read_tileset

from conftest import load_bench_script, real_file

pytestmark = pytest.mark.usefixtures("single_torch_thread")

LEAF = 700


def scene(seed: int = 0, sh_degree: int = 1) -> GaussianCloud:
    return make_scene(seed=seed, curves=4, per_curve=250, blobs=1400, sh_degree=sh_degree).cloud


@pytest.fixture(scope="module")
def scene_ply(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("scene") / "scene.ply"
    write_ply(path, scene())
    return path


@pytest.fixture(scope="module")
def small_ply(tmp_path_factory) -> Path:
    """Two leaves and a root with branching 2: the smallest tree, for the engine's tests."""
    path = tmp_path_factory.mktemp("small") / "small.ply"
    write_ply(path, make_scene(seed=1, curves=2, per_curve=250, blobs=900, sh_degree=1).cloud)
    return path


SMALL = dict(leaf_size=700, branching=2)


class RecordedStage(Stage):
    """A progress stage that remembers what it was told."""

    def __init__(self, name: str, total: int | None) -> None:
        self.name, self.total, self.count, self.summary = name, total, 0, None

    def update(self, count: int = 1, **figures: float) -> None:
        self.count += count

    def done(self, summary: str = "") -> None:
        self.summary = summary


class Recorder:
    """A progress factory (``encoder.stages.ProgressFactory``) that keeps its stages."""

    def __init__(self) -> None:
        self.stages: list[RecordedStage] = []

    def __call__(self, name: str, total: int | None) -> RecordedStage:
        self.stages.append(RecordedStage(name, total))
        return self.stages[-1]

    def named(self, start: str) -> RecordedStage:
        (stage,) = [s for s in self.stages if s.name.startswith(start)]
        return stage


@pytest.fixture(scope="module")
def building(scene_ply, tmp_path_factory):
    """The synthetic scene built in this process (no engine), read 1,000 rows at a time, with
    the progress it reported."""
    out = tmp_path_factory.mktemp("tiles")
    recorder = Recorder()
    summary = build_tileset(scene_ply, out, TilingConfig(leaf_size=LEAF, workers=0,
                                                         chunk_rows=1000), recorder)
    return out, summary, recorder


@pytest.fixture(scope="module")
def built(building):
    return building[:2]


def sorted_rows(rows: np.ndarray) -> np.ndarray:
    return rows[np.lexsort(rows.T[::-1])]


def tiles(node: dict):
    yield node
    for child in node.get("children", []):
        yield from tiles(child)


# ------------------------------------------------------------------------------- input
def test_chunks_of_a_mapped_ply_are_the_reader_s_cloud(scene_ply):
    source = open_source(scene_ply)
    assert source.mapped
    whole = GaussianCloud.concat([c for _, c in source.chunks(333)])
    assert whole.equals(read_ply(scene_ply))
    assert np.array_equal(source.all_positions(1000), whole.means)


def splat_file(path: Path, n: int, seed: int = 0) -> Path:
    """A ``.splat`` of ``n`` random Gaussians, written by the format's writer."""
    from spcodec.formats import splat

    rng = np.random.default_rng(seed)
    cloud = GaussianCloud(means=rng.normal(size=(n, 3)) * 5, scales=rng.uniform(-5, -1, (n, 3)),
                          quats=rng.normal(size=(n, 4)), opacities=rng.uniform(-4, 4, n),
                          sh_dc=rng.normal(size=(n, 3)), sh_rest=np.zeros((n, 0, 3)))
    splat.write(str(path), cloud)
    return path


def test_chunks_of_a_mapped_splat_are_the_reader_s_cloud(tmp_path):
    from spcodec.formats import read_scene

    path = splat_file(tmp_path / "scene.splat", 1000)
    source = open_source(path)
    assert source.mapped and source.count == 1000 and source.sh_degree == 0
    whole = GaussianCloud.concat([c for _, c in source.chunks(333)])
    assert whole.equals(read_scene(path))
    assert np.array_equal(source.all_positions(97), whole.means)


def test_a_mapped_splat_holds_a_chunk_not_the_file(tmp_path):
    """Reading a .splat in chunks allocates about a chunk's worth, not the file's 6.4 MB."""
    import tracemalloc

    path = splat_file(tmp_path / "big.splat", 200_000)
    tracemalloc.start()
    try:
        source = open_source(path)
        for _, cloud in source.chunks(5000):
            assert len(cloud) == 5000
        source.all_positions(5000)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    centres = 200_000 * 12  # pass 1 keeps every centre, by design
    assert peak < centres + 2_000_000, f"peak {peak:,} bytes for a {path.stat().st_size:,}-byte file"


def test_other_inputs_are_loaded_whole_and_chunked_alike(tmp_path):
    from plyfile import PlyData, PlyElement

    from spcodec.ply import ply_bytes

    cloud = scene(sh_degree=0).subset(slice(0, 300))
    _, records = ply_bytes(cloud)
    path = tmp_path / "ascii.ply"
    PlyData([PlyElement.describe(records, "vertex")], text=True).write(str(path))
    source = open_source(path)
    assert not source.mapped
    assert GaussianCloud.concat([c for _, c in source.chunks(64)]).equals(read_ply(path))


def test_a_ply_without_the_3dgs_properties_is_refused(tmp_path):
    from plyfile import PlyData, PlyElement

    from spcodec.errors import FormatError

    records = np.zeros(4, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4")])
    path = tmp_path / "points.ply"
    PlyData([PlyElement.describe(records, "vertex")]).write(str(path))
    with pytest.raises(FormatError, match="lacks the 3DGS properties f_dc_0"):
        open_source(path)


def test_rows_round_trip():
    cloud = scene(sh_degree=3).subset(slice(0, 50))
    assert rows_to_cloud(cloud_to_rows(cloud)).equals(cloud)


# --------------------------------------------------------------------------- partition
@given(n=st.integers(1, 3000), leaf=st.integers(64, 400), branching=st.sampled_from([2, 4, 8]),
       seed=st.integers(0, 2 ** 16))
def test_tree_leaves_hold_every_row_once_and_at_most_leaf_size(n, leaf, branching, seed):
    rng = np.random.default_rng(seed)
    points = rng.normal(size=(n, 3)) * rng.uniform(0.01, 10, 3)
    nodes, leaf_rows = build_tree(points, leaf, branching)
    held = np.concatenate(list(leaf_rows.values()))
    assert np.array_equal(np.sort(held), np.arange(n))
    assert all(0 < len(r) <= leaf for r in leaf_rows.values())
    for node in nodes.values():
        if node.children:
            assert len(node.children) == branching
            assert sum(nodes[c].count for c in node.children) == node.count
        else:
            assert node.count == len(leaf_rows[node.id])


def test_spilled_leaves_hold_every_input_row_exactly_once(scene_ply, tmp_path):
    source = open_source(scene_ply)
    identity = input_identity(scene_ply, leaf_size=400, branching=4)
    parts = partition(source, tmp_path, identity, 400, 4, chunk_rows=257)
    spilled = np.concatenate([np.load(leaf_path(tmp_path, n.id)) for n in parts.leaves])
    original = cloud_to_rows(read_ply(scene_ply))
    assert np.array_equal(sorted_rows(spilled), sorted_rows(original))
    assert all(n.count <= 400 for n in parts.leaves)
    # same input and settings: the recorded partition is reused, not made again
    before = leaf_path(tmp_path, parts.leaves[0].id).stat().st_mtime_ns
    again = partition(source, tmp_path, identity, 400, 4, chunk_rows=257)
    assert leaf_path(tmp_path, parts.leaves[0].id).stat().st_mtime_ns == before
    assert [n.leaf_digest for n in again.leaves] == [n.leaf_digest for n in parts.leaves]


@settings(max_examples=40, deadline=None)
@given(n=st.integers(2, 2500), leaf=st.integers(64, 300), branching=st.sampled_from([2, 4, 8]),
       block=st.integers(64, 900), sample=st.sampled_from([50, 400, 1 << 21]),
       seed=st.integers(0, 2 ** 16), duplicates=st.booleans())
def test_a_scene_cut_through_blocks_holds_every_row_once_in_leaves_of_at_most_leaf_size(
        tmp_path_factory, n, leaf, branching, block, sample, seed, duplicates):
    """The block path (a scene larger than a block): every input row in exactly one leaf, in
    input order; no leaf over the leaf size or empty; every node's count its children's sum, its
    children named by one more digit, at most ``branching`` of them; the blocks' files gone.
    ``duplicates``: many equal centres, which can leave a block empty."""
    from spcodec.tiling import blocks
    from spcodec.tiling.source import LoadedScene

    rng = np.random.default_rng(seed)
    means = rng.normal(size=(n, 3)) * rng.uniform(0.01, 10, 3)
    if duplicates:
        means[rng.random(n) < 0.6] = means[0]
    cloud = GaussianCloud(means=means, scales=rng.uniform(-4, 0, (n, 3)),
                          quats=rng.normal(size=(n, 4)), opacities=rng.normal(size=n),
                          sh_dc=rng.normal(size=(n, 3)), sh_rest=np.zeros((n, 0, 3)))
    work = tmp_path_factory.mktemp("blocks")
    original = blocks.SAMPLE_ROWS
    blocks.SAMPLE_ROWS = sample
    try:
        parts = partition(LoadedScene(cloud), work, {"n": n}, leaf, branching, chunk_rows=97,
                          block=min(block, n - 1))
    finally:
        blocks.SAMPLE_ROWS = original
    rows = cloud_to_rows(cloud)
    spilled = [np.load(leaf_path(work, node.id)) for node in parts.leaves]
    assert np.array_equal(sorted_rows(np.concatenate(spilled)), sorted_rows(rows))
    assert all(0 < len(s) <= leaf for s in spilled)
    assert [len(s) for s in spilled] == [node.count for node in parts.leaves]
    for part in spilled:  # in input order: the rows' positions in the input ascend
        where = [int(np.flatnonzero((rows == r).all(axis=1))[0]) for r in part[:5]]
        assert where == sorted(where) or duplicates
    assert parts.nodes["n"].count == n
    for node in parts.nodes.values():
        if node.children:
            assert 0 < len(node.children) <= branching
            assert all(c[:-1] == node.id and parts.nodes[c] for c in node.children)
            assert sum(parts.nodes[c].count for c in node.children) == node.count
    assert not (work / "blocks").exists()


def test_a_scene_within_one_block_is_cut_exactly_as_before(scene_ply, tmp_path):
    source = open_source(scene_ply)
    exact = partition(source, tmp_path / "a", {"k": 1}, 400, 4, chunk_rows=257)
    same = partition(source, tmp_path / "b", {"k": 1}, 400, 4, chunk_rows=257, block=source.count)
    assert [(n.id, n.count, n.children, n.leaf_digest) for n in exact.nodes.values()] == \
        [(n.id, n.count, n.children, n.leaf_digest) for n in same.nodes.values()]
    cut = partition(source, tmp_path / "c", {"k": 1}, 400, 4, chunk_rows=257, block=500)
    assert sorted(n.id for n in cut.leaves) != [] and all(n.count <= 400 for n in cut.leaves)


def test_a_tileset_built_through_blocks_holds_the_scene_and_decodes(scene_ply, tmp_path, monkeypatch):
    """The whole build when the scene is larger than a block (blocks of 900 here): the index
    names every node, each decodes, and the leaves hold every input Gaussian once."""
    from spcodec.tiling import blocks

    monkeypatch.setattr(blocks, "block_rows", lambda sh_degree, leaf_size: 900)
    recorder = Recorder()
    summary = build_tileset(scene_ply, tmp_path, TilingConfig(leaf_size=LEAF, workers=0), recorder)
    assert [s.name.split(":")[0] for s in recorder.stages] == [
        "partition", "partition pass 1 of 2", "partition pass 2 of 2",
        f"digest {summary.leaves} leaves", f"encode {summary.nodes} nodes"]
    assert "route" in recorder.stages[1].name and "blocks into leaves" in recorder.stages[2].name
    for stage in recorder.stages:  # each counted to its total, and closed
        assert stage.total and stage.count == stage.total and stage.summary is not None
    index = read_tileset(tmp_path / "tileset.json")
    nodes = list(tiles(index["root"]))
    assert len(nodes) == summary.nodes and not (tmp_path / "work").exists()
    decoded = {t["content"]["uri"]: decode((tmp_path / t["content"]["uri"]).read_bytes())
               for t in nodes}
    leaves = [decoded[t["content"]["uri"]] for t in nodes if not t.get("children")]
    assert sum(len(c) for c in leaves) == len(read_ply(scene_ply))
    assert all(len(c) <= LEAF for c in leaves)


# ------------------------------------------------------------------------------- merge
@st.composite
def clouds(draw):
    n = draw(st.integers(1, 40))
    rng = np.random.default_rng(draw(st.integers(0, 2 ** 16)))
    quats = rng.normal(size=(n, 4))
    return GaussianCloud(means=rng.normal(size=(n, 3)), scales=rng.uniform(-4, 0, (n, 3)),
                         quats=quats, opacities=rng.uniform(-6, 4, n), sh_dc=rng.normal(size=(n, 3)),
                         sh_rest=rng.normal(size=(n, 3, 3)))


@given(cloud=clouds(), size=st.integers(1, 8))
def test_merge_keeps_weight_mean_and_covariance(cloud, size):
    labels, count = pair_groups(cloud, -(-len(cloud) // size))
    assert count == -(-len(cloud) // size) and np.array_equal(np.unique(labels), np.arange(count))
    merged = merge_groups(cloud, labels, count).cloud
    w = weights(cloud)
    total = np.bincount(labels, w, count)
    mean = np.stack([np.bincount(labels, w * cloud.means[:, i], count) for i in range(3)], 1) / total[:, None]
    offset = cloud.means - mean[labels]
    second = covariances(cloud) + offset[:, :, None] * offset[:, None, :]
    cov = np.zeros((count, 3, 3))
    np.add.at(cov, labels, w[:, None, None] * second)
    cov /= total[:, None, None]
    got = covariances(merged)
    scale = np.abs(cov).max(axis=(1, 2))[:, None, None]
    assert np.allclose(merged.means, mean, atol=1e-5)
    assert np.all(np.abs(got - cov) <= 1e-4 * scale + 1e-12)
    alpha = merged.activated_opacity().astype(np.float64)
    capped = alpha >= MAX_OPACITY * (1 - 1e-6)
    # the total weight is kept wherever the opacity cap does not bind, and never exceeded
    merged_weight = weights(merged)
    assert np.allclose(merged_weight[~capped], total[~capped], rtol=1e-4)
    assert np.all(merged_weight <= total * (1 + 1e-4))
    colour = np.stack([np.bincount(labels, w * cloud.sh_dc[:, i], count) for i in range(3)], 1)
    assert np.allclose(merged.sh_dc, colour / total[:, None], atol=1e-5)


def test_a_level_reduces_by_the_branching_factor():
    cloud = scene()
    level = merge_level(cloud, 4)
    assert len(level.cloud) == -(-len(cloud) // 4)
    assert level.spatial_error > 0 and level.cloud.is_finite()


def test_the_spec_states_the_pair_cost_the_code_uses():
    """spec/tileset.md describes how inner tiles are made; its figures are the code's."""
    from spcodec.tiling.grouping import NEIGHBOURS
    from spcodec.tiling.pair_cost import APPEARANCE_COST, THINNEST

    text = " ".join((Path(__file__).parents[1] / "spec" / "tileset.md").read_text().split())
    section = text[text.index("## Levels of detail"):text.index("## Decoding")]
    for phrase in (f"{NEIGHBOURS} nearest neighbours", "Kullback-Leibler divergence",
                   "six sigma points", f"1/{round(1 / THINNEST)} of its longest",
                   f"{APPEARANCE_COST:g} times the squared difference", "every SH coefficient",
                   f"capped below 1 (at {MAX_OPACITY:g}", "opacity times the surface area"):
        assert phrase in section, phrase
    assert "weighted variance the pair adds" not in section  # the retired cost


# ---------------------------------------------------------------------- the whole build
def check_tileset(out: Path, input_count: int) -> dict:
    doc = read_tileset(out)
    assert doc["asset"]["version"] == "1.1"
    assert doc["geometricError"] >= doc["root"]["geometricError"] > 0
    leaf_inputs = 0
    for tile in tiles(doc["root"]):
        assert {"boundingVolume", "geometricError", "refine", "content"} <= set(tile)
        assert tile["refine"] == "REPLACE" and len(tile["boundingVolume"]["box"]) == 12
        node = out / tile["content"]["uri"]
        extras = tile["extras"]["spcodec"]
        assert node.stat().st_size == extras["bytes"]
        assert len(decode(node)) == extras["gaussians"]
        children = tile.get("children", [])
        if not children:
            assert tile["geometricError"] == 0
            leaf_inputs += extras["inputGaussians"]
        box = np.array(tile["boundingVolume"]["box"])
        for child in children:
            assert 0 <= child["geometricError"] <= tile["geometricError"]
            inner = np.array(child["boundingVolume"]["box"])
            lo, hi = box[:3] - box[[3, 7, 11]], box[:3] + box[[3, 7, 11]]
            child_lo, child_hi = inner[:3] - inner[[3, 7, 11]], inner[:3] + inner[[3, 7, 11]]
            assert np.all(child_lo >= lo - 1e-6) and np.all(child_hi <= hi + 1e-6)
    assert leaf_inputs == input_count
    return doc


def test_every_node_decodes_to_the_count_the_index_says(built):
    out, summary = built
    doc = check_tileset(out, summary.input_gaussians)
    assert summary.leaves > 1 and summary.encoded_nodes == summary.nodes
    root = doc["root"]["extras"]["spcodec"]
    assert root["gaussians"] <= LEAF  # an inner node holds about as many as a leaf


def test_every_pass_and_every_node_is_a_counted_stage(building):
    out, summary, recorder = building
    chunks = -(-summary.input_gaussians // 1000)
    assert [s.name.split(":")[0] for s in recorder.stages] == [
        "partition pass 1 of 2", "partition pass 2 of 2", f"digest {summary.leaves} leaves",
        f"encode {summary.nodes} nodes"]
    for stage in recorder.stages:  # each counted to its total, and closed
        assert stage.total and stage.count == stage.total and stage.summary is not None
    assert recorder.stages[0].total == chunks == recorder.stages[1].total
    assert recorder.named("encode").summary == f"{summary.nodes} encoded, 0 reused"


def test_a_second_run_does_no_work(built, scene_ply):
    out, summary = built
    stamps = {p.name: p.stat().st_mtime_ns for p in (out / "nodes").iterdir()}
    (out / "nodes" / "n77.spc").write_bytes(b"a node of an earlier tree")
    again = build_tileset(scene_ply, out, TilingConfig(leaf_size=LEAF, workers=0))
    assert again.encoded_nodes == 0 and again.bytes == summary.bytes
    # the same files, untouched, and none that the index does not name
    assert {p.name: p.stat().st_mtime_ns for p in (out / "nodes").iterdir()} == stamps


def node_files(out: Path) -> list[Path]:
    return sorted((out / "nodes").glob("*.spc"))


def has_sketch(node: Path) -> tuple[bool, bool]:
    """(the encoder settings stored in the node say ``use_sketch``, its sketch layer holds
    Gaussians): every file has a sketch layer, empty without a sketch."""
    from spcodec.container import LayerKind
    from spcodec.decoder import inspect

    info = inspect(node)
    return (info.metadata["settings"]["use_sketch"],
            any(layer.kind == LayerKind.SKETCH and layer.gaussian_count > 0
                for layer in info.header.layers))


def test_nodes_are_encoded_without_a_sketch_by_default(built):
    """A tileset's nodes skip the sketch (TilingConfig.sketch, measured in docs/LOG.md): the
    setting reaches every node's encoder, which stores it in the file."""
    out, _ = built
    assert TilingConfig().sketch is False
    assert [has_sketch(node) for node in node_files(out)] == [(False, False)] * len(node_files(out))


def test_the_sketch_setting_reaches_the_node_and_redoes_it(small_ply, tmp_path):
    """``sketch=True`` encodes a node as the preset would: the scene in one node (a leaf of
    700 is too small for the encoder's clusters) gets its curves as sketch. Switching back
    re-encodes it, since the setting is in the digest, and the node's sketch layer is empty."""
    whole = dict(leaf_size=2048, branching=2, workers=0)
    first = build_tileset(small_ply, tmp_path, TilingConfig(**whole, sketch=True))
    assert first.nodes == 1 and [has_sketch(node) for node in node_files(tmp_path)] == [(True, True)]
    again = build_tileset(small_ply, tmp_path, TilingConfig(**whole))
    assert again.encoded_nodes == 1 and again.bytes != first.bytes
    assert [has_sketch(node) for node in node_files(tmp_path)] == [(False, False)]


def test_a_preset_without_a_sketch_never_gets_one():
    from spcodec.tiling.build import NodeJob, encoder_config

    def job(preset: str, sketch: bool) -> NodeJob:
        return NodeJob("n", (), "digest", ".", preset, 0, 4, sketch)

    assert encoder_config(job("balanced", True)).use_sketch is True
    assert encoder_config(job("balanced", False)).use_sketch is False
    assert encoder_config(job("transparent", True)).use_sketch is False


def test_precision_search_makes_a_node_its_presets_point_and_redoes_it(small_ply, tmp_path):
    """``precision_search="all"`` encodes a node as a single file's preset is (DECISIONS D-33,
    D-34): its preset's bytes spent by the precision search, recorded in the node's settings; the
    setting is in the digest, so switching it re-encodes the node."""
    from spcodec.decoder import inspect
    from spcodec.errors import UsageError
    from spcodec.tiling.build import NodeJob, encoder_config

    job = NodeJob("n", (), "digest", ".", "balanced", 0, 4, True, True)
    assert encoder_config(job).allocation is not None and encoder_config(job).use_sketch is False
    whole = dict(leaf_size=2048, branching=2, workers=0)
    plain = build_tileset(small_ply, tmp_path, TilingConfig(**whole, precision_search="none"))
    searched = build_tileset(small_ply, tmp_path, TilingConfig(**whole, precision_search="all"))
    assert searched.nodes == 1 and searched.encoded_nodes == 1
    # the point spends the bytes the search predicts for the shapes (D-34): about theirs
    assert searched.bytes <= 1.03 * plain.bytes
    [node] = node_files(tmp_path)
    settings = inspect(node).metadata["settings"]
    assert settings["allocation"] is not None and settings["use_sketch"] is False
    with pytest.raises(UsageError, match="--precision-search all makes every node its preset's "
                                         "point, which builds no sketch"):
        build_tileset(small_ply, tmp_path / "both", TilingConfig(**whole, sketch=True,
                                                                 precision_search="all"))
    assert not (tmp_path / "both").exists()
    with pytest.raises(UsageError, match="precision search must be one of none, coarse, inner, all, "
                                         "got 'leaves'"):
        build_tileset(small_ply, tmp_path / "bad", TilingConfig(**whole, precision_search="leaves"))
    assert not (tmp_path / "bad").exists()


@pytest.mark.parametrize("searched, least", [("coarse", 2), ("inner", 1)])
def test_a_coarse_or_inner_precision_search_makes_only_those_levels_points(small_ply, tmp_path,
                                                                           searched, least):
    """``coarse``: the levels two merges or more above the leaves are points of the curve;
    ``inner``: every merged level. The other nodes keep the preset's shapes (their files are
    those of a build without the search)."""
    from spcodec.decoder import inspect

    assert [TilingConfig(precision_search=p).searches(h) for p in PRECISION_SEARCHES
            for h in (0, 1, 2)] == [False] * 3 + [False, False, True] + [False, True, True] + \
        [True] * 3
    whole = dict(leaf_size=350, branching=2, workers=0)  # four leaves, two inner nodes, a root
    build_tileset(small_ply, tmp_path / "none", TilingConfig(**whole, precision_search="none"))
    build_tileset(small_ply, tmp_path / searched, TilingConfig(**whole, precision_search=searched))
    ids = [node.stem for node in node_files(tmp_path / searched)]
    height = {i: max(len(j) - len(i) for j in ids if j.startswith(i)) for i in ids}
    assert sorted(height.values()) == [0, 0, 0, 0, 1, 1, 2]
    for node in node_files(tmp_path / searched):
        points = inspect(node).metadata["settings"]["allocation"] is not None
        assert points == (height[node.stem] >= least)
        plain = (tmp_path / "none" / "nodes" / node.name).read_bytes()
        assert (node.read_bytes() == plain) == (not points)


@pytest.mark.parametrize("module", ["spcodec", "tiling"])
@pytest.mark.parametrize("flag, expected", [([], False), (["--sketch"], True), (["--no-sketch"], False)])
def test_both_clis_pass_the_sketch_setting(module, flag, expected, scene_ply, tmp_path, monkeypatch):
    """And --precision-search, off unless given."""
    import spcodec.tiling.__main__ as tiling_main
    from spcodec import tiling
    from spcodec.cli import main as spcodec
    from spcodec.errors import UsageError

    seen = []

    def build(input_path, out_dir, config, progress=None):
        seen.append(config)
        raise UsageError("stopped after reading the settings")

    monkeypatch.setattr(tiling, "build_tileset", build)
    args = [str(scene_ply), "-o", str(tmp_path / "out"), "--workers", "0", *flag]
    assert (spcodec(["tile", *args]) if module == "spcodec" else tiling_main.main(args)) == 2
    assert [config.sketch for config in seen] == [expected]
    assert [config.precision_search for config in seen] == [TilingConfig().precision_search]
    for flags, searched in ((["--precision-search"], "all"),
                            (["--precision-search", "inner"], "inner"),
                            (["--precision-search=none"], "none")):
        assert (spcodec(["tile", *args, *flags]) if module == "spcodec"
                else tiling_main.main([*args, *flags])) == 2
        assert seen[-1].precision_search == searched


@pytest.mark.slow  # starts a Dask cluster: 20-80 s on a busy 2-core machine
def test_two_local_workers_retry_a_failed_node_and_a_rerun_resumes(small_ply, tmp_path,
                                                                    monkeypatch):
    monkeypatch.setenv(FAIL_ONCE_ENV, "n0")
    recorder = Recorder()
    summary = build_tileset(small_ply, tmp_path, TilingConfig(**SMALL, workers=2, retries=1,
                                                              keep_work=True), recorder)
    assert (tmp_path / "work" / "failed-once-n0").exists()  # the first attempt did fail
    assert summary.nodes == 3 and summary.encoded_nodes == 3
    nodes = recorder.named("encode")  # each node counted once as it completed, the retried too
    assert nodes.total == nodes.count == 3 and nodes.summary == "3 encoded, 0 reused"
    check_tileset(tmp_path, summary.input_gaussians)
    # in this process, a changed encoder setting (the seed) redoes every node; the same, none
    assert build_tileset(small_ply, tmp_path, TilingConfig(**SMALL, workers=0, seed=1)) \
        .encoded_nodes == 3
    assert build_tileset(small_ply, tmp_path, TilingConfig(**SMALL, workers=0, seed=1)) \
        .encoded_nodes == 0


def test_the_worker_environment_drops_only_dasks_malloc_trim_threshold():
    import dask

    from spcodec.tiling.jobs import worker_environment

    with dask.config.set({"distributed.nanny.pre-spawn-environ":
                          {"MALLOC_TRIM_THRESHOLD_": 65536, "OTHER": 1}}):
        assert worker_environment() == {"OTHER": 1}


@pytest.mark.slow  # starts a Dask cluster
def test_local_workers_start_without_the_malloc_trim_threshold_and_with_quiet_watchers(monkeypatch):
    """Dask's default (65536) made each worker map and unmap the encoder's temporaries on every
    call: the same merge cost nearly twice the CPU of a plain process (docs/LOG.md 22.5). A
    nanny also leaves the variable in its parent's environment (as any earlier Dask cluster in
    this test process did), so the workers must not inherit it from there either. The worker
    process itself (not only this one) runs with the watchers slowed (:data:`jobs.QUIET`)."""
    import os

    import dask

    from spcodec.tiling.jobs import QUIET, engine

    monkeypatch.setenv("MALLOC_TRIM_THRESHOLD_", "65536")
    with engine(TilingConfig(**SMALL, workers=1)) as client:
        seen = client.run(lambda: os.environ.get("MALLOC_TRIM_THRESHOLD_"))
        settings = list(client.run(lambda: {k: dask.config.get(k) for k in QUIET}).values())
    assert list(seen.values()) == [None]
    assert os.environ["MALLOC_TRIM_THRESHOLD_"] == "65536"  # this process's own setting is back
    assert settings == [QUIET]
    assert dask.config.get("distributed.worker.profile.enabled") is True  # not left set here


@pytest.mark.slow
def test_without_retries_an_injected_failure_fails_the_build(small_ply, tmp_path, monkeypatch):
    monkeypatch.setenv(FAIL_ONCE_ENV, "n1")
    with pytest.raises(RuntimeError, match="injected failure of node n1"):
        build_tileset(small_ply, tmp_path, TilingConfig(**SMALL, workers=2, retries=0))
    assert not (tmp_path / "tileset.json").exists()


# ------------------------------------------------------------------------------- the CLI
def run_cli(*args: str):
    import subprocess
    return subprocess.run([sys.executable, "-m", "spcodec.tiling", *args], capture_output=True,
                          text=True, timeout=120)


def test_cli_builds_and_reports(built, scene_ply, capsys):
    from spcodec.tiling.__main__ import main

    out, summary = built
    assert main([str(scene_ply), "-o", str(out), "--leaf-size", str(LEAF), "--workers", "0"]) == 0
    line = capsys.readouterr().out
    assert f"{summary.nodes} nodes" in line and "0 nodes encoded" in line


def test_spcodec_tile_resumes_what_the_library_built_and_refuses_in_one_line(built, scene_ply,
                                                                            tmp_path, capsys):
    """``spcodec tile`` runs the same build: on the folder the library wrote, nothing is redone;
    a missing input is one line and exit 2, with nothing written."""
    from spcodec.cli import main as spcodec

    out, summary = built
    assert spcodec(["tile", str(scene_ply), "-o", str(out), "--leaf-size", str(LEAF),
                    "--workers", "0"]) == 0
    assert f"{summary.nodes} nodes" in capsys.readouterr().out
    assert spcodec(["tile", str(tmp_path / "missing.ply"), "-o", str(tmp_path / "t")]) == 2
    error = capsys.readouterr().err.strip()
    assert "missing.ply" in error and len(error.splitlines()) == 1
    assert not (tmp_path / "t" / "tileset.json").exists()


def test_spcodec_tile_shows_its_stages_and_quiet_hides_them(small_ply, tmp_path, monkeypatch,
                                                             capsys):
    from spcodec.cli import main as spcodec
    from spcodec.cli import tile

    monkeypatch.setattr(tile, "PROGRESS_DELAY", 0.0)  # a stage shows at once, however quick
    args = ["tile", str(small_ply), "-o", str(tmp_path / "t"), "--leaf-size", "700",
            "--branching", "2", "--workers", "0"]
    assert spcodec(args) == 0
    err = capsys.readouterr().err
    for line in ("partition pass 1 of 2: read 1,400 centres", "partition pass 2 of 2",
                 "encode 3 nodes 1/3", "encode 3 nodes 3/3", "encode 3 nodes: 3 encoded, 0 reused"):
        assert line in err, err
    assert "ETA" in err
    assert spcodec([*args, "--quiet"]) == 0
    out, err = capsys.readouterr()
    assert err == "" and "3 nodes (2 leaves, depth 1)" in out and "0 nodes encoded this run" in out


def test_a_missing_dask_is_one_line_before_anything_is_written(scene_ply, tmp_path, monkeypatch,
                                                                capsys):
    from spcodec.cli import main as spcodec

    monkeypatch.setitem(sys.modules, "dask.distributed", None)  # as if it were not installed
    out = tmp_path / "out"
    assert spcodec(["tile", str(scene_ply), "-o", str(out), "--workers", "2"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "pip install 'spcodec[tiling]'" in err, err
    assert not out.exists()


@pytest.mark.parametrize("args, message, code", [
    (["missing.ply"], "no such file", 2),
    (["{ply}", "--leaf-size", "10"], "--leaf-size: must be an integer >= 16", 2),
    (["{ply}", "--branching", "3"], "--branching: invalid choice: 3 (choose from 2, 4, 8)", 2),
    (["{ply}", "--preset", "best"], "unknown preset", 2),
    (["{text}"], "not a 3DGS scene file", 1),  # bad data, not a bad command (as spcodec's)
])
def test_cli_refuses_bad_input_with_one_line(scene_ply, tmp_path, args, message, code):
    text = tmp_path / "notes.txt"
    text.write_text("hello\n")
    args = [a.format(ply=scene_ply, text=text) for a in args]
    result = run_cli(*args, "-o", str(tmp_path / "out"))
    assert result.returncode == code
    assert message in result.stderr and len(result.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "out" / "tileset.json").exists()


# --------------------------------------------------------------------------- real scene
@pytest.mark.slow
def test_a_tiled_copy_of_a_real_scene(tmp_path):
    scenes = load_bench_script("scenes")
    base = read_ply(real_file(scenes.REAL["fourth_st"]))
    cloud = scenes.tiled_scene(base.subset(slice(0, 3000)), 12000)
    path = tmp_path / "tiled.ply"
    write_ply(path, cloud)
    summary = build_tileset(path, tmp_path / "out", TilingConfig(leaf_size=3000, workers=0))
    assert summary.leaves >= 4 and summary.input_gaussians == 12000
    check_tileset(tmp_path / "out", 12000)


def test_a_large_scene_is_written_part_by_part_as_the_whole_would_be(tmp_path):
    """``bench_tiles.py make`` writes a city or a cube of copies block by block, so a 100 M
    scene needs one block's memory; the file is the one the whole scene would write."""
    scenes = load_bench_script("scenes")
    bench_tiles = load_bench_script("bench_tiles")
    bases = [make_scene(seed=seed, curves=2, per_curve=50, blobs=200, sh_degree=degree).cloud
             for seed, degree in ((1, 0), (2, 1), (3, 2))]
    whole, parts = tmp_path / "whole.ply", tmp_path / "parts.ply"
    for n in (100, 1000, 2345):
        write_ply(whole, scenes.city_scene(bases, n, seed=5))
        bench_tiles.write_parts(parts, scenes.city_blocks(bases, n, seed=5), n)
        assert parts.read_bytes() == whole.read_bytes(), n
    write_ply(whole, scenes.tiled_scene(bases[1], 1000, seed=2))
    bench_tiles.write_parts(parts, scenes.tiled_copies(bases[1], 1000, seed=2), 1000)
    assert parts.read_bytes() == whole.read_bytes()


def test_nodes_built_in_this_process_run_torch_on_one_thread(monkeypatch):
    # as each worker does: the encoder's own task threads, not torch's, use the cores
    import torch

    from spcodec.tiling import jobs

    seen = []
    monkeypatch.setattr(jobs, "build_node",
                        lambda job, children: seen.append(torch.get_num_threads()) or {})
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        work = [type("Job", (), {"id": str(k), "children": []})() for k in range(3)]
        assert set(jobs.run_nodes(work, None, retries=0)) == {"0", "1", "2"}
        assert seen == [1, 1, 1] and torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(before)
