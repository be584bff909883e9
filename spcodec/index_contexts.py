"""Context-coded patch indices (spec 7.5, format 1.2): the ``PATCH_INDEX_CONTEXTS`` section.

An index column of a patch layer often depends on an earlier one: the G and B coefficients of an
SH band follow the R coefficient, the second rotation pair follows the first. For such a *target*
column the file stores a *rank* per Gaussian, and the index is ``table[context_index, rank]``,
where the table's row for each index of the *context* column lists the target's entries by
decreasing frequency given that index. Ranks concentrate on small values, which zlib and zstd code
in fewer bits than the indices themselves; decoding stays one gather per target column.

This module holds the section's payload (pack, parse and validate), the two transforms (indices
to ranks for the writer, ranks to indices for the decoder) and the rank table a writer derives from
its indices. Choosing which columns get a context is an encoder decision (encoder/contexts.py).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import FormatError

MAX_COLUMNS = 255
"""Column numbers are one byte; a file has at most 56 index columns (every attribute scalar)."""


@dataclass(frozen=True)
class IndexContext:
    """One record of the section: ``target`` is coded given the indices of ``context``.

    ``table`` is (entries of the context's codebook, entries of the target's codebook) uint8:
    row ``c`` maps a rank to the target index for Gaussians whose context index is ``c``.
    """

    target: int
    context: int
    table: np.ndarray

    def __eq__(self, other: object) -> bool:
        return (isinstance(other, IndexContext) and (self.target, self.context)
                == (other.target, other.context) and np.array_equal(self.table, other.table))

    def __hash__(self) -> int:  # pragma: no cover - records are not used as keys
        return hash((self.target, self.context, self.table.tobytes()))


def column_entries(entry_counts: list[int], groups: list[int]) -> np.ndarray:
    """Entry count of every index column, in [R-52] order: each codebook's count per group."""
    return np.repeat(np.asarray(entry_counts, np.int64), groups)


def pack_contexts(contexts: list[IndexContext]) -> bytes:
    """Raw ``PATCH_INDEX_CONTEXTS`` payload ([R-105]): a count, then each record's two column
    numbers and its table, row-major."""
    if len(contexts) > MAX_COLUMNS:
        raise ValueError(f"{len(contexts)} context records, at most {MAX_COLUMNS}")
    parts = [bytes([len(contexts)])]
    for rec in contexts:
        parts.append(bytes([rec.target, rec.context]))
        parts.append(np.ascontiguousarray(rec.table, np.uint8).tobytes())
    return b"".join(parts)


def parse_contexts(raw: bytes, entries: np.ndarray) -> list[IndexContext]:
    """Parse and validate ``PATCH_INDEX_CONTEXTS`` against the columns' entry counts
    (``entries``, from :func:`column_entries`): [R-105], [R-106].

    Structure first (lengths, column numbers, order: ``bad-section``), then values
    (``bad-value``), so every table is sized from column numbers already checked.
    """
    data = memoryview(raw)
    if len(data) < 1:
        raise FormatError("PATCH_INDEX_CONTEXTS is empty: it holds no record count", "bad-section")
    count, pos, previous = data[0], 1, -1
    out = []
    for i in range(count):
        if pos + 2 > len(data):
            raise FormatError(f"PATCH_INDEX_CONTEXTS ends inside record {i}", "bad-section")
        target, context = data[pos], data[pos + 1]
        if target >= len(entries) or context >= len(entries):
            raise FormatError(f"context record {i} names column {max(target, context)}; the file "
                              f"has {len(entries)} index columns", "bad-section")
        if context >= target:
            raise FormatError(f"context record {i}: column {target} is given column {context}, "
                              f"which is not an earlier column", "bad-section")
        if target <= previous:
            raise FormatError(f"context record {i}: target column {target} does not follow "
                              f"{previous}", "bad-section")
        rows, cols = int(entries[context]), int(entries[target])
        start, end = pos + 2, pos + 2 + rows * cols
        if end > len(data):
            raise FormatError(f"PATCH_INDEX_CONTEXTS ends inside the table of record {i}",
                              "bad-section")
        table = np.frombuffer(raw, np.uint8, rows * cols, start).reshape(rows, cols)
        out.append(IndexContext(int(target), int(context), table))
        pos, previous = end, target
    if pos != len(data):
        raise FormatError(f"PATCH_INDEX_CONTEXTS has {len(data) - pos} trailing bytes",
                          "bad-section")
    for i, rec in enumerate(out):
        if rec.table.size and int(rec.table.max()) >= int(entries[rec.target]):
            raise FormatError(f"context record {i}: a table value exceeds column {rec.target}'s "
                              f"{int(entries[rec.target])} codebook entries", "bad-value")
    return out


def resolve_ranks(columns: np.ndarray, contexts: list[IndexContext]) -> np.ndarray:
    """Indices from stored columns ((columns, n) uint8; ranks in the target columns), [R-107].

    Targets are resolved in increasing order, so a context that is itself a target is already an
    index when it is read. One gather per target: ``table[context, rank]``, its flat position
    computed in 16 bits (at most 255 * 256 + 255), which halves the time of an intp index.
    """
    if not contexts:
        return columns
    out = np.array(columns, np.uint8, copy=True)
    for rec in contexts:
        flat = out[rec.context].astype(np.uint16)
        flat *= rec.table.shape[1]
        flat += out[rec.target]
        np.take(rec.table.ravel(), flat, out=out[rec.target])
    return out


def rank_table(context: np.ndarray, target: np.ndarray, context_entries: int,
               target_entries: int) -> np.ndarray:
    """The table whose row ``c`` lists the target's entries by decreasing frequency among the
    Gaussians with context index ``c``, ties (unseen entries included) by increasing index: a
    permutation per row, deterministic, so that rank 0 is the likeliest index."""
    joint = np.bincount(np.asarray(context, np.intp) * target_entries + target,
                        minlength=context_entries * target_entries)
    joint = joint.reshape(context_entries, target_entries)
    # A stable sort of negated counts keeps equal counts in increasing index order.
    return np.argsort(-joint, axis=1, kind="stable").astype(np.uint8)


def to_ranks(columns: np.ndarray, contexts: list[IndexContext]) -> np.ndarray:
    """The stored columns for indices ``columns`` ((columns, n) uint8): each target's index
    replaced by its position in its context's row, the inverse of :func:`resolve_ranks`."""
    if not contexts:
        return columns
    out = np.array(columns, np.uint8, copy=True)
    for rec in contexts:
        rows, width = rec.table.shape
        inverse = np.zeros((rows, width), np.uint8)
        np.put_along_axis(inverse, rec.table.astype(np.intp),
                          np.broadcast_to(np.arange(width, dtype=np.uint8), (rows, width)), axis=1)
        lookup = inverse[columns[rec.context].astype(np.intp), columns[rec.target]]
        if not np.array_equal(np.take(rec.table.ravel(), columns[rec.context].astype(np.intp)
                                      * width + lookup), columns[rec.target]):
            raise ValueError(f"the table of column {rec.target} cannot express its indices")
        out[rec.target] = lookup
    return out
