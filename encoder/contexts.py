"""Choosing context-coded index columns (spec 7.5) by measurement, once indices are final.

For every index column, the candidate contexts are the earlier columns of the same attribute (the
G and B of an SH coefficient given its R, colour channels given each other, the second rotation
pair given the first), or every earlier column when the attribute has a single column (a vector
SH band given colour DC). An order-0 entropy of the rank column, computed from the joint
histogram alone, picks each column's best candidate cheaply; the file's own codec then decides:
a context is kept only when the target column's compressed bytes, summed over the patch layers,
drop by more than its table costs compressed. A last check compresses the PATCH_ATTRIBUTES
sections both ways, as the writer does, and drops every context if the file would not shrink,
so contexts never make a file larger.
"""

from __future__ import annotations

import zlib
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from spcodec.container import Codec
from spcodec.index_contexts import IndexContext, pack_contexts, rank_table, to_ranks
from spcodec.sections import Codebook, codebook_columns, pack_indices
from spcodec.writer import PatchLayer

from . import compressions
from .codebook_fits import digest
from .recent import Recent
from .refine import default_jobs

TOC_ENTRY_BYTES = 40
"""What one more section costs in the table of contents (spec 3.3)."""

MIN_ESTIMATED_GAIN = 64
"""Bytes the entropy estimate must promise before a candidate is compressed for real."""


class RecentChoices(Recent):
    """The context choices of recent files, the last ``max_entries``, keyed by the content of
    the columns they read.

    A size target writes the same patch at several precisions, each trial changing only some
    attributes' columns, and the file it keeps repeats one trial: a column's choice, and a
    whole file's, are deterministic for its columns, codec and level, so they are made once."""

    def __init__(self, max_entries: int) -> None:
        super().__init__(max_entries)


RECENT = RecentChoices(4096)
"""The choices :func:`choose_index_contexts` remembers (a column's is a few kB at most)."""


def choose_index_contexts(codebooks: list[Codebook], layers: list[PatchLayer],
                          codec: Codec = Codec.ZLIB, level: int | None = None,
                          jobs: int | None = None) -> list[IndexContext]:
    """The context records that make the patch layers' index sections smallest with ``codec``
    (empty when none pays for itself). Deterministic for given inputs whatever ``jobs``.

    Each column's choice depends only on the indices (a context is read as indices, never as
    ranks), so columns are decided independently, on ``jobs`` threads (None: the cores
    available); zlib and zstd release the GIL while they compress, which is most of the work."""
    if codec == Codec.NONE or not layers or not codebooks:
        return []
    per_layer = [_columns(layer, codebooks) for layer in layers if len(layer)]
    if not per_layer:
        return []
    entries = codebook_columns(codebooks)
    whole = (int(codec), level, tuple(int(e) for e in entries), tuple(cb.groups for cb in codebooks),
             tuple(digest(columns) for columns in per_layer))
    known = RECENT.get(whole)
    if known is not None:
        return list(known)
    joined = np.concatenate(per_layer, axis=1)
    owner = np.repeat(np.arange(len(codebooks)), [cb.groups for cb in codebooks])

    def decide(target: int) -> IndexContext | None:
        if entries[target] < 2:
            return None
        candidates = _candidates(owner, target)
        # the choice reads only these columns: trials that change other attributes repeat it
        read = candidates + [target]
        key = (int(codec), level, target, tuple(read), tuple(int(entries[c]) for c in read),
               tuple(digest(columns[read]) for columns in per_layer))
        return RECENT.get_or_make(key, lambda: _decided(per_layer, joined, entries, candidates,
                                                         target, codec, level))

    with ThreadPoolExecutor(jobs or default_jobs()) as pool:
        chosen = [r for r in pool.map(decide, range(1, len(entries))) if r is not None]
        if chosen and not _shrinks_file(per_layer, chosen, codec, level, pool):
            chosen = []
    RECENT.put(whole, list(chosen))
    return chosen


def _candidates(owner: np.ndarray, target: int) -> list[int]:
    """The columns ``target`` may be coded given: the earlier ones of its attribute, or every
    earlier one when the attribute has a single column."""
    same = [c for c in range(target) if owner[c] == owner[target]]
    return same if same else list(range(target))


def _decided(per_layer: list[np.ndarray], joined: np.ndarray, entries: np.ndarray,
             candidates: list[int], target: int, codec: Codec, level: int | None
             ) -> IndexContext | None:
    """The context record of column ``target`` when its best candidate saves bytes on the
    file's codec (None otherwise)."""
    context = _best_candidate(joined, entries, candidates, target)
    if context is None:
        return None
    table = rank_table(joined[context], joined[target], int(entries[context]),
                       int(entries[target]))
    record = IndexContext(target, context, table)
    return record if _measured_gain(per_layer, record, codec, level) > 0 else None


def _columns(layer: PatchLayer, codebooks: list[Codebook]) -> np.ndarray:
    """A layer's index columns, (columns, n) uint8 in [R-52] order."""
    return np.frombuffer(pack_indices(layer.indices, codebooks), np.uint8).reshape(-1, len(layer))


def _best_candidate(columns: np.ndarray, entries: np.ndarray, candidates: list[int],
                    target: int) -> int | None:
    """The column of ``candidates`` whose rank coding of ``target`` has the smallest order-0
    entropy, when it beats the index column's own by :data:`MIN_ESTIMATED_GAIN` bytes (else
    None)."""
    width = int(entries[target])
    own = _entropy_bytes(np.bincount(columns[target], minlength=width))
    best, best_bytes = None, own - MIN_ESTIMATED_GAIN
    for context in candidates:
        rows = int(entries[context])
        if rows < 2:
            continue
        joint = np.bincount(columns[context].astype(np.intp) * width + columns[target],
                            minlength=rows * width).reshape(rows, width)
        ranks = -np.sort(-joint, axis=1)  # each row by decreasing count: the rank histogram
        cost = _entropy_bytes(ranks.sum(axis=0)) + _table_estimate(joint)
        if cost < best_bytes:
            best, best_bytes = context, cost
    return best


def _entropy_bytes(counts: np.ndarray) -> float:
    """Order-0 entropy of a histogram, in bytes for all its symbols."""
    counts = counts[counts > 0].astype(np.float64)
    total = counts.sum()
    return float(-(counts * np.log2(counts / total)).sum() / 8) if total else 0.0


def _table_estimate(joint: np.ndarray) -> float:
    """A rough compressed size of a rank table: a byte per observed (context, index) pair; rows
    and tails of unseen entries are runs of increasing indices that compress to little."""
    return float(np.count_nonzero(joint))


def _column_bytes(data: bytes, codec: Codec, level: int | None) -> int:
    """Compressed size of one column as the writer codes it (zlib: a block of its own, the
    smaller of the default and Huffman-only strategies, :func:`spcodec.codecs.compress`)."""
    if codec == Codec.ZLIB:
        level = 9 if level is None else level
        sizes = []
        for strategy in (zlib.Z_DEFAULT_STRATEGY, zlib.Z_HUFFMAN_ONLY):
            deflater = zlib.compressobj(level, zlib.DEFLATED, 15, 9, strategy)
            sizes.append(len(deflater.compress(data)) + len(deflater.flush()))
        return min(sizes)
    return len(compressions.RECENT(codec, data, level))


def _measured_gain(per_layer: list[np.ndarray], record: IndexContext, codec: Codec,
                   level: int | None) -> int:
    """Bytes saved over all layers by coding ``record.target`` as ranks, less the table's
    compressed size and the record's two column bytes."""
    saved = 0
    for columns in per_layer:
        ranks = to_ranks(columns, [record])[record.target]
        saved += (_column_bytes(columns[record.target].tobytes(), codec, level)
                  - _column_bytes(ranks.tobytes(), codec, level))
    return saved - _column_bytes(record.table.tobytes(), codec, level) - 2


def _shrinks_file(per_layer: list[np.ndarray], chosen: list[IndexContext], codec: Codec,
                  level: int | None, pool: ThreadPoolExecutor) -> bool:
    """Whether the index sections with ``chosen`` plus the contexts section and its table entry
    are smaller than the index sections without, each compressed as the writer compresses it,
    through the encoder's memory of compressions (:mod:`.compressions`): the writer then finds
    the chosen sections there instead of compressing them again."""
    def stored(columns: np.ndarray) -> int:
        raw = columns.tobytes()
        return min(len(compressions.RECENT(codec, raw, level, columns.shape[1])), len(raw))

    sizes = list(pool.map(stored, per_layer + [to_ranks(c, chosen) for c in per_layer]))
    without, with_contexts = sum(sizes[:len(per_layer)]), sum(sizes[len(per_layer):])
    table = pack_contexts(chosen)
    extra = min(len(compressions.RECENT(codec, table, level)), len(table)) + TOC_ENTRY_BYTES
    return with_contexts + extra < without
