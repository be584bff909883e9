"""Built-in synthetic scenes with known structure, for the demo, tests and conformance vectors.

:func:`make_scene` draws Gaussians along lines, arcs and helices, elongated along the curve's tangent
with colour, size and opacity varying smoothly along it (what the paper calls sketch Gaussians), plus
scattered isotropic blobs with random attributes (patch Gaussians). The ground truth says which is
which, so categorization can be scored.

:func:`random_encoded_scene` draws already-encoded components (Draco blobs, coefficients, codebooks,
indices) directly, to exercise the format without an encoder.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .attributes import PatchAttribute, SketchAttribute
from .cloud import SH_REST_COUNTS, GaussianCloud
from .container import PositionMode
from .polynomial import monomial_count
from .sections import Codebook, PatchPositions, SketchCluster
from .writer import EncodedScene, PatchLayer


@dataclass
class SyntheticScene:
    """A generated scene and its ground truth."""

    cloud: GaussianCloud
    structured: np.ndarray
    """Boolean mask: True for Gaussians drawn along a curve."""
    curve_id: np.ndarray
    """Index of the curve each structured Gaussian belongs to, -1 for blobs."""


def _quat_from_x_to(v: np.ndarray) -> np.ndarray:
    """Unit quaternions (w, x, y, z) rotating the x axis onto the unit vectors ``v``."""
    x = np.array([1.0, 0.0, 0.0])
    dot = v @ x
    axis = np.cross(np.broadcast_to(x, v.shape), v)
    q = np.concatenate([(1.0 + dot)[:, None], axis], axis=1)
    opposite = (1.0 + dot) < 1e-9
    q[opposite] = (0.0, 0.0, 0.0, 1.0)
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def _curve_points(kind: int, t: np.ndarray, rng: np.random.Generator, size: float) -> np.ndarray:
    """Points along a random line, arc or helix, for parameters t in [0, 1]."""
    centre = rng.uniform(-0.6, 0.6, 3) * size
    if kind == 0:  # straight line
        direction = rng.normal(size=3)
        direction /= np.linalg.norm(direction)
        return centre + np.outer(t - 0.5, direction) * size * rng.uniform(0.5, 0.9)
    u, w = np.linalg.qr(rng.normal(size=(3, 3)))[0][:, :2].T
    radius = size * rng.uniform(0.15, 0.35)
    angle = t * rng.uniform(1.0, 2.5) * np.pi
    ring = np.outer(np.cos(angle), u) + np.outer(np.sin(angle), w)
    if kind == 1:  # circular arc
        return centre + radius * ring
    normal = np.cross(u, w)  # helix
    return centre + radius * ring + np.outer(t - 0.5, normal) * size * 0.4


def make_scene(seed: int = 0, curves: int = 12, per_curve: int = 400, blobs: int = 3000,
               sh_degree: int = 3, size: float = 1.0) -> SyntheticScene:
    """A scene of ``curves`` structured curves and ``blobs`` scattered Gaussians."""
    rng = np.random.default_rng(seed)
    parts, ids = [], []
    k = SH_REST_COUNTS[sh_degree]
    for c in range(curves):
        t = np.sort(rng.uniform(0, 1, per_curve))
        pts = _curve_points(c % 3, t, rng, size)
        tangent = np.gradient(pts, axis=0)
        tangent /= np.linalg.norm(tangent, axis=1, keepdims=True) + 1e-12
        base_colour = rng.uniform(-1.2, 1.2, 3)
        colour_slope = rng.uniform(-0.6, 0.6, 3)
        spacing = np.linalg.norm(np.diff(pts, axis=0), axis=1).mean()
        long_axis = np.log(spacing * (2.0 + 1.0 * np.sin(np.pi * t)))
        short_axis = np.log(spacing * 0.35) + 0.1 * t
        parts.append(GaussianCloud(
            means=pts,
            scales=np.stack([long_axis, short_axis, short_axis - 0.2], axis=1),
            quats=_quat_from_x_to(tangent),
            opacities=1.5 + 1.0 * np.cos(np.pi * t),
            sh_dc=base_colour + np.outer(t, colour_slope),
            sh_rest=(np.outer(t, rng.normal(0, 0.05, 3 * k)) + rng.normal(0, 0.05, 3 * k)
                     ).reshape(per_curve, k, 3),
        ))
        ids.append(np.full(per_curve, c))
    q = rng.normal(size=(blobs, 4))
    blob_means = rng.uniform(-0.8, 0.8, (blobs, 3)) * size
    # Like trained scenes, blob colour varies smoothly over space (plus noise) and the higher SH
    # bands are small (real captures: standard deviation ~0.05-0.07); uniformly random colours
    # and SH would be harder to code than any real scene.
    field_colour = np.sin(2.5 * blob_means / size + np.array([0.0, 1.0, 2.0])) * 1.2
    parts.append(GaussianCloud(
        means=blob_means,
        scales=np.log(rng.uniform(0.01, 0.04, (blobs, 3)) * size),
        quats=q / np.linalg.norm(q, axis=1, keepdims=True),
        opacities=rng.uniform(-2.0, 2.0, blobs),
        sh_dc=field_colour + rng.normal(0, 0.3, (blobs, 3)),
        sh_rest=rng.normal(0, 0.05, (blobs, k, 3)),
    ))
    ids.append(np.full(blobs, -1))
    curve_id = np.concatenate(ids)
    return SyntheticScene(GaussianCloud.concat(parts), curve_id >= 0, curve_id)


# ------------------------------------------------------------------- random encoded components
def random_cluster(rng: np.random.Generator, sh_degree: int, points: int | None = None,
                   with_sh_rest: bool | None = None, max_degree: int = 3) -> SketchCluster:
    """A cluster with real Draco positions and random small float16 models."""
    import DracoPy

    n = int(points if points is not None else rng.integers(1, 60))
    centre = rng.uniform(-5, 5, 3)
    pts = (centre + rng.normal(0, 0.3, (n, 3))).astype(np.float32)
    blob = DracoPy.encode(pts, quantization_bits=14, compression_level=1)
    decoded = np.asarray(DracoPy.decode(blob).points, dtype=np.float32).reshape(-1, 3)
    lo, hi = decoded.min(axis=0), decoded.max(axis=0)
    half = np.maximum((hi - lo) / 2, 1e-3).astype(np.float32)
    models = {}
    if with_sh_rest is None:
        with_sh_rest = bool(rng.integers(0, 2))
    for attr in SketchAttribute:
        if attr is SketchAttribute.SH_REST and (sh_degree == 0 or not with_sh_rest):
            continue
        d = int(rng.integers(0, max_degree + 1))
        coeffs = rng.normal(0, 0.3, (monomial_count(d), attr.outputs(sh_degree)))
        if attr is SketchAttribute.OPACITY:
            coeffs[0] += 0.5
        if attr is SketchAttribute.ROTATION:
            coeffs[0, 0] += 2.0
        models[attr] = coeffs.astype(np.float16)
    return SketchCluster(blob, decoded.shape[0], ((lo + hi) / 2).astype(np.float32), half, models)


def random_sketch(rng: np.random.Generator, sh_degree: int, clusters: int) -> list[SketchCluster]:
    """Random clusters; runs of consecutive clusters sometimes share one order-preserving blob."""
    import DracoPy

    out = [random_cluster(rng, sh_degree) for _ in range(clusters)]
    start = 0
    while start < len(out):
        run = int(rng.integers(1, 4))
        members = out[start:start + run]
        if len(members) > 1:
            parts = [np.asarray(DracoPy.decode(m.draco).points, np.float32).reshape(-1, 3)
                     for m in members]
            blob = DracoPy.encode(np.concatenate(parts), quantization_bits=20,
                                  compression_level=1, preserve_order=True)
            shared = np.asarray(DracoPy.decode(blob).points, np.float32).reshape(-1, 3)
            rows = 0
            for m, part in zip(members, parts):
                mine = shared[rows:rows + len(part)]
                rows += len(part)
                lo, hi = mine.min(axis=0), mine.max(axis=0)
                m.center = ((lo + hi) / 2).astype(np.float32)
                m.half_extent = np.maximum((hi - lo) / 2, 1e-3).astype(np.float32)
                m.draco = b""
            members[0].draco = blob
        start += run
    return out


def random_codebooks(rng: np.random.Generator, sh_degree: int) -> list[Codebook]:
    """One random codebook per patch attribute, with random entry dimensions and sizes."""
    books = []
    for attr in PatchAttribute.for_sh_degree(sh_degree):
        dims = [d for d in range(1, attr.width + 1) if attr.width % d == 0]
        dim = int(rng.choice(dims))
        count = int(rng.integers(1, 257))
        entries = rng.normal(0, 1, (count, dim))
        if attr is PatchAttribute.OPACITY:
            entries = rng.uniform(0, 1, (count, dim))
        books.append(Codebook(attr, entries.astype(np.float16)))
    return books


def random_patch_layer(rng: np.random.Generator, codebooks: list[Codebook], n: int,
                       mode: PositionMode | None = None) -> PatchLayer:
    """A patch layer with random positions (in a random mode) and valid random indices."""
    xyz = rng.uniform(-20, 20, (n, 3))
    mode = PositionMode(int(rng.integers(0, 4))) if mode is None else mode
    positions = positions_in_mode(xyz, mode, 40.0 / 65535)
    indices = {cb.attribute: rng.integers(0, cb.entries.shape[0], (n, cb.groups)).astype(np.uint8)
               for cb in codebooks}
    return PatchLayer(positions, indices)


def positions_in_mode(xyz: np.ndarray, mode: PositionMode, quant_step: float) -> PatchPositions:
    """Positions stored in ``mode`` (QUANT16 with ``quant_step``, DRACO order-preserving)."""
    if mode == PositionMode.DRACO:
        import DracoPy

        if len(xyz) == 0:
            return PatchPositions.draco(b"", np.zeros((0, 3), np.float32))
        blob = DracoPy.encode(np.asarray(xyz, np.float32), quantization_bits=18,
                              compression_level=1, preserve_order=True)
        return PatchPositions.draco(blob, np.asarray(DracoPy.decode(blob).points).reshape(-1, 3))
    if mode == PositionMode.QUANT16:
        return PatchPositions.quant16(xyz, quant_step)
    if mode == PositionMode.FLOAT16:
        return PatchPositions.float16(xyz)
    return PatchPositions.float32(xyz)


def random_encoded_scene(seed: int = 0, clusters: int = 4, patch_layers: int = 2,
                         patch_size: int = 200, sh_degree: int | None = None,
                         metadata: dict | None = None) -> EncodedScene:
    """A valid :class:`EncodedScene` of random components (format tests, conformance, demo)."""
    rng = np.random.default_rng(seed)
    sh = int(rng.integers(0, 4)) if sh_degree is None else sh_degree
    sketch = random_sketch(rng, sh, clusters)
    books = random_codebooks(rng, sh) if patch_layers else []
    layers = [random_patch_layer(rng, books, int(rng.integers(0, patch_size + 1)))
              for _ in range(patch_layers)]
    return EncodedScene(sh, sketch, books, layers, metadata)
