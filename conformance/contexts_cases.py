"""Vectors of spec 1.2: context-coded patch indices, the ``PATCH_INDEX_CONTEXTS`` section (7.5).

The valid vectors decode index columns stored as ranks through tables of every shape the text
allows: chains (a context that is itself a target), a context of another attribute, tables that
are not square, a row that is not a permutation, an empty record list, and a file whose header
still says 1.1. The invalid ones carry one defect each: every ``bad-section`` and ``bad-value``
rule of [R-105], the rank range of [R-107], and the placement rules of [R-106].
"""

from __future__ import annotations

import dataclasses

import numpy as np

from spcodec.attributes import PatchAttribute
from spcodec.container import PositionMode, SectionType
from spcodec.index_contexts import IndexContext
from spcodec.sections import Codebook, codebook_columns

from . import scenes
from .declare import invalid, valid
from .forge import Draft

_DIMS = {PatchAttribute.SCALE: 1, PatchAttribute.ROTATION: 2, PatchAttribute.COLOR_DC: 1,
         PatchAttribute.SH_BAND_1: 3}
_ENTRIES = {PatchAttribute.SCALE: 5, PatchAttribute.ROTATION: 7, PatchAttribute.OPACITY: 3,
            PatchAttribute.COLOR_DC: 6, PatchAttribute.SH_BAND_1: 4}
"""Columns 0-2 scale (5 entries), 3-4 rotation pairs (7), 5 opacity (3), 6-8 colour DC (6),
9-11 SH band 1 (4): tables of several shapes."""

_RECORDS = ((1, 0), (2, 1), (4, 3), (5, 3), (7, 6), (8, 7), (10, 9), (11, 6))
"""(target, context): chains 0 -> 1 -> 2 and 6 -> 7 -> 8, opacity given a rotation pair, the
last SH column given colour DC."""


def _scene(seed: int = 61):
    """SH degree 1, three patch layers (QUANT16, FLOAT16, DRACO), codebooks of varied sizes."""
    scene = scenes.scene(seed, 1, [4, 3], [PositionMode.QUANT16, PositionMode.FLOAT16,
                                          PositionMode.DRACO], 9)
    rng = np.random.default_rng(seed + 1)
    books = []
    for attr in PatchAttribute.for_sh_degree(1):
        dim = _DIMS.get(attr, attr.width)
        values = rng.normal(0, 1, (_ENTRIES[attr], dim))
        if attr is PatchAttribute.OPACITY:
            values = rng.uniform(0.02, 0.98, values.shape)
        books.append(Codebook(attr, values.astype(np.float16)))
    layers = [dataclasses.replace(layer, indices={
        cb.attribute: rng.integers(0, cb.entries.shape[0], (len(layer), cb.groups)).astype(np.uint8)
        for cb in books}) for layer in scene.patch_layers]
    entries = codebook_columns(books)
    records = []
    for target, context in _RECORDS:
        rows, width = int(entries[context]), int(entries[target])
        table = np.argsort(rng.random((rows, width)), axis=1).astype(np.uint8)
        records.append(IndexContext(target, context, table))
    return dataclasses.replace(scene, codebooks=books, patch_layers=layers, index_contexts=records)


def _draft(seed: int = 61) -> Draft:
    return Draft.of(_scene(seed))


def _contexts_index(draft: Draft) -> int:
    return next(i for i, s in enumerate(draft.sections)
                if s.type == SectionType.PATCH_INDEX_CONTEXTS)


def _with_payload(raw: bytes, seed: int = 62) -> bytes:
    """The valid file with its contexts section's payload replaced (ranks left as written)."""
    draft = _draft(seed)
    i = _contexts_index(draft)
    draft.sections[i] = dataclasses.replace(draft.sections[i], raw=raw)
    return draft.build()


def _record(target: int, context: int, rows: int, width: int, value: int = 0) -> bytes:
    return bytes([target, context]) + bytes([value]) * (rows * width)


@valid("index-contexts", "Version 1.2: index columns coded as ranks given earlier columns through "
       "PATCH_INDEX_CONTEXTS in layer 1, for three patch layers: chains, a context of another "
       "attribute, tables of several shapes, with its prefixes",
       ["R-105", "R-106", "R-107", "R-52", "R-57", "R-92"], prefixes=True)
def contexts_valid() -> bytes:
    return _draft().build()


@valid("index-contexts-table-not-a-permutation", "A table row that repeats a value and leaves "
       "another out: nothing asks a table to be a permutation, the gather reads it as it is",
       ["R-105", "R-107"])
def contexts_not_permutation() -> bytes:
    scene = _scene(63)
    records = list(scene.index_contexts)
    table = records[0].table.copy()
    table[:, :] = table[:, :1]           # every rank of column 1 gives its row's first entry
    records[0] = IndexContext(records[0].target, records[0].context, table)
    layers = []
    for layer in scene.patch_layers:     # column 1 (scale, group 1): the indices it can code
        scale = layer.indices[PatchAttribute.SCALE].copy()
        scale[:, 1] = table[scale[:, 0], 0]
        layers.append(dataclasses.replace(layer, indices={**layer.indices,
                                                          PatchAttribute.SCALE: scale}))
    return Draft.of(dataclasses.replace(scene, patch_layers=layers,
                                        index_contexts=records)).build()


@valid("index-contexts-empty", "A PATCH_INDEX_CONTEXTS section of no record: every column holds "
       "indices, as in a 1.0 file", ["R-105", "R-106"])
def contexts_empty() -> bytes:
    return _with_payload(bytes([0]), 64)


@valid("index-contexts-header-says-1-1", "PATCH_INDEX_CONTEXTS in a file whose header says minor "
       "version 1: decoders do not read the minor version, the sections say what a file needs",
       ["R-92", "R-107"])
def contexts_old_header() -> bytes:
    draft = _draft(65)
    draft.header["version_minor"] = 1
    return draft.build()


# ----------------------------------------------------------------------------- bad payloads
def _bad_payload(id_: str, title: str, code: str, raw: bytes, seed: int) -> None:
    invalid(id_, title, code, ["R-105", "R-106"])(lambda: _with_payload(raw, seed))


# Columns of _scene: 12, entries (5, 5, 5, 7, 7, 3, 6, 6, 6, 4, 4, 4).
_bad_payload("index-contexts-empty-payload", "PATCH_INDEX_CONTEXTS of 0 bytes: no record count",
             "bad-section", b"", 70)
_bad_payload("index-contexts-cut-in-record", "Two records announced, the payload ends after "
             "the first record and one byte of the second", "bad-section",
             bytes([2]) + _record(1, 0, 5, 5) + bytes([2]), 71)
_bad_payload("index-contexts-cut-in-table", "A table one byte shorter than its 5 x 5 entries",
             "bad-section", bytes([1]) + _record(1, 0, 5, 5)[:-1], 72)
_bad_payload("index-contexts-trailing-byte", "A byte after the last record", "bad-section",
             bytes([1]) + _record(1, 0, 5, 5) + b"\0", 73)
_bad_payload("index-contexts-column-out-of-range", "A target column 12 in a file of 12 index "
             "columns (0-11)", "bad-section", bytes([1]) + _record(12, 0, 5, 5), 74)
_bad_payload("index-contexts-context-is-target", "A column given itself as context",
             "bad-section", bytes([1]) + _record(1, 1, 5, 5), 75)
_bad_payload("index-contexts-context-after-target", "A column given a later column",
             "bad-section", bytes([1]) + _record(1, 2, 5, 5), 76)
_bad_payload("index-contexts-targets-decreasing", "Targets 4, then 1", "bad-section",
             bytes([2]) + _record(4, 3, 7, 7) + _record(1, 0, 5, 5), 77)
_bad_payload("index-contexts-target-twice", "Column 1 a target twice", "bad-section",
             bytes([2]) + _record(1, 0, 5, 5) + _record(1, 0, 5, 5), 78)
_bad_payload("index-contexts-table-value-too-large", "A table value 3 for opacity's 3 entries",
             "bad-value", bytes([1]) + _record(5, 3, 7, 3, 2)[:-1] + bytes([3]), 79)


@invalid("index-contexts-rank-out-of-range", "A stored rank of the last patch layer equal to its "
         "column's entry count; --max-layer 1 and 2 decode", "bad-value",
         ["R-52", "R-107"], max_layers=(1, 2))
def contexts_rank_out_of_range() -> bytes:
    draft = _draft(80)
    scene_layers = [s for s in draft.sections if s.type == SectionType.PATCH_ATTRIBUTES]
    last = scene_layers[-1]
    n = len(last.raw) // 12
    raw = bytearray(last.raw)
    raw[4 * n] = 7                       # column 4 (a target, 7 entries), first Gaussian
    draft.sections[draft.sections.index(last)] = dataclasses.replace(last, raw=bytes(raw))
    return draft.build()


# ------------------------------------------------------------------------------- placement
def _moved(layer: int, seed: int) -> bytes:
    draft = _draft(seed)
    sec = draft.sections.pop(_contexts_index(draft))
    draft.insert_after_layer(layer, dataclasses.replace(sec, layer=layer))
    return draft.build()


@invalid("index-contexts-in-layer-2", "PATCH_INDEX_CONTEXTS in layer 2 instead of layer 1",
         "bad-layout", ["R-13", "R-106"])
def contexts_in_layer_2() -> bytes:
    return _moved(2, 81)


@invalid("index-contexts-in-layer-0", "PATCH_INDEX_CONTEXTS in the sketch layer", "bad-layout",
         ["R-13", "R-106"])
def contexts_in_layer_0() -> bytes:
    return _moved(0, 82)


@invalid("index-contexts-twice", "Two PATCH_INDEX_CONTEXTS sections in layer 1",
         "duplicate-section", ["R-13", "R-106"])
def contexts_twice() -> bytes:
    draft = _draft(83)
    i = _contexts_index(draft)
    draft.sections.insert(i, draft.sections[i])
    return draft.build()


@invalid("index-contexts-flagged-optional", "PATCH_INDEX_CONTEXTS with the required flag 0",
         "bad-layout", ["R-14", "R-106"])
def contexts_optional() -> bytes:
    draft = _draft(84)
    i = _contexts_index(draft)
    draft.sections[i] = dataclasses.replace(draft.sections[i], required=False)
    return draft.build()


@invalid("index-contexts-section-crc", "The contexts section fails its CRC", "section-crc",
         ["R-7", "R-106"])
def contexts_crc() -> bytes:
    draft = _draft(85)
    i = _contexts_index(draft)
    draft.sections[i] = dataclasses.replace(draft.sections[i], crc=0)
    return draft.build()
