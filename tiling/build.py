"""Build a tileset: partition, then encode every node on its own, leaves first.

Each node is an ordinary ``.spc`` made by the no-retrain encoder (``nodes/<id>.spc``); a leaf
encodes its share of the input, an inner node the merge of its children's Gaussians
(:mod:`.grouping`), so every node holds about ``leaf_size`` Gaussians and one encode's memory follows
that setting, not the scene. Beside each file a small JSON records the digest of what the node was
made from; a re-run whose digest matches reuses the file (resume after a crash or a new setting).

Geometric error (the 3D Tiles field that drives refinement): 0 at a leaf, which holds the input
itself; at an inner node, the merge's spatial error (a high quantile, by weight, of how far the
Gaussians it replaced moved, :func:`.grouping.merge_level`) plus the largest of its children's. An
input Gaussian reaches the node through one merge per level, and by the triangle inequality it
has moved at most the sum of those moves, so the error grows with every level up the tree, as
the detail a coarser level loses does; the largest single move, used before, was set by a few
stray Gaussians and hardly grew from level to level.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from spcodec.fileio import atomic_write

from .grouping import merge_level
from .merge import MergedLevel, covariances
from .partition import leaf_path
from .rows import cloud_to_rows, rows_to_cloud

FAIL_ONCE_ENV = "SPCODEC_TILING_FAIL_ONCE"
"""Test hook: node ids (comma-separated) whose first attempt raises, to exercise retries."""

FORMAT_VERSION = 5
"""Bumped when a node's content would change for the same input (part of every digest)."""


@dataclass(frozen=True)
class NodeJob:
    """What one node task needs: picklable, so it can travel to a worker process."""

    id: str
    children: tuple[str, ...]
    leaf_digest: str | None
    out_dir: str
    preset: str
    seed: int
    branching: int
    sketch: bool
    """Whether the encode may build a sketch (:attr:`.config.TilingConfig.sketch`)."""
    precision_search: bool = False
    """Whether this node is its preset's point of the curve
    (:meth:`.config.TilingConfig.searches`)."""


def build_node(job: NodeJob, children: list[dict]) -> dict:
    """Encode one node (or reuse its file) and return its record (count, bytes, box, error...).

    ``children`` are the children's records, in order: an inner node merges their Gaussians.
    """
    out = Path(job.out_dir)
    config = encoder_config(job)
    digest = node_digest(job, [c["digest"] for c in children], config.to_json())
    record_path = out / "nodes" / f"{job.id}.json"
    previous = _reusable(record_path, digest, out, job)
    if previous is not None:
        if not cloud_path(out, job).is_file():  # the work folder was removed: the parent merges it
            _save_rows(cloud_path(out, job), cloud_to_rows(merge_children(out, job, children).cloud))
        return {**previous, "encoded": False}
    record_path.unlink(missing_ok=True)  # its files are about to change: never pair old and new
    _maybe_fail(job.id, out)
    start, cpu_start = time.perf_counter(), time.process_time()
    if job.children:
        level = merge_children(out, job, children)
        cloud, capped = level.cloud, level.capped
        error = level.spatial_error + max(c["error"] for c in children)
        _save_rows(cloud_path(out, job), cloud_to_rows(cloud))
    else:
        cloud, error, capped = rows_to_cloud(np.load(leaf_path(out / "work", job.id))), 0.0, 0
    merge_cpu = time.process_time() - cpu_start
    from spcodec.encoder import encode

    result = encode(cloud, config, source_name=f"tile {job.id}")
    atomic_write(out / "nodes" / f"{job.id}.spc", result.data)
    lo, hi = content_box(cloud)
    for child in children:
        lo, hi = np.minimum(lo, child["box"][0]), np.maximum(hi, child["box"][1])
    record = {"id": job.id, "digest": digest,
              "cloud": cloud_path(out, job).relative_to(out).as_posix(),
              "count": int(len(result.source_index)), "input_count": len(cloud),
              "bytes": len(result.data),
              "box": [lo.tolist(), hi.tolist()], "error": float(error), "capped": capped,
              "seconds": time.perf_counter() - start,
              # CPU of this process, every thread: the merge (or a leaf's load) and the whole node
              "merge_cpu_seconds": merge_cpu, "cpu_seconds": time.process_time() - cpu_start}
    atomic_write(record_path, json.dumps(record).encode())
    return {**record, "encoded": True}


def merge_children(out: Path, job: NodeJob, children: list[dict]) -> MergedLevel:
    """The coarser level of an inner node: its children's Gaussians merged (deterministic)."""
    finer = rows_to_cloud(np.concatenate([np.load(out / c["cloud"]) for c in children]))
    return merge_level(finer, job.branching)


def encoder_config(job: NodeJob):
    """The no-retrain encoder settings every node of the tileset is encoded with.

    One process per encode (``n_jobs=1``): nodes run side by side on the engine's workers, one
    core each, and a worker may not start processes of its own; a pool per small encode would
    also cost more to start than it saves. ``n_jobs`` changes no byte of the file, so it is no
    part of the digest (:meth:`EncoderConfig.to_json` leaves it out). ``job.sketch`` can only
    take the preset's sketch away, never add one to a preset that has none; ``use_sketch`` is in
    the digest, so switching it re-encodes every node. Nodes keep the preset's own codebook
    shapes (``point=False``) unless ``job.precision_search``: a single file's precision search
    (DECISIONS D-33) is a fixed cost that every node pays (docs/LOG.md 26.3).
    """
    from spcodec.encoder import preset_config

    config = preset_config(job.preset, point=job.precision_search)
    return dataclasses.replace(config, seed=job.seed, n_jobs=1,
                               use_sketch=config.use_sketch and job.sketch)


def node_digest(job: NodeJob, child_digests: list[str], settings: dict) -> str:
    """What decides a node's file: its leaf rows or its children's digests (a merge is
    deterministic), the merge's branching and the encoder settings."""
    doc = {"version": FORMAT_VERSION, "leaf": job.leaf_digest, "children": child_digests,
           "branching": job.branching, "settings": settings}
    return hashlib.sha256(json.dumps(doc, sort_keys=True, default=str).encode()).hexdigest()


def cloud_path(out: Path, job: NodeJob) -> Path:
    """The Gaussians node ``job`` is encoded from, which its parent merges: a leaf's spilled
    rows, or an inner node's merged level."""
    if not job.children:
        return leaf_path(out / "work", job.id)
    return out / "work" / "clouds" / f"{job.id}.npy"


def content_box(cloud) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned box holding every Gaussian out to three standard deviations."""
    reach = 3.0 * np.sqrt(np.maximum(np.diagonal(covariances(cloud), axis1=1, axis2=2), 0.0))
    means = cloud.means.astype(np.float64)
    return (means - reach).min(axis=0), (means + reach).max(axis=0)


def _reusable(record_path: Path, digest: str, out: Path, job: NodeJob) -> dict | None:
    """The recorded node when its file exists and was made from the same input (its merged
    Gaussians, which only its parent needs, may be missing: the caller makes them again)."""
    try:
        record = json.loads(record_path.read_text())
    except (OSError, ValueError):
        return None
    spc = out / "nodes" / f"{job.id}.spc"
    if record.get("digest") != digest or not spc.is_file() or spc.stat().st_size != record["bytes"]:
        return None
    return record


def _save_rows(path: Path, rows: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(path, lambda fh: np.save(fh, rows))


def _maybe_fail(node_id: str, out: Path) -> None:
    """The fault-injection hook (:data:`FAIL_ONCE_ENV`): fail a listed node's first attempt,
    leaving a marker so the retry goes through."""
    listed = os.environ.get(FAIL_ONCE_ENV, "")
    if node_id not in listed.split(","):
        return
    marker = out / "work" / f"failed-once-{node_id}"
    if not marker.exists():
        marker.touch()
        raise RuntimeError(f"injected failure of node {node_id} ({FAIL_ONCE_ENV})")
