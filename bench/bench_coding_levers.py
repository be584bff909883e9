"""Two codings item 3 of issue 37 left open, measured before any format change is made for them.

``neighbours FILE.spc ...``: what coding an index column given a spatial neighbour could save.
Each patch layer's columns are read as stored (Draco's kd-tree order, which keeps neighbours
near each other); every second Gaussian is coded given its predecessor, the form a decoder can
still resolve in one gather per column. Two codings of those Gaussians: the index given the
predecessor's index (a rank table per context value, as spec 7.5 does between columns), its
cost the cross-entropy of a table fitted on one half of the layer and applied to the other
(an in-sample entropy of 128 x 128 tables on tens of thousands of values flatters it by several
per cent, table bytes aside); and the difference from the predecessor's index (no table: the
scalar codebooks' entries are sorted, so near values have near indices). Against the columns'
order-0 entropy, which per-column Huffman coding reaches within 1 %::

    python bench/bench_coding_levers.py neighbours guitar-075.spc

``rotations PLY``: rotations stored as their three smallest components (the largest rebuilt
from the unit norm, a 2-bit column saying which) against the four components of today's scalar
codebooks, assigned as the encoder assigns them (the nearest entries at many multiples of the
quaternion, ``encoder.patch.assign_rotation``) and rounded plainly. A shared codebook of E
entries fitted by Lloyd's algorithm to the stored components; bits are the order-0 entropy of
the index columns, errors the angle between input and decoded rotation::

    python bench/bench_coding_levers.py rotations guitar_inria.ply
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from spcodec import read_ply  # noqa: E402
from spcodec.attributes import canonical_rotation  # noqa: E402
from spcodec.decoder.header import read_header  # noqa: E402
from spcodec.decoder.layers import (  # noqa: E402
    load_layer,
    prepare_patch_layer,
    read_codebooks,
    read_index_contexts,
)
from spcodec.encoder.patch import assign_rotation  # noqa: E402
from spcodec.limits import Limits  # noqa: E402

ENTRY_COUNTS = (64, 128, 256)


def entropy_bytes(values: np.ndarray) -> float:
    """Order-0 entropy of ``values`` (small non-negative integers), in bytes."""
    counts = np.bincount(values.astype(np.int64))
    counts = counts[counts > 0].astype(np.float64)
    return float(-(counts * np.log2(counts / counts.sum())).sum() / 8)


def held_out_bytes(values: np.ndarray, context: np.ndarray, entries: int) -> float:
    """Bytes of ``values`` given ``context`` under a conditional table fitted on every other
    value and applied to the rest (both halves, so the total covers every value)."""
    total = 0.0
    for fit in (0, 1):
        train = np.arange(len(values)) % 2 == fit
        table = np.bincount(context[train] * entries + values[train],
                            minlength=entries * entries).reshape(entries, entries) + 0.02
        table /= table.sum(axis=1, keepdims=True)
        total += float(-np.log2(table[context[~train], values[~train]]).sum() / 8)
    return total


def index_columns(data: bytes) -> tuple[list[str], list[int], list[np.ndarray]]:
    """Column names, entry counts, and per patch layer the resolved index columns
    ((columns, n) uint8, in stored order)."""
    limits = Limits()
    header = read_header(data, limits)
    codebooks, contexts, layers = None, [], []
    for index in range(1, len(header.layers)):
        payloads = load_layer(data, header.layers[index], limits)
        if codebooks is None:
            codebooks = read_codebooks(payloads, header)
            contexts = read_index_contexts(payloads, codebooks)
        plan = prepare_patch_layer(payloads, header, index, codebooks, contexts)
        layers.append(np.concatenate([plan.columns[cb.attribute] for cb in codebooks]))
    names = [f"{cb.attribute.name.lower()}[{g}]" for cb in codebooks for g in range(cb.groups)]
    entries = [cb.entries.shape[0] for cb in codebooks for _ in range(cb.groups)]
    return names, entries, layers


def neighbours(path: Path) -> dict:
    """Order-0, neighbour-context and neighbour-difference bytes of every index column."""
    data = path.read_bytes()
    names, entries, layers = index_columns(data)
    rows = []
    for column, (name, count) in enumerate(zip(names, entries)):
        plain = context = difference = 0.0
        for layer in layers:
            values = layer[column].astype(np.int64)
            even, odd = values[0::2], values[1::2]
            before = values[0:2 * len(odd):2]
            plain += entropy_bytes(values)
            context += entropy_bytes(even) + held_out_bytes(odd, before, count)
            difference += entropy_bytes(even) + entropy_bytes((odd - before) % count)
        rows.append({"column": name, "entries": count, "order0_bytes": round(plain),
                     "given_neighbour_bytes": round(context),
                     "neighbour_difference_bytes": round(difference)})
    total = {key: sum(r[key] for r in rows) for key in
             ("order0_bytes", "given_neighbour_bytes", "neighbour_difference_bytes")}
    best = min(total["given_neighbour_bytes"], total["neighbour_difference_bytes"])
    return {"file": path.name, "bytes": len(data), "columns": rows, **total,
            "best_saving_percent_of_file": round(100 * (total["order0_bytes"] - best) / len(data), 2)}


def lloyd(values: np.ndarray, entries: int, iterations: int = 25) -> np.ndarray:
    """A sorted scalar codebook of at most ``entries`` values (Lloyd's algorithm from quantiles)."""
    book = np.unique(np.quantile(values, (np.arange(entries) + 0.5) / entries))
    for _ in range(iterations):
        nearest = np.searchsorted((book[1:] + book[:-1]) / 2, values)
        sums = np.bincount(nearest, values, len(book))
        hits = np.bincount(nearest, minlength=len(book))
        book = np.unique(np.where(hits > 0, sums / np.maximum(hits, 1), book))
    return book


def angles(truth: np.ndarray, coded: np.ndarray) -> np.ndarray:
    """Rotation angle (degrees) between unit quaternions and coded ones (normalized here)."""
    coded = coded / np.linalg.norm(coded, axis=1, keepdims=True)
    return np.degrees(2 * np.arccos(np.clip(np.abs((truth * coded).sum(axis=1)), 0, 1)))


def summary(bits: float, error: np.ndarray) -> dict:
    return {"bits": round(bits, 2), "mean_degrees": round(float(error.mean()), 3),
            "rms_degrees": round(float(np.sqrt((error ** 2).mean())), 3)}


def rotations(path: Path) -> dict:
    """Four scalar components (plainly rounded, and assigned at multiples) against the smallest
    three, at each entry count."""
    quats = canonical_rotation(read_ply(path).quats)
    n = len(quats)
    bits = lambda idx: sum(entropy_bytes(c) for c in idx.T) * 8 / n  # noqa: E731
    largest = np.abs(quats).argmax(axis=1)
    signed = quats * np.sign(quats[np.arange(n), largest])[:, None]
    kept = np.ones_like(quats, bool)
    kept[np.arange(n), largest] = False
    three = signed[kept].reshape(n, 3)
    rows = []
    for count in ENTRY_COUNTS:
        book = lloyd(quats.ravel(), count).astype(np.float16).astype(np.float64)
        plain = np.searchsorted((book[1:] + book[:-1]) / 2, quats)
        multiples = assign_rotation(quats, book[:, None]).astype(np.int64)
        small = lloyd(three.ravel(), count).astype(np.float16).astype(np.float64)
        idx = np.searchsorted((small[1:] + small[:-1]) / 2, three)
        rebuilt = np.zeros_like(quats)
        rebuilt[kept] = small[idx].ravel()
        rebuilt[np.arange(n), largest] = np.sqrt(np.clip(1 - (small[idx] ** 2).sum(axis=1), 0, 1))
        rows.append({"entries": count,
                     "four_rounded": summary(bits(plain), angles(quats, book[plain])),
                     "four_at_multiples": summary(bits(multiples), angles(quats, book[multiples])),
                     "smallest_three": summary(bits(idx) + entropy_bytes(largest) * 8 / n,
                                               angles(quats, rebuilt))})
    return {"scene": path.name, "gaussians": n, "rows": rows}


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    sub.add_parser("neighbours").add_argument("files", nargs="+", type=Path)
    sub.add_parser("rotations").add_argument("scenes", nargs="+", type=Path)
    args = parser.parse_args(argv)
    if args.command == "neighbours":
        for path in args.files:
            print(json.dumps(neighbours(path)), flush=True)
    else:
        for path in args.scenes:
            print(json.dumps(rotations(path)), flush=True)


if __name__ == "__main__":
    main()
