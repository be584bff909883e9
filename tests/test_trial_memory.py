"""The encoder's memories of codebook fits and index-context choices (encoder/codebook_fits.py,
encoder/contexts.py): what they return equals a fresh fit or choice, they serve what a size
target's trials repeat, and a size-targeted file is the same with and without them."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from spcodec.attributes import PatchAttribute
from spcodec.container import Codec
from spcodec.encoder import codebook_fits, contexts
from spcodec.encoder.codebook_fits import RecentFits, digest
from spcodec.encoder.config import PatchConfig
from spcodec.encoder.contexts import RecentChoices, choose_index_contexts
from spcodec.encoder.patch import PatchEncoder, Quantized
from spcodec.sections import Codebook
from spcodec.synthetic import make_scene
from spcodec.writer import PatchLayer

FAST = PatchConfig(kmeans_iterations=5, kmeans_samples=4_000)


@pytest.fixture(scope="module")
def cloud():
    return make_scene(3, blobs=600).cloud


def _same(a: Quantized, b: Quantized) -> bool:
    return [cb.attribute for cb in a.codebooks] == [cb.attribute for cb in b.codebooks] and \
        all(np.array_equal(x.entries, y.entries) for x, y in zip(a.codebooks, b.codebooks)) and \
        all(np.array_equal(a.indices[k], b.indices[k]) for k in a.indices)


@pytest.mark.slow  # twelve pairs of codebook fits: 11 s
@settings(max_examples=12, deadline=None)
@given(st.integers(0, 1000), st.sampled_from([None, 8, 40]), st.booleans(), st.booleans())
def test_a_remembered_fit_is_the_fresh_fit(cloud, seed, count, scalar, weighted):
    """Quantizing with a memory that has seen other fits of the same attributes gives what a
    memory that never stores gives, for any seed, entry count, shape and weights."""
    config = dataclasses.replace(FAST, entry_dims={"SCALE": 1, "COLOR_DC": 1} if scalar else {},
                                 entry_counts={"SCALE": count, "OPACITY": count} if count else {})
    weights = np.linspace(0.5, 2.0, len(cloud)) if weighted else None
    warm = RecentFits(64 << 20)
    original = codebook_fits.RECENT
    try:
        codebook_fits.RECENT = warm
        PatchEncoder(FAST, seed=seed).quantize(cloud, weights)  # other options of some attributes
        remembered = PatchEncoder(config, seed=seed).quantize(cloud, weights)
        again = PatchEncoder(config, seed=seed).quantize(cloud, weights)
        codebook_fits.RECENT = RecentFits(0)
        fresh = PatchEncoder(config, seed=seed).quantize(cloud, weights)
    finally:
        codebook_fits.RECENT = original
    assert _same(remembered, fresh) and _same(again, fresh)


def test_repeated_fits_are_served_and_settings_that_change_a_fit_are_fitted_again(
        cloud, monkeypatch):
    memory = RecentFits(64 << 20)
    monkeypatch.setattr(codebook_fits, "RECENT", memory)
    attributes = len(PatchEncoder(FAST).quantize(cloud).codebooks)
    assert memory.hits == 0
    first = PatchEncoder(FAST).quantize(cloud)
    assert memory.hits == attributes
    # one attribute's option changed: only that one is fitted again
    PatchEncoder(dataclasses.replace(FAST, entry_counts={"OPACITY": 8})).quantize(cloud)
    assert memory.hits == 2 * attributes - 1
    # every fit reads the seed, the iterations and the weights
    for encoder, weights in ((PatchEncoder(FAST, seed=1), None),
                             (PatchEncoder(dataclasses.replace(FAST, kmeans_iterations=6)), None),
                             (PatchEncoder(FAST), np.ones(len(cloud))),
                             (PatchEncoder(FAST), np.ones(len(cloud), np.float32))):
        before = memory.hits
        encoder.quantize(cloud, weights)
        assert memory.hits == before
    # a caller changing what it got (retraining moves entries) changes nothing remembered
    first.codebooks[0].entries[:] = 0
    first.indices[first.codebooks[0].attribute][:] = 0
    assert _same(PatchEncoder(FAST).quantize(cloud), PatchEncoder(FAST, seed=0).quantize(cloud))
    assert not np.all(PatchEncoder(FAST).quantize(cloud).codebooks[0].entries == 0)


def test_the_fit_memory_stays_within_its_bound():
    memory = RecentFits(max_bytes=10_000)
    for k in range(50):
        memory((k,), lambda: (Codebook(PatchAttribute.OPACITY, np.zeros((16, 1), np.float16)),
                              np.zeros((1000, 1), np.uint8)))
    assert memory.size == sum(cb.entries.nbytes + i.nbytes for cb, i in memory.entries.values())
    assert 0 < memory.size <= memory.max_bytes


def test_digests_tell_dtype_shape_and_content_apart():
    a = np.arange(12, dtype=np.float64)
    assert digest(a) == digest(a.copy()) != digest(a.astype(np.float32))
    assert digest(a) != digest(a.reshape(3, 4)) and digest(a) != digest(a + 1e-12)
    assert digest(None) == b""


# ---------------------------------------------------------------------------- index contexts
def _layers(seed: int, n: int, noise: int, changed: int | None = None
            ) -> tuple[list[Codebook], list[PatchLayer]]:
    """Two layers of correlated index columns over four attributes; ``changed``: that
    attribute's columns drawn again (another option of one attribute, as a trial makes)."""
    from spcodec.sections import PatchPositions

    rng = np.random.default_rng(seed)
    attrs = [PatchAttribute.SCALE, PatchAttribute.ROTATION, PatchAttribute.OPACITY,
             PatchAttribute.COLOR_DC]
    books = [Codebook(a, np.arange(64, dtype=np.float16).reshape(64, 1)) for a in attrs]
    layers = []
    for size in (n // 3, n - n // 3):
        indices = {}
        for k, cb in enumerate(books):
            base = rng.integers(0, 64, (size, 1))
            jitter = rng.integers(-noise, noise + 1, (size, cb.groups))
            column = np.clip(base + jitter, 0, 63).astype(np.uint8)
            if k == changed:
                column = np.ascontiguousarray(column[::-1])
            indices[cb.attribute] = column
        positions = PatchPositions.float16(rng.normal(0, 1, (size, 3)))
        layers.append(PatchLayer(positions, indices))
    return books, layers


@settings(max_examples=10, deadline=None)
@given(st.integers(0, 2**31 - 1), st.integers(200, 4000), st.integers(0, 6),
       st.sampled_from([0, 1, 3]))
def test_a_remembered_context_choice_is_the_fresh_one(seed, n, noise, changed):
    """After the choice for a file whose columns differ in one attribute only, the choice for
    this one equals what a memory that never stores chooses."""
    books, layers = _layers(seed, n, noise)
    other_books, other = _layers(seed, n, noise, changed)
    original = contexts.RECENT
    try:
        contexts.RECENT = RecentChoices(4096)
        choose_index_contexts(other_books, other, Codec.ZLIB)
        remembered = choose_index_contexts(books, layers, Codec.ZLIB)
        again = choose_index_contexts(books, layers, Codec.ZLIB)
        contexts.RECENT = RecentChoices(0)
        fresh = choose_index_contexts(books, layers, Codec.ZLIB)
    finally:
        contexts.RECENT = original
    assert _records(remembered) == _records(again) == _records(fresh)


def _records(records) -> list:
    return [(r.target, r.context, r.table.tobytes()) for r in records]


def test_a_repeated_file_is_chosen_for_once_and_unchanged_columns_are_not_decided_again(
        monkeypatch):
    memory = RecentChoices(4096)
    monkeypatch.setattr(contexts, "RECENT", memory)
    decided = []
    real = contexts._decided
    monkeypatch.setattr(contexts, "_decided", lambda *a: decided.append(a[4]) or real(*a))
    books, layers = _layers(2, 3000, 2)
    first = choose_index_contexts(books, layers, Codec.ZLIB)
    assert first and decided
    count = len(decided)
    assert _records(choose_index_contexts(books, layers, Codec.ZLIB)) == _records(first)
    assert len(decided) == count  # the whole file came from memory
    other_books, other = _layers(2, 3000, 2, changed=3)  # colour DC's columns only
    choose_index_contexts(other_books, other, Codec.ZLIB)
    again = decided[count:]
    # scale 0-2, rotation 3-6, opacity 7 (given any earlier column), colour DC 8-10
    assert again and all(target >= 8 for target in again)


# ---------------------------------------------------------------------------- a whole encode
@pytest.mark.slow  # two whole encodes with the precision search: 10-20 s each
def test_a_size_targeted_file_is_the_same_with_and_without_the_memories(single_torch_thread,
                                                                         monkeypatch):
    """The trials of a size target repeat fits and context choices, and the file finally
    written repeats the trial that fitted: served from memory, the file is byte-identical to
    one encoded with memories that never store, and the memory served something."""
    from spcodec.encoder.config import AllocationConfig, EncoderConfig
    from spcodec.encoder.pipeline import encode
    from spcodec.encoder.presets import preset_config, sized

    scene = make_scene(5, blobs=1500).cloud
    base = preset_config("balanced", EncoderConfig(patch=FAST))
    base = dataclasses.replace(base, patch=dataclasses.replace(base.patch, kmeans_iterations=10,
                                                               kmeans_samples=20_000))
    small = AllocationConfig(sample=3_000, views=2, resolution=64, entry_counts=(256, 64, 16))
    target = int(len(encode(scene, base).data) * 0.7)
    config = dataclasses.replace(sized(base, target), allocation=small)

    monkeypatch.setattr(codebook_fits, "RECENT", RecentFits(0))
    monkeypatch.setattr(contexts, "RECENT", RecentChoices(0))
    without = encode(scene, config).data
    fits, choices = RecentFits(256 << 20), RecentChoices(4096)
    monkeypatch.setattr(codebook_fits, "RECENT", fits)
    monkeypatch.setattr(contexts, "RECENT", choices)
    with_memory = encode(scene, config).data
    assert with_memory == without
    assert len(with_memory) <= target
    assert fits.hits > 0, "the final file repeats the fits of the trial that fitted"
    assert len(choices.entries) > 0


# ---------------------------------------------------------------------------- position grids
def test_grids_that_decode_alike_are_rendered_once_and_measure_alike(single_torch_thread,
                                                                     monkeypatch):
    """Positions already on a coarse power-of-two grid are stored on it whatever the bits
    asked: those grids store the input exactly, add no error and are not rendered; a scene off
    any grid renders only the calibration grids of the displacement model."""
    from spcodec.encoder import allocation
    from spcodec.encoder.allocation import position_options
    from spcodec.encoder.config import AllocationConfig, EncoderConfig
    from spcodec.imaging import render

    scene = make_scene(4, blobs=800).cloud
    small = AllocationConfig(sample=2_000, views=2, resolution=48, position_bits=(8, 10, 12, 14))
    config = EncoderConfig(patch=dataclasses.replace(FAST, position_mode="quant16"))
    calls = []
    real = render.render_image
    monkeypatch.setattr(render, "render_image", lambda *a, **k: calls.append(1) or real(*a, **k))
    rows = np.arange(len(scene))

    on_grid = scene.subset(rows)
    span = float(np.ptp(scene.means.astype(np.float64), axis=0).max())
    step = 2.0 ** np.floor(np.log2(span / 500))  # 500-1000 levels: finer than 8 bits, not 10
    on_grid.means[:] = np.round(on_grid.means / step) * step
    grids = position_options(on_grid, rows, config, small, device="cpu")
    per_set = 2 * small.views
    # the reference (one set), then one set for 8 bits (coarser than the input's grid); 10, 12
    # and 14 store the input as it is
    assert len(calls) == 2 * per_set
    assert grids[1].distortion == grids[2].distortion == grids[3].distortion == 0.0
    assert grids[1].bits_per_gaussian == grids[3].bits_per_gaussian
    assert grids[0].distortion > 0.0
    calls.clear()
    alone = position_options(on_grid, rows, config,
                             dataclasses.replace(small, position_bits=(14,)), device="cpu")
    assert alone[0] == grids[3] and not calls

    calls.clear()
    position_options(scene, rows, config, small, device="cpu")
    assert len(calls) == (1 + len(set(allocation.POSITION_RENDERS))) * per_set


def test_training_views_are_placed_once_per_scene_content(monkeypatch):
    """A size target asks for the search's views four times: they are placed once per scene
    content and settings, equal to a fresh placement; other content or settings place again."""
    from spcodec.encoder import allocation
    from spcodec.encoder.config import AllocationConfig, EncoderConfig
    from spcodec.imaging import views

    scene = make_scene(2, blobs=300).cloud
    small = AllocationConfig(views=2, resolution=32)
    config = EncoderConfig(patch=FAST)
    placed = []
    real = views.sample_views
    monkeypatch.setattr(views, "sample_views", lambda *a, **k: placed.append(1) or real(*a, **k))
    allocation._FRAMINGS.clear()
    first = allocation.training_framings(scene, config, small)
    again = allocation.training_framings(scene.subset(np.arange(len(scene))), config, small)
    def poses(cameras) -> list:
        return [(c.name, c.width, c.fx, c.cx, c.world_to_camera.tolist()) for c in cameras]

    assert len(placed) == 1
    assert all(poses(again[name]) == poses(first[name]) for name in ("orbit", "close"))
    assert poses(first["orbit"]) == poses(real(scene, 2, resolution=(32, 32), split="train",
                                               up=config.up, seed=config.seed))
    first["orbit"][0].world_to_camera[0, 3] += 1.0  # a caller's copy: the memory keeps its own
    assert poses(allocation.training_framings(scene, config, small)["orbit"]) == poses(again["orbit"])
    allocation.training_framings(scene, config, dataclasses.replace(small, views=3))
    moved = scene.subset(np.arange(len(scene)))
    moved.means[0] += 1.0
    allocation.training_framings(moved, config, small)
    assert len(placed) == 3
