"""Tests of the multi-criteria DBSCAN (spcodec.encoder.categorize) and its neighbour search.

* Structure recovery on synthetic scenes with ground truth, at three scales.
* Exact agreement with a plain O(n^2) reference on small random inputs (hypothesis), ties included.
* Invariances: chunk size, repetition, input order, quaternion sign and ellipsoid symmetries.
* Degenerate inputs and a real-scene smoke test.
"""

from __future__ import annotations

import subprocess
import sys
from collections import deque

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from spcodec import GaussianCloud, read_ply
from spcodec.encoder.categorize import MultiCriteriaDBSCAN, canonical_labels, categorize, principal_axes
from spcodec.encoder.config import CategorizeConfig
from spcodec.encoder.morton import morton_order
from spcodec.encoder.neighbors import iter_radius_pairs
from spcodec.synthetic import make_scene

from conftest import data_dir

FOURTH_ST = "pdal_fourth_st_spz/fourth_st_inria.ply"
PROPERTY = settings(deadline=None, suppress_health_check=[HealthCheck.too_slow])


# ----------------------------------------------------------------------------------- helpers
def quat_mul(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Hamilton product of (w, x, y, z) quaternions, row-wise (q broadcasts)."""
    pw, px, py, pz = np.moveaxis(p, -1, 0)
    qw, qx, qy, qz = np.moveaxis(np.broadcast_to(q, p.shape), -1, 0)
    return np.stack([pw * qw - px * qx - py * qy - pz * qz,
                     pw * qx + px * qw + py * qz - pz * qy,
                     pw * qy - px * qz + py * qw + pz * qx,
                     pw * qz + px * qy - py * qx + pz * qw], axis=-1)


def with_quats(cloud: GaussianCloud, quats: np.ndarray) -> GaussianCloud:
    out = cloud.subset(slice(None))
    out.quats = quats.astype(np.float32)
    return out


def turn_about_local_axis(cloud: GaussianCloud, axis: np.ndarray,
                          where: np.ndarray) -> GaussianCloud:
    """Rotate the selected Gaussians by 180 degrees about their own local axis ``axis[i]`` (0-2).

    The ellipsoid is unchanged (its covariance is symmetric under such turns); the world-space
    directions of the other two local axes are negated.
    """
    pure = np.zeros((len(cloud), 4))
    pure[np.arange(len(cloud)), 1 + axis] = 1.0
    turned = quat_mul(cloud.quats.astype(np.float64), pure)
    return with_quats(cloud, np.where(where[:, None], turned, cloud.quats))


def precision_recall(labels: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    clustered = labels >= 0
    hits = np.sum(clustered & truth)
    return hits / max(clustered.sum(), 1), hits / truth.sum()


def same_partition(a: np.ndarray, b: np.ndarray) -> bool:
    """Labels equal up to renumbering (a bijection between cluster ids), noise matching noise."""
    if not np.array_equal(a < 0, b < 0):
        return False
    pairs = set(zip(a[a >= 0].tolist(), b[b >= 0].tolist()))
    return len(pairs) == len({p for p, _ in pairs}) == len({q for _, q in pairs})


# ---------------------------------------------------------------- the O(n^2) plain reference
def reference_dbscan(cloud: GaussianCloud, eps_s: float, eps_d: float, eps_c: float,
                     min_samples: int, min_cluster_size: int, metric: str):
    """Textbook DBSCAN over all pairs, with the documented rules spelled out in plain Python.

    Scalar arithmetic in the same order as the implementation (Python floats are IEEE doubles),
    so ties at a threshold are decided identically.
    """
    n = len(cloud)
    pos = cloud.means.astype(np.float64).tolist()
    axes = principal_axes(cloud).tolist()
    rgb = cloud.rgb().astype(np.float64).tolist()

    def sq(u, v):
        d0, d1, d2 = u[0] - v[0], u[1] - v[1], u[2] - v[2]
        return d0 * d0 + d1 * d1 + d2 * d2

    def direction(u, v):
        cos = min(max(u[0] * v[0] + u[1] * v[1] + u[2] * v[2], -1.0), 1.0)
        return (1.0 - (abs(cos) if metric == "axis" else cos)) / 2.0

    def neighbours(i, j):
        return i == j or (sq(pos[i], pos[j]) <= eps_s * eps_s
                          and direction(axes[i], axes[j]) <= eps_d
                          and sq(rgb[i], rgb[j]) <= eps_c * eps_c)

    hood = [[j for j in range(n) if neighbours(i, j)] for i in range(n)]
    core = [len(h) >= min_samples for h in hood]
    component = [-1] * n
    for seed in range(n):
        if core[seed] and component[seed] < 0:
            component[seed] = seed
            queue = deque([seed])
            while queue:
                i = queue.popleft()
                for j in hood[i]:
                    if core[j] and component[j] < 0:
                        component[j] = seed
                        queue.append(j)
    raw = list(component)
    for i in range(n):
        core_hood = [j for j in hood[i] if core[j]]
        if not core[i] and core_hood:
            nearest = min(core_hood, key=lambda j: (sq(pos[i], pos[j]), j))
            raw[i] = component[nearest]
    members: dict[int, list[int]] = {}
    for i, c in enumerate(raw):
        if c >= 0:
            members.setdefault(c, []).append(i)
    kept = sorted((m for m in members.values() if len(m) >= min_cluster_size), key=min)
    labels = np.full(n, -1, np.int64)
    for k, m in enumerate(kept):
        labels[m] = k
    return labels, np.array(core, bool), hood


# ----------------------------------------------------------------------- synthetic recovery
@pytest.mark.parametrize("seed", [0, 1])
@pytest.mark.parametrize("size", [1.0, 1000.0, 0.001])
def test_recovers_structured_gaussians_at_any_scale(seed, size):
    scene = make_scene(seed=seed, size=size)
    model = MultiCriteriaDBSCAN().fit(scene.cloud)
    precision, recall = precision_recall(model.labels_, scene.structured)
    assert precision >= 0.9 and recall >= 0.9, (precision, recall)
    assert model.n_clusters_ >= 12  # at least one cluster per curve, blobs left out


def test_spatial_radius_follows_the_scene_unit():
    eps = [MultiCriteriaDBSCAN().fit(make_scene(seed=3, size=s).cloud).eps_s_
           for s in (1.0, 1000.0, 0.001)]
    assert eps[1] == pytest.approx(1000 * eps[0], rel=1e-5)
    assert eps[2] == pytest.approx(0.001 * eps[0], rel=1e-5)


def test_recovers_structure_among_dense_clutter_with_random_axis_signs():
    """Ten times more blobs than curve points, axis signs randomized: colour and direction, not
    density alone, must separate structure from clutter."""
    scene = make_scene(seed=4, blobs=40_000)
    rng = np.random.default_rng(0)
    cloud = turn_about_local_axis(scene.cloud, np.ones(len(scene.cloud), int),
                                  rng.random(len(scene.cloud)) < 0.5)
    precision, recall = precision_recall(categorize(cloud), scene.structured)
    assert precision >= 0.9 and recall >= 0.9, (precision, recall)


# ------------------------------------------------------------------ equivalence (hypothesis)
@st.composite
def small_problems(draw):
    """A small cloud with many exact ties (grid positions, repeated colours and rotations) and
    thresholds that sit on those ties, plus a chunk size."""
    n = draw(st.integers(0, 28))
    unit = draw(st.sampled_from([1.0, 0.1, 0.37, 1e-3]))
    grid = np.array(draw(st.lists(st.tuples(*[st.integers(0, 4)] * 3), min_size=n, max_size=n)),
                    float).reshape(n, 3)
    jitter = draw(st.booleans())
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    means = (grid + (rng.normal(0, 0.3, (n, 3)) if jitter else 0.0)) * unit
    palette = rng.normal(0, 0.4, (3, 3))
    sh_dc = palette[rng.integers(0, 3, n)] + (rng.normal(0, 0.2, (n, 3)) * draw(st.booleans()))
    fixed = np.array([[1, 0, 0, 0], [0, 0, 0, 1], [0.7, 0.7, 0, 0], [0, 0, 0, 0], [-1, 0, 0, 0]])
    quats = np.where(rng.random((n, 1)) < 0.6, fixed[rng.integers(0, 5, n)],
                     rng.normal(size=(n, 4)))
    scales = np.where(rng.random((n, 1)) < 0.2, 0.0, rng.normal(size=(n, 3)))
    cloud = GaussianCloud(means=means, scales=scales, quats=quats,
                          opacities=np.zeros(n), sh_dc=sh_dc, sh_rest=np.zeros((n, 0, 3)))
    config = CategorizeConfig(
        eps_s=unit * draw(st.sampled_from([0.0, 1.0, 2 ** 0.5, 1.5, 2.0, 3 ** 0.5])),
        eps_d=draw(st.sampled_from([0.0, 0.05, 0.25, 0.5, 1.0])),
        eps_c=draw(st.sampled_from([0.0, 0.1, 0.3, 2.0])),
        direction_metric=draw(st.sampled_from(["axis", "signed"])),
        min_samples=draw(st.integers(1, 6)),
        min_cluster_size=draw(st.integers(1, 4)),
        chunk_size=draw(st.integers(1, 9)),
    )
    return cloud, config


@PROPERTY
@given(small_problems())
def test_matches_brute_force_reference(problem):
    cloud, config = problem
    model = MultiCriteriaDBSCAN(config).fit(cloud)
    labels, core, hood = reference_dbscan(cloud, config.eps_s, config.eps_d, config.eps_c,
                                          config.min_samples, config.min_cluster_size,
                                          config.direction_metric)
    np.testing.assert_array_equal(model.core_sample_mask_, core)
    np.testing.assert_array_equal(model.labels_, labels)  # same rules, same canonical numbering
    assert model.n_clusters_ == (labels.max() + 1 if labels.size else 0)
    for i in np.flatnonzero((model.labels_ >= 0) & ~core):  # borders join a neighbouring core
        assert any(core[j] and model.labels_[j] == model.labels_[i] for j in hood[i])


@PROPERTY
@given(st.integers(0, 60), st.integers(1, 70), st.floats(0.0, 0.6), st.integers(0, 2**32 - 1))
def test_radius_pairs_are_all_pairs_within_the_radius(n, chunk_size, radius, seed):
    points = np.random.default_rng(seed).random((n, 3)).round(1)  # rounding makes ties
    chunks = list(iter_radius_pairs(points, radius, chunk_size))
    found = [(int(i), int(j)) for c in chunks for i, j in zip(c.rows, c.cols)]
    d = points[:, None, :] - points[None, :, :]
    d2 = d[..., 0] * d[..., 0] + d[..., 1] * d[..., 1] + d[..., 2] * d[..., 2]
    expected = {(i, j) for i in range(n) for j in range(n)
                if i != j and d2[i, j] <= radius * radius}
    assert len(found) == len(set(found)) and set(found) == expected
    rows_per_chunk = [set(c.rows.tolist()) for c in chunks]
    assert all(len(r) <= chunk_size for r in rows_per_chunk)
    assert sum(len(r) for r in rows_per_chunk) == len(set().union(*rows_per_chunk))


@PROPERTY
@given(st.integers(0, 200), st.integers(0, 2**32 - 1))
def test_morton_order_is_a_permutation(n, seed):
    points = np.random.default_rng(seed).random((n, 3)) * 1e3
    np.testing.assert_array_equal(np.sort(morton_order(points)), np.arange(n))


def line_cloud(xs: list[float]) -> GaussianCloud:
    """Identical Gaussians at positions (x, 0, 0)."""
    cloud = GaussianCloud.zeros(len(xs))
    cloud.means[:, 0] = xs
    return cloud


def test_border_joins_its_nearest_core_and_ties_go_to_the_lowest_index():
    """Two clusters of five cores on a line, one border point between them (4 neighbours < 5)."""
    config = CategorizeConfig(eps_s=5.5, min_samples=5, min_cluster_size=1)
    left, right = [-9, -8, -7, -6, -5], [4, 5, 6, 7, 8]
    labels = categorize(line_cloud(left + right + [0]), config)
    assert labels[-1] == labels[5] != labels[0]  # the core at 4 is nearer than the one at -5
    tie_right = [5, 6, 7, 8, 9]  # now the cores at -5 and 5 are equally near
    labels = categorize(line_cloud(left + tie_right + [0]), config)
    assert labels[-1] == labels[4] != labels[5]
    labels = categorize(line_cloud(tie_right + left + [0]), config)
    assert labels[-1] == labels[0] != labels[9]


# ------------------------------------------------------------------------------ invariances
@pytest.fixture(scope="module")
def scene():
    return make_scene(seed=5)


@pytest.fixture(scope="module")
def fitted(scene):
    return MultiCriteriaDBSCAN().fit(scene.cloud)


@pytest.mark.parametrize("chunk_size", [1, 333, 4096, 1_000_000])
def test_chunk_size_does_not_change_the_result(scene, fitted, chunk_size):
    model = MultiCriteriaDBSCAN(CategorizeConfig(chunk_size=chunk_size)).fit(scene.cloud)
    np.testing.assert_array_equal(model.labels_, fitted.labels_)
    np.testing.assert_array_equal(model.core_sample_mask_, fitted.core_sample_mask_)


def test_repeated_fits_are_identical(scene, fitted):
    again = MultiCriteriaDBSCAN().fit(scene.cloud)
    np.testing.assert_array_equal(again.labels_, fitted.labels_)
    assert again.eps_s_ == fitted.eps_s_


def test_sampled_eps_is_reproducible_and_close_to_exact(scene):
    sampled = CategorizeConfig(eps_s_sample=2000, random_state=7)
    first = MultiCriteriaDBSCAN(sampled).fit(scene.cloud).eps_s_
    assert MultiCriteriaDBSCAN(sampled).fit(scene.cloud).eps_s_ == first
    exact = MultiCriteriaDBSCAN().fit(scene.cloud).eps_s_
    assert first == pytest.approx(exact, rel=0.1)


def test_labels_are_canonical(fitted):
    labels = fitted.labels_
    firsts = [np.flatnonzero(labels == k)[0] for k in range(fitted.n_clusters_)]
    assert firsts == sorted(firsts)
    assert np.bincount(labels[labels >= 0]).min() >= CategorizeConfig().min_cluster_size


def test_input_order_does_not_change_the_core_partition(scene, fitted):
    perm = np.random.default_rng(1).permutation(len(scene.cloud))
    model = MultiCriteriaDBSCAN().fit(scene.cloud.subset(perm))
    core = fitted.core_sample_mask_
    np.testing.assert_array_equal(model.core_sample_mask_, core[perm])
    assert same_partition(model.labels_[core[perm]], fitted.labels_[perm][core[perm]])


def test_quaternion_sign_changes_nothing(scene, fitted):
    flip = np.random.default_rng(2).random(len(scene.cloud)) < 0.5
    cloud = with_quats(scene.cloud, np.where(flip[:, None], -scene.cloud.quats, scene.cloud.quats))
    np.testing.assert_array_equal(categorize(cloud), fitted.labels_)


def test_half_turn_about_the_principal_axis_changes_nothing(scene, fitted):
    longest = np.argmax(scene.cloud.scales, axis=1)
    cloud = turn_about_local_axis(scene.cloud, longest, np.ones(len(scene.cloud), bool))
    np.testing.assert_allclose(np.abs((principal_axes(cloud) * principal_axes(scene.cloud))
                                      .sum(1)), 1.0, atol=1e-6)
    np.testing.assert_array_equal(categorize(cloud), fitted.labels_)


def test_half_turn_about_a_minor_axis_changes_nothing_for_the_axis_metric_only(scene, fitted):
    """The same ellipsoids with negated principal axes: the sign-free default is blind to it,
    the paper's signed formula is not (it splits the curves into sign classes)."""
    minor = (np.argmax(scene.cloud.scales, axis=1) + 1) % 3
    flip = np.random.default_rng(3).random(len(scene.cloud)) < 0.5
    cloud = turn_about_local_axis(scene.cloud, minor, flip)
    dots = (principal_axes(cloud) * principal_axes(scene.cloud)).sum(1)
    assert np.all(dots[flip] < -0.999) and np.all(dots[~flip] > 0.999)
    np.testing.assert_array_equal(categorize(cloud), fitted.labels_)
    signed = CategorizeConfig(direction_metric="signed")
    before, after = categorize(scene.cloud, signed), categorize(cloud, signed)
    assert after.max() > before.max()  # more, smaller clusters
    _, recall_before = precision_recall(before, scene.structured)
    _, recall_after = precision_recall(after, scene.structured)
    assert recall_after < recall_before - 0.02


# ------------------------------------------------------------------------ degenerate inputs
def test_unstructured_scene_has_almost_no_clusters():
    rng = np.random.default_rng(0)
    n = 6000
    cloud = GaussianCloud(means=rng.random((n, 3)), scales=rng.normal(-4, 0.5, (n, 3)),
                          quats=rng.normal(size=(n, 4)), opacities=rng.normal(size=n),
                          sh_dc=rng.uniform(-1.7, 1.7, (n, 3)), sh_rest=np.zeros((n, 0, 3)))
    model = MultiCriteriaDBSCAN().fit(cloud)
    assert np.mean(model.labels_ >= 0) < 0.01
    assert model.core_sample_mask_.mean() < 0.01


@pytest.mark.parametrize("n", [0, 1, 2])
def test_tiny_inputs_are_noise_by_default(n):
    model = MultiCriteriaDBSCAN().fit(GaussianCloud.zeros(n))
    assert model.labels_.shape == (n,) and model.labels_.dtype == np.int64
    assert np.all(model.labels_ == -1) and model.n_clusters_ == 0
    assert model.core_sample_mask_.shape == (n,) and np.isfinite(model.eps_s_)


def test_tiny_inputs_cluster_when_the_thresholds_allow():
    loose = CategorizeConfig(min_samples=1, min_cluster_size=1)
    np.testing.assert_array_equal(categorize(GaussianCloud.zeros(1), loose), [0])
    two = GaussianCloud.zeros(2)
    two.means[1, 0] = 5.0  # derived eps_s = 1.5 * 5: one cluster
    np.testing.assert_array_equal(categorize(two, loose), [0, 0])
    apart = CategorizeConfig(eps_s=1.0, min_samples=1, min_cluster_size=1)
    np.testing.assert_array_equal(categorize(two, apart), [0, 1])
    pair = CategorizeConfig(min_samples=2, min_cluster_size=1)
    np.testing.assert_array_equal(categorize(two, pair), [0, 0])


def test_non_finite_centres_are_rejected():
    cloud = GaussianCloud.zeros(3)
    cloud.means[1, 2] = np.nan
    with pytest.raises(ValueError, match="finite"):
        MultiCriteriaDBSCAN().fit(cloud)


@pytest.mark.parametrize("field, value", [
    ("eps_s", -1.0), ("eps_d", 1.5), ("eps_c", -0.1), ("eps_s_factor", 0.0),
    ("eps_s_quantile", 2.0), ("min_samples", 0), ("chunk_size", 0), ("direction_metric", "cos"),
])
def test_invalid_config_is_rejected(field, value):
    with pytest.raises(ValueError, match=field):
        CategorizeConfig(**{field: value})


# ------------------------------------------------------------------------------- the pieces
def test_principal_axes_match_rotation_matrices():
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(0)
    n = 500
    cloud = GaussianCloud.zeros(n)
    cloud.quats = rng.normal(size=(n, 4)).astype(np.float32) * 3
    cloud.scales = rng.normal(size=(n, 3)).astype(np.float32)
    matrices = Rotation.from_quat(cloud.quats[:, [1, 2, 3, 0]].astype(np.float64)).as_matrix()
    expected = matrices[np.arange(n), :, np.argmax(cloud.scales, axis=1)]
    np.testing.assert_allclose(principal_axes(cloud), expected, atol=1e-6)
    cloud.quats[:] = 0.0  # a zero quaternion decodes to the identity rotation
    np.testing.assert_allclose(principal_axes(cloud), np.eye(3)[np.argmax(cloud.scales, axis=1)])


def test_canonical_labels_drop_small_clusters_and_number_by_first_member():
    raw = np.array([7, 3, 3, -1, 9, 7, 3, 9, 5])
    np.testing.assert_array_equal(canonical_labels(raw, 2), [0, 1, 1, -1, 2, 0, 1, 2, -1])
    np.testing.assert_array_equal(canonical_labels(raw, 3), [-1, 0, 0, -1, -1, -1, 0, -1, -1])


def test_module_imports_no_torch():
    code = ("import sys, spcodec.encoder.categorize, spcodec.encoder.neighbors; "
            "sys.exit('torch' in sys.modules)")
    assert subprocess.run([sys.executable, "-c", code]).returncode == 0


# ------------------------------------------------------------------------------- real scene
@pytest.mark.slow
def test_real_scene_fourth_st():
    path = data_dir() / FOURTH_ST
    if not path.exists():
        pytest.skip(f"real data {FOURTH_ST} not found under {data_dir()} (set SPCODEC_DATA)")
    cloud = read_ply(path)
    model = MultiCriteriaDBSCAN().fit(cloud)
    clustered = float(np.mean(model.labels_ >= 0))
    print(f"fourth_st: {model.n_clusters_} clusters, {clustered:.1%} clustered, "
          f"eps_s={model.eps_s_:.4g}")
    assert 0.1 <= clustered <= 0.9, clustered
    assert model.n_clusters_ >= 50
    extent = float(np.max(cloud.means.max(axis=0) - cloud.means.min(axis=0)))
    assert 1e-4 * extent < model.eps_s_ < 0.05 * extent  # a local radius, in the scene's unit
