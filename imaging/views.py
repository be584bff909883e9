"""Cameras for a scene given only as Gaussians (a PLY): robust framing, coverage checks, splits.

A codec is judged by renders, but a bare PLY has no cameras. This module makes a deterministic set
that looks at the scene the way its capture did: from outside, at the part that holds the mass.

Strategy (all lengths relative to the scene, so a 0.3-unit object and a 1000-unit one behave alike):

1. **Robust extent** (:func:`robust_bounds`): centres of Gaussians with opacity >= 0.05. Their
   per-axis 2nd..98th percentile box is the *core*, where the mass is. Thin parts hold too few
   Gaussians to move a percentile (a guitar's headstock, a lamp post, an antenna), so the extent
   also takes in what is *connected* to the core: points in the occupied cells of a grid (the
   core's longest side / 48) that touch the core's cells through occupied neighbours, up to
   ``reach`` (one longest side) beyond the core. Floaters are isolated cells and far background
   lies beyond the reach: both stay out.
2. **Directions**: a Fibonacci spiral over the band of elevations ``elevation_deg`` (default
   -15..65 degrees) above the horizon of the ``up`` axis, equal-area in elevation, azimuths a
   golden angle apart from a seed-dependent start. Training views start at that azimuth, evaluation
   views half a golden angle (68.75 deg) further, so the two sets never share a position.
   ``up`` defaults to **-y**: COLMAP-derived scenes and PLYs converted to RDF (x right, y down,
   z forward), like fourth_st and biker, have -y up. Blender-made scenes (donut) are z-up: pass
   ``up="+z"``. No automatic estimate is made: on our real scenes principal axes and dominant
   planes point at the wrong axis as often as the right one (fourth_st's flattest axis is z, its
   up is -y), so a wrong guess would be silent, while a wrong explicit ``up`` only rolls and tilts
   views, which still see the scene.
3. **Framing**: each camera looks at the robust centre from the distance at which *every*
   robust point projects inside ``fill`` (default 90%, a 5% margin on each side) of the image,
   solved in closed form per point; the camera never comes closer than the robust points' depth
   extent allows (all of them in front). Training views then get a seeded distance jitter (x0.8..1.25)
   and a small target jitter, for variety when distilling; evaluation views are exactly framed.
4. **Check** (:func:`view_coverage`): Gaussians are stamped as discs of their projected 2-sigma
   radius on a coarse grid (32 cells across), accumulating opacity; coverage is the fraction of
   cells whose accumulated opacity reaches 0.5. A view passes when coverage >= ``min_coverage``
   and >= 99% of the robust points are in front of it. A failing view is replaced by the first
   passing nearby direction (elevation steps towards the band's middle, azimuth steps of 15 deg);
   if none passes, the best one is kept and a :class:`ViewSamplingWarning` says so.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from spcodec.cloud import GaussianCloud
from spcodec.errors import UsageError

from .cameras import Camera

GOLDEN_ANGLE = math.pi * (3.0 - math.sqrt(5.0))
"""Azimuth step of the Fibonacci spiral (about 137.5 degrees)."""

DEFAULT_UP = (0.0, -1.0, 0.0)
COVERAGE_GRID = 32
"""Cells across the image for the coverage check (rows follow the aspect ratio)."""

_MAX_ROBUST_POINTS = 20000

MIN_COVERAGE = 0.1
"""Coverage below which a sampled view is moved. A view of empty space or from inside scores
about 0; a thin object seen whole in a landscape view (guitar at 4:3) only 0.12-0.15."""


class ViewSamplingWarning(UserWarning):
    """A sampled view could not be made to pass the coverage check and was kept anyway."""


@dataclass(frozen=True)
class SceneBounds:
    """Robust extent of a cloud: the percentile box and a subsample of the points inside it."""

    lo: np.ndarray
    hi: np.ndarray
    points: np.ndarray  # (n, 3) float64, robust inliers, at most 20,000 (evenly subsampled)

    @property
    def centre(self) -> np.ndarray:
        return (self.lo + self.hi) / 2.0

    @property
    def radius(self) -> float:
        """Half the diagonal of the percentile box."""
        return float(np.linalg.norm(self.hi - self.lo) / 2.0)


@dataclass(frozen=True)
class ViewCoverage:
    """How well one camera sees a cloud (see :func:`view_coverage`)."""

    coverage: float
    """Fraction of coarse grid cells with accumulated opacity >= 0.5."""
    in_front: float
    """Fraction of the opaque Gaussians (opacity >= 0.05) with positive depth."""
    robust_in_front: float
    """Fraction of the robust points with positive depth."""
    robust_in_frame: float
    """Fraction of the robust points that project inside the image."""

    def passes(self, min_coverage: float) -> bool:
        return self.coverage >= min_coverage and self.robust_in_front >= 0.99


@dataclass(frozen=True)
class SampledView:
    camera: Camera
    check: ViewCoverage
    passed: bool


def parse_up(up: Sequence[float] | str) -> np.ndarray:
    """A unit up vector from a 3-vector or a signed axis name such as ``"-y"`` or ``"+z"``."""
    if isinstance(up, str):
        text = up.strip().lower()
        sign = -1.0 if text.startswith("-") else 1.0
        axis = text.lstrip("+-")
        if axis not in ("x", "y", "z"):
            raise UsageError(f"up must be a vector or one of +x -x +y -y +z -z, got {up!r}")
        vector = np.zeros(3)
        vector["xyz".index(axis)] = sign
        return vector
    vector = np.asarray(up, dtype=np.float64).reshape(-1)
    if vector.shape != (3,) or not np.isfinite(vector).all() or np.linalg.norm(vector) < 1e-9:
        raise UsageError(f"up must be a non-zero 3-vector, got {up!r}")
    return vector / np.linalg.norm(vector)


def _opacity(cloud: GaussianCloud) -> np.ndarray:
    return 1.0 / (1.0 + np.exp(-cloud.opacities.astype(np.float64)))


def robust_bounds(cloud: GaussianCloud, percentile: float = 2.0, min_opacity: float = 0.05,
                  reach: float = 1.0) -> SceneBounds:
    """Robust box of the centres of the non-transparent Gaussians (see the module docstring).

    ``percentile`` cuts the core box; ``reach``, in longest sides of the core, bounds how far
    beyond it the parts connected to it are followed.
    """
    if len(cloud) == 0:
        raise UsageError("cannot place cameras around an empty cloud")
    means = cloud.means.astype(np.float64)
    finite = np.isfinite(means).all(axis=1)
    solid = finite & (_opacity(cloud) >= min_opacity)
    points = means[solid] if solid.sum() >= 10 else means[finite]
    if len(points) == 0:
        raise UsageError("the cloud has no finite Gaussian centre")
    core_lo, core_hi = np.percentile(points, [percentile, 100.0 - percentile], axis=0)
    inside = points[_connected_to_box(points, core_lo, core_hi, reach)]
    if len(inside) == 0:  # a few points straddle the box their own percentiles cut
        inside = points
    lo, hi = inside.min(axis=0), inside.max(axis=0)
    if len(inside) > _MAX_ROBUST_POINTS:  # an even stride keeps it deterministic and spread out
        inside = inside[np.linspace(0, len(inside) - 1, _MAX_ROBUST_POINTS).astype(np.int64)]
    size = hi - lo
    floor = max(float(size.max()) * 1e-3, 1e-9)  # a flat or single-point scene still has a volume
    lo, hi = lo - np.maximum(floor - size, 0) / 2, hi + np.maximum(floor - size, 0) / 2
    return SceneBounds(lo, hi, inside)


_CELLS_PER_SIDE = 48
"""Grid cells along the core's longest side when following parts connected to it."""


def _connected_to_box(points: np.ndarray, lo: np.ndarray, hi: np.ndarray, reach: float
                      ) -> np.ndarray:
    """Mask of the points in the box ``lo..hi`` or connected to it (see the module docstring).

    Points are binned on a grid of cubes spanning the box grown by ``reach`` longest sides on
    every side; cells holding a point are occupied, and the occupied cells of the components
    (26-neighbourhood) that meet the box are kept.
    """
    from scipy.ndimage import label

    cell = max(float((hi - lo).max()), 1e-12) / _CELLS_PER_SIDE
    margin = int(math.ceil(reach * _CELLS_PER_SIDE))  # cells
    origin = lo - margin * cell
    shape = np.floor((hi - origin) / cell).astype(np.int64) + margin + 1
    index = np.floor((points - origin) / cell).astype(np.int64)
    on_grid = np.all((index >= 0) & (index < shape), axis=1)
    occupied = np.zeros(tuple(shape), bool)
    occupied[tuple(index[on_grid].T)] = True
    components, _ = label(occupied, structure=np.ones((3, 3, 3), bool))
    box = tuple(slice(int(a), int(b) + 1) for a, b in
                zip(np.floor((lo - origin) / cell), np.floor((hi - origin) / cell)))
    kept = np.zeros(int(components.max()) + 1, bool)
    kept[np.unique(components[box])] = True
    kept[0] = False  # the empty cells
    mask = np.zeros(len(points), bool)
    mask[on_grid] = kept[components[tuple(index[on_grid].T)]]
    return mask


def _frame(up: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors spanning the horizontal plane of ``up``."""
    helper = np.eye(3)[int(np.argmin(np.abs(up)))]
    e1 = np.cross(up, helper)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(up, e1)


def _direction(up: np.ndarray, elevation: float, azimuth: float) -> np.ndarray:
    e1, e2 = _frame(up)
    return math.cos(elevation) * (math.cos(azimuth) * e1 + math.sin(azimuth) * e2) + \
        math.sin(elevation) * up


def framing_distance(points: np.ndarray, target: np.ndarray, direction: np.ndarray,
                     up: np.ndarray, width: int, height: int, fov_y: float, fill: float = 0.9,
                     quantile: float = 1.0) -> float:
    """Distance along ``direction`` from ``target`` at which the points fill the frame.

    For a camera at ``target + d * direction`` looking at ``target``, a point with camera
    coordinates (X, Y, Z + d) is inside ``fill`` of the half-width when |f X| / (Z + d) <=
    fill * W / 2, i.e. d >= |f X| / (fill W / 2) - Z (same for Y). The returned d is the
    ``quantile`` of these per-point requirements, but never less than what keeps every point at
    least 5% of the scene depth in front of the camera.
    """
    camera = Camera.look_at(target + direction, target, up, width, height, fov_y)
    rel = (points - target) @ camera.rotation.T  # camera axes, origin at the target
    x, y, z = rel[:, 0], rel[:, 1], rel[:, 2]
    need_x = np.abs(camera.fx * x) / (fill * width / 2.0) - z
    need_y = np.abs(camera.fy * y) / (fill * height / 2.0) - z
    need = float(np.quantile(np.maximum(need_x, need_y), quantile))
    depth_span = float(z.max() - z.min()) if len(z) else 0.0
    in_front = float(-z.min()) + 0.05 * max(depth_span, 1e-9) if len(z) else 0.0
    return max(need, in_front, 1e-9)


@dataclass(frozen=True)
class CoverageDiscs:
    """The Gaussians :func:`view_coverage` stamps, prepared once per cloud: a view search checks
    dozens of cameras of the same cloud, and these arrays do not depend on the camera."""

    means: np.ndarray
    """(m, 3) float64 centres of the Gaussians at or above the opacity threshold."""
    sigma: np.ndarray
    """(m,) largest standard deviation of each."""
    alpha: np.ndarray
    """(m,) opacity, capped at 0.99 so its optical depth stays finite."""

    @classmethod
    def of(cls, cloud: GaussianCloud, min_opacity: float = 0.05) -> "CoverageDiscs":
        alpha = np.minimum(_opacity(cloud), 0.99)
        solid = alpha >= min_opacity
        return cls(cloud.means.astype(np.float64)[solid],
                   np.exp(cloud.scales.astype(np.float64)[solid].max(axis=1)), alpha[solid])


def view_coverage(cloud: GaussianCloud, camera: Camera, bounds: SceneBounds | None = None,
                  grid: int = COVERAGE_GRID, min_opacity: float = 0.05,
                  discs: CoverageDiscs | None = None) -> ViewCoverage:
    """Coverage diagnostics of one camera, from projected centres and scales (no renderer).

    Each Gaussian with opacity >= ``min_opacity`` in front of the camera is a disc of radius
    2 sigma_max * f / depth on a grid of ``grid`` cells across; the cells accumulate optical depth
    -log(1 - alpha) and count as covered at an accumulated opacity of 0.5. ``discs``: the same
    Gaussians prepared by :meth:`CoverageDiscs.of` (with ``min_opacity``), to check many cameras.
    """
    bounds = bounds or robust_bounds(cloud)
    discs = discs or CoverageDiscs.of(cloud, min_opacity)
    means, sigma, alpha = discs.means, discs.sigma, discs.alpha
    uv, depth = camera.project(means)
    in_front = float((depth > 0).mean()) if len(depth) else 0.0
    cell = camera.width / grid
    cols, rows = grid, max(1, int(round(camera.height / cell)))
    near = depth > 1e-9 * bounds.radius
    cu = np.floor(uv[near, 0] / cell).astype(np.int64)
    cv = np.floor(uv[near, 1] / (camera.height / rows)).astype(np.int64)
    radius = 2.0 * sigma[near] * camera.fx / depth[near] / cell
    density = -np.log1p(-alpha[near])
    # float even when no stamp falls on the grid (bincount of nothing is an int64 array)
    accumulated = np.bincount(*_cell_index(cu, cv, cols, rows, density),
                              minlength=rows * cols).astype(np.float64)
    wide = radius >= 0.5  # only these reach beyond their own cell; usually a small minority
    cu, cv, radius, density = cu[wide], cv[wide], radius[wide], density[wide]
    reach = int(min(3, np.ceil(radius.max(initial=0.0))))
    for dy in range(-reach, reach + 1):
        for dx in range(-reach, reach + 1):
            dist = math.hypot(dx, dy)
            if dist == 0:
                continue
            pick = radius >= dist - 0.5
            accumulated += np.bincount(*_cell_index(cu[pick] + dx, cv[pick] + dy, cols, rows,
                                                    density[pick]), minlength=rows * cols)
    covered = 1.0 - np.exp(-accumulated) >= 0.5
    ruv, rdepth = camera.project(bounds.points)
    inside = (rdepth > 0) & (ruv[:, 0] >= 0) & (ruv[:, 0] < camera.width) & (ruv[:, 1] >= 0) & \
        (ruv[:, 1] < camera.height)
    return ViewCoverage(float(covered.mean()), in_front, float((rdepth > 0).mean()),
                        float(inside.mean()))


def _cell_index(x: np.ndarray, y: np.ndarray, cols: int, rows: int, weights: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray]:
    """(flat cell index, weight) of the stamps that fall on the grid."""
    ok = (x >= 0) & (x < cols) & (y >= 0) & (y < rows)
    return y[ok] * cols + x[ok], weights[ok]


def sample_views_report(cloud: GaussianCloud, count: int, resolution: tuple[int, int] = (800, 600),
                        split: str = "train", seed: int = 0, fov_y_deg: float = 50.0,
                        up: Sequence[float] | str = DEFAULT_UP,
                        elevation_deg: tuple[float, float] = (-15.0, 65.0), fill: float = 0.9,
                        min_coverage: float = MIN_COVERAGE,
                        bounds: SceneBounds | None = None, warn: bool = True) -> list[SampledView]:
    """:func:`sample_views` with each view's coverage check and whether it passed."""
    if split not in ("train", "eval"):
        raise UsageError(f"split must be 'train' or 'eval', got {split!r}")
    if isinstance(count, bool) or not isinstance(count, int) or count < 1:
        raise UsageError(f"count must be a positive integer, got {count!r}")
    width, height = (int(v) for v in resolution)
    if width < 8 or height < 8:
        raise UsageError(f"resolution must be at least 8x8, got {resolution!r}")
    low, high = (math.radians(v) for v in elevation_deg)
    if not -math.pi / 2 <= low <= high <= math.pi / 2:
        raise UsageError(f"elevation_deg must be an increasing pair within [-90, 90], got "
                         f"{elevation_deg!r}")
    if not 0 < fov_y_deg < 170 or not 0 < fill <= 1:
        raise UsageError("fov_y_deg must be in (0, 170) and fill in (0, 1]")
    up_vector = parse_up(up)
    fov_y = math.radians(fov_y_deg)
    bounds = bounds or robust_bounds(cloud)
    rng = np.random.default_rng([seed, 0 if split == "train" else 1])
    start = np.random.default_rng(seed).uniform(0.0, 2.0 * math.pi)  # shared by both splits
    if split == "eval":
        start += GOLDEN_ANGLE / 2.0
    sin_low, sin_high = math.sin(low), math.sin(high)
    views, failures = [], 0
    discs = CoverageDiscs.of(cloud)
    for i in range(count):
        t = (i + 0.5) / count
        elevation = math.asin(sin_low + t * (sin_high - sin_low))
        azimuth = start + i * GOLDEN_ANGLE
        jitter = (rng.uniform(0.8, 1.25), rng.uniform(-0.1, 0.1, 3)) if split == "train" else None
        name = f"{split}_{i:03d}"
        best = None
        for d_el, d_az in _adjustments(elevation, (low + high) / 2.0):
            camera = _place(bounds, up_vector, elevation + d_el, azimuth + d_az, width, height,
                            fov_y, fill, jitter, name)
            check = view_coverage(cloud, camera, bounds, discs=discs)
            if check.passes(min_coverage):
                best = SampledView(camera, check, True)
                break
            if best is None or check.coverage > best.check.coverage:
                best = SampledView(camera, check, False)
        failures += not best.passed
        views.append(best)
    if failures and warn:
        warnings.warn(f"{failures} of {count} {split} views reach less than {min_coverage:.0%} "
                      "coverage even after adjustment; kept the best found", ViewSamplingWarning,
                      stacklevel=2)
    return views


def sample_views(cloud: GaussianCloud, count: int, resolution: tuple[int, int] = (800, 600),
                 split: str = "train", seed: int = 0, fov_y_deg: float = 50.0,
                 up: Sequence[float] | str = DEFAULT_UP,
                 elevation_deg: tuple[float, float] = (-15.0, 65.0), fill: float = 0.9,
                 min_coverage: float = MIN_COVERAGE,
                 bounds: SceneBounds | None = None, warn: bool = True) -> list[Camera]:
    """``count`` deterministic cameras of ``resolution`` (width, height) around ``cloud``.

    ``split="train"`` and ``split="eval"`` give disjoint position sets for the same seed (see the
    module docstring for the strategy). Same arguments, same cameras, on every machine.
    ``bounds``: ``robust_bounds(cloud)`` when the caller has it already (it is computed
    otherwise; a caller that also needs the centre the views look at saves doing it twice).
    ``warn=False``: no :class:`ViewSamplingWarning` where a view keeps its best try, for callers
    whose views are their own business (the encoder's), not the user's; a flag rather than a
    warnings filter, which is process-wide and not safe across threads.
    """
    return [v.camera for v in sample_views_report(
        cloud, count, resolution, split, seed, fov_y_deg, up, elevation_deg, fill, min_coverage,
        bounds=bounds, warn=warn)]


def _adjustments(elevation: float, middle: float) -> list[tuple[float, float]]:
    """(d_elevation, d_azimuth) to try for one view: itself first, then nearby directions."""
    towards = math.copysign(1.0, middle - elevation) if middle != elevation else 1.0
    steps = [(0.0, 0.0)]
    for k in (1, 2, 3):
        steps.append((towards * math.radians(10.0 * k), 0.0))
    for k in (1, 2):
        for sign in (1.0, -1.0):
            steps.append((towards * math.radians(10.0 * k), sign * math.radians(15.0 * k)))
    return steps


def _place(bounds: SceneBounds, up: np.ndarray, elevation: float, azimuth: float, width: int,
           height: int, fov_y: float, fill: float,
           jitter: tuple[float, np.ndarray] | None, name: str) -> Camera:
    direction = _direction(up, elevation, azimuth)
    target = bounds.centre
    if jitter is not None:
        target = target + jitter[1] * (bounds.hi - bounds.lo)
    distance = framing_distance(bounds.points, target, direction, up, width, height, fov_y, fill)
    if jitter is not None:
        distance *= jitter[0]
        rel_depth = (bounds.points - target) @ (-direction)
        distance = max(distance, float(-rel_depth.min()) * 1.05)  # stay outside the robust box
    return Camera.look_at(target + distance * direction, target, up, width, height, fov_y, name)


def close_crops(cloud: GaussianCloud, count: int, distance: float = 0.5,
                resolution: int = 800, crop: int = 256, seed: int = 0,
                up: Sequence[float] | str = DEFAULT_UP) -> list[Camera]:
    """``count`` training views from nearer, each cut to a ``crop``-pixel square of its frame.

    Whole-scene views leave fine texture below a pixel, so a model trained on them alone never
    learns it. These views take the directions of a separate set of training views, come
    ``distance`` times as far from the robust centre (0.5: half way) and have ``resolution``
    pixels across; a training step renders only a crop of ``crop`` pixels, centred on a random
    robust point the view sees (seeded), so detail costs its pixels and not the whole frame. The
    crop keeps the full view's intrinsics, shifted: its pixels are those of the full view.
    """
    if not 0 < distance <= 1:
        raise UsageError(f"close-up distance must lie in (0, 1], got {distance}")
    if not 8 <= crop <= resolution:
        raise UsageError(f"crop must lie in 8..{resolution} pixels, got {crop}")
    bounds = robust_bounds(cloud)
    directions = sample_views(cloud, count, resolution=(resolution, resolution), split="train",
                              seed=seed + 1, up=up)
    rng = np.random.default_rng([seed, 0xC105E])
    crops = []
    for i, camera in enumerate(directions):
        near = camera.dollied(bounds.centre, distance)
        uv, depth = near.project(bounds.points)
        seen = (depth > 0) & (uv >= 0).all(axis=1) & (uv < resolution).all(axis=1)
        u, v = uv[rng.choice(np.flatnonzero(seen))] if seen.any() else (resolution / 2,) * 2
        x0 = int(np.clip(round(u - crop / 2), 0, resolution - crop))
        y0 = int(np.clip(round(v - crop / 2), 0, resolution - crop))
        crops.append(Camera(crop, crop, near.fx, near.fy, near.cx - x0, near.cy - y0,
                            near.world_to_camera, f"close_{i:03d}"))
    return crops
