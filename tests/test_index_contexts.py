"""Context-coded patch indices (format 1.2, spec 7.5): the transforms, the section's rules, the
decoder, the writer's version and the encoder's choice."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import spcodec
from spcodec.container import CONTEXTS_MINOR, Codec, SectionType
from spcodec.decoder import header as header_module
from spcodec.encoder.contexts import choose_index_contexts
from spcodec.errors import FormatError
from spcodec.index_contexts import (
    IndexContext,
    pack_contexts,
    parse_contexts,
    rank_table,
    resolve_ranks,
    to_ranks,
)
from spcodec.sections import Codebook, codebook_columns, pack_indices
from spcodec.synthetic import random_encoded_scene
from spcodec.writer import WriteOptions, assemble, build_bitstream, scene_sections

FIELDS = ("means", "scales", "quats", "opacities", "sh_dc", "sh_rest")


def _code(fn) -> str:
    with pytest.raises(FormatError) as err:
        fn()
    return err.value.code


def _same(a, b) -> bool:
    return all(np.array_equal(getattr(a, f), getattr(b, f)) for f in FIELDS)


@st.composite
def columns_and_contexts(draw):
    """Random index columns and a random valid set of context records (chains included), with
    each table a random permutation per row, so that every index has a rank."""
    n_cols = draw(st.integers(1, 7))
    n = draw(st.integers(0, 60))
    seed = draw(st.integers(0, 2**31 - 1))
    rng = np.random.default_rng(seed)
    entries = rng.integers(1, 257, n_cols)
    columns = np.stack([rng.integers(0, e, n) for e in entries]).astype(np.uint8) \
        if n else np.zeros((n_cols, 0), np.uint8)
    targets = sorted(draw(st.sets(st.integers(1, max(1, n_cols - 1)), max_size=n_cols - 1))) \
        if n_cols > 1 else []
    contexts = []
    for t in targets:
        c = int(rng.integers(0, t))
        table = np.argsort(rng.random((int(entries[c]), int(entries[t]))), axis=1)
        contexts.append(IndexContext(t, c, table.astype(np.uint8)))
    return columns, entries, contexts


@given(columns_and_contexts())
def test_ranks_decode_back_to_the_indices_for_any_tables(case):
    columns, entries, contexts = case
    ranks = to_ranks(columns, contexts)
    for rec in contexts:                                   # ranks obey like indices
        assert ranks[rec.target].size == 0 or ranks[rec.target].max() < entries[rec.target]
    np.testing.assert_array_equal(resolve_ranks(ranks, contexts), columns)
    parsed = parse_contexts(pack_contexts(contexts), entries)
    assert parsed == contexts


@given(st.integers(1, 256), st.integers(1, 256), st.integers(0, 500), st.integers(0, 2**31 - 1))
def test_rank_tables_are_deterministic_permutations_by_decreasing_frequency(ec, et, n, seed):
    rng = np.random.default_rng(seed)
    ctx = rng.integers(0, ec, n)
    tgt = np.minimum(ctx % et + rng.integers(0, 3, n), et - 1)
    table = rank_table(ctx, tgt, ec, et)
    assert table.shape == (ec, et)
    assert (np.sort(table, axis=1) == np.arange(et)).all()         # a permutation per row
    np.testing.assert_array_equal(table, rank_table(ctx, tgt, ec, et))
    for row in np.unique(ctx)[:5]:
        counts = np.bincount(tgt[ctx == row], minlength=et)[table[row].astype(int)]
        assert (np.diff(counts) <= 0).all()                        # decreasing frequency
        ties = table[row][counts == 0].astype(int)
        assert (np.diff(ties) > 0).all()                           # unseen: by index


ENTRIES = np.array([4, 3, 5])


@pytest.mark.parametrize("raw, code", [
    (b"", "bad-section"),                                      # no count
    (bytes([1, 1]), "bad-section"),                            # record header cut
    (bytes([1, 1, 0]) + bytes(11), "bad-section"),             # table cut (4 x 3 = 12)
    (bytes([1, 1, 0]) + bytes(12) + b"\0", "bad-section"),     # trailing byte
    (bytes([1, 3, 0]) + bytes(20), "bad-section"),             # target out of range
    (bytes([1, 1, 1]) + bytes(9), "bad-section"),              # context == target
    (bytes([1, 1, 2]) + bytes(15), "bad-section"),             # context after target
    (bytes([2, 2, 0]) + bytes(20) + bytes([1, 0]) + bytes(12), "bad-section"),  # not increasing
    (bytes([2, 1, 0]) + bytes(12) + bytes([1, 0]) + bytes(12), "bad-section"),  # twice
    (bytes([1, 1, 0]) + bytes(11) + bytes([3]), "bad-value"),  # value >= E_target
])
def test_malformed_sections_are_refused(raw, code):
    assert _code(lambda: parse_contexts(raw, ENTRIES)) == code


def test_an_empty_record_list_is_valid():
    assert parse_contexts(bytes([0]), ENTRIES) == []


# ---------------------------------------------------------------------------- files
def _scene_with_contexts(seed: int = 3):
    scene = random_encoded_scene(seed, patch_layers=3, patch_size=120, sh_degree=1)
    entries = codebook_columns(scene.codebooks)
    cols = np.concatenate([np.frombuffer(pack_indices(layer.indices, scene.codebooks), np.uint8)
                           .reshape(-1, len(layer)) for layer in scene.patch_layers if len(layer)],
                          axis=1)
    records = [IndexContext(t, t - 1, rank_table(cols[t - 1], cols[t], int(entries[t - 1]),
                                                 int(entries[t])))
               for t in range(1, len(entries)) if t % 2]
    return scene, dataclasses.replace(scene, index_contexts=records)


def test_a_file_with_contexts_decodes_to_the_same_gaussians_and_says_1_2():
    plain, coded = _scene_with_contexts()
    data = build_bitstream(coded)
    assert int.from_bytes(data[10:12], "little") == CONTEXTS_MINOR
    assert int.from_bytes(build_bitstream(plain)[10:12], "little") == 0
    info = spcodec.inspect(data).to_json()
    assert [s["layer"] for s in info["sections"] if s["type"] == "PATCH_INDEX_CONTEXTS"] == [1]
    assert _same(spcodec.decode(data), spcodec.decode(build_bitstream(plain)))
    for k in range(len(plain.patch_layers) + 1):                        # prefixes and K
        assert _same(spcodec.decode(data, max_layer=k), spcodec.decode(build_bitstream(plain),
                                                                       max_layer=k))


def test_a_1_1_decoder_refuses_the_layers_that_need_the_section(monkeypatch):
    """A decoder that does not know the type (1.1's, simulated by forgetting it) rejects the
    patch layers ([R-21]) and still decodes layer 0, the sketch."""
    plain, coded = _scene_with_contexts()
    data = build_bitstream(coded)
    monkeypatch.delitem(header_module.KNOWN_SECTIONS, SectionType.PATCH_INDEX_CONTEXTS)
    with pytest.raises(FormatError) as err:
        spcodec.decode(data)
    assert err.value.code == "unknown-required-section"
    sketch = spcodec.decode(data, max_layer=0)
    assert len(sketch) > 0 and _same(sketch, spcodec.decode(build_bitstream(plain), max_layer=0))


def test_a_1_2_decoder_reads_the_section_whatever_minor_version_the_header_says():
    plain, coded = _scene_with_contexts()
    sections, layers = scene_sections(coded)
    old = assemble(sections, layers, coded.sh_degree, header_overrides={"version_minor": 1})
    assert _same(spcodec.decode(old), spcodec.decode(build_bitstream(plain)))


def _forged(edit) -> bytes:
    _, coded = _scene_with_contexts()
    sections, layers = scene_sections(coded)
    edit(sections)
    return assemble(sections, layers, coded.sh_degree)


def _contexts_at(sections) -> int:
    return next(i for i, s in enumerate(sections) if s.type == SectionType.PATCH_INDEX_CONTEXTS)


def _decode_code(data: bytes) -> str:
    return _code(lambda: spcodec.decode(data))


def test_placement_and_flag_rules():
    def moved_to_layer_2(sections):
        sec = sections.pop(_contexts_at(sections))
        at = next(i for i, s in enumerate(sections) if s.layer == 2)
        sections.insert(at, dataclasses.replace(sec, layer=2))

    def twice(sections):
        i = _contexts_at(sections)
        sections.insert(i, sections[i])

    def optional(sections):
        i = _contexts_at(sections)
        sections[i] = dataclasses.replace(sections[i], required=False)

    def cut(sections):
        i = _contexts_at(sections)
        sections[i] = dataclasses.replace(sections[i], raw=sections[i].raw[:-1])

    assert _decode_code(_forged(moved_to_layer_2)) == "bad-layout"
    assert _decode_code(_forged(twice)) == "duplicate-section"
    assert _decode_code(_forged(optional)) == "bad-layout"
    assert _decode_code(_forged(cut)) == "bad-section"


def test_stored_ranks_keep_the_index_range_rule():
    _, coded = _scene_with_contexts()
    target = coded.index_contexts[0].target

    def bad_rank(sections):
        i = next(i for i, s in enumerate(sections) if s.type == SectionType.PATCH_ATTRIBUTES)
        n = len(coded.patch_layers[0])
        raw = bytearray(sections[i].raw)
        raw[target * n] = 255
        sections[i] = dataclasses.replace(sections[i], raw=bytes(raw))

    entries = codebook_columns(coded.codebooks)
    assert entries[target] < 256
    assert _decode_code(_forged(bad_rank)) == "bad-value"


# ---------------------------------------------------------------------------- encoder
def _correlated_scene(seed: int, n: int, noise: int):
    """A scene whose SH band is scalar-coded with G and B close to R, as real SH rest is."""
    scene = random_encoded_scene(seed, patch_layers=2, patch_size=10, sh_degree=1)
    rng = np.random.default_rng(seed)
    books = []
    for cb in scene.codebooks:
        dim = 1 if cb.attribute.width in (3, 9) else cb.entry_dim
        books.append(Codebook(cb.attribute, rng.normal(0, 1, (64, dim)).astype(np.float16)))
    layers = []
    for size in (n // 4, n - n // 4):
        indices = {}
        for cb in books:
            base = rng.integers(0, 64, (size, 1))
            jitter = rng.integers(-noise, noise + 1, (size, cb.groups))
            indices[cb.attribute] = np.clip(base + jitter, 0, 63).astype(np.uint8)
        layers.append(dataclasses.replace(scene.patch_layers[0], indices=indices,
                                          positions=type(scene.patch_layers[0].positions)
                                          .float16(rng.normal(0, 1, (size, 3)))))
    return dataclasses.replace(scene, codebooks=books, patch_layers=layers)


@settings(max_examples=15, deadline=None)
@given(st.integers(0, 2**31 - 1), st.integers(0, 3000), st.integers(0, 40),
       st.sampled_from([Codec.ZLIB, Codec.ZSTD]))
def test_chosen_contexts_never_make_the_file_bigger(seed, n, noise, codec):
    scene = _correlated_scene(seed, n, noise)
    contexts = choose_index_contexts(scene.codebooks, scene.patch_layers, codec)
    options = WriteOptions(codec=codec)
    with_contexts = build_bitstream(dataclasses.replace(scene, index_contexts=contexts), options)
    assert len(with_contexts) <= len(build_bitstream(scene, options))
    assert _same(spcodec.decode(with_contexts), spcodec.decode(build_bitstream(scene, options)))


def test_correlated_columns_get_contexts_that_pay():
    scene = _correlated_scene(7, 20_000, 2)
    contexts = choose_index_contexts(scene.codebooks, scene.patch_layers, Codec.ZLIB)
    assert contexts, "columns within 2 of each other must be worth a context"
    assert all(rec.context < rec.target for rec in contexts)
    smaller = build_bitstream(dataclasses.replace(scene, index_contexts=contexts))
    assert len(smaller) < 0.9 * len(build_bitstream(scene))
    assert choose_index_contexts(scene.codebooks, scene.patch_layers, Codec.NONE) == []



def _index_sections(scene, contexts) -> list[bytes]:
    sections, _ = scene_sections(dataclasses.replace(scene, index_contexts=contexts))
    return [s.raw for s in sections if s.type == SectionType.PATCH_ATTRIBUTES]


@settings(max_examples=4, deadline=None)
@given(st.integers(0, 2**31 - 1), st.integers(0, 6))
def test_a_layer_longer_than_the_window_is_judged_by_its_columns_and_never_grows(seed, noise):
    """A layer of more rows than deflate's window is not compressed without contexts when its
    columns' savings settle the "does it shrink" check; the choice is the exact check's and the
    file is never larger."""
    from spcodec.encoder import compressions
    from spcodec.encoder import contexts as contexts_module

    scene = _correlated_scene(seed, 48_000, noise)  # layers of 12,000 and 36,000 rows
    assert len(scene.patch_layers[1]) > contexts_module.DEFLATE_WINDOW
    memory = compressions.RecentCompressions(64 << 20)
    compressed = []
    real = compressions.compress
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(compressions, "RECENT", memory)
        patch.setattr(contexts_module, "RECENT", contexts_module.RecentChoices(4096))
        patch.setattr(compressions, "compress",
                      lambda codec, raw, *a: compressed.append(bytes(raw)) or real(codec, raw, *a))
        chosen = choose_index_contexts(scene.codebooks, scene.patch_layers, Codec.ZLIB)
        first = list(compressed)
        patch.setattr(contexts_module, "RECENT", contexts_module.RecentChoices(4096))
        patch.setattr(contexts_module, "DEFLATE_WINDOW", 1 << 30)  # every layer checked exactly
        exact = choose_index_contexts(scene.codebooks, scene.patch_layers, Codec.ZLIB)
    assert [(r.target, r.context) for r in chosen] == [(r.target, r.context) for r in exact]
    if chosen and noise <= 2:  # columns within 2 of each other: the savings settle it
        long_without = _index_sections(scene, [])[1]
        assert long_without not in first
    with_contexts = build_bitstream(dataclasses.replace(scene, index_contexts=chosen))
    assert len(with_contexts) <= len(build_bitstream(scene))


# ---------------------------------------------------------------------------- vectors
def test_the_vectors_of_spec_1_2_cover_each_rule():
    from spcodec.conformance import load_manifest

    suite = load_manifest()
    outcomes = {v.id: v.outcomes[0] for v in suite.vectors if v.id.startswith("index-contexts")}
    assert all(outcomes[v].accepts for v in ("index-contexts", "index-contexts-empty",
                                             "index-contexts-table-not-a-permutation",
                                             "index-contexts-header-says-1-1"))
    errors = {v: o.error for v, o in outcomes.items() if not o.accepts}
    assert sorted(set(errors.values())) == ["bad-layout", "bad-section", "bad-value",
                                            "duplicate-section", "section-crc"]
    assert sum(code == "bad-section" for code in errors.values()) == 9   # one per rule
    assert tuple(int(part) for part in suite.spec_version.split(".")[:2]) >= (1, 2)


def test_the_encoding_chooses_once_per_codec_and_only_when_asked():
    from spcodec.encoder.patch import PatchEncoding

    scene = _correlated_scene(11, 4000, 2)
    on = PatchEncoding(scene.codebooks, scene.patch_layers, [], index_contexts=True)
    chosen = on.contexts_for(Codec.ZLIB, None)
    assert chosen and on.contexts_for(Codec.ZLIB, None) is chosen         # chosen once
    assert on.contexts_for(Codec.NONE, None) == []
    off = PatchEncoding(scene.codebooks, scene.patch_layers, [], index_contexts=False)
    assert off.contexts_for(Codec.ZLIB, None) == []
    assert dataclasses.replace(on, layers=scene.patch_layers[:1])._chosen == {}  # not inherited


def test_the_writer_reuses_the_index_sections_the_check_compressed(monkeypatch):
    """The "does the file shrink" check compresses every index section with the chosen
    contexts exactly as the writer does: writing the file then compresses none of them again."""
    from spcodec.encoder import compressions
    from spcodec.encoder import contexts as contexts_module
    from spcodec.writer import write_file

    monkeypatch.setattr(compressions, "RECENT", compressions.RecentCompressions(64 << 20))
    # a fresh memory of choices too: one remembered from an earlier test compresses nothing
    monkeypatch.setattr(contexts_module, "RECENT", contexts_module.RecentChoices(4096))
    scene = _correlated_scene(5, 6000, 2)
    contexts = choose_index_contexts(scene.codebooks, scene.patch_layers, Codec.ZLIB)
    assert contexts
    compressed = []
    real = compressions.compress
    monkeypatch.setattr(compressions, "compress",
                        lambda codec, raw, *a: compressed.append(bytes(raw)) or real(codec, raw, *a))
    sections, _ = scene_sections(dataclasses.replace(scene, index_contexts=contexts))
    data = write_file(dataclasses.replace(scene, index_contexts=contexts),
                      compressor=compressions.RECENT).data  # as the encoder's writer does
    indices = [s.raw for s in sections if s.type == SectionType.PATCH_ATTRIBUTES]
    assert compressed, "the other sections were compressed"
    assert len(indices) == 2 and not any(raw in compressed for raw in indices)
    assert _same(spcodec.decode(data), spcodec.decode(build_bitstream(scene)))
