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

That check compresses each section twice, and the file's own write compresses the chosen ones
again (from memory): on a large patch it was most of the cost of choosing. With zlib, a layer
longer than deflate's 32 KiB window codes each column in its section as it codes alone (no
string match reaches the same row of another column), so such a layer's saving is taken from
its columns' measured savings, counted at :data:`ESTIMATE_TRUST`, instead of compressing its
section without contexts. Short layers, every zstd layer (whose window spans columns), and long
layers whose discounted savings leave the answer in doubt are still compressed both ways.
"""

from __future__ import annotations

import zlib
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from spcodec.container import Codec
from spcodec.index_contexts import IndexContext, pack_contexts, rank_table, to_ranks
from spcodec.sections import Codebook, codebook_columns, pack_indices
from spcodec.writer import PatchLayer

from . import compressions
from .codebook_fits import digest
from .recent import Recent
from .threads import default_jobs

TOC_ENTRY_BYTES = 40
"""What one more section costs in the table of contents (spec 3.3)."""

MIN_ESTIMATED_GAIN = 64
"""Bytes the entropy estimate must promise before a candidate is compressed for real."""

DEFLATE_WINDOW = 32768
"""zlib's largest window: a string match reaches at most this many bytes back."""

ESTIMATE_TRUST = 0.5
"""The share of a long layer's summed column savings the "does it shrink" check counts on: a
section's own saving comes out close to its columns' (within a few percent on real patches),
and half leaves room for the plain stream or zlib's block splits to take some of it."""


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

    def decide(target: int) -> Decided | None:
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
        decided = [d for d in pool.map(decide, range(1, len(entries))) if d is not None]
        chosen = [d.record for d in decided]
        saved = [sum(d.saved[i] for d in decided) for i in range(len(per_layer))]
        if chosen and not _shrinks_file(per_layer, chosen, saved, codec, level, pool):
            chosen = []
    RECENT.put(whole, list(chosen))
    return chosen


@dataclass(frozen=True)
class Decided:
    """A column's context record and the bytes it saves in each layer's column, coded alone."""

    record: IndexContext
    saved: tuple[int, ...]


def _candidates(owner: np.ndarray, target: int) -> list[int]:
    """The columns ``target`` may be coded given: the earlier ones of its attribute, or every
    earlier one when the attribute has a single column."""
    same = [c for c in range(target) if owner[c] == owner[target]]
    return same if same else list(range(target))


def _decided(per_layer: list[np.ndarray], joined: np.ndarray, entries: np.ndarray,
             candidates: list[int], target: int, codec: Codec, level: int | None
             ) -> Decided | None:
    """The context record of column ``target`` when its best candidate saves bytes on the
    file's codec, less its table (None otherwise)."""
    context = _best_candidate(joined, entries, candidates, target)
    if context is None:
        return None
    table = rank_table(joined[context], joined[target], int(entries[context]),
                       int(entries[target]))
    record = IndexContext(target, context, table)
    saved = _layer_savings(per_layer, record, codec, level)
    cost = _column_bytes(record.table.tobytes(), codec, level) + 2  # and the record's two bytes
    return Decided(record, tuple(saved)) if sum(saved) - cost > 0 else None


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


def _layer_savings(per_layer: list[np.ndarray], record: IndexContext, codec: Codec,
                   level: int | None) -> list[int]:
    """Bytes saved in each layer by coding column ``record.target`` as ranks, each column
    compressed alone."""
    saved = []
    for columns in per_layer:
        ranks = to_ranks(columns, [record])[record.target]
        saved.append(_column_bytes(columns[record.target].tobytes(), codec, level)
                     - _column_bytes(ranks.tobytes(), codec, level))
    return saved


def _shrinks_file(per_layer: list[np.ndarray], chosen: list[IndexContext], saved: list[int],
                  codec: Codec, level: int | None, pool: ThreadPoolExecutor) -> bool:
    """Whether the index sections with ``chosen`` plus the contexts section and its table entry
    are smaller than the index sections without, each compressed as the writer compresses it,
    through the encoder's memory of compressions (:mod:`.compressions`): the writer then finds
    the chosen sections there instead of compressing them again.

    A layer longer than deflate's window first counts :data:`ESTIMATE_TRUST` of its ``saved``
    (its columns' savings, coded alone) instead of being compressed both ways; only when that
    leaves the answer short of yes are those layers compressed too."""
    def stored(columns: np.ndarray) -> int:
        raw = columns.tobytes()
        return min(len(compressions.RECENT(codec, raw, level, columns.shape[1])), len(raw))

    def saving(layers: list[np.ndarray]) -> int:
        sizes = list(pool.map(stored, layers + [to_ranks(c, chosen) for c in layers]))
        return sum(sizes[:len(layers)]) - sum(sizes[len(layers):])

    table = pack_contexts(chosen)
    extra = min(len(compressions.RECENT(codec, table, level)), len(table)) + TOC_ENTRY_BYTES
    long = [codec == Codec.ZLIB and columns.shape[1] > DEFLATE_WINDOW for columns in per_layer]
    short = saving([columns for columns, is_long in zip(per_layer, long) if not is_long])
    estimated = ESTIMATE_TRUST * sum(s for s, is_long in zip(saved, long) if is_long)
    if short + estimated > extra:
        return True
    return short + saving([columns for columns, is_long in zip(per_layer, long) if is_long]) > extra
