"""Sampled cameras for PLY-only scenes: determinism, splits, framing and coverage at any scale."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

import spcodec
from spcodec.cloud import GaussianCloud
from spcodec.errors import UsageError
from spcodec.imaging.cameras import Camera
from spcodec.imaging.views import (
    CoverageDiscs,
    ViewSamplingWarning,
    parse_up,
    robust_bounds,
    sample_views,
    sample_views_report,
    view_coverage,
)

from conftest import data_dir

DATA = data_dir()
RES = (160, 120)


def _cloud(points: np.ndarray, sigma: float, opacity_logit: float = 3.0) -> GaussianCloud:
    n = len(points)
    cloud = GaussianCloud.zeros(n)
    cloud.means = points.astype(np.float32)
    cloud.scales = np.full((n, 3), math.log(sigma), np.float32)
    cloud.quats = np.tile(np.array([1, 0, 0, 0], np.float32), (n, 1))
    cloud.opacities = np.full(n, opacity_logit, np.float32)
    return cloud


def _object_scene(size: float, seed: int = 0, floaters: bool = True) -> GaussianCloud:
    """A box-shaped object standing on a disc (y is down, so 'up' is -y), plus far floaters."""
    rng = np.random.default_rng(seed)
    box = rng.uniform(-0.5, 0.5, (6000, 3)) * [0.6, 1.0, 0.6]
    face = rng.integers(0, 3, len(box))
    box[np.arange(len(box)), face] = np.sign(box[np.arange(len(box)), face]) * \
        np.array([0.3, 0.5, 0.3])[face]  # push each point onto a face of the box
    angle, radius = rng.uniform(0, 2 * np.pi, 3000), np.sqrt(rng.uniform(0, 1, 3000))
    disc = np.stack([radius * np.cos(angle), np.full(3000, 0.5), radius * np.sin(angle)], 1)
    points = np.vstack([box, disc])
    if floaters:
        far = rng.normal(size=(150, 3))
        points = np.vstack([points, 40.0 * far / np.linalg.norm(far, axis=1, keepdims=True)])
    return _cloud(points * size, 0.01 * size)


def _positions(cameras: list[Camera]) -> np.ndarray:
    return np.array([c.position for c in cameras])


@pytest.mark.parametrize("size", [1e-3, 1.0, 1e3])
def test_views_see_the_object_at_any_scale(size: float) -> None:
    cloud = _object_scene(size)
    bounds = robust_bounds(cloud)
    assert np.all(np.abs(bounds.centre) < 0.1 * size)  # floaters do not move the robust centre
    assert bounds.radius <= 1.5 * size  # nor inflate the extent past the object's half-diagonal
    for split in ("train", "eval"):
        report = sample_views_report(cloud, 10, RES, split)
        assert len(report) == 10
        for view in report:
            assert view.passed
            assert view.check.coverage >= 0.15  # the whole disc and box, with a margin
            assert view.check.robust_in_front == 1.0
            assert view.check.robust_in_frame >= (1.0 if split == "eval" else 0.85)
            offset = view.camera.position - bounds.centre
            assert np.linalg.norm(offset) > bounds.radius  # outside the object
            assert np.linalg.norm(offset) < 6 * bounds.radius  # and not lost in the distance


def _elongated_scene(floaters: bool = True) -> tuple[GaussianCloud, np.ndarray]:
    """A round body with a thin neck sticking up (-y) that holds under 1% of the Gaussians, like
    a guitar's neck and headstock; plus far floaters. Returns the cloud and the neck's tip."""
    rng = np.random.default_rng(5)
    body = rng.normal(size=(12000, 3))
    body *= 0.5 * rng.uniform(0, 1, (12000, 1)) ** (1 / 3) / np.linalg.norm(body, axis=1,
                                                                              keepdims=True)
    tip = np.array([0.0, -1.2, 0.0])
    neck = np.linspace([0.0, -0.5, 0.0], tip, 100) + rng.normal(0, 0.005, (100, 3))
    points = [body, neck]
    if floaters:
        far = rng.normal(size=(150, 3))
        points.append(40.0 * far / np.linalg.norm(far, axis=1, keepdims=True))
    return _cloud(np.vstack(points), 0.01), tip


def test_thin_parts_are_framed_whole_and_floaters_are_not() -> None:
    """The guitar's headstock was cut off: a percentile box (and a 98 % framing) drops a thin part
    that holds few Gaussians. Every eval view, and every turntable frame, must show the neck's tip,
    inside a margin, while floaters at 40x the size stay out of the extent."""
    cloud, tip = _elongated_scene()
    assert np.percentile(cloud.means[:, 1], 2) > -0.6  # the core box alone ends at the body
    bounds = robust_bounds(cloud)
    assert bounds.lo[1] <= tip[1] + 0.01 and bounds.radius < 1.2  # floaters: about 40
    for count in (8, 6):
        for camera in sample_views(cloud, count, RES, "eval"):
            uv, depth = camera.project(tip[None])
            assert depth[0] > 0
            assert 0.04 * RES[0] <= uv[0, 0] <= 0.96 * RES[0]
            assert 0.04 * RES[1] <= uv[0, 1] <= 0.96 * RES[1]
    body_only, _ = _elongated_scene(floaters=False)
    body_only = body_only.subset(slice(0, 12000))
    assert robust_bounds(body_only).lo[1] > -0.55  # no neck, nothing to take in


@pytest.mark.parametrize("count", [2, 3, 5])
def test_a_few_gaussians_are_framed_whole(count: int) -> None:
    """A handful of centres straddle the box their own percentiles cut, which nothing is
    connected to; the box is then theirs, and views are placed around it."""
    points = (np.random.default_rng(count).normal(size=(count, 3)) * 2.0).astype(np.float32)
    bounds = robust_bounds(_cloud(points, 0.1))
    assert len(bounds.points) >= 1 and np.all(bounds.hi > bounds.lo)
    assert np.all(bounds.lo <= bounds.points.min(axis=0)) and \
        np.all(bounds.hi >= bounds.points.max(axis=0))
    if count == 2:  # neither is a floater of the other
        assert len(bounds.points) == 2
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ViewSamplingWarning)
        assert len(sample_views(_cloud(points, 0.1), 2, resolution=RES)) == 2


def test_views_scale_with_the_scene() -> None:
    small = sample_views(_object_scene(1e-3), 6, RES, "eval")
    large = sample_views(_object_scene(1e3), 6, RES, "eval")
    np.testing.assert_allclose(_positions(small) / 1e-3, _positions(large) / 1e3, rtol=1e-4,
                               atol=1e-4)


def test_sampling_is_deterministic_and_seeded() -> None:
    cloud = _object_scene(1.0)
    a = sample_views(cloud, 8, RES, "train", seed=3)
    b = sample_views(cloud, 8, RES, "train", seed=3)
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x.world_to_camera, y.world_to_camera)
        assert (x.fx, x.width, x.height, x.name) == (y.fx, y.width, y.height, y.name)
    c = sample_views(cloud, 8, RES, "train", seed=4)
    assert np.abs(_positions(a) - _positions(c)).max() > 0.1


def test_train_and_eval_views_are_disjoint() -> None:
    cloud = _object_scene(1.0)
    radius = robust_bounds(cloud).radius
    for count in (8, 24, 60):
        train = _positions(sample_views(cloud, count, RES, "train"))
        evals = _positions(sample_views(cloud, 12, RES, "eval"))
        gaps = np.linalg.norm(train[:, None] - evals[None], axis=2)
        assert gaps.min() > 0.02 * radius


def test_eval_views_look_at_the_robust_centre_with_up_up() -> None:
    cloud = _object_scene(2.0)
    centre = robust_bounds(cloud).centre
    for camera in sample_views(cloud, 8, RES, "eval"):
        uv, depth = camera.project(centre[None])
        np.testing.assert_allclose(uv[0], [RES[0] / 2, RES[1] / 2], atol=1e-6)
        assert depth[0] > 0
        # World -y (up) points up in the image: a point above the centre has a smaller row.
        uv_up, _ = camera.project((centre + [0.0, -0.1, 0.0])[None])
        assert uv_up[0, 1] < RES[1] / 2
    elevations = [np.dot(c.position - centre, [0, -1, 0]) / np.linalg.norm(c.position - centre)
                  for c in sample_views(cloud, 20, RES, "eval")]
    assert min(elevations) >= math.sin(math.radians(-15)) - 1e-9
    assert max(elevations) <= math.sin(math.radians(65)) + 1e-9


def test_up_axis_argument() -> None:
    np.testing.assert_array_equal(parse_up("+z"), [0, 0, 1])
    np.testing.assert_array_equal(parse_up("-y"), [0, -1, 0])
    np.testing.assert_allclose(parse_up([0, 0, 2]), [0, 0, 1])
    for bad in ("w", [0, 0, 0], [1, 2]):
        with pytest.raises(UsageError):
            parse_up(bad)
    cloud = _object_scene(1.0)
    for camera in sample_views(cloud, 4, RES, "eval", up="+z"):
        direction = camera.position - robust_bounds(cloud).centre
        assert direction[2] / np.linalg.norm(direction) > math.sin(math.radians(-15)) - 1e-9


def test_coverage_flags_views_of_empty_space_and_from_inside() -> None:
    cloud = _object_scene(1.0, floaters=False)
    good = sample_views(cloud, 1, RES, "eval")[0]
    assert view_coverage(cloud, good).coverage > 0.25
    away = Camera.look_at(np.array([0.0, 0.0, -3.0]), np.array([0.0, 0.0, -10.0]),
                          np.array([0.0, -1.0, 0.0]), *RES, math.radians(50))
    check = view_coverage(cloud, away)
    assert check.coverage == 0.0 and check.robust_in_front == 0.0 and not check.passes(0.15)
    inside = Camera.look_at(np.zeros(3), np.array([0.0, 0.0, 1.0]), np.array([0.0, -1.0, 0.0]),
                            *RES, math.radians(50))
    check = view_coverage(cloud, inside)
    assert check.robust_in_front < 0.9 and not check.passes(0.15)


def test_coverage_from_prepared_discs_equals_coverage_from_the_cloud() -> None:
    """The view search prepares the discs once per cloud; every camera must see the same."""
    cloud = _object_scene(1.0)
    discs = CoverageDiscs.of(cloud)
    for camera in sample_views(cloud, 3, RES, "train", up="+z"):
        assert view_coverage(cloud, camera, discs=discs) == view_coverage(cloud, camera)


def test_coverage_counts_wide_gaussians_whose_centres_are_off_the_grid() -> None:
    """Only the stamps around the centres land on the grid (this once failed on int64 cells)."""
    points = np.array([[2.0, 0.0, 0.0], [2.0, 0.3, 0.1], [2.1, -0.3, 0.0]])
    cloud = _cloud(points, 0.3)
    camera = Camera.look_at(np.array([0.0, 0.0, -3.0]), np.zeros(3), np.array([0.0, -1.0, 0.0]),
                            *RES, math.radians(50))
    assert (camera.project(points)[0][:, 0] > RES[0]).all()
    assert view_coverage(cloud, camera, robust_bounds(cloud)).coverage > 0.0


def test_bad_views_are_adjusted_towards_better_elevations() -> None:
    """A flat disc seen edge-on covers almost nothing; the sampler must tilt the view up."""
    rng = np.random.default_rng(1)
    angle, radius = rng.uniform(0, 2 * np.pi, 4000), np.sqrt(rng.uniform(0, 1, 4000))
    disc = np.stack([radius * np.cos(angle), np.zeros(4000), radius * np.sin(angle)], 1)
    cloud = _cloud(disc, 0.01)
    edge_on = Camera.look_at(np.array([3.0, 0.0, 0.0]), np.zeros(3), np.array([0.0, -1.0, 0.0]),
                             *RES, math.radians(50))
    assert view_coverage(cloud, edge_on).coverage < 0.1
    report = sample_views_report(cloud, 4, RES, "eval", elevation_deg=(0.0, 0.0),
                                 min_coverage=0.2)
    for view in report:
        assert view.passed and view.check.coverage >= 0.2
        assert -view.camera.position[1] > 0.05 * np.linalg.norm(view.camera.position)


def test_unreachable_coverage_warns_and_keeps_the_count() -> None:
    cloud = _object_scene(1.0)
    with pytest.warns(ViewSamplingWarning):
        report = sample_views_report(cloud, 3, RES, "eval", min_coverage=0.999)
    assert len(report) == 3 and not any(v.passed for v in report)
    with warnings.catch_warnings():  # warn=False: the same views, and nothing said
        warnings.simplefilter("error", ViewSamplingWarning)
        quiet = sample_views_report(cloud, 3, RES, "eval", min_coverage=0.999, warn=False)
    assert [v.camera.position.tolist() for v in quiet] == [v.camera.position.tolist() for v in report]


def test_invalid_arguments() -> None:
    cloud = _object_scene(1.0)
    with pytest.raises(UsageError):
        sample_views(cloud, 0, RES)
    with pytest.raises(UsageError):
        sample_views(cloud, 3, RES, split="test")
    with pytest.raises(UsageError):
        sample_views(cloud, 3, RES, elevation_deg=(50.0, 10.0))
    with pytest.raises(UsageError):
        sample_views(GaussianCloud.zeros(0), 3, RES)


REAL_SCENES = {  # path under $SPCODEC_DATA -> (up axis, minimum coverage seen in any view)
    "pdal_fourth_st_spz/fourth_st_inria.ply": ("-y", 0.12),
    "playcanvas_biker_guitar/biker_from_spz_inria.ply": ("-y", 0.12),
    "playcanvas_biker_guitar/guitar_inria.ply": ("-y", 0.1),
    "v3dg_donut_mipsplatting/fused.ply": ("+z", 0.35),
    "kacytran_try_sh3/point_cloud_iteration_7000.ply": ("-y", 0.35),
}


@pytest.mark.slow
@pytest.mark.parametrize("relative", sorted(REAL_SCENES))
def test_views_see_real_scenes(relative: str) -> None:
    path = DATA / relative
    if not path.is_file():
        pytest.skip(f"real scene {path} is not present")
    cloud = spcodec.read_ply(path)
    up, min_coverage = REAL_SCENES[relative]
    with warnings.catch_warnings():
        warnings.simplefilter("error", ViewSamplingWarning)
        train = sample_views_report(cloud, 8, RES, "train", up=up)
        evals = sample_views_report(cloud, 8, RES, "eval", up=up)
    for view, in_frame in [(v, 0.85) for v in train] + [(v, 1.0) for v in evals]:
        assert view.passed
        assert view.check.coverage >= min_coverage
        assert view.check.robust_in_front == 1.0 and view.check.in_front > 0.95
        assert view.check.robust_in_frame >= in_frame
    gaps = np.linalg.norm(_positions([v.camera for v in train])[:, None]
                          - _positions([v.camera for v in evals])[None], axis=2)
    assert gaps.min() > 0.02 * robust_bounds(cloud).radius


# ------------------------------------------------------------------------------ close-up crops
def test_close_crops_are_pieces_of_nearer_views_that_see_the_scene():
    from spcodec.imaging.views import close_crops

    cloud = _object_scene(2.0)
    bounds = robust_bounds(cloud)
    crops = close_crops(cloud, 6, distance=0.5, resolution=200, crop=64, seed=3)
    again = close_crops(cloud, 6, distance=0.5, resolution=200, crop=64, seed=3)
    assert all(np.array_equal(a.world_to_camera, b.world_to_camera) and (a.cx, a.cy) == (b.cx, b.cy)
               for a, b in zip(crops, again))
    whole = sample_views(cloud, 6, resolution=(200, 200), split="train", seed=4)
    for crop, full in zip(crops, whole):
        assert (crop.width, crop.height) == (64, 64) and crop.fx == full.fx
        # half as far from the centre, looking the same way
        assert np.linalg.norm(crop.position - bounds.centre) == pytest.approx(
            0.5 * np.linalg.norm(full.position - bounds.centre))
        assert np.allclose(crop.rotation, full.rotation)
        # its pixels are those of the whole nearer frame, shifted, and inside it
        offset = np.array([full.cx - crop.cx, full.cy - crop.cy])
        assert (offset >= 0).all() and (offset + 64 <= 200).all()
        uv, depth = crop.project(bounds.points)
        inside = (depth > 0) & (uv >= 0).all(axis=1) & (uv < 64).all(axis=1)
        assert inside.any()  # centred on a point of the scene


def test_close_crops_refuse_what_cannot_be_cut():
    from spcodec.imaging.views import close_crops

    cloud = _object_scene(1.0)
    with pytest.raises(UsageError, match="crop"):
        close_crops(cloud, 2, resolution=100, crop=200)
    with pytest.raises(UsageError, match="distance"):
        close_crops(cloud, 2, distance=0.0)
