"""Seeded encoded scenes for the conformance vectors: small, varied, and built from real Draco blobs.

:mod:`spcodec.synthetic` draws random components of random sizes; the vectors need control over
each choice (how many points a cluster has, which polynomial degrees, kd-tree or sequential Draco,
how large each codebook is) so that every file stays a few kilobytes and covers what it is meant to
cover. Every function takes a ``numpy.random.Generator``: a vector is a function of its seed.
"""

from __future__ import annotations

import numpy as np

from spcodec.attributes import PatchAttribute, SketchAttribute
from spcodec.container import SH_REST_ABSENT, PositionMode
from spcodec.polynomial import monomial_count
from spcodec.sections import Codebook, SketchCluster
from spcodec.synthetic import positions_in_mode
from spcodec.writer import EncodedScene, PatchLayer

Degrees = dict[SketchAttribute, int]


def draco_points(points: np.ndarray, kdtree: bool, bits: int = 14,
                 level: int | None = None) -> tuple[bytes, np.ndarray]:
    """A Draco point cloud of ``points`` and the points it decodes to, in decode order.

    kd-tree blobs (method 1) reorder points; sequential ones (method 0, ``preserve_order``) keep
    the order, which clusters sharing a blob need ([R-47]).
    """
    import DracoPy

    if level is None:
        level = 1 if kdtree else 0
    blob = DracoPy.encode(np.asarray(points, np.float32), quantization_bits=bits,
                          compression_level=level, preserve_order=not kdtree)
    decoded = np.asarray(DracoPy.decode(blob).points, np.float32).reshape(-1, 3)
    if decoded.shape[0] != len(points) or blob[8] != (1 if kdtree else 0):
        raise AssertionError("Draco did not code the points as asked")
    return blob, decoded


def frame_of(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The normalization frame writers use: the points' bounding box ([R-42])."""
    lo, hi = points.min(axis=0), points.max(axis=0)
    return ((lo + hi) / 2).astype(np.float32), np.maximum((hi - lo) / 2, 1e-3).astype(np.float32)


def random_model(rng: np.random.Generator, attribute: SketchAttribute, degree: int, sh_degree: int,
                 density: float = 1.0, scale: float = 0.3) -> np.ndarray:
    """A float16 coefficient matrix of a model; ``density`` < 1 leaves most terms zero (compact
    high-degree models whose non-zero terms still pin down the monomial order)."""
    shape = (monomial_count(degree), attribute.outputs(sh_degree))
    coeffs = rng.normal(0, scale, shape) * (rng.uniform(size=shape) < density)
    if attribute is SketchAttribute.ROTATION:
        coeffs[0, 0] += 2.0  # well away from the identity threshold of
    if attribute is SketchAttribute.OPACITY:
        coeffs[0] += 0.5
    return coeffs.astype(np.float16)


def cluster(rng: np.random.Generator, sh_degree: int, points: int, degrees: Degrees,
            kdtree: bool = True, density: float = 1.0, spread: float = 0.3) -> SketchCluster:
    """A sketch cluster with its own Draco blob and models of the given degrees (an absent
    SH_REST degree, or ``SH_REST_ABSENT``, means no SH-rest model)."""
    centre = rng.uniform(-4, 4, 3)
    blob, decoded = draco_points(centre + rng.normal(0, spread, (points, 3)), kdtree)
    center, half = frame_of(decoded)
    models = {a: random_model(rng, a, d, sh_degree, density)
              for a, d in degrees.items() if d != SH_REST_ABSENT}
    return SketchCluster(blob, points, center, half, models)


def share_blob(clusters: list[SketchCluster]) -> None:
    """Put the clusters' points into one order-preserving blob held by the first ([R-47])."""
    parts = [_points_of(c) for c in clusters]
    blob, shared = draco_points(np.concatenate(parts), kdtree=False, bits=20)
    start = 0
    for c, part in zip(clusters, parts):
        c.center, c.half_extent = frame_of(shared[start:start + len(part)])
        c.draco = b""
        start += len(part)
    clusters[0].draco = blob


def _points_of(c: SketchCluster) -> np.ndarray:
    import DracoPy

    return np.asarray(DracoPy.decode(c.draco).points, np.float32).reshape(-1, 3)


def degrees(scale: int, rotation: int, opacity: int, colour: int,
            rest: int = SH_REST_ABSENT) -> Degrees:
    return {SketchAttribute.SCALE: scale, SketchAttribute.ROTATION: rotation,
            SketchAttribute.OPACITY: opacity, SketchAttribute.COLOR_DC: colour,
            SketchAttribute.SH_REST: rest}


def sketch(rng: np.random.Generator, sh_degree: int, sizes: list[int], runs: list[int] | None = None,
           max_degree: int = 2) -> list[SketchCluster]:
    """Clusters of the given sizes with random degrees up to ``max_degree``; ``runs`` groups
    consecutive clusters into shared blobs (a run of 1 keeps its own kd-tree blob)."""
    out = []
    for n in sizes:
        d = [int(v) for v in rng.integers(0, max_degree + 1, 5)]
        rest = d[4] if sh_degree and rng.integers(0, 2) else SH_REST_ABSENT
        out.append(cluster(rng, sh_degree, n, degrees(*d[:4], rest)))
    start = 0
    for run in runs or []:
        if run > 1:
            share_blob(out[start:start + run])
        start += run
    return out


def codebooks(rng: np.random.Generator, sh_degree: int, entries: int = 8,
              dims: dict[PatchAttribute, int] | None = None) -> list[Codebook]:
    """One small codebook per patch attribute: ``entries`` entries of the given dimension (the
    attribute's whole width by default: vector quantization)."""
    books = []
    for attr in PatchAttribute.for_sh_degree(sh_degree):
        dim = (dims or {}).get(attr, attr.width)
        values = rng.normal(0, 1, (entries, dim))
        if attr is PatchAttribute.OPACITY:
            values = rng.uniform(0.02, 0.98, (entries, dim))
        if attr is PatchAttribute.ROTATION and dim == 4:
            values[:, 0] += 2.0
        books.append(Codebook(attr, values.astype(np.float16)))
    return books


def patch_layer(rng: np.random.Generator, books: list[Codebook], n: int, mode: PositionMode,
                extent: float = 8.0) -> PatchLayer:
    """``n`` patch Gaussians with positions in ``mode`` and random valid indices."""
    xyz = rng.uniform(-extent, extent, (n, 3))
    positions = positions_in_mode(xyz, mode, 2 * extent / 65535)
    indices = {cb.attribute: rng.integers(0, cb.entries.shape[0], (n, cb.groups)).astype(np.uint8)
               for cb in books}
    return PatchLayer(positions, indices)


def scene(seed: int, sh_degree: int, cluster_sizes: list[int], modes: list[PositionMode],
          patch_size: int, runs: list[int] | None = None, entries: int = 8,
          metadata: dict | None = None, max_degree: int = 2) -> EncodedScene:
    """A complete small scene: a sketch, codebooks and one patch layer per position mode."""
    rng = np.random.default_rng(seed)
    clusters = sketch(rng, sh_degree, cluster_sizes, runs, max_degree)
    books = codebooks(rng, sh_degree, entries) if modes else []
    layers = [patch_layer(rng, books, patch_size, mode) for mode in modes]
    return EncodedScene(sh_degree, clusters, books, layers, metadata)
